"""The twin as an OPC UA server of its own results (asyncua), in the twin's event loop.

Address space, namespace ``urn:drafttwin:twin`` (index 2), per machine ``NAME``::

    Objects/Twin/NAME/                           ns=2;s=NAME
        Measured/CHANNEL   Physics/CHANNEL       ns=2;s=NAME.Measured.front ...
        Prediction/CHANNEL Residual/CHANNEL      AnalogItemType, Double, EngineeringUnits
                                                 (UNECE), EURange, SourceTimestamp = sample
        Setpoint                                 AnalogItemType (Hz)
        Health/  State, Detector (none, learning, watching), DataAge, SinceLastSample,
                 LearningLeft, LatencyP99 (AnalogItemType s / ms), Received, Processed, Late,
                 Dropped (UInt64)
        Alarm/   Active (Boolean), Kind, Cause, Detail (String), Time (UtcTime)
        Identification/  Manufacturer, Model, SerialNumber, ProductInstanceUri (the machine's,
                 as its source said: OPC 40001-1; empty until known), ComponentName (NAME)
        Sliver/  Count (ktex), CV (%), DeliveredLength (m) AnalogItemType; Chimneys (String,
                 JSON: the last spectrogram's chimneys and their elements)
        Leveller/  State (no leveller, collecting, recommending, not placed), ActionPoint (mm), Intensity:
                 the machine's setting; RecommendedActionPoint, RecommendedActionPointLow,
                 RecommendedActionPointHigh (mm, 95 %), RecommendedIntensity, CurrentCV and
                 ExpectedCV (%), MetresUsed, MetresNeeded (m); Advice (String, 'sliver level' JSON).
                 Read only: a recommendation, the twin never writes a setting.

The server itself says ApplicationUri ``urn:drafttwin:twin:server`` and ProductUri
``urn:drafttwin:twin`` (the plant's: ``urn:drafttwin:plant:server``, ``urn:drafttwin:plant``;
:mod:`drafttwin.wire.identity`).

Each machine's alarms are also an OPC UA condition (``NAME.Alarm``, AlarmConditionType) whose
events the Server object emits (subscribe to events there), with ConditionRefresh,
Acknowledge and Confirm written on top of asyncua (:mod:`drafttwin.twin.publish.conditions`):
a client connecting after an alarm sees it, active until it returns to normal, retained
until an operator acknowledged and confirmed it.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import json
import math
from dataclasses import dataclass, field
from typing import Any

from drafttwin._constants import __version__
from drafttwin.twin.publish.base import CLOSE_S, Publisher
from drafttwin.twin.publish.conditions import Conditions
from drafttwin.twin.publish.payload import alarm, setpoint_unit, unit_of, utc
from drafttwin.twin.service import MachineState, TwinService
from drafttwin.twin.store.db import EventRow, SampleRow
from drafttwin.wire.conventions import UNECE_NAMESPACE
from drafttwin.wire.identity import MANUFACTURER, TWIN_PRODUCT_URI, TWIN_SERVER_URI

NAMESPACE = "urn:drafttwin:twin"
SUPPLY_MAX_HZ = 120.0
"""The highest supply set-point a machine takes (the plant's VFD limit, plant/live.py, not
imported: the twin does not depend on the emulator): the top of the speeds' EURange."""
KINDS = (("Measured", "measured", "measured speed"), ("Physics", "physics", "physics' speed"),
         ("Prediction", "twin", "twin's prediction"),
         ("Residual", "residual", "residual, measured - prediction"))  # fmt: skip
HEALTH = (("DataAge", "s", "wall clock minus the newest sample's source time (not for a replay)"),
          ("SinceLastSample", "s", "time since the twin received the machine's last sample"),
          ("LatencyP99", "ms", "the twin's p99 latency, sample received -> stored and pushed"))  # fmt: skip
COUNTS = ("Received", "Processed", "Late", "Dropped")
SLIVER_NODES = (("Count", "ktex", 200.0, "running mean count of the delivered sliver"),
                ("CV", "%", 100.0, "running CV of the delivery sensor's readings"),
                ("DeliveredLength", "m", 1e7, "delivered length of the newest reading"))  # fmt: skip
