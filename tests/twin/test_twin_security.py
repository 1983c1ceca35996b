"""OPC UA with Basic256Sha256 SignAndEncrypt: the twin with its certificate gets the samples;
a client without security, or with a certificate the server does not trust, gets nothing."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
from pathlib import Path

import pytest

from drafttwin.twin.aio import run_bounded
from drafttwin.twin.build import build_service
from drafttwin.wire.certs import make_certificates

from ._twin import cli, env, free_port

pytestmark = pytest.mark.timeout(150)


def _received(model: Path, source: str, seconds: float) -> tuple[int, str]:
    service = build_service(model, [source])
    run_bounded(service.run(duration_s=seconds))
    st = service.states["fa320a"]
    return st.received, st.state


@pytest.mark.slow  # a server and three client connections: about 20 s
def test_secured_server_serves_only_trusted_clients(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    _, model = twin_files
    certs, stranger = tmp_path / "certs", tmp_path / "stranger"
    asyncio.run(make_certificates(certs))
    asyncio.run(make_certificates(stranger))  # a valid certificate the server never trusted
    shutil.copyfile(certs / "server_cert.der", stranger / "server_cert.der")
    url = f"opc.tcp://127.0.0.1:{free_port()}"
    proc = subprocess.Popen(cli("plant", "serve", "--opcua", url, "--cert", str(certs),
                                "--duration", "60", "--physics", "reduced"), env=env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert "serving fa320a" in line, line + proc.stderr.read()
        trusted = _received(model, f"opcua:{url}?cert={certs}", 3.0)
        plain = _received(model, f"opcua:{url}", 2.0)
        foreign = _received(model, f"opcua:{url}?cert={stranger}", 2.0)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert trusted[0] > 100 and trusted[1] == "live"
    assert plain == (0, "reconnecting")
    assert foreign == (0, "reconnecting")


def test_wrong_tokens_are_limited_per_client(monkeypatch: pytest.MonkeyPatch) -> None:
    # 300 guesses had each been answered at once with 401: no limit on guessing (the guard
    # answers 429 while a client is locked, before it compares the token)
    from drafttwin.twin.web import guard as guard_module

    now = [1000.0]
    monkeypatch.setattr(guard_module.time, "monotonic", lambda: now[0])
    failures = guard_module.FailedTokens()
    locked = []
    for _ in range(guard_module.FAILED_BURST + 2):
        locked.append(failures.locked("10.0.0.1"))
        if not locked[-1]:
            failures.failed("10.0.0.1")
    assert locked == [False] * guard_module.FAILED_BURST + [True, True]
    assert not failures.locked("10.0.0.2")  # another client is not
    now[0] += guard_module.FAILED_REFILL_S  # one more try after the refill time
    assert not failures.locked("10.0.0.1")
    failures.failed("10.0.0.1")
    assert failures.locked("10.0.0.1")


def test_an_acknowledgement_that_takes_nothing_stores_nothing() -> None:
    # a client in a loop had stored an alarm-ack event (and printed a console line) per
    # request, with nothing to acknowledge or the same alarm again
    from types import SimpleNamespace

    from drafttwin.diagnosis.cusum import Alarm
    from drafttwin.twin.faults import FaultDesk

    events: list = []
    host = SimpleNamespace(states={"m": object()}, subscribers=[], metrics=None, loop=None,
                           event=lambda st, ev: events.append(ev))  # fmt: skip
    desk = FaultDesk(host)  # type: ignore[arg-type]
    assert desk.acknowledge("m") == 0 and events == []
    alarm = Alarm(time_s=10.0, block=10, test="belt", direction=1, change_s=9.0)
    desk.book.raised("m", alarm, "fault")
    assert desk.acknowledge("m", confirm=True) == 0 and events == []  # acknowledge first
    assert desk.acknowledge("m") == 1 and len(events) == 1
    assert desk.acknowledge("m") == 0 and len(events) == 1  # the same again: nothing
    assert desk.acknowledge("m", confirm=True) == 1 and len(events) == 2
    assert desk.acknowledge("m", confirm=True) == 0 and len(events) == 2


def test_certs_keep_what_is_valid_and_keys_are_the_owners(tmp_path: Path) -> None:
    """A second 'twin certs' had replaced the MQTT TLS certificate (its clients then failed
    verification) and the OPC UA keys were 0644; an empty or 70-character --host ended in a
    traceback with half the folder written."""
    from typer.testing import CliRunner

    from drafttwin.cli import app

    certs = tmp_path / "certs"
    written, kept = asyncio.run(make_certificates(certs))
    assert len(written) == 6 and kept == []
    first = {p.name: p.read_bytes() for p in written}
    for key in ("server_key.pem", "client_key.pem", "mqtt_key.pem"):
        assert (certs / key).stat().st_mode & 0o077 == 0, key
    written, kept = asyncio.run(make_certificates(certs))
    assert written == [] and len(kept) == 6
    assert {p.name: p.read_bytes() for p in kept} == first
    written, _ = asyncio.run(make_certificates(certs, "localhost"))  # another host: new ones
    assert {"mqtt_cert.pem", "server_cert.der"} <= {p.name for p in written}
    for host in ("", "a" * 70, "bad host"):
        res = CliRunner().invoke(
            app, ["twin", "certs", "--out", str(tmp_path / "c"), "--host", host]
        )
        assert res.exit_code == 2 and "--host" in res.output and "Traceback" not in res.output
        assert not (tmp_path / "c" / "server_key.pem").exists()


def test_a_security_mismatch_says_what_to_do(tmp_path: Path) -> None:
    """An unsecured twin at a secured server read "UaError: No matching endpoints ..."; a
    ?cert= naming a file said "--cert" (twin run has none) and to make certificates there."""
    from drafttwin.errors import ConfigError
    from drafttwin.twin.sources.mapping import MachineMap
    from drafttwin.twin.sources.opcua import _reason
    from drafttwin.twin.sources.spec import parse_source

    default = MachineMap("fa320a", ("front", "second", "third", "back"))

    exc = RuntimeError("No matching endpoints: 1, http://opcfoundation.org/UA/SecurityPolicy#None")
    assert _reason(exc, secured=False).startswith("the server accepts secured sessions only: "
                                                  "add ?cert=DIR to --source")  # fmt: skip
    assert _reason(exc, secured=True).startswith("RuntimeError: No matching endpoints")
    afile = tmp_path / "rec.json"
    afile.write_text("{}")
    with pytest.raises(ConfigError, match=r"--source \(\?cert=\).*is not a folder of certificates"):
        parse_source(f"opcua:opc.tcp://127.0.0.1:4840?cert={afile}", default, ())
    with pytest.raises(ConfigError, match=r"--source \(\?cert=\).*no client_key.pem"):
        parse_source(f"opcua:opc.tcp://127.0.0.1:4840?cert={tmp_path}", default, ())
