"""The plant served live: ``drafttwin plant serve`` over OPC UA (:mod:`.opcua`) or MQTT
(:mod:`.mqtt`, with the embedded broker), keeping the wall clock (:mod:`.pacing`), with its own
log of every published sample (:mod:`drafttwin.wire.plantlog`).

:mod:`drafttwin.wire` holds what the plant and the twin share: units (UNECE codes), ranges,
ISO 8601 times, topics and JSON payloads (the sample's schema in ``schemas/``), certificates.
Needs the ``twin`` extra (asyncua, paho-mqtt, amqtt), imported only when a server starts.
"""
