"""The blocked folds' rule (issue 38, item 2): a residual model is kept only when it beats
its baseline on every fold and by more than 1 % on the mean; accumulated changes must also
beat the measured residual they start from, held; a judge's effort stops growing with the
record's length."""

from __future__ import annotations

import numpy as np
import pytest

from drafttwin.models.estimators import accumulation as acc
from drafttwin.models.estimators.folds import JUDGE_WINDOWS, FoldScores, judge_epochs

BLOCKS = [(0, 10), (10, 20), (20, 30)]


def _folds(**scores: list[float]) -> FoldScores:
    return FoldScores(dict(scores), BLOCKS, [10, 10, 10])


def test_a_correction_must_win_every_fold_and_by_one_percent_on_the_mean() -> None:
    assert _folds(none=[1.0, 1.0, 1.0], level=[0.5, 0.6, 0.7]).reliable("level")
    two_of_three = _folds(none=[1.0, 1.0, 1.0], level=[0.5, 0.6, 1.2])
    assert two_of_three.wins("level") == 2 and not two_of_three.reliable("level")
    too_close = _folds(none=[1.0, 1.0, 1.0], level=[0.995, 0.995, 0.995])
    assert too_close.wins("level") == 3 and not too_close.reliable("level")
    assert acc.choose_on_folds("level", two_of_three).kept == acc.CORRECTION_NONE
    assert acc.choose_on_folds("level", two_of_three, test=False).kept == "level"


def test_accumulated_changes_must_beat_the_measured_residual_held() -> None:
    """A gain over the physics alone that the anchor held scores as well is the measured
    start's, not the residual model's: no correction, and the level is chosen when it wins."""
    folds = _folds(none=[2.0, 3.0, 3.0], held=[1.0, 1.5, 1.0], accumulate=[1.1, 1.4, 0.9],
                   level=[1.8, 2.7, 2.8])  # fmt: skip
    assert folds.wins("accumulate") == 2 and not folds.reliable("accumulate")
    assert folds.baseline("level") == [2.0, 3.0, 3.0]  # the held anchor is accumulation's
    choice = acc.choose_on_folds("accumulate", folds)
    assert choice.kept == acc.CORRECTION_NONE and choice.wins == 2
    assert choice.scores[acc.CORRECTION_HELD] == pytest.approx(3.5 / 3)
    # accumulation has the lower mean, but only the level wins reliably
    assert folds.mean("accumulate") < folds.mean("level")
    assert acc.choose_accumulation_on_folds([True, False], folds).accumulate is False
    beats_held = _folds(none=[2.0, 3.0, 3.0], held=[1.0, 1.5, 1.0], accumulate=[0.5, 0.7, 0.6])
    assert beats_held.reliable("accumulate")
    # neither wins reliably: the lower fold mean, accumulation on a tie
    tie = _folds(none=[1.0] * 3, held=[0.5] * 3, accumulate=[1.1] * 3, level=[1.1] * 3)
    assert acc.choose_accumulation_on_folds([True, False], tie).accumulate is True


def test_a_judge_goes_through_all_windows_in_fewer_epochs_on_a_long_record() -> None:
    assert judge_epochs(12, JUDGE_WINDOWS) == 12 and judge_epochs(0, 10) == 1
    assert (
        judge_epochs(12, 4 * JUDGE_WINDOWS) == 3
    )  # the same steps as 12 epochs over JUDGE_WINDOWS
    assert judge_epochs(2, 100 * JUDGE_WINDOWS) == 1  # at least once over all of them


def test_a_judge_of_a_300_s_record_trains_a_quarter_of_the_final_nets_steps() -> None:
    """100 Hz, stride 4, 15 epochs: the final net goes 15 times through 7500 windows, each of
    three judges through the 5000 outside its block. With 600 windows' worth per epoch the
    judges got 2 epochs (9 % of the final net's steps), lost a fold on the generalisation
    benchmark's training record and refused corrections that fully trained judges kept on
    every fold (docs/models.md, "Validation on folds")."""
    final_steps, judge_windows = 15 * 7500, 5000
    assert judge_epochs(15, judge_windows) * judge_windows >= final_steps / 4


def test_the_fold_table_labels_every_row_and_names_what_accumulation_had_to_beat() -> None:
    from drafttwin.cli._fitprint import _fold_lines

    folds = _folds(none=[2.0, 3.0, 3.0], held=[1.0, 1.5, 1.0], accumulate=[1.1, 1.4, 0.9],
                   level=[2.1, 2.9, 3.1])  # fmt: skip
    choice = acc.choose_accumulation_on_folds([True, False], folds).to_dict()
    assert choice["accumulate"] is True  # neither wins reliably: the lower fold mean
    correction = {**acc.choose_on_folds("accumulate", folds).to_dict(), **folds.to_dict()}
    text = "\n".join(_fold_lines(correction, choice))
    rows = [line for line in text.splitlines() if line.startswith("  ")]
    assert [r.split("  ")[1].strip() for r in rows] == [
        "physics alone",
        "measured residual held",
        "accumulated changes",
        "residual level",
    ]
    assert len({r.index("[") for r in rows}) == 1  # one column of per-fold cells
    assert (
        "no correction: the physics alone predicts (the residual model beat the physics "
        "alone and the measured residual held on 2 of 3 folds" in text
    )


