"""Thresholds from a short healthy record are said to be unsure: on the plant a healthy 60-s
record alarmed with thresholds from 60-180 s of another healthy record of its machine (every
machine tried), never with 300 s (a helper's hunt: `diagnose --healthy` on 60-s records gave
a healthy record a gear-wear verdict)."""

import numpy as np

from drafttwin.diagnosis.detect import LEVEL_TUNING_BLOCKS, FaultDetector
from drafttwin.diagnosis.residuals import block_features

from ..test_faults_angles import counted


def _features(seconds: float, seed: int):
    n = int(seconds * 100)
    y, true = counted(0.0, 50.0, n, seed)
    return block_features(y, true, np.arange(n) * 0.01, 1.0)


def test_a_short_tuning_record_gets_a_note_a_long_one_none() -> None:
    short = FaultDetector().fit([_features(60.0, 1)])
    assert short.tuning_blocks_ == 45  # 60 blocks less the 15-s reference window
    note = short.levels_note()
    assert note is not None and "45 s of healthy running" in note and "300 s" in note
    long = FaultDetector().fit([_features(60.0 + LEVEL_TUNING_BLOCKS, 2)])
    assert long.tuning_blocks_ >= LEVEL_TUNING_BLOCKS and long.levels_note() is None
    # several records add up, each past its own reference window
    two = FaultDetector().fit([_features(15.0 + LEVEL_TUNING_BLOCKS / 2, s) for s in (3, 4)])
    assert two.tuning_blocks_ == LEVEL_TUNING_BLOCKS - (LEVEL_TUNING_BLOCKS % 2)


def test_the_note_survives_the_detector_file() -> None:
    short = FaultDetector().fit([_features(60.0, 1)])
    again = FaultDetector.from_state(short.to_state())
    assert again.levels_note() == short.levels_note()
    older = short.to_state()
    older.pop("tuning_blocks")  # a detector file written before the count was kept
    assert FaultDetector.from_state(older).levels_note() is None


def test_a_detector_from_an_older_file_is_written_again_without_a_count() -> None:
    """A twin that read a detector file written before the count was kept stopped with an
    AttributeError in to_state (its first alarm's ranking pickles the state)."""
    older = FaultDetector().fit([_features(60.0, 1)]).to_state()
    older.pop("tuning_blocks")
    again = FaultDetector.from_state(older).to_state()
    assert "tuning_blocks" not in again and FaultDetector.from_state(again).levels_note() is None
