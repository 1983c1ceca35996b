"""An alarm and its probable cause share a time stamp: /api/alarms (oldest first) listed the
cause before its alarm after a restart, and reads disagreed (DuckDB's INSERT OR IGNORE does
not keep the insertion order)."""

from pathlib import Path

from drafttwin.twin.store.db import EventRow, TwinStore
from drafttwin.twin.store.history import events_window


def test_a_cause_comes_after_its_alarm_in_every_read(tmp_path: Path) -> None:
    store = TwinStore(tmp_path)
    rows = []
    for k in range(50):
        rows += [
            EventRow("m", "fault", 1000 + k, "{}"),
            EventRow("m", "fault-cause", 1000 + k, "{}"),
        ]
    store.commit([], rows)
    store.close()
    for _ in range(2):  # a reopened store (a restarted twin) reads the same
        store = TwinStore(tmp_path)
        got = events_window(store.con, None, ("fault", "fault-cause"), False, 0, 10**12, 1000)
        store.close()
        assert [(t, k) for _, k, t, _ in got] == [(r.ts_us, r.kind) for r in rows]
