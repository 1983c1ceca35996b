"""The plant's true roller surfaces at a fine rate: the recording stays bit for bit what it is
without them, the mean surface speed is the rollers' speed times their radius, and an eccentric
roller's radius modulates its surface speed once per revolution by e / r."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from drafttwin import ROLLERS
from drafttwin.errors import ConfigError
from drafttwin.mechanics import DriveTrain, simulate, simulate_chunks
from drafttwin.mechanics.simulation import interval_means
from drafttwin.plant import Plant, PlantConfig, PlantRecording
from drafttwin.plant import surface as S
from drafttwin.plant.config import Eccentricity
from drafttwin.plant.faults import FaultSpec

FINE_HZ = 2000.0
GEAR_RUNOUT = "A-B:runout:severity=30:onset=0.5"  # a gear fault: the kernel's table schedule
ROLLER_ECC = "front:eccentricity:severity=0.3:onset=0.5:ramp=0.5"  # load signal and radius


def _same_recording(a: PlantRecording, b: PlantRecording) -> None:
    for x, y in ((a.series.values, b.series.values), (a.true_rpm, b.true_rpm),
                 (a.true_motor_rpm, b.true_motor_rpm), (a.series.motor_rpm, b.series.motor_rpm),
                 (a.series.time_s, b.series.time_s), (a.missing, b.missing),
                 (a.outlier, b.outlier),
                 (a.series.inputs["supply_hz"], b.series.inputs["supply_hz"])):  # fmt: skip
        assert np.array_equal(x, y, equal_nan=True)
    info = dict(b.info)
    assert "surface" not in a.info and info.pop("surface")["rate_hz"] == FINE_HZ
    assert "roller_eccentricity_um" not in a.info["plant_config"]["eccentricity"]
    info["plant_config"] = {**info["plant_config"], "eccentricity": {
        k: v for k, v in info["plant_config"]["eccentricity"].items()
        if k != "roller_eccentricity_um"}}  # fmt: skip
    assert info == a.info


@pytest.mark.parametrize("fault", [None, GEAR_RUNOUT, ROLLER_ECC])
def test_surface_leaves_the_recording_bit_identical(fault):
    faults = [FaultSpec.parse(fault)] if fault else []
    plant = Plant()
    a = plant.run(2.0, seed=5, faults=faults)
    b = plant.run(2.0, seed=5, faults=faults, surface_rate_hz=FINE_HZ)
    assert a.surface is None and b.surface is not None
    _same_recording(a, b)
    s = b.surface
    assert s.length_m.shape == (4001, 4) and s.rollers == ROLLERS
    assert np.array_equal(s.time_s, np.arange(4001) / FINE_HZ)
    assert np.all(s.length_m[0] == 0.0) and np.all(np.diff(s.length_m, axis=0) > 0)


def test_sidecar_records_the_run_outs(tmp_path):
    fault = FaultSpec.parse(ROLLER_ECC)
    rec = Plant().run(1.0, seed=4, faults=[fault], surface_rate_hz=FINE_HZ)
    info = json.loads(rec.write(tmp_path / "r.csv")[2].read_text())
    surf = info["surface"]
    assert info["plant_config"]["eccentricity"]["roller_eccentricity_um"] == 10.0
    assert surf["rate_hz"] == FINE_HZ and surf["radius_m"]["front"] == pytest.approx(0.0225)
    outs = surf["run_outs"]
    assert [o["roller"] for o in outs] == [*ROLLERS, "front"]
    assert outs[-1]["eccentricity_um"] == pytest.approx(60.0)
    assert outs[-1]["source"]["kind"] == "eccentricity"
    assert surf["eccentricity_um"] == pytest.approx(rec.surface.eccentricity_um)  # type: ignore[union-attr]


def test_fine_pieces_join_bit_identically(monkeypatch):
    """Pieces of the fine run that end between two recording rows (0.3333 s = 666.6 rows)."""
    faults = [FaultSpec.parse(GEAR_RUNOUT)]
    whole = Plant().run(2.0, seed=6, faults=faults, surface_rate_hz=FINE_HZ)
    monkeypatch.setattr(S, "CHUNK_S", 0.3333)
    pieces = Plant().run(2.0, seed=6, faults=faults, surface_rate_hz=FINE_HZ)
    _same_recording(Plant().run(2.0, seed=6, faults=faults), pieces)
    assert whole.surface is not None and pieces.surface is not None
    assert np.array_equal(whole.surface.length_m, pieces.surface.length_m)


def test_simulation_angles_give_its_interval_means_bit_for_bit():
    train = DriveTrain.preset("fa320a")
    plain = simulate(train, 0.6, output_rate_hz=100.0, settle_s=0.1)
    res = simulate(train, 0.6, output_rate_hz=100.0, settle_s=0.1, angles=True)
    assert plain.angle_rad is None and res.angle_rad is not None
    assert res.angle_rad.shape == (61, len(train.node_names))
    for name in ("time_s", "node_rpm", "point_rpm", "energy_j"):
        assert np.array_equal(getattr(plain, name), getattr(res, name))
    assert np.array_equal(interval_means(res.angle_rad, 100.0), res.node_rpm)
    pieces = list(simulate_chunks(train, 0.6, chunk_s=0.23, output_rate_hz=100.0, settle_s=0.1,
                                  angles=True))  # fmt: skip
    assert len(pieces) == 3
    for p in pieces:
        assert p.angle_rad is not None and len(p.angle_rad) == len(p.time_s) + 1
        assert np.array_equal(interval_means(p.angle_rad, 100.0), p.node_rpm)
    joined = np.vstack([pieces[0].angle_rad[:1], *(p.angle_rad[1:] for p in pieces)])  # type: ignore[index]
    assert np.array_equal(joined, res.angle_rad)


def _diameters(rec: PlantRecording) -> np.ndarray:
    by_name = {r["name"]: r["diameter_mm"] for r in rec.info["true_train"]["roller"]}
    return np.array([by_name[r] for r in ROLLERS]) * 1e-3


def test_mean_surface_speed_is_pi_d_n():
    no_runout = PlantConfig(eccentricity=Eccentricity(roller_eccentricity_um=0.0))
    for plant, tol in ((Plant(config=no_runout), 1e-9), (Plant(), None)):
        rec = plant.run(2.0, seed=2, surface_rate_hz=FINE_HZ)
        assert rec.surface is not None
        length = rec.surface.length_m[-1]
        expected = math.pi * _diameters(rec) * rec.true_rpm.mean(axis=0) / 60.0
        mean_speed = length / 2.0
        if tol is None:  # the run-out term adds at most 2 e to the travel
            tol = 2 * 10e-6 / length.min()
            assert not np.allclose(mean_speed, expected, rtol=1e-12, atol=0)
        np.testing.assert_allclose(mean_speed, expected, rtol=tol, atol=0)


def _once_per_rev(y: np.ndarray, angle: np.ndarray) -> complex:
    """Least-squares phasor of ``y`` at the angle's once-per-revolution (sin, cos, mean)."""
    x = np.column_stack([np.sin(angle), np.cos(angle), np.ones_like(angle)])
    c, *_ = np.linalg.lstsq(x, y, rcond=None)
    return complex(c[0], c[1])


