"""Hybrid models' residual machinery, which the parallel hybrid
(:mod:`~drafttwin.models.estimators.parallel`) and MD-S-L (:mod:`~drafttwin.models.estimators.mdsl`)
build on.

Both correct the mechanistic prediction with a learned residual (paper eq. 15):
``yhat(T) = yhat_m(T) + ehat_m(T)``.

Task ``prediction``: ``ehat_m(T)`` comes from residual channels up to ``T-h`` only; the parallel
hybrid sees the mechanistic residual ``e_m = y - yhat_m``; MD-S-L adds the data-driven
residual ``e_d`` (:mod:`drafttwin.models.estimators.mdsl`).

Task ``simulation``: no measured residual exists after each record's initialisation window,
so the windows hold the inputs and the simulated outputs instead: ``[yhat_m, dyhat_m]``
(parallel), plus the per-sample change of the data-driven free run ``dyhat_d`` (MD-*), at rows
``T-W+1 .. T``. The target is the residual's level ``e_m(T)`` or its per-sample change summed
from the last measured residual; :mod:`drafttwin.models.estimators.accumulation` chooses between them on
validation data unless ``accumulate`` is set.

Structure outside the training range (``structure``, ``fade``): with ``structure="relative"``
every speed-like channel the residual net sees or predicts (residuals, the physics' output and
its changes, the data-driven model's changes) is divided by the physics' own speed (floored at
:data:`LEVEL_FLOOR` of its typical training value, so a standstill does not divide by zero)
and the inputs by their training mean: the net learns the residual as a fraction of the
physics' speed, which is what carries over to another set-point or gear set. With
``fade=True`` the correction is scaled down linearly as the net's scaled inputs leave the
training range (to nothing at :data:`FADE_WIDTH` training ranges beyond it): outside what it
was trained on, the hybrid falls back on its physics. ``fade="strict"`` also counts the
channels that were constant in training (a set-point held at one value): the correction is off
wherever such a channel leaves its training value, since nothing in training showed what it
does there (MD-S-L's data-driven model, fed the set-point, returns garbage at another one).
Which of these to use is chosen on validation records (``drafttwin benchmark
generalisation``); the defaults keep the plain structure.

Never worse than the physics on validation (``fallback``): every hybrid scores "no
correction" (the physics alone) beside its residual model on the validation part of the
training data, and keeps the residual model on each output channel only where it beats the
physics there; the other channels (all of them: ``selection_["correction"]["kept"] ==
"none"``) predict the physics' values exactly (``corrected_``, per channel). In a simulation
judged on whole records the measured offset held (the record's mean residual over its
initialisation rows, no network) is a candidate too, and corrects the channels where it wins
(``offset_``, per channel; :func:`~drafttwin.models.estimators.accumulation.with_offset`).
"""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
import torch
from torch import nn

from drafttwin.data.scaling import MinMaxScaler
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import ConfigError, DataError
from drafttwin.models.estimators import accumulation as acc
from drafttwin.models.estimators.base import pack_module, unpack_module
from drafttwin.models.estimators.datadriven import _NeuralModel
from drafttwin.models.estimators.features import fit_scaler
from drafttwin.models.estimators.folds import MEASURE, folds_are_records, judge
from drafttwin.models.estimators.hybrid_state import (
    corrected_channels,
    offset_channels,
    relative_state,
)
from drafttwin.models.estimators.networks import ResidualNet
from drafttwin.models.estimators.schedule import Windows, train_residual_nets
from drafttwin.models.estimators.task import check_windows, input_matrix
from drafttwin.models.estimators.windows import (
    causal_ffill,
    finite_rows,
    gather_windows,
    increments,
    target_rows,
)
from drafttwin.models.training import (
    FitProgress,
    History,
    debias_head,
    predict_network,
    train_network,
)

VARIANTS = ("md-s-l", "md-l", "md-s")
"""MD-S-L (SKNet + LSTM), MD-L (no SKNet), MD-S (no LSTM)."""
STRUCTURES = ("absolute", "relative")
"""How the residual net sees speeds: as they are, or relative to the physics' speed."""
LEVEL_FLOOR = 0.05
"""Relative structure: the physics' speed is floored at this share of its median training
magnitude before dividing by it (start-up and stop pass through zero)."""
FADE_WIDTH = 1.0
"""Fade: the correction reaches zero this many training ranges outside the training range."""
FADES = (False, True, "strict")
"""No fade; fade over the channels that varied in training; also over those constant in it."""
CONSTANT_TOLERANCE = 1e-6
"""Strict fade: a channel constant in training counts as left when it moves by more than this
share of its training value (set-points are exact numbers; float round-off is far below)."""

