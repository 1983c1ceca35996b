"""The twin's results over MQTT (paho-mqtt): topics of its own, JSON with a shipped schema.

Topics, per machine ``NAME`` (``PREFIX`` = ``drafttwin/twin`` unless ``?prefix=`` says)::

    PREFIX/NAME/prediction   a processed sample (twin-prediction.schema.json), <= max_hz
    PREFIX/NAME/alarm        an alarm and, later, its probable cause (twin-alarm.schema.json)
    PREFIX/NAME/alarms       retained: the machine's alarms that are active or wait for an
                             operator, most severe first (twin-alarms.schema.json)
    PREFIX/NAME/status       retained: health and current alarm, once a second
                             (twin-status.schema.json); the will message sets it offline
    PREFIX/NAME/sliver       retained: the sliver watched (count, CV, chimneys) and the
                             leveller's recommended action point, when they change
                             (twin-sliver.schema.json); a recommendation, never a setting

Each machine has its own connection, so that its will message (MQTT allows one per
connection) marks exactly that machine offline when the twin dies; a clean stop publishes
the offline status itself. paho's network thread sends; ``publish`` never blocks the event
loop. Messages paho holds for a slow or absent broker are bounded (``max_queued_messages``);
beyond, a message is refused and counted as dropped.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from typing import Any

from drafttwin.errors import ConfigError
from drafttwin.twin.publish.base import CLOSE_S, QUEUE_LEN, Publisher
from drafttwin.twin.publish.payload import active_alarms, alarm, prediction
from drafttwin.twin.service import MachineState, TwinService
from drafttwin.twin.store.db import EventRow, SampleRow

PREFIX = "drafttwin/twin"
CONNECT_S = 5.0
"""How long the broker may take to acknowledge the first connection."""


def topic(prefix: str, machine: str, what: str) -> str:
    return f"{prefix}/{machine}/{what}"


def encode(payload: dict[str, Any]) -> bytes:
    return json.dumps(payload, allow_nan=False, separators=(",", ":")).encode()


class MqttPublisher(Publisher):
    """Publish to the broker at ``host:port`` with QoS ``qos`` (0 or 1)."""

    kind = "mqtt"

    def __init__(self, host: str, port: int, *, qos: int = 1, prefix: str = PREFIX,
                 **kw: Any) -> None:  # fmt: skip
        super().__init__(f"mqtt://{host}:{port}?qos={qos}", **kw)
        self.host, self.port, self.qos, self.prefix = host, port, qos, prefix
        self.clients: dict[str, Any] = {}
        self._alarms_stand: set[str] = set()  # machines whose retained alarms were published

    async def open(self, service: TwinService) -> None:
        await super().open(service)
        try:
            for name, st in service.states.items():
                await self._connect(name, st)
            deadline = time.monotonic() + CONNECT_S
            while not all(c.is_connected() for c in self.clients.values()):
                if time.monotonic() > deadline:
                    raise ConfigError(f"the MQTT broker at {self.host}:{self.port} did not "
                                      f"acknowledge within {CONNECT_S:g} s", where="--publish",
                                      fix="start the broker or correct mqtt://HOST:PORT")  # fmt: skip
                await asyncio.sleep(0.02)
        except BaseException:
            await self._stop_clients()
            raise

    async def _connect(self, name: str, st: MachineState) -> None:
        """One machine's connection, its will the machine's status saying offline."""
        import paho.mqtt.client as mqtt

        assert self.health is not None
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2,
                             client_id=f"drafttwin-twin-{name}-{id(self):x}")  # fmt: skip
        client.max_queued_messages_set(QUEUE_LEN)
        client.will_set(topic(self.prefix, name, "status"),
                        encode(self.health.status(st, "offline")), qos=self.qos, retain=True)  # fmt: skip
        client.reconnect_delay_set(1, 30)
        self.clients[name] = client
        # a refused connection raises here (an OSError: the caller names the option)
        await asyncio.to_thread(client.connect, self.host, self.port, 30)
        client.loop_start()  # paho's thread reconnects after a loss

    def _publish(self, machine: str, what: str, payload: dict[str, Any], retain: bool) -> Any:
        info = self.clients[machine].publish(topic(self.prefix, machine, what), encode(payload),
                                             qos=self.qos, retain=retain)  # fmt: skip
        if info.rc != 0:  # paho's queue full, or not connected at QoS 0
            self.dropped += 1
        return info

    async def send_prediction(self, st: MachineState, row: SampleRow) -> None:
        self._publish(st.twin.name, "prediction", prediction(st, row), retain=False)

    async def send_alarm(self, st: MachineState, ev: EventRow) -> None:
        self._publish(st.twin.name, "alarm", alarm(ev), retain=False)
        # the machine's alarms as they stand, retained: a client that connects later reads
        # them at once (empty when none is active or waiting for an operator)
        assert self.service is not None
        self._publish(st.twin.name, "alarms", active_alarms(self.service, st.twin.name),
                      retain=True)  # fmt: skip

    async def send_status(self, st: MachineState, status: dict[str, Any]) -> None:
        self._publish(st.twin.name, "status", status, retain=True)
        if st.twin.name not in self._alarms_stand:  # a client reads them at once, even none
            self._alarms_stand.add(st.twin.name)
            assert self.service is not None
            self._publish(st.twin.name, "alarms", active_alarms(self.service, st.twin.name),
                          retain=True)  # fmt: skip

    async def send_sliver(self, st: MachineState, doc: dict[str, Any]) -> None:
        self._publish(st.twin.name, "sliver", doc, retain=True)

    async def close(self, service: TwinService) -> None:
        if not self.clients:
            return
        assert self.health is not None
        with contextlib.suppress(Exception):
            await asyncio.wait_for(self.drain(service), CLOSE_S / 4)
        sent = [self._publish(name, "status", self.health.status(st, "offline"), retain=True)
                for name, st in service.states.items() if name in self.clients]  # fmt: skip
        deadline = time.monotonic() + CLOSE_S / 2  # QoS 1: the broker's acknowledgements
        while not all(i.is_published() for i in sent if i.rc == 0):
            if time.monotonic() > deadline:
                break
            await asyncio.sleep(0.02)
        await self._stop_clients()

    async def _stop_clients(self) -> None:
        for c in self.clients.values():
            c.disconnect()  # a clean DISCONNECT: the broker drops the will
        await asyncio.gather(*(asyncio.to_thread(c.loop_stop) for c in self.clients.values()))
        self.clients = {}


__all__ = ["PREFIX", "MqttPublisher", "encode", "topic"]
