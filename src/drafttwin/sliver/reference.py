"""A machine's own sliver lines: the reference its healthy sliver gives.

A healthy machine's sliver carries lines of its own: each roller and gear turns within its
tolerance, not perfectly round, and once a well-set leveller has taken out the feed's long
waves, the two middle rollers' 10-um run-out stands at 59-60 cm above half the base
(docs/sliver.md). Such a line is the machine's, not a fault: a chimney no higher than
:data:`KNOWN_FACTOR` times the reference's channel is named as one of the machine's own
lines, not alarmed.

A :class:`SliverReference` holds a healthy sliver's channel amplitudes: the whole record's
spectrogram (``sliver diagnose --reference``), or the mean band variance of the windows a
:class:`~drafttwin.sliver.watch.SliverWatch` saw while the machine learned its healthy state
(the live twin; ``diagnose --healthy`` pushes the healthy record through the same watch).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from drafttwin.errors import DataError
from drafttwin.sliver.spectra import Spectrogram

KNOWN_FACTOR = 1.5
"""A chimney up to this many times the reference's channel amplitude is the machine's own."""
SAME_CHANNEL = 0.04
"""Two channel centres within this |ln ratio| are one channel (10 per octave: 0.069 apart)."""
MAX_CHANNELS = 200


@dataclass(frozen=True)
class SliverReference:
    """Channel centres (m) and amplitudes (%, ``100 sqrt(2 band variance)``) of a healthy
    sliver, with the number of windows and metres of sliver they came from."""

    wavelength_m: np.ndarray
    amplitude_pct: np.ndarray
    windows: int
    metres: float

    @classmethod
    def of(cls, spec: Spectrogram | SliverReference) -> SliverReference:
        """The reference a whole spectrogram gives (one window)."""
        if isinstance(spec, SliverReference):
            return spec
        metres = spec.length_m if math.isfinite(spec.length_m) else 0.0
        return cls(np.asarray(spec.wavelength_m, dtype=np.float64).copy(),
                   np.asarray(spec.amplitude_pct, dtype=np.float64).copy(), 1, metres)  # fmt: skip

    def add(self, spec: Spectrogram, metres: float) -> SliverReference:
        """This reference and one more window of ``metres`` new sliver: the band variances
        averaged channel by channel (a channel only one of them has keeps its own)."""
        var = {self._key(w): (a * a, self.windows) for w, a in
               zip(self.wavelength_m, self.amplitude_pct, strict=True)}  # fmt: skip
        for w, a in zip(spec.wavelength_m, spec.amplitude_pct, strict=True):
            s, n = var.get(self._key(w), (0.0, 0))
            var[self._key(w)] = ((s * n + a * a) / (n + 1), n + 1)
        keys = sorted(var)
        return SliverReference(0.01 * 2.0 ** (np.array(keys, dtype=np.float64) / 10),
                               np.sqrt([var[k][0] for k in keys]), self.windows + 1,
                               self.metres + metres)  # fmt: skip

    @staticmethod
    def _key(wavelength_m: float) -> int:
        return int(round(10 * math.log2(float(wavelength_m) / 0.01)))

    def amplitude_at(self, wavelength_m: float) -> float | None:
        """The reference's amplitude in the channel at ``wavelength_m`` (%), or None where
        it has no such channel (it does not reach that wavelength)."""
        if not self.wavelength_m.size:
            return None
        j = int(np.argmin(np.abs(np.log(self.wavelength_m / wavelength_m))))
        if abs(math.log(self.wavelength_m[j] / wavelength_m)) > SAME_CHANNEL:
            return None
        return float(self.amplitude_pct[j])

    def holds(self, amplitude_pct: float, channels_m: list[float]) -> bool:
        """A chimney of ``amplitude_pct`` over ``channels_m`` is one of the machine's own
        lines: no higher than :data:`KNOWN_FACTOR` times the reference there (for a line
        over two channels, their quadrature sum)."""
        ref = 0.0
        for lam in channels_m:
            a = self.amplitude_at(float(lam))
            if a is None:
                return False
            ref = math.hypot(ref, a)
        return amplitude_pct <= KNOWN_FACTOR * ref

    def to_doc(self) -> dict[str, Any]:
        return {"wavelength_m": self.wavelength_m.tolist(),
                "amplitude_pct": self.amplitude_pct.tolist(),
                "windows": self.windows, "metres": self.metres}  # fmt: skip

    @classmethod
    def from_doc(cls, doc: Any, source: str, fix: str) -> SliverReference:
        """Read back what :meth:`to_doc` wrote, checked field by field (a
        :class:`~drafttwin.errors.DataError` naming ``source`` otherwise)."""
        where = "sliver_reference"
        if not isinstance(doc, dict):
            raise DataError("not an object", source=source, where=where, fix=fix)
        arrays = []
        for k in ("wavelength_m", "amplitude_pct"):
            v = doc.get(k)
            ok = isinstance(v, list) and 0 < len(v) <= MAX_CHANNELS and all(
                isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                and x >= 0 for x in v)  # fmt: skip
            if not ok:
                raise DataError(f"{k} is not a list of up to {MAX_CHANNELS} numbers >= 0",
                                source=source, where=f"{where}.{k}", fix=fix)  # fmt: skip
            arrays.append(np.asarray(v, dtype=np.float64))
        w, a = arrays
        if w.size != a.size or np.any(w <= 0) or np.any(np.diff(w) <= 0):
            raise DataError("wavelength_m must rise, one amplitude each", source=source,
                            where=where, fix=fix)  # fmt: skip
        n, m = doc.get("windows"), doc.get("metres")
        if not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
            raise DataError("windows is not a whole number >= 1", source=source,
                            where=f"{where}.windows", fix=fix)  # fmt: skip
        if not (isinstance(m, int | float) and math.isfinite(m) and m >= 0):
            raise DataError("metres is not a number >= 0", source=source,
                            where=f"{where}.metres", fix=fix)  # fmt: skip
        return cls(w, a, n, float(m))


__all__ = ["KNOWN_FACTOR", "SAME_CHANNEL", "SliverReference"]
