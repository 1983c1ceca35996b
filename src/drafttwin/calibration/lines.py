"""Known-frequency terms: what the shafts' own rotation puts into the physics residual.

Eccentricity and run-out repeat once (and twice) per revolution of their shaft, a gear mesh
``teeth`` times per revolution of its driver, a chain ``teeth`` times per sprocket revolution:
their frequencies follow from the kinematics, so only amplitudes and phases are unknown, and
least squares finds them. The regressors are ``sin`` / ``cos`` of ``order x angle`` of each
node, in the angle domain, so they follow start-ups and speed changes.

Angles come from the measured speeds (an encoder's count is an angle): each node's angle is a
measured channel's, scaled by the simulated speed ratio between the two nodes (creep
included). They are causal: the angle at sample ``k`` (mid-interval) uses samples before
``k`` only. The angle at the start of a record is unknown (no index pulse), so the phases hold
for that record; a fit on a record's first part is scored on its held-out last part.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from drafttwin.data.series import MeasurementSeries
from drafttwin.mechanics import DriveTrain, SimulationResult, simulate

HELD_OUT = 0.3
"""Share of each record (its end) kept out of the fit and scored."""
ORDERS = (1, 2)
"""Harmonics of each node's rotation (once and twice per revolution)."""


@dataclass(frozen=True)
class Line:
    """A known-frequency term: ``order`` cycles per revolution of ``node``."""

    name: str
    node: str
    order: float


def known_lines(train: DriveTrain) -> list[Line]:
    """Once and twice per revolution of every node, each gear mesh, each chain's tooth pass.

    Terms at the same frequency (two nodes joined by a shaft; a shaft's second order and
    another's first through a 2:1 chain) are one term for speed data: they are merged, their
    names joined by `` = ``."""
    raw = [Line(f"{n} x{k}", n, float(k)) for n in train.node_names for k in ORDERS]
    raw += [Line(f"mesh {g.name}", g.driver, float(g.driver_teeth)) for g in train.spec.gear]
    raw += [Line(f"chain {c.name}", c.driver, float(c.driver_teeth)) for c in train.spec.chain]
    ratios = train.speed_ratios
    merged: list[tuple[float, Line]] = []
    for line in raw:
        cycles = line.order * ratios[train.node_index(line.node)]  # per motor revolution
        for k, (other, kept) in enumerate(merged):
            if abs(cycles - other) <= 1e-9 * max(abs(cycles), 1.0):
                merged[k] = (other, Line(f"{kept.name} = {line.name}", kept.node, kept.order))
                break
        else:
            merged.append((cycles, line))
    return [line for _, line in merged]


def node_angles(train: DriveTrain, record: MeasurementSeries, sim: SimulationResult) -> np.ndarray:
    """Causal mid-interval angles (rev) of every node, ``(n, nodes)``, from the measured
    speeds (gaps filled with the simulation)."""
    maps = {m.channel: m for m in train.output_channels()}
    step = float(np.median(np.diff(record.time_s)))
    measured: dict[int, np.ndarray] = {}
    for j, c in enumerate(record.channels):
        if c not in maps:
            continue
        m, node = maps[c], train.node_index(maps[c].node)
        per_rpm = float(m.from_rpm(np.array(1.0)))  # channel units per node rpm
        rpm = record.values[:, j] / per_rpm
        rpm = np.where(np.isfinite(rpm), rpm, sim.node_rpm[:, node])
        before = np.concatenate([[0.0], np.cumsum(rpm[:-1])]) * step / 60.0
        previous = np.concatenate([[sim.node_rpm[0, node]], rpm[:-1]])
        measured[node] = before + 0.5 * previous * step / 60.0  # half an interval ahead
    if not measured:
        raise ValueError("no measured channel reads a node of this train")
    mean = np.maximum(np.abs(sim.node_rpm.mean(axis=0)), 1e-12)
    angles = np.empty((len(record), len(train.node_names)))
    for j in range(len(train.node_names)):
        src = min(measured, key=lambda k: abs(np.log(mean[j] / mean[k])))
        angles[:, j] = measured[src] * mean[j] / mean[src]
    return angles


