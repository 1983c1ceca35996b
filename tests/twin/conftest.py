"""Fixtures of the live-twin tests: one short plant record, one tiny hybrid (per session);
a Mosquitto broker (per test)."""

from __future__ import annotations

import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

pytest.importorskip("duckdb", reason="the live twin needs the 'twin' extra")
pytest.importorskip("asyncua", reason="the live twin needs the 'twin' extra")

from ._twin import free_port, plant_record, tiny_hybrid  # noqa: E402


@pytest.fixture(scope="session")
def twin_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(plant record of 6 s with a speed change, tiny parallel hybrid fitted on it)."""
    folder = tmp_path_factory.mktemp("twin")
    record = plant_record(folder)
    return record, tiny_hybrid(folder, record)


@pytest.fixture
def mosquitto(tmp_path: Path) -> Iterator[int]:
    """A Mosquitto broker (Debian package) on a free 127.0.0.1 port, anonymous, no
    persistence; stopped at the end. Skips when the binary is absent."""
    binary = shutil.which("mosquitto") or next(
        (p for p in ("/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto") if Path(p).is_file()), None
    )
    if binary is None:
        pytest.skip("mosquitto is not installed (Debian: apt-get install mosquitto)")
    from drafttwin.plant.serve.mqtt import broker_answers

    port = free_port()
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n"
                    "log_dest stderr\nlog_type error\nlog_type warning\n", encoding="utf-8")  # fmt: skip
    proc = subprocess.Popen([binary, "-c", str(conf)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 15
        while not broker_answers("127.0.0.1", port):
            assert proc.poll() is None, (
                f"mosquitto exited: {proc.stderr.read() if proc.stderr else ''}"
            )
            assert time.monotonic() < deadline, "mosquitto did not listen within 15 s"
            time.sleep(0.05)
        yield port
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
