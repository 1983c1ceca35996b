"""``drafttwin plant serve --opcua``: live plants published as an OPC UA server (asyncua).

Address space (namespace ``urn:drafttwin:plant``, index 2; docs/twin.md, "The plant's OPC UA
address space")::

    Objects/Machines/NAME/                 one object per machine (OPC 40001 Machinery style)
        Identification/                    Manufacturer, Model, SerialNumber, ProductInstanceUri,
                                           SoftwareRevision, ComponentName
        MachineryBuildingBlocks/MachineryItemState/CurrentState    Executing | NotExecuting
        sample          ns=2;s=NAME.sample Double[8]: seq, time, front, second, third, back,
                                           motor, supply_hz (ArrayDimensions [8]; FieldNames,
                                           FieldUnits properties)
        front_rpm ... back_rpm, motor_rpm, supply_hz     AnalogItemType: EngineeringUnits
                                           (UNECE), EURange, ValuePrecision
        supply_setpoint_hz                 AnalogItemType, writable: the VFD set-point
        lag_s                              AnalogItemType: how late the last sample went out
        Sliver/, Leveller/                 with --sliver: the sliver sensors' readings and the
                                           leveller's setting (:mod:`.sliver`)

Every value of one tick carries the sample's own time as SourceTimestamp. The twin subscribes
to ``sample`` (one notification per tick carrying the whole row and its counter); the scalars
are for people and SCADA clients. A written set-point is checked (a number from 0 to 120 Hz)
and applied from the next sample computed (the physics runs up to 0.2 s ahead of the wall
clock, :mod:`~drafttwin.plant.serve.feed`); anything else is answered BadOutOfRange to the
client that wrote it and not written (a warning on the plant's stderr).

The node layout follows OPC 40001-1 (Machinery) where it applies, with browse names of its
namespace's meaning but in this server's namespace: the Machinery and DI nodesets are not
loaded (asyncua ships neither), so the objects are typed BaseObjectType, not
MachineIdentificationType / MachineryItemState_StateMachineType.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drafttwin.errors import ConfigError
from drafttwin.plant.faults import FaultSpec
from drafttwin.plant.live import MAX_SUPPLY_HZ, LivePlant, LiveSample
from drafttwin.plant.serve.channels import as_published, plant_channels, values_of
from drafttwin.plant.serve.feed import AHEAD_S, Feed
from drafttwin.plant.serve.opcua_nodes import analog_item, describe, nid
from drafttwin.plant.serve.pacing import Pacing, catch_up
from drafttwin.wire.certs import SERVER_URI
from drafttwin.wire.conventions import (
    HERTZ,
    SAMPLE_FIELDS,
    SECOND,
    UNITLESS,
    Channel,
    utc,
)
from drafttwin.wire.identity import (
    MANUFACTURER,
    PLANT_MODEL,
    PLANT_PRODUCT_URI,
    machine_uri,
    plant_serial,
)

NAMESPACE = "urn:drafttwin:plant"
SCALARS = ("front_rpm", "second_rpm", "third_rpm", "back_rpm", "motor_rpm", "supply_hz")
PRODUCT_URI = PLANT_PRODUCT_URI
MODEL = PLANT_MODEL


@dataclass
class ServedMachine:
    name: str
    plant: LivePlant
    sample_node: Any
    setpoint_node: Any
    scalars: list[Any]
    last_setpoint: float
    state_node: Any
    lag_node: Any
    channels: tuple[Channel, ...]
    refused: int = 0
    executing: bool | None = None
    obj: Any = None  # the machine's object node
    sliver: Any = None  # its LiveSliver (plant serve --sliver)
    sliver_nodes: Any = None


def parse_opcua_url(text: str) -> tuple[str, int]:
    if not text.startswith("opc.tcp://"):
        bare = text.partition("://")[2] or text  # the user's own host and port, if any
        raise ConfigError(f"bad OPC UA address {text!r}", where="--opcua",
                          fix=f"write opc.tcp://{bare}" if ":" in bare and "/" not in bare
                          else "write opc.tcp://HOST:PORT, e.g. opc.tcp://127.0.0.1:4840")  # fmt: skip
    host, _, port = text.removeprefix("opc.tcp://").rstrip("/").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"bad OPC UA address {text!r}", where="--opcua",
                          fix="write opc.tcp://HOST:PORT, e.g. opc.tcp://127.0.0.1:4840")  # fmt: skip
    return host, int(port)


async def _identification(obj: Any, idx: int, name: str, seed: int) -> None:
    """OPC 40001-1 §8 identification (the mandatory Manufacturer, SerialNumber and
    ProductInstanceUri, and Model, SoftwareRevision, ComponentName)."""
    from asyncua import ua

    from drafttwin._constants import __version__

    ident = await obj.add_object(nid(idx, f"{name}.Identification"), f"{idx}:Identification")
    props: list[tuple[str, Any, Any]] = [
        ("Manufacturer", ua.LocalizedText(MANUFACTURER), ua.VariantType.LocalizedText),
        ("Model", ua.LocalizedText(MODEL), ua.VariantType.LocalizedText),
        ("SerialNumber", plant_serial(seed), ua.VariantType.String),
        ("ProductInstanceUri", machine_uri(plant_serial(seed)), ua.VariantType.String),
        ("SoftwareRevision", __version__, ua.VariantType.String),
        ("ComponentName", ua.LocalizedText(name), ua.VariantType.LocalizedText),
    ]
    for prop, value, vtype in props:
        await ident.add_property(nid(idx, f"{name}.Identification.{prop}"), f"{idx}:{prop}",
                                 value, varianttype=vtype)  # fmt: skip


async def _add_machine(server: Any, idx: int, parent: Any, name: str, plant: LivePlant,
                       seed: int) -> ServedMachine:  # fmt: skip
    from asyncua import ua

    channels = plant_channels(plant)
    obj = await parent.add_object(nid(idx, name), f"{idx}:{name}")
    await describe(obj, f"{MODEL} {name}, live (drafttwin plant serve)")
    await _identification(obj, idx, name, seed)
    blocks = await obj.add_object(nid(idx, f"{name}.MachineryBuildingBlocks"),
                                  f"{idx}:MachineryBuildingBlocks")  # fmt: skip
    item_state = await blocks.add_object(nid(idx, f"{name}.MachineryItemState"),
                                         f"{idx}:MachineryItemState")  # fmt: skip
    state = await item_state.add_variable(nid(idx, f"{name}.MachineryItemState.CurrentState"),
                                          f"{idx}:CurrentState", ua.LocalizedText("NotExecuting"))  # fmt: skip
    sample = await obj.add_variable(nid(idx, f"{name}.sample"), f"{idx}:sample",
                                    [0.0] * len(SAMPLE_FIELDS), varianttype=ua.VariantType.Double)  # fmt: skip
    await sample.write_array_dimensions([len(SAMPLE_FIELDS)])
    await sample.write_value_rank(1)
    await describe(sample, "one sample: " + ", ".join(SAMPLE_FIELDS) + " (time: epoch s)")
    units = {c.name: c.unit.symbol for c in channels} | {"seq": UNITLESS.symbol, "time": "s"}
    await sample.add_property(nid(idx, f"{name}.sample.FieldNames"), f"{idx}:FieldNames",
                              list(SAMPLE_FIELDS), varianttype=ua.VariantType.String)  # fmt: skip
    await sample.add_property(nid(idx, f"{name}.sample.FieldUnits"), f"{idx}:FieldUnits",
                              [units[f] for f in SAMPLE_FIELDS], varianttype=ua.VariantType.String)  # fmt: skip
    scalars = [await analog_item(obj, idx, f"{name}.{s}", s, 0.0, c.unit, c.eu_range,
                                 c.description, c.decimals)
               for s, c in zip(SCALARS, channels, strict=True)]  # fmt: skip
    sp = await analog_item(obj, idx, f"{name}.supply_setpoint_hz", "supply_setpoint_hz",
                           plant.target_hz, HERTZ, (0.0, MAX_SUPPLY_HZ),
                           "VFD supply set-point (write to change the speed)", 2)  # fmt: skip
    await sp.set_writable()
    lag = await analog_item(obj, idx, f"{name}.lag_s", "lag_s", 0.0, SECOND, (0.0, 10.0),
                            "how late the last sample went out: wall clock minus its time")  # fmt: skip
    return ServedMachine(name, plant, sample, sp, scalars, plant.target_hz, state, lag, channels,
                         obj=obj)  # fmt: skip


async def _identify_server(server: Any, secure: bool) -> None:
    """The server's own identity: application URI, product URI, name, manufacturer, build."""
    from drafttwin._constants import __version__

    if not secure:  # secure_server sets the URI its certificate names
        await server.set_application_uri(SERVER_URI)
    await server.set_build_info(PRODUCT_URI, MANUFACTURER, "drafttwin plant", __version__,
                                __version__, dt.datetime.now(dt.UTC))  # fmt: skip


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
    pacing: Pacing | None = None,
    ahead_s: float = AHEAD_S,
    sliver: Any = None,
    on_sliver: Callable[[Any, Any], None] | None = None,
) -> dict[str, int]:
    """Serve ``names`` live plants at ``url`` until ``duration_s`` (or cancelled); returns
    the samples published per machine. With ``history_s`` the server keeps each machine's
    samples of the last ``history_s`` seconds for OPC UA HistoryRead (in memory), so that a
    restarted twin recovers what was published while it was down. ``pacing`` keeps the wall
    clock and records lateness (a default one when ``None``). The physics is computed up to
    ``ahead_s`` ahead in a worker thread (:mod:`~drafttwin.plant.serve.feed`). ``sliver``
    (plant :class:`~drafttwin.plant.sliver_channel.SliverSettings`) makes each machine's sliver
    and publishes its sensors (:mod:`.sliver`); ``on_sliver(live_sliver, batch)`` is called
    after each batch."""
    from asyncua import Server, ua

    host, port = parse_opcua_url(url)
    server = Server()
    server.name, server.manufacturer_name, server.product_uri = (
        "drafttwin plant", MANUFACTURER, PRODUCT_URI)  # fmt: skip
    await server.init()
    server.set_endpoint(f"opc.tcp://{host}:{port}/")
    server.set_server_name("drafttwin plant")
    if cert_dir is None:
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    else:
        from drafttwin.wire.certs import secure_server

        await secure_server(server, cert_dir)
    await _identify_server(server, cert_dir is not None)
    idx = await server.register_namespace(NAMESPACE)
    if idx != 2:
        raise RuntimeError(f"namespace index {idx}, expected 2")
    folder = await server.nodes.objects.add_folder(nid(idx, "Machines"), f"{idx}:Machines")
    machines = []
    for k, name in enumerate(names):
        plant = LivePlant(seed + k, rate_hz, physics=physics, ramp_hz_per_s=ramp_hz_per_s,
                          faults=faults)  # fmt: skip
        served = await _add_machine(server, idx, folder, name, plant, seed + k)
        if sliver is not None:  # before the feed's worker computes ahead
            from drafttwin.plant.live_sliver import LiveSliver
            from drafttwin.plant.serve.sliver import add_sliver_nodes

            served.sliver = LiveSliver(plant, sliver, seed + k, name)
            served.sliver_nodes = await add_sliver_nodes(served.obj, idx, name, served.sliver)
        machines.append(served)
    _refuse_bad_setpoints(server, {m.setpoint_node.nodeid for m in machines})
    pacing = pacing if pacing is not None else Pacing(rate_hz)
    async with server:
        if history_s > 0:
            period = dt.timedelta(seconds=history_s)
            for m in machines:
                await server.historize_node_data_change(m.sample_node, period=period)
        with Feed([m.plant for m in machines], rate_hz, ahead_s=ahead_s) as feed:
            t0 = pacing.start()  # the clocks start when the machines run, not while built
            for m in machines:
                m.plant.t0_s = t0
            if ready is not None:
                ready()
            return await _tick(server, machines, pacing, feed, duration_s, scalar_nodes,
                               on_sample, on_sliver)  # fmt: skip


