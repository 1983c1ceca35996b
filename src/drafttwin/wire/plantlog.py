"""The live plant's own log: every sample ``plant serve`` published, for auditing a twin's store.

A twin's store is only as good as what it can be checked against. ``plant serve --log FILE``
records each sample as it goes out (machine, counter, time, values, set-point and the wall
time it was published), so that ``drafttwin twin audit`` can count, sample by sample,
what a twin stored, what it lost, and what it stored twice. ``lag_s`` says how late each sample went out (the
wall time it was handed to the transport minus its own time; docs/twin.md, "Keeping time").

With the sliver (``plant serve --sliver``) the sensors' readings go to ``LOG.sliver.parquet``
(or ``.csv``) beside it, one row per reading (:data:`SLIVER_COLUMNS`): the columns a leveller
record has. For one machine a sidecar ``LOG.json`` names that file and the machine's sliver
description (the leveller's setting, the fibres, the sensors), so ``sliver level --data LOG``
reads it as it reads a generated record.

The file is written in row groups to a temporary name beside the target and renamed onto it
when the plant stops (:func:`drafttwin._io.atomic_path`): a reader sees the whole log or none,
and memory stays bounded on a long run. A plant killed with SIGKILL leaves no log (only the
hidden temporary file); Ctrl-C, SIGTERM and ``--duration`` write it.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drafttwin.errors import ConfigError

if TYPE_CHECKING:
    from drafttwin.data.series import MeasurementSeries

COLUMNS = ("machine", "seq", "ts_us", "time", "front", "second", "third", "back", "motor",
           "supply_hz", "published")  # fmt: skip
"""Columns every plant log has; ``ts_us`` is the sample time in µs as a twin stores it,
``published`` the wall time (s since the epoch) the plant handed the sample to the transport."""
WRITTEN = (*COLUMNS, "lag_s")
"""Columns written: also ``lag_s`` = published - time, s (logs of older versions lack it)."""
ROW_GROUP = 2000
"""Samples buffered before they are written (20 s of one machine at 100 Hz)."""
SLIVER_COLUMNS = ("machine", "seq", "delivered_length_m", "time", "linear_density_ktex",
                  "infeed_ktex", "fed_length_m")  # fmt: skip
"""Columns of the sliver log (``seq``: the batch a reading came in)."""
SLIVER_ROW_GROUP = 50_000
GENERATOR = "drafttwin plant serve --log"


class PlantLog:
    """Append published samples to ``path`` (``.parquet`` or ``.csv``); :meth:`close` makes
    it appear. Use as a context manager."""

    def __init__(self, path: Path, *, sliver: bool = False) -> None:
        from drafttwin._io import atomic_path

        suffix = path.suffix.lower()
        if suffix not in (".parquet", ".csv"):
            raise ConfigError(f"unsupported log file type '{path.suffix or '(none)'}'",
                              source=path, where="--log", fix="name the log *.parquet or *.csv")  # fmt: skip
        self.path, self.rows = path, 0
        self._buf: dict[str, list[Any]] = {c: [] for c in WRITTEN}
        self._writer: Any = None
        self._parquet = suffix == ".parquet"
        self.sliver_path = path.with_name(f"{path.stem}.sliver{path.suffix}") if sliver else None
        self.sidecar_path = path.with_name(path.stem + ".json")
        self.sidecar_written = False
        self._described: dict[str, dict[str, Any]] = {}
        self._sliver: _Columns | None = None
        if self.sliver_path is not None:
            self._refuse_foreign()
        self._ctx = atomic_path(path)
        self._tmp = self._ctx.__enter__()
        if self.sliver_path is not None:
            self._sliver = _Columns(self.sliver_path, SLIVER_COLUMNS, self._parquet)

    def _refuse_foreign(self) -> None:
        """The sliver file and the sidecar beside the log are written over only where an
        earlier ``plant serve --log`` wrote them (a user's ``LOG.sliver.parquet`` was replaced,
        a foreign ``LOG.json`` silently left without a word)."""
        own = _own_sidecar(self.sidecar_path)
        if self.sidecar_path.exists() and own is None:
            raise ConfigError(f"{self.sidecar_path.name} exists and is not the sidecar of an "
                              "earlier plant log", source=self.sidecar_path, where="--log",
                              fix="choose another --log name, or move that file")  # fmt: skip
        assert self.sliver_path is not None
        named = own is not None and own.get("files", {}).get("sliver") == self.sliver_path.name
        if self.sliver_path.exists() and not named:
            raise ConfigError(f"{self.sliver_path.name} exists and is not the sliver of an "
                              "earlier plant log", source=self.sliver_path, where="--log",
                              fix="choose another --log name, or move that file")  # fmt: skip

    def add_sliver(self, batch: Any) -> None:
        """Record one batch of sliver readings (a :class:`drafttwin.wire.sliver.SliverBatch`)."""
        if self._sliver is None:
            return
        n = batch.time_s.size
        self._sliver.add({"machine": [batch.machine] * n, "seq": [batch.seq] * n,
                          "delivered_length_m": batch.delivered_m, "time": batch.time_s,
                          "linear_density_ktex": batch.ktex, "infeed_ktex": batch.infeed_ktex,
                          "fed_length_m": batch.fed_length_m}, n)  # fmt: skip

    def add(self, machine: str, s: Any) -> None:
        """Record one sample (a :class:`drafttwin.plant.live.LiveSample`: ``seq``, ``time_s``,
        ``rollers_rpm``, ...), just after it was published."""
        b = self._buf
        b["machine"].append(machine)
        b["seq"].append(s.seq)
        b["ts_us"].append(int(round(s.time_s * 1e6)))  # as the twin's mapping reads it
        b["time"].append(s.time_s)
        for col, v in zip(("front", "second", "third", "back"), s.rollers_rpm, strict=True):
            b[col].append(float(v))
        b["motor"].append(float(s.motor_rpm))
        b["supply_hz"].append(float(s.supply_hz))
        now = time.time()
        b["published"].append(now)
        b["lag_s"].append(now - s.time_s)
        self.rows += 1
        if len(b["seq"]) >= ROW_GROUP:
            self._write()

    def _write(self) -> None:
        import pyarrow as pa

        if not self._buf["seq"]:
            return
        schema = _schema()
        table = pa.table({c: pa.array(self._buf[c], schema.field(c).type) for c in WRITTEN})
        if self._writer is None:
            self._open(schema)
        self._writer.write_table(table)
        self._buf = {c: [] for c in WRITTEN}

    def _open(self, schema: Any) -> None:
        if self._parquet:
            import pyarrow.parquet as pq

            self._writer = pq.ParquetWriter(self._tmp, schema)
        else:
            import pyarrow.csv as pcsv

            self._writer = pcsv.CSVWriter(str(self._tmp), schema)

    def close(self) -> None:
        """Write what is buffered and rename the file onto its name."""
        self._write()
        if self._writer is None:  # nothing published: an empty log with the columns
            self._open(_schema())
        self._writer.close()
        self._ctx.__exit__(None, None, None)
        if self._sliver is not None:
            self._sliver.close()
            self._sidecar()

    def describe(self, machine: str, description: dict[str, Any]) -> None:
        """A machine's sliver description, for the sidecar."""
        self._described[machine] = description

    def _sidecar(self) -> None:
        """``LOG.json`` naming the sliver file and describing its one machine (not written
        over a file it did not write)."""
        import json

        from drafttwin._io import atomic_path

        if len(self._described) != 1 or self.sliver_path is None:
            return
        sidecar = self.sidecar_path
        if sidecar.exists() and _own_sidecar(sidecar) is None:  # came meanwhile: not ours
            return
        ((machine, section),) = self._described.items()
        doc = {"generator": GENERATOR, "machine": machine,
               "files": {"log": self.path.name, "sliver": self.sliver_path.name},
               "sliver": {k: v for k, v in section.items() if k != "v"}}  # fmt: skip
        with atomic_path(sidecar) as tmp:
            tmp.write_text(json.dumps(doc, indent=2), encoding="utf-8")
        self.sidecar_written = True

    def abandon(self, exc: BaseException) -> None:
        """Remove the temporary file (the run failed before anything was published)."""
        with contextlib.suppress(Exception):
            if self._writer is not None:
                self._writer.close()
        with contextlib.suppress(BaseException):
            self._ctx.__exit__(type(exc), exc, exc.__traceback__)
        if self._sliver is not None:
            self._sliver.abandon(exc)

    def __enter__(self) -> PlantLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _own_sidecar(path: Path) -> dict[str, Any] | None:
    """The sidecar at ``path`` if an earlier ``plant serve --log`` wrote it, else ``None``."""
    import json

    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("generator") == GENERATOR else None


