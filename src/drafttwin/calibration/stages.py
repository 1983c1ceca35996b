"""``calibrate``: estimate a drive train's uncertain parameters from measured records.

Stages (on the records cleaned as everywhere in drafttwin: gaps filled, spikes smoothed):

1. **Screening** at the nominal values: each parameter's effect on the block means (its
   Jacobian column, in noise units). Parameters the data do not see are "not from this data"
   and stay nominal; parameters whose effects are parallel are "only in combination" and move
   together as one factor (for mean roller speeds: the friction loads, through their total
   torque at the motor).
2. **Output-error fit** of the free factors (least squares on block means; the first 0.5 s
   after a start from rest are not scored, see ``fit.BREAKAWAY_S``): a robust first
   pass, then blocks far off set aside and each channel weighted by its residual scale, a
   least-squares refit, and a generalised least-squares refit in which the motor channel's
   error is white noise plus the supply's wander (an exponentially correlated process whose
   size and correlation time are estimated from that residual by maximum likelihood,
   :mod:`drafttwin.calibration.noise`): the wander, which only the motor sees, is then no
   longer read as motor slip. Standard errors by the sandwich formula with an AR model of
   the (whitened) residuals and, where whitened, no smaller than the leverage-corrected
   heteroscedasticity-consistent ones (HC3: a few blocks of the ramp carry most of it).
3. **Identifiability**: while an estimate's relative standard error exceeds 10 % (or the free
   set is numerically rank-deficient: collinearity index over 1000), the least determined
   entry goes back to nominal ("not separable in this data") and the rest is refitted.

The result holds the calibrated train, each parameter's nominal value, estimate, standard
error and verdict, and the fit's bias and RMSE per channel before and after; optionally the
known-frequency terms fitted to the calibrated physics' residual
(:mod:`drafttwin.calibration.lines`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from drafttwin._io import json_number
from drafttwin.calibration import fit as F
from drafttwin.calibration import identify as I
from drafttwin.calibration import noise as N
from drafttwin.calibration.registry import Parameter, nominal_values, select, with_factors
from drafttwin.data.preprocessing import preprocess
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError
from drafttwin.mechanics import DriveTrain

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Estimate:
    """One parameter's outcome. ``factor`` is estimate / nominal; ``verdict`` one of
    ``identified``, ``only in combination``, ``not separable in this data``, ``not from this
    data``, ``at its bound`` (the fit pushed it to a fifth or five times nominal, or to the edge of
    the values its declaration accepts: the data ask for something the model does not have;
    not identified)."""

    name: str
    unit: str
    nominal: float
    estimate: float
    std_error: float
    factor: float
    factor_se: float
    identifiable: bool
    verdict: str
    combined_with: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "unit": self.unit,
            "nominal": self.nominal,
            "estimate": self.estimate,
            "std_error": json_number(self.std_error),
            "identifiable": self.identifiable,
            "verdict": self.verdict,
            "factor": self.factor,
            "factor_std_error": json_number(self.factor_se),
            "combined_with": list(self.combined_with),
        }


@dataclass(frozen=True)
class Calibration:
    """What :func:`calibrate` found; ``train`` is the calibrated drive train."""

    train: DriveTrain
    estimates: list[Estimate]
    channels: tuple[str, ...]
    units: dict[str, str]
    bias_before: dict[str, float]
    bias_after: dict[str, float]
    rmse_before: dict[str, float]
    rmse_after: dict[str, float]
    collinearity: float
    block_s: float
    records: int
    evaluations: int
    wall_s: float
    model: str
    notes: list[str] = field(default_factory=list)
    lines: dict[str, Any] | None = None  # known-frequency terms (calibrate(lines=True))
    # the weighted fit's residual model per channel (calibrate(coloured=...)): standard
    # deviations of the wander and of the white part in the channel's unit, correlation time
    residual_model: dict[str, dict[str, float]] = field(default_factory=dict)
    weighting: str = "least squares"  # or the channels given a wander model

    @staticmethod
    def _overall(per_channel: dict[str, float]) -> float:
        return float(np.sqrt(np.mean(np.square(list(per_channel.values())))))

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe: parameters, the fit's RMSE before and after (overall and per channel),
        the bias per channel, and how the fit was made."""
        return {
            "parameters": [e.to_dict() for e in self.estimates],
            "rmse_before": self._overall(self.rmse_before),
            "rmse_after": self._overall(self.rmse_after),
            "channels": {
                c: {
                    "unit": self.units.get(c, ""),
                    "rmse_before": self.rmse_before[c],
                    "rmse_after": self.rmse_after[c],
                    "bias_before": self.bias_before[c],
                    "bias_after": self.bias_after[c],
                }
                for c in self.channels
            },  # fmt: skip
            "collinearity_index": json_number(self.collinearity),
            "block_s": self.block_s,
            "records": self.records,
            "model": self.model,
            "weighting": self.weighting,
            "simulations": self.evaluations,
            "wall_s": self.wall_s,
            "notes": list(self.notes),
            **({"lines": self.lines} if self.lines is not None else {}),
            **({"residual_model": self.residual_model} if self.residual_model else {}),
        }


