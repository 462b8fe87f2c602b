"""The agent on MAVLink: component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) of its vehicle's system.

What a ground station hears from the agent, whichever flight controller it
flies: a HEARTBEAT (type ONBOARD_CONTROLLER), its memory map and planned path
(the TUNNEL map stream), what its radio heard (TUNNEL ``RADIO_LINKS``, given by
``hear``; a simulated vehicle's radio, ``vehicle.sim.radios``), its state (running, paused and why; TUNNEL
``AGENT_STATUS``) and its messages (STATUSTEXT, chunked when long). What it
answers: MAV_CMD_MISSION_START addressed to it starts or resumes the mission
(a ground station's Resume), MAV_CMD_DO_PAUSE_CONTINUE addressed to it pauses
the mission and holds (param1 0; param2 1: the operator takes control, and the
agent commands nothing until handed back) or continues it (param1 1),
MAV_CMD_DO_REPOSITION addressed to it is the
operator's "Go here" (planned and flown by the agent, or denied with the
reason in a STATUSTEXT), and the parameter protocol for the mission
parameters (``SCN_*``). The caller sends what ``tick`` and ``handle`` return,
packed as component 191; the clock is the caller's (the wall clock live).
"""

from __future__ import annotations

from collections import deque

from vehicle.agent.agent import Agent
from vehicle.agent.params import Parameters
from vehicle.protocol import agent_status
from vehicle.protocol.geodesy import on_earth
from vehicle.protocol.mapstream import PAYLOAD, MapStreamer
from vehicle.protocol.mav import COMPANION as COMPONENT
from vehicle.protocol.mav import mavlink
from vehicle.protocol.radiostream import PER_PAYLOAD, RADIO_LINKS, LinkRecord, LinkSender
from vehicle.protocol.statustext import statustexts

HEARTBEAT_PERIOD = 1.0  # s
PATH_PERIOD = 0.5  # s between checks of the planned path
STATUS_PERIOD = 1.0  # s between repeats of an unchanged status
RADIO_PERIOD = 0.5  # s between batches of link records (sooner when a payload is full)
RADIO_BACKLOG = 10_000  # link records kept unsent at most (the oldest go first)
PARAM_MESSAGES = ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET")


def tunnel(kind: int, payload: bytes):
    return mavlink.MAVLink_tunnel_message(0, 0, kind, len(payload), list(payload.ljust(PAYLOAD, b"\0")))


