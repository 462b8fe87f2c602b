"""Pathfind: visit waypoints in order, finding the way around obstacles with A* on the memory map.

When the monitor reports an obstacle ahead, the vehicle stops, scans around
and plans again on what it now knows (``routines.Travel``). A waypoint with no
known path is skipped and reported; the mission then ends ``stopped``.
"""

from __future__ import annotations

from vehicle.agent.missions.base import Mission, Status
from vehicle.agent.missions.routines import Travel
from vehicle.agent.missions.square import square_corners


class Pathfind(Mission):
    name = "pathfind"

    def begin(self) -> None:
        ctx = self.ctx
        self.waypoints = list(ctx.waypoints or square_corners(ctx.home, ctx.settings.space_size))
        self.index = 0
        self.skipped: list[int] = []
        self.travel = Travel(ctx, self.waypoints[0], ctx.settings.closeness)

    def step(self) -> Status:
        return self._next(self.travel.step())

    def progress(self) -> tuple[int, int] | None:
        return (self.index, len(self.waypoints)) if hasattr(self, "waypoints") else None

    def _next(self, status: Status) -> Status:
        """After the Travel to the current waypoint reports: go on to the next one when it is over."""
        if status is Status.RUNNING:
            return status
        if status is Status.STOPPED:
            self.skipped.append(self.index + 1)
            self.ctx.say(f"Pathfind: skipping waypoint {self.index + 1}: {self.travel.reason}")
        else:
            self.ctx.say(f"Pathfind: reached waypoint {self.index + 1}")
        self.index += 1
        if self.index >= len(self.waypoints):
            if self.skipped:
                self.reason = f"waypoints {', '.join(map(str, self.skipped))} unreachable"
                return Status.STOPPED
            return Status.DONE
        self.travel = Travel(self.ctx, self.waypoints[self.index], self.ctx.settings.closeness)
        return Status.RUNNING

    def too_close(self) -> Status:
        return self._next(self.travel.too_close())

    def out_of_time(self) -> Status:
        self.reason = f"time budget spent at waypoint {self.index + 1} of {len(self.waypoints)}"
        return Status.STOPPED
