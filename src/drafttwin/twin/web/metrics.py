"""The twin's Prometheus metrics, in a registry of their own.

Counters and the latency histogram are updated as rows are processed; the per-machine and
per-channel gauges (speeds, residuals, alarm active, data age, sliver) are read from the
service's state when Prometheus scrapes, so that a machine or channel never shows a stale
value of another run. Units are in the names (``_rpm``, ``_seconds``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import Any

from drafttwin.twin.service import TwinService
from drafttwin.twin.store.db import EventRow

LATENCY_BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.015, 0.02, 0.03, 0.05, 0.1, 0.25, 1.0)
SPEEDS = (("drafttwin_speed_rpm", "measured", "Measured roller speed (the newest row), rpm"),
          ("drafttwin_physics_speed_rpm", "physics", "The physics' roller speed, rpm"),
          ("drafttwin_twin_speed_rpm", "twin", "The twin's (hybrid's) roller speed, rpm"),
          ("drafttwin_residual_rpm", "residual", "Measured minus twin roller speed, rpm"))  # fmt: skip
"""Per-channel gauges: (metric name, the row's field, help)."""
ALARMING = ("fault", "fault-cause", "sensor-fault")


class StateCollector:
    """Gauges read from the service's state at each scrape (a prometheus_client collector)."""

    def __init__(self, service: TwinService) -> None:
        self.service = service

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import GaugeMetricFamily

        speeds = [(GaugeMetricFamily(name, text, labels=["machine", "channel"]), field)
                  for name, field, text in SPEEDS]  # fmt: skip
        alarm = GaugeMetricFamily("drafttwin_alarm_active", "1 once the machine raised a fault "
                                  "or sensor-fault alarm in this run (the detector latches)",
                                  labels=["machine"])  # fmt: skip
        age = GaugeMetricFamily("drafttwin_data_age_seconds", "Seconds since the machine's "
                                "newest sample arrived", labels=["machine"])  # fmt: skip
        up = GaugeMetricFamily("drafttwin_source_up", "1 while the machine's source delivers",
                               labels=["machine"])  # fmt: skip
        count = GaugeMetricFamily("drafttwin_sliver_count_ktex", "Running mean count of the "
                                  "delivered sliver, ktex", labels=["machine"])  # fmt: skip
        cv = GaugeMetricFamily("drafttwin_sliver_cv_percent", "Running CV of the delivery "
                               "sensor's readings, %", labels=["machine"])  # fmt: skip
        now = time.monotonic()
        for name, st in list(self.service.states.items()):
            up.add_metric([name], 1.0 if st.state == "live" else 0.0)
            active = st.last_fault is not None and st.last_fault.kind in ALARMING
            alarm.add_metric([name], 1.0 if active else 0.0)
            if st.last_wall:
                age.add_metric([name], now - st.last_wall)
            row = st.recent[-1] if st.recent else None
            if row is not None:
                for family, field in speeds:
                    for ch, v in zip(st.mapping.channels, getattr(row, field), strict=False):
                        if math.isfinite(v):
                            family.add_metric([name, ch], float(v))
            if st.sliver is not None and math.isfinite(st.sliver.cv_pct):
                count.add_metric([name], st.sliver.count_ktex)
                cv.add_metric([name], st.sliver.cv_pct)
        yield from (f for f, _ in speeds)
        yield from (alarm, age, up, count, cv)


class Metrics:
    """Prometheus metrics of one service, in their own registry."""

    def __init__(self, service: TwinService | None = None) -> None:
        from prometheus_client import CollectorRegistry, Counter, Histogram

        self.registry = CollectorRegistry()
        self.samples = Counter("drafttwin_samples", "Samples processed", ["machine"],
                               registry=self.registry)  # fmt: skip
        self.drops = Counter("drafttwin_dropped_payloads", "Malformed payloads dropped",
                             ["machine"], registry=self.registry)  # fmt: skip
        self.alarms = Counter("drafttwin_events", "Events (gaps, reconnects, alarms)",
                              ["machine", "kind"], registry=self.registry)  # fmt: skip
        self.latency = Histogram("drafttwin_latency_seconds",
                                 "Sample received to prediction stored and pushed",
                                 buckets=LATENCY_BUCKETS, registry=self.registry)  # fmt: skip
        self.causes = Counter("drafttwin_fault_causes", "Fault alarms localised, by the most "
                              "probable cause (element:kind; none when not localised)",
                              ["machine", "cause"], registry=self.registry)  # fmt: skip
        self._samples: dict[str, Any] = {}
        if service is not None:
            self.registry.register(StateCollector(service))

    def cause(self, machine: str, cause: str) -> None:
        self.causes.labels(machine, cause).inc()

    def observe(self, machine: str, rows: int, latency_s: float) -> None:
        counter = self._samples.get(machine)
        if counter is None:  # the labelled child once per machine: its lookup took 3 us a row
            counter = self._samples[machine] = self.samples.labels(machine)
        counter.inc(rows)
        self.latency.observe(latency_s)

    def dropped(self, machine: str, count: int = 1) -> None:
        self.drops.labels(machine).inc(count)

    def event(self, ev: EventRow) -> None:
        self.alarms.labels(ev.machine, ev.kind).inc()

    def text(self, service: TwinService | None = None) -> bytes:
        """The exposition (``service``: kept for callers of the old signature)."""
        from prometheus_client import generate_latest

        return bytes(generate_latest(self.registry))


__all__ = ["LATENCY_BUCKETS", "Metrics", "StateCollector"]
