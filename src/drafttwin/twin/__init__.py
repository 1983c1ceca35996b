"""The live twin: machines streaming over OPC UA or MQTT (or a replayed file), the hybrid per
sample in real time, a history that survives a crash, a page and Prometheus metrics.

Modules: :mod:`~drafttwin.twin.live` (one machine's causal hybrid), :mod:`~drafttwin.twin.sources`
and :mod:`~drafttwin.twin.mapping` (where samples come from), :mod:`~drafttwin.twin.store` and
:mod:`~drafttwin.twin.history` (DuckDB history), :mod:`~drafttwin.twin.service` (the loop),
the plant emulator served live is :mod:`drafttwin.plant.serve`.
Needs the ``twin`` extra: ``pip install 'drafttwin[twin]'``.
"""
