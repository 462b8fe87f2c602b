"""The onboard agent's state on the wire: one TUNNEL payload, both ends here.

A ground station shows the autopilot's mode from its HEARTBEAT; whether the
onboard mission runs, waits, was paused by an operator or has ended, and why,
only the agent knows. It sends it in TUNNEL (385) payload type ``AGENT_STATUS``
(32803, after the map stream's 32800-32802), as component 191, once a second
and on every change: ``<BBBB`` phase, flags (bit 0: paused; bit 1: paused by
the operator's Pause; bit 2: the operator has taken control), outcome, length
of the mission name; then the mission name and the reason (UTF-8, cut to fit
the 128-byte payload).

Its progress goes in payload type ``AGENT_PROGRESS`` (32804) beside it: ``<HHf``
waypoints done and in all (0, 0: the mission has none of its own) and the
seconds left of the mission's time budget (NaN while no mission runs).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

AGENT_STATUS = 32803
AGENT_PROGRESS = 32804
_PROGRESS = struct.Struct("<HHf")
PAYLOAD = 128
PHASES = ("waiting", "preflight", "takeoff", "mission", "homing", "landing", "done")
OUTCOMES = ("", "finished", "stopped")
OPERATOR = ("", "pause", "control")  # who holds the agent: nobody, the operator's Pause, the operator's control
_HEADER = struct.Struct("<BBBB")


@dataclass(frozen=True)
class AgentStatus:
    phase: str
    paused: bool
    outcome: str  # "" while the mission has not ended
    mission: str
    reason: str  # why it is paused, or why the mission ended
    operator: str = ""  # "pause": held by the operator's Pause; "control": the operator has control

    @property
    def state(self) -> str:
        """One word for the page: running, paused, operator (the operator has control), waiting, finished or
        stopped."""
        if self.paused and self.operator == "control":
            return "operator"
        if self.paused:
            return "paused"
        if self.phase == "waiting":
            return "waiting"
        return self.outcome if self.outcome and self.phase == "done" else "running"


def encode(status: AgentStatus) -> bytes:
    mission = status.mission.encode("utf-8")[:32]
    flags = int(status.paused) | (1 << OPERATOR.index(status.operator) if status.operator else 0)
    head = _HEADER.pack(PHASES.index(status.phase), flags, OUTCOMES.index(status.outcome), len(mission)) + mission
    reason = status.reason.encode("utf-8")[:PAYLOAD - len(head)]
    return head + reason.decode("utf-8", "ignore").encode("utf-8")  # never half a character


@dataclass(frozen=True)
class AgentProgress:
    done: int
    total: int
    time_left: float  # s of the mission's time budget; NaN while no mission runs


def encode_progress(progress: AgentProgress) -> bytes:
    return _PROGRESS.pack(min(progress.done, 65535), min(progress.total, 65535), progress.time_left)


def decode_progress(payload: bytes) -> AgentProgress | None:
    """The progress in a payload; None if it is malformed."""
    if len(payload) < _PROGRESS.size:
        return None
    done, total, left = _PROGRESS.unpack_from(payload)
    return AgentProgress(done, total, left) if done <= total else None


def decode(payload: bytes) -> AgentStatus | None:
    """The status in a payload; None if it is malformed."""
    if len(payload) < _HEADER.size:
        return None
    phase, flags, outcome, length = _HEADER.unpack_from(payload)
    if phase >= len(PHASES) or outcome >= len(OUTCOMES) or _HEADER.size + length > len(payload):
        return None
    body = payload[_HEADER.size:]
    mission = body[:length].decode("utf-8", "replace")
    reason = body[length:].rstrip(b"\0").decode("utf-8", "replace")
    operator = "control" if flags & 4 else "pause" if flags & 2 else ""
    return AgentStatus(PHASES[phase], bool(flags & 1), OUTCOMES[outcome], mission, reason, operator)