async def _tick(server: Any, machines: list[ServedMachine], pacing: Pacing, feed: Feed,
                duration_s: float | None, scalar_nodes: bool,
                on_sample: Callable[[str, LiveSample], None] | None,
                on_sliver: Callable[[Any, Any], None] | None = None) -> dict[str, int]:  # fmt: skip
    """Publish every plant's samples at their instants (wall clock), apply set-points."""
    end = None if duration_s is None else round(duration_s * pacing.rate_hz)
    pacing.end_tick = feed.end = end
    while end is None or pacing.tick < end:
        skip = await pacing.next_tick()
        await catch_up([m.plant for m in machines], skip, pacing.rate_hz)
        now: Any = dt.datetime.now(dt.UTC)
        t_s = 0.0
        for m in machines:
            await _apply_setpoint(server, m)
            s = as_published(m.plant.step(), m.channels)
            t_s = s.time_s
            await _publish(server, m, s, scalar_nodes, now)
            if on_sample is not None:
                on_sample(m.name, s)
            batch = None if m.sliver is None else m.sliver.after()
            if batch is not None:
                from drafttwin.plant.serve.sliver import publish_sliver_opcua

                await publish_sliver_opcua(m.sliver_nodes, batch)
                if on_sliver is not None:
                    on_sliver(m.sliver, batch)
        feed.took()
        lag = pacing.published(t_s)
        if skip or pacing.tick % max(1, round(pacing.rate_hz)) == 0:  # once a second
            for m in machines:
                await m.lag_node.write_value(round(lag, 4))
    return {m.name: m.plant.seq for m in machines}