class _Columns:
    """A second file written as the log is (row groups to a temporary name, renamed at the end)."""

    def __init__(self, path: Path, columns: tuple[str, ...], parquet: bool) -> None:
        from drafttwin._io import atomic_path

        self.columns, self.parquet = columns, parquet
        self._ctx = atomic_path(path)
        self._tmp = self._ctx.__enter__()
        self._buf: dict[str, list[Any]] = {c: [] for c in columns}
        self._n = 0
        self._writer: Any = None

    def add(self, values: dict[str, Any], n: int) -> None:
        for c in self.columns:
            self._buf[c].extend(np.asarray(values[c]).tolist())
        self._n += n
        if self._n >= SLIVER_ROW_GROUP:
            self._write()

    def _schema(self) -> Any:
        import pyarrow as pa

        kinds = {"machine": pa.string(), "seq": pa.int64()}
        return pa.schema([(c, kinds.get(c, pa.float64())) for c in self.columns])

    def _write(self) -> None:
        import pyarrow as pa

        schema = self._schema()
        if self._writer is None:
            if self.parquet:
                import pyarrow.parquet as pq

                self._writer = pq.ParquetWriter(self._tmp, schema)
            else:
                import pyarrow.csv as pcsv

                self._writer = pcsv.CSVWriter(str(self._tmp), schema)
        if self._n:
            self._writer.write_table(pa.table({c: pa.array(self._buf[c], schema.field(c).type)
                                               for c in self.columns}))  # fmt: skip
        self._buf, self._n = {c: [] for c in self.columns}, 0

    def close(self) -> None:
        self._write()
        self._writer.close()
        self._ctx.__exit__(None, None, None)

    def abandon(self, exc: BaseException) -> None:
        with contextlib.suppress(Exception):
            if self._writer is not None:
                self._writer.close()
        with contextlib.suppress(BaseException):
            self._ctx.__exit__(type(exc), exc, exc.__traceback__)


