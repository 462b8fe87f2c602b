"""Browse: stay at home and turn in place, scanning one full circle, then land.

The thesis's simplest GUIDED mission and the building block of the others:
it shows whether the vehicle and its sensor work without going anywhere.
"""

from __future__ import annotations

from vehicle.agent.missions.base import Mission, Status
from vehicle.agent.missions.routines import scan


class Browse(Mission):
    name = "browse"

    def begin(self) -> None:
        self.scan = scan(self.ctx)

    def step(self) -> Status:
        return Status.DONE if self.scan.step() else Status.RUNNING

    def too_close(self) -> Status:
        return Status.RUNNING  # turning in place never moves towards anything

    def out_of_time(self) -> Status:
        self.reason = "time ran out before the full turn"
        return Status.STOPPED