def calibrate(
    train: DriveTrain,
    data: MeasurementSeries,
    params: Sequence[str] | None = None,
    *,
    block_s: float = 0.1,
    model: Callable[[DriveTrain], DriveTrain] | None = None,
    model_name: str = "full",
    progress: Progress | None = None,
    lines: bool = False,
    coloured: Sequence[str] = (),
) -> Calibration:
    """Estimate ``params`` (dotted names; ``None``: the default set) of ``train`` from the
    measured records ``data`` (outputs the train maps, inputs it follows). ``model`` turns a
    train into the one simulated in the loop (e.g. :func:`drafttwin.mechanics.reduce`).
    ``lines``: also fit the known-frequency terms to the calibrated physics' residual
    (:mod:`drafttwin.calibration.lines`). ``coloured``: the channels whose error is modelled as
    white noise plus an exponentially correlated wander in the final, generalised
    least-squares fit (``"all"``: every channel; empty: plain least squares)."""
    start = time.perf_counter()
    say = progress or (lambda _msg: None)
    chosen = select(train, params)
    missing = [c for c in data.channels if c not in {m.channel for m in train.output_channels()}]
    if missing:
        raise DataError(f"the drive train gives no output channel(s) {missing}",
                        fix="calibrate on the channels the train maps ([[output]] tables)")  # fmt: skip
    data, _ = preprocess(data)  # gaps and spikes as everywhere in drafttwin: a spike is 100 sigma
    blocks = F.blocks(data, block_s, train=train, skip_start=bool(coloured))
    absent = [c for c in coloured if c != "all" and c not in blocks.channels]
    if absent:
        raise DataError(f"no recorded {', '.join(absent)} speed to model the wander of",
                        fix="record the motor speed (a 'motor' column) or leave out --wander")  # fmt: skip
    singles = [[i] for i in range(len(chosen))]
    say(f"screening {len(chosen)} parameters at their nominal values")
    screen = F.Objective(train, blocks, chosen, singles, transform=model)
    jac0 = F.jacobian(screen, np.ones(len(chosen)))
    notes: list[str] = []
    residual: dict[str, dict[str, float]] = {}
    free, verdicts, powers = _screen(jac0, chosen, notes)
    x, jac, se, gamma, objective, runs = _fit_and_prune(
        train, blocks, chosen, free, verdicts, model, say, notes, powers, coloured, residual
    )
    factors = objective.factors(x) if free else np.ones(len(chosen))
    calibrated = with_factors(train, chosen, factors)
    estimates = _estimates(train, chosen, objective, x, se, verdicts)
    before = F.simulate_blocks(model(train) if model else train, blocks)
    final = model(calibrated) if model else calibrated  # the train as simulated in the loop
    after = F.simulate_blocks(final, blocks)
    return Calibration(
        train=calibrated, estimates=estimates, channels=blocks.channels, units=blocks.units,
        bias_before=_bias(before, blocks), bias_after=_bias(after, blocks),
        rmse_before=_rmse(before, blocks), rmse_after=_rmse(after, blocks),
        collinearity=gamma, block_s=block_s, records=data.n_records,
        evaluations=screen.evaluations + runs, wall_s=time.perf_counter() - start,
        model=model_name, notes=notes,
        lines=_lines(train, data, final, say) if lines else None, residual_model=residual,
        weighting=(f"generalised least squares, white noise + wander on {', '.join(coloured)}"
                   if coloured else "least squares"),
    )  # fmt: skip


def _lines(
    train: DriveTrain, data: MeasurementSeries, physics: DriveTrain, say: Progress
) -> dict[str, Any]:
    from drafttwin.calibration.lines import fit_lines

    say("fitting the known-frequency terms to the calibrated physics' residual")
    return fit_lines(train, data, physics).to_dict()


