"""``drafttwin plant serve``: live plants published as an OPC UA server (asyncua).

Address space, per machine ``NAME`` (namespace ``urn:drafttwin:plant``, index 2)::

    Objects/Machines/NAME/
        sample               ns=2;s=NAME.sample        Double[8]: seq, time, front, second,
                                                       third, back, motor, supply_hz
        front_rpm ... back_rpm, motor_rpm, supply_hz   ns=2;s=NAME.front_rpm ... (scalars)
        supply_setpoint_hz   ns=2;s=NAME.supply_setpoint_hz   writable: the VFD set-point

The twin subscribes to ``sample`` (one notification per tick carrying the whole row and its
counter; see docs/twin.md for why); the scalars are for people and SCADA clients. A written
set-point is checked (a number from 0 to 120 Hz) and applied at the next tick; anything else
is refused and the node is set back.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drafttwin.errors import ConfigError
from drafttwin.plant.faults import FaultSpec
from drafttwin.plant.live import LivePlant, LiveSample

NAMESPACE = "urn:drafttwin:plant"
SCALARS = ("front_rpm", "second_rpm", "third_rpm", "back_rpm", "motor_rpm", "supply_hz")


@dataclass
class ServedMachine:
    name: str
    plant: LivePlant
    sample_node: Any
    setpoint_node: Any
    scalars: list[Any]
    last_setpoint: float
    refused: int = 0


def parse_opcua_url(text: str) -> tuple[str, int]:
    if not text.startswith("opc.tcp://"):
        raise ConfigError(f"bad OPC UA address {text!r}", where="--opcua",
                          fix="write opc.tcp://127.0.0.1:4840")  # fmt: skip
    host, _, port = text.removeprefix("opc.tcp://").rstrip("/").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"bad OPC UA address {text!r}", where="--opcua",
                          fix="write opc.tcp://HOST:PORT, e.g. opc.tcp://127.0.0.1:4840")  # fmt: skip
    return host, int(port)


async def _add_machine(
    server: Any, idx: int, parent: Any, name: str, plant: LivePlant
) -> ServedMachine:
    from asyncua import ua

    obj = await parent.add_object(_nid(idx, f"{name}"), f"{idx}:{name}")
    sample = await obj.add_variable(_nid(idx, f"{name}.sample"), f"{idx}:sample",
                                    [0.0] * 8, varianttype=ua.VariantType.Double)  # fmt: skip
    scalars = [await obj.add_variable(_nid(idx, f"{name}.{s}"), f"{idx}:{s}", 0.0)
               for s in SCALARS]  # fmt: skip
    sp = await obj.add_variable(_nid(idx, f"{name}.supply_setpoint_hz"),
                                f"{idx}:supply_setpoint_hz", plant.target_hz)  # fmt: skip
    await sp.set_writable()
    return ServedMachine(name, plant, sample, sp, scalars, plant.target_hz)


async def serve_opcua(
    url: str,
    names: list[str],
    *,
    seed: int = 0,
    rate_hz: float = 100.0,
    physics: str = "full",
    ramp_hz_per_s: float = 10.0,
    duration_s: float | None = None,
    scalar_nodes: bool = True,
    on_sample: Callable[[str, LiveSample], None] | None = None,
    ready: Callable[[], None] | None = None,
    cert_dir: Path | None = None,
    history_s: float = 0.0,
    faults: Sequence[FaultSpec] = (),
) -> dict[str, int]:
    """Serve ``names`` live plants at ``url`` until ``duration_s`` (or cancelled); returns
    the samples published per machine. With ``history_s`` the server keeps each machine's
    samples of the last ``history_s`` seconds for OPC UA HistoryRead (in memory), so that a
    restarted twin recovers what was published while it was down."""
    from asyncua import Server, ua

    host, port = parse_opcua_url(url)
    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://{host}:{port}/")
    server.set_server_name("drafttwin plant")
    if cert_dir is None:
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    else:
        from drafttwin.twin.security import secure_server

        await secure_server(server, cert_dir)
    idx = await server.register_namespace(NAMESPACE)
    if idx != 2:
        raise RuntimeError(f"namespace index {idx}, expected 2")
    folder = await server.nodes.objects.add_folder(_nid(idx, "Machines"), f"{idx}:Machines")
    machines = []
    for k, name in enumerate(names):
        plant = LivePlant(
            seed + k, rate_hz, physics=physics, ramp_hz_per_s=ramp_hz_per_s, faults=faults
        )
        machines.append(await _add_machine(server, idx, folder, name, plant))
    async with server:
        if history_s > 0:
            import datetime as dt

            period = dt.timedelta(seconds=history_s)
            for m in machines:
                await server.historize_node_data_change(m.sample_node, period=period)
        t0 = time.time()  # the clocks start when the machines run, not while they were built
        for m in machines:
            m.plant.t0_s = t0
        if ready is not None:
            ready()
        return await _tick(machines, rate_hz, t0, duration_s, scalar_nodes, on_sample)


async def _tick(machines: list[ServedMachine], rate_hz: float, t0: float, duration_s: float | None,
                scalar_nodes: bool, on_sample: Callable[[str, LiveSample], None] | None) -> dict[str, int]:  # fmt: skip
    """Step every plant at its sample instants (wall clock), publish, apply set-points."""
    from asyncua import ua

    k = 0
    start = time.monotonic() - (time.time() - t0)
    end = math.inf if duration_s is None else duration_s * rate_hz
    while k < end:
        k += 1
        delay = start + k / rate_hz - time.monotonic()
        # always yield: a loop behind schedule must still let the others run
        await asyncio.sleep(max(delay, 0.0))
        for m in machines:
            await _apply_setpoint(m)
            s = m.plant.step()
            row = [float(s.seq), s.time_s, *map(float, s.rollers_rpm), s.motor_rpm, s.supply_hz]
            stamp = ua.DataValue(ua.Variant(row, ua.VariantType.Double),
                                 SourceTimestamp=_utc(s.time_s))  # fmt: skip
            await m.sample_node.write_value(stamp)
            if scalar_nodes:
                for node, v in zip(m.scalars, row[2:], strict=True):
                    await node.write_value(float(v))
            if on_sample is not None:
                on_sample(m.name, s)
    return {m.name: m.plant.seq for m in machines}


async def _apply_setpoint(m: ServedMachine) -> None:
    value = await m.setpoint_node.read_value()
    if value == m.last_setpoint:
        return
    try:
        m.plant.set_supply(float(value))
        m.last_setpoint = value
    except (ConfigError, TypeError, ValueError):
        m.refused += 1
        with contextlib.suppress(Exception):
            await m.setpoint_node.write_value(float(m.last_setpoint))


def _nid(idx: int, name: str) -> Any:
    from asyncua import ua

    return ua.NodeId.from_string(f"ns={idx};s={name}")


def _utc(t: float) -> Any:
    import datetime as dt

    return dt.datetime.fromtimestamp(t, tz=dt.UTC)


__all__ = ["NAMESPACE", "SCALARS", "parse_opcua_url", "serve_opcua"]
