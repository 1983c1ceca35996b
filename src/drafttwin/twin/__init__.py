"""The live twin: machines streaming over OPC UA or MQTT (or a replayed file), the hybrid per
sample in real time, a history that survives a crash, a page and Prometheus metrics.

Rooms, each a package that says what it holds:

* :mod:`~drafttwin.twin.sources`: where samples come from (replay, OPC UA with its client
  security, MQTT), the mapping file and the ``--source`` text;
* :mod:`~drafttwin.twin.store`: the DuckDB history, its reading back and its audit against the
  plant's log;
* :mod:`~drafttwin.twin.web`: the page, REST API, WebSocket, metrics and the hall's page, behind
  one token guard.

At the top: :mod:`~drafttwin.twin.live` (one machine's causal hybrid),
:mod:`~drafttwin.twin.faultwatch` (live fault detection), :mod:`~drafttwin.twin.service` (the
loop), :mod:`~drafttwin.twin.build` (a service from the command line's pieces),
:mod:`~drafttwin.twin.hall` (a hall of twins as Ray actors), :mod:`~drafttwin.twin.aio` (a
bounded shutdown) and :mod:`~drafttwin.twin.publish` (the twin's own OPC UA server and MQTT
topics). The rooms run one way: ``web`` above the service above ``sources`` and ``store``,
which know nothing of each other (``lint-imports``). The plant emulator served live is
:mod:`drafttwin.plant.serve`.
Needs the ``twin`` extra: ``pip install 'drafttwin[twin]'``.
"""
