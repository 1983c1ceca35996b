"""The live stepper equals the offline simulation driven by the same set-point samples."""

from __future__ import annotations

import numpy as np
import pytest

from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain, Signal, reduce, simulate
from drafttwin.mechanics.stepper import LiveStepper

RATE = 100.0


@pytest.fixture(scope="module")
def train() -> DriveTrain:
    return DriveTrain.preset("fa320a")


def _supply() -> np.ndarray:
    return np.r_[np.full(30, 48.0), np.linspace(48.0, 40.0, 40), np.full(30, 40.0)]


@pytest.mark.parametrize("reduced", [False, True])
def test_stepper_matches_simulate_on_a_speed_change(train: DriveTrain, reduced: bool) -> None:
    t = reduce(train) if reduced else train
    sup = _supply()
    # offline: the set-point samples at 0.01, 0.02, ... s, linear between them
    ref = simulate(t.with_supply_schedule(Signal(1 / RATE, 1 / RATE, sup)), len(sup) / RATE,
                   output_rate_hz=RATE, settle_s=0.5)  # fmt: skip
    live = LiveStepper(t, RATE, float(sup[0]), t0_s=0.0, settle_s=0.5)
    rows = np.array([live.step(float(f)) for f in sup])
    assert np.abs(rows - ref.node_rpm).max() < 1e-6
    # the machine really slowed down: the last rows follow the lower set-point
    motor = live.motor_node
    assert rows[-1, motor] < 0.9 * rows[0, motor]


def test_snapshot_restore_repeats_a_step(train: DriveTrain) -> None:
    live = LiveStepper(reduce(train), RATE, 48.0, settle_s=0.2)
    snap = live.snapshot()
    ahead = live.step(47.0)
    live.restore(snap)
    again = live.step(47.0)
    np.testing.assert_array_equal(ahead, again)


def test_a_train_without_motor_is_refused(train: DriveTrain) -> None:
    raw = train.to_dict()
    raw.pop("motor")
    with pytest.raises(ConfigError, match="no motor"):
        LiveStepper(DriveTrain.from_dict(raw), RATE, 48.0)


@pytest.mark.parametrize("reduced", [False, True])
def test_the_compiled_kernel_steps_exactly_as_the_dispatcher(train: DriveTrain, reduced: bool,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """The stepper calls numba's compiled overload directly and keeps its last angles for the
    next step: bit for bit the rows of the dispatcher recomputing both, look-aheads included."""
    import drafttwin.mechanics.stepper as S

    t = reduce(train) if reduced else train

    def run(recompute: bool) -> np.ndarray:
        live = LiveStepper(t, RATE, 48.0, settle_s=0.2)
        assert (live._kernel is live._integrate) == recompute
        rows = []
        for f in _supply()[25:45]:
            snap = live.snapshot()
            rows.append(live.step(f - 1.0))  # a look-ahead, undone
            live.restore(snap)
            for span in (None, 2 / RATE):
                if recompute:
                    live._after = None
                rows.append(live.step(f, span))
        return np.array(rows)

    fast = run(False)
    monkeypatch.setattr(S, "_compiled", lambda dispatcher, args: dispatcher)
    np.testing.assert_array_equal(fast, run(True))
