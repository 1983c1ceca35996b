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
from dataclasses import asdict, dataclass

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.datasets.emps import INPUT, OUTPUT, SAMPLE_TIME_S
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