def _screen(
    jac: np.ndarray, chosen: Sequence[Parameter], notes: list[str]
) -> tuple[list[list[int]], dict[int, str], dict[int, float]]:
    """Free entries (groups of parameters moved together), the verdicts of the rest and the
    members that act against their group (power -1: they move as 1 / factor): a group is
    free when moving its members together changes the fit by at least MIN_SENSITIVITY noise
    units; a member acting as a small share of a stronger one stays nominal
    (``identify.absorbed``)."""
    n = len(chosen)
    sens = I.sensitivities(jac)
    touched = [i for i in range(n) if sens[i] > 1e-3 * I.MIN_SENSITIVITY]
    free, verdicts = [], {i: "not from this data" for i in range(n) if i not in touched}
    powers: dict[int, float] = {}
    for group in I.combine(jac, touched) if touched else []:
        lead = group[int(np.argmax(sens[group]))]
        against = {i: -1.0 for i in group if float(jac[:, i] @ jac[:, lead]) < 0}
        signs = np.array([against.get(i, 1.0) for i in group])
        if np.linalg.norm(jac[:, group] @ signs) < I.MIN_SENSITIVITY:
            verdicts.update({i: "not from this data" for i in group})
            continue
        kept, weak = I.absorbed(jac, group)
        for i in weak:
            verdicts[i] = "not separable in this data"
        if weak:
            top = kept[int(np.argmax(sens[kept]))]
            share = max(sens[i] for i in weak) / sens[top]
            notes.append(f"left nominal, acting as {chosen[top].name} does with at most "
                         f"{share:.0%} of its effect (a 10 % error in one moves that estimate "
                         f"by {0.1 * share:.1%} at most): "
                         + ", ".join(chosen[i].name for i in weak))  # fmt: skip
        free.append(kept)
        powers.update({i: p for i, p in against.items() if i in kept})
    return free, verdicts, powers


def _fit_and_prune(
    train: DriveTrain,
    blocks: F.Blocks,
    chosen: Sequence[Parameter],
    free: list[list[int]],
    verdicts: dict[int, str],
    model: Callable[[DriveTrain], DriveTrain] | None,
    say: Progress,
    notes: list[str],
    powers: dict[int, float],
    coloured: Sequence[str] = (),
    residual: dict[str, dict[str, float]] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, F.Objective, int]:
    """Fit (a robust pass, outliers set aside and channels reweighted, then least squares);
    standard errors by the sandwich formula under AR residuals; drop the least determined
    free entry while the set is not identifiable. Returns the final factors, Jacobian,
    standard errors, collinearity, the objective they belong to and the simulations run."""
    x = np.ones(len(free))
    noises: list[N.ChannelNoise | None] = []
    cache: dict[tuple[float, ...], np.ndarray] = {}  # simulations do not depend on weights
    while True:
        robust = F.Objective(
            train, blocks, chosen, free, transform=model, powers=powers, _cache=cache
        )
        say(f"fitting {len(free)} free factor(s)")
        x = F.fit(robust, x, loss="soft_l1")
        data, wild = F.reweighted(blocks, blocks.errors(robust.blocks(x)))
        plain = F.Objective(train, data, chosen, free, transform=model, powers=powers, _cache=cache)
        x = F.fit(plain, x)
        if coloured:
            plain, noises = _coloured(plain, x, coloured)
            x = F.fit(plain, x)
        jac = F.jacobian(plain, x)
        mask = np.isfinite(data.measured)
        resid = plain.residuals(x)
        se = I.sandwich_standard_errors(jac, resid, mask, data.record_rows)
        if coloured:  # whitened: also the rows' own scatter where few rows carry the fit
            se = np.maximum(se, I.hc3_standard_errors(jac, resid))
        gamma = I.collinearity(jac)
        rel = se / np.maximum(np.abs(x), 1e-12)
        worst = I.least_determined(rel, gamma)
        if worst is None:
            if coloured:
                model_of = _residual_model(plain.data, noises)
                notes.append("residual model of the weighted fit: " + "; ".join(
                    f"{c}: wander {m['wander_sd']:.3g} {plain.data.units.get(c, '')} over "
                    f"{m['correlation_s']:.3g} s, white {m['white_sd']:.3g}; steady level "
                    f"known to {m['level_sd']:.3g}, a new minute's own mean moves by "
                    f"{m['mean_sd_60s']:.3g} (1 SD)"
                    for c, m in model_of.items()))  # fmt: skip
                if residual is not None:
                    residual.update(model_of)
            if wild:
                notes.append(f"{wild} block(s) set aside as outliers (over "
                             f"{F.OUTLIER_SCALES:g} robust standard deviations off)")  # fmt: skip
            return x, jac, se, gamma, plain, len(cache)
        for i in free[worst]:
            verdicts[i] = "not separable in this data"
        say(f"{', '.join(chosen[i].name for i in free[worst])}: relative SE {rel[worst]:.0%}, "
            f"collinearity {gamma:.3g}: back to nominal")  # fmt: skip
        free = [g for k, g in enumerate(free) if k != worst]
        x = np.delete(x, worst)


