"""OPC UA security, the twin's side: its client certificate and Basic256Sha256 SignAndEncrypt.

The certificates (``drafttwin twin certs --out DIR``) and the plant server's side live in
:mod:`drafttwin.wire.certs` (the plant sits below the twin); what is written where is
described there. The twin connects with ``--source "opcua:URL?cert=DIR"``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from drafttwin.wire.certs import (
    CLIENT_URI,
    SERVER_URI,
    make_certificates,
    need_files,
    secure_server,
)

_need = need_files  # the name sources.spec uses


async def secure_client(client: Any, folder: Path) -> None:
    """The twin's side: its certificate, the server's, SignAndEncrypt."""
    need_files(folder, "client_key.pem", "client_cert.der", "server_cert.der")
    client.application_uri = CLIENT_URI
    await client.set_security_string(
        f"Basic256Sha256,SignAndEncrypt,{folder / 'client_cert.der'},"
        f"{folder / 'client_key.pem'},{folder / 'server_cert.der'}"
    )


__all__ = ["SERVER_URI", "make_certificates", "secure_client", "secure_server"]
