"""The mission parameters as MAVLink parameters, so standard parameter editors list and change them.

Each setting appears under its short id (``SCN_SPEED`` ...) as a REAL32. A
change is validated like ``--set``; a refused value is answered with the
unchanged value (what ArduPilot does) and a STATUSTEXT saying why. The map's
size and resolution are fixed when the map is made, so changes to those apply
to the next mission.
"""

from __future__ import annotations

from pydantic import ValidationError

from vehicle.agent.settings import Settings
from vehicle.protocol.mav import mavlink

REAL32 = mavlink.MAV_PARAM_TYPE_REAL32


class Parameters:
    def __init__(self, settings: Settings):
        self.settings = settings
        self.ids = list(Settings.param_ids())  # stable order: the index of each parameter
        self._names = Settings.param_ids()

    def __len__(self) -> int:
        return len(self.ids)

    def value(self, param_id: str) -> float:
        return float(getattr(self.settings, self._names[param_id]))

    def message(self, index: int):
        param_id = self.ids[index]
        return mavlink.MAVLink_param_value_message(param_id.encode(), self.value(param_id), REAL32, len(self),
                                                   index)

    def find(self, param_id: str | bytes, index: int = -1) -> int | None:
        """Index of a parameter by id (or by index when index >= 0); None if there is none."""
        if index >= 0:
            return index if index < len(self) else None
        if isinstance(param_id, bytes):
            param_id = param_id.decode("ascii", "replace")
        param_id = param_id.rstrip("\0")
        return self.ids.index(param_id) if param_id in self._names else None

    def set(self, param_id: str, value: float) -> str | None:
        """Change a parameter; None if it took, else the reason it did not."""
        name = self._names[param_id]
        try:
            setattr(self.settings, name, value)
        except ValidationError as error:
            return f"{param_id}: {error.errors()[0]['msg']}"[:50]
        return None