def test_eccentric_roller_modulates_its_surface_speed_by_e_over_r():
    """Severity 0.3 on the front roller: e = 0.3 / 0.05 x 10 um = 60 um added to its healthy
    10 um (phasors: ~50-70 um), e / r ~ 0.3 %. The radius setting does not touch the dynamics,
    so a run without radius run-out has the very same angles: its surface speed is the angular
    speed alone. The angular speed's own once-per-revolution line (gear eccentricity, the
    healthy and the faulty load modulation) is 0.07 % on the healthy machine and 0.06-0.11 %
    with this fault (seeds 1-5; the fault's load moves it by ~0.04 %), 20-40 % of e / r: so the
    surface speed's total line is e / r only within that, and the radius's line is the
    difference of the two phasors (0.9996 e / r: the 2 kHz interval means attenuate a 30 Hz
    line by 4e-4)."""
    fault = [FaultSpec.parse("front:eccentricity:severity=0.3:onset=0")]
    rec = Plant().run(3.0, seed=1, surface_rate_hz=FINE_HZ, faults=fault)
    no_runout = PlantConfig(eccentricity=Eccentricity(roller_eccentricity_um=0.0))
    bare = Plant(config=no_runout).run(3.0, seed=1, surface_rate_hz=FINE_HZ, faults=fault)
    assert rec.surface is not None and bare.surface is not None
    r = _diameters(rec)[0] / 2
    theta = bare.surface.length_m[:, 0] / r  # angle from t = 0
    omega = np.diff(theta) * FINE_HZ
    mid = 0.5 * (theta[1:] + theta[:-1])
    total = _once_per_rev(np.diff(rec.surface.length_m[:, 0]) * FINE_HZ / (r * omega.mean()) - 1,
                          mid)  # fmt: skip
    angular = _once_per_rev(omega / omega.mean() - 1, mid)
    e_over_r = rec.surface.eccentricity_um["front"] * 1e-6 / r
    assert 50.0 < rec.surface.eccentricity_um["front"] < 70.0
    assert abs(total - angular) == pytest.approx(e_over_r, rel=0.1)
    assert abs(angular) < 0.4 * e_over_r
    assert abs(abs(total) - e_over_r) <= abs(angular) * 1.01
    healthy = rec.info["surface"]["eccentricity_um"]
    assert healthy["second"] == healthy["third"] == healthy["back"] == 10.0


