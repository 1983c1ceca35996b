"""The live twin against Mosquitto (Debian's broker; skipped when absent): 'plant serve --mqtt
--broker external' publishes to it, the twin follows a set-point, and the store is counted
against the plant's log. Then a hall spread over two twins: a shared subscription splits the
samples, shards split the machines; none lost or stored twice across both."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from drafttwin.twin.build import build_service
from drafttwin.twin.service import TwinService
from drafttwin.twin.store.audit import audit
from drafttwin.twin.store.history import read_history
from drafttwin.wire.plantlog import read_plant_log

from ._twin import cli, env

pytestmark = pytest.mark.timeout(150)


def _plant(port: int, log: Path, *extra: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen(cli("plant", "serve", "--mqtt", f"127.0.0.1:{port}", "--broker",
                                "external", "--physics", "reduced", "--ramp", "50", "--log",
                                str(log), *extra), env=env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    assert proc.stderr is not None
    line = proc.stderr.readline()
    assert "(external broker)" in line, line + proc.stderr.read()
    return proc


def _stop(proc: subprocess.Popen[str]) -> None:
    """SIGTERM (the plant writes its log), SIGKILL if it does not end."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=30)


def _publish(port: int, topic: str, payload: bytes) -> None:
    import paho.mqtt.client as mqtt

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    client.connect("127.0.0.1", port, 30)
    client.loop_start()
    client.publish(topic, payload, qos=1).wait_for_publish(10)
    client.loop_stop()
    client.disconnect()


def _close(*services: TwinService) -> None:
    for s in services:
        if s.writer is not None:
            s.writer.close()
            s.writer.store.close()