class Companion:
    component = COMPONENT

    def __init__(self, agent: Agent, sysid: int, start: float = 0.0):
        self.agent = agent
        self.sysid = sysid
        self.streamer = MapStreamer(agent.map, agent.ctx.home)
        self.params = Parameters(agent.settings)
        self._next_heartbeat = self._next_path = self._next_status = start
        self._status: agent_status.AgentStatus | None = None
        self._texts = 0
        self.radio = LinkSender()
        self.heard: deque[LinkRecord] = deque(maxlen=RADIO_BACKLOG)
        self._next_radio = start

    def hear(self, records: list[LinkRecord]) -> None:
        """Link records the vehicle's radio measured (positions relative to home), to send in batches."""
        self.heard.extend(records)

    # ---- sending ----------------------------------------------------------------------------------
    def tick(self, now: float) -> list:
        """Messages due at ``now``."""
        out = []
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + HEARTBEAT_PERIOD
            out.append(self.heartbeat())
        out += self.texts()
        out += [self.tunnel(kind, payload) for kind, payload in self.streamer.tick(now)]
        if now >= self._next_path:
            self._next_path = now + PATH_PERIOD
            out += [self.tunnel(kind, payload) for kind, payload in self.streamer.path(self.agent.ctx.planned_path)]
        if self.heard and (now >= self._next_radio or len(self.heard) >= PER_PAYLOAD):
            self._next_radio = now + RADIO_PERIOD
            out += [self.tunnel(RADIO_LINKS, payload) for payload in self.radio.payloads(self.heard)]
            self.heard.clear()
        status = self.status()
        if status != self._status or now >= self._next_status:
            self._status, self._next_status = status, now + STATUS_PERIOD
            out.append(self.tunnel(agent_status.AGENT_STATUS, agent_status.encode(status)))
            out.append(self.tunnel(agent_status.AGENT_PROGRESS, agent_status.encode_progress(self.progress())))
        return out

    def tunnel(self, kind: int, payload: bytes):
        """The TUNNEL message of one of the agent's payloads (a log may keep the payload as it is instead)."""
        return tunnel(kind, payload)

    def next_due(self) -> float:
        """When ``tick`` next has something to send by the clock alone (a heartbeat, map, path or status repeat);
        until then only a step of the agent gives it more."""
        return min(self._next_heartbeat, self._next_path, self._next_status, self.streamer.next_due())

    def final(self) -> list:
        """A heartbeat, the messages not sent yet, the status and a full map snapshot: the last word of a log."""
        radio = [tunnel(RADIO_LINKS, payload) for payload in self.radio.payloads(self.heard)]
        self.heard.clear()
        return [self.heartbeat(), *self.texts(), tunnel(agent_status.AGENT_STATUS, agent_status.encode(self.status())),
                *[tunnel(kind, payload) for kind, payload in self.streamer.snapshot()], *radio]

    def heartbeat(self):
        agent = self.agent
        state = mavlink.MAV_STATE_STANDBY if agent.paused or agent.done else mavlink.MAV_STATE_ACTIVE
        return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID,
                                                 0, 0, state, 3)

    def texts(self) -> list:
        out = []
        outbox = self.agent.outbox
        while outbox:
            severity, text = outbox.popleft()
            self._texts += 1
            out += statustexts(text, severity, self._texts)
        return out

    def status(self) -> agent_status.AgentStatus:
        agent = self.agent
        reason = agent.pause_reason if agent.paused else agent.reason
        return agent_status.AgentStatus(agent.phase.value, agent.paused, agent.outcome or "", agent.mission_name,
                                        reason, agent.operator if agent.paused else "")

    def progress(self) -> agent_status.AgentProgress:
        agent = self.agent
        flying = agent.phase.value == "mission"
        done, total = (agent.mission.progress() or (0, 0)) if flying else (0, 0)
        return agent_status.AgentProgress(done, total, agent.ctx.time_left if flying else float("nan"))

    # ---- receiving --------------------------------------------------------------------------------
    def handle(self, message) -> list | None:
        """The replies to a message addressed to the agent; None if it is not one the agent answers."""
        kind = message.get_type()
        if kind in ("COMMAND_LONG", "COMMAND_INT") and message.command == mavlink.MAV_CMD_MISSION_START:
            result = mavlink.MAV_RESULT_ACCEPTED if self.mission_start() else mavlink.MAV_RESULT_DENIED
            return [mavlink.MAVLink_command_ack_message(message.command, result, 0, 0, message.get_srcSystem(),
                                                        message.get_srcComponent())]
        if kind in ("COMMAND_LONG", "COMMAND_INT") and message.command == mavlink.MAV_CMD_DO_PAUSE_CONTINUE:
            result = mavlink.MAV_RESULT_ACCEPTED if self.pause_continue(message) else mavlink.MAV_RESULT_DENIED
            return [mavlink.MAVLink_command_ack_message(message.command, result, 0, 0, message.get_srcSystem(),
                                                        message.get_srcComponent()), *self.texts()]
        if kind in ("COMMAND_LONG", "COMMAND_INT") and message.command == mavlink.MAV_CMD_DO_REPOSITION:
            result = mavlink.MAV_RESULT_ACCEPTED if self.go_here(message) else mavlink.MAV_RESULT_DENIED
            return [mavlink.MAVLink_command_ack_message(message.command, result, 0, 0, message.get_srcSystem(),
                                                        message.get_srcComponent()), *self.texts()]
        if kind in PARAM_MESSAGES:
            return self._param(message)
        if kind in ("COMMAND_LONG", "COMMAND_INT"):  # every command gets its answer, as from an autopilot
            return [mavlink.MAVLink_command_ack_message(message.command, mavlink.MAV_RESULT_UNSUPPORTED, 0, 0,
                                                        message.get_srcSystem(), message.get_srcComponent())]
        return None

    def go_here(self, message) -> bool:
        """DO_REPOSITION's latitude and longitude (COMMAND_INT: degrees x 1e7; COMMAND_LONG: degrees) as a target
        for the agent; False (and the reason said) if it refuses."""
        if message.get_type() == "COMMAND_INT":
            lat, lon = message.x * 1e-7, message.y * 1e-7
        else:
            lat, lon = message.param5, message.param6
        if not on_earth(lat, lon):
            self.agent.say("Go here: the target is not a position", mavlink.MAV_SEVERITY_WARNING)
            return False
        refused = self.agent.go_to(self.agent.fc.datum.to_local(lat, lon))
        if refused:
            self.agent.say(f"Go here refused: {refused}", mavlink.MAV_SEVERITY_WARNING)
        return refused is None

    def pause_continue(self, message) -> bool:
        """DO_PAUSE_CONTINUE: param1 0 pauses (param2 1: the operator takes control), 1 continues (hands back).
        False, and the reason said, if the agent cannot."""
        if message.param1 == 1:
            if self.agent.resume():
                return True
            self.agent.say(f"Continue refused: the mission is {self.status().state}, not paused",
                           mavlink.MAV_SEVERITY_WARNING)
            return False
        refused = self.agent.hold_for_operator(control=message.param2 == 1)
        if refused:
            self.agent.say(f"{'Take control' if message.param2 == 1 else 'Pause'} refused: {refused}",
                           mavlink.MAV_SEVERITY_WARNING)
        return refused is None

    def mission_start(self) -> bool:
        """Start the mission if it waits, resume it if paused; False if neither (it runs, or just ended)."""
        return self.agent.start() or self.agent.resume()

    def _param(self, m) -> list:
        kind = m.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self.params.message(i) for i in range(len(self.params))]
        index = self.params.find(m.param_id, getattr(m, "param_index", -1) if kind == "PARAM_REQUEST_READ" else -1)
        if index is None:
            return []  # ArduPilot stays silent about unknown parameters
        if kind == "PARAM_SET":
            param_id = self.params.ids[index]
            refused = self.params.set(param_id, m.param_value)
            if refused:
                return [*statustexts(refused, mavlink.MAV_SEVERITY_WARNING, 0), self.params.message(index)]
            if param_id == "SCN_SPEED":  # over MAVLink sent by the controller's next pump: no waiting here
                self.agent.set_speed()
        return [self.params.message(index)]
