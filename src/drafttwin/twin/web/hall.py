"""The page of a whole hall (``drafttwin twin hall --http``): every shard's machines at a glance.

The hall's driver polls each shard actor's status every second (:func:`~drafttwin.twin.hall.run_hall`)
and keeps the latest in a :class:`HallView`; this app serves it as ``GET /api/hall`` and a page
(``static/hall.html``, no chart library, nothing from the internet) that redraws a tile per
machine from it: its shard, state, samples, p99 latency of its shard and its latest fault
alarm with the probable cause. The same token guard as the twin's page
(:mod:`~drafttwin.twin.web.guard`): any bind address but 127.0.0.1 needs a token, checked on
every request.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from fastapi import FastAPI, HTTPException
from fastapi.responses import HTMLResponse

from drafttwin._json import to_strict
from drafttwin.twin.web.assets import page_text, serve_docs, serve_static
from drafttwin.twin.web.guard import guard


class HallView:
    """The latest status of each shard, thread-safe: its ``state`` (starting, loading,
    running, not answering, restarting, ended, failed; ``None`` before the first poll:
    starting) and, once running, its twin's status."""

    def __init__(self, shards: int) -> None:
        self.lock = threading.Lock()
        self.shards: list[dict[str, Any] | None] = [None] * shards
        self.updated = 0.0
        self.command: Callable[..., dict[str, Any]] | None = None  # set once the shards run

    def bind_commands(self, command: Callable[..., dict[str, Any]]) -> None:
        """``command(shard, kind, machine, args)``: an operator's command through the shard
        that watches the machine (:func:`drafttwin.twin.hall.run_hall`)."""
        self.command = command

    def shard_of(self, machine: str) -> int | None:
        """The shard watching ``machine`` in the latest poll (None: none does)."""
        with self.lock:
            shards = list(self.shards)
        return next((i for i, st in enumerate(shards)
                     if st is not None and machine in st.get("machines", {})), None)  # fmt: skip

    def update(self, statuses: list[dict[str, Any] | None]) -> None:
        with self.lock:
            self.shards, self.updated = list(statuses), time.time()

    def snapshot(self) -> dict[str, Any]:
        with self.lock:
            shards, updated = list(self.shards), self.updated
        out = []
        for i, st in enumerate(shards):
            if st is None or "machines" not in st:  # starting, loading, failed: no machines yet
                out.append({"shard": i, "state": "starting" if st is None else st["state"],
                            "machines": {}, **({"error": st["error"]} if st and "error" in st else {})})  # fmt: skip
                continue
            out.append({"shard": i, "state": st.get("state", "running"), "rows": st.get("rows"),
                        "latency_ms": st.get("latency_ms"),
                        "machines": {name: {k: m.get(k) for k in MACHINE_KEYS}
                                     for name, m in st.get("machines", {}).items()}})  # fmt: skip
        status: dict[str, Any] = to_strict({"updated": updated, "shards": out})
        return status


MACHINE_KEYS = ("state", "received", "processed", "dropped", "late", "fault_alarms",
                "fault_detector", "last_fault", "active_alarms", "detector", "identity")  # fmt: skip


def create_hall_app(view: HallView, token: str | None = None) -> FastAPI:
    """The hall's app; its OpenAPI schema is ``/openapi.json``, the interactive docs ``/docs``."""
    app = FastAPI(
        title="drafttwin hall",
        summary="Every shard's machines (docs/twin.md)",
        docs_url=None,
        redoc_url=None,
    )
    guard(app, token)
    serve_static(app)
    serve_docs(app)

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def page() -> str:
        return page_text("hall.html")

    @app.get("/api/hall")
    def hall() -> Any:
        """Each shard's state, rows and p99 latency, and per machine its counts and last alarm."""
        return view.snapshot()

    def through_shard(kind: str, machine: str, args: dict[str, Any]) -> Any:
        shard = view.shard_of(machine)
        if shard is None or view.command is None:
            raise HTTPException(404, f"no machine {machine[:100]!r} in the hall")
        answer = view.command(shard, kind, machine, args)
        if answer["status"] != 200:
            raise HTTPException(answer["status"], answer["body"])
        return answer["body"]

    @app.post("/api/machines/{machine}/relearn")
    def relearn(machine: str) -> Any:
        """After maintenance: the machine's shard forgets its learned healthy state and learns
        it again (as the twin's own API)."""
        return through_shard("relearn", machine, {})

    @app.post("/api/machines/{machine}/alarms/{what}")
    def acknowledge(machine: str, what: str, comment: str = "", alarm: str | None = None) -> Any:
        """``what`` = acknowledge or confirm the machine's retained alarms (or the one whose id
        is ``alarm``), on its shard; the alarms after."""
        if what not in ("acknowledge", "confirm"):
            raise HTTPException(404, "acknowledge or confirm")
        return through_shard(what, machine, {"comment": comment[:500], "alarm": alarm})

    return app


class HallServer:
    """uvicorn in a thread of the driver (the driver's own thread waits on Ray)."""

    def __init__(self, view: HallView, bind: tuple[str, int], token: str | None) -> None:
        import uvicorn

        from drafttwin.twin.web.server import bound_socket

        self.sock = bound_socket(bind)
        config = uvicorn.Config(create_hall_app(view, token), log_level="warning", lifespan="off")
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]},
                                       name="hall-page", daemon=True)  # fmt: skip

    def __enter__(self) -> HallServer:
        self.thread.start()
        deadline = time.monotonic() + 10
        while not self.server.started and self.thread.is_alive() and time.monotonic() < deadline:
            time.sleep(0.02)
        if not self.server.started:
            raise OSError("the hall page did not start")
        return self

    def __exit__(self, *exc: object) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=5)
        self.sock.close()


__all__ = ["HallServer", "HallView", "create_hall_app"]