def regressors(train: DriveTrain, lines: list[Line], angles: np.ndarray) -> np.ndarray:
    """``sin`` and ``cos`` columns of every line, then a constant."""
    cols = []
    for line in lines:
        phase = 2.0 * np.pi * line.order * angles[:, train.node_index(line.node)]
        cols += [np.sin(phase), np.cos(phase)]
    return np.column_stack([*cols, np.ones(len(angles))])


@dataclass(frozen=True)
class LineFit:
    """Amplitudes per line and channel, and the share of the physics residual's variance
    the lines explain, on the fitted part and on each record's held-out end."""

    lines: list[Line]
    channels: tuple[str, ...]
    amplitude: np.ndarray  # (lines, channels), channel units, mean over records
    frequency_hz: np.ndarray  # (lines,), at the records' mean speeds
    share_fit: dict[str, float]
    share_held_out: dict[str, float]

    def to_dict(self, top: int = 10) -> dict[str, Any]:
        """JSON-safe; the ``top`` lines by their largest amplitude."""
        order = np.argsort(-self.amplitude.max(axis=1))[:top]
        return {
            "share_fit": self.share_fit,
            "share_held_out": self.share_held_out,
            "held_out": HELD_OUT,
            "lines": [
                {
                    "name": self.lines[i].name,
                    "frequency_hz": float(self.frequency_hz[i]),
                    "amplitude": {
                        c: float(self.amplitude[i, j]) for j, c in enumerate(self.channels)
                    },
                }
                for i in order
            ],  # fmt: skip
        }


def fit_lines(train: DriveTrain, data: MeasurementSeries, physics: DriveTrain) -> LineFit:
    """Fit the known lines to the residual (measured - ``physics``) of every record of
    ``data``: on each record's first part, scored on its last :data:`HELD_OUT`."""
    lines = known_lines(train)
    chans = tuple(data.channels)
    amp, freq = [], []
    sums = {k: np.zeros((2, len(chans))) for k in ("fit", "held")}  # residual SS, explained SS
    for record in data.records():
        sim = simulate(physics, time_s=record.time_s, inputs=record.inputs)
        outputs = {m.channel: m for m in physics.output_channels()}
        pred = np.column_stack([outputs[c].from_rpm(sim.node_rpm[:, physics.node_index(outputs[c].node)])
                                for c in chans])  # fmt: skip
        x = regressors(train, lines, node_angles(train, record, sim))
        cut = int(round((1.0 - HELD_OUT) * len(record)))
        for j in range(len(chans)):
            y = record.values[:, j] - pred[:, j]
            ok = np.isfinite(y)
            fit_rows, held_rows = ok.copy(), ok.copy()
            fit_rows[cut:], held_rows[:cut] = False, False
            beta, *_ = np.linalg.lstsq(x[fit_rows], y[fit_rows], rcond=None)
            for key, rows in (("fit", fit_rows), ("held", held_rows)):
                before = y[rows] - y[rows].mean()  # the fluctuation: a bias is calibration's
                after = y[rows] - x[rows] @ beta
                after -= after.mean()
                sums[key][:, j] += [float(before @ before), float(after @ after)]
            if j == 0:
                amp.append(np.zeros((len(lines), len(chans))))
            amp[-1][:, j] = np.hypot(beta[0:-1:2], beta[1:-1:2])
        mean_rpm = np.abs(sim.node_rpm.mean(axis=0))
        freq.append([line.order * mean_rpm[train.node_index(line.node)] / 60.0 for line in lines])
    share = {k: {c: 1.0 - v[1, j] / v[0, j] if v[0, j] > 0 else float("nan")
                 for j, c in enumerate(chans)} for k, v in sums.items()}  # fmt: skip
    return LineFit(lines, chans, np.mean(amp, axis=0), np.mean(freq, axis=0),
                   share["fit"], share["held"])  # fmt: skip
