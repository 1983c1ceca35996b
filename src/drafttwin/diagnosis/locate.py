"""Model-based localisation: which element's fault explains the residual shift, how severe.

For every candidate (each bearing, roller load, the belt, the motor's rotor resistance and
torque, each gear mesh's wear, the chain's elongation, each encoder's gain) the mechanistic
model gives the steady-state change of the block features the fault would cause: the five
channel levels (torque balance, :func:`drafttwin.mechanics.operating_point` of the physics
with that fault's parameter changed) and the three roller angle lags behind the front roller
(static node angles, :func:`drafttwin.mechanics.static_angles`: a worn mesh's backlash grows
by twice the wear depth and its driven gear, resting on the loaded flank, trails by the depth
over its base radius; an elongated chain's driven sprocket trails by half the extra loop; an
encoder gain error makes its roller's counted angle run away at ``gain x speed``). The
observed shift (post-change mean of the block features minus the baseline) is matched to
each by SciPy ``least_squares`` over the
fault's parameter within its physical range, whitened by the healthy covariance; the
candidates are ranked by chi-square plus a severity prior (exponential with the kind's
moderate level as its mean: of two candidates that explain the shift equally, the one that
needs the more plausible severity ranks first; a tie-break, not evidence), with a 95 %
interval on the severity from the Jacobian.

Candidates whose whitened signatures point the same way (cosine > :data:`SAME_DIRECTION`)
cannot be told apart by these sensors: each cause carries that group (e.g. wear of C-D and
of E-F: both make only the second roller trail). Faults that leave both the mean speeds and
the angles unchanged (gear crack and run-out, roller run-out) are not assessed:
:data:`NOT_ASSESSED` lists them in the result.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import chi2 as chi2_dist

from drafttwin.diagnosis.residuals import CHANNELS, LAGGED
from drafttwin.mechanics import DriveTrain, Signal, operating_point, simulate, static_angles
from drafttwin.mechanics.faults import (
    KINDS,
    FaultKind,
    catalogue,
    chain_slack_m,
    slacken_chain,
    worn_gear,
)

LEVEL_KINDS = ("bearing_friction", "load_loss", "belt_wear", "rotor_resistance", "torque_loss",
               "gain")  # fmt: skip
ANGLE_KINDS = ("wear", "elongation")  # seen in the roller angle lags, not in levels
NOT_ASSESSED = ("crack", "runout", "eccentricity")
SAME_DIRECTION = 0.99
_SETTLED: dict[tuple[str, str, float], np.ndarray] = {}  # settled chain lags, per train
FIT_P = 1e-3
"""A cause fits when a misfit at least as large as its own would come from the healthy
noise with at least this chance (chi-square on its degrees of freedom)."""


@dataclass(frozen=True)
class Growth:
    """A cause's severity still changing at the end of the record (see
    :func:`drafttwin.diagnosis.growth.severity_trend`): the rate, and the severity at
    ``at_time_s`` (the middle of the record's last block), each with a 95 % interval."""

    growing: bool
    rate_per_s: float
    rate_interval: tuple[float, float]
    severity: float
    interval: tuple[float, float]
    at_time_s: float
    blocks: int

    def to_dict(self) -> dict[str, Any]:
        return {"growing": self.growing, "rate_per_s": self.rate_per_s,
                "rate_interval": list(self.rate_interval), "severity_at_end": self.severity,
                "interval_at_end": list(self.interval), "at_time_s": self.at_time_s,
                "blocks": self.blocks}  # fmt: skip


@dataclass(frozen=True)
class Cause:
    """One candidate explanation, as ranked.

    ``chi2`` is the whitened misfit of the cause at its fitted severity, on ``dof`` degrees
    of freedom (features measured minus the one severity); ``fit_p`` the chance of a misfit
    at least this large if the cause were the truth (absolute: ``fits`` when >= :data:`FIT_P`);
    ``probability`` is relative, among the candidates ranked (they sum to 1), by ``score``
    (``chi2`` plus the severity prior). ``bound`` says where the interval reaches a range
    limit of the kind: ``"at_least"`` (the severity is at least ``interval[0]``; the upper
    end is the range's), ``"at_most"``, or ``"anywhere"``. A sensor rule's cause has no fit
    (``fit_p`` None).
    """

    element: str
    kind: str
    family: str
    severity: float
    interval: tuple[float, float]
    parameter: str
    chi2: float
    probability: float
    group: tuple[str, ...] = field(default=())
    dof: int = 0
    fit_p: float | None = None
    score: float = 0.0
    bound: str | None = None
    growth: Growth | None = None

    @property
    def name(self) -> str:
        return f"{self.element}:{self.kind}"

    @property
    def fits(self) -> bool:
        """The cause explains the shift within the healthy noise (a rule's cause does)."""
        return self.fit_p is None or self.fit_p >= FIT_P

    @property
    def interval_text(self) -> str:
        """The interval in words where it reaches a range limit."""
        lo, hi = self.interval
        return {"at_least": f"at least {lo:.4g}", "at_most": f"at most {hi:.4g}",
                "anywhere": f"anywhere in [{lo:.4g}, {hi:.4g}]"}.get(
                    str(self.bound), f"[{lo:.4g}, {hi:.4g}]")  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        return {"element": self.element, "kind": self.kind, "family": self.family,
                "severity": self.severity, "interval": list(self.interval),
                "interval_bound": self.bound, "interval_text": self.interval_text,
                "parameter": self.parameter, "chi2": self.chi2, "dof": self.dof,
                "fit_p": self.fit_p, "fits": self.fits, "score": self.score,
                "probability": self.probability, "group": list(self.group),
                "growth": None if self.growth is None else self.growth.to_dict()}  # fmt: skip


class SignatureModel:
    """Steady-state signatures (channel levels, roller angle lags) of candidate faults on
    one physics train.

    Args:
        train: the physics.
        elapsed_s: mean time since the change over each part of the window the shift is
            measured on (the lags are compared part by part: a worn mesh's lag is a step, the
            same in every part; an encoder gain error's grows with the time since the change),
            one tuple for all channels or one per roller channel.
    """

    def __init__(self, train: DriveTrain,
                 elapsed_s: tuple[float, ...] | dict[str, tuple[float, ...]] = (0.0,)) -> None:  # fmt: skip
        self.train, self.elapsed_s = train, elapsed_s
        self.raw = train.to_dict()
        self._units: dict[tuple[str, str], np.ndarray] = {}
        self._takeup: dict[tuple[str, str], float] = {}  # severity the pretension takes up
        self._rel_sd: dict[tuple[str, str], float] = {}  # signature model errors
        self._roller_nodes = [train.node_index(r.node) for r in sorted(
            train.spec.roller, key=lambda r: CHANNELS.index(str(r.name)))]  # fmt: skip

    @cached_property
    def _healthy_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self._state(self.train)

    @property
    def healthy(self) -> np.ndarray:
        return self._healthy_state[0]

    @property
    def healthy_angles(self) -> np.ndarray:
        return self._healthy_state[1]

    @cached_property
    def candidates(self) -> list[tuple[str, str]]:
        cat = catalogue(self.train)
        return sorted((e, k) for e, kinds in cat.items() for k in kinds
                      if k in LEVEL_KINDS + ANGLE_KINDS)  # fmt: skip

    def _state(self, train: DriveTrain,
               chain_slack_m: dict[str, float] | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """Speeds of the four rollers and the motor (rpm), and the static angle of each
        roller (``CHANNELS[:4]`` order, rad), at the train's operating point."""
        op = operating_point(train)
        levels = np.array([*(op.roller_rpm[c] for c in CHANNELS[:4]), op.motor_rpm])
        return levels, static_angles(train, chain_slack_m, op)[self._roller_nodes]

    def _lags(self, d_theta: np.ndarray) -> np.ndarray:
        """Angle changes of the four rollers -> lag changes of ``LAGGED``, mrad."""
        ratio = self.healthy[1:4] / self.healthy[0]
        lags: np.ndarray = 1e3 * (d_theta[1:] - ratio * d_theta[0])
        return lags

    def signature(self, element: str, kind: str, severity: float) -> np.ndarray:
        """Change of the block features under the fault: relative change of the five
        channel levels, then the angle lags (mrad) of ``LAGGED`` behind the front roller."""
        el = self.elapsed_s
        nc, parts = len(CHANNELS), len(el if isinstance(el, tuple) else next(iter(el.values())))
        out = np.zeros(nc + len(LAGGED) * parts)
        if kind == "gain":
            j = CHANNELS.index(element)
            out[j] = severity
            if j < 4:  # the counted angle runs away at gain x speed since the change
                rate = np.zeros(4)
                rate[j] = severity * self.healthy[j] * 2 * math.pi / 60.0
                times = el if isinstance(el, tuple) else el[element]
                out[nc:] = np.concatenate([self._lags(rate * e) for e in times])
            return out
        if kind in ANGLE_KINDS:  # linear in the depth / elongation beyond its take-up
            unit = self._unit(element, kind)
            moved = max(0.0, severity - self._takeup[(element, kind)])
            out[:nc] = unit[:nc] * moved
            out[nc:] = np.tile(unit[nc:] * moved, parts)
            return out
        levels, angles = self._state(self.faulted_train(element, kind, severity))
        out[:nc] = levels / self.healthy - 1.0
        out[nc:] = np.tile(self._lags(angles - self.healthy_angles), parts)
        return out

    def _unit(self, element: str, kind: str) -> np.ndarray:
        """Levels and lags per unit severity of a wear or an elongation beyond its take-up
        (:attr:`_takeup`), from the model at the kind's moderate level and twice it
        (backlash and slack add angle in proportion; the worn mesh's lower stiffness changes
        its deflection by nanometres; a chain's pretension takes up the first few um of
        slack, :func:`~drafttwin.mechanics.start.chain_stretch_m`)."""
        key = (element, kind)
        if key not in self._units:
            s = KINDS[kind].levels[1]
            one, two = self._change(element, kind, s), self._change(element, kind, 2.0 * s)
            unit = (two - one) / s
            j = int(np.argmax(np.abs(unit)))
            takeup = s - one[j] / unit[j] if unit[j] != 0 else 0.0
            self._units[key] = unit
            self._takeup[key] = min(max(takeup, 0.0), s)
        return self._units[key]

    def _change(self, element: str, kind: str, s: float) -> np.ndarray:
        """Levels (relative) and lags (mrad) of a wear or an elongation of severity ``s``."""
        slack = None
        if kind == "elongation":
            chain = next(c for c in self.train.spec.chain if c.name == element)
            slack = {element: chain_slack_m(s, chain.pitch_mm * 1e-3)}
            faulted = self.train
        else:
            faulted = self.faulted_train(element, kind, s)
        levels, angles = self._state(faulted, slack)
        return np.concatenate(
            [levels / self.healthy - 1.0, self._lags(angles - self.healthy_angles)]
        )

    def model_rel_sd(self, element: str, kind: str) -> float:
        """Relative error of the static lag signature of an elongation against the physics
        settling with it (:meth:`settled_lags`), the larger at the kind's moderate level and
        twice it; 0 for other kinds and for a reduced train (its chain is rigid). The static
        angles make a chain trail 1.7-2.5 % more than the settled physics (-20.9 / -17.4 mrad
        on the third / back roller for 1.1 % against -20.5 / -17.1 settled, the plant's own
        steps -20.6 / -17.1), and not in proportion to the elongation, so the ranking carries
        it as a model error of the signature rather than a correction."""
        if kind != "elongation" or self.train.reduction is not None:
            return 0.0
        if (element, kind) not in self._rel_sd:
            moderate = KINDS[kind].levels[1]
            errs = []
            for s in (moderate, 2.0 * moderate):
                static = self._change(element, kind, s)[len(CHANNELS) :]
                j = int(np.argmax(np.abs(static)))
                errs.append(abs(self.settled_lags(element, s)[j] / static[j] - 1.0))
            self._rel_sd[(element, kind)] = float(max(errs))
        return self._rel_sd[(element, kind)]

    def settled_lags(self, element: str, s: float) -> np.ndarray:
        """Lag change (mrad) of a chain elongated by ``s`` % as the physics settles with it:
        the train simulated at 1 kHz, the slack taken off the pretension at 1 s as the plant
        injects it, the mean lag over 2.5-3.5 s minus over 0.5-1 s (0.4 CPU-s, kept per
        train)."""
        key = (json.dumps(self.raw, sort_keys=True), element, float(s))
        if key not in _SETTLED:
            tab = self.train.tables()
            row = [c.name for c in self.train.spec.chain].index(element)
            slack = tab._replace(chain_f=slacken_chain(tab.chain_f, row, s))
            res = simulate(self.train, duration_s=3.5, output_rate_hz=1000.0, angles=True,
                           tables_at=lambda t: slack if t >= 1.0 else tab)  # fmt: skip
            theta = np.asarray(res.angle_rad)[1:, self._roller_nodes]
            lag = np.array([self._lags(row_) for row_ in theta])
            t = np.asarray(res.time_s)
            _SETTLED[key] = (lag[(t > 2.5)].mean(axis=0)
                             - lag[(t > 0.5) & (t <= 1.0)].mean(axis=0))  # fmt: skip
        return _SETTLED[key].copy()

    def faulted_train(self, element: str, kind: str, s: float) -> DriveTrain:
        if kind == "rotor_resistance":
            return self.train.with_rotor_resistance(Signal(0.0, 1.0, np.array([1.0 + s] * 2)))
        raw: dict[str, Any] = dict(self.raw)
        if kind == "wear":  # as the plant injects it: backlash + 2 depth, stiffness falls
            raw["gear"] = [worn_gear(g, s) if g["name"] == element else g for g in raw["gear"]]
        elif kind == "bearing_friction":
            raw["bearing"] = [dict(b) for b in raw["bearing"]]
            for b in raw["bearing"]:
                if b["node"] == element:
                    b["coulomb_torque_nm"] *= 1.0 + s
                    b["viscous_nms"] *= 1.0 + s
        elif kind == "load_loss":
            raw["roller"] = [dict(r, top_load_per_side_n=r["top_load_per_side_n"] * (1.0 - s))
                             if r["name"] == element else r for r in raw["roller"]]  # fmt: skip
        elif kind == "belt_wear":
            raw["belt"] = [dict(b, axial_rigidity_n=b["axial_rigidity_n"] * (1.0 - s))
                           if b["name"] == element else b for b in raw["belt"]]  # fmt: skip
        elif kind == "torque_loss":
            motor = dict(raw["motor"])
            motor["rated_power_w"] *= 1.0 - s  # T_k = lambda P / w_rated; breakdown slip kept
            raw["motor"] = motor
        return DriveTrain.from_dict(raw, source="fault candidate")


def belt_direction(size: int) -> np.ndarray:
    """A wrong belt creep moves the four rollers together and leaves the motor and the
    angle lags where they are (``size``: length of the feature vector)."""
    d = np.zeros(size)
    d[:4] = 1.0
    return d


def _belt(sig: np.ndarray) -> float:
    """The belt component of a signature: mean roller change minus motor change."""
    return float(sig[:4].mean() - sig[4])


def nominal_creep(model: SignatureModel) -> float:
    """The physics' belt creep at its operating point, as a relative speed (0 without a
    belt): halving the belt's axial rigidity doubles the creep (creep = F / EA)."""
    belts = [e for e, k in model.candidates if k == "belt_wear"]
    return -_belt(model.signature(belts[0], "belt_wear", 0.5)) if belts else 0.0


def creep_mismatch(model: SignatureModel, belt_levels: np.ndarray) -> float:
    """Relative error of the physics' belt creep on the machines of the healthy records:
    the RMS of their belt levels (rollers minus motor against the physics; the physics is
    the reference, so its bias counts) over the nominal creep. A machine's belt rigidity and
    load are not the nominal ones (the plant draws the rigidity +-30 %), so a load fault's
    predicted rollers-to-motor split is off by this share of its creep part."""
    creep = nominal_creep(model)
    levels = np.asarray(belt_levels, dtype=float)
    levels = levels[np.isfinite(levels)]
    if creep == 0 or levels.size == 0:
        return 0.0
    return float(np.sqrt(np.mean(levels**2)) / abs(creep))


def rank_causes(model: SignatureModel, shift: np.ndarray, cov: np.ndarray,
                creep_rel_sd: float = 0.0, judged: np.ndarray | None = None) -> list[Cause]:  # fmt: skip
    """Candidates ranked by how well each explains ``shift`` (5 relative level changes, then
    the angle lags) with noise covariance ``cov``; the best first. ``creep_rel_sd`` adds the
    model mismatch of a wrong belt creep: each machine candidate's covariance gets
    ``(sd * b) d d'`` with ``b`` the belt part of its fitted signature and ``d``
    :func:`belt_direction` (refitted once with it); a sensor gain does not pass the belt and
    gets none.

    Each cause carries its absolute fit: ``chi2`` of its misfit on the features ``judged``
    (a mask; default: those with healthy variance), on ``dof`` = their number - 1, and
    ``fit_p``; its interval is widened by ``sqrt(chi2 / dof)`` where that exceeds 1 (as
    weighted least squares scales its standard errors by the residual variance)."""
    chol = _chol(cov)
    judged = (
        np.diag(cov) > 0 if judged is None else np.asarray(judged, dtype=bool) & (np.diag(cov) > 0)
    )
    dof = max(1, int(np.count_nonzero(judged)) - 1)

    def white(v: np.ndarray) -> np.ndarray:
        return np.linalg.solve(chol, v)

    fits = []
    nc = len(CHANNELS)
    for element, kind in model.candidates:
        if kind == "gain" and len(shift) > nc:
            # an encoder gain is sized by the level it shifts (what it is); its angle lag
            # depends on how it came on (step or ramp), so the lags only judge it
            s, half, _, x0 = _fit(model, element, kind, shift[:nc], _chol(cov[:nc, :nc]))
            cost = float(np.sum(white(shift - model.signature(element, kind, s)) ** 2))
            # its absolute fit allows for the uncertainty the level leaves on its size: the
            # lags measure a gain's run-away far more finely than the level sizes it
            g = model.signature(element, kind, 1e-3) / 1e-3  # linear in the gain
            sd = half / 1.96 if math.isfinite(half) else 0.0
            fit_cov = cov + sd**2 * np.outer(g, g)
        else:
            s, half, cost, x0 = _fit(model, element, kind, shift, chol)
            fit_cov = cov
            if creep_rel_sd > 0 and kind != "gain":
                m = (
                    creep_rel_sd
                    * _belt(model.signature(element, kind, s))
                    * belt_direction(len(shift))
                )
                fit_cov = cov + np.outer(m, m)
                s, half, cost, x0 = _fit(model, element, kind, shift, _chol(fit_cov))
            rel = model.model_rel_sd(element, kind)
            if rel > 0:  # the signature's own model error (an elongation's static lags)
                m = rel * model.signature(element, kind, s)[: len(shift)]
                m[:nc] = 0.0
                fit_cov = fit_cov + np.outer(m, m)
                s, half, cost, x0 = _fit(model, element, kind, shift, _chol(fit_cov))
        r = (shift - model.signature(element, kind, s)[: len(shift)])[judged]
        chi2 = float(
            r @ np.linalg.solve(fit_cov[np.ix_(judged, judged)] + 1e-30 * np.eye(len(r)), r)
        )
        direction = white(model.signature(element, kind, s if s != 0 else x0))
        fits.append((element, kind, s, half, cost, direction, chi2))
    score = np.array([f[4] + 2 * abs(f[2]) / KINDS[f[1]].levels[1] for f in fits])
    prob = np.exp(-(score - score.min()) / 2)
    prob /= prob.sum()
    order = np.argsort(score)
    causes = []
    for i in order:
        element, kind, s, half, _, d, chi2 = fits[i]
        group = tuple(f"{fits[j][0]}:{fits[j][1]}" for j in order if j != i
                      and _cos(d, fits[j][5]) > SAME_DIRECTION)  # fmt: skip
        k = KINDS[kind]
        interval, bound = _interval(k, s, half * math.sqrt(max(1.0, chi2 / dof)))
        causes.append(Cause(element, kind, k.family, s, interval, k.parameter, chi2,
                            float(prob[i]), group, dof, float(chi2_dist.sf(chi2, dof)),
                            float(score[i]), bound))  # fmt: skip
    return causes


def explained(causes: list[Cause]) -> bool:
    """Whether any ranked cause fits (the verdict: else no candidate explains the shift)."""
    return any(c.fits for c in causes)


def told_apart(group: Sequence[str], fits: bool, fitting: Mapping[str, bool]) -> list[str]:
    """The members of a fitting cause's look-alike group that its fit tells apart (their
    signatures point the same way, but they do not fit: ``fitting``, by cause name); a
    cause that does not fit itself tells none apart."""
    return [n for n in group if fits and not fitting.get(n, True)]


def _chol(cov: np.ndarray) -> np.ndarray:
    return np.linalg.cholesky(cov + 1e-30 * np.eye(len(cov)))


def _range(kind: str) -> tuple[float, float]:
    k = KINDS[kind]
    return (-k.high, k.high) if k.signed else (0.0, k.high)


def _fit(model: SignatureModel, element: str, kind: str, shift: np.ndarray,
         chol: np.ndarray) -> tuple[float, float, float, float]:  # fmt: skip
    """Severity, the half width of its 95 % interval (Jacobian), chi-square and start value
    of one candidate."""
    k = KINDS[kind]
    lo, hi = _range(kind)
    x0 = k.levels[0] * (1.0 if not k.signed or shift[CHANNELS.index(element)] >= 0 else -1.0)
    n = len(shift)
    res = least_squares(lambda x: np.linalg.solve(chol, shift - model.signature(element, kind, x[0])[:n]),
                        [x0], bounds=([lo], [hi]), diff_step=1e-3)  # fmt: skip
    s = float(res.x[0])
    jtj = float(res.jac[:, 0] @ res.jac[:, 0])
    half = 1.96 / math.sqrt(jtj) if jtj > 0 else math.inf
    return s, half, float(2 * res.cost), x0


def _interval(kind: FaultKind, s: float, half: float) -> tuple[tuple[float, float], str | None]:
    """The interval ``s +- half`` within the kind's range, and which end the range cut: the
    severity is then "at least" the lower end (or "at most" the upper), not in a closed
    interval."""
    lo, hi = _range(kind.name)
    below, above = s - half < lo, s + half > hi
    bound = {(False, True): "at_least", (True, False): "at_most", (True, True): "anywhere"}
    return (max(lo, s - half), min(hi, s + half)), bound.get((below, above))


def _cos(a: np.ndarray, b: np.ndarray) -> float:
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    return float(a @ b / (na * nb)) if na > 0 and nb > 0 else 0.0