def test_folds_follow_the_records_when_there_are_several() -> None:
    from drafttwin.models.estimators.windows import blocked_folds, record_folds

    assert record_folds(19, 1000, (0, 500), 3) == [(19, 500), (500, 1000)]
    assert record_folds(0, 300, (0,), 3) == blocked_folds(0, 300, 3)  # one record: blocks
    six = tuple(range(0, 600, 100))  # six records of 100 rows: three runs of two records
    assert record_folds(0, 600, six, 3) == [(0, 200), (200, 400), (400, 600)]
    assert record_folds(0, 600, (0, 100, 550), 3) == [(0, 100), (100, 550), (550, 600)]


def test_each_output_channel_is_corrected_only_where_it_wins_every_fold() -> None:
    """A correction that helps one roller may hurt another: the verdict is per channel, the
    other channels predict their physics, and the tuning's score is that of the mix."""
    channel = {"none": [[1.0, 1.0]] * 3, "level": [[0.5, 1.6], [0.6, 1.5], [0.7, 0.9]]}
    means = {k: [sum(f) / 2 for f in v] for k, v in channel.items()}
    folds = FoldScores(means, BLOCKS, [10, 10, 10], channel_scores=channel)
    assert folds.channel_wins("level") == [3, 1]
    assert folds.channel_reliable("level") == [True, False]
    choice = acc.choose_on_folds("level", folds)
    assert choice.kept == "level" and choice.channels == (True, False)
    assert choice.corrected(2).tolist() == [True, False]
    assert list(choice.chosen_fold_nrmse) == pytest.approx([0.75, 0.8, 0.85])
    assert acc.choose_on_folds("level", folds, test=False).channels == (True, True)
    # by the mean over the channels it won 1 fold of 3: one verdict for all refused it
    assert folds.wins("level") == 1 and not folds.reliable("level")
    nowhere = FoldScores(means, BLOCKS, [10, 10, 10],
                         channel_scores={"none": channel["none"],
                                         "level": [[0.995, 1.2]] * 3})  # fmt: skip
    refused = acc.choose_on_folds("level", nowhere)
    assert refused.kept == acc.CORRECTION_NONE and refused.channels == (False, False)
    assert list(refused.chosen_fold_nrmse) == [1.0, 1.0, 1.0]


def test_per_channel_accumulated_changes_must_beat_that_channels_held_residual() -> None:
    channel = {"none": [[2.0, 2.0]] * 3, "held": [[1.0, 3.0]] * 3,
               "accumulate": [[1.1, 1.5]] * 3}  # fmt: skip
    means = {k: [sum(f) / 2 for f in v] for k, v in channel.items()}
    folds = FoldScores(means, BLOCKS, [10, 10, 10], channel_scores=channel)
    assert folds.channel_reliable("accumulate") == [False, True]


def test_the_tail_verdict_is_per_channel_too() -> None:
    rng = np.random.default_rng(0)
    residual = rng.normal(0.0, 1.0, (200, 2)) + np.array([3.0, 0.0])
    correction = np.column_stack([np.full(200, 3.0), np.full(200, 0.5)])
    choice = acc.choose_correction("residual", correction, residual)
    assert choice.kept == "residual" and choice.channels == (True, False)


def test_the_fit_printout_gives_each_channels_verdict_with_its_scores() -> None:
    from drafttwin.cli._fitprint import _fold_lines

    channel = {"none": [[1.0, 1.0]] * 3, "residual": [[0.5, 1.6], [0.6, 1.5], [0.7, 0.9]]}
    means = {k: [sum(f) / 2 for f in v] for k, v in channel.items()}
    folds = FoldScores(means, BLOCKS, [10, 10, 10], channel_scores=channel)
    correction = {**acc.choose_on_folds("residual", folds).to_dict(), **folds.to_dict()}
    correction["corrected"] = dict(zip(("front", "second"), correction["corrected"], strict=True))
    correction["channel_wins"] = dict(zip(("front", "second"), correction["channel_wins"],
                                          strict=True))  # fmt: skip
    lines = _fold_lines(correction, None)
    front = next(line for line in lines if line.strip().startswith("front"))
    second = next(line for line in lines if line.strip().startswith("second"))
    assert front.split() == ["front", "1", "->", "0.6", "3", "of", "3", "corrected"]
    assert second.split() == ["second", "1", "->", "1.33", "1", "of", "3", "physics", "alone"]


