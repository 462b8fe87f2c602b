"""Session and health: a browser's watching cookie, the operator's sign-in check, and how the station is doing."""

from __future__ import annotations

from typing import TYPE_CHECKING

from fastapi import APIRouter, Depends, Header, HTTPException, Request, Response

from groundstation.security import SESSION_COOKIE
from vehicle import __version__

if TYPE_CHECKING:
    from groundstation.api.common import Guards
    from groundstation.server import GroundStation


def routes(station: GroundStation, guards: Guards) -> APIRouter:
    router = APIRouter(tags=["status"])

    @router.post("/api/session", status_code=204,
                 responses={401: {"description": "neither the operator nor the viewer token"}})
    def session(request: Request, authorization: str | None = Header(None, description="Bearer TOKEN")):
        """Let this browser watch (a cookie for the 3D view and the stream, which cannot carry a header).
        Needed only when the station serves beyond loopback; commands still need the operator token."""
        if not station.access.grants_session(authorization):
            raise HTTPException(401, "neither the operator nor the viewer token",
                                headers={"WWW-Authenticate": "Bearer"})
        response = Response(status_code=204)
        response.set_cookie(SESSION_COOKIE, station.access.session_value(), httponly=True, samesite="strict",
                            secure=request.url.scheme == "https", path="/")
        return response

    @router.get("/api/health")
    @router.head("/api/health", include_in_schema=False)  # what uptime monitors send
    def health():
        scene, recorder, replay = station.scene, station.recorder, station.replay
        link = station.link.health() if station.link is not None else None
        if link is not None and recorder is not None and recorder.refused:
            link["recording_error"] = recorder.refused  # what the page's health banner says of the recording
        troubled = link is not None and (link["thread"] != "ok" or link["recording_error"]
                                         or not all(port["up"] for port in link["links"]))
        return {"status": "degraded" if troubled else "ok", "version": __version__, "mode": station.mode,
                "vehicles": len(station.fleet.ids()), "links": station.link_urls, "link": link,
                "far_from_scene": station.far_from_scene(),
                "recording": None if recorder is None else {
                    "file": recorder.path.name if recorder.path is not None else None,
                    "error": link["recording_error"] if link else None, "refused": recorder.refused or None,
                    "not_kept": recorder.not_kept, "strangers_dropped": recorder.strangers_dropped},
                "replay": None if replay is None else {"name": replay.name, "errors": replay.errors,
                                                       "last_error": replay.last_error or None},
                "scene": None if scene is None else {"name": scene.path.name if scene.path else None,
                                                     "triangles": len(scene.faces)}}

    @router.get("/api/auth", dependencies=[Depends(guards.operator)])
    def auth():
        """200 when the operator token is right (the page's sign-in uses this)."""
        return {"ok": True}

    return router
