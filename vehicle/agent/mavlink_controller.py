"""The flight-controller interface over MAVLink: the agent on a companion computer, flying an ArduPilot.

``MavlinkController`` speaks to an ArduPilot-like autopilot (ArduPilot itself,
or ``vehicle sim --role autopilot``) over any pymavlink connection, as
component 191 of the autopilot's system. Observations are the latest values of
the messages it asks for (SET_MESSAGE_INTERVAL, falling back to
REQUEST_DATA_STREAM); its clock is the autopilot's ``time_boot_ms``. Actions
are the commands ArduPilot takes in GUIDED: every COMMAND_LONG/INT waits for its
COMMAND_ACK, resent with confirmation += 1. A refusal or a silence is reported
(``took_over`` returns it, so the agent pauses) and the vehicle is told to
hold, so no target or velocity stays running that nobody watches. A gap in the
autopilot's heartbeat is no refusal: ``lost`` says it (the process pauses the
agent until the heartbeat is back), and a command left unanswered while it
lasted is not reported.

A ground station's requests to the agent (component 191) are answered by
``pump``, the main loop's call, never inside a wait for the autopilot's answer:
a request answered there could wait in turn, and a flood of them nested until
the agent died. The autopilot is heard where its heartbeat comes from (a link,
and a sender on it), as the ground station hears it: what comes in its name
from elsewhere while that heartbeat still comes is dropped. What is dropped,
and a message the agent fails on, is counted and said (``news``), and the
agent flies on.

What ArduPilot needs that our simulator does not: Rover refuses CONDITION_YAW
(it turns to a heading target instead, which expires after 3 s and is resent);
a mode change resets DO_CHANGE_SPEED (it is sent again); a copter holds best
on a zero-velocity target. Positions on the wire are latitude and longitude,
turned into scene metres with the datum; heights are above home.

Team-mates (``traffic``) are the ADSB_VEHICLE reports the autopilot forwards
(our simulator reports each vehicle of its world so; an ArduPilot with an
ADS-B receiver forwards what it hears): ICAO address = the team-mate's system
id, altitude geometric above sea level. A report older than TRAFFIC_STALE s of
the autopilot's clock is forgotten. ADS-B carries no size: a team-mate's
radius is assumed to be this vehicle's own. A ground station the agent talks
to directly (``--gcs``) relays the team-mates it sees when the autopilots do
not report them (two ArduPilots do not: each has its own world); those are
taken from that link only.
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from collections.abc import Callable

from vehicle.protocol import mission as mission_protocol
from vehicle.protocol.frames import Navigation, Pose
from vehicle.protocol.geodesy import Datum, heading_of, on_earth, wrap_pi
from vehicle.protocol.mav import ACCEPTED, AUTOPILOT, NO_ANSWER, UNSUPPORTED, mavlink, refusal
from vehicle.protocol.mav import COMPANION as COMPONENT
from vehicle.protocol.mission import MissionItem, MissionProgress
from vehicle.protocol.modes import DISARMED, Kind, name_of, number_of
from vehicle.protocol.radiostream import RADIO_LINKS, LinkReceiver, LinkRecord
from vehicle.protocol.rangefinder import Reading, Servo, reading_from, readings_from_obstacles
from vehicle.protocol.traffic import Traffic

HEARTBEAT_LOST = 2.0  # wall s without the autopilot's heartbeat before the agent stops commanding until it is back
FAILSAFE_NEWS = 3.0  # wall s: a mode change this soon after the autopilot said "failsafe" is the failsafe's
LINK_LOST_AFTER = 3.0  # wall s the autopilot's heartbeat is silent where it came from before it is heard elsewhere
REQUESTS_HELD = 256  # requests to the agent kept for the next pump's answers; more are dropped (a flood)
NEWS_EVERY = 5.0  # wall s at least between two lines about what was dropped (a flood is said, not each message)
FROM_ELSEWHERE = "messages in the autopilot's name from elsewhere"  # why a message was dropped (``dropped``)
TOO_MANY = f"requests beyond the {REQUESTS_HELD} it holds at once"
FAILED = "messages it failed to handle"
RADIO_HELD = 10_000  # link records kept for the agent to send at most
TRAFFIC_STALE = 3.0  # s of the autopilot's clock after which a team-mate's ADSB_VEHICLE is forgotten
TRAFFIC_HELD = 64  # team-mates remembered at once (more reports are dropped)
STREAMS = {  # message -> rate (Hz of the autopilot's clock) the agent asks for
    "HEARTBEAT": 4, "GLOBAL_POSITION_INT": 20, "ATTITUDE": 20, "SYS_STATUS": 1, "HOME_POSITION": 0.5,
    "MISSION_CURRENT": 2, "EXTENDED_SYS_STATE": 4, "DISTANCE_SENSOR": 10,
}
DATA_STREAMS = {  # the older REQUEST_DATA_STREAM groups that carry the same (for autopilots without the above)
    mavlink.MAV_DATA_STREAM_POSITION: 20, mavlink.MAV_DATA_STREAM_EXTRA1: 20,
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: 2, mavlink.MAV_DATA_STREAM_EXTRA3: 2,
}
HEADING_RESEND = 1.0  # s of autopilot time between repeats of a heading target (Rover drops them after 3 s)
YAW_DONE = math.radians(2)
ARRIVED = 0.3  # m from its target, navigation is going nowhere
MOVING = 0.3  # m/s: moving this fast, the vehicle is going somewhere (in modes the agent set no target for)
FACING = math.radians(12)  # a vehicle at rest not yet facing its target is still turning towards it
BLOCKED_SPEED = 0.1  # m/s: slower than this, short of its target and not turning, the vehicle is held back
IGNORE_ALL_BUT_VELOCITY = 0x0DC7  # type masks ArduPilot documents for GUIDED targets
IGNORE_ALL_BUT_YAW = 0x09FF


class FlightControllerError(Exception):
    """The flight controller cannot be flown: it does not answer, or it is not the vehicle we were told."""


def finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


class MavlinkController:
    """A flight controller over a pymavlink connection (see the module's docstring). ``connect()`` first."""

    def __init__(self, connection, kind: Kind | str, datum: Datum,
                 ground: Callable[[float, float], float] | None = None, radius: float = 0.3, brake: float = 2.5,
                 avoid_margin: float = 0.0, servo: Servo | None = None, use_fc_sensors: bool = True,
                 timeout: float = 1.0, retries: int = 3,
                 handler: Callable[[object], list | None] | None = None, extra_links: tuple = ()):
        self.conn = connection
        self.kind = Kind(kind)
        self.datum = datum
        self.ground = ground or (lambda x, y: 0.0)
        self.radius, self.brake, self.avoid_margin, self.servo = radius, brake, avoid_margin, servo
        self.use_fc_sensors = use_fc_sensors
        self.timeout, self.retries = timeout, retries
        self.handler = handler  # answers messages addressed to the agent (the Companion's handle)
        self.extra_links = list(extra_links)  # ground stations the agent also talks to directly
        self.sysid = 0
        self.home: tuple[float, float, float] | None = None
        self.problems = 0
        self._pose = Pose()
        self._time = 0.0
        self._speed = 0.0
        self._velocity = (0.0, 0.0)  # m/s east, north
        self._yawspeed = 0.0
        self._mode = "UNKNOWN"
        self._armed = False
        self._landed: int | None = None
        self._prearm_ok = False
        self._progress = MissionProgress(0, 0, False, False)
        self._heard = -math.inf  # wall time of the autopilot's last heartbeat
        self._back = -math.inf  # wall time its heartbeat came (back) after none for HEARTBEAT_LOST
        self._place: tuple | None = None  # (link, sender) the autopilot's heartbeat comes from
        self._requests: deque[tuple] = deque()  # (request, link) to answer at the next pump
        self.dropped: Counter[str] = Counter()  # why (FROM_ELSEWHERE, TOO_MANY, FAILED) -> messages dropped
        self.last_error = ""
        self._dropped_said: Counter[str] = Counter()
        self._news_at = -math.inf
        self._have_position = False
        self._readings: list[Reading] = []
        self._events: deque[str] = deque(maxlen=32)
        self._failsafe_said = -math.inf  # when the autopilot last announced a failsafe (wall clock)
        self._acks: dict[int, int] = {}
        self._replies: list = []
        self._wanted_mode: str | None = None
        self._mission_done_at = -math.inf
        self._target: tuple[float, float] | None = None  # where the agent sent it
        self._takeoff_to: float | None = None  # height above home of a take-off under way
        self._yaw_target: float | None = None
        self._yaw_by_target = False  # this autopilot turns to heading targets (Rover), not CONDITION_YAW
        self._next_heading = 0.0
        self._speed_wanted: float | None = None
        self._speed_applied = False
        self._speed_news = False  # the operator set a speed that the next pump sends
        self._reposition_ok = True
        self._traffic: dict[int, Traffic] = {}  # ICAO address (a team-mate's system id) -> its last report
        self.radio = LinkReceiver()  # the vehicle's radio, as its flight controller forwards it (TUNNEL RADIO_LINKS)
        self._radio_heard: deque[LinkRecord] = deque(maxlen=RADIO_HELD)

    # ---- connecting ---------------------------------------------------------------------------------
    def connect(self, timeout: float = 30.0) -> None:
        """Wait for the autopilot's heartbeat, check what it is, ask for its telemetry, wait for its home and
        first position. Raises FlightControllerError if any of that does not come within ``timeout`` s."""
        deadline = time.monotonic() + timeout
        beat = self._wait(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == AUTOPILOT
                          and m.autopilot != mavlink.MAV_AUTOPILOT_INVALID, deadline, "heartbeat from an autopilot")
        kind = {mavlink.MAV_TYPE_GROUND_ROVER: Kind.ROVER, mavlink.MAV_TYPE_SURFACE_BOAT: Kind.ROVER}.get(
            beat.type, Kind.COPTER if beat.type in COPTER_TYPES else None)
        if kind is not self.kind:
            found = mavlink.enums["MAV_TYPE"][beat.type].name.removeprefix("MAV_TYPE_").lower() \
                if beat.type in mavlink.enums["MAV_TYPE"] else str(beat.type)
            raise FlightControllerError(f"the flight controller is a {found}, not a {self.kind.value} (--vehicle)")
        self.sysid = beat.get_srcSystem()
        self._place, self._heard = beat._place, time.monotonic()  # heard there from now on (``_from_elsewhere``)
        self._back = self._heard
        self.conn.mav.srcSystem, self.conn.mav.srcComponent = self.sysid, COMPONENT
        for link in self.extra_links:
            link.mav.srcSystem, link.mav.srcComponent = self.sysid, COMPONENT
        self.send(self.heartbeat())  # before anything: it tells ArduPilot's router that 191 lives here
        self._ask_for_telemetry()
        self.send(self._command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, 0, mavlink.MAVLINK_MSG_ID_HOME_POSITION))
        self._wait(lambda m: self.home is not None and self._have_position, deadline,
                   "the autopilot's home and position", repeat=lambda: self.send(self._command_long(
                       mavlink.MAV_CMD_REQUEST_MESSAGE, 0, mavlink.MAVLINK_MSG_ID_HOME_POSITION)))

    def ready(self) -> bool:
        """The autopilot's pre-arm checks pass (in its current mode)."""
        return self._prearm_ok

    def _ask_for_telemetry(self) -> None:
        refused = 0
        for name, rate in STREAMS.items():
            if name == "DISTANCE_SENSOR" and not self.use_fc_sensors:
                continue
            message_id = getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
            if self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 1e6 / rate, report=False) != ACCEPTED:
                refused += 1
        if refused:  # an older autopilot: the stream groups instead
            for stream, rate in DATA_STREAMS.items():
                self.send(mavlink.MAVLink_request_data_stream_message(self.sysid, AUTOPILOT, stream, rate, 1))

    def _wait(self, done: Callable, deadline: float, what: str, repeat: Callable | None = None):
        last = time.monotonic()
        while time.monotonic() < deadline:
            for message in self._receive():
                if done(message):
                    return message
            if repeat is not None and time.monotonic() - last > 2.0:
                repeat()
                last = time.monotonic()
            time.sleep(0.005)
        down = "" if getattr(self.conn, "up", True) else f" (the link is down: {self.conn.error})"
        raise FlightControllerError(f"no {what} within the time allowed{down}")

    # ---- receiving ----------------------------------------------------------------------------------
    def pump(self) -> list:
        """Take in everything waiting on the links, answer the requests to the agent among it and send a speed
        the operator set meanwhile; returns the messages (the caller may look at them too). The main loop's
        call: a wait for the autopilot takes in (``_take_in``) and answers nothing."""
        messages = self._take_in()
        self._answer_requests()
        if self._speed_news:
            self._speed_news = False  # applied: the next target need not send it again
            self._speed_applied = self.command(mavlink.MAV_CMD_DO_CHANGE_SPEED, 1, self._speed_wanted, -1) == ACCEPTED
        return messages

    def _take_in(self) -> list:
        messages = list(self._receive())
        if self._yaw_target is not None and self._yaw_by_target and self._time >= self._next_heading:
            self._send_heading(self._yaw_target)
        return messages

    def _receive(self):
        for link in [self.conn, *self.extra_links]:
            while True:
                try:
                    message = link.recv_msg()
                except (OSError, ConnectionError):
                    break
                if message is None:
                    break
                if message.get_type() == "BAD_DATA":
                    continue
                message._place = (link, getattr(message, "_peer", None))  # a UDP link has many senders
                if self._from_elsewhere(message):
                    self.dropped[FROM_ELSEWHERE] += 1
                    continue
                try:
                    self._apply(message, link)
                except Exception as error:  # noqa: BLE001 - one message must not end the flight; counted, said
                    self._failed(error)
                    continue
                yield message

    def _failed(self, error: Exception) -> None:
        self.dropped[FAILED] += 1
        self.last_error = f"{type(error).__name__}: {error}"[:200]

    def _answer_requests(self) -> None:
        """Answer the requests taken in so far; those that come meanwhile (while an answer waits for the
        autopilot: a resume sets GUIDED) wait for the next pump."""
        for _ in range(len(self._requests)):
            request, link = self._requests.popleft()
            try:
                replies = self.handler(request) or []
            except Exception as error:  # noqa: BLE001 - as in _receive
                self._failed(error)
                continue
            for reply in replies:
                self.send(reply, link=link)

    def news(self) -> str | None:
        """A line on the messages dropped since the last line (why, and how many), at most every NEWS_EVERY s;
        None if there is nothing new to say yet."""
        if time.monotonic() - self._news_at < NEWS_EVERY:  # first: the main loop asks hundreds of times a second
            return None
        new = self.dropped - self._dropped_said
        if not new:
            return None
        self._dropped_said, self._news_at = self.dropped.copy(), time.monotonic()
        line = "dropped " + "; ".join(f"{why}: {count}" for why, count in new.items())
        return line + (f" (last: {self.last_error})" if FAILED in new else "")

    def _from_elsewhere(self, m) -> bool:
        """A message in the autopilot's name from another place than the one its heartbeat comes from, while that
        heartbeat still comes (after LINK_LOST_AFTER of silence its link died, and it may come back on another
        link or port). The ground station's rule (groundstation/link.py): without it, one heartbeat saying RTL
        from anyone paused the agent."""
        if (m.get_srcSystem(), m.get_srcComponent()) != (self.sysid, AUTOPILOT) or self._place is None:
            return False
        return m._place != self._place and time.monotonic() - self._heard <= LINK_LOST_AFTER

    def _apply(self, m, link) -> None:
        kind = m.get_type()
        if kind in REQUESTS and (m.target_system, m.target_component) == (self.sysid, COMPONENT):
            if self.handler is None:
                return
            if len(self._requests) >= REQUESTS_HELD:
                self.dropped[TOO_MANY] += 1
                return
            self._requests.append((m, link))  # a ground station asks the agent (resume, its parameters)
            return
        if kind == "ADSB_VEHICLE" and link in self.extra_links:
            self._on_adsb_vehicle(m)  # a ground station's relay of a team-mate (groundstation.traffic_relay)
            return
        if m.get_srcSystem() != self.sysid or m.get_srcComponent() == COMPONENT:
            return  # another system (a ground station), or an echo of ourselves
        if m.get_srcComponent() != AUTOPILOT and kind not in ("DISTANCE_SENSOR", "OBSTACLE_DISTANCE"):
            return
        if kind in MISSION_REPLIES:
            self._replies.append(m)
            return
        handler = getattr(self, f"_on_{kind.lower()}", None)
        if handler is not None:
            handler(m)

    def _clock(self, m) -> None:
        boot = m.time_boot_ms / 1000.0
        if boot + 5.0 < self._time:
            self._events.append("flight controller rebooted")
        self._time = boot

    def _on_heartbeat(self, m) -> None:
        if self.lost:
            self._back = time.monotonic()
        self._heard, self._place = time.monotonic(), m._place  # the autopilot is heard there (``_from_elsewhere``)
        was_armed, self._armed = self._armed, bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        mode = name_of(m.type, m.custom_mode) or f"MODE{m.custom_mode}"
        if was_armed and not self._armed and mode == "GUIDED":  # the agent never disarms: a kill
            self._events.append(DISARMED)
        if mode == self._mode:
            return
        was, self._mode = self._mode, mode
        self._target = self._yaw_target = self._takeoff_to = None  # a mode change drops every target
        own_ending = was == "AUTO" and time.monotonic() - self._mission_done_at < 5.0  # Rover holds after AUTO
        if self._wanted_mode is not None and mode != self._wanted_mode and not own_ending:
            failsafe = time.monotonic() - self._failsafe_said < FAILSAFE_NEWS
            self._events.append(f"{'failsafe' if failsafe else 'operator'} switched to {mode}")

    def _on_statustext(self, m) -> None:
        """An autopilot announces a failsafe (ArduPilot: "GCS Failsafe", "Battery Failsafe", ...) as it changes
        mode: the mode change that follows is the failsafe's, not an operator's."""
        text = m.text if isinstance(m.text, str) else bytes(m.text).decode("utf-8", "replace")
        if "failsafe" in text.lower() and "clear" not in text.lower():
            self._failsafe_said = time.monotonic()

    def _on_global_position_int(self, m) -> None:
        self._clock(m)
        if m.lat == 0 and m.lon == 0:
            return  # no fix yet
        x, y = self.datum.to_local(m.lat * 1e-7, m.lon * 1e-7)
        ground = self.home[2] if self.home is not None else 0.0
        self._pose.x, self._pose.y, self._pose.z = x, y, ground + m.relative_alt / 1000.0
        self._velocity = (m.vy / 100.0, m.vx / 100.0)  # east, north
        self._speed = math.hypot(m.vx, m.vy) / 100.0
        self._have_position = True
        if self._takeoff_to is not None and m.relative_alt / 1000.0 >= self._takeoff_to - 0.3:
            self._takeoff_to = None

    def _on_attitude(self, m) -> None:
        self._clock(m)
        if finite(m.roll, m.pitch, m.yaw, m.yawspeed):  # a broken estimate keeps the last good attitude
            self._pose.roll, self._pose.pitch, self._pose.yaw = m.roll, m.pitch, m.yaw % (2 * math.pi)
            self._yawspeed = m.yawspeed
            if self._yaw_target is not None and abs(wrap_pi(self._pose.yaw - self._yaw_target)) < YAW_DONE:
                self._yaw_target = None

    def _on_home_position(self, m) -> None:
        x, y = self.datum.to_local(m.latitude * 1e-7, m.longitude * 1e-7)
        self.home = (x, y, self.ground(x, y))

    def _on_sys_status(self, m) -> None:
        self._prearm_ok = bool(m.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK)

    def _on_extended_sys_state(self, m) -> None:
        self._landed = m.landed_state

    def _on_mission_current(self, m) -> None:
        state = getattr(m, "mission_state", 0)
        complete = state == mavlink.MISSION_STATE_COMPLETE
        if complete and not self._progress.complete:
            self._mission_done_at = time.monotonic()
        total = getattr(m, "total", 0)
        self._progress = MissionProgress(m.seq, total if total != 65535 else self._progress.count,
                                         state == mavlink.MISSION_STATE_ACTIVE, complete)

    def _on_command_ack(self, m) -> None:
        """Ours: addressed to this agent, or to no one (MAVLink 1 carries no address); an answer to another
        ground station's command is not (taking one for ours paused the agent on a refusal it never got). An
        acceptance waiting to be read stays: a slow autopilot's answers to two tries may come together, and its
        refusal of the second (ArduPilot: a take-off already climbing FAILS) is no refusal of the command."""
        ours = (getattr(m, "target_system", 0), getattr(m, "target_component", 0)) in ((0, 0), (self.sysid, COMPONENT))
        if ours and self._acks.get(m.command) != ACCEPTED:
            self._acks[m.command] = m.result

    def _on_adsb_vehicle(self, m) -> None:
        """A team-mate as the autopilot's ADS-B receiver heard it (see the module's docstring)."""
        flags = mavlink.ADSB_FLAGS_VALID_COORDS | mavlink.ADSB_FLAGS_VALID_ALTITUDE
        if m.flags & flags != flags or m.ICAO_address in (0, self.sysid) or not on_earth(m.lat * 1e-7, m.lon * 1e-7):
            return
        if m.ICAO_address not in self._traffic and len(self._traffic) >= TRAFFIC_HELD:
            return
        x, y = self.datum.to_local(m.lat * 1e-7, m.lon * 1e-7)
        speed = m.hor_velocity / 100.0 if m.flags & mavlink.ADSB_FLAGS_VALID_VELOCITY else 0.0
        track = math.radians(m.heading / 100.0) if m.flags & mavlink.ADSB_FLAGS_VALID_HEADING else 0.0
        self._traffic[m.ICAO_address] = Traffic(m.ICAO_address, x, y, m.altitude / 1000.0 - self.datum.alt,
                                                speed * math.sin(track), speed * math.cos(track), self.radius,
                                                self._time - m.tslc)

    def _on_tunnel(self, m) -> None:
        """Link records the vehicle's radio measured, forwarded by the flight controller (the simulator's radio
        does so; the agent sends them on to the ground station, ``Companion.hear``)."""
        if m.payload_type == RADIO_LINKS:
            self._radio_heard.extend(self.radio.feed(bytes(m.payload[:m.payload_length]), self.sysid))

    def take_radio(self) -> list[LinkRecord]:
        """The link records heard since the last call."""
        records = list(self._radio_heard)
        self._radio_heard.clear()
        return records

    def _on_distance_sensor(self, m) -> None:
        self._clock(m)
        if self.use_fc_sensors and self._have_position:
            reading = reading_from(m, self._pose, self._time)
            if reading is not None:
                self._readings.append(reading)

    def _on_obstacle_distance(self, m) -> None:
        if self.use_fc_sensors and self._have_position:
            self._readings += readings_from_obstacles(m, self._pose, self._time)

    def collect(self, readings: list[Reading]) -> None:
        """Readings taken elsewhere (cast in the scene at this controller's pose)."""
        self._readings.extend(readings)

    # ---- observing ----------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        return self._time

    @property
    def pose(self) -> Pose:
        return self._pose

    @property
    def speed(self) -> float:
        return self._speed

    @property
    def mode(self) -> str:
        return self._mode

    @property
    def armed(self) -> bool:
        return self._armed

    @property
    def lost(self) -> bool:
        """No heartbeat from the autopilot for HEARTBEAT_LOST wall seconds (as of the last take-in: ask after a
        pump, or a step that kept the main loop busy reads as a gap)."""
        return time.monotonic() - self._heard > HEARTBEAT_LOST

    @property
    def last_heard(self) -> float:
        """When (``time.monotonic()``) the autopilot's last heartbeat came."""
        return self._heard

    @property
    def back_since(self) -> float:
        """When (``time.monotonic()``) the autopilot's heartbeat came back after the last gap (or first came)."""
        return self._back

    @property
    def flying(self) -> bool:
        if self.kind is not Kind.COPTER or not self._armed:
            return False
        if self._landed is not None:
            return self._landed in (mavlink.MAV_LANDED_STATE_IN_AIR, mavlink.MAV_LANDED_STATE_LANDING,
                                    mavlink.MAV_LANDED_STATE_TAKEOFF)
        return self.home is not None and self._pose.z - self.home[2] > 0.3

    @property
    def taking_off(self) -> bool:
        return self._takeoff_to is not None

    @property
    def navigation(self) -> Navigation:
        """Towards the agent's own target in GUIDED; else (AUTO, RTL) along the way the vehicle moves."""
        if self._target is not None and self._mode == "GUIDED":
            dx, dy = self._target[0] - self._pose.x, self._target[1] - self._pose.y
            reach = math.hypot(dx, dy)
            heading = heading_of(dx, dy)
            under_way = self._speed > MOVING or abs(wrap_pi(heading - self._pose.yaw)) < FACING
            return Navigation(heading if reach > ARRIVED and under_way else None, reach)
        if self._speed > MOVING:
            return Navigation(heading_of(*self._velocity), math.inf)
        return Navigation(None, math.inf)

    @property
    def blocked(self) -> bool:
        navigation = self.navigation
        return (navigation.heading is not None and navigation.reach > 1.0 and self._speed < BLOCKED_SPEED
                and abs(self._yawspeed) < 0.1)

    @property
    def mission(self) -> MissionProgress:
        return self._progress

    def readings(self) -> list[Reading]:
        readings, self._readings = self._readings, []
        return readings

    @property
    def system_id(self) -> int:
        return self.sysid

    def traffic(self) -> list[Traffic]:
        """The team-mates heard within the last TRAFFIC_STALE s of the autopilot's clock."""
        fresh = {k: t for k, t in self._traffic.items() if self._time - t.time <= TRAFFIC_STALE}
        if len(fresh) < len(self._traffic):
            self._traffic = fresh
        return list(fresh.values())

    def took_over(self) -> str | None:
        """(A gap in the heartbeat is not one: see ``lost``.)"""
        return self._events.popleft() if self._events else None

    # ---- sending ------------------------------------------------------------------------------------
    def heartbeat(self):
        return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID,
                                                 0, 0, mavlink.MAV_STATE_ACTIVE, 3)

    def send(self, message, sysid: int | None = None, *, link=None) -> None:
        """To the autopilot's link (or ``link``). (``sysid``: the mission protocol's Requester passes it.)"""
        for target in [link if link is not None else self.conn]:
            try:
                target.mav.send(message)
            except OSError:
                continue

    def broadcast(self, messages: list) -> None:
        """The agent's own messages (map, path, state, texts): to the autopilot, which routes them on to every
        ground station, and straight to the ones given with --gcs."""
        for message in messages:
            for link in [self.conn, *self.extra_links]:
                try:
                    link.mav.send(message)
                except OSError:
                    continue

    def _command_long(self, command: int, confirmation: int, *params: float):
        values = (list(params) + [0.0] * 7)[:7]
        return mavlink.MAVLink_command_long_message(self.sysid, AUTOPILOT, command, confirmation, *values)

    def command(self, command: int, *params: float, report: bool = True) -> int:
        """COMMAND_LONG, resent with confirmation += 1 until acknowledged; the MAV_RESULT (NO_ANSWER if none).
        A refusal or a silence is reported (``report``) and the vehicle told to hold."""
        return self._acknowledged(command, lambda k: self._command_long(command, k, *params), report)

    def command_int(self, command: int, frame: int, params: list[float], x: int, y: int, z: float,
                    report: bool = True) -> int:
        def build(_):  # COMMAND_INT has no confirmation field: every try is the same message
            return mavlink.MAVLink_command_int_message(self.sysid, AUTOPILOT, frame, command, 0, 0, *params, x, y, z)

        return self._acknowledged(command, build, report)

    def _acknowledged(self, command: int, build: Callable[[int], object], report: bool) -> int:
        result = NO_ANSWER
        gap = False  # the autopilot's heartbeat went missing meanwhile: its silence is the gap's, no refusal
        for attempt in range(self.retries):
            self._acks.pop(command, None)
            self.send(build(attempt))
            deadline = time.monotonic() + self.timeout
            while time.monotonic() < deadline and command not in self._acks:
                self._take_in()
                gap = gap or self.lost
                if command not in self._acks:
                    time.sleep(0.002)
            result = self._acks.pop(command, NO_ANSWER)
            if result == mavlink.MAV_RESULT_IN_PROGRESS:
                continue
            if result != NO_ANSWER:
                break
        if result == NO_ANSWER and gap:
            return result
        if report and result not in (ACCEPTED, UNSUPPORTED) and not self._refused_for_a_takeover(result):
            self._problem(refusal(command, result))
        return result

    def _refused_for_a_takeover(self, result: int) -> bool:
        """A command "temporarily rejected" may be refused only because an operator changed the mode (or
        disarmed the vehicle) a moment ago, which the autopilot's next heartbeat (1 Hz) would tell. Ask for one
        now: then the agent pauses for the operator's takeover, not for the refusal it caused."""
        if result != mavlink.MAV_RESULT_TEMPORARILY_REJECTED or self._wanted_mode is None:
            return False
        if self._mode != self._wanted_mode or DISARMED in self._events:  # the heartbeat that tells came first
            return True
        heard = self._heard
        self.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HEARTBEAT, report=False)
        deadline = time.monotonic() + self.timeout
        while self._heard == heard and time.monotonic() < deadline:
            self._take_in()
            time.sleep(0.002)
        return self._mode != self._wanted_mode or DISARMED in self._events

    def _problem(self, text: str) -> None:
        self.problems += 1
        self._events.append(text)
        self._stop_moving()

    def _stop_moving(self) -> None:
        """Zero velocity: the vehicle brakes and holds; nothing it was given before runs on."""
        self._target = self._yaw_target = None
        if self._mode == "GUIDED" and self._armed:
            self.send(mavlink.MAVLink_set_position_target_local_ned_message(
                int(self._time * 1000) & 0xFFFFFFFF, self.sysid, AUTOPILOT, mavlink.MAV_FRAME_LOCAL_NED,
                IGNORE_ALL_BUT_VELOCITY, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
            self._speed_applied = False  # the next position target starts the autopilot's own speed again

    # ---- acting -------------------------------------------------------------------------------------
    def arm(self, report: bool = True) -> int:
        return self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, report=report)

    def takeoff(self, altitude: float, report: bool = True) -> int:
        result = self.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, altitude, report=report)
        if result == ACCEPTED:
            self._takeoff_to = altitude
            self._speed_applied = False  # the first target after it starts the autopilot's own speed again
        return result

    def set_mode(self, name: str) -> int:
        number = number_of(self._mav_type(), name)
        if number is None:
            self._problem(f"flight controller has no mode {name}")
            return UNSUPPORTED
        self._wanted_mode = name.upper()
        result = self.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, number)
        if result == ACCEPTED:
            self._speed_applied = False  # a mode change resets ArduPilot's speed
            if name.upper() == "GUIDED":
                self._apply_speed()
        return result

    def _apply_speed(self) -> None:
        """The wanted speed, sent after a target once per GUIDED session, and again after the first target that
        follows a take-off or a stop: ArduCopter goes back to its own WPNAV_SPEED whenever GUIDED starts flying
        to a position from another kind of target (SITL's copters flew a 1 m/s mission at up to 4 m/s). Rover
        takes it only once it has a target (before, it says FAILED), so a refusal here is no problem: it is tried
        again after the next target."""
        if self._speed_wanted is not None and not self._speed_applied:
            result = self.command(mavlink.MAV_CMD_DO_CHANGE_SPEED, 1, self._speed_wanted, -1, report=False)
            self._speed_applied = result == ACCEPTED

    def _mav_type(self) -> int:
        return mavlink.MAV_TYPE_GROUND_ROVER if self.kind is Kind.ROVER else mavlink.MAV_TYPE_QUADROTOR

    def goto(self, x: float, y: float, altitude: float | None = None) -> int:
        if not finite(x, y, altitude if altitude is not None else 0.0):
            self._problem("refused a target that is not a number")
            return mavlink.MAV_RESULT_DENIED
        lat, lon = self.datum.to_global(x, y)
        height = altitude if altitude is not None else (self._pose.z - (self.home[2] if self.home else 0.0))
        result = UNSUPPORTED
        if self._reposition_ok:
            # speed -1: the autopilot's own (Rover refuses a reposition with a speed before it has a target)
            result = self.command_int(mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                      [-1, 0, 0, math.nan], int(round(lat * 1e7)), int(round(lon * 1e7)), height)
            self._reposition_ok = result != UNSUPPORTED
        if result == UNSUPPORTED:  # an autopilot without DO_REPOSITION: a position target (not acknowledged)
            self.send(mavlink.MAVLink_set_position_target_global_int_message(
                int(self._time * 1000) & 0xFFFFFFFF, self.sysid, AUTOPILOT,
                mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0x0DF8, int(round(lat * 1e7)), int(round(lon * 1e7)),
                height, 0, 0, 0, 0, 0, 0, 0, 0))
            result = ACCEPTED
        if result == ACCEPTED:
            self._target, self._yaw_target = (x, y), None
            self._apply_speed()
        return result

    def set_yaw(self, heading: float, relative: bool = False) -> int:
        target = ((self._pose.yaw if relative else 0.0) + heading) % (2 * math.pi)
        if not self._yaw_by_target:
            degrees = math.degrees(target)
            result = self.command(mavlink.MAV_CMD_CONDITION_YAW, degrees, 0, 0, 0)
            if result != UNSUPPORTED:
                if result == ACCEPTED:
                    self._yaw_target = target
                return result
            self._yaw_by_target = True  # Rover: a heading target, resent until reached
        self._yaw_target = target
        self._send_heading(target)
        return ACCEPTED

    def _send_heading(self, heading: float) -> None:
        self._next_heading = self._time + HEADING_RESEND
        self.send(mavlink.MAVLink_set_position_target_local_ned_message(
            int(self._time * 1000) & 0xFFFFFFFF, self.sysid, AUTOPILOT, mavlink.MAV_FRAME_LOCAL_NED,
            IGNORE_ALL_BUT_YAW, 0, 0, 0, 0, 0, 0, 0, 0, 0, heading, 0))

    def prefer_speed(self, speed: float) -> None:
        """The speed to fly at, sent each time GUIDED is entered (ArduPilot resets it on a mode change)."""
        self._speed_wanted = speed

    def set_speed(self, speed: float) -> int:
        """The operator's speed (PARAM_SET SCN_SPEED), sent by the next pump: a request's handler never waits for
        the autopilot. IN_PROGRESS: the answer comes then (a refusal pauses the agent, as any)."""
        self._speed_wanted, self._speed_news = speed, True
        return mavlink.MAV_RESULT_IN_PROGRESS

    def set_servo(self, channel: int, pwm: int) -> int:
        result = self.command(mavlink.MAV_CMD_DO_SET_SERVO, channel, pwm)
        if result == ACCEPTED and self.servo is not None and self.servo.channel == channel:
            self.servo.pwm = int(pwm)  # a sonar on that servo now points there
        return result

    def hold(self) -> int:
        self._stop_moving()
        return ACCEPTED

    def return_home(self) -> int:
        return self.set_mode("RTL")

    def land(self) -> int:
        return self.set_mode("LAND") if self.kind is Kind.COPTER else UNSUPPORTED

    def upload_mission(self, items: list[MissionItem]) -> int:
        try:
            word = mission_protocol.upload(self, self.sysid, items, AUTOPILOT, self.timeout)
        except (FlightControllerError, mission_protocol.MissionError) as error:
            self._problem(f"mission upload: {error}")
            return mavlink.MAV_RESULT_FAILED
        if word != "accepted":
            self._problem(f"mission upload: {word}")
            return mavlink.MAV_RESULT_FAILED
        return ACCEPTED

    def download_mission(self) -> list[MissionItem]:
        try:
            return mission_protocol.download(self, self.sysid, AUTOPILOT, self.timeout)
        except FlightControllerError as error:
            self._problem(f"mission download: {error}")
            return []

    def start_mission(self) -> int:
        return self.command(mavlink.MAV_CMD_MISSION_START, 0, 0)

    # ---- the mission protocol's link (``vehicle.protocol.mission.Requester``) ---------------------------
    def request(self, sysid: int, message, accepts: Callable[[object], bool], timeout: float = 1.0):
        for _ in range(self.retries):
            self._replies.clear()
            self.send(message)
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                self._take_in()
                found = next((m for m in self._replies if accepts(m)), None)
                if found is not None:
                    return found
                time.sleep(0.002)
        raise FlightControllerError(f"no answer to {message.get_type()}")


REQUESTS = {"COMMAND_LONG", "COMMAND_INT", "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"}
MISSION_REPLIES = {"MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_REQUEST_INT", "MISSION_REQUEST",
                   "MISSION_ACK"}
COPTER_TYPES = {mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_TYPE_HEXAROTOR, mavlink.MAV_TYPE_OCTOROTOR,
                mavlink.MAV_TYPE_TRICOPTER, mavlink.MAV_TYPE_COAXIAL, mavlink.MAV_TYPE_HELICOPTER,
                mavlink.MAV_TYPE_DODECAROTOR}
