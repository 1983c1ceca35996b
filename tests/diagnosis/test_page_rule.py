"""The diagnosis page says which rule raised the alarm and plots that rule's own statistic
against its own limit (issue 29, item 5); the detection result carries the rule."""

from dataclasses import replace

import numpy as np
import pytest

from drafttwin.data.series import MeasurementSeries
from drafttwin.diagnosis.cusum import RULES
from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.diagnosis.diagnose import Diagnosis, sensor_cause
from drafttwin.diagnosis.locate import Cause
from drafttwin.diagnosis.residuals import block_features
from drafttwin.mechanics import DriveTrain

from ..test_faults_angles import TUNING_ROWS, counted, lost_rows

N = 8000  # 80 s at 100 Hz
T = np.arange(N) * 0.01


def features(step_mrad: float, seed: int, n: int = N):
    y, true = counted(step_mrad, 50.0, n, seed)
    y = lost_rows(y, seed)
    return y, true, block_features(y, true, np.arange(n) * 0.01, 1.0)


@pytest.fixture(scope="module")
def detector():
    # the lags are watched with 400 decided blocks of tuning: 2 x 225 here
    det = FaultDetector().fit([features(0.0, s, TUNING_ROWS)[2] for s in (21, 22)])
    # these synthetic counts of a constant speed repeat one value through a step's 0.1-s
    # dip (see test_faults_angles): the stuck rule is not what the lag test is about
    det.run_limit_ = det.run_limit_ * 10
    return det


def page_of(dx, y, info):
    from drafttwin.report.diagnosis import render_diagnosis

    series = MeasurementSeries(time_s=T, values=y[:, :4], motor_rpm=y[:, 4],
                               inputs={"supply_hz": np.full(N, 50.0)})  # fmt: skip
    return render_diagnosis(dx, DriveTrain.preset("fa320a"), series, info)


def test_a_lag_jump_alarm_is_shown_as_the_jump_rule_with_its_own_statistic(detector):
    y, _, f = features(3.0, 24)
    # the ranking is not under test here (tests/test_faults_angles.py): a cause as it gives
    cause = Cause(element="E-F", kind="wear", family="gear", severity=150.0,
                  interval=(140.0, 160.0), parameter="wear depth (um)", chi2=3.0,
                  probability=0.9, group=("C-D:wear",))  # fmt: skip
    dx = Diagnosis(f, detector.run(f), [cause])
    a = dx.alarm
    assert a is not None and a.rule == "jump" and a.test == "lag_second"
    det = dx.detection
    # the rule's own statistic crosses its limit in the alarm block; the CUSUM did not
    assert det.jump is not None and det.jump[a.block, 7] > 1.0 and det.statistic[a.block, 7] < 1
    info = {"data": "x.parquet", "physics": "preset", "thresholds_from": "two records",
            "detector": detector.describe(), "creep_rel_sd": 0.07}  # fmt: skip
    html = page_of(dx, y, info)
    assert "raised by the lag jump rule on lag_second" in html
    assert "Cannot be told apart from C-D:wear" in html
    assert 'id="detector"' in html and "twice the largest in the healthy records" in html
    assert "long_run_factor" not in html  # no parameter dump
    walk = np.sqrt(np.diag(detector.lag_walk_) * 60.0)  # mrad per minute, as the page says
    assert f"random-walk by lag_second {walk[0]:.1f}, lag_third {walk[1]:.1f}" in html


def test_a_sensor_alarm_names_the_sensor_rule(detector):
    _, _, f = features(0.0, 25)
    run, stale = f.run.copy(), f.stale_runs.copy()
    run[40, 3] = stale[40, 3] = 3 * detector.stale_limit_[3]  # a held value: it moved the lag
    f = replace(f, run=run, stale=stale)
    det = detector.run(f)
    a = det.first
    assert a is not None
    dx = Diagnosis(f, det, [sensor_cause(a, f.lost[a.block], f.run[a.block])])
    assert a is not None and a.rule == "sensor" and a.test == "stuck_back"
    assert dx.detection.sensor is not None and dx.detection.sensor[40, 5 + 3] == pytest.approx(3)
    assert set(RULES) == {"cusum", "jump", "sensor"}
    from drafttwin.report.diagnosis import rule_statistic, summary

    value, label, _ = rule_statistic(dx)
    assert value[40] == pytest.approx(3) and "back" in label
    assert "raised by the sensor rule on stuck_back" in summary(dx).html


def test_a_look_alike_that_does_not_fit_is_not_called_indistinguishable(detector):
    """A belt ramp's page said "cannot be told apart from motor:gain" beside "motor:gain
    does not fit, p 2.3e-14": the fit tells them apart."""
    from drafttwin.cli._dxprint import _marked
    from drafttwin.report.diagnosis import look_alikes

    y, _, f = features(3.0, 24)
    top = Cause(element="E-F", kind="wear", family="gear", severity=150.0,
                interval=(140.0, 160.0), parameter="wear depth (um)", chi2=3.0,
                probability=0.8, group=("C-D:wear", "motor:gain"), dof=8, fit_p=0.5)  # fmt: skip
    alike = replace(top, element="C-D", group=("E-F:wear", "motor:gain"), probability=0.15)
    misfit = Cause(element="motor", kind="gain", family="sensor", severity=0.01,
                   interval=(0.009, 0.011), parameter="gain", chi2=90.0, probability=0.05,
                   group=("E-F:wear", "C-D:wear"), dof=8, fit_p=2.3e-14)  # fmt: skip
    causes = [top, alike, misfit]
    assert look_alikes(top, causes) == (["C-D:wear"], ["motor:gain"])
    # a cause that does not fit itself is told apart by nothing: its group stands
    assert look_alikes(misfit, causes) == (["E-F:wear", "C-D:wear"], [])
    info = {"data": "x.parquet", "physics": "preset", "thresholds_from": "two records",
            "detector": detector.describe(), "creep_rel_sd": 0.07}  # fmt: skip
    html = page_of(Diagnosis(f, detector.run(f), causes), y, info)
    assert "Cannot be told apart from C-D:wear with these sensors" in html
    assert "C-D:wear (same direction, no fit: motor:gain)" in html
    alone = replace(top, group=("motor:gain",))
    html = page_of(Diagnosis(f, detector.run(f), [alone, misfit]), y, info)
    assert "Cannot be told apart" not in html
    assert (
        "No other fitting candidate moves the measured channels the same way (motor:gain: "
        "the same direction, but no fit here)" in html
    )
    as_json = [{**c.to_dict()} for c in causes]
    assert _marked(as_json[0], as_json) == ["C-D:wear", "motor:gain (no fit)"]
    assert _marked(as_json[2], as_json) == ["E-F:wear", "C-D:wear"]
