"""One machine's live hybrid against independent offline computations: the physics against
the offline simulation, the cleaning against reject_spikes_causal, the twin's predictions
against the model's batch predict; reordering, duplicates, late rows and gaps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from drafttwin.data.io import read_measurements
from drafttwin.data.preprocessing import reject_spikes_causal
from drafttwin.mechanics import DriveTrain, Signal, reduce, simulate
from drafttwin.models import MechanisticModel
from drafttwin.models.registry import load_model
from drafttwin.plant.emulator import attach_truth
from drafttwin.twin.live import MachineTwin, Reorder, SpikeFilter
from drafttwin.twin.live import Pending as P

from ._twin import CHANNELS

pytestmark = pytest.mark.timeout(120)


def _feed(twin: MachineTwin, series, order=None) -> list:  # noqa: ANN001
    ts = np.round(series.time_s * 1e6).astype(np.int64)
    sp = series.inputs["supply_hz"]
    rows = []
    for i in range(len(ts)) if order is None else order:
        rows += twin.receive(int(ts[i]), i, series.values[i], float(sp[i]))
    return rows + twin.flush()


@pytest.fixture(scope="module")
def replayed(twin_files: tuple[Path, Path]):  # noqa: ANN201
    record, model_path = twin_files
    series = attach_truth(read_measurements(record), record)
    values = series.values.copy()
    values[[50, 130, 333, 334], [0, 2, 1, 1]] *= [1.3, 0.7, 1.25, 1.25]  # spikes, and a pair
    series = series.with_values(values)
    model = load_model(model_path)
    twin = MachineTwin("m", model, 100.0)
    return series, model, twin, _feed(twin, series)


def test_live_physics_is_the_offline_simulation_of_the_setpoints(replayed) -> None:  # noqa: ANN001
    series, _, _, rows = replayed
    train = reduce(DriveTrain.preset("fa320a"))
    sup = series.inputs["supply_hz"]
    ref = simulate(train.with_supply_schedule(Signal(0.01, 0.01, sup)), len(sup) / 100.0,
                   output_rate_hz=100.0)  # fmt: skip
    maps = {m.channel: m.node for m in train.output_channels()}
    expected = np.column_stack([ref.node_rpm[:, train.node_index(maps[c])] for c in CHANNELS])
    physics = np.array([r.physics for r in rows])
    assert np.abs(physics - expected).max() < 1e-6


def test_cleaning_is_the_causal_spike_rule(replayed) -> None:  # noqa: ANN001
    series, _, twin, rows = replayed
    physics0 = rows[0].physics
    _, rejected = reject_spikes_causal(series.values, 0.10, floor=0.5 * np.abs(physics0))
    assert twin.filter.rejected == int(rejected.sum()) >= 3


def test_twin_equals_the_models_batch_prediction(replayed) -> None:  # noqa: ANN001
    series, model, _, rows = replayed
    physics = np.array([r.physics for r in rows])
    table = pd.DataFrame(
        {"time": series.time_s, **{c: physics[:, j] for j, c in enumerate(CHANNELS)}}
    )
    cleaned, _ = reject_spikes_causal(series.values, 0.10, floor=0.5 * np.abs(physics[0]))
    batch = model.predict_values(series.with_values(cleaned), MechanisticModel(table))
    twin = np.array([r.twin for r in rows])
    both = np.isfinite(batch).all(axis=1) & np.isfinite(twin).all(axis=1)
    assert both.sum() > 0.9 * len(rows)
    assert np.abs(twin[both] - batch[both]).max() < 1e-3


def test_shuffled_rows_within_the_reorder_depth_give_the_same_result(
    replayed, twin_files: tuple[Path, Path]
) -> None:  # noqa: ANN001
    series, model, _, rows = replayed
    order = np.arange(len(series))
    rng = np.random.default_rng(0)
    for start in range(5, len(order) - 3, 7):  # swap neighbours here and there
        if rng.random() < 0.5:
            order[start], order[start + 1] = order[start + 1], order[start]
    twin = MachineTwin("m", model, 100.0)
    again = _feed(twin, series, [*order[:300], 299, 10, *order[300:]])  # a duplicate, a late row
    assert [r.ts_us for r in again] == [r.ts_us for r in rows]
    np.testing.assert_allclose([r.twin for r in again], [r.twin for r in rows], equal_nan=True)
    assert (twin.reorder.duplicate, twin.reorder.late) == (1, 1)


def test_missing_rows_are_observed_as_missing_and_long_gaps_restart(replayed) -> None:  # noqa: ANN001
    series, model, _, rows = replayed
    n = len(series)
    keep = np.r_[0:100, 110:250, 550:n]  # 10 rows lost (0.1 s), then 300 (3 s > 2 s)
    twin = MachineTwin("m", model, 100.0)
    out = _feed(twin, series, keep)
    kinds = [e.kind for e in twin.events]
    assert kinds == ["missing", "gap"]
    assert len(out) == len(keep) + 10
    filled = [r for r in out if r.seq == -1]
    assert len(filled) == 10 and all(np.isnan(r.measured).all() for r in filled)
    assert np.isfinite(filled[-1].physics).all()


def test_spike_filter_matches_the_batch_rule_on_random_data() -> None:
    rng = np.random.default_rng(4)
    x = 400 + np.cumsum(rng.normal(0, 5, (500, 3)), axis=0)
    x[rng.random(x.shape) < 0.03] *= 1.5
    x[rng.random(x.shape) < 0.02] = np.nan
    x[200:, 1] *= 1.3  # a level step the rule must follow
    floor = np.array([100.0, 100.0, 100.0])
    batch, _ = reject_spikes_causal(x, 0.1, floor=floor)
    f = SpikeFilter(3, floor=floor)
    live = np.array([f(row) for row in x])
    np.testing.assert_array_equal(np.isnan(live), np.isnan(batch))
    np.testing.assert_array_equal(live[~np.isnan(live)], batch[~np.isnan(batch)])


def test_reorder_releases_in_time_order() -> None:
    r = Reorder(10, depth=2)
    out = []
    for t in (0, 20, 10, 30, 30, 5, 60, 70, 80):
        out += [p.ts_us for p in r.push(P(t, 0, np.zeros(1), 1.0))]
    out += [p.ts_us for p in r.flush()]
    assert out == [0, 10, 20, 30, 60, 70, 80]
    assert (r.duplicate, r.late) == (1, 1)


def test_machines_of_one_tick_share_one_network_pass_with_the_same_result(replayed) -> None:  # noqa: ANN001
    """The service forecasts all machines of a tick in one batched pass: the same rows as each
    machine alone, up to float32 rounding of the batch."""
    import asyncio

    from drafttwin.twin.service import MachineState, TwinService
    from drafttwin.twin.sources.base import Sample
    from drafttwin.twin.sources.mapping import MachineMap

    series, model, _, rows = replayed
    names = ["a", "b", "c"]
    states = {n: MachineState(MachineTwin(n, model, 100.0), MachineMap(n, CHANNELS), "test")
              for n in names}  # fmt: skip
    service = TwinService(states, [])
    got: dict[str, list] = {n: [] for n in names}
    service.subscribers.append(lambda name, out, ev: got[name].extend(out))
    calls = []
    real = service._finish
    service._finish = lambda rnd: (calls.append(len(rnd)), real(rnd))  # type: ignore[method-assign]
    ts = np.round(series.time_s * 1e6).astype(np.int64)
    sp = series.inputs["supply_hz"]

    async def feed() -> None:
        for i in range(len(ts)):
            for n in names:
                service.on_sample(Sample(n, int(ts[i]), i, series.values[i], float(sp[i])))
            await asyncio.sleep(0)

    asyncio.run(feed())
    assert max(calls) == 3  # three machines per network pass
    for n in names:
        assert [r.ts_us for r in got[n]] == [r.ts_us for r in rows]
        np.testing.assert_array_equal([r.physics for r in got[n]], [r.physics for r in rows])
        np.testing.assert_allclose([r.twin for r in got[n]], [r.twin for r in rows], atol=1e-3,
                                   equal_nan=True)  # fmt: skip


def test_a_machine_the_source_never_sends_waits_and_says_so(replayed, monkeypatch) -> None:  # noqa: ANN001
    """Connected without a sample of the machine (a wrong name in the mapping) is 'waiting',
    not 'live' (it read live at 0 samples all run), and said once; a sample makes it live."""
    import asyncio

    from drafttwin.twin import service as service_module
    from drafttwin.twin.service import MachineState, TwinService
    from drafttwin.twin.sources.base import Sample
    from drafttwin.twin.sources.mapping import MachineMap

    series, model, _, _ = replayed
    monkeypatch.setattr(service_module, "WAITING_S", 0.2)
    st = MachineState(MachineTwin("a", model, 100.0), MachineMap("a", CHANNELS), "test")
    service = TwinService({"a": st}, [], silent_s=0.4)
    kinds: list[str] = []
    service.event_hooks.append(lambda ev: kinds.append(ev.kind))

    async def run() -> None:
        service.report("a", "source-live", "mqtt://x")
        assert st.state == "waiting"
        watch = asyncio.create_task(service._watch())
        await asyncio.sleep(0.8)
        assert kinds.count("no-samples") == 1 and st.state == "waiting"
        service.on_sample(Sample("a", 0, 0, series.values[0], 48.47))
        await asyncio.sleep(0.05)
        assert st.state == "live"
        service._stop.set()
        await watch

    asyncio.run(run())