LEVELLER_NODES = (
    ("ActionPoint", "mm", 10_000.0, "the leveller's action point setting (mm of fed sliver "
     "from the scanning rollers), as the machine says"),
    ("Intensity", "", 2.0, "the leveller's intensity setting, as the machine says"),
    ("RecommendedActionPoint", "mm", 10_000.0, "the recommended action point"),
    ("RecommendedActionPointLow", "mm", 10_000.0, "its 95 % interval's low end"),
    ("RecommendedActionPointHigh", "mm", 10_000.0, "its 95 % interval's high end"),
    ("RecommendedIntensity", "", 2.0, "the recommended intensity"),
    ("CurrentCV", "%", 100.0, "the CV of the window the recommendation came from"),
    ("ExpectedCV", "%", 100.0, "the CV expected at the recommendation"),
    ("MetresUsed", "m", 1e5, "delivered sliver the recommendation came from"),
    ("MetresNeeded", "m", 1e5, "metres from which its interval was within +-5 mm"),
)  # fmt: skip


def _ua() -> Any:
    """asyncua's ``ua`` (imported when used; its stubs want its own scalar types)."""
    from asyncua import ua

    return ua


def channel_range(st: MachineState, channel: str) -> tuple[float, float]:
    """0 to the roller's speed at the highest supply (rigid kinematics), rpm."""
    train = st.twin.train
    motor = train.spec.motor
    if motor is None or channel not in train.roller_nodes:
        return (-math.inf, math.inf)
    sync_rpm = 120.0 * SUPPLY_MAX_HZ / motor.poles
    return (0.0, float(train.speed_ratios[train.roller_nodes[channel]]) * sync_rpm)


IDENTITY_FIELDS = ("Manufacturer", "Model", "SerialNumber", "ProductInstanceUri")


def _known(st: MachineState) -> tuple[str, ...]:
    i = st.identity
    return () if i is None else (i.manufacturer, i.model, i.serial, i.product_instance_uri)


def _identification() -> tuple[tuple[str, Any], ...]:
    ua = _ua()
    text, string = ua.VariantType.LocalizedText, ua.VariantType.String
    return (("Manufacturer", text), ("Model", text), ("SerialNumber", string),
            ("ProductInstanceUri", string), ("ComponentName", text))  # fmt: skip


@dataclass
class MachineNodes:
    values: dict[str, list[Any]] = field(default_factory=dict)  # kind -> node per channel
    setpoint: Any = None
    health: dict[str, Any] = field(default_factory=dict)
    alarm: dict[str, Any] = field(default_factory=dict)
    events: Any = None  # the AlarmConditionType event generator
    ident: dict[str, Any] = field(default_factory=dict)  # Identification's properties
    sliver: dict[str, Any] = field(default_factory=dict)  # Sliver/ and Leveller/ nodes
    known: tuple[str, ...] = ()  # the identity last written there


