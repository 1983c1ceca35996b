"""One detector: plant records replayed through ``twin run`` raise the alarms ``diagnose``
raises on the same records (issue 36): the same rule and test, the alarm time within one
block, the same first cause, overlapping severity intervals, and the same sliver chimneys.

Each record is replayed as a machine whose blocks start on its first sample (a name whose
block phase is 0), with the detector file both paths use (``--learn 0``: the file judges as
it is). The records carry what the plant's data path does to every record (lost rows,
spikes); one carries a gap of lost rows across a block's edge besides."""

from __future__ import annotations

import json
import subprocess
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from drafttwin.data.io import read_measurements
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.diagnose import Diagnoser
from drafttwin.diagnosis.residuals import record_features
from drafttwin.mechanics import DriveTrain

from ._twin import cli, env

RATE = 100.0
ONSET = 16.0


def phase_zero_names(n: int) -> list[str]:
    """Machine names whose blocks start on the first sample (block_phase 0 at 100 Hz)."""
    out, i = [], 0
    while len(out) < n:
        name = f"eq{i}"
        if zlib.crc32(name.encode()) % 100 == 0:
            out.append(name)
        i += 1
    return out


def plant_records(folder: Path, tuning_s: float, cases: list[tuple[str, str | None]],
                  duration_s: float) -> tuple[list[Path], dict[str, Path]]:  # fmt: skip
    """Healthy tuning records (two machines) and one record per case (its own machine): a
    fault spec, ``None`` (healthy), or ``"gap"`` (healthy with 0.6 s of lost rows)."""
    from drafttwin.plant import Machine, Plant
    from drafttwin.plant.faults import FaultSpec

    plant = Plant()
    tuning = []
    for k in range(2):
        rec = plant.run(tuning_s, RATE, seed=100 + k,
                        machine=Machine.draw(plant.train, plant.config, 200 + k))  # fmt: skip
        tuning.append(folder / f"tuning{k}.parquet")
        rec.write(tuning[-1])
    records = {}
    for j, (name, spec) in enumerate(cases):
        faults = [] if spec in (None, "gap") else [FaultSpec.parse(spec)]
        rec = plant.run(duration_s, RATE, seed=300 + j, faults=faults,
                        machine=Machine.draw(plant.train, plant.config, 400 + j))  # fmt: skip
        if spec == "gap":  # a run of lost rows across a block's edge
            rec.series.values[1985:2045] = np.nan
            assert rec.series.motor_rpm is not None
            rec.series.motor_rpm[1985:2045] = np.nan
        records[name] = folder / f"{name}.parquet"
        rec.write(records[name])
    return tuning, records


def offline(records: dict[str, Path], det: FaultDetector) -> dict[str, Any]:
    """Every alarm ``diagnose`` raises on each record (the stream it pushes the record
    through), each window's first cause and interval."""
    train = DriveTrain.preset("fa320a")
    dx = Diagnoser(train, det)
    out = {}
    for name, path in records.items():
        series = read_measurements(path)
        first = dx.diagnose(series)  # what the command prints: its first alarm's causes
        from drafttwin.diagnosis.residuals import measured, physics_prediction

        stream = dx.stream(float(np.median(np.diff(series.time_s))))
        step = stream.push(series.time_s, measured(series), physics_prediction(train, series))
        step += stream.finish()
        causes = {round(r.alarm.time_s, 2): dx.locate(r)[1] for r in step.requests}
        out[name] = {"alarms": step.alarms, "causes": causes, "first": first}
    return out


