"""What the API's areas share: who may command, which vehicle a path names, live or replay, and the threads that
wait on vehicles."""

from __future__ import annotations

import asyncio
import functools
import logging
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING
from urllib.parse import quote

from fastapi import Header, HTTPException

if TYPE_CHECKING:
    from groundstation.server import GroundStation

EXCHANGES = 16  # commands and mission transfers under way at once (each waits on a vehicle, not on the CPU)
log = logging.getLogger("groundstation")


class Guards:
    """The checks routes depend on, for one station."""

    def __init__(self, station: GroundStation):
        self.station = station
        # Exchanges with vehicles (commands, missions) wait on the radio, up to seconds each: on threads of their
        # own, so that slow or hostile vehicles never hold up what the page draws on asyncio's default threads.
        self._exchanges = ThreadPoolExecutor(max_workers=EXCHANGES, thread_name_prefix="vehicle-exchange")

    def operator(self, authorization: str | None = Header(None, description="Bearer TOKEN (the operator token)")):
        if not self.station.access.is_operator(authorization):
            log.warning("refused a request without a valid operator token")
            raise HTTPException(401, "the operator token is missing or wrong",
                                headers={"WWW-Authenticate": "Bearer"})

    def vehicle_or_404(self, sysid: int):
        vehicle = self.station.fleet.get(sysid)
        if vehicle is None:
            raise HTTPException(404, f"no vehicle with system id {sysid}")
        return vehicle

    def live_only(self) -> None:
        if self.station.replay is not None:
            raise HTTPException(409, "commands are disabled in replay")

    async def exchange(self, function, *args):
        """``function(*args)`` on the exchanges' threads."""
        return await asyncio.get_running_loop().run_in_executor(self._exchanges, functools.partial(function, *args))


def attachment(name: str) -> str:
    """A Content-Disposition for a download called ``name`` (RFC 6266): the name itself percent-encoded as UTF-8
    for browsers, and for older clients an ASCII one without quotes, backslashes or control characters. A file
    in the record folder may be called anything: put in a header as it is, a non-ASCII name was a 500, and a
    line break in it ended the response."""
    plain = "".join(c if " " <= c < "\x7f" and c not in '"\\' else "_" for c in name)
    return f"attachment; filename=\"{plain}\"; filename*=UTF-8''{quote(name, safe='', errors='surrogateescape')}"