def test_the_measured_offset_is_the_mean_of_the_rows_before_each_run_in_its_record() -> None:
    """Closed form: each run of consecutive target rows holds the mean of the finite measured
    residual over up to ``n_init`` rows just before it, never from another record; 0 (the
    physics alone) where its record has no measured row before it."""
    measured = np.arange(20.0)[:, None] * np.array([[1.0, -1.0]])
    measured[2] = np.nan  # a gap is skipped, not a zero
    rows = np.array([4, 5, 6, 10, 11, 15])  # runs: 4-6 (record 0), 10-11, 15 (record 1 from 10)
    out = acc.offset_runs(rows, measured, (0, 10), n_init=3)
    assert out[:3, 0] == pytest.approx([(1 + 3) / 2] * 3)  # rows 1, 3 (row 2 a gap)
    assert out[:3, 1] == pytest.approx([-2.0] * 3)
    assert out[3:5].tolist() == [[0.0, 0.0]] * 2  # record 1's first row: nothing before it
    assert out[5].tolist() == pytest.approx([13.0, -13.0])  # rows 12-14 of record 1


def test_the_measured_offset_replaces_the_net_only_where_it_wins_and_scores_lower() -> None:
    """Three channels: the net wins and scores lower (kept), the offset scores lower than a
    winning net (offset), the net refused and the offset wins (offset); an offset that does
    not win every fold is never kept."""
    channel = {"none": [[1.0, 1.0, 1.0, 1.0]] * 2,
               "level": [[0.5, 0.8, 1.2, 0.9], [0.6, 0.7, 1.1, 0.9]],
               "offset": [[0.7, 0.4, 0.6, 0.8], [0.7, 0.5, 0.5, 1.1]]}  # fmt: skip
    means = {k: [sum(f) / 4 for f in v] for k, v in channel.items()}
    folds = FoldScores(means, BLOCKS[:2], [10, 10], by_record=True, channel_scores=channel)
    choice = acc.with_offset("level", acc.choose_on_folds("level", folds), folds)
    assert choice.channels == (True, True, True, True) and choice.kept == "level"
    assert choice.offset_channels == (False, True, True, False)
    assert choice.corrected(4).tolist() == [True, True, True, True]
    # the last channel: the net wins (0.9 < 1 on both folds), the offset loses a fold
    assert list(choice.chosen_fold_nrmse) == pytest.approx([(0.5 + 0.4 + 0.6 + 0.9) / 4,
                                                           (0.6 + 0.5 + 0.5 + 0.9) / 4])  # fmt: skip
    assert choice.to_dict(("a", "b", "c", "d"))["offset"] == {"a": False, "b": True,
                                                              "c": True, "d": False}  # fmt: skip
    only = FoldScores({"none": [1.0, 1.0], "level": [1.2, 0.9], "offset": [0.5, 0.6]},
                      BLOCKS[:2], [10, 10], by_record=True)  # fmt: skip
    kept = acc.with_offset("level", acc.choose_on_folds("level", only), only)
    assert kept.kept == acc.CORRECTION_OFFSET and kept.wins == 2
    assert kept.scores[acc.CORRECTION_OFFSET] == pytest.approx(0.55)
    # kept by the user (fallback=False): the net, untested, as asked
    user = acc.choose_on_folds("level", only, test=False)
    assert acc.with_offset("level", user, only) is user


def test_the_fit_printout_names_the_measured_offset_where_it_is_kept() -> None:
    from drafttwin.cli._fitprint import _fold_lines

    channel = {"none": [[1.0, 1.0]] * 2, "level": [[0.5, 1.2], [0.6, 1.1]],
               "offset": [[0.7, 0.5], [0.7, 0.6]]}  # fmt: skip
    means = {k: [sum(f) / 2 for f in v] for k, v in channel.items()}
    folds = FoldScores(means, BLOCKS[:2], [10, 10], by_record=True, channel_scores=channel)
    choice = acc.with_offset("level", acc.choose_on_folds("level", folds), folds)
    names = ("front", "second")
    correction = {**choice.to_dict(names), **folds.to_dict()}
    lines = _fold_lines(correction, None)
    second = next(line for line in lines if line.strip().startswith("second"))
    assert second.split() == ["second", "1", "->", "1.15", "0", "of", "2", "offset", "held"]
    assert any(line.startswith("offset held: the measured offset") for line in lines), lines
    one = FoldScores({"none": [1.0, 1.0], "level": [1.2, 0.9], "offset": [0.5, 0.6]},
                     BLOCKS[:2], [10, 10], by_record=True)  # fmt: skip
    kept = acc.with_offset("level", acc.choose_on_folds("level", one), one)
    text = _fold_lines({**kept.to_dict(("y",)), **one.to_dict()}, None)
    assert any(line.startswith("correction kept: measured offset held (beats the physics alone "
                               "on 2 of 2 folds") for line in text), text  # fmt: skip
    assert any(line.strip().startswith("measured offset held") for line in text), text
