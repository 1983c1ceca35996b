"""A restarted twin keeps the alarm book of the run before: an alarm nobody acknowledged had
vanished from /api/alarms/active and /api/status at a restart, though the fault was still
there (and, present in the reference window, was not raised again)."""

from __future__ import annotations

import json
from pathlib import Path

from drafttwin.diagnosis.cusum import Alarm
from drafttwin.twin.alarms import AlarmBook
from drafttwin.twin.build import build_service
from drafttwin.twin.faultwatch import alarm_detail
from drafttwin.twin.store.db import EventRow, TwinStore

CAUSE = {"element": "main_belt", "kind": "belt_wear", "severity": 0.45, "probability": 1.0}


def _events(machine: str) -> list[EventRow]:
    """Alarm A (belt, open, with its cause), B (acknowledged, confirmed, back to normal:
    done), C (a sensor rule, acknowledged only)."""
    a = Alarm(100.0, 99, "belt", 1, 80.0)
    b = Alarm(200.0, 199, "level_front", -1, 190.0)
    c = Alarm(300.0, 299, "stuck_motor", 0, 299.0, "sensor")
    ids = {x.test: AlarmBook.key(machine, x.time_s, x.test) for x in (a, b, c)}
    return [
        EventRow(machine, "fault", 100_000_000, alarm_detail(a)),
        EventRow(machine, "fault-cause", 100_000_000, alarm_detail(a, [CAUSE])),
        EventRow(machine, "fault", 200_000_000, alarm_detail(b)),
        EventRow(machine, "fault-cleared", 250_000_000,
                 json.dumps({"test": b.test, "alarm_s": b.time_s, "cleared_s": 250.0, "why": "x"})),
        EventRow(machine, "sensor-fault", 300_000_000, alarm_detail(c, [{"element": "motor"}])),
        EventRow(machine, "alarm-ack", 1_800_000_000_000_000,  # the wall clock
                 json.dumps({"what": "acknowledged", "alarms": [ids["level_front"], ids["stuck_motor"]]})),
        EventRow(machine, "alarm-ack", 1_800_000_001_000_000,
                 json.dumps({"what": "confirmed", "alarms": [ids["level_front"]]})),
    ]  # fmt: skip


def test_the_book_of_a_stored_run_comes_back(twin_files: tuple[Path, Path], tmp_path: Path) -> None:
    record, model = twin_files
    store = TwinStore(tmp_path / "store")
    store.commit([], _events("m1"))
    store.close()
    service = build_service(model, [f"replay:{record}?machine=m1"], store_dir=tmp_path / "store",
                            detector="none")  # fmt: skip
    try:
        retained = service.faults.book.retained("m1")
        by_test = {a.test: a for a in retained}
        assert set(by_test) == {"belt", "stuck_motor"}  # B was done: not retained
        belt, stuck = by_test["belt"], by_test["stuck_motor"]
        assert belt.active and not belt.acked and belt.cause == CAUSE and belt.change_s == 80.0
        assert stuck.kind == "sensor-fault" and stuck.acked and not stuck.confirmed
        last = service.states["m1"].last_fault
        assert last is not None and last.kind == "sensor-fault" and last.ts_us == 300_000_000
    finally:
        if service.writer is not None:
            service.writer.close()


def test_details_that_are_not_alarms_are_passed_over() -> None:
    book = AlarmBook()
    shown = book.restore([EventRow("m", "fault", 1, "not json"),
                          EventRow("m", "alarm-ack", 2, '{"alarms": "x"}'),
                          EventRow("m", "fault-cleared", 3, "{}")])  # fmt: skip
    assert shown == [] and book.alarms == {}


def test_a_restarted_twin_watches_its_active_alarms_return_to_normal(
    twin_files: tuple[Path, Path], tmp_path: Path
) -> None:
    """An alarm read back from the store stayed active for good (only relearn cleared it):
    its baseline is stored with it now, and the restarted twin judges its return to normal
    against it; an angle lag's is not carried (its lag counts from the run's start)."""
    import numpy as np

    record, model = twin_files
    base = np.linspace(-1e-4, 1e-4, 8)
    belt = Alarm(100.0, 99, "belt", -1, 80.0)
    lag = Alarm(150.0, 149, "lag_second", 1, 140.0)
    old = Alarm(160.0, 159, "level_front", 1, 150.0)  # stored before baselines were
    stuck = Alarm(300.0, 299, "stuck_motor", 0, 299.0, "sensor")
    store = TwinStore(tmp_path / "store")
    store.commit([], [EventRow("m1", "fault", 100_000_000, alarm_detail(belt, baseline=base)),
                      EventRow("m1", "fault", 150_000_000, alarm_detail(lag, baseline=base)),
                      EventRow("m1", "fault", 160_000_000, alarm_detail(old)),
                      EventRow("m1", "sensor-fault", 300_000_000, alarm_detail(stuck))])  # fmt: skip
    store.close()
    service = build_service(model, [f"replay:{record}?machine=m1"], store_dir=tmp_path / "store",
                            detector="auto")  # fmt: skip
    try:
        watch = service.states["m1"].watch
        assert watch is not None
        carried = {a.test: b for a, b in watch.stream.carried()}
        assert set(carried) == {"belt", "stuck_motor"} and carried["stuck_motor"] is None
        np.testing.assert_array_equal(carried["belt"], base)
    finally:
        if service.writer is not None:
            service.writer.close()
