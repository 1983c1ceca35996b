"""The pages' files (``static/``: HTML, CSS, scripts, uPlot), shipped in the package, no CDN,
the JSON Schemas of what the twin publishes, served beside them
(:func:`~drafttwin.twin.publish.payload.schema_dir`), and the interactive API docs (``/docs``)
from Swagger UI's files installed with the package (``swagger-ui-bundle``): a plant network
has no internet."""

from __future__ import annotations

from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

import swagger_ui_bundle
from fastapi import FastAPI, HTTPException
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, Response

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


DOCS_FILES = ("swagger-ui-bundle.js", "swagger-ui.css", "favicon-32x32.png")
"""Swagger UI's files that ``/docs`` loads."""


def openapi_30(node: Any) -> Any:
    """An OpenAPI 3.1 document (FastAPI's) as OpenAPI 3.0: the Swagger UI the package ships
    (4.x) reads no 3.1 and showed "Unable to render this definition". JSON Schema 2020-12's
    ``null`` types become ``nullable``, ``examples`` an ``example``, a numeric
    ``exclusiveMinimum``/``Maximum`` the 3.0 pair, ``const`` a one-value ``enum``."""
    if isinstance(node, list):
        return [openapi_30(v) for v in node]
    if not isinstance(node, dict):
        return node
    out = {k: openapi_30(v) for k, v in node.items()}
    if out.get("openapi", "").startswith("3.1"):
        out["openapi"] = "3.0.3"
    for key in ("anyOf", "oneOf"):
        options = out.get(key)
        if isinstance(options, list) and {"type": "null"} in options:
            rest = [o for o in options if o != {"type": "null"}]
            del out[key]
            out.update(rest[0] if len(rest) == 1 else {key: rest})
            out["nullable"] = True
    if isinstance(out.get("type"), list):
        types = [t for t in out["type"] if t != "null"]
        out["nullable"] = out.get("nullable", False) or len(types) < len(out["type"])
        out["type"] = types[0] if types else "string"
    if isinstance(out.get("examples"), list) and "paths" not in out:
        examples = out.pop("examples")
        if examples:
            out["example"] = examples[0]
    for bound, plain in (("exclusiveMinimum", "minimum"), ("exclusiveMaximum", "maximum")):
        if isinstance(out.get(bound), int | float) and not isinstance(out[bound], bool):
            out[plain], out[bound] = out[bound], True
    if "const" in out:
        out["enum"] = [out.pop("const")]
    return out


def serve_docs(app: FastAPI) -> None:
    """``GET /docs``: Swagger UI on the app's API (``/docs-files/openapi.json``: the app's
    ``/openapi.json`` as OpenAPI 3.0, which it reads), its files from the package.

    The app must be made with ``docs_url=None`` (FastAPI's own ``/docs`` loads a CDN)."""
    folder = Path(swagger_ui_bundle.swagger_ui_path)

    @app.get("/docs-files/openapi.json", include_in_schema=False)
    def docs_schema() -> dict[str, Any]:
        return openapi_30(app.openapi())  # type: ignore[no-any-return]

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return get_swagger_ui_html(openapi_url="docs-files/openapi.json",
                                   title=f"{app.title} - API", swagger_js_url="docs-files/swagger-ui-bundle.js",
                                   swagger_css_url="docs-files/swagger-ui.css",
                                   swagger_favicon_url="docs-files/favicon-32x32.png")  # fmt: skip

    @app.get("/docs-files/{name}", include_in_schema=False)
    def docs_file(name: str) -> Response:
        if name not in DOCS_FILES:
            raise HTTPException(404, "no such file")
        kind = next(m for suffix, m in MEDIA.items() if name.endswith(suffix))
        return Response(
            (folder / name).read_bytes(),
            media_type=kind,
            headers={"Cache-Control": "max-age=86400"},
        )


__all__ = ["DOCS_FILES", "MEDIA", "page_text", "serve_docs", "serve_static", "static_dir"]
