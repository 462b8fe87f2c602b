"""The operator page, its files, and the API's documentation (Swagger UI, served from the station itself)."""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

DOCS_ASSETS = "/docs/assets"


def _static() -> Path:
    """The operator page: package data (``groundstation/static``) in a wheel, the top-level ``static/`` of a
    checkout."""
    here = Path(__file__).resolve().parent.parent
    return here / "static" if (here / "static").is_dir() else here.parent / "static"


STATIC = _static()


def install(app: FastAPI) -> None:
    """The page's routes and mounts (mounts belong to the app: a router does not carry them)."""

    @app.get("/", include_in_schema=False)
    def page():
        return FileResponse(STATIC / "index.html")

    @app.get("/favicon.ico", include_in_schema=False)
    def icon():
        """Where browsers and bookmarking tools look first, whatever the page names."""
        return FileResponse(STATIC / "favicon.svg", media_type="image/svg+xml")

    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/docs", include_in_schema=False)
    def docs():
        """Swagger UI from files installed with the station (no CDN: it works offline, under our policy)."""
        return HTMLResponse(_DOCS_PAGE, headers={"content-security-policy": _DOCS_POLICY})

    app.mount(DOCS_ASSETS, StaticFiles(directory=_swagger_assets()), name="docs-assets")


def _swagger_assets() -> Path:
    import fastapi_offline

    return Path(fastapi_offline.__file__).parent / "static"


_DOCS_PAGE = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>scanstation ground station: API</title>
<link rel="stylesheet" href="{DOCS_ASSETS}/swagger-ui.css"><link rel="icon" href="{DOCS_ASSETS}/favicon.png">
</head><body><div id="swagger-ui"></div>
<script src="{DOCS_ASSETS}/swagger-ui-bundle.js"></script><script src="/static/docs.js"></script>
</body></html>"""
_DOCS_POLICY = ("default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
                "connect-src 'self'; frame-ancestors 'self'; base-uri 'none'; form-action 'self'; object-src 'none'")
