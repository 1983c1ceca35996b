"""The plant server's OPC UA node helpers: analog items with units and ranges (Part 8),
descriptions, node ids; shared by the speed channels (:mod:`.opcua`) and the sliver
(:mod:`.sliver`)."""

from __future__ import annotations

import logging
from typing import Any

from drafttwin.wire.conventions import UNECE_NAMESPACE


async def analog_item(parent: Any, idx: int, node_id: str, name: str, value: float | None,
                      unit: Any, eu_range: tuple[float, float], description: str,
                      decimals: int | None = None) -> Any:  # fmt: skip
    """An AnalogItemType variable (OPC UA Part 8 §5.3.2.2) of Double under ``parent``: EURange
    (mandatory), EngineeringUnits (UNECE ``unit``), ValuePrecision (``decimals``), a
    description. Instantiated from the type, so clients see TypeDefinition AnalogItemType.
    ``value`` ``None``: a Double array (value rank 1), empty until the first write."""
    from asyncua import Node, ua
    from asyncua.common.instantiate_util import instantiate

    kind = Node(parent.session, ns0(ua.ObjectIds.AnalogItemType))
    log = logging.getLogger("asyncua.common.copy_node_util")
    level = log.level
    log.setLevel(logging.ERROR)  # it warns of attributes a type has no value for
    var: Any  # asyncua's stubs type the array dimensions as one int
    try:
        var, *_ = await instantiate(parent, kind, nid(idx, node_id), f"{idx}:{name}",
                                    ua.LocalizedText(name), instantiate_optional=False)  # fmt: skip
    finally:
        log.setLevel(level)
    await var.write_attribute(ua.AttributeIds.DataType,
                              ua.DataValue(ua.Variant(ns0(ua.ObjectIds.Double))))  # fmt: skip
    if value is None:
        await var.write_value_rank(1)
        await var.write_array_dimensions([0])
        await var.write_value(ua.Variant([], ua.VariantType.Double))
    else:
        await var.write_attribute(ua.AttributeIds.ValueRank, ua.DataValue(ua.Variant(-1, ua.VariantType.Int32)))  # fmt: skip
        await var.write_value(ua.Variant(float(value), ua.VariantType.Double))
    await describe(var, description)
    rng = await var.get_child(["0:EURange"])
    await rng.write_value(ua.Range(Low=float(eu_range[0]), High=float(eu_range[1])))
    eu = ua.EUInformation(NamespaceUri=UNECE_NAMESPACE, UnitId=unit.unit_id,
                          DisplayName=ua.LocalizedText(unit.symbol),
                          Description=ua.LocalizedText(unit.name))  # fmt: skip
    await var.add_property(nid(idx, f"{node_id}.EngineeringUnits"), "0:EngineeringUnits", eu,
                           datatype=ns0(ua.ObjectIds.EUInformation))  # fmt: skip
    if decimals is not None:
        await var.add_property(nid(idx, f"{node_id}.ValuePrecision"), "0:ValuePrecision",
                               float(decimals), varianttype=ua.VariantType.Double)  # fmt: skip
    return var


async def describe(node: Any, text: str) -> None:
    """Write ``text`` as the node's Description attribute."""
    from asyncua import ua

    value = ua.DataValue(ua.Variant(ua.LocalizedText(text)))
    await node.write_attribute(ua.AttributeIds.Description, value)


def ns0(i: int) -> Any:
    """A node of namespace 0 (the OPC UA standard's)."""
    from asyncua import ua

    return ua.NodeId.from_string(f"i={i}")


def nid(idx: int, name: str) -> Any:
    """The string node id ``name`` in namespace ``idx``."""
    from asyncua import ua

    return ua.NodeId.from_string(f"ns={idx};s={name}")


__all__ = ["analog_item", "describe", "nid", "ns0"]
