"""The EMPS benchmark data (Janot et al. 2019): finding, checking and loading the records.

The two original MATLAB files of the benchmark (train ``DATA_EMPS.mat``, test
``DATA_EMPS_PULSES.mat``) are not shipped with drafttwin (their licence is unclear). Their
folder is given explicitly (``--data-dir``) or by the ``DRAFTTWIN_EMPS_DIR`` environment
variable; nothing else is searched. Every file is checked against the SHA-256 listed in
the data set's README before it is read; a missing or altered file is refused with a
:class:`DataError` naming the file and what to do.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from drafttwin._io import sha256_file
from drafttwin.data.series import MeasurementSeries
from drafttwin.errors import DataError

TRAIN_FILE = "DATA_EMPS.mat"
TEST_FILE = "DATA_EMPS_PULSES.mat"
SHA256 = {
    TRAIN_FILE: "6cf6814ae14618795da0101aae2bb97ff0c6351b0501b5492751b02b07facf7e",
    TEST_FILE: "0eab75bb1f6b16228ee78791343a88bf9bfd9a51036ac9807d7b5fc11c0e1704",
}
"""SHA-256 of the original files, from the data set's README."""

ENV_VAR = "DRAFTTWIN_EMPS_DIR"
SAMPLE_TIME_S = 1e-3
INIT_SAMPLES = 20
"""Official initialisation window: only ``test.y[:20]`` may be used; RMSE over the rest."""

OUTPUT = "qm"
INPUT = "vir"


@dataclass(frozen=True)
class EmpsRecord:
    """One EMPS record on its 1 kHz grid.

    Attributes:
        name: file name. time_s: s. qm_m: measured motor position on the load side, m.
        qg_m: reference position, m. vir_v: drive voltage (controller output), V.
        gtau_n_per_v: drive gain, N/V (force = gtau * vir). pulses: the test record's pulse
        flag (0/5), else ``None``.
    """

    name: str
    time_s: np.ndarray
    qm_m: np.ndarray
    qg_m: np.ndarray
    vir_v: np.ndarray
    gtau_n_per_v: float
    pulses: np.ndarray | None = field(default=None)

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def head(self, n: int | None) -> EmpsRecord:
        """The first ``n`` samples (all for ``None``)."""
        if n is None:
            return self
        cut = slice(0, n)
        pulses = None if self.pulses is None else self.pulses[cut]
        return replace(self, time_s=self.time_s[cut], qm_m=self.qm_m[cut], qg_m=self.qg_m[cut],
                       vir_v=self.vir_v[cut], pulses=pulses)  # fmt: skip

    def series(self) -> MeasurementSeries:
        """The record as a drafttwin series: output channel ``qm`` (m), inputs ``vir`` (V)
        and ``qg`` (m) among the set-points."""
        return MeasurementSeries(
            time_s=self.time_s,
            values=self.qm_m[:, None],
            channels=(OUTPUT,),
            inputs={INPUT: self.vir_v, "qg": self.qg_m},
            units={"qm": "m", "vir": "V", "qg": "m"},
            metadata={"source": self.name},
        )


def find_data_dir(data_dir: str | Path | None = None) -> Path:
    """The folder holding the EMPS files: ``data_dir``, else ``$DRAFTTWIN_EMPS_DIR``. Nothing
    else is searched. Raises :class:`DataError`."""
    if data_dir is not None:
        path = Path(data_dir)
        if not path.is_dir():
            raise DataError("folder not found", source=path, where="--data-dir",
                            fix="pass the folder that holds DATA_EMPS.mat and "
                            "DATA_EMPS_PULSES.mat")  # fmt: skip
        return path
    env = os.environ.get(ENV_VAR)
    if env:
        path = Path(env)
        if not path.is_dir():
            raise DataError("folder not found", source=path, where=ENV_VAR,
                            fix=f"point {ENV_VAR} at the EMPS data folder or unset it")  # fmt: skip
        return path
    raise DataError(
        "no folder of EMPS data was given",
        fix=f"pass --data-dir DIR or set {ENV_VAR} to the folder holding {TRAIN_FILE} and "
        f"{TEST_FILE} (from https://www.nonlinearbenchmark.org/benchmarks/emps)",
    )


def verify_file(path: Path) -> str:
    """Check one EMPS file against its published SHA-256; returns the hash."""
    expected = SHA256[path.name]
    if not path.is_file():
        raise DataError("file not found", source=path,
                        fix="copy the original file from the EMPS benchmark archive into this "
                        "folder, or pass --data-dir")  # fmt: skip
    actual = sha256_file(path)
    if actual != expected:
        raise DataError(
            f"SHA-256 {actual} does not match the published {expected}: the file is altered "
            "or not the original",
            source=path,
            fix="restore the original, unmodified file from the EMPS benchmark archive",
        )
    return actual


def load_record(path: Path) -> EmpsRecord:
    """Read one verified ``.mat`` record (float64 columns)."""
    from scipy.io import loadmat

    verify_file(path)
    try:
        raw = loadmat(path)
        cols = {k: np.asarray(raw[k], dtype=np.float64).ravel() for k in ("t", "qm", "qg", "vir")}
        gtau = float(np.asarray(raw["gtau"]).ravel()[0])
    except (KeyError, ValueError, OSError) as exc:
        raise DataError(f"cannot read the EMPS variables ({exc})", source=path) from exc
    pulses = raw.get("pulses_N")
    return EmpsRecord(
        name=path.name,
        time_s=cols["t"],
        qm_m=cols["qm"],
        qg_m=cols["qg"],
        vir_v=cols["vir"],
        gtau_n_per_v=gtau,
        pulses=None if pulses is None else np.asarray(pulses, dtype=np.float64).ravel(),
    )


def load_emps(data_dir: str | Path | None = None) -> tuple[EmpsRecord, EmpsRecord, Path]:
    """The official split: (train ``DATA_EMPS``, test ``DATA_EMPS_PULSES``, folder)."""
    folder = find_data_dir(data_dir)
    return load_record(folder / TRAIN_FILE), load_record(folder / TEST_FILE), folder