@contextlib.contextmanager
def open_plant_log(path: Path | None, *, sliver: bool = False) -> Iterator[PlantLog | None]:
    """The log of a ``plant serve`` run (``None``: no log): written when the run ends, by
    its duration, Ctrl-C or an error after samples went out; nothing when it failed first.
    ``sliver``: the sliver readings' log beside it too."""
    if path is None:
        yield None
        return
    log = PlantLog(path, sliver=sliver)
    try:
        yield log
    except BaseException as exc:
        if log.rows:
            log.close()
        else:
            log.abandon(exc)
        raise
    log.close()


def _schema() -> Any:
    import pyarrow as pa

    def kind(c: str) -> Any:
        return (
            pa.string() if c == "machine" else pa.int64() if c in ("seq", "ts_us") else pa.float64()
        )

    return pa.schema([(c, kind(c)) for c in WRITTEN])


def read_plant_log(path: Path) -> Any:
    """A plant log as a DataFrame, checked: the columns, whole counters, one row per
    (machine, seq)."""
    import pandas as pd

    from drafttwin.errors import DataError

    if not path.is_file():
        raise DataError("file not found", source=path, where="--plant-log",
                        fix="give the file 'drafttwin plant serve --log FILE' wrote")  # fmt: skip
    try:
        frame = pd.read_parquet(path) if path.suffix.lower() == ".parquet" else pd.read_csv(path)
    except Exception as exc:  # noqa: BLE001  any reader error: not a log
        raise DataError(f"cannot read the plant log ({type(exc).__name__})", source=path,
                        fix="give the file 'drafttwin plant serve --log FILE' wrote") from None  # fmt: skip
    missing = [c for c in COLUMNS if c not in frame.columns]
    if missing:
        raise DataError(f"not a plant log: columns {missing} missing", source=path,
                        fix="give the file 'drafttwin plant serve --log FILE' wrote")  # fmt: skip
    frame["machine"] = frame["machine"].astype(str)
    for col in ("seq", "ts_us"):
        values = pd.to_numeric(frame[col], errors="coerce").to_numpy(dtype=np.float64)
        if not np.isfinite(values).all() or (values != np.round(values)).any():
            raise DataError(f"column {col!r} holds non-integers", source=path,
                            fix="give the file 'drafttwin plant serve --log FILE' wrote")  # fmt: skip
        frame[col] = values.astype(np.int64)
    if frame.duplicated(["machine", "seq"]).any():
        raise DataError("the log has a sample twice (same machine and seq)", source=path,
                        fix="give the log of one plant run")  # fmt: skip
    return frame


__all__ = ["COLUMNS", "SLIVER_COLUMNS", "WRITTEN", "PlantLog", "open_plant_log",
           "read_plant_log"]  # fmt: skip


def plant_log_series(path: Path, *, own_clock: bool = False) -> list[MeasurementSeries] | None:
    """Each machine's record in a ``plant serve --log`` file as a ``MeasurementSeries``
    (``None``: not a plant log): to fit a detector on the live plant's own healthy running
    (times rebuilt from the counter, from 0), or with ``own_clock`` on the plant's clock, the
    one its sliver log's readings carry."""
    from drafttwin._constants import ROLLERS
    from drafttwin.data.series import MeasurementSeries
    from drafttwin.errors import DataError

    try:
        frame = read_plant_log(path)
    except DataError:
        return None
    out = []
    for name, rows in frame.sort_values(["machine", "seq"]).groupby("machine", sort=True):
        seq = rows["seq"].to_numpy(dtype=np.int64)
        # the plant's sample times are t0 + seq / rate: rebuilt from the counter, exactly uniform
        period_s = (
            float(np.median(np.diff(rows["ts_us"].to_numpy()))) / 1e6 if len(seq) > 1 else 0.01
        )
        time_s = rows["time"].to_numpy(dtype=np.float64) if own_clock else (seq - seq[0]) * period_s
        out.append(MeasurementSeries(
            time_s=time_s, values=rows[list(ROLLERS)].to_numpy(dtype=np.float64),
            inputs={"supply_hz": rows["supply_hz"].to_numpy(dtype=np.float64)},
            motor_rpm=rows["motor"].to_numpy(dtype=np.float64),
            metadata={"source": f"{path} (machine {name})"}))  # fmt: skip
    return out
