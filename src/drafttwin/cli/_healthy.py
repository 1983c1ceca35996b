"""The ``--healthy`` records of ``diagnose``: read with ``--data``'s column map, each once,
none of them the record under diagnosis (by name or by content), all at its rate; and of
``twin fit-detector``, each once."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from drafttwin.cli._oserrors import same_file
from drafttwin.errors import ConfigError

if TYPE_CHECKING:
    from drafttwin.cli._data import Channels
    from drafttwin.data.series import MeasurementSeries


OWN_REFERENCE_FIX = (
    "give healthy records of the same machine other than --data, or leave "
    "--healthy out (the record's first half is the reference)"
)


def healthy_records(paths: list[str], data: str, series: MeasurementSeries,
                     channels: Channels) -> list[MeasurementSeries]:  # fmt: skip
    """The --healthy records, each once: a record given twice (two names, or a copy) would
    count its running twice towards the thresholds' length."""
    records = [_healthy_record(path, data, series, channels) for path in paths]
    refuse_repeated(list(zip(paths, records, strict=True)))
    return records


def refuse_repeated(labelled: list[tuple[str, MeasurementSeries]]) -> None:
    """Refuse a --healthy record given twice (two names, or a copy): it would count its
    running twice towards the thresholds' length."""
    for k, (label, record) in enumerate(labelled):
        twin = next((q for q, r in labelled[:k] if _same_samples(r, record)), None)
        if twin is not None:
            raise ConfigError(f"holds the same samples as {twin}, given before it: a record "
                              "counted twice", source=label, where="--healthy",
                              fix="give each healthy record once")  # fmt: skip


def _same_samples(a: MeasurementSeries, b: MeasurementSeries) -> bool:
    """Whether two records hold the same time stamps and readings (a copy, an export)."""
    return (a.values.shape == b.values.shape and np.array_equal(a.time_s, b.time_s)
            and np.array_equal(a.values, b.values, equal_nan=True))  # fmt: skip


def _healthy_record(path: str, data: str, series: MeasurementSeries,
                    channels: Channels) -> MeasurementSeries:  # fmt: skip
    """A --healthy record (read with --data's column map), refused where it is the record
    under diagnosis or sampled at another rate (the thresholds are per block of rows)."""
    if same_file(path, data):
        raise ConfigError(
            "is the record under diagnosis: its own reference hides the fault it shows",
            source=path,
            where="--healthy",
            fix=OWN_REFERENCE_FIX,
        )
    record = channels.read(path)
    if _same_samples(record, series):
        raise ConfigError(
            f"holds the same samples as --data {data}: its own reference hides the fault it shows",
            source=path,
            where="--healthy",
            fix=OWN_REFERENCE_FIX,
        )
    if not np.isclose(record.sample_rate_hz, series.sample_rate_hz, rtol=0.01):
        raise ConfigError(f"sampled at {record.sample_rate_hz:g} Hz, --data at "
                          f"{series.sample_rate_hz:g} Hz: the thresholds hold at one rate",
                          source=path, where="--healthy",
                          fix="give healthy records at the record's rate (resample one of them)")  # fmt: skip
    return record


def head_rows(series: MeasurementSeries, n: int) -> MeasurementSeries:
    from dataclasses import replace

    return replace(series, time_s=series.time_s[:n], values=series.values[:n],
                   inputs={k: v[:n] for k, v in series.inputs.items()},
                   truth=None if series.truth is None else series.truth[:n],
                   motor_rpm=None if series.motor_rpm is None else series.motor_rpm[:n],
                   metadata={})  # fmt: skip
