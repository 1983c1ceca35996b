"""Output-error least squares of drive-train parameters on block means of measured speeds.

The simulation is driven by the records' inputs only (set-points, torque inputs) and compared
with the measurement's block means (``block_s``, 0.1 s by default): block means keep what the
parameters change (mean speeds, start-up and speed-change transients) and attenuate the
fluctuation lines (mesh, chain polygon, eccentricity) whose phase a simulation cannot follow
over minutes. Several records share one parameter set; each record starts by the simulation's
own start rule (from rest, or the steady state of its first inputs).

Residuals are weighted per channel by the measurement's noise and fitted with SciPy's
``least_squares`` (trust-region reflective, bounds, finite-difference Jacobian with a relative
step large enough to stay above the simulator's round-off).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TypeAlias

import numpy as np
from scipy.optimize import least_squares

from drafttwin.calibration.registry import Parameter, nominal_values, with_factors
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError
from drafttwin.mechanics import STOPPED_SUPPLY_HZ, DriveTrain, convert_rpm, simulate
from drafttwin.mechanics.inputs import select_outputs

Vector: TypeAlias = Sequence[float] | np.ndarray
"""A parameter vector: the free factors."""

ROBUST_SCALE = 3.0
"""Residual (noise units) beyond which the robust first pass counts a block linearly."""
OUTLIER_SCALES = 10.0
"""A block this many robust standard deviations off its channel's median is set aside."""
BOUNDS = (0.2, 5.0)
"""Factor bounds: a parameter may move from a fifth to five times its nominal value, and
stays inside the values its declaration accepts (:meth:`Objective.bounds`)."""
BREAKAWAY_S = 0.5
"""Blocks at standstill and this long after a start from rest are not scored. At standstill
model and machine agree (speed 0) and tell nothing, but the supply's wander, absent while the
VFD is off, would look pinned to zero there and make the first running blocks carry the
whole level of the wander model. Just after the start the model lacks what happens: the plant
drafts its sliver from 5 % of the set-point on (a step in load), while the model's zones act
as soon as the rollers turn, and the gears' backlash is taken up. On validation machine 7
the machine's own true train is 0.3-0.65 rpm off at the motor in the first four blocks of a
start-up (ten times the block noise), exactly where the ramp's acceleration torque sets in:
a fit that weights sharp features (generalised least squares under a slow wander) would
read that as motor slip."""
DIFF_STEP = 1e-3
"""Relative finite-difference step: the simulator's round-off (angle states of ~1e4 rad) makes
the default step of ~1.5e-8 useless for weak parameters."""


@dataclass(frozen=True)
class Blocks:
    """The measured records as block means: what the fit compares with (the output channels,
    and the motor speed when the records carry it)."""

    series: MeasurementSeries
    channels: tuple[str, ...]
    units: dict[str, str]
    block: int  # samples per block
    measured: np.ndarray  # (n_blocks_total, channels), NaN = not enough samples
    record_rows: list[tuple[int, int]]  # block rows of each record
    noise: np.ndarray  # (channels,) per-block noise scale of the scored errors
    motor_gain: np.ndarray | None = None  # (channels,) channel speed per motor rpm, see errors

    @property
    def n(self) -> int:
        return int(np.isfinite(self.measured).sum())

    def errors(self, simulated: np.ndarray) -> np.ndarray:
        """Scored errors in noise units. With a recorded motor speed, each output's error is
        taken relative to the motor's (``e_j - g_j e_motor``, ``g_j`` its nominal speed per
        motor rpm): the supply frequency's wander moves the motor and every roller alike and
        cancels, which leaves what the drive train between them (belt creep) does."""
        errors: np.ndarray = _differential(simulated - self.measured, self) / self.noise
        return errors


def _unscorable(
    measured: np.ndarray, channels: Sequence[str], gains: np.ndarray | None
) -> np.ndarray:
    """``measured`` with the motor-relative outputs set aside wherever the motor's block is
    (missing, or set aside as an outlier): an output scored against the motor cannot be scored
    without it (a NaN residual that the optimiser refuses)."""
    if gains is None:
        return measured
    gone = ~np.isfinite(measured[:, channels.index("motor")])
    return np.where(gone[:, None] & (gains != 0)[None, :], np.nan, measured)


def _differential(err: np.ndarray, data: Blocks) -> np.ndarray:
    if data.motor_gain is None:
        return err
    motor = err[:, data.channels.index("motor")]
    scored = data.motor_gain != 0  # a channel not scored against the motor keeps its error
    return err - np.where(scored[None, :], data.motor_gain[None, :] * motor[:, None], 0.0)


