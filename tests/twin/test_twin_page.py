"""The page in headless Chromium (Debian's, driven by Playwright): it loads, the live values
update, the screenshot shows the charts. The token guards REST, the WebSocket and /metrics;
a page off 127.0.0.1 without a token is refused."""

from __future__ import annotations

import asyncio
import io
import json
import shutil
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.twin.build import build_service
from drafttwin.twin.web import serve_with

from ._twin import free_port

pytestmark = pytest.mark.timeout(150)
TOKEN = "t0ken-for-the-page-test-0123456789"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _get(url: str, headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:  # noqa: S310  a local test server
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


async def _ws_refused(url: str) -> bool:
    import websockets

    try:
        async with websockets.connect(url) as ws:
            await asyncio.wait_for(ws.recv(), 5)
    except websockets.exceptions.InvalidStatus:
        return True  # refused before the upgrade
    except websockets.exceptions.ConnectionClosed as exc:
        return exc.rcvd is not None and exc.rcvd.code == 1008
    return False


def test_a_public_bind_without_token_is_refused(twin_files: tuple[Path, Path]) -> None:
    record, model = twin_files
    res = CliRunner().invoke(app, ["twin", "run", "--model", str(model), "--source",
                                   f"replay:{record}", "--http", "0.0.0.0:8050"])  # fmt: skip
    assert res.exit_code == 2
    assert "refusing to serve the page on 0.0.0.0 without a token" in res.stderr


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed "
                    "(apt-get install chromium): the browser test needs it")  # fmt: skip
def test_page_loads_updates_live_and_shows_the_charts(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    playwright = pytest.importorskip("playwright.async_api", reason="needs playwright (test extra)")
    record, model = twin_files
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    service = build_service(model, [f"replay:{record}?speed=1&machine=df-01"])
    found: dict[str, object] = {}

    async def browse() -> None:
        while not found.get("up"):
            await asyncio.sleep(0.05)
        found["no_token"] = await asyncio.to_thread(_get, base + "/api/status")
        found["bearer"] = await asyncio.to_thread(
            _get, base + "/metrics", {"Authorization": f"Bearer {TOKEN}"}
        )
        found["ws_refused"] = await _ws_refused(f"ws://127.0.0.1:{port}/ws")
        async with playwright.async_playwright() as p:
            browser = await p.chromium.launch(executable_path=CHROMIUM, args=[
                "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--no-first-run"])  # fmt: skip
            page = await browser.new_page(viewport={"width": 1280, "height": 1000})
            await page.goto(f"{base}/?token={TOKEN}")
            value = page.locator("#value-front")
            await page.wait_for_function(
                "document.querySelector('#value-front') && "
                "/twin [0-9]/.test(document.querySelector('#value-front').textContent)",
                timeout=20_000,
            )
            first = await value.text_content()
            await asyncio.sleep(1.0)
            found["values"] = (first, await value.text_content())
            found["tiles"] = await page.locator(".tile").count()
            found["png"] = await page.screenshot()
            await browser.close()
        service.stop()

    def started(_: object) -> None:
        found["up"] = True

    async def main() -> None:
        await asyncio.gather(
            serve_with(service, ("127.0.0.1", port), TOKEN, 60, None, started), browse()
        )

    asyncio.run(main())
    assert found["no_token"][0] == 401
    code, body = found["bearer"]
    assert code == 200 and b"drafttwin_samples_total" in body
    assert found["ws_refused"]
    first, later = found["values"]
    assert first != later  # the live values moved within a second
    assert found["tiles"] == 1
    import matplotlib.image as mpimg

    png = mpimg.imread(io.BytesIO(found["png"]), format="png")[..., :3]
    twin_orange = np.array([0xD9, 0x48, 0x0F]) / 255.0  # the twin's line colour
    near = (np.abs(png - twin_orange) < 0.08).all(axis=-1)
    assert near.sum() > 200  # the twin's lines are drawn
    assert len(np.unique((png * 255).astype(np.uint8).reshape(-1, 3), axis=0)) > 50
    json.dumps(service.status())
