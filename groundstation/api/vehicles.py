"""Vehicles and commands: what each vehicle is doing, its history, the operator's commands and AUTO missions."""

from __future__ import annotations

import asyncio
import time
from typing import TYPE_CHECKING

from fastapi import APIRouter, Depends, HTTPException, Query, Request
from fastapi.responses import PlainTextResponse

from groundstation.api.common import log
from groundstation.commands import Command, blocked, execute, explain, note, outside_space, refusal
from groundstation.link import LinkError
from vehicle.protocol.waypoints import WaypointError, mission_text, parse_mission

if TYPE_CHECKING:
    from groundstation.api.common import Guards
    from groundstation.server import GroundStation

MAX_HISTORY = 3000  # samples per vehicle in a history or timeline answer
SAID_WITHIN = 0.3  # s after a refusal its reason (a STATUSTEXT) is waited for
SAYS_WHY = 4  # MAV_SEVERITY_WARNING: a vehicle's message this severe, or worse, after a refusal says why


def routes(station: GroundStation, guards: Guards) -> APIRouter:
    router = APIRouter()
    operator = [Depends(guards.operator)]

    @router.get("/api/vehicles", tags=["vehicles"])
    def vehicles():
        return station.vehicles()

    @router.get("/api/vehicles/{sysid}", tags=["vehicles"])
    def vehicle(sysid: int):
        described = station.vehicles(sysid)
        if not described:
            raise HTTPException(404, f"no vehicle with system id {sysid}")
        return described[0]

    @router.get("/api/vehicles/{sysid}/history", tags=["vehicles"])
    def vehicle_history(sysid: int, since: float | None = Query(None, ge=0, le=1e11, allow_inf_nan=False,
                                                                 description="only samples and events after this "
                                                                             "time (the station's clock, s)"),
                        limit: int = Query(600, ge=1, le=MAX_HISTORY, description="samples at most (thinned)")):
        """The vehicle's sampled telemetry (every numeric field, by name, with units) and its events (mode
        changes, arming, commands and their ACKs, messages, the onboard agent's phases), oldest first."""
        fleet = station.fleet
        with fleet.lock:
            if fleet.get(sysid) is None:
                raise HTTPException(404, f"no vehicle with system id {sysid}")
            return {"sysid": sysid, **fleet.history.of(sysid).as_json(since, limit)}

    @router.post("/api/vehicles/{sysid}/commands", tags=["commands"], dependencies=operator,
                 responses={401: {"description": "no or wrong operator token"},
                            404: {"description": "no such vehicle"},
                            409: {"description": "replaying"}, 504: {"description": "the vehicle did not answer"}})
    async def command(sysid: int, body: Command):
        """Send a command; answers with the vehicle's COMMAND_ACK result, and with anything but "accepted" the
        ``reason`` in words (what the vehicle said about it, or what its answer means); an accepted command
        whose answer alone does not say what happened has a ``note``. A command that cannot do what its name
        says (a resume of a mission that runs) is "refused" with the reason, and nothing is sent."""
        guards.live_only()
        v = guards.vehicle_or_404(sysid)
        if body.action == "goto":
            refused = (outside_space(station.fleet, v, body.x, body.y, station.scene)
                       or blocked(station.fleet, v, body.x, body.y, station.scene))
            if refused:
                raise HTTPException(422, refused)
        sent = time.time()
        refused = refusal(v, body, sent)
        if refused:
            return {"action": body.action, "result": "refused", "reason": refused}
        before = note(v, body, sent)  # what the agent was doing when it was sent
        try:
            result = await guards.exchange(execute, station.link, v, body, station.fleet.datum, sent)
        except LinkError as error:
            raise HTTPException(504, str(error)) from None
        log.info("vehicle %s: %s -> %s", sysid, body.action, result)
        if result == "accepted":
            return {"action": body.action, "result": result, **({"note": before} if before else {})}
        await asyncio.sleep(SAID_WITHIN)  # a refusal's reason comes in a STATUSTEXT just after its ACK
        with station.fleet.lock:
            said = [m["text"] for m in v.messages if m["time"] >= sent and m["severity"] <= SAYS_WHY]
        return {"action": body.action, "result": result, "reason": explain(result, said)}

    @router.get("/api/vehicles/{sysid}/mission", tags=["missions"], response_class=PlainTextResponse)
    async def get_mission(sysid: int):
        """The AUTO mission, downloaded from the vehicle, as QGC WPL 110 text."""
        guards.live_only()
        guards.vehicle_or_404(sysid)
        try:
            items = await guards.exchange(station.link.download_mission, sysid)
        except LinkError as error:
            raise HTTPException(504, str(error)) from None
        station.note_waypoints(sysid, items)
        return mission_text(items)

    @router.put("/api/vehicles/{sysid}/mission", tags=["missions"], dependencies=operator)
    async def put_mission(sysid: int, request: Request):
        """Upload an AUTO mission (QGC WPL 110 text; item 0 is home)."""
        guards.live_only()
        guards.vehicle_or_404(sysid)
        text = (await request.body()).decode("utf-8", "replace")  # at most security.MAX_BODY bytes: the Gate read it
        try:
            items = parse_mission(text)
        except WaypointError as error:
            raise HTTPException(422, str(error)) from None
        if not items:
            raise HTTPException(422, "the mission has no items")
        try:
            result = await guards.exchange(station.link.upload_mission, sysid, items)
        except LinkError as error:
            raise HTTPException(504, str(error)) from None
        if result == "accepted":
            station.note_waypoints(sysid, items)
        return {"result": result, "items": len(items)}

    return router