def live(tmp: Path, model: Path, detector: Path, records: dict[str, Path]) -> dict[str, Any]:
    """The same records replayed through ``twin run`` (one process, a machine each); its
    stored alarms and causes."""
    names = dict(zip(records, phase_zero_names(len(records)), strict=True))
    sources = []
    for rec, machine in names.items():
        sources += ["--source", f"replay:{records[rec]}?speed=inf&machine={machine}"]
    store = tmp / "store"
    done = subprocess.run(cli("twin", "run", "--model", str(model), *sources, "--store",
                              str(store), "--detector", str(detector), "--learn", "0", "--quiet"),
                          env=env(), capture_output=True, text=True, timeout=600, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    events = tmp / "events.json"
    q = subprocess.run(cli("twin", "query", "--store", str(store), "--events", "--out",
                           str(tmp / "events.csv")), env=env(), capture_output=True, text=True,
                       timeout=120, check=False)  # fmt: skip
    assert q.returncode == 0, q.stderr
    import pandas as pd

    frame = pd.read_csv(tmp / "events.csv")
    events.write_text(frame.to_json(orient="records"))
    by_machine = {m: r for r, m in names.items()}
    out: dict[str, Any] = {r: {"alarms": [], "causes": {}, "chimneys": []} for r in records}
    for ev in frame.to_dict("records"):
        rec = by_machine[ev["machine"]]
        if ev["kind"] in ("fault", "sensor-fault"):
            out[rec]["alarms"].append(json.loads(ev["detail"]))
        elif ev["kind"] == "fault-cause":
            d = json.loads(ev["detail"])
            out[rec]["causes"][round(d["alarm_s"], 2)] = d.get("causes") or []
        elif ev["kind"] == "sliver-chimney":
            out[rec]["chimneys"].append(ev["detail"])
    return out


def same_word(off: dict[str, Any], on: dict[str, Any], record: str) -> None:
    """The live alarms are the offline ones: rule and test, time within a block, the first
    cause named alike with overlapping intervals."""
    a_off, a_on = off["alarms"], on["alarms"]
    assert len(a_on) == len(a_off), (record, a_off, a_on)
    for x, y in zip(a_off, a_on, strict=True):
        assert (x.rule, x.test, x.direction) == (y["rule"], y["test"], y["direction"]), record
        assert abs(x.time_s - y["alarm_s"]) <= 1.0, (record, x, y)
    for t, causes in off["causes"].items():
        live_causes = next((c for s, c in on["causes"].items() if abs(s - t) <= 1.0), None)
        assert live_causes is not None, (record, t, on["causes"])
        if not causes:
            assert not live_causes, record
            continue
        top, lt = causes[0], live_causes[0]
        assert (top.element, top.kind) == (lt["element"], lt["kind"]), (record, top, lt)
        lo, hi = lt["interval"]
        assert lo <= top.interval[1] and top.interval[0] <= hi, (record, top.interval, lt)


@pytest.fixture(scope="module")
def physics_model(tmp_path_factory: pytest.TempPathFactory, twin_files: tuple[Path, Path]) -> Path:
    """A model of the FA320A's physics alone (the twin's detector reads its drive train)."""
    folder = tmp_path_factory.mktemp("eqmodel")
    model = folder / "physics.dtm"
    done = subprocess.run(cli("fit", "--model", "mechanistic", "--data", str(twin_files[0]),
                              "--out", str(model), "--quiet"), env=env(), capture_output=True,
                          text=True, timeout=300, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    return model


def check(tmp: Path, model: Path, tuning_s: float, cases: list[tuple[str, str | None]],
          duration_s: float) -> dict[str, Any]:  # fmt: skip
    tuning, records = plant_records(tmp, tuning_s, cases, duration_s)
    fit = subprocess.run(cli("twin", "fit-detector", "--model", str(model), "--healthy",
                             ",".join(map(str, tuning)), "--out", str(tmp / "det.json")),
                         env=env(), capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    assert fit.returncode == 0, fit.stderr
    train = DriveTrain.preset("fa320a")
    det = FaultDetector().fit([record_features(train, read_measurements(p)) for p in tuning])
    off = offline(records, det)
    on = live(tmp, model, tmp / "det.json", records)
    for rec in records:
        same_word(off[rec], on[rec], rec)
    return {"offline": off, "live": on}


@pytest.mark.slow
def test_live_alarms_are_the_offline_ones(tmp_path: Path, physics_model: Path) -> None:
    """Healthy running (with a gap), a machine fault and two sensor faults: the same alarms
    and causes live and offline (lags not watched: short tuning)."""
    cases = [("healthy", "gap"), ("belt", f"main_belt:belt_wear:severity=0.5:onset={ONSET}"),
             ("stuck", f"back:stuck:severity=2:onset={ONSET}"),
             ("dropout", f"front:dropout:severity=0.3:onset={ONSET}")]  # fmt: skip
    got = check(tmp_path, physics_model, 60.0, cases, 36.0)
    off = got["offline"]
    assert not off["healthy"]["alarms"]  # the gap of lost rows raises nothing
    assert off["belt"]["first"].causes[0].name == "main_belt:belt_wear"
    assert off["stuck"]["first"].causes[0].name == "back:stuck"


@pytest.mark.long
def test_every_fault_family_live_as_offline(tmp_path: Path, physics_model: Path) -> None:
    """Every fault family (bearing, load, belt, motor, gear wear and chain elongation in the
    angle lags, encoder gain, stuck and dropout), healthy running with a gap, and a record
    with its sliver channel: tuning long enough for the lag streams to be watched."""
    s = f"onset={ONSET}"
    cases = [("healthy", "gap"), ("bearing", f"front_roller:bearing_friction:severity=10:{s}"),
             ("load", f"front:load_loss:severity=0.4:{s}"),
             ("belt", f"main_belt:belt_wear:severity=0.5:{s}"),
             ("motor", f"motor:torque_loss:severity=0.2:{s}"),
             ("wear", f"E-F:wear:severity=150:{s}"),
             ("chain", f"rear_chain:elongation:severity=2:{s}"),
             ("gain", f"third:gain:severity=0.005:{s}"), ("stuck", f"back:stuck:severity=2:{s}"),
             ("dropout", f"front:dropout:severity=0.3:{s}")]  # fmt: skip
    got = check(tmp_path, physics_model, 215.0, cases, 40.0)
    named = {r: o["first"].causes[0].name for r, o in got["offline"].items()
             if o["first"].causes}  # fmt: skip
    assert named.get("wear") == "E-F:wear" and named.get("belt") == "main_belt:belt_wear"


@pytest.mark.long
def test_the_sliver_channel_live_as_offline(tmp_path: Path, physics_model: Path) -> None:
    """A record with its sliver channel (an eccentric front roller, which the encoders do
    not see): the twin's chimney alarms are the offline watch's."""
    from drafttwin.diagnosis.sliver_evidence import sliver_evidence
    from drafttwin.plant import Plant
    from drafttwin.plant.faults import FaultSpec
    from drafttwin.plant.sliver_channel import SliverSettings

    rec = tmp_path / "sliver.parquet"
    Plant().run(30.0, RATE, seed=4, sliver=SliverSettings(),
                faults=[FaultSpec.parse("front:eccentricity:severity=0.3:onset=0")]).write(rec)  # fmt: skip
    ev = sliver_evidence(rec, DriveTrain.preset("fa320a"), read_measurements(rec))
    assert ev is not None
    off = [(a["wavelength_m"], a["element"]) for a in ev[0]["alarms"]]
    store = tmp_path / "store"
    run = subprocess.run(cli("twin", "run", "--model", str(physics_model), "--source",
                             f"replay:{rec}?speed=inf&machine={phase_zero_names(1)[0]}",
                             "--store", str(store), "--detector", "none", "--quiet"),
                         env=env(), capture_output=True, text=True, timeout=600, check=False)  # fmt: skip
    assert run.returncode == 0, run.stderr
    q = subprocess.run(cli("twin", "query", "--store", str(store), "--events", "--out",
                           str(tmp_path / "ev.csv")), env=env(), capture_output=True, text=True,
                       timeout=120, check=False)  # fmt: skip
    assert q.returncode == 0, q.stderr
    import pandas as pd

    frame = pd.read_csv(tmp_path / "ev.csv")
    chimneys = frame[frame["kind"] == "sliver-chimney"]["detail"].tolist()
    assert off and len(chimneys) == len(off), (off, chimneys)
    for (wave, element), text in zip(off, chimneys, strict=True):
        assert f"{wave * 100:.2f} cm" in text and element in text, (wave, element, text)
