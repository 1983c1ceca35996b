"""What crosses the wire between a machine and the twin, shared by the plant's servers
(:mod:`drafttwin.plant.serve`) and the twin (:mod:`drafttwin.twin`) without either importing
the other: units (UNECE codes), ranges, ISO 8601 times, MQTT addresses, topics and JSON
payloads (:mod:`.conventions`), the OPC UA / MQTT certificates (:mod:`.certs`) and the plant
log's file format (:mod:`.plantlog`). The twin depends on these, never on the emulator that
plays a machine (an import-linter contract).
"""
