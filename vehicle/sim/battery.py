"""A simulated flight battery that drains with use, for SYS_STATUS and BATTERY_STATUS.

A 4-cell LiPo: hovering or driving draws a base current, speed and climbing
draw more, and the voltage follows the charge along a typical discharge curve.
Enough to show an operator a battery going down during a mission.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CELLS = 4
# (state of charge, cell voltage) of a LiPo discharge curve
_CURVE_SOC = np.array([0.0, 0.05, 0.1, 0.2, 0.4, 0.6, 0.8, 0.95, 1.0])
_CURVE_V = np.array([3.3, 3.5, 3.6, 3.7, 3.78, 3.87, 4.0, 4.15, 4.2])


@dataclass
class Battery:
    capacity_mah: float = 5000.0
    idle_amps: float = 0.5  # armed, not moving (a rover), or electronics only
    hover_amps: float = 14.0  # a copter in the air
    amps_per_speed: float = 0.8  # extra per m/s
    charge_mah: float = 5000.0
    current: float = 0.0  # amps drawn in the last step

    def drain(self, dt: float, armed: bool, flying: bool, speed: float, climb: float) -> None:
        amps = 0.1
        if armed:
            amps = (self.hover_amps if flying else self.idle_amps) + self.amps_per_speed * speed
            amps += 4.0 * max(0.0, climb)
        self.current = amps
        self.charge_mah = max(0.0, self.charge_mah - amps * dt / 3.6)

    @property
    def remaining(self) -> float:
        """State of charge, 0..1."""
        return self.charge_mah / self.capacity_mah

    @property
    def voltage(self) -> float:
        return CELLS * float(np.interp(self.remaining, _CURVE_SOC, _CURVE_V))

    @property
    def consumed_mah(self) -> float:
        return self.capacity_mah - self.charge_mah