Groups = dict[str, np.ndarray]


class _ResidualHybrid(_NeuralModel):
    """Residual correction of the mechanistic model from windows of residual channels
    (prediction) or of the inputs and simulated model outputs (simulation)."""

    needs_mechanistic = True
    accumulate: bool | None
    structure: str
    fade: bool | str
    fallback: bool
    val_folds: int

    @property
    def use_sknet(self) -> bool:
        """Whether the residual net lifts its channels with SKNet first."""
        return False

    @property
    def use_lstm(self) -> bool:
        """Whether the residual net runs an LSTM over the window."""
        return True

    # --- what each hybrid feeds the residual net ---------------------------------------
    def _groups(self, y: np.ndarray, mech: np.ndarray, data: np.ndarray | None) -> Groups:
        """Prediction: raw channel groups, ``em`` (the residual, also the target) first."""
        return {"em": y - mech}

    def _channel_groups(self) -> tuple[str, ...]:
        return ("em",)

    def _sim_channel_groups(self) -> tuple[str, ...]:
        """Simulation: the mechanistic output and its per-sample change."""
        return ("ym", "dym")

    def _extra_group(self) -> str | None:
        return None

    def _fit_data(
        self, y: np.ndarray, u: np.ndarray, starts: tuple[int, ...], progress: FitProgress
    ) -> np.ndarray | None:
        return None

    def _predict_data(
        self, y: np.ndarray, u: np.ndarray, starts: tuple[int, ...]
    ) -> np.ndarray | None:
        return None

    # --- checks and channel plumbing -------------------------------------------------
    def _check_params(self) -> None:
        super()._check_params()
        if self.task.simulation:
            self._refuse_for_task("skip", "a free run has no measured residual to add to")
            if self.accumulate is None and self.training.val_fraction == 0 and self.val_folds < 2:
                raise ConfigError(
                    "accumulate unset chooses residual accumulation on the validation part of "
                    "the training data, but {val_fraction} leaves none",
                    terms={"val_fraction": 0, "accumulate": None},
                    fix="set {val_fraction:name} to 0.2 (any share above 0), or fix "
                    "{accumulate:name} to true or false",
                )
        else:
            self._refuse_for_task("accumulate", "one-step prediction sees measured residuals")
        check_windows(self.task, window=self.window)
        if self.structure not in STRUCTURES:
            raise ConfigError(f"unknown structure {self.structure!r}",
                              fix=f"use one of {', '.join(STRUCTURES)}")  # fmt: skip

    def _channels(self) -> tuple[str, ...]:
        """Window channel groups in order (the ``em`` group first in prediction mode)."""
        base = self._sim_channel_groups() if self.task.simulation else self._channel_groups()
        return base + (("u",) if self.task.inputs else ())

    def _all_groups(
        self, y: np.ndarray, mech: np.ndarray, data: np.ndarray | None, u: np.ndarray,
        starts: tuple[int, ...],
    ) -> Groups:  # fmt: skip
        level = self._level(mech)  # 1 in the absolute structure
        if not self.task.simulation:
            groups = {k: v / level for k, v in self._groups(y, mech, data).items()}
        else:
            em = (y - mech) / level
            dem = np.full_like(em, np.nan)
            dem[1:] = em[1:] - em[:-1]
            dem[[s for s in starts if 0 < s < len(em)]] = np.nan
            groups = {"em": em, "dem": dem, "ym": mech / level,
                      "dym": increments(mech, starts) / level}  # fmt: skip
            if data is not None:
                groups["dyd"] = increments(data, starts) / level
                if self._extra_group() is not None:
                    groups["dis"] = (data - mech) / level
        if u.shape[1]:
            groups["u"] = u / self.input_ref_ if self.structure == "relative" else u
        return groups

    def _level(self, mech: np.ndarray) -> np.ndarray | float:
        """What speed-like channels are divided by: the physics' speed (relative structure)."""
        if self.structure != "relative":
            return 1.0
        level: np.ndarray = np.maximum(np.abs(mech), self.level_floor_)
        return level

    def _fit_structure(self, mech: np.ndarray, u: np.ndarray) -> None:
        """The relative structure's references, from the training part."""
        typical = np.nanmedian(np.abs(mech), axis=0)
        self.level_floor_ = LEVEL_FLOOR * np.where(
            np.isfinite(typical) & (typical > 0), typical, 1.0
        )
        ref = np.nanmean(np.abs(u), axis=0) if u.shape[1] else np.zeros(0)
        self.input_ref_ = np.where(np.isfinite(ref) & (ref > 0), ref, 1.0)

    def _fade(self, x: np.ndarray) -> np.ndarray:
        """Per window, the share of the correction kept: 1 inside the training range of every
        scaled channel, falling linearly to 0 at FADE_WIDTH ranges outside it. A channel that
        was constant in training has no range to measure against (and taught the net nothing
        about changes of it): it is left out, unless the fade is strict, where leaving its
        training value turns the correction off."""
        varying = np.concatenate([self.scalers_[k].max_ > self.scalers_[k].min_
                                  for k in self._channels()])  # fmt: skip
        keep = np.ones(len(x))
        if varying.any():
            beyond = np.fmax(x[..., varying] - 1.0, -x[..., varying])
            beyond = np.where(np.isfinite(beyond), beyond, 0.0).reshape(len(x), -1)
            keep = np.clip(1.0 - np.maximum(np.nanmax(beyond, axis=1), 0.0) / FADE_WIDTH, 0, 1)
        if self.fade == "strict" and not varying.all():
            # a constant channel scales to x - min: 0 while it holds its training value
            lows = np.concatenate([self.scalers_[k].min_ for k in self._channels()])
            moved = np.abs(x[..., ~varying]) > CONSTANT_TOLERANCE * np.maximum(
                np.abs(lows[~varying]), 1.0
            )
            keep = np.where(moved.reshape(len(x), -1).any(axis=1), 0.0, keep)
        return keep

    def _new_net(self, n_out: int) -> ResidualNet:
        widths = {g: (len(self.task.inputs) if g == "u" else n_out) for g in self._channels()}
        return ResidualNet(
            sum(widths.values()),
            n_out,
            n_extra=n_out if self._extra_group() else 0,
            use_sknet=self.use_sknet,
            use_lstm=self.use_lstm,
            sk_channels=int(getattr(self, "sk_channels", 24)),
            hidden=self.hidden,
            layers=self.layers,
            dropout=self.dropout,
            skip=not self.task.simulation and self.skip is not False,
        )

    def _windows(
        self, groups: Groups, starts: tuple[int, ...]
    ) -> tuple[np.ndarray, np.ndarray | None, dict[str, np.ndarray], np.ndarray]:
        """Scaled windows, extras, scaled groups and target rows. Prediction: rows
        ``T-h-W+1 .. T-h``; simulation: rows ``T-W+1 .. T`` (no measured channel in them)."""
        scaled = {k: self.scalers_[k].transform(v) for k, v in groups.items()}
        chans = np.hstack([causal_ffill(scaled[k], starts) for k in self._channels()])
        lag = 0 if self.task.simulation else self.task.horizon
        rows = target_rows(len(chans), self.window, lag, starts)
        x = gather_windows(chans, rows, self.window, lag)
        key = self._extra_group()
        extra = None if key is None else scaled[key][rows].astype(np.float32)
        return x, extra, scaled, rows

    # --- fitting ----------------------------------------------------------------------
    def _fit(
        self, series: MeasurementSeries, mech: np.ndarray | None, progress: FitProgress
    ) -> None:
        assert mech is not None
        y, starts = series.values, series.record_starts
        u = input_matrix(series, self.task.inputs)
        self._fit_structure(mech, u)
        data = self._fit_data(y, u, starts, progress)
        groups = self._all_groups(y, mech, data, u, starts)
        self.scalers_ = {k: fit_scaler(v, f"{k} channels") for k, v in groups.items()}
        x, extra, scaled, rows = self._windows(groups, starts)
        if not self.task.simulation:
            candidates = [False]
        elif self.accumulate is not None:
            candidates = [self.accumulate]
        elif folds_are_records(self, rows, starts) is False:
            candidates = [False]  # acc.ONE_RECORD: a fold is too short to judge accumulation
        else:
            candidates = [True, False]
        fits, judges = train_residual_nets(self, Windows(x, extra, scaled, rows), starts,
                                           candidates, partial(_finite, x, extra=extra), progress)  # fmt: skip
        val = self._validation(fits, x, extra, rows, groups["em"], starts)
        level = self._level(mech)
        folds = judge(self, fits, judges, x, extra, scaled, rows, groups["em"], y - mech, level,
                      starts)  # fmt: skip
        kept = False
        if self.task.simulation:
            if self.accumulate is not None:
                choice = acc.Choice(self.accumulate, "user", {}, 0)
            elif folds is not None and not folds.by_record:
                choice = acc.Choice(False, acc.ONE_RECORD, {"level": folds.mean("level")},
                                    sum(folds.rows))  # fmt: skip
            elif folds is not None:
                choice = acc.choose_accumulation_on_folds(candidates, folds)
            else:
                if any(v is None for v in val.values()):
                    raise DataError(
                        "no validation samples to choose residual accumulation on",
                        fix="use a longer training part, or fix accumulate=True or False",
                    )
                choice = acc.choose({k: v[0] for k, v in val.items() if v is not None},
                                    max(len(v[1]) for v in val.values() if v is not None))  # fmt: skip
            self.accumulate_ = kept = choice.accumulate
            self.selection_["accumulate"] = choice.to_dict()
        self.net_, self.history_, _ = fits[kept]
        if folds is not None:
            name = _candidate(kept) if self.task.simulation else "residual"
            correction = acc.choose_on_folds(name, folds, test=self.fallback)
            self._keep(acc.with_offset(name, correction, folds), series.channels)
            self.selection_["correction"] = {**self.selection_["correction"], **folds.to_dict(),
                                             "measure": MEASURE}  # fmt: skip
            return
        self._choose_correction(val[kept], y - mech, mech, series.channels)

    def _choose_correction(
        self, val: tuple[float, np.ndarray, np.ndarray] | None, em: np.ndarray, mech: np.ndarray,
        channels: tuple[str, ...],
    ) -> None:  # fmt: skip
        """Keep the residual model only when it beats the physics alone on validation rows
        (compared in the output's units, whatever the structure)."""
        name = (
            ("accumulate" if self.accumulate_ else "level") if self.task.simulation else "residual"
        )
        correction = residual = None
        if val is not None:
            _, vrows, pred = val
            level = self._level(mech)
            correction = pred * (level[vrows] if isinstance(level, np.ndarray) else level)
            residual = em[vrows]
        self._keep(acc.choose_correction(name, correction, residual, test=self.fallback),
                   channels)  # fmt: skip

    def _keep(self, choice: acc.CorrectionChoice, channels: tuple[str, ...]) -> None:
        """Take the correction choice: per output channel, residual model or physics alone."""
        self.corrected_ = choice.corrected(len(channels))
        self.offset_ = choice.offset(len(channels))
        self.correct_ = bool(self.corrected_.any())
        self.selection_["correction"] = choice.to_dict(channels)

    def _train_final(
        self, net: nn.Module, x: np.ndarray, target: np.ndarray, extra: np.ndarray | None,
        ok: np.ndarray, progress: FitProgress, accumulate: bool,
    ) -> History:  # fmt: skip
        """Train a candidate's final net (built by the caller) on its usable windows."""
        extra_ok = None if extra is None else extra[ok]
        tr = self.training
        validate = (acc.drift_validator(x[ok], target[ok], extra_ok, tr.val_fraction, tr.stride)
                    if accumulate else None)  # fmt: skip
        what = " (accumulated changes)" if accumulate else ""
        history = train_network(net, x[ok], target[ok], tr, seed=self.seed, extra=extra_ok,
                                progress=progress, stage=f"{self.name} residual model{what}",
                                validate=validate)  # fmt: skip
        if accumulate:
            debias_head(net, x[ok], target[ok], extra_ok, self._device())
        return history

    def _build(self, n_out: int) -> ResidualNet:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(self.seed)
            return self._new_net(n_out)

    def _validation(
        self, fits: dict[bool, tuple[ResidualNet, History, np.ndarray]], x: np.ndarray,
        extra: np.ndarray | None, rows: np.ndarray, em: np.ndarray, starts: tuple[int, ...],
    ) -> dict[bool, tuple[float, np.ndarray, np.ndarray] | None]:  # fmt: skip
        """Per candidate, over the validation part of the training rows: the residual's
        free-run (simulation) or one-step NRMSE, the rows and the predicted residual (``None``
        without validation rows)."""
        tr = self.training
        scale = np.nanstd(em, axis=0)
        scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
        anchors = causal_ffill(em, starts)
        out: dict[bool, tuple[float, np.ndarray, np.ndarray] | None] = {}
        for accumulate, (net, _, ok) in fits.items():
            val = acc.validation_slice(int(ok.sum()), tr.val_fraction, tr.stride)
            vrows = rows[ok][val]
            if vrows.size == 0:
                out[accumulate] = None
                continue
            ev = None if extra is None else extra[ok][val]
            net_out = predict_network(net, x[ok][val], extra=ev, device=self._device())
            pred = self.scalers_["dem" if accumulate else "em"].inverse_transform(net_out)
            if accumulate:
                pred = acc.accumulate_runs(pred, vrows, anchors, starts)
            out[accumulate] = (acc.free_run_nrmse(pred, em[vrows], scale), vrows, pred)
        return out

    # --- prediction -------------------------------------------------------------------
    def _predict(self, series: MeasurementSeries, mech: np.ndarray | None) -> np.ndarray:
        assert mech is not None
        if not self.correct_:  # validation chose the physics alone
            out = np.array(mech, dtype=np.float64)
            if self.task.simulation:
                for a, b in series.record_bounds():
                    out[a : min(b, a + self._init_rows())] = np.nan
            return out
        y, starts = series.values, series.record_starts
        u = input_matrix(series, self.task.inputs)
        groups = self._all_groups(y, mech, self._predict_data(y, u, starts), u, starts)
        x, extra, _, rows = self._windows(groups, starts)
        ok = finite_rows(x) if extra is None else finite_rows(x, extra)
        accumulate = self.task.simulation and self.accumulate_
        key = "dem" if accumulate else "em"
        pred = np.full(y.shape, np.nan)
        keep = np.ones(len(y))
        if ok.any():
            e = predict_network(self.net_, x[ok], extra=None if extra is None else extra[ok],
                                device=self._device())  # fmt: skip
            pred[rows[ok]] = self.scalers_[key].inverse_transform(e)
            if self.fade:
                keep[rows[ok]] = self._fade(x[ok])
        if self.task.simulation:
            init = self._init_rows()
            anchors = causal_ffill(groups["em"], starts)  # measured only in the init rows
            for a, b in series.record_bounds():
                if accumulate and b - a > init:
                    seg = np.arange(a + init, b)
                    pred[seg] = acc.accumulate_runs(pred[seg], seg, anchors, starts)
                pred[a : min(b, a + init)] = np.nan
        correction = pred * keep[:, None]
        level = self._level(mech)
        if self.task.simulation and self.offset_.any():  # the record's own offset: no net, no fade
            init = self._init_rows()
            run = np.concatenate([np.arange(a + init, b) for a, b in series.record_bounds()])
            # the init rows' mean residual in the output's units: a record starting from
            # rest would give a relative one over the floored level, scaled up by the
            # running speed's level
            held = acc.offset_runs(run, groups["em"] * level, starts, init)
            lev = level[run] if isinstance(level, np.ndarray) else level
            correction[np.ix_(run, self.offset_)] = (held / lev)[:, self.offset_]
        corrected = mech + correction * level
        if self.corrected_.all():
            return corrected
        out = np.where(self.corrected_[None, :], corrected, mech)
        if self.task.simulation:  # the physics-alone channels wait for the same rows
            for a, b in series.record_bounds():
                out[a : min(b, a + self._init_rows())] = np.nan
        return out

    # --- persistence ------------------------------------------------------------------
    def _get_state(self) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
        state: dict[str, Any] = {
            "scalers": {k: s.to_dict() for k, s in self.scalers_.items()},
            "history": self.history_.to_dict(),
        }
        if not self.correct_:  # written only when the physics alone was chosen, so that a
            state["correct"] = False  # file from before the choice reads back as it was stored
        if self.correct_ and not self.corrected_.all():
            state["corrected"] = self.corrected_.tolist()
        if self.offset_.any():  # written only when chosen: earlier files read back as stored
            state["offset"] = self.offset_.tolist()
        if self.task.simulation:
            state["accumulate"] = bool(self.accumulate_)
        if self.structure == "relative":
            state["relative"] = {"level_floor": self.level_floor_.tolist(),
                                 "input_ref": self.input_ref_.tolist()}  # fmt: skip
        return state, pack_module("net", self.net_)

    def _set_state(self, state: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
        self.scalers_ = {k: MinMaxScaler.from_dict(v) for k, v in state["scalers"].items()}
        self.history_ = History.from_dict(state["history"])
        self.correct_ = bool(state.get("correct", True))  # files before the choice: kept
        self.corrected_ = corrected_channels(state, self.correct_, len(self.channels_))
        self.offset_ = offset_channels(state, self.corrected_)
        if self.task.simulation:
            self.accumulate_ = bool(state["accumulate"])
        if self.structure == "relative":
            self.level_floor_, self.input_ref_ = relative_state(state, len(self.channels_),
                                                                 len(self.task.inputs))  # fmt: skip
        net = self._new_net(len(self.channels_))
        unpack_module("net", tensors, net)
        self.net_ = net


def _candidate(accumulate: bool) -> str:
    return "accumulate" if accumulate else "level"


def _finite(x: np.ndarray, target: np.ndarray, extra: np.ndarray | None) -> np.ndarray:
    """The windows whose inputs, target and extras are all finite."""
    return finite_rows(x, target) if extra is None else finite_rows(x, target, extra)
