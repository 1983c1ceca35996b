"""Family-wise false-alarm rate of the chimney rule (``drafttwin.sliver.spectrogram``) on
random slivers: records with no periodic line, of which the rule states that at most 1 %
show a chimney.

    python benchmarks/bench_chimney_false_alarms.py [--records 200] [--seed 7]

Three kinds of record, ``--records`` each, seeded:

* ``white 64 m``: 32 000 points at 2 mm, 1 % white irregularity (no staple diagram);
* ``long-wave 64 m + ideal``: the same grid, 0.6 % white plus 1.2 % of an AR(1) irregularity
  (coefficient 0.995, about 0.4 m correlation), read with the cotton ideal curve;
* ``long-wave 300 m + ideal``: 60 000 points at 5 mm, 0.8 % white plus 1 % AR(1) (0.99).

Prints the share of records with at least one chimney and where they fell, and writes
benchmarks/results/chimney_false_alarms.json.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import write_results  # noqa: E402
from drafttwin.sliver import StapleDiagram, spectrogram  # noqa: E402

Record = Callable[[np.random.Generator], np.ndarray]
COTTON = StapleDiagram.preset("cotton")


def _long_wave(n: int, pole: float, white: float, wave: float) -> Record:
    def make(rng: np.random.Generator) -> np.ndarray:
        x = lfilter([1.0], [1.0, -pole], rng.standard_normal(n))
        return 5.0 * (1.0 + white * rng.standard_normal(n) + wave * x / x.std())

    return make


KINDS: tuple[tuple[str, Record, float, StapleDiagram | None], ...] = (
    ("white 64 m", lambda rng: 5.0 * (1.0 + 0.01 * rng.standard_normal(32_000)), 0.002, None),
    ("long-wave 64 m + ideal", _long_wave(32_000, 0.995, 0.006, 0.012), 0.002, COTTON),
    ("long-wave 300 m + ideal", _long_wave(60_000, 0.99, 0.008, 0.01), 0.005, COTTON),
)


def false_alarms(make: Record, step_m: float, staple: StapleDiagram | None, records: int,
                 seed: int) -> tuple[int, list[float]]:  # fmt: skip
    """Records with a chimney, and the chimneys' wavelengths (m)."""
    rng = np.random.default_rng(seed)
    hits, where = 0, []
    for _ in range(records):
        spec = spectrogram(make(rng), step_m, staple=staple)
        if spec.chimney.any():
            hits += 1
            where += [float(w) for w in spec.wavelength_m[spec.chimney]]
    return hits, where


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=200)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    figures = []
    for name, make, step, staple in KINDS:
        hits, where = false_alarms(make, step, staple, args.records, args.seed)
        share = 100.0 * hits / args.records
        print(f"{name}: {hits} of {args.records} records show a chimney ({share:.1f} %)"
              + (f", at {', '.join(f'{w:.2f}' for w in sorted(where))} m" if where else ""))  # fmt: skip
        figures.append({"figure": f"records with a chimney, {name} (no periodic line; "
                        f"{args.records} records, seed {args.seed})", "value": share,
                        "unit": "%", "target": "<= 1 % (the rule's family-wise level)"})  # fmt: skip
    print(f"wrote {write_results('chimney_false_alarms', figures)}")


if __name__ == "__main__":
    main()
