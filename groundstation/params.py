"""The battery failsafe parameters the station reads from each autopilot (ArduPilot's BATT_*), and what they say.

An operator should see the levels at which the vehicle itself warns and acts, not a figure the page assumes:
ArduPilot keeps them in parameters, which nobody streams. So the link asks each autopilot for ``WANTED`` with
PARAM_REQUEST_READ when it is first heard (and again when its link comes back), and again for those still
missing every ``RETRY_AFTER`` seconds, ``TRIES`` times at most (``Schedule``): a vehicle that never answers costs
``TRIES * len(WANTED)`` requests per link. The fleet keeps what comes (``value``), and ``failsafe`` turns it
into the card's levels, with ArduPilot's action names for the vehicle's kind.
"""

from __future__ import annotations

import math

# ArduPilot's names; units: mAh, V, mAh, and the failsafe action's number (its enum per vehicle kind)
WANTED = ("BATT_CAPACITY", "BATT_LOW_VOLT", "BATT_CRT_VOLT", "BATT_LOW_MAH", "BATT_CRT_MAH", "BATT_FS_LOW_ACT",
          "BATT_FS_CRT_ACT")
RANGES = {"BATT_CAPACITY": 1e7, "BATT_LOW_VOLT": 1000.0, "BATT_CRT_VOLT": 1000.0, "BATT_LOW_MAH": 1e7,
          "BATT_CRT_MAH": 1e7, "BATT_FS_LOW_ACT": 100.0, "BATT_FS_CRT_ACT": 100.0}  # a value in [0, this] makes sense
TRIES = 3  # rounds of requests for what is missing, per link-up
RETRY_AFTER = 2.0  # s between rounds
# BATT_FS_LOW_ACT / BATT_FS_CRT_ACT values, as ArduPilot's parameter docs list them per vehicle
_COPTER = {0: "None", 1: "Land", 2: "RTL", 3: "SmartRTL or RTL", 4: "SmartRTL or Land", 5: "Terminate",
           6: "Auto DO_LAND_START or RTL", 7: "Brake or Land"}
_ROVER = {0: "None", 1: "RTL", 2: "Hold", 3: "SmartRTL", 4: "SmartRTL or Hold", 5: "Terminate"}
_PLANE = {0: "None", 1: "RTL", 2: "Land", 3: "Terminate", 4: "QLand", 5: "Parachute", 6: "Loiter to QLand"}
ACTIONS = {"copter": _COPTER, "rover": _ROVER, "boat": _ROVER, "plane": _PLANE}


def name_of(message) -> str | None:
    """The parameter a PARAM_VALUE carries, if it is one the station wants."""
    raw = message.param_id
    name = (raw.decode(errors="replace") if isinstance(raw, bytes) else str(raw)).rstrip("\0")
    return name if name in WANTED else None


def value(message) -> tuple[str, float | None] | None:
    """(name, value) of a wanted parameter, the value None if it is not finite or out of any sensible range (the
    caller counts it and keeps the last good one); None for a parameter not wanted."""
    name = name_of(message)
    if name is None:
        return None
    number = float(message.param_value)
    return name, number if math.isfinite(number) and 0.0 <= number <= RANGES[name] else None


def failsafe(params: dict[str, float], kind: str) -> dict | None:
    """The low and critical levels for the API (None until any wanted parameter came): each with its voltage
    and remaining capacity (0: that check is off, as ArduPilot has it), the capacity's share in %, and the
    action's name; a field not answered yet is None."""
    if not params:
        return None
    capacity = params.get("BATT_CAPACITY")

    def level(volt: str, mah: str, action: str) -> dict:
        left = params.get(mah)
        code = params.get(action)
        share = round(100.0 * left / capacity, 1) if left and capacity else None
        return {"volt": params.get(volt), "mah": left, "percent": share,
                "action": None if code is None else ACTIONS.get(kind, {}).get(int(code), f"action {int(code)}")}

    return {"capacity_mah": capacity, "low": level("BATT_LOW_VOLT", "BATT_LOW_MAH", "BATT_FS_LOW_ACT"),
            "critical": level("BATT_CRT_VOLT", "BATT_CRT_MAH", "BATT_FS_CRT_ACT")}


class Schedule:
    """Which wanted parameters to ask each vehicle for, and when (on the caller's clock)."""

    def __init__(self, tries: int = TRIES, retry_after: float = RETRY_AFTER):
        self.tries, self.retry_after = tries, retry_after
        self._vehicles: dict[int, tuple[set[str], int, float]] = {}  # sysid -> (missing, rounds sent, when last)

    def start(self, sysid: int) -> None:
        """Ask for all of them again, from the next ``due``: the vehicle is new, or back (maybe rebooted)."""
        self._vehicles[sysid] = (set(WANTED), 0, -math.inf)

    def answered(self, sysid: int, name: str) -> None:
        entry = self._vehicles.get(sysid)
        if entry is not None:
            entry[0].discard(name)

    def __contains__(self, sysid: int) -> bool:
        """Whether the station still means to ask this vehicle for some."""
        return sysid in self._vehicles

    def forget(self, sysid: int) -> None:
        self._vehicles.pop(sysid, None)

    def due(self, now: float) -> list[tuple[int, str]]:
        """The (sysid, name) requests to send now; each vehicle gets a round every ``retry_after`` s while some
        are missing, ``tries`` rounds at most."""
        requests = []
        for sysid, (missing, rounds, last) in list(self._vehicles.items()):
            if not missing or rounds >= self.tries:
                del self._vehicles[sysid]  # all came, or it never answers: stop asking
            elif now - last >= self.retry_after:
                self._vehicles[sysid] = (missing, rounds + 1, now)
                requests += [(sysid, name) for name in WANTED if name in missing]
        return requests
