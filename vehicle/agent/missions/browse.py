"""Browse: stay at home and turn in place, scanning one full circle, then land.

The thesis's simplest GUIDED mission and the building block of the others:
it shows whether the vehicle and its sensor work without going anywhere.

A team splits the area instead of every vehicle scanning the same place from
spots a few metres apart: each browses from a spot in its own share, ``SPREAD``
metres out from where it starts, away from the team's centre (the middle of
where all of them are at the start), and only if no team-mate is nearer to that
spot (``someone_elses``: the share is the Voronoi cell of where each is). A
vehicle in the middle of its team, or whose spot is taken, blocked or outside
the allowed space, browses where it is, as a lone vehicle does.
"""

from __future__ import annotations

import math

from vehicle.agent.missions.base import Mission, Status
from vehicle.agent.missions.routines import Travel, scan
from vehicle.agent.traffic import someone_elses, team_mates

SPREAD = 10.0  # m out from its start a vehicle of a team browses from
MIDDLE = 0.5  # m from the team's centre within which a vehicle browses where it is


class Browse(Mission):
    name = "browse"

    def begin(self) -> None:
        self.scan = None
        self.travel = None
        spot = self._own_spot()
        if spot is None:
            self.scan = scan(self.ctx)
        else:
            self.ctx.say(f"Browse: browsing from ({spot[0]:.1f}, {spot[1]:.1f}), in this vehicle's share of the area")
            self.travel = Travel(self.ctx, spot, self.ctx.settings.closeness)

    def _own_spot(self) -> tuple[float, float] | None:
        ctx = self.ctx
        others = team_mates(ctx.fc)
        if not others:
            return None
        x, y = ctx.position
        cx = (x + sum(o.x for o in others)) / (len(others) + 1)
        cy = (y + sum(o.y for o in others)) / (len(others) + 1)
        out = math.hypot(x - cx, y - cy)
        if out < MIDDLE:
            return None
        spot = (x + (x - cx) / out * SPREAD, y + (y - cy) / out * SPREAD)
        if not ctx.inside(spot) or not ctx.is_clear(spot) or someone_elses(ctx, spot):
            return None
        return spot

    def step(self) -> Status:
        if self.travel is not None:
            return self._travelled(self.travel.step())
        return Status.DONE if self.scan.step() else Status.RUNNING

    def _travelled(self, status: Status) -> Status:
        """On the way to its spot: once there (or when the way is not found) it browses from where it is."""
        if status is Status.RUNNING:
            return status
        if status is Status.STOPPED:
            self.ctx.say(f"Browse: {self.travel.reason}; browsing from here")
        self.travel = None
        self.ctx.planned_path = []
        self.scan = scan(self.ctx)
        return Status.RUNNING

    def too_close(self) -> Status:
        if self.travel is not None:
            return self._travelled(self.travel.too_close())
        return Status.RUNNING  # turning in place never moves towards anything

    def out_of_time(self) -> Status:
        self.reason = "time ran out before the full turn"
        return Status.STOPPED