def _coloured(
    objective: F.Objective, x: np.ndarray, channels: Sequence[str]
) -> tuple[F.Objective, list[N.ChannelNoise | None]]:
    """The objective weighted by the residual's coloured model (generalised least squares):
    a white + OU model per channel in ``channels``, by maximum likelihood on the residual at
    ``x``."""
    data = objective.data
    resid = data.errors(objective.blocks(x))
    mask = np.isfinite(data.measured) & np.isfinite(resid)
    block_s = data.block / data.series.sample_rate_hz
    noises = [
        N.fit_noise(N.channel_segments(resid, mask, data.record_rows, j, block_s), block_s)
        if (c in channels or "all" in channels) else None
        for j, c in enumerate(data.channels)
    ]  # fmt: skip
    whiten = N.Whitener(noises, mask, data.record_rows, block_s)
    return replace(objective, whiten=whiten, evaluations=0), noises


def _residual_model(
    data: F.Blocks, noises: Sequence[N.ChannelNoise | None]
) -> dict[str, dict[str, float]]:
    """Each modelled channel's wander and white standard deviation per block (in the
    channel's unit), the wander's correlation time, how well the calibration records pin the
    channel's steady level against the wander (``level_sd``: a constant offset's standard
    error) and how far a new minute-long record's own wander moves its mean (``mean_sd_60s``).
    Together they bound the steady bias a calibration from these records can promise."""
    mask = np.isfinite(data.measured)
    block_s = data.block / data.series.sample_rate_hz
    out = {}
    for j, (c, n) in enumerate(zip(data.channels, noises, strict=True)):
        if n is None:
            continue
        times = [t for t, _ in N.channel_segments(np.zeros(mask.shape), mask, data.record_rows,
                                                   j, block_s)]  # fmt: skip
        out[c] = {"wander_sd": float(np.sqrt(n.ou_var) * data.noise[j]), "correlation_s": n.tau_s,
                  "white_sd": float(np.sqrt(n.white_var) * data.noise[j]),
                  "level_sd": N.offset_sd(n, times) * float(data.noise[j]),
                  "mean_sd_60s": N.mean_sd(n, 60.0, block_s) * float(data.noise[j])}  # fmt: skip
    return out


def _estimates(
    train: DriveTrain,
    chosen: Sequence[Parameter],
    objective: F.Objective,
    x: np.ndarray,
    se: np.ndarray,
    verdicts: dict[int, str],
) -> list[Estimate]:
    groups = objective.groups
    nominal = nominal_values(train, chosen)
    factor = np.ones(len(chosen))
    factor_se = np.full(len(chosen), np.nan)
    partners: dict[int, tuple[str, ...]] = {}
    low, high = objective.bounds()
    for k, members in enumerate(groups):
        if min(abs(x[k] - low[k]), abs(x[k] - high[k])) < 1e-6:
            # the data push it out of the plausible or valid range: a model error
            for i in members:
                if verdicts.get(i) != "not from this data":
                    verdicts[i] = "at its bound"
        for i in members:  # x ** p and its standard error by the delta method
            power = objective.powers.get(i, 1.0)
            factor[i] = x[k] ** power
            factor_se[i] = se[k] * abs(power) * x[k] ** (power - 1.0)
        for i in members:
            partners[i] = tuple(chosen[j].name for j in members if j != i)
            verdicts.setdefault(i, "only in combination" if len(members) > 1 else "identified")
    out = []
    for i, p in enumerate(chosen):
        verdict = verdicts[i]
        out.append(Estimate(
            name=p.name, unit=p.unit, nominal=nominal[i], estimate=nominal[i] * factor[i],
            std_error=abs(nominal[i]) * factor_se[i], factor=float(factor[i]),
            factor_se=float(factor_se[i]), identifiable=verdict == "identified",
            verdict=verdict, combined_with=partners.get(i, ()),
        ))  # fmt: skip
    return out


def _bias(sim: np.ndarray, blocks: F.Blocks) -> dict[str, float]:
    err = sim - blocks.measured
    return {c: float(np.nanmean(err[:, j])) for j, c in enumerate(blocks.channels)}


def _rmse(sim: np.ndarray, blocks: F.Blocks) -> dict[str, float]:
    err = sim - blocks.measured
    return {c: float(np.sqrt(np.nanmean(err[:, j] ** 2)))
            for j, c in enumerate(blocks.channels)}  # fmt: skip
