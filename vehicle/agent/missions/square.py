"""Square: the thesis's planned mission, AUTO waypoints in a square around home.

The autopilot flies the waypoints on its own; the agent only watches. AUTO does
not avoid obstacles, so when the monitor finds one too close ahead the agent
stops the vehicle and brings it home along a planned path: the thesis's Square
flew into objects, ours stops safely instead.
"""

from __future__ import annotations

from vehicle.agent.missions.base import Mission, Status
from vehicle.protocol.mission import DO_CHANGE_SPEED, NAV_TAKEOFF, NAV_WAYPOINT, MissionItem, home_item
from vehicle.protocol.modes import Kind

MAX_HALF_SIDE = 25.0  # m


def square_corners(home: tuple[float, float], space_size: float) -> list[tuple[float, float]]:
    """North-west, north-east, south-east, south-west corners of a square around home inside the space."""
    half = min(space_size / 4, MAX_HALF_SIDE)
    x, y = home
    return [(x - half, y + half), (x + half, y + half), (x + half, y - half), (x - half, y - half)]


class Square(Mission):
    name = "square"
    mode = "AUTO"

    def begin(self) -> None:
        ctx = self.ctx
        datum = ctx.fc.datum
        loaded = ctx.fc.download_mission()
        if len(loaded) > 1:  # a mission was uploaded or loaded: fly it as it is
            self.corners = [datum.to_local(i.lat, i.lon) for i in loaded[1:] if i.has_position]
            self.first_corner = len(loaded) - len(self.corners)
            return
        self.corners = ctx.waypoints or square_corners(ctx.home, ctx.settings.space_size)
        items = [home_item(datum, *ctx.home)]
        if ctx.kind is Kind.COPTER:
            items.append(MissionItem(NAV_TAKEOFF, alt=ctx.settings.altitude))
        items.append(MissionItem(DO_CHANGE_SPEED, param1=1, param2=ctx.speed))
        for x, y in self.corners:
            lat, lon = datum.to_global(x, y)
            items.append(MissionItem(NAV_WAYPOINT, lat, lon, ctx.settings.altitude, param2=ctx.settings.closeness))
        ctx.fc.upload_mission(items)
        self.first_corner = len(items) - len(self.corners)

    def step(self) -> Status:
        progress = self.ctx.fc.mission
        if progress.complete:
            return Status.DONE
        remaining = self.corners[max(0, progress.current - self.first_corner):]
        self.ctx.planned_path = [self.ctx.position, *remaining]
        return Status.RUNNING
