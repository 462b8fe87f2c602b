"""The plan view's routes: check a plan's legs against the scene, read and write mission files, and how far a
mission upload or download has come. The upload itself is ``PUT /api/vehicles/{sysid}/mission``."""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import PlainTextResponse

from groundstation.api.common import attachment
from groundstation.plan import Plan, PlanError, check_legs, read_file, write_file
from vehicle.world.raycast import RayCaster

if TYPE_CHECKING:
    from groundstation.api.common import Guards
    from groundstation.server import GroundStation


def routes(station: GroundStation, guards: Guards) -> APIRouter:
    router = APIRouter()

    def datum():
        if station.fleet.datum is None:
            raise HTTPException(409, "the station has no datum yet (no scene, and no vehicle's home heard): "
                                     "plans are in scene metres, placed on Earth by the datum")
        return station.fleet.datum

    @router.post("/api/plan/check", tags=["plan"])
    def check(plan: Plan):
        """Each leg of the plan (from home): its length, and whether the scene stands in its way (where, what)."""
        scene = station.scene
        caster = None
        ground = 0.0
        if scene is not None and len(scene.faces):
            caster = scene.prepared(("caster", "auto"), lambda: RayCaster(scene))
            home = plan.home or (0.0, 0.0)
            ground = caster.ground_height(*home)
        return {"legs": check_legs(plan, scene, caster, ground), "scene": caster is not None}

    @router.post("/api/plan/import", tags=["plan"])
    async def import_file(request: Request):
        """A plan from a QGC WPL 110 or QGroundControl .plan file (the body); 422 says what is wrong with it."""
        text = (await request.body()).decode("utf-8", "replace")  # at most security.MAX_BODY bytes
        try:
            return read_file(text, datum())
        except PlanError as error:
            raise HTTPException(422, str(error)) from None

    @router.post("/api/plan/export", tags=["plan"], response_class=PlainTextResponse)
    def export_file(plan: Plan, format: Literal["wpl", "plan"] = Query("wpl"),  # noqa: A002 - the query's name
                    vehicle: Literal["copter", "rover"] = Query("copter")):
        """The plan as a QGC WPL 110 (.waypoints) or QGroundControl .plan file."""
        name = "mission.plan" if format == "plan" else "mission.waypoints"
        return PlainTextResponse(write_file(plan, datum(), format, vehicle),
                                 headers={"Content-Disposition": attachment(name)})

    @router.get("/api/vehicles/{sysid}/mission/progress", tags=["missions"])
    def progress(sysid: int):
        """The last mission transfer with the vehicle: direction, items done of total, and its result (the
        vehicle's MISSION_ACK for an upload) once it ended."""
        guards.vehicle_or_404(sysid)
        return station.link.transfer_progress.get(sysid) or {"direction": None, "done": 0, "total": None,
                                                            "result": None}

    return router