async def _publish(server: Any, m: ServedMachine, s: LiveSample, scalar_nodes: bool,
                   now: Any) -> None:  # fmt: skip
    """Write one sample: the array and (optionally) the scalars, all stamped with its time.
    Written into the address space directly (``write_attribute_value``: what a Node's write
    does without building a request and checking a user's rights, 12 instead of 32 us), with
    the server time a client's write gets."""
    from asyncua import ua

    stamp: Any = utc(s.time_s)  # asyncua's stubs name their own DateTime alias
    row = [float(s.seq), s.time_s, *map(float, s.rollers_rpm), s.motor_rpm, s.supply_hz]
    await server.write_attribute_value(m.sample_node.nodeid, ua.DataValue(
        ua.Variant(row, ua.VariantType.Double), SourceTimestamp=stamp, ServerTimestamp=now))  # fmt: skip
    if scalar_nodes:
        for node, v in zip(m.scalars, values_of(s).values(), strict=True):
            await server.write_attribute_value(node.nodeid, ua.DataValue(
                ua.Variant(v, ua.VariantType.Double), SourceTimestamp=stamp, ServerTimestamp=now))  # fmt: skip
    executing = s.supply_hz > 0.0
    if executing != m.executing:
        m.executing = executing
        await m.state_node.write_value(ua.DataValue(ua.Variant(ua.LocalizedText(
            "Executing" if executing else "NotExecuting")), SourceTimestamp=stamp))  # fmt: skip


