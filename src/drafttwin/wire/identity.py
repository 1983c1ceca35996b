"""One identity scheme for the machines, the plant's servers and the twin's (URNs).

A machine is known by its serial number (OPC 40001-1 Identification: ``SerialNumber``) and
its ``ProductInstanceUri``; a server by its ApplicationUri and ProductUri. The plant
emulator's machines are its machine seeds: machine seed ``K`` is serial ``FA320A-SIM-K``
whether it is served live (``plant serve --seed K``) or recorded (``generate --machine-seed
K``, whose sidecar names the seed), so a twin can tell a baseline learned on one machine
from another machine wherever it met them.

URNs (RFC 8141, informal namespace ``drafttwin``):

* ``urn:drafttwin:plant`` / ``urn:drafttwin:twin``: the products (OPC UA ProductUri);
* ``urn:drafttwin:plant:server`` / ``urn:drafttwin:twin:server``: the servers (ApplicationUri);
* ``urn:drafttwin:machine:SERIAL``: a machine (ProductInstanceUri).

On MQTT the plant publishes the same fields, retained, on ``drafttwin/NAME/identification``
(schema ``plant/serve/schemas/identification.schema.json``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

PLANT_PRODUCT_URI = "urn:drafttwin:plant"
TWIN_PRODUCT_URI = "urn:drafttwin:twin"
PLANT_SERVER_URI = "urn:drafttwin:plant:server"
TWIN_SERVER_URI = "urn:drafttwin:twin:server"
MANUFACTURER = "drafttwin"
PLANT_MODEL = "FA320A drawing frame (plant emulator)"
MAX_FIELD = 200  # characters of an identification field accepted from the wire
_SAFE = re.compile(r"^[^\x00-\x1f\x7f]{1,200}$")  # printable, one line, bounded


@dataclass(frozen=True)
class MachineIdentity:
    """Who a machine is: serial number, product instance URI, manufacturer and model."""

    serial: str
    product_instance_uri: str
    manufacturer: str = MANUFACTURER
    model: str = PLANT_MODEL

    def to_dict(self) -> dict[str, str]:
        return {"serial_number": self.serial, "product_instance_uri": self.product_instance_uri,
                "manufacturer": self.manufacturer, "model": self.model}  # fmt: skip

    @classmethod
    def from_dict(cls, doc: Any) -> MachineIdentity | None:
        """From :meth:`to_dict` (or a wire payload of the same fields); ``None`` when a field
        is missing, not text, too long or holds control characters."""
        if not isinstance(doc, dict):
            return None
        fields = [doc.get(k) for k in ("serial_number", "product_instance_uri", "manufacturer",
                                       "model")]  # fmt: skip
        if not all(isinstance(f, str) and _SAFE.match(f) for f in fields):
            return None
        return cls(*fields)  # type: ignore[arg-type]

    def __str__(self) -> str:
        return f"serial {self.serial}"


def plant_serial(machine_seed: int) -> str:
    """The emulated machine's serial number."""
    return f"FA320A-SIM-{int(machine_seed)}"


def machine_uri(serial: str) -> str:
    """A machine's ProductInstanceUri."""
    return f"urn:drafttwin:machine:{serial}"


def plant_identity(machine_seed: int) -> MachineIdentity:
    """The identity of the plant emulator's machine ``machine_seed``."""
    serial = plant_serial(machine_seed)
    return MachineIdentity(serial, machine_uri(serial))


def recorded_identity(path: Path) -> MachineIdentity | None:
    """The identity of the machine a recorded file was made on, from the file beside it:
    ``generate``'s sidecar (``STEM.json``: ``machine.seed``) or the fault benchmark's record
    (``STEM.json``: ``config.machine_seed``); ``None`` when neither says."""
    import json

    try:
        doc = json.loads(Path(path).with_suffix(".json").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if not isinstance(doc, dict):
        return None
    machine, config = doc.get("machine"), doc.get("config")
    seed = machine.get("seed") if isinstance(machine, dict) else None
    if seed is None and isinstance(config, dict):
        seed = config.get("machine_seed")
    if not isinstance(seed, int) or isinstance(seed, bool):
        return None
    return plant_identity(seed)


def identification_payload(identity: MachineIdentity, software_revision: str) -> dict[str, Any]:
    """The retained MQTT identification message."""
    from drafttwin.wire.conventions import PAYLOAD_VERSION

    return {"v": PAYLOAD_VERSION, **identity.to_dict(), "software_revision": software_revision}


__all__ = [
    "MANUFACTURER",
    "PLANT_MODEL",
    "PLANT_PRODUCT_URI",
    "PLANT_SERVER_URI",
    "TWIN_PRODUCT_URI",
    "TWIN_SERVER_URI",
    "MachineIdentity",
    "identification_payload",
    "machine_uri",
    "plant_identity",
    "plant_serial",
    "recorded_identity",
]
