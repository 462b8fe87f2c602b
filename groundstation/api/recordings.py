"""Recordings and replay: the session recordings (list, download, delete), and replaying one in the page."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from fastapi import APIRouter, Depends, HTTPException, Query, Response
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, ConfigDict, Field, field_validator

from groundstation.api.common import attachment
from groundstation.api.vehicles import MAX_HISTORY
from groundstation.replay import ReplayError

if TYPE_CHECKING:
    from groundstation.api.common import Guards
    from groundstation.server import GroundStation


class ReplayStart(BaseModel):
    name: str = Field(max_length=255, description="a recording's name, as GET /api/recordings lists it")


class ReplayControl(BaseModel):
    model_config = ConfigDict(allow_inf_nan=False, strict=True)

    play: bool | None = None
    speed: float | None = Field(None, ge=0.1, le=20)
    seek: float | None = Field(None, ge=0, le=1e7, description="seconds from the start of the recording")
    step: Literal[-1, 1] | None = None

    @field_validator("step", mode="before")
    @classmethod
    def _step_is_a_number(cls, value):
        if isinstance(value, bool):  # true == 1 to the Literal
            raise ValueError("step is -1 or 1, not true or false")
        return value


def _read_prefix(path: Path, size: int, chunk: int = 1 << 16):
    """The first ``size`` bytes of a file, in chunks."""
    with open(path, "rb") as handle:
        left = size
        while left > 0:
            data = handle.read(min(chunk, left))
            if not data:
                return
            left -= len(data)
            yield data


def routes(station: GroundStation, guards: Guards) -> APIRouter:
    router = APIRouter()
    operator = [Depends(guards.operator)]

    def recording_or_404(name: str) -> Path:
        path = station.recordings.path(name)
        if path is None:
            shown = name if len(name) <= 80 else f"{name[:80]}..."  # the start of a long name says enough
            raise HTTPException(404, f"no recording called {shown!r}")
        return path

    @router.get("/api/recordings", tags=["recordings"])
    def recordings():
        """The session recordings, newest first."""
        return station.recordings.listing()

    @router.get("/api/recordings/{name}", tags=["recordings"])
    def recording(name: str):
        """Download a recording (.tlog, readable by mavlogdump.py, MAVExplorer, QGroundControl).

        The session being recorded goes on growing: its download is the file as it
        was when the request came (its last record may be cut short; replay reads
        up to it)."""
        path = recording_or_404(name)
        size = path.stat().st_size
        return StreamingResponse(_read_prefix(path, size), media_type="application/octet-stream",
                                 headers={"Content-Length": str(size),
                                          "Content-Disposition": attachment(name)})

    @router.delete("/api/recordings/{name}", tags=["recordings"], dependencies=operator)
    def delete_recording(name: str):
        path = recording_or_404(name)
        if station.recorder is not None and path == station.recorder.path:
            raise HTTPException(409, "that is the session being recorded now")
        if station.replay is not None and station.replay.index.path == path:
            raise HTTPException(409, "that recording is being replayed")
        path.unlink()
        return {"deleted": name}

    @router.get("/api/replay", tags=["replay"])
    def replay_status():
        replay = station.replay
        return {"mode": station.mode, "replay": replay.status() if replay is not None else None}

    @router.post("/api/replay", tags=["replay"], dependencies=operator)
    async def start_replay(body: ReplayStart):
        """Replay a recording in the page (instead of the live vehicles)."""
        path = recording_or_404(body.name)
        try:
            replay = await asyncio.to_thread(station.replays.start, path)
        except ReplayError as error:
            raise HTTPException(422, str(error)) from None
        return replay.status()

    @router.post("/api/replay/control", tags=["replay"], dependencies=operator)
    async def control_replay(body: ReplayControl):
        """Play or pause, change speed, seek to a time (s from the start) or step by a tenth of a second."""
        replay = station.replay
        if replay is None:
            raise HTTPException(409, "nothing is being replayed")
        return await asyncio.to_thread(replay.control, body.play, body.speed, body.seek, body.step)

    @router.post("/api/replay/stop", tags=["replay"], dependencies=operator)
    def stop_replay():
        """Back to the live vehicles."""
        station.replays.stop()
        return {"mode": station.mode}

    @router.get("/api/replay/timeline", tags=["replay"])
    def replay_timeline(limit: int = Query(1500, ge=1, le=MAX_HISTORY, description="samples per vehicle at most"),
                        sysid: int | None = Query(None, ge=1, le=255, description="only this vehicle's")):
        """The replayed log's whole history, every vehicle's (or one's), on the log's clock (``start`` is replay
        time 0): scanned in the background when the replay starts (``ready`` false meanwhile)."""
        replay, timeline = station.replay, station.timeline
        if replay is None or timeline is None:
            raise HTTPException(409, "nothing is being replayed")
        history = timeline.history
        vehicles = {} if history is None else {str(key): {"sysid": key, **found.as_json(None, limit)}
                                                for key, found in sorted(history.vehicles.items())
                                                if sysid is None or key == sysid}
        return {"ready": timeline.ready, "error": timeline.error, "skipped": timeline.skipped,
                "start": replay.index.start, "duration": replay.duration, "vehicles": vehicles}

    @router.get("/api/replay/export", tags=["replay"])
    async def export_replay():
        """The replay as one standalone HTML file that plays offline."""
        replay = station.replay
        if replay is None:
            raise HTTPException(409, "nothing is being replayed")
        html = await asyncio.to_thread(station.replays.export, replay)
        name = Path(replay.name).stem + ".html"
        return Response(html, media_type="text/html",
                        headers={"Content-Disposition": attachment(name)})

    return router