def _refuse_bad_setpoints(server: Any, nodes: set[Any]) -> None:
    """A client's write of a set-point that is no number from 0 to MAX_SUPPLY_HZ answers
    BadOutOfRange to that client and is not written (it had answered Good and been set back
    unseen); the other values of the request are written as asked."""
    import dataclasses

    from asyncua import ua

    service = server.iserver.attribute_service
    write = service.write

    def bad(wv: Any) -> bool:
        if wv.NodeId not in nodes or wv.AttributeId != ua.AttributeIds.Value:
            return False
        value = getattr(getattr(wv.Value, "Value", None), "Value", None)
        if not isinstance(value, int | float) or isinstance(value, bool):
            return True
        return not (math.isfinite(value) and 0.0 <= value <= MAX_SUPPLY_HZ)

    async def passed(params: Any, user: Any) -> list[Any]:
        return list(await (write(params) if user is None else write(params, user)))

    async def guarded(params: Any, user: Any = None) -> list[Any]:
        refused = {i for i, wv in enumerate(params.NodesToWrite) if bad(wv)}
        if not refused:
            return await passed(params, user)
        for i in sorted(refused):
            value = params.NodesToWrite[i].Value.Value
            logging.getLogger(__name__).warning("set-point %r refused: write a number from 0 "
                                                "to %g Hz", getattr(value, "Value", value),
                                                MAX_SUPPLY_HZ)  # fmt: skip
        kept = [wv for i, wv in enumerate(params.NodesToWrite) if i not in refused]
        sub = dataclasses.replace(params, NodesToWrite=kept)
        done = iter(await passed(sub, user) if kept else [])
        return [ua.StatusCode(ua.UInt32(ua.StatusCodes.BadOutOfRange)) if i in refused else next(done)
                for i in range(len(params.NodesToWrite))]  # fmt: skip

    service.write = guarded


async def _apply_setpoint(server: Any, m: ServedMachine) -> None:
    """A set-point a client wrote (read from the address space directly: no request built)."""
    from asyncua import ua

    value = server.read_attribute_value(m.setpoint_node.nodeid).Value.Value
    if value == m.last_setpoint:
        return
    try:
        m.plant.set_supply(float(value))
        m.last_setpoint = value
    except (ConfigError, TypeError, ValueError):
        m.refused += 1
        with contextlib.suppress(Exception):
            await server.write_attribute_value(m.setpoint_node.nodeid, ua.DataValue(
                ua.Variant(float(m.last_setpoint), ua.VariantType.Double)))  # fmt: skip


__all__ = ["NAMESPACE", "SCALARS", "SERVER_URI", "parse_opcua_url", "serve_opcua"]
