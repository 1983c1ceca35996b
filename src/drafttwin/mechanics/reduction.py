"""What a reduction did to a drive train (:class:`Reduction`), as plain data.

Kept apart from :mod:`drafttwin.mechanics.reduced` (which builds it from a
:class:`~drafttwin.mechanics.assembly.DriveTrain`) so that the train can carry one without the
two modules importing each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Reduction:
    """How a train is reduced (built by :func:`reduce`; arrays are per original node).

    Attributes:
        cutoff_hz: cut-off frequency, Hz.
        cluster: super-node of each node, shape ``(n,)``.
        ratio: speed of each node over its super-node's speed (nominal, no creep).
        rigid: names of the couplings made rigid.
        highest_hz: highest eigenfrequency of the reduced linearised train, Hz (0 if none).
        dt_s: default RK4 step, s (see :data:`~drafttwin.mechanics.reduced.OMEGA_DT`).
        keep: per coupling table (``chain``, ``gear``, ``spring``: the torsional couplings,
            shafts and registered kinds), which rows stay.
    """

    cutoff_hz: float
    cluster: np.ndarray
    ratio: np.ndarray
    rigid: tuple[str, ...]
    highest_hz: float
    dt_s: float
    keep: dict[str, np.ndarray]

    @property
    def n_super(self) -> int:
        """Number of super-nodes (degrees of freedom of the reduced train)."""
        return int(self.cluster.max()) + 1

    def summary(self) -> str:
        """One line: super-nodes, rigid couplings, highest remaining mode and default step."""
        belt = " (in the belts, which stay compliant)" if self.highest_hz > self.cutoff_hz else ""
        return (f"reduced train: {self.n_super} super-node(s), {len(self.rigid)} rigid "
                f"coupling(s) above {self.cutoff_hz:g} Hz, highest remaining mode "
                f"{self.highest_hz:.1f} Hz{belt}, step {self.dt_s:.2e} s")  # fmt: skip
