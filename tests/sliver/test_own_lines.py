"""A machine's own sliver lines: learned while it learns its healthy state, not alarmed
after, kept in its baseline. A healthy machine whose leveller is set right showed its middle
rollers' 10-um run-out at 59-60 cm as a chimney, and the live twin alarmed on it, where
``diagnose --healthy`` named it as the machine's own line."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drafttwin.errors import DataError
from drafttwin.mechanics import DriveTrain
from drafttwin.sliver import StapleDiagram
from drafttwin.sliver.reference import KNOWN_FACTOR, SliverReference
from drafttwin.sliver.spectra import spectrogram
from drafttwin.sliver.watch import SliverWatch

STEP_M, LINE_M = 0.002, 0.59  # 2-mm readings; the second roller's wavelength (about)


def _sliver(start_m: float, length_m: float, line_pct: float, seed: int) -> tuple[np.ndarray, ...]:
    """Readings (delivered m, ktex, time s) of a 5-ktex sliver with 1 % white noise and a
    line of ``line_pct`` at :data:`LINE_M`."""
    s = start_m + (np.arange(int(length_m / STEP_M)) + 0.5) * STEP_M
    r = 0.01 * np.random.default_rng(seed).standard_normal(s.size)
    x = 5.0 * (1.0 + r + line_pct / 100 * np.sin(2 * np.pi * s / LINE_M))
    return s, x, s / 4.27


def _watch(**kw: object) -> SliverWatch:
    return SliverWatch(DriveTrain.preset("fa320a"), StapleDiagram.preset("cotton"),
                       window_m=40.0, every_m=20.0, **kw)  # type: ignore[arg-type]  # fmt: skip


def _push(watch: SliverWatch, start_m: float, length_m: float, line_pct: float, seed: int) -> list:
    return watch.push(*_sliver(start_m, length_m, line_pct, seed))


def test_the_line_is_a_chimney_without_the_machines_lines() -> None:
    alarms = _push(_watch(), 0.0, 100.0, 0.12, 1)
    assert alarms and abs(math.log(alarms[0].wavelength_m / LINE_M)) < 0.04, alarms


def test_lines_learned_while_learning_do_not_alarm_after() -> None:
    watch = _watch(learning=True)
    assert _push(watch, 0.0, 101.0, 0.12, 1) == []  # learning: no alarm
    assert watch.learned is not None and watch.learned.windows == 4  # ends 40, 60, 80, 100 m
    assert watch.learned.metres == pytest.approx(100.0, rel=0.01)
    assert watch.end_learning() is None and not watch.learning and watch.own_lines is watch.learned
    known = 0
    for k in range(5):  # the same line: the machine's own, named as such
        assert _push(watch, 101.0 + 20 * k, 20.0, 0.12, 2 + k) == []
        assert watch.last is not None and not watch.last.causes
        known += bool(watch.last.known) and bool(watch.summary()["own_lines"])
    assert known >= 3, known
    said = watch.summary()  # what /api/status and the page show
    assert not said["learning"] and said["learned"]["windows"] == 4
    grown = _push(watch, 201.0, 60.0, 0.36, 9)  # three times the line: a fault
    assert len(grown) == 1 and abs(math.log(grown[0].wavelength_m / LINE_M)) < 0.04


def test_a_relearn_forgets_the_lines() -> None:
    watch = _watch(learning=True)
    _push(watch, 0.0, 60.0, 0.12, 1)
    watch.end_learning()
    watch.relearn()
    assert watch.learned is None and watch.own_lines is None and watch.learning


def test_the_reference_averages_band_variance_channel_by_channel() -> None:
    s, x, _ = _sliver(0.0, 40.0, 0.12, 1)
    a = spectrogram(x, STEP_M)
    b = spectrogram(_sliver(0.0, 40.0, 0.36, 2)[1], STEP_M)
    ref = SliverReference.of(a).add(b, 20.0)
    assert ref.windows == 2 and ref.metres == pytest.approx(60.0)
    np.testing.assert_allclose(ref.wavelength_m, a.wavelength_m, rtol=1e-12)
    np.testing.assert_allclose(ref.amplitude_pct,
                               np.sqrt((a.amplitude_pct**2 + b.amplitude_pct**2) / 2), rtol=1e-12)  # fmt: skip
    j = int(np.argmin(np.abs(np.log(ref.wavelength_m / LINE_M))))
    at = float(ref.amplitude_pct[j])
    assert ref.holds(KNOWN_FACTOR * at * 0.99, [LINE_M])
    assert not ref.holds(KNOWN_FACTOR * at * 1.01, [LINE_M])
    assert not ref.holds(0.0, [100.0])  # a channel the reference does not reach is new


def test_the_reference_round_trips_and_refuses_what_it_cannot_trust() -> None:
    ref = SliverReference.of(spectrogram(_sliver(0.0, 40.0, 0.12, 1)[1], STEP_M))
    back = SliverReference.from_doc(ref.to_doc(), "b.json", "fix")
    np.testing.assert_array_equal(back.amplitude_pct, ref.amplitude_pct)
    np.testing.assert_array_equal(back.wavelength_m, ref.wavelength_m)
    assert (back.windows, back.metres) == (ref.windows, ref.metres)
    doc = ref.to_doc()
    for bad, where in ((dict(doc, amplitude_pct=[float("nan")] * len(doc["amplitude_pct"])),
                        "amplitude_pct"),
                       (dict(doc, wavelength_m=doc["wavelength_m"][::-1]), "rise"),
                       (dict(doc, amplitude_pct=doc["amplitude_pct"][1:]), "rise"),
                       (dict(doc, windows=0), "windows"), ([1, 2], "not an object")):  # fmt: skip
        with pytest.raises(DataError, match=where) as err:
            SliverReference.from_doc(bad, "b.json", "delete b.json")
        assert "b.json" in str(err.value)


def test_a_check_in_a_worker_thread_neither_tears_nor_loses_readings() -> None:
    """The live twin checks in a worker thread while its loop pushes: the check read the
    three buffers at different moments ("boolean index did not match", the window never
    judged, its chimney never raised) and its trim dropped readings pushed meanwhile. Here a
    batch arrives exactly while the check gathers the buffers."""
    import threading

    s, x, t = _sliver(0.0, 101.0, 0.36, 4)
    alone = _watch()
    alone.push(s, x, t)
    live = _watch(checks_now=False)
    live.push(s[:-500], x[:-500], t[:-500])
    late = (s[-500:], x[-500:], t[-500:])
    pusher = threading.Thread(target=live.push, args=late)

    class Arriving(list):  # type: ignore[type-arg]
        def __iter__(self):  # noqa: ANN204 - the batch comes while the check reads
            if not pusher.is_alive() and pusher.ident is None:
                pusher.start()
                pusher.join(timeout=0.5)  # with the lock it waits for the check
            return super().__iter__()

    live._x = Arriving(live._x)
    assert live.due()
    live.check()
    pusher.join(timeout=10)
    kept = np.concatenate(live._s)
    assert kept.size == np.concatenate(live._x).size == np.concatenate(live._t).size
    assert kept[-1] == s[-1] and np.all(np.diff(kept) > 0)  # the late batch kept, in order
    assert [a.delivered_m for a in live.alarms] == [a.delivered_m for a in alone.alarms]


def test_a_chimney_names_the_other_line_its_channel_holds() -> None:
    """The second and third rollers' lines lie 2 % apart in one 7-%-wide channel: offline the
    whole record peaked on the second, the live window on the third, and neither named the
    other. Now each chimney says what else its channel holds."""
    from drafttwin.sliver.diagnose import diagnose_sliver
    from drafttwin.sliver.record import Sliver
    from drafttwin.sliver.wavelengths import wavelength_table

    train = DriveTrain.preset("fa320a")
    table = wavelength_table(train)
    second = next(e for e in table.elements if e.name == "roller second").wavelength_m
    third = next(e for e in table.elements if e.name == "roller third").wavelength_m
    s = (np.arange(50_000) + 0.5) * STEP_M
    r = 0.01 * np.random.default_rng(5).standard_normal(s.size)
    x = 5.0 * (1.0 + r + 0.003 * np.sin(2 * np.pi * s / second))
    dx = diagnose_sliver(Sliver(x, STEP_M), train, StapleDiagram.preset("cotton"))
    (cause,) = [c for c in dx.causes if abs(math.log(c.wavelength_m / second)) < 0.01]
    assert cause.candidates[0].element == "roller second"
    assert "roller third" in cause.extra["same_channel"]
    assert f"also holds the line at {third * 100:.3g} cm (roller third" in cause.verdict
    centre = cause.extra["channel_m"]
    for name in cause.extra["same_channel"]:
        w = next(e for e in table.elements if e.name == name).wavelength_m
        assert abs(math.log2(w / centre)) <= 1 / 20 + 1e-12, name
