"""A live machine over OPC UA: 'plant serve' in a subprocess, the twin in this process; a new
supply set-point written to the server changes the plant, and the twin follows."""

from __future__ import annotations

import asyncio
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from drafttwin.twin.build import build_service

from ._twin import cli, env, free_port

pytestmark = pytest.mark.timeout(150)


@pytest.fixture
def served() -> tuple[str, subprocess.Popen[str]]:
    port = free_port()
    url = f"opc.tcp://127.0.0.1:{port}"
    proc = subprocess.Popen(cli("plant", "serve", "--opcua", url, "--duration", "60",
                                "--ramp", "50"), env=env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    assert proc.stderr is not None
    line = proc.stderr.readline()  # 'serving ...' once the server listens
    assert "serving fa320a" in line, line + proc.stderr.read()
    yield url, proc
    proc.kill()
    proc.wait(timeout=30)


async def _write_setpoint(url: str, hz: float) -> None:
    from asyncua import Client

    async with Client(url) as client:
        await client.get_node("ns=2;s=fa320a.supply_setpoint_hz").write_value(hz)


async def _write(url: str, hz: float) -> None:
    """Write from another thread with its own client loop, as an operator's tool would."""
    await asyncio.wait_for(asyncio.to_thread(asyncio.run, _write_setpoint(url, hz)), 30)


def test_the_twin_follows_a_new_setpoint_within_a_second(
    served: tuple[str, subprocess.Popen[str]], twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    url, _ = served
    _, model = twin_files
    service = build_service(model, [f"opcua:{url}"], store_dir=tmp_path / "store", commit_ms=100)
    seen: list[tuple[float, object]] = []
    service.subscribers.append(
        lambda name, rows, ev: seen.extend((time.monotonic(), r) for r in rows)
    )
    marks: dict[str, float] = {}

    async def drive() -> None:
        start = time.monotonic()
        while len(seen) < 150:  # 1.5 s of live samples first
            assert time.monotonic() - start < 60, "no live samples from the OPC UA server"
            await asyncio.sleep(0.05)
        marks["before"] = len(seen)
        marks["written"] = time.monotonic()
        await _write(url, 40.0)
        await asyncio.sleep(1.5)
        from asyncua import ua

        for hostile in (float("nan"), -5.0, 500.0):  # answered BadOutOfRange, not written
            with pytest.raises(ua.UaStatusCodeError):
                await _write(url, hostile)
        await asyncio.sleep(1.0)
        service.stop()

    async def main() -> None:
        await asyncio.gather(service.run(duration_s=60), drive())

    asyncio.run(main())
    service.writer.close()
    service.writer.store.close()
    rows = [r for _, r in seen]
    times = np.array([t for t, _ in seen])
    setpoint = np.array([r.setpoint for r in rows])
    front = np.array([r.measured[0] for r in rows])
    physics = np.array([r.physics[0] for r in rows])
    twin = np.array([r.twin[0] for r in rows])
    before = slice(marks["before"] - 100, marks["before"])
    assert np.allclose(setpoint[before], 48.47)
    reached = np.flatnonzero(setpoint == 40.0)
    assert reached.size, "the twin never saw the new set-point"
    # the plant ramps 8.47 Hz at 50 Hz/s (0.17 s): the twin has it within a second
    assert times[reached[0]] - marks["written"] < 1.0
    # the plant really slowed down by the set-point's ratio, and the twin with it
    after = slice(reached[0] + 50, reached[0] + 100)
    assert np.nanmean(front[after]) / np.nanmean(front[before]) == pytest.approx(
        40 / 48.47, rel=0.01
    )
    assert np.nanmean(twin[after]) == pytest.approx(np.nanmean(front[after]), rel=0.01)
    assert np.nanmean(physics[after]) == pytest.approx(np.nanmean(front[after]), rel=0.02)
    # the hostile set-points were refused: the plant kept running at 40 Hz
    assert (setpoint[reached[0] :] == 40.0).all()
    # every sample of the machine arrived once and in order
    seq = np.array([r.seq for r in rows if r.seq >= 0])
    assert (np.diff(seq) == 1).all()
    assert service.status()["machines"]["fa320a"]["dropped"] == 0


def test_a_setpoint_out_of_range_is_answered_bad_out_of_range(
    served: tuple[str, subprocess.Popen[str]],
) -> None:
    # every write had answered Good; the plant set the node back unseen
    from asyncua import Client, ua

    url, _ = served

    async def writes() -> list[str]:
        async with Client(url) as client:
            node = client.get_node("ns=2;s=fa320a.supply_setpoint_hz")
            out = []
            for hz in (500.0, -5.0, float("nan"), 40.0):
                try:
                    await node.write_value(ua.DataValue(ua.Variant(hz, ua.VariantType.Double)))
                    out.append("Good")
                except ua.UaStatusCodeError as exc:
                    out.append(type(exc).__name__)
            out.append(str(await node.read_value()))
            return out

    assert asyncio.run(writes()) == ["BadOutOfRange"] * 3 + ["Good", "40.0"]
