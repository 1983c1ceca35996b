"""The EMPS physical model (Janot et al. 2019) built from drafttwin's mechanics components.

Direct dynamic model, symmetric IDIM-LS parameters estimated by the authors on ``DATA_EMPS``::

    M q'' = gtau * vir - Fv q' - Fc sign(q') - offset

In drafttwin terms (radius-1 convention: kg for kg m^2, N for N m, m for rad) this is a train
without a motor: one inertia ``carriage`` of mass ``M``, a :class:`BearingFriction` with
Coulomb force ``Fc`` (``tanh(q'/eps)`` regularised) and viscous ``Fv``, the drive force
``gtau * vir`` as a zero-order-hold torque signal and the constant ``-offset``. It is
integrated open loop with fixed-step RK4 (10 steps per 1 ms sample, as the data set's reference
computation) from ``q(0) = qm(0)``, ``q'(0) = 0``; positions are the interval-mean speeds
summed (exact at the sample instants).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.datasets.emps import INIT_SAMPLES, INPUT, OUTPUT, SAMPLE_TIME_S
from drafttwin.mechanics import DriveTrain, Signal, simulate
from drafttwin.models.mechanistic import MechanisticModel


@dataclass(frozen=True)
class EmpsPhysics:
    """Parameters of the EMPS direct dynamic model (published symmetric IDIM-LS values).

    Attributes:
        mass_kg: M. viscous_ns_per_m: Fv, N s/m. coulomb_n: Fc, N. offset_n: offset, N.
        gtau_n_per_v: drive gain, N/V. speed_eps_m_per_s: tanh regularisation speed of the
        Coulomb term, m/s. dt_s: RK4 step, s.
    """

    mass_kg: float = 95.1089
    viscous_ns_per_m: float = 203.5034
    coulomb_n: float = 20.3935
    offset_n: float = -3.1648
    gtau_n_per_v: float = 35.15065188
    speed_eps_m_per_s: float = 1e-4
    dt_s: float = 1e-4

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    def train(self, vir_v: np.ndarray, sample_time_s: float = SAMPLE_TIME_S) -> DriveTrain:
        """The carriage as a drafttwin drive train driven by ``gtau * vir`` (held per sample)
        and the constant ``-offset``."""
        train = DriveTrain.from_dict(
            {
                "train": {"name": "emps", "description": "EMPS carriage, Janot et al. 2019"},
                "inertia": [{"name": "carriage", "inertia_kgm2": self.mass_kg}],
                "bearing": [
                    {
                        "node": "carriage",
                        "coulomb_torque_nm": self.coulomb_n,
                        "viscous_nms": self.viscous_ns_per_m,
                        "speed_eps_rad_s": self.speed_eps_m_per_s,
                    }
                ],
                "solver": {"dt_s": self.dt_s, "output_rate_hz": 1.0 / sample_time_s,
                           "settle_s": 0.0},
            },
            source="EMPS physics",
        )  # fmt: skip
        force = Signal(0.0, sample_time_s, self.gtau_n_per_v * np.asarray(vir_v, float), "zoh")
        offset = Signal(0.0, 1.0, np.full(2, -self.offset_n))
        return train.with_torque("carriage", force).with_torque("carriage", offset)

    def simulate(
        self, vir_v: np.ndarray, q0_m: float, sample_time_s: float = SAMPLE_TIME_S
    ) -> np.ndarray:
        """Open-loop positions (m) at the sample instants, shape ``(n,)``, from rest at
        ``q0_m``; row ``k`` depends on ``vir[0 .. k-1]`` only."""
        vir_v = np.asarray(vir_v, dtype=np.float64)
        n = len(vir_v)
        out = np.full(n, float(q0_m))
        if n < 2:
            return out
        res = simulate(self.train(vir_v, sample_time_s), (n - 1) * sample_time_s,
                       output_rate_hz=1.0 / sample_time_s, dt_s=self.dt_s, settle_s=0.0,
                       from_rest=True)  # fmt: skip
        speed_m_s = res.node_rpm[:, 0] * math.pi / 30.0
        out[1:] = q0_m + np.cumsum(speed_m_s) * sample_time_s
        return out

    def mechanistic(self) -> MechanisticModel:
        """A mechanistic source for the estimators: the open-loop simulation of a series from
        its input ``vir`` and its first measured position."""

        def run(series: MeasurementSeries) -> np.ndarray:
            q0 = float(series.values[0, 0])
            return self.simulate(series.inputs[INPUT], q0, _step(series))[:, None]

        return MechanisticModel.from_series_function(run, channels=(OUTPUT,), name="EMPS physics")


REFIT_FIELDS = ("mass_kg", "viscous_ns_per_m", "coulomb_n", "offset_n")
"""The parameters :func:`refit` estimates (``gtau`` and the solver settings stay)."""


@dataclass(frozen=True)
class PhysicsRefit:
    """What :func:`refit` found: the refitted ``physics``, the ``initial`` one, their RMSE
    on the fitted record (mm, rows ``start ..``), SciPy's ``nfev``/``njev``/``status``/
    ``message`` (each finite-difference Jacobian costs 4 more simulations) and the fit's wall
    time ``fit_s``."""

    physics: EmpsPhysics
    initial: EmpsPhysics
    rmse_mm_initial: float
    rmse_mm: float
    start: int
    nfev: int
    njev: int
    status: int
    message: str
    fit_s: float

    def to_dict(self) -> dict[str, object]:
        out: dict[str, object] = asdict(self)
        out["parameters"] = {k: getattr(self.physics, k) for k in REFIT_FIELDS}
        return out


def refit(
    vir_v: np.ndarray,
    qm_m: np.ndarray,
    initial: EmpsPhysics | None = None,
    *,
    start: int = INIT_SAMPLES,
    sample_time_s: float = SAMPLE_TIME_S,
    diff_step: float = 1e-3,
    max_nfev: int = 200,
) -> PhysicsRefit:
    """Output-error refit of M, Fv, Fc and offset on one record (give it the training record
    only): ``scipy.optimize.least_squares`` (trf) on the open-loop simulated minus measured
    position over rows ``start ..``, from ``initial`` (default: the published values), with
    M > 0, Fv >= 0, Fc >= 0 and the offset free. Steps are scaled by the initial values and
    the finite-difference step is 1e-3 of each parameter: with a smaller one the stick
    region's tanh makes the differences noisy. SciPy's default tolerances: on ``DATA_EMPS``
    the cost is flat along one direction and the fit stops on ``xtol`` in the valley, where
    points within 0.05 mm of training RMSE differ by 1.8 mm on the test (docs/emps.md).
    Deterministic (no random start)."""
    from scipy.optimize import least_squares

    p0 = EmpsPhysics() if initial is None else initial
    vir_v, qm_m = np.asarray(vir_v, dtype=np.float64), np.asarray(qm_m, dtype=np.float64)
    x0 = np.array([getattr(p0, k) for k in REFIT_FIELDS], dtype=np.float64)

    def physics(x: np.ndarray) -> EmpsPhysics:
        return replace(p0, **{k: float(v) for k, v in zip(REFIT_FIELDS, x, strict=True)})

    def residual(x: np.ndarray) -> np.ndarray:
        out: np.ndarray = (physics(x).simulate(vir_v, qm_m[0], sample_time_s) - qm_m)[start:]
        return out

    began = time.perf_counter()
    sol = least_squares(residual, x0, bounds=([1e-6, 0.0, 0.0, -np.inf], [np.inf] * 4),
                        x_scale=np.where(x0 != 0, np.abs(x0), 1.0), diff_step=diff_step,
                        max_nfev=max_nfev)  # fmt: skip
    fit_s = time.perf_counter() - began
    fitted = physics(sol.x)
    return PhysicsRefit(
        physics=fitted, initial=p0, start=start,
        rmse_mm_initial=rmse_mm(qm_m, p0.simulate(vir_v, qm_m[0], sample_time_s), start),
        rmse_mm=rmse_mm(qm_m, fitted.simulate(vir_v, qm_m[0], sample_time_s), start),
        nfev=int(sol.nfev), njev=int(sol.njev), status=int(sol.status),
        message=str(sol.message), fit_s=fit_s,
    )  # fmt: skip


def _step(series: MeasurementSeries) -> float:
    return float(np.median(np.diff(series.time_s))) if len(series) > 1 else SAMPLE_TIME_S


def rmse_mm(y_m: np.ndarray, pred_m: np.ndarray, start: int) -> float:
    """RMSE in mm over rows ``start ..`` (the official metric with ``start = 20``)."""
    e = np.asarray(y_m, float)[start:] - np.asarray(pred_m, float)[start:]
    return float(np.sqrt(np.mean(e**2)) * 1e3)


def fit_pct(y_m: np.ndarray, pred_m: np.ndarray, start: int) -> float:
    """Fit ``100 (1 - ||y - yhat|| / ||y - mean(y)||)`` over rows ``start ..``, %."""
    y = np.asarray(y_m, float)[start:]
    e = y - np.asarray(pred_m, float)[start:]
    return float(100.0 * (1.0 - np.linalg.norm(e) / np.linalg.norm(y - y.mean())))