class OpcUaPublisher(Publisher):
    """Serve the twin's results at ``opc.tcp://HOST:PORT/``."""

    kind = "opcua"

    def __init__(self, host: str, port: int, **kw: Any) -> None:
        super().__init__(f"opcua:opc.tcp://{host}:{port}", **kw)
        self.host, self.port = host, port
        self.server: Any = None
        self.idx = 2
        self.nodes: dict[str, MachineNodes] = {}
        self.conditions: Conditions = Conditions(lambda _: [], lambda *_: None)

    async def open(self, service: TwinService) -> None:
        from asyncua import Server

        ua = _ua()

        await super().open(service)
        server = Server()
        await server.init()
        server.set_endpoint(f"opc.tcp://{self.host}:{self.port}/")
        server.set_server_name("drafttwin twin")
        await server.set_application_uri(TWIN_SERVER_URI)
        await server.set_build_info(TWIN_PRODUCT_URI, MANUFACTURER, "drafttwin twin",
                                    __version__, __version__, dt.datetime.now(dt.UTC))  # fmt: skip
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        self.idx = await server.register_namespace(NAMESPACE)
        folder = await server.nodes.objects.add_folder(self._nid("Twin"), f"{self.idx}:Twin")
        self.conditions = Conditions(service.book.retained, service.faults.acknowledge)
        await self.conditions.install(server)
        for name, st in service.states.items():
            self.nodes[name] = await self._add_machine(server, folder, st)
            self.conditions.add(name, self.nodes[name].events, self._nid(f"{name}.Alarm"))
        await server.start()  # an OSError (port taken) reaches the CLI
        self.server = server

    # ---- the address space ------------------------------------------------------------------
    def _nid(self, text: str) -> Any:
        ua = _ua()

        return ua.NodeId(text, self.idx)

    async def _add_machine(self, server: Any, folder: Any, st: MachineState) -> MachineNodes:
        ua = _ua()

        name = st.twin.name
        obj = await folder.add_object(self._nid(name), f"{self.idx}:{name}")
        out = MachineNodes()
        units = st.twin.model.units_
        for kind, key, what in KINDS:
            sub = await obj.add_object(self._nid(f"{name}.{kind}"), f"{self.idx}:{kind}")
            out.values[key] = []
            for c in st.twin.channels:
                lo, hi = channel_range(st, c)
                if key == "residual":
                    lo, hi = -hi, hi
                out.values[key].append(await self._analog(
                    server, sub, f"{name}.{kind}.{c}", c, f"{name}: {c} roller, {what}",
                    units.get(c, ""), (lo, hi)))  # fmt: skip
        sp = st.mapping.setpoint
        out.setpoint = await self._analog(server, obj, f"{name}.Setpoint", "Setpoint",
                                          f"{name}: the {sp} set-point the twin follows",
                                          setpoint_unit(sp), (0.0, SUPPLY_MAX_HZ))  # fmt: skip
        health = await obj.add_object(self._nid(f"{name}.Health"), f"{self.idx}:Health")
        out.health["State"] = await self._plain(health, f"{name}.Health.State", "State", "",
                                                "connecting, waiting, live, silent, reconnecting, offline")  # fmt: skip
        out.health["Detector"] = await self._plain(
            health, f"{name}.Health.Detector", "Detector", "",
            "the fault detector: none, learning (the machine's healthy state: no fault alarm "
            "meanwhile) or watching")  # fmt: skip
        out.health["LearningLeft"] = await self._analog(
            server, health, f"{name}.Health.LearningLeft", "LearningLeft",
            f"{name}: running time still to learn (0 when watching)", "s", (0.0, 86_400.0))  # fmt: skip
        for key, unit, what in HEALTH:
            out.health[key] = await self._analog(server, health, f"{name}.Health.{key}", key,
                                                 f"{name}: {what}", unit, (0.0, math.inf))  # fmt: skip
        for key in COUNTS:
            out.health[key] = await self._plain(health, f"{name}.Health.{key}", key,
                                                ua.Variant(0, ua.VariantType.UInt64),
                                                f"{name}: samples {key.lower()}")  # fmt: skip
        ident = await obj.add_object(self._nid(f"{name}.Identification"),
                                     f"{self.idx}:Identification")  # fmt: skip
        out.known = _known(st)
        values = dict(zip(IDENTITY_FIELDS, out.known or ("",) * 4, strict=True))
        values["ComponentName"] = name
        for prop, vtype in _identification():
            v = values[prop]
            out.ident[prop] = await ident.add_property(
                self._nid(f"{name}.Identification.{prop}"), f"{self.idx}:{prop}",
                ua.LocalizedText(v) if vtype == ua.VariantType.LocalizedText else v,
                varianttype=vtype)  # fmt: skip
        await self._add_sliver(server, obj, name, out)
        al = await obj.add_object(self._nid(f"{name}.Alarm"), f"{self.idx}:Alarm")
        out.alarm["Active"] = await self._plain(al, f"{name}.Alarm.Active", "Active", False,
                                                f"{name}: an alarm was raised")  # fmt: skip
        for key, what in (("Kind", "fault, sensor-fault, fault-cause or sliver-chimney"),
                          ("Cause", "the probable cause, element:kind"),
                          ("Detail", "the detector's test and the ranked causes, JSON")):  # fmt: skip
            out.alarm[key] = await self._plain(
                al, f"{name}.Alarm.{key}", key, "", f"{name}: {what}"
            )
        out.alarm["Time"] = await self._plain(
            al, f"{name}.Alarm.Time", "Time",
            ua.Variant(dt.datetime(1970, 1, 1, tzinfo=dt.UTC), ua.VariantType.DateTime),
            f"{name}: the sample time the alarm was raised at")  # fmt: skip
        await obj.set_event_notifier([ua.EventNotifier.SubscribeToEvents])
        gen = await server.get_event_generator(ua.ObjectIds.AlarmConditionType, server.nodes.server)
        gen.event.SourceNode, gen.event.SourceName = obj.nodeid, name
        gen.event.NodeId = self._nid(f"{name}.Alarm")  # the condition's id
        out.events = gen
        return out

    async def _add_sliver(self, server: Any, obj: Any, name: str, out: MachineNodes) -> None:
        """The machine's Sliver and Leveller objects (values once a source sends them)."""
        sl = await obj.add_object(self._nid(f"{name}.Sliver"), f"{self.idx}:Sliver")
        for key, unit, hi, what in SLIVER_NODES:
            out.sliver[key] = await self._analog(server, sl, f"{name}.Sliver.{key}", key,
                                                 f"{name}: {what}", unit, (0.0, hi))  # fmt: skip
        out.sliver["Chimneys"] = await self._plain(sl, f"{name}.Sliver.Chimneys", "Chimneys", "",
                                                   f"{name}: the last spectrogram's chimneys "
                                                   "with their elements (JSON)")  # fmt: skip
        lev = await obj.add_object(self._nid(f"{name}.Leveller"), f"{self.idx}:Leveller")
        out.sliver["State"] = await self._plain(lev, f"{name}.Leveller.State", "State", "",
                                                "no leveller, collecting, recommending or not placed "
                                                "(the last window does not place the action "
                                                "point: nothing recommended)")  # fmt: skip
        for key, unit, hi, what in LEVELLER_NODES:
            out.sliver[key] = await self._analog(server, lev, f"{name}.Leveller.{key}", key,
                                                 f"{name}: {what}", unit, (0.0, hi))  # fmt: skip
        out.sliver["Advice"] = await self._plain(lev, f"{name}.Leveller.Advice", "Advice", "",
                                                 f"{name}: the recommendation as 'drafttwin "
                                                 "sliver level --json' gives it; the twin writes "
                                                 "no setting")  # fmt: skip

    async def send_sliver(self, st: MachineState, doc: dict[str, Any]) -> None:
        ua = _ua()

        nodes, now = self.nodes[st.twin.name].sliver, dt.datetime.now(dt.UTC)
        w, lev = doc["sliver"] or {}, doc["leveller"] or {}
        for key, field_ in (("Count", "count_ktex"), ("CV", "cv_pct"),
                            ("DeliveredLength", "delivered_m")):  # fmt: skip
            v = w.get(field_)
            await self._write(nodes[key], math.nan if v is None else float(v), now)
        await self._set(nodes["Chimneys"], json.dumps(w.get("chimneys", [])), ua.VariantType.String)
        await self._set(nodes["State"], lev.get("state", ""), ua.VariantType.String)
        setting, advice = lev.get("setting") or {}, lev.get("advice") or {}
        # a window that does not place the action point recommends nothing (NaN)
        placed = advice if lev.get("state") == "recommending" else {}
        lo, hi = placed.get("action_point_interval_mm") or (None, None)
        values = {"ActionPoint": setting.get("action_point_mm"),
                  "Intensity": setting.get("intensity"),
                  "RecommendedActionPoint": placed.get("recommended_action_point_mm"),
                  "RecommendedActionPointLow": lo, "RecommendedActionPointHigh": hi,
                  "RecommendedIntensity": placed.get("recommended_intensity"),
                  "CurrentCV": (advice.get("current") or {}).get("cv_pct"),
                  "ExpectedCV": (advice.get("recommended") or {}).get("cv_pct"),
                  "MetresUsed": advice.get("metres_used"),
                  "MetresNeeded": advice.get("metres_needed")}  # fmt: skip
        for key, v in values.items():
            await self._write(nodes[key], math.nan if v is None else float(v), now)
        await self._set(nodes["Advice"], json.dumps(advice) if advice else "",
                        ua.VariantType.String)  # fmt: skip

    async def _plain(self, parent: Any, nid: str, name: str, value: Any, description: str) -> Any:
        ua = _ua()

        node = await parent.add_variable(self._nid(nid), f"{self.idx}:{name}", value)
        await node.write_attribute(ua.AttributeIds.Description,
                                   ua.DataValue(ua.Variant(ua.LocalizedText(description))))  # fmt: skip
        return node

    async def _analog(self, server: Any, parent: Any, nid: str, name: str, description: str,
                      unit: str, eu_range: tuple[float, float]) -> Any:  # fmt: skip
        """An AnalogItemType variable (Double) with EngineeringUnits and EURange."""
        ua = _ua()

        item = ua.AddNodesItem()
        item.RequestedNewNodeId = self._nid(nid)
        item.BrowseName = ua.QualifiedName(name, self.idx)
        item.NodeClass = ua.NodeClass.Variable
        item.ParentNodeId = parent.nodeid
        item.ReferenceTypeId = ua.NodeId(ua.ObjectIds.HasComponent)
        item.TypeDefinition = ua.NodeId(ua.ObjectIds.AnalogItemType)
        attrs = ua.VariableAttributes()
        attrs.DisplayName, attrs.Description = ua.LocalizedText(name), ua.LocalizedText(description)
        attrs.DataType = ua.NodeId(ua.ObjectIds.Double)
        attrs.Value = ua.Variant(math.nan, ua.VariantType.Double)
        attrs.ValueRank = ua.ValueRank.Scalar
        attrs.AccessLevel = attrs.UserAccessLevel = ua.AccessLevel.CurrentRead.mask
        item.NodeAttributes = attrs
        (added,) = await server.iserver.isession.add_nodes([item])
        added.StatusCode.check()
        node = server.get_node(added.AddedNodeId)
        await server.write_attribute_value(node.nodeid, ua.DataValue(
            ua.Variant(math.nan, ua.VariantType.Double),
            StatusCode=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData)))  # fmt: skip
        known = unit_of(unit)  # UnitId -1: no UNECE code (OPC UA Part 8)
        eu = ua.EUInformation(NamespaceUri=UNECE_NAMESPACE,
                              UnitId=-1 if known is None else known.unit_id,
                              DisplayName=ua.LocalizedText(unit if known is None else known.symbol),
                              Description=ua.LocalizedText(unit if known is None else known.name))  # fmt: skip
        await node.add_property(self._nid(f"{nid}.EngineeringUnits"), "0:EngineeringUnits", eu,
                                datatype=ua.NodeId(ua.ObjectIds.EUInformation))  # fmt: skip
        await node.add_property(self._nid(f"{nid}.EURange"), "0:EURange",
                                ua.Range(Low=eu_range[0], High=eu_range[1]),
                                datatype=ua.NodeId(ua.ObjectIds.Range))  # fmt: skip
        return node

    # ---- values ----------------------------------------------------------------------------
    async def _write(self, node: Any, value: float, when: dt.datetime) -> None:
        ua = _ua()

        status = ua.StatusCode(ua.StatusCodes.Good if math.isfinite(value)
                               else ua.StatusCodes.BadWaitingForInitialData)  # fmt: skip
        await self.server.write_attribute_value(node.nodeid, ua.DataValue(
            ua.Variant(float(value), ua.VariantType.Double), StatusCode=status,
            SourceTimestamp=when, ServerTimestamp=dt.datetime.now(dt.UTC)))  # fmt: skip

    async def _set(self, node: Any, value: Any, vtype: Any) -> None:
        ua = _ua()

        await self.server.write_attribute_value(node.nodeid, ua.DataValue(
            ua.Variant(value, vtype), SourceTimestamp=dt.datetime.now(dt.UTC),
            ServerTimestamp=dt.datetime.now(dt.UTC)))  # fmt: skip

    async def send_prediction(self, st: MachineState, row: SampleRow) -> None:
        nodes, when = self.nodes[st.twin.name], utc(row.ts_us)
        for key, per_channel in nodes.values.items():
            for node, v in zip(per_channel, getattr(row, key), strict=True):
                await self._write(node, float(v), when)
        await self._write(nodes.setpoint, float(row.setpoint), when)

    async def _identify(self, nodes: MachineNodes, st: MachineState) -> None:
        """The machine's Identification as the twin knows it from its source (OPC 40001-1:
        the plant's SerialNumber and ProductInstanceUri; empty until the source said)."""
        ua = _ua()

        known = _known(st)
        if known == nodes.known or not nodes.ident:
            return
        nodes.known = known
        values = dict(zip(IDENTITY_FIELDS, known or ("",) * 4, strict=True))
        for prop, vtype in _identification():
            if prop in values:
                v = (
                    ua.LocalizedText(values[prop])
                    if vtype == ua.VariantType.LocalizedText
                    else values[prop]
                )
                await self._set(nodes.ident[prop], v, vtype)

    async def send_status(self, st: MachineState, status: dict[str, Any]) -> None:
        ua = _ua()

        await self._identify(self.nodes[st.twin.name], st)
        h = self.nodes[st.twin.name].health
        await self._set(h["State"], status["state"], ua.VariantType.String)
        now = dt.datetime.now(dt.UTC)
        for key, field_ in (("DataAge", "data_age_s"), ("SinceLastSample", "since_last_sample_s"),
                            ("LatencyP99", "latency_p99_ms")):  # fmt: skip
            v = status[field_]
            await self._write(h[key], math.nan if v is None else float(v), now)
        for key in COUNTS:
            await self._set(h[key], int(status[key.lower()]), ua.VariantType.UInt64)
        det = status["detector"]
        await self._set(h["Detector"], det["state"], ua.VariantType.String)
        await self._write(h["LearningLeft"], math.nan if det["left_s"] is None else det["left_s"],
                          now)  # fmt: skip

    async def send_alarm(self, st: MachineState, ev: EventRow) -> None:
        """The machine's Alarm nodes and its condition as they stand after ``ev``."""
        ua = _ua()

        name = st.twin.name
        doc, nodes = alarm(ev), self.nodes[name]
        retained = self.conditions.retained(name)
        await self._set(nodes.alarm["Active"], any(a.active for a in retained),
                        ua.VariantType.Boolean)  # fmt: skip
        if ev.kind in ("fault", "sensor-fault", "fault-cause", "sliver-chimney", "sliver-count"):
            await self._set(nodes.alarm["Kind"], ev.kind, ua.VariantType.String)
            await self._set(nodes.alarm["Cause"], doc["cause"] or "", ua.VariantType.String)
            await self._set(nodes.alarm["Detail"], json.dumps(doc["detail"]), ua.VariantType.String)
            await self._set(nodes.alarm["Time"], utc(ev.ts_us), ua.VariantType.DateTime)
        await self.conditions.emit(name, when=utc(ev.ts_us) if ev.kind != "alarm-ack" else None)

    async def close(self, service: TwinService) -> None:
        if self.server is None:
            return
        with contextlib.suppress(Exception):
            await asyncio.wait_for(self.drain(service), CLOSE_S / 2)
            await asyncio.wait_for(self.statuses(service, "offline"), CLOSE_S / 4)
        # the server's clock task sleeps 1 s between updates: end it now, not after its sleep
        clock, self.server.iserver.time_task = self.server.iserver.time_task, None
        if clock is not None:
            clock.cancel()
            await asyncio.wait([clock], timeout=CLOSE_S / 4)
        with contextlib.suppress(Exception):
            await asyncio.wait_for(self.server.stop(), CLOSE_S)
        self.server = None


__all__ = ["NAMESPACE", "OpcUaPublisher", "channel_range"]