def test_twin_over_mosquitto_follows_a_setpoint_and_stores_every_sample(
    mosquitto: int, twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    _, model = twin_files
    log = tmp_path / "plant.parquet"
    plant = _plant(mosquitto, log)
    try:
        service = build_service(model, [f"mqtt://127.0.0.1:{mosquitto}"],
                                store_dir=tmp_path / "store", commit_ms=100)  # fmt: skip
        seen: list[tuple[float, object]] = []
        service.subscribers.append(
            lambda n, rows, ev: seen.extend((time.monotonic(), r) for r in rows)
        )
        marks: dict[str, float] = {}

        async def drive() -> None:
            while len(seen) < 100:
                await asyncio.sleep(0.05)
            marks["before"], marks["written"] = len(seen), time.monotonic()
            await asyncio.to_thread(_publish, mosquitto, "drafttwin/fa320a/setpoint", b"40")
            await asyncio.sleep(1.5)
            service.stop()

        async def main() -> None:
            await asyncio.gather(service.run(duration_s=60), drive())

        asyncio.run(main())
        _close(service)
    finally:
        _stop(plant)
    rows = [r for _, r in seen]
    times = np.array([t for t, _ in seen])
    setpoint = np.array([r.setpoint for r in rows])  # type: ignore[attr-defined]
    reached = np.flatnonzero(setpoint == 40.0)
    assert reached.size and times[reached[0]] - marks["written"] < 1.0
    front = np.array([r.measured[0] for r in rows])  # type: ignore[attr-defined]
    twin = np.array([r.twin[0] for r in rows])  # type: ignore[attr-defined]
    after = slice(reached[0] + 50, reached[0] + 100)
    assert np.nanmean(twin[after]) == pytest.approx(np.nanmean(front[after]), rel=0.01)
    # counted against the plant's log: between the twin's first and last sample, every
    # published sample stored once, as published
    (m,) = audit(tmp_path / "store", log)
    assert m.stored > 200
    assert (m.missing_inside, m.duplicates, m.mismatched, m.foreign, m.filled) == (0, 0, 0, 0, 0)


HALL = "".join(f'[[machine]]\nname = "fa320a-{k}"\n\n' for k in (1, 2, 3))


def _seqs(store: Path) -> dict[str, set[int]]:
    frame = read_history(store)
    real = frame[frame["seq"] >= 0]
    return {str(m): set(g["seq"].tolist()) for m, g in real.groupby("machine")}


def test_a_hall_spread_over_two_twins_by_shared_subscription_and_by_shard(
    mosquitto: int, twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    _, model = twin_files
    mapping = tmp_path / "hall.toml"
    mapping.write_text(HALL, encoding="utf-8")
    log = tmp_path / "plant.parquet"
    url = f"mqtt://127.0.0.1:{mosquitto}"
    plant = _plant(mosquitto, log, "--machines", "3")
    try:
        services = [build_service(model, [src], mapping=mapping, store_dir=tmp_path / name,
                                  commit_ms=100)  # fmt: skip
                    for name, src in (("share-a", f"{url}?share=hall"),
                                      ("share-b", f"{url}?share=hall"),
                                      ("shard-0", f"{url}?shard=0/2"),
                                      ("shard-1", f"{url}?shard=1/2"))]  # fmt: skip

        async def main() -> None:
            await asyncio.gather(*(s.run(duration_s=4.0) for s in services))

        asyncio.run(main())
        _close(*services)
    finally:
        _stop(plant)
    plant_log = read_plant_log(log)
    published = {str(m): set(g["seq"].tolist()) for m, g in plant_log.groupby("machine")}
    a, b = _seqs(tmp_path / "share-a"), _seqs(tmp_path / "share-b")
    for name in published:
        in_a, in_b = a[name], b[name]
        # every message went to exactly one member: none in both stores ...
        assert not in_a & in_b
        # ... and none lost while both members were subscribed (at QoS 0, what the broker had
        # sent to a member that then leaves is gone with it: the members' runs end apart)
        lo, hi = max(min(in_a), min(in_b)), min(max(in_a), max(in_b))
        window = {s for s in published[name] if lo <= s <= hi}
        assert {s for s in in_a | in_b if lo <= s <= hi} == window, name
        assert len(window) > 200  # most of the 4 s run
    # Mosquitto 2.0 takes turns per message: both members got a good part of the hall
    total_a, total_b = sum(map(len, a.values())), sum(map(len, b.values()))
    assert min(total_a, total_b) > 0.3 * (total_a + total_b)
    # shards split machines, not samples: each machine whole in one store, nothing made up
    assert set(_seqs(tmp_path / "shard-0")) == {"fa320a-1", "fa320a-3"}
    assert set(_seqs(tmp_path / "shard-1")) == {"fa320a-2"}
    for shard in ("shard-0", "shard-1"):
        for m in audit(tmp_path / shard, log):
            assert (m.missing_inside, m.duplicates, m.mismatched, m.filled) == (0, 0, 0, 0)
    made_up = sum(m.filled for m in audit(tmp_path / "share-a", log))
    print(
        f"share: {total_a} / {total_b} samples; per machine a="  # noqa: T201
        f"{ {k: len(v) for k, v in a.items()} } b={ {k: len(v) for k, v in b.items()} }; "
        f"rows member a made up for samples it never got: {made_up}"
    )


def test_share_and_shard_options_are_checked() -> None:
    from drafttwin.errors import ConfigError
    from drafttwin.twin.sources.mapping import MachineMap
    from drafttwin.twin.sources.spec import parse_source

    chans = ("front", "second", "third", "back")
    hall = tuple(MachineMap(f"m{k}", chans) for k in range(5))
    default = MachineMap("fa320a", chans)
    src = parse_source("opcua:opc.tcp://127.0.0.1:4840?shard=1/2", default, hall)
    assert [m.name for m in src.machines] == ["m1", "m3"]
    src = parse_source("mqtt://127.0.0.1:1883?shard=0/2&share=hall", default, hall)
    assert [m.name for m in src.machines] == ["m0", "m2", "m4"]
    assert src.share == "hall" and src.spec.endswith("?share=hall")  # type: ignore[attr-defined]
    for bad, needle in (("shard=2/2", "bad shard"), ("shard=x", "bad shard"),
                        ("shard=-1/2", "bad shard"), ("share=a/b", "bad share group"),
                        ("share=", "bad share group"), ("share=%23", "bad share group")):  # fmt: skip
        with pytest.raises(ConfigError, match=needle):
            parse_source(f"mqtt://127.0.0.1:1883?{bad}", default, hall)
    with pytest.raises(ConfigError, match="is empty"):
        parse_source("mqtt://127.0.0.1:1883?shard=1/2", default, ())
