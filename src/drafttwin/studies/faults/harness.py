"""What a live benchmark runs around the twin: its child commands (each in a process of its
own that dies with this one), a broker on 127.0.0.1, the twin's status and its events read
back. Shared by :mod:`.live` (the records served by ``plant replay``) and :mod:`.live_plant`
(the live plant itself)."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from drafttwin.errors import RunError
from drafttwin.execution.interrupt import die_with_parent

LEARN_MARGIN_S = 10.0
"""A machine learns this much less than the healthy running it is given (its blocks are final
a block late)."""


def cli_command(*args: str) -> list[str]:
    """A drafttwin command in a process of its own (this interpreter)."""
    return [sys.executable, "-m", "drafttwin", *args]


def run_command(cmd: list[str]) -> None:
    """Run a child command to its end; its error's last lines as a :class:`RunError`."""
    done = subprocess.run(cmd, capture_output=True, text=True, check=False, env=child_env())
    if done.returncode != 0:
        raise RunError(f"'{' '.join(cmd[3:6])}' failed: {done.stderr.strip()[-300:]}")


def child_env() -> dict[str, str]:
    """The children's environment: one OpenMP thread each (they share the cores)."""
    return {**os.environ, "OMP_NUM_THREADS": "1"}


def twin_status(http: int) -> dict[str, Any] | None:
    """The twin's ``/api/status`` on 127.0.0.1:``http``, or ``None`` while it does not answer."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{http}/api/status", timeout=10) as r:  # noqa: S310  the twin this run started, on 127.0.0.1
            doc: dict[str, Any] = json.loads(r.read())
            return doc
    except (OSError, ValueError):
        return None


def wait_live(http: int, twin: subprocess.Popen[bytes], names: set[str]) -> None:
    """Until the twin answers and its source is subscribed (at most two minutes)."""
    deadline = time.monotonic() + 120.0
    while time.monotonic() < deadline:
        if twin.poll() is not None:
            raise RunError(f"the twin ended at its start (exit {twin.returncode}); see twin.log")
        status = twin_status(http)
        # subscribed: 'waiting' until the first sample (the replay starts after this), 'live'
        if status and all(status["machines"].get(n, {}).get("state") in ("waiting", "live")
                          for n in names):  # fmt: skip
            return
        time.sleep(0.5)
    raise RunError("the twin did not connect to the broker within two minutes")


@contextlib.contextmanager
def child_process(cmd: list[str], log: Path) -> Iterator[subprocess.Popen[bytes]]:
    """A child process writing to ``log``, ended (SIGTERM, then kill) if still running."""
    with log.open("wb") as f:
        p = subprocess.Popen(
            cmd, stdout=f, stderr=subprocess.STDOUT, env=child_env(), preexec_fn=die_with_parent()
        )
        try:
            yield p
        finally:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()


@contextlib.contextmanager
def broker() -> Iterator[int]:
    """A broker on 127.0.0.1 for the run: Mosquitto when installed, else the embedded one in
    a thread of this process; its port."""
    port = free_port()
    exe = shutil.which("mosquitto") or (
        "/usr/sbin/mosquitto" if Path("/usr/sbin/mosquitto").exists() else None
    )
    if exe is not None:
        with tempfile.TemporaryDirectory() as tmp:
            conf = Path(tmp) / "mosquitto.conf"
            conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\n"
                            "max_queued_messages 0\n", encoding="utf-8")  # fmt: skip
            with child_process([exe, "-c", str(conf)], Path(tmp) / "mosquitto.log"):
                _wait_port(port)
                yield port
        return
    yield from _embedded_broker(port)


def _embedded_broker(port: int) -> Iterator[int]:
    import asyncio

    from drafttwin.plant.serve.mqtt import start_broker

    loop = asyncio.new_event_loop()
    ready = threading.Event()
    holder: dict[str, Any] = {}

    def run() -> None:
        asyncio.set_event_loop(loop)
        holder["broker"] = loop.run_until_complete(start_broker("127.0.0.1", port))
        ready.set()
        loop.run_forever()

    thread = threading.Thread(target=run, daemon=True, name="mqtt-broker")
    thread.start()
    ready.wait(30)
    try:
        yield port
    finally:
        if "broker" in holder:
            asyncio.run_coroutine_threadsafe(holder["broker"].shutdown(), loop).result(10)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)


def _wait_port(port: int) -> None:
    import socket

    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.5):
            return
        time.sleep(0.1)
    raise RunError(f"the broker did not open port {port}")


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def twin_events(store: Path) -> list[dict[str, Any]]:
    """The twin's events, read back with ``twin query``."""
    # one file per store: the replay's and the plant's runs share a folder
    target = store.parent / f"{store.name}_events.parquet"
    run_command(
        cli_command("twin", "query", "--store", str(store), "--events", "--out", str(target))
    )
    import pandas as pd

    frame = pd.read_parquet(target)
    return frame.to_dict("records")  # type: ignore[no-any-return]