def test_surface_rate_must_be_a_whole_multiple_of_the_rate():
    for bad in (150.0, 2050.0, 50.0, math.nan):
        with pytest.raises(ConfigError, match="surface_rate_hz|multiple") as err:
            Plant().run(1.0, rate_hz=100.0, surface_rate_hz=bad)
        assert err.value.where == "surface_rate_hz"
    # 3 kHz is a multiple, but 1/3000 s is no whole number of the 20 us RK4 steps
    with pytest.raises(ConfigError, match="step differently") as err:
        Plant().run(1.0, rate_hz=100.0, surface_rate_hz=3000.0)
    assert err.value.where == "surface_rate_hz"


def test_a_damaged_flute_slows_the_surface_over_its_arc_once_per_revolution():
    """A flute fault acts on the roller's surface only (the encoders' speeds stay as they
    are) and is non-sinusoidal: its surface speed has a comb of harmonics of the roller's
    rotation, each about ``2 severity arc sinc(h arc)`` (arc = 1/20)."""
    import math

    from drafttwin.plant import Plant
    from drafttwin.plant.faults import FaultSpec

    plant = Plant()
    healthy = plant.run(4.0, 100.0, seed=2, surface_rate_hz=2000.0)
    flute = plant.run(4.0, 100.0, seed=2, surface_rate_hz=2000.0,
                      faults=[FaultSpec.parse("front:flute:severity=0.15:onset=0")])  # fmt: skip
    assert np.array_equal(healthy.series.values, flute.series.values, equal_nan=True)
    dv = np.diff(flute.surface.length_m[:, 0] - healthy.surface.length_m[:, 0]) * 2000.0
    v = np.diff(healthy.surface.length_m[:, 0]).mean() * 2000.0
    rev_hz = v / (math.pi * 0.045)
    t = flute.surface.time_s[1:] - 0.00025
    for h in (1, 2, 3, 5):
        z = 2 * np.mean(dv / v * np.exp(-2j * np.pi * h * rev_hz * t))
        expected = 2 * 0.15 / 20 * np.sinc(h / 20)
        assert abs(z) == pytest.approx(expected, rel=0.05)