def block_means(values: np.ndarray, block: int) -> np.ndarray:
    """Means over consecutive blocks of ``block`` rows (a trailing part block dropped); a
    block with fewer than half its samples measured is NaN."""
    n = values.shape[0] // block
    cut = values[: n * block].reshape(n, block, *values.shape[1:])  # n may be 0: no -1
    finite = np.isfinite(cut)
    count = finite.sum(axis=1)
    total = np.where(finite, cut, 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out: np.ndarray = total / count
    out[count < (block + 1) // 2] = np.nan
    return out


def _columns(series: MeasurementSeries, with_motor: bool) -> tuple[tuple[str, ...], np.ndarray]:
    names, values = tuple(series.channels), series.values
    if with_motor and series.motor_rpm is not None and "motor" not in names:
        names, values = (*names, "motor"), np.column_stack([values, series.motor_rpm])
    return names, values


def motor_gains(train: DriveTrain, channels: Sequence[str], units: dict[str, str]) -> np.ndarray:
    """Each channel's nominal speed per motor rpm, in its unit (the motor's own gain is 0, so
    its error stays as it is)."""
    maps = {m.channel: m for m in train.output_channels()}
    ratios = train.speed_ratios
    gains = np.zeros(len(channels))
    for j, c in enumerate(channels):
        if c != "motor" and c in maps:
            m = maps[c]
            gains[j] = float(convert_rpm(ratios[train.node_index(m.node)], units.get(c, m.unit),
                                         m.diameter_mm))  # fmt: skip
    return gains


def blocks(
    series: MeasurementSeries, block_s: float, with_motor: bool = True,
    train: DriveTrain | None = None, skip_start: bool = False,
) -> Blocks:  # fmt: skip
    """Block means of every record (and of the motor speed, when recorded and
    ``with_motor``); the noise scale from the block-to-block changes of the scored errors
    (relative to the motor's, when ``train`` is given and the motor speed recorded).
    ``skip_start``: standstill and start-up blocks are not scored (:data:`BREAKAWAY_S`)."""
    rate = series.sample_rate_hz
    block = max(1, int(round(block_s * rate)))
    names, _ = _columns(series, with_motor)
    parts, rows, start = [], [], 0
    for record in series.records():
        means = block_means(_columns(record, with_motor)[1], block)
        if skip_start:
            means[_breakaway(record, block, len(means))] = np.nan
        if len(means) < 3:
            raise DataError(
                f"a record of {len(record)} samples gives {len(means)} blocks of {block_s:g} s",
                fix="use longer records or a shorter --block",
            )
        parts.append(means)
        rows.append((start, start + len(means)))
        start += len(means)
    measured = np.vstack(parts)
    units = {c: ("rpm" if c == "motor" else series.unit(c)) for c in names}
    gains = motor_gains(train, names, units) if train is not None and "motor" in names else None
    measured = _unscorable(measured, names, gains)
    draft = Blocks(series, names, units, block, measured, rows, np.ones(len(names)), gains)
    scored = _differential(measured, draft)  # the measurement through the scoring transform
    steps = np.vstack([np.diff(scored[a:b], axis=0) for a, b in rows])
    # half the median absolute step (x 1.4826 for a normal scale): the noise between blocks,
    # robust to the transients a start-up puts into the steps
    noise = 1.4826 * np.nanmedian(np.abs(steps), axis=0) / np.sqrt(2.0)
    floor = 1e-6 * np.maximum(np.nanmax(np.abs(measured), axis=0), 1.0)
    return replace(draft, noise=np.maximum(noise, floor))


def _breakaway(record: MeasurementSeries, block: int, n_blocks: int) -> np.ndarray:
    """Blocks that overlap standstill (the supply set-point below the VFD's starting
    frequency) or the first :data:`BREAKAWAY_S` after a start from rest."""
    supply = record.inputs.get("supply_hz")
    out = np.zeros(n_blocks, bool)
    if supply is None:
        return out
    still = supply < STOPPED_SUPPLY_HZ
    span = int(round(BREAKAWAY_S * record.sample_rate_hz))
    for i in np.flatnonzero(~still[1:] & still[:-1]) + 1:  # starts from rest
        still[i : i + span] = True
    for k in range(n_blocks):
        out[k] = bool(still[k * block : (k + 1) * block].any())
    return out


def simulate_blocks(train: DriveTrain, data: Blocks) -> np.ndarray:
    """The train's block means on every record, ``(n_blocks_total, channels)``."""
    parts = []
    select_outputs(train, data.channels, data.units)  # refused before the simulation runs
    for record in data.series.records():
        res = simulate(train, time_s=record.time_s, inputs=record.inputs)
        sim = res.channels(data.channels, data.units)
        parts.append(block_means(sim, data.block))
    return np.vstack(parts)


@dataclass
class Objective:
    """Weighted residuals of a parameter vector, with a cache (the optimiser and the
    identifiability analysis evaluate the same points more than once)."""

    train: DriveTrain
    data: Blocks
    params: Sequence[Parameter]
    groups: list[list[int]]  # free entries: each a list of parameter indices moved together
    transform: Callable[[DriveTrain], DriveTrain] | None = None
    # parameter index -> -1 for a member acting against its group (belt rigidity against the
    # loads): it moves as 1 / x while the others move as x, so that their effects add
    powers: dict[int, float] = field(default_factory=dict)
    whiten: Callable[[np.ndarray], np.ndarray] | None = None
    evaluations: int = 0
    _cache: dict[tuple[float, ...], np.ndarray] = field(default_factory=dict)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the free vector: :data:`BOUNDS` cut, for each member of
        an entry, to the factors its declaration accepts (a member moving as ``1 / x`` cuts
        the reciprocal range): the fit cannot reach a train the declaration refuses."""
        nominal = nominal_values(self.train, self.params)
        lows, highs = [], []
        for members in self.groups:
            low, high = BOUNDS
            for m in members:
                f_low, f_high = self.params[m].factor_range(nominal[m], BOUNDS)
                power = self.powers.get(m, 1.0)  # x ** power in [f_low, f_high]
                ends = sorted((f_low ** (1.0 / power), f_high ** (1.0 / power)))
                low, high = max(low, ends[0]), min(high, ends[1])
            lows.append(low)
            highs.append(high)
        return np.array(lows), np.array(highs)

    def factors(self, x: Vector) -> np.ndarray:
        """Per-parameter factors from the free vector (parameters not free stay at 1)."""
        f = np.ones(len(self.params))
        for value, members in zip(x, self.groups, strict=True):
            for m in members:
                f[m] = float(value) ** self.powers.get(m, 1.0)
        return f

    def blocks(self, x: Vector) -> np.ndarray:
        key = tuple(round(float(v), 12) for v in x)
        if key not in self._cache:
            train = with_factors(self.train, self.params, self.factors(x))
            model = self.transform(train) if self.transform is not None else train
            self._cache[key] = simulate_blocks(model, self.data)
            self.evaluations += 1
        return self._cache[key]

    def residuals(self, x: Vector) -> np.ndarray:
        """(simulated − measured) / noise on the measured blocks, whitened when asked."""
        r = self.data.errors(self.blocks(x))
        if self.whiten is not None:
            r = self.whiten(r)
        scored: np.ndarray = r[np.isfinite(self.data.measured)]
        return scored


def fit(objective: Objective, x0: Vector, max_nfev: int = 60, loss: str = "linear") -> np.ndarray:
    """Least-squares factors of the free entries (bounded, trust-region reflective);
    ``loss="soft_l1"`` for a first pass that a few wild blocks cannot steer."""
    if not objective.groups:
        return np.zeros(0)
    low, high = objective.bounds()
    start = np.clip(np.asarray(x0, float), low, high)
    res = least_squares(objective.residuals, start, bounds=(low, high),
                        diff_step=DIFF_STEP, x_scale=1.0, method="trf", max_nfev=max_nfev,
                        loss=loss, f_scale=ROBUST_SCALE)  # fmt: skip
    return np.asarray(res.x)


def reweighted(data: Blocks, errors: np.ndarray) -> tuple[Blocks, int]:
    """The blocks with outliers set aside and each channel weighted by its residual scale.

    ``errors`` are the scored errors (noise units) after a robust first fit. A block further
    than :data:`OUTLIER_SCALES` robust standard deviations from its channel's median is set
    aside (a spike the cleaning missed, e.g. two in a row: a 30 % spike is a hundred-sigma
    residual). Each channel's noise scale is then multiplied by the RMS of its remaining
    errors (feasible weighted least squares): the block-to-block noise misses the slow
    wander a channel carries (the motor's supply frequency, the rollers' lines), which would
    otherwise give one channel the weight of all. Returns the blocks and the number set aside."""
    centre = np.nanmedian(errors, axis=0)
    scale = 1.4826 * np.nanmedian(np.abs(errors - centre), axis=0)
    wild = np.abs(errors - centre) > OUTLIER_SCALES * np.maximum(scale, 1e-12)
    measured = _unscorable(np.where(wild, np.nan, data.measured), data.channels, data.motor_gain)
    kept = np.where(np.isfinite(measured), errors, np.nan)
    rms = np.sqrt(np.nanmean(kept**2, axis=0))
    noise = data.noise * np.where(np.isfinite(rms) & (rms > 0), rms, 1.0)
    return replace(data, measured=measured, noise=noise), int(wild.sum())


def jacobian(objective: Objective, x: Vector) -> np.ndarray:
    """The residuals' Jacobian at ``x`` by the optimiser's own finite differences (one
    iteration of ``least_squares`` that may not move: it returns the Jacobian it used)."""
    if not objective.groups:
        return np.zeros((int(np.isfinite(objective.data.measured).sum()), 0))
    low, high = objective.bounds()
    res = least_squares(objective.residuals, np.clip(np.asarray(x, float), low, high),
                        bounds=(low, high), diff_step=DIFF_STEP, x_scale=1.0, method="trf",
                        max_nfev=1)  # fmt: skip
    return np.asarray(res.jac)
