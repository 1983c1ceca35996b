"""A source's text (``--source``) parsed into a :class:`~drafttwin.twin.sources.base.Source`.

Apart from the kinds because it builds every one, the MQTT source of
:mod:`~drafttwin.twin.sources.mqtt` among them, which itself builds on
:mod:`~drafttwin.twin.sources.base`.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from urllib.parse import SplitResult, parse_qs, urlsplit

from drafttwin.errors import ConfigError, DataError
from drafttwin.twin.sources.base import Source
from drafttwin.twin.sources.mapping import MachineMap
from drafttwin.twin.sources.opcua import OpcUaSource
from drafttwin.twin.sources.replay import ReplaySource


def parse_source(text: str, default: MachineMap, mapped: tuple[MachineMap, ...]) -> Source:
    """``replay:FILE?speed=10&machine=NAME``, ``opcua:opc.tcp://HOST:PORT``,
    ``mqtt://HOST:PORT`` into a source (its machines from the mapping, or ``default``).
    ``shard=I/K`` (OPC UA, MQTT) keeps one shard of the mapping's machines; ``share=GROUP``
    (MQTT) subscribes as a member of a shared subscription."""
    kind, _, rest = text.partition(":")
    if kind == "replay":
        path, _, query = rest.partition("?")
        opts = _query(query, text, {"speed", "machine"})
        speed = _speed(opts.get("speed", "1"), text)
        name = opts.get("machine", Path(path).stem)
        machine = next((m for m in mapped if m.name == name), default.renamed(name))
        if not Path(path).is_file():
            raise DataError("file not found", source=path, where="--source",
                            fix="replay a file 'drafttwin generate --out FILE' wrote")  # fmt: skip
        return ReplaySource(Path(path), machine, speed)
    if kind == "opcua":
        url = rest.split("?", 1)[0]
        opts = _query(rest.partition("?")[2], text, {"machine", "publish_ms", "cert", "shard"})
        if not url.startswith("opc.tcp://"):
            raise ConfigError(f"bad OPC UA address {url!r}", where="--source",
                              fix="write opcua:opc.tcp://HOST:PORT")  # fmt: skip
        _check_host_port(urlsplit(url), text, "opcua:opc.tcp://HOST:PORT")
        machines = mapped or (default.renamed(opts.get("machine", default.name)),)
        machines = select_shard(machines, opts.get("shard"), text)
        cert = Path(opts["cert"]) if "cert" in opts else None
        if cert is not None:
            from drafttwin.twin.sources.security import _need

            _need(cert, "client_key.pem", "client_cert.der", "server_cert.der",
                  where="--source (?cert=)")  # fmt: skip
        return OpcUaSource(url, machines, float(opts.get("publish_ms", 10)), cert)
    if kind in ("mqtt", "mqtts"):
        from drafttwin.twin.sources.mqtt import MqttSource  # paho only when MQTT is asked for

        parts = urlsplit(text)
        _check_host_port(parts, text, f"{kind}://[USER@]HOST:PORT")
        opts = _query(parts.query, text, {"machine", "cert", "share", "shard"})
        ca = None
        if kind == "mqtts":
            if "cert" not in opts:
                raise ConfigError("mqtts needs the broker's certificate", where="--source",
                                  fix="write mqtts://HOST:PORT?cert=DIR (drafttwin twin certs)")  # fmt: skip
            ca = Path(opts["cert"]) / "mqtt_cert.pem"
            if not ca.is_file():
                raise DataError("file not found", source=ca, where="--source",
                                fix=f"make it with: drafttwin twin certs --out {opts['cert']}")  # fmt: skip
        machines = mapped or (default.renamed(opts.get("machine", default.name)),)
        machines = select_shard(machines, opts.get("shard"), text)
        share = opts.get("share")
        if share is not None and (not share or any(c in share for c in "/+#")):
            raise ConfigError(f"bad share group {share!r} in {text!r}", where="--source",
                              fix="name the group without '/', '+' or '#', e.g. share=hall")  # fmt: skip
        password = os.environ.get("DRAFTTWIN_MQTT_PASSWORD") if parts.username else None
        if parts.username and not password:
            raise ConfigError(f"no password for MQTT user {parts.username!r}", where="--source",
                              fix="set DRAFTTWIN_MQTT_PASSWORD (kept out of the command line)")  # fmt: skip
        return MqttSource(parts.hostname or "127.0.0.1", parts.port or 1883, machines,
                          parts.username, password, ca, share=share)  # fmt: skip
    raise ConfigError(f"unknown source {text!r}", where="--source",
                      fix="use replay:FILE?speed=10, opcua:opc.tcp://HOST:PORT or "
                      "mqtt://[USER@]HOST:PORT")  # fmt: skip


def _check_host_port(parts: SplitResult, text: str, form: str) -> None:
    """A host, and a port that is a number from 1 to 65535 where one is written (a typo had
    been a traceback, or a source that retried the bad address for the whole run)."""
    try:
        port = parts.port
    except ValueError:
        port = 0
    written = parts.netloc.rpartition("@")[2]
    if not parts.hostname or port == 0 or (port is None and written.endswith(":")):
        raise ConfigError(f"bad address {text!r}: no host, or a port that is not a number from "
                          "1 to 65535", where="--source", fix=f"write {form}")  # fmt: skip


def select_shard(machines: tuple[MachineMap, ...], shard: str | None,
                 text: str) -> tuple[MachineMap, ...]:  # fmt: skip
    """``shard=I/K``: the machines at positions I, I+K, I+2K... of the mapping (every process
    of a hall reads the same mapping, so the K shards split it exactly, each machine whole)."""
    if shard is None:
        return machines
    i_text, _, k_text = shard.partition("/")
    ok = i_text.isdigit() and k_text.isdigit() and 0 <= int(i_text) < int(k_text) <= 10_000
    if not ok:
        raise ConfigError(f"bad shard {shard!r} in {text!r}", where="--source",
                          fix="write shard=I/K with 0 <= I < K, e.g. shard=0/4")  # fmt: skip
    chosen = machines[int(i_text) :: int(k_text)]
    if not chosen:
        raise ConfigError(f"shard {shard} of {len(machines)} machine(s) is empty", where="--source",
                          fix="use at most as many shards as the mapping has machines")  # fmt: skip
    return chosen


def _query(query: str, text: str, allowed: set[str]) -> dict[str, str]:
    opts = {k: v[-1] for k, v in parse_qs(query, keep_blank_values=True).items()}
    unknown = sorted(set(opts) - allowed)
    if unknown:
        raise ConfigError(f"unknown option(s) {unknown} in {text!r}", where="--source",
                          fix=f"use {', '.join(sorted(allowed))}")  # fmt: skip
    return opts


def _speed(value: str, text: str) -> float:
    if value in ("max", "inf"):
        return math.inf
    try:
        speed = float(value)
    except ValueError:
        speed = math.nan
    if not (math.isfinite(speed) and 0 < speed <= 1e6):
        raise ConfigError(f"speed={value!r} in {text!r}", where="--source",
                          fix="speed must be > 0 and <= 1e6 (or 'max')")  # fmt: skip
    return speed


__all__ = ["parse_source", "select_shard"]
