"""SIGTERM and SIGINT end every long-running twin and plant command within 5 s, with its
summary, exit code 0 and no traceback, for every source kind and with the page on (a page
that served requests left an AnyIO worker thread that kept ``twin run`` alive; a signal
landing in the physics' numba kernel made ``plant serve`` print a SystemError)."""

from __future__ import annotations

import signal
import subprocess
import time
import urllib.request
from pathlib import Path

import pytest

from ._twin import cli, env, free_port

pytest.importorskip("asyncua")

STOP_WITHIN_S = 5.0


def _start(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(cli(*args), env=env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip


def _wait_for(proc: subprocess.Popen[str], text: str, timeout: float = 60.0) -> None:
    """Read stderr until a line holds ``text`` (the command's 'serving' / 'page on' line)."""
    assert proc.stderr is not None
    deadline = time.monotonic() + timeout
    seen = []
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        seen.append(line)
        if text in line:
            return
        if not line and proc.poll() is not None:
            break
    raise AssertionError(f"no {text!r} from {proc.args}: {''.join(seen)}")


def _stop(proc: subprocess.Popen[str], sig: int) -> tuple[float, str, str]:
    """Send ``sig``; (seconds to exit, stdout, stderr). Killed (and failed) past 30 s."""
    t0 = time.monotonic()
    proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate(timeout=30)
        raise AssertionError(
            f"{proc.args} still ran 30 s after {signal.Signals(sig).name}"
        ) from None
    return time.monotonic() - t0, out, err


def _visit(port: int) -> None:
    """Ask the page what a browser and a scraper ask (runs the server's worker threads)."""
    for path in ("/", "/api/status", "/metrics"):
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10) as r:
            assert r.status == 200


def _check(took: float, proc: subprocess.Popen[str], out: str, err: str, summary: str) -> None:
    assert took < STOP_WITHIN_S, f"{took:.1f} s to stop: {err}"
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "Error" not in err, err
    assert summary in out + err, out + err


@pytest.mark.slow  # a plant and a twin start-up: about 15 s
# MQTT in the suite: plant serve --mqtt stopped by SIGTERM in test_twin_mosquitto.py, twin run
# with MQTT publishers in test_twin_publish.py; the full variant with pytest -m long
@pytest.mark.parametrize("kind", ["opcua", pytest.param("mqtt", marks=pytest.mark.long)])
def test_signals_end_plant_and_twin_with_the_page_on(
    kind: str, twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    _, model = twin_files
    port, http = free_port(), free_port()
    address = f"opc.tcp://127.0.0.1:{port}" if kind == "opcua" else f"127.0.0.1:{port}"
    source = f"opcua:{address}" if kind == "opcua" else f"mqtt://{address}"
    plant = _start("plant", "serve", f"--{kind}", address, "--physics", "reduced",
                   "--log", str(tmp_path / "plant.parquet"))  # fmt: skip
    twin = None
    try:
        _wait_for(plant, "serving")
        twin = _start("twin", "run", "--model", str(model), "--source", source, "--http",
                      f"127.0.0.1:{http}", "--store", str(tmp_path / "store"), "--quiet")  # fmt: skip
        _wait_for(twin, "page on")
        time.sleep(1.0)  # samples flow
        _visit(http)
        took, out, err = _stop(twin, signal.SIGTERM)
        _check(took, twin, out, err, "rows committed")
        # a live source stamps its samples: the twin splits off the transport's share
        assert "fa320a: source -> received" in out, out
        # the plant by SIGINT (Ctrl-C): the same clean end, and its log written
        took, out, err = _stop(plant, signal.SIGINT)
        _check(took, plant, out, err, "published fa320a")
        assert "stopped by SIGINT" in err and (tmp_path / "plant.parquet").is_file()
    finally:
        for p in (plant, twin):
            if p is not None and p.poll() is None:
                p.kill()
                p.communicate(timeout=30)


def test_sigint_ends_a_replay_twin_with_the_page_on(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    record, model = twin_files
    http = free_port()
    twin = _start("twin", "run", "--model", str(model), "--source", f"replay:{record}?speed=0.5",
                  "--http", f"127.0.0.1:{http}", "--quiet")  # fmt: skip
    try:
        _wait_for(twin, "page on")
        _visit(http)
        took, out, err = _stop(twin, signal.SIGINT)
        _check(took, twin, out, err, "latency")
        assert "stopped by SIGINT" in err
    finally:
        if twin.poll() is None:
            twin.kill()
            twin.communicate(timeout=30)


@pytest.mark.slow  # a plant start-up with three machines: about 10 s
def test_three_machines_on_the_embedded_broker_stop_within_5_s(tmp_path: Path) -> None:
    """Each machine's 'offline' waited 2 s for an acknowledgement the embedded broker, on the
    same event loop, could not send while the wait blocked it: three machines took 6.1 s."""
    port = free_port()
    plant = _start("plant", "serve", "--mqtt", f"127.0.0.1:{port}", "--physics", "reduced",
                   "--machines", "3")  # fmt: skip
    try:
        _wait_for(plant, "serving")
        time.sleep(1.0)
        took, out, err = _stop(plant, signal.SIGTERM)
        _check(took, plant, out, err, "fa320a-3: ")
    finally:
        if plant.poll() is None:
            plant.kill()
            plant.communicate(timeout=30)
