"""The REST API and the page's other routes, one module per area; ``groundstation.app`` assembles them.

Each area module has ``routes(station, guards) -> APIRouter``; a new area is a
new module here and one line in ``AREAS``. ``common`` holds what the areas share:
the operator check, the vehicle look-up, the live-only rule and the pool the
vehicle exchanges wait on.
"""

from groundstation.api import maps, plan, recordings, rti, session, streams, vehicles

AREAS = (session, vehicles, plan, maps, rti, recordings, streams)  # the order routes are matched and documented in
