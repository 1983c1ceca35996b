"""The pages' files (``static/``: HTML, CSS, scripts, uPlot), shipped in the package, no CDN,
and the JSON Schemas of what the twin publishes, served beside them
(:func:`~drafttwin.twin.publish.payload.schema_dir`)."""

from __future__ import annotations

from importlib import resources
from importlib.resources.abc import Traversable

from fastapi import FastAPI, HTTPException
from fastapi.responses import Response

from drafttwin.twin.publish.payload import SCHEMA_FILES, schema_dir

MEDIA = {".js": "text/javascript", ".css": "text/css", ".html": "text/html",
         ".png": "image/png", ".svg": "image/svg+xml", ".json": "application/json",
         ".LICENSE": "text/plain"}  # fmt: skip
"""The files of ``static/`` the page may load, by suffix."""


def static_dir() -> Traversable:
    """The folder of the pages' files inside the installed package."""
    return resources.files("drafttwin.twin.web") / "static"


def page_text(name: str) -> str:
    """A page (``index.html``, ``hall.html``) of ``static/``."""
    return (static_dir() / name).read_text(encoding="utf-8")


def serve_static(app: FastAPI) -> None:
    """``GET /static/{name}``: the files of ``static/`` with a known suffix and the published
    payloads' JSON Schemas (both pages)."""
    static, schemas = static_dir(), schema_dir()

    @app.get("/static/{name}", include_in_schema=False)
    def asset(name: str) -> Response:
        kind = next((m for suffix, m in MEDIA.items() if name.endswith(suffix)), None)
        path = (schemas if name in SCHEMA_FILES.values() else static) / name
        if kind is None or name.startswith(".") or not path.is_file():
            raise HTTPException(404, "no such file")
        return Response(path.read_bytes(), media_type=kind)


__all__ = ["MEDIA", "page_text", "serve_static", "static_dir"]
