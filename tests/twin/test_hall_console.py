"""The hall's console prints its shards' events as 'twin run' prints its own (it printed
only a status line per 10 s: an alarm in a shard never reached the operator's terminal)."""

from __future__ import annotations

import json

from drafttwin.diagnosis.cusum import Alarm
from drafttwin.twin.alarms import event_line
from drafttwin.twin.faultwatch import alarm_detail
from drafttwin.twin.hall import ConsoleFollower, ConsoleLines
from drafttwin.twin.store.db import EventRow


def _shard(lines: ConsoleLines) -> dict:
    return {"state": "running", "console": json.loads(json.dumps(lines.status()))}  # as Ray sends


def test_each_shards_events_are_printed_once_as_twin_run_prints_them() -> None:
    a, b = ConsoleLines(), ConsoleLines()
    alarm = EventRow("m1", "fault", 100_000_000, alarm_detail(Alarm(100.0, 99, "belt", -1, 80.0)))
    a.hook(alarm)
    a.hook(EventRow("m1", "sample", 1, "not a console kind"))  # nothing printed of it
    b.hook(EventRow("m2", "learned", 2, "learned its healthy state over 120 s of running"))
    follow = ConsoleFollower()
    first = follow.new_lines([_shard(a), None, _shard(b)])
    assert first == [event_line("m1", "fault", 100_000_000, alarm.detail),
                     "m2 learned: learned its healthy state over 120 s of running"]  # fmt: skip
    assert first[0] is not None and first[0].startswith("ALARM m1 fault belt down")
    assert follow.new_lines([_shard(a), None, _shard(b)]) == []  # printed once
    b.hook(EventRow("m2", "sliver-chimney", 3, "sliver chimney at 14.14 cm"))
    assert follow.new_lines([_shard(a), {"state": "restarting"}, _shard(b)]) == [
        "m2 sliver-chimney: sliver chimney at 14.14 cm"
    ]


def test_a_shard_started_again_is_followed_from_its_first_line() -> None:
    old = ConsoleLines()
    for k in range(5):
        old.hook(EventRow("m1", "gap", k, f"gap {k}"))
    follow = ConsoleFollower()
    assert len(follow.new_lines([_shard(old)])) == 5
    new = ConsoleLines()  # Ray started the shard's process again: numbers from 1
    new.run_id = old.run_id + "-again"
    new.hook(EventRow("m1", "source-live", 9, "live again"))
    assert follow.new_lines([_shard(new)]) == ["m1 source-live: live again"]


def test_only_the_last_lines_are_kept() -> None:
    lines = ConsoleLines()
    for k in range(ConsoleLines.KEEP + 30):
        lines.hook(EventRow("m1", "gap", k, f"gap {k}"))
    kept = lines.status()["lines"]
    assert len(kept) == ConsoleLines.KEEP and kept[-1] == [
        ConsoleLines.KEEP + 30,
        f"m1 gap: gap {ConsoleLines.KEEP + 29}",
    ]


def test_twin_run_prints_what_its_detector_said_at_the_start_quiet_or_not(
    twin_files, tmp_path
) -> None:
    """The start's events (learning, or the stored baseline it watches with) came before the
    console's printer was attached, and --quiet printed no event at all."""
    from ._twin import run_cli

    record, model = twin_files
    for extra in ((), ("--quiet",)):
        got = run_cli("twin", "run", "--model", str(model), "--source", f"replay:{record}?speed=inf",
                      "--learn", "60", "--store", str(tmp_path / f"s{len(extra)}"), *extra)  # fmt: skip
        assert got.returncode == 0, got.stderr
        assert "learning: learning its healthy state: 60 s of running" in got.stderr, got.stderr


def test_a_stop_says_which_shards_ran_and_which_were_still_starting() -> None:
    """A shard that ran (its status listed machines) but did not end within the stop's wait
    was reported as "still starting"."""
    from drafttwin.twin.hall import _stop_note

    seen = [{"state": "running", "machines": {"m1": {}}}, {"state": "loading"}, None,
            {"state": "not answering", "machines": {"m4": {}}}]  # fmt: skip
    note = _stop_note(4, [1, 2, 3], seen)
    assert note.startswith("shard 0 committed what it received; shards 1, 2 still starting")
    assert "shard 3 ran but did not end within 2 s of the stop" in note
    assert (
        "lost" in note and _stop_note(2, [], seen[:2]) == "shards 0, 1 committed what they received"
    )
