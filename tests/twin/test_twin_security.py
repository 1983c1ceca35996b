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
