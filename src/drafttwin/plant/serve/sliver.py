"""``plant serve --sliver``: each machine's sliver sensors on the wire (:mod:`drafttwin.wire.sliver`).

OPC UA, under ``Objects/Machines/NAME``::

    Sliver/block        ns=2;s=NAME.Sliver.block   Double array: seq, n, then the n values of
                        time, delivered_length_m, linear_density_ktex, infeed_ktex,
                        fed_length_m (FieldNames, FieldUnits properties): the twin's
    Sliver/FIELD        ns=2;s=NAME.Sliver.FIELD   AnalogItemType, Double array of the batch:
                        EngineeringUnits (UNECE SEC, MTR, GF), EURange, ValuePrecision
    Leveller/Description  ns=2;s=NAME.Leveller.Description  String: the description (JSON)
    Leveller/Intensity, Leveller/ActionPoint   AnalogItemType: the setting (mm of fed sliver
                        from the scanning rollers), read only: the machine's own

MQTT: ``drafttwin/NAME/sliver`` per batch (QoS of the samples) and ``drafttwin/NAME/leveller``
retained (QoS 1). Every value of a batch carries its last reading's time as SourceTimestamp.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drafttwin.plant.live_sliver import LiveSliver
from drafttwin.wire.conventions import UNITLESS, topic, utc
from drafttwin.wire.sliver import (
    MILLIMETRE,
    SLIVER_CHANNELS,
    SLIVER_FIELDS,
    SliverBatch,
    sliver_block,
    sliver_payload,
)

SCHEMA = Path(__file__).with_name("schemas") / "sliver.schema.json"
"""JSON Schema of the sliver payload."""
DESCRIPTION_SCHEMA = Path(__file__).with_name("schemas") / "leveller.schema.json"
"""JSON Schema of the retained description."""


@dataclass
class SliverNodes:
    block: Any
    fields: list[Any]


async def add_sliver_nodes(obj: Any, idx: int, name: str, live: LiveSliver) -> SliverNodes:
    """The machine's Sliver and Leveller objects (see the module)."""
    from asyncua import ua

    from drafttwin.plant.serve.opcua_nodes import analog_item, describe, nid

    sliver = await obj.add_object(nid(idx, f"{name}.Sliver"), f"{idx}:Sliver")
    await describe(sliver, "the drawframe's sliver sensors: delivery funnel and infeed "
                    "scanning rollers, one batch of readings at a time")  # fmt: skip
    block = await sliver.add_variable(nid(idx, f"{name}.Sliver.block"), f"{idx}:block", [0.0],
                                      varianttype=ua.VariantType.Double)  # fmt: skip
    await block.write_value_rank(1)
    await block.write_array_dimensions([0])
    await describe(block, "one batch: seq, n, then the n values of each of "
                    + ", ".join(SLIVER_FIELDS) + " (time: epoch s)")  # fmt: skip
    await block.add_property(nid(idx, f"{name}.Sliver.block.FieldNames"), f"{idx}:FieldNames",
                             ["seq", "n", *SLIVER_FIELDS], varianttype=ua.VariantType.String)  # fmt: skip
    units = [UNITLESS.symbol, UNITLESS.symbol, *(c.unit.symbol for c in SLIVER_CHANNELS)]
    await block.add_property(nid(idx, f"{name}.Sliver.block.FieldUnits"), f"{idx}:FieldUnits",
                             units, varianttype=ua.VariantType.String)  # fmt: skip
    fields = [await analog_item(sliver, idx, f"{name}.Sliver.{c.name}", c.name, None, c.unit,
                                c.eu_range, c.description, c.decimals)
              for c in SLIVER_CHANNELS]  # fmt: skip
    lev = await obj.add_object(nid(idx, f"{name}.Leveller"), f"{idx}:Leveller")
    described = json.dumps(live.describe())
    desc = await lev.add_variable(nid(idx, f"{name}.Leveller.Description"),
                                  f"{idx}:Description", described)  # fmt: skip
    await describe(desc, "the sliver's description (JSON, drafttwin plant leveller schema): "
                    "the leveller's setting, the fibres, the sensors")  # fmt: skip
    setting = live.leveller
    await analog_item(lev, idx, f"{name}.Leveller.Intensity", "Intensity",
                      0.0 if setting is None else setting.intensity, UNITLESS, (0.0, 2.0),
                      "the leveller's intensity (0: none), the machine's setting", 3)  # fmt: skip
    point = math.nan if setting is None or setting.action_point_mm is None else (
        setting.action_point_mm)  # fmt: skip
    await analog_item(lev, idx, f"{name}.Leveller.ActionPoint", "ActionPoint", point, MILLIMETRE,
                      (0.0, 10_000.0), "the leveller's action point: mm of fed sliver from the "
                      "scanning rollers, the machine's setting (NaN: no leveller)", 1)  # fmt: skip
    return SliverNodes(block, fields)


async def publish_sliver_opcua(nodes: SliverNodes, batch: SliverBatch) -> None:
    """Write one batch: the block, then each field's array, stamped with its last time."""
    from asyncua import ua

    stamp: Any = utc(float(batch.time_s[-1]))
    await nodes.block.write_value(ua.DataValue(
        ua.Variant(sliver_block(batch), ua.VariantType.Double), SourceTimestamp=stamp))  # fmt: skip
    for node, values in zip(nodes.fields, batch.arrays, strict=True):
        await node.write_value(ua.DataValue(
            ua.Variant(values.tolist(), ua.VariantType.Double), SourceTimestamp=stamp))  # fmt: skip


def publish_sliver_mqtt(client: Any, batch: SliverBatch, qos: int) -> None:
    client.publish(topic(batch.machine, "sliver"), json.dumps(sliver_payload(batch),
                   allow_nan=False), qos=qos)  # fmt: skip


def announce_leveller(client: Any, name: str, live: LiveSliver) -> Any:
    """The retained description (QoS 1); returns paho's message info."""
    return client.publish(topic(name, "leveller"), json.dumps(live.describe()), qos=1, retain=True)


__all__ = ["DESCRIPTION_SCHEMA", "SCHEMA", "SliverNodes", "add_sliver_nodes",
           "announce_leveller", "publish_sliver_mqtt", "publish_sliver_opcua"]  # fmt: skip
