"""The reduced plant as a generator of healthy running: what it keeps and what it misses.

The fault benchmark's 24 h of healthy running would be 80 times cheaper on the reduced
plant; docs/faults.md ("A cheaper healthy generator?") compares it with the full plant on six
machines and does not use it. This checks that verdict on one machine: the common-mode
levels agree, the streams the rigid couplings feed do not.
"""

from drafttwin.diagnosis.detect import FaultDetector
from drafttwin.studies.faults.generator import channel_stats, tasks
from drafttwin.studies.faults.plan import run_record
from drafttwin.studies.faults.score import features


def test_reduced_plant_keeps_the_levels_but_not_the_lags_and_encoder_runs():
    full, reduced = [t for t in tasks(0, 1, 60.0, seed=1) if t["set"] != "tuning"]
    assert reduced["generator"] == "reduced" and "generator" not in full
    assert (full["machine_seed"], full["seed"]) == (reduced["machine_seed"], reduced["seed"])
    ref = FaultDetector().reference_s
    a = channel_stats([features(run_record(full))], ref)
    b = channel_stats([features(run_record(reduced))], ref)
    # kept: each roller's and the motor's level (mean within 0.1 SD, block-to-block SD within
    # 8 %: on this record 0-4 % apart; the lag-1 autocorrelation of 45 blocks within 0.1: its
    # sampling error is about 0.05)
    for ch in ("front", "second", "third", "back", "motor"):
        sd = a[ch]["dev_sd"]
        assert abs(b[ch]["dev_sd"] / sd - 1.0) < 0.08, ch
        assert abs(b[ch]["level_mean"] - a[ch]["level_mean"]) < 0.1 * sd, ch
        assert abs(b[ch]["ac1"] - a[ch]["ac1"]) < 0.1, ch
    # missed: the third roller's angle lag wanders far less (no gear backlash or mesh
    # compliance), and without the rigid couplings' vibration the encoders repeat one count
    # far longer (the stuck rule's statistic)
    assert b["lag_third"]["dev_sd"] < 0.5 * a["lag_third"]["dev_sd"]  # here 0.06 vs 0.52 mrad
    runs_a = max(a[ch]["run_max"] for ch in ("second", "third", "back"))
    runs_b = max(b[ch]["run_max"] for ch in ("second", "third", "back"))
    assert runs_b > 2 * runs_a  # on this record 81 against 10 samples
