"""The page beside the twin: its loop is not the twin's, and a stuck page does not stop the twin.

The bridge runs a handler's short function on the twin's loop (result and errors come back, a
snapshot many clients ask for is computed once per tenth of a second, a stopped twin answers
503); the page's server runs in a thread of its own, so that when its loop is held (a hundred
clients, a slow encoder) the twin keeps processing at the source's pace.
"""

from __future__ import annotations

import asyncio
import json
import threading
import time
import urllib.request
from typing import Any

import pytest
from fastapi import HTTPException

from drafttwin.twin.web.bridge import SNAPSHOT_S, Bridge

from ._twin import free_port, serve_beside


class _TwinLoop:
    """An event loop in a thread of its own, standing for the twin's."""

    def __enter__(self) -> asyncio.AbstractEventLoop:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        return self.loop

    def __exit__(self, *exc: object) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


def test_a_call_runs_on_the_twins_loop_and_brings_back_its_result_or_error() -> None:
    with _TwinLoop() as twin:
        bridge = Bridge(twin)
        where: list[threading.Thread] = []

        def on_twin(x: int) -> int:
            where.append(threading.current_thread())
            return 2 * x

        def refuse() -> None:
            raise HTTPException(404, "no machine 'x'")

        async def ask() -> tuple[int, int]:
            got = await bridge.call(on_twin, 21)
            with pytest.raises(HTTPException) as err:
                await bridge.call(refuse)
            return got, err.value.status_code

        assert asyncio.run(ask()) == (42, 404)
        assert where and where[0] is not threading.current_thread()


def test_a_snapshot_many_ask_for_is_computed_once_and_a_failure_is_not_kept() -> None:
    with _TwinLoop() as twin:
        bridge = Bridge(twin)
        calls: list[float] = []

        def status() -> dict[str, int]:
            calls.append(time.monotonic())
            return {"rows": len(calls)}

        async def clients(n: int) -> list[dict[str, int]]:
            return list(await asyncio.gather(*(bridge.shared("status", status) for _ in range(n))))

        first = asyncio.run(clients(100))
        assert len(calls) == 1 and all(a is first[0] for a in first)
        time.sleep(SNAPSHOT_S * 1.5)
        assert asyncio.run(clients(10))[0] == {"rows": 2}  # stale: asked again

        fails = iter([True, False])

        def flaky() -> str:
            if next(fails):
                raise HTTPException(503, "busy")
            return "ok"

        async def twice() -> str:
            with pytest.raises(HTTPException):
                await bridge.shared("flaky", flaky)
            return await bridge.shared("flaky", flaky)

        assert asyncio.run(twice()) == "ok"


def test_a_twin_that_has_stopped_answers_503() -> None:
    loop = asyncio.new_event_loop()
    loop.close()

    async def ask() -> int:
        with pytest.raises(HTTPException) as err:
            await Bridge(loop).call(lambda: 1)
        return err.value.status_code

    assert asyncio.run(ask()) == 503


def _get(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=10) as r:  # noqa: S310 - 127.0.0.1 only
        return json.load(r)


@pytest.mark.slow  # 100 Hz replayed for a few seconds
def test_the_twin_keeps_its_pace_while_the_pages_loop_is_held(twin_files) -> None:
    """The page's loop held for 2 s (as by a hundred clients): the twin processes about 200
    rows meanwhile, and the page answers again afterwards with the twin's status."""
    from drafttwin.twin.build import build_service

    record, model = twin_files
    service = build_service(model, [f"replay:{record}?speed=1&machine=m1"], detector="none")
    port = free_port()
    found: dict[str, Any] = {}

    def load(page: Any) -> None:
        time.sleep(0.5)
        before = service.rows
        page.loop.call_soon_threadsafe(time.sleep, 2.0)  # the page's loop held for 2 s
        time.sleep(2.0)
        found["held"] = service.rows - before
        found["status"] = _get(f"http://127.0.0.1:{port}/api/status")
        found["page_thread"] = page.thread.name
        service.stop()

    serve_beside(service, port, 30, load, join_s=30)
    assert found["page_thread"] == "twin-page"
    assert found["held"] >= 150, found["held"]  # 100 Hz for 2 s: ~200 rows
    assert found["status"]["machines"]["m1"]["processed"] > 0


def test_the_hubs_push_is_the_strict_json_of_its_rows_and_events() -> None:
    """Made without walking the rows in Python: the same document as :func:`to_strict`, every
    non-finite number null, a machine's name left as it is even when it reads NaN."""
    import math

    import numpy as np

    from drafttwin._json import to_strict
    from drafttwin.twin.web.app import _push_json

    rng = np.random.default_rng(3)
    rows = {name: rng.normal(0, 1e3, (40, 11)).tolist() for name in ("m1", "NaN", 'a"b')}
    for r in rows["m1"][::3]:
        r[1], r[5], r[-1] = math.nan, math.inf, -math.inf
    events = [{"machine": "m1", "kind": "gap", "detail": "NaN Infinity", "x": math.nan}]
    text = _push_json(rows, events)
    assert json.loads(text) == to_strict({"rows": rows, "events": events})
    assert "NaN," not in text and "Infinity]" not in text


def test_a_snapshot_is_not_shared_across_event_loops() -> None:
    """A test client runs each request in a loop of its own: the second request, within the
    snapshot's tenth of a second, computes its own instead of awaiting a closed loop's."""
    bridge = Bridge()  # no twin loop: the handlers' own loop is the twin's
    calls: list[int] = []

    def status() -> int:
        calls.append(1)
        return len(calls)

    assert asyncio.run(bridge.shared("status", status)) == 1
    assert asyncio.run(bridge.shared("status", status)) == 2
