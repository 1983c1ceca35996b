"""A machine that goes away: the twin marks it silent, keeps reconnecting with backoff, and
picks it up again when it is back (the downtime stored as a gap). The twin's process and the
store stay up throughout."""

from __future__ import annotations

import asyncio
import subprocess
import time
from pathlib import Path

import pytest

from drafttwin.twin.build import build_service
from drafttwin.twin.store.history import read_events

from ._twin import cli, env, free_port

pytestmark = pytest.mark.timeout(150)


def _serve(url: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen(cli("plant", "serve", "--opcua", url, "--duration", "60", "--physics",
                                "reduced"), env=env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    assert proc.stderr is not None
    line = proc.stderr.readline()
    assert "serving fa320a" in line, line + proc.stderr.read()
    return proc


@pytest.mark.slow  # two server start-ups and a reconnect: about 30 s
def test_silent_machine_is_marked_reconnected_and_the_gap_stored(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    _, model = twin_files
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    procs = [_serve(url)]
    service = build_service(model, [f"opcua:{url}"], store_dir=tmp_path / "store", silent_s=1.0)
    st = service.states["fa320a"]
    states: list[str] = []

    async def drive() -> None:
        start = time.monotonic()
        while st.received < 100:
            assert time.monotonic() - start < 60, "no samples"
            await asyncio.sleep(0.05)
        procs[0].kill()  # the machine's server dies
        await asyncio.sleep(3.0)
        states.append(st.state)
        before = st.received
        procs.append(await asyncio.to_thread(_serve, url))  # and comes back on the same port
        start = time.monotonic()
        while st.received < before + 100:
            assert time.monotonic() - start < 60, "not reconnected"
            await asyncio.sleep(0.05)
        states.append(st.state)
        service.stop()

    async def main() -> None:
        await asyncio.wait_for(asyncio.gather(service.run(duration_s=120), drive()), 130)

    try:
        asyncio.run(main())
    finally:
        for p in procs:
            p.kill()
            p.wait(timeout=30)
        service.writer.close()
        service.writer.store.close()
    assert states[0] in ("silent", "reconnecting")
    assert states[1] == "live"
    kinds = read_events(tmp_path / "store")["kind"].tolist()
    assert "silent" in kinds and "source-reconnecting" in kinds and "gap" in kinds
    assert kinds.count("source-live") >= 2
    # the console says the source came back (it said only that it was lost)
    from drafttwin.twin.alarms import event_line

    assert event_line("fa320a", "source-live", 0, "opcua") == "fa320a source-live: opcua"
    assert event_line("fa320a", "gap", 0, "9 samples missing") is not None
