"""The reference paper's published numbers (a real FA320A; ours come from the plant emulator).

Transcribed from the paper (Zhang & Li, "Mechanism-data hybrid modeling method for the drafting
section of a sliver machine", Molecular & Cellular Biomechanics, article 1733): Table 2 (max and mean
relative error, %, per roller and model), Table 3 (ablation "prediction accuracy", %, ten
repeated tests) and the grid-search optima of Fig. 7.
"""

from __future__ import annotations

ROLLER_ORDER = ("front", "second", "third", "back")

# Table 2: (max relative error %, mean relative error %) per roller
TABLE2 = {
    "mechanistic": {"max": (0.390, 0.610, 0.530, 0.970), "mean": (0.230, 0.360, 0.360, 0.780)},
    "gru": {"max": (0.076, 0.074, 0.039, 0.170), "mean": (0.013, 0.025, 0.011, 0.047)},
    "parallel": {"max": (0.110, 0.160, 0.120, 0.089), "mean": (0.039, 0.033, 0.024, 0.050)},
    "md-s-l": {"max": (0.051, 0.056, 0.029, 0.088), "mean": (0.017, 0.016, 0.011, 0.049)},
}

# Table 3: prediction accuracy %, one row per test (1..10): for each roller in ROLLER_ORDER the
# accuracies of MD-S-L, MD-L and MD-S
# fmt: off
_TABLE3_ROWS = (
    # front               second               third                back
    (99.64, 98.45, 97.55, 99.65, 98.55, 97.25, 99.72, 98.45, 97.63, 99.57, 98.65, 97.22),  # test 1
    (99.66, 98.64, 97.54, 99.64, 98.54, 97.24, 99.74, 98.42, 97.62, 99.55, 98.64, 97.25),  # test 2
    (99.61, 98.12, 97.52, 99.61, 98.52, 97.24, 99.75, 98.43, 97.61, 99.52, 98.62, 97.23),  # test 3
    (99.64, 98.43, 97.43, 99.62, 98.43, 97.27, 99.71, 98.43, 97.61, 99.54, 98.63, 97.23),  # test 4
    (99.64, 98.45, 97.55, 99.64, 98.45, 97.26, 99.78, 98.47, 97.66, 99.54, 98.65, 97.24),  # test 5
    (99.59, 98.44, 97.54, 99.60, 98.54, 97.25, 99.72, 98.41, 97.62, 99.52, 98.64, 97.21),  # test 6
    (99.65, 98.54, 97.54, 99.61, 98.54, 97.24, 99.74, 98.42, 97.64, 99.54, 98.64, 97.24),  # test 7
    (99.63, 98.32, 97.52, 99.64, 98.52, 97.23, 99.74, 98.38, 97.62, 99.57, 98.62, 97.25),  # test 8
    (99.67, 98.76, 97.56, 99.67, 98.56, 97.22, 99.76, 98.42, 97.63, 99.52, 98.66, 97.24),  # test 9
    (99.68, 98.81, 97.51, 99.62, 98.51, 97.25, 99.74, 98.43, 97.64, 99.51, 98.61, 97.23),  # test 10
)
# fmt: on
TABLE3: dict[str, list[tuple[float, float, float]]] = {
    roller: [(row[3 * j], row[3 * j + 1], row[3 * j + 2]) for row in _TABLE3_ROWS]
    for j, roller in enumerate(ROLLER_ORDER)
}
"""Table 3 per roller: the ten tests' (MD-S-L, MD-L, MD-S) accuracies, %."""
TABLE3_VARIANTS = ("md-s-l", "md-l", "md-s")

# Fig. 7: best grid-search configurations and their (validation) loss
FIG7_BEST = {
    "lstm": {"lr": 0.001, "hidden": 256, "layers": 3, "loss": 0.0120},
    "gru": {"lr": 0.001, "hidden": 128, "layers": 3, "loss": 0.0135},
}

INCONSISTENCY = (
    "The paper's Table 3 gives MD-S-L a prediction accuracy of 99.51-99.78 %, i.e. a mean "
    "relative error of 0.22-0.49 %, while its Table 2 gives the same model a mean relative "
    "error of 0.011-0.049 % (accuracy 99.95-99.99 %). The two tables cannot describe the same "
    "model on the same test data; we show both as published."
)


def table3_mean(roller: str, variant: str) -> float:
    k = TABLE3_VARIANTS.index(variant)
    rows = TABLE3[roller]
    return sum(r[k] for r in rows) / len(rows)
