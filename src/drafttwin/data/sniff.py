"""A data file's first bytes checked before the file is read whole.

:func:`~drafttwin.data.io.read_measurements` reads a CSV file into memory at once (and
pyarrow a Parquet file). A file that is not what its suffix claims (a 2 GB binary dump, a
gzip archive named ``.csv``, a log that is one endless line) would take memory in proportion
to its size before any check could refuse it. :func:`sniff` reads the first
:data:`HEAD_BYTES` (and, for Parquet, the last four) and refuses such a file with one line
naming it, so memory stays flat in the size of the junk.
"""

from __future__ import annotations

import os
from pathlib import Path

from drafttwin.errors import DataError

HEAD_BYTES = 64 * 1024
"""Bytes read from the start of a file to judge it."""

PARQUET_MAGIC = b"PAR1"
"""A Parquet file starts and ends with these four bytes."""

MAGIC: tuple[tuple[bytes, str, str], ...] = (
    (b"\x1f\x8b", "gzip-compressed data", "decompress it first (gunzip FILE)"),
    (b"PK\x03\x04", "a zip archive (an .xlsx workbook?)", "unpack it, or export the sheet as CSV"),
    (PARQUET_MAGIC, "a Parquet file", "name it *.parquet"),
    (b"BZh", "bzip2-compressed data", "decompress it first (bunzip2 FILE)"),
    (b"\xfd7zXZ\x00", "xz-compressed data", "decompress it first (unxz FILE)"),
    (b"\x28\xb5\x2f\xfd", "zstd-compressed data", "decompress it first (unzstd FILE)"),
    (b"\x89HDF", "an HDF5 file", "export the measurements as CSV or Parquet"),
    (b"%PDF", "a PDF document", "export the measurements as CSV or Parquet"),
)
"""Signatures of common non-CSV files: what each is and what to do."""

MAX_CONTROL_SHARE = 0.01
"""Share of control bytes (other than tab, CR, LF, form feed) above which a head is binary."""


def sniff(path: Path, fmt: str) -> None:
    """Refuse ``path`` unless its first bytes look like ``fmt`` (``csv`` or ``parquet``)."""
    with open(path, "rb") as fh:
        head = fh.read(HEAD_BYTES)
        size = os.fstat(fh.fileno()).st_size
        tail = b""
        if fmt == "parquet" and size >= 2 * len(PARQUET_MAGIC):
            fh.seek(-len(PARQUET_MAGIC), os.SEEK_END)
            tail = fh.read(len(PARQUET_MAGIC))
    if fmt == "parquet":
        _sniff_parquet(path, head, tail)
    else:
        _sniff_csv(path, head, size)


def _sniff_parquet(path: Path, head: bytes, tail: bytes) -> None:
    if head.startswith(PARQUET_MAGIC) and tail == PARQUET_MAGIC:
        return
    where = "start" if not head.startswith(PARQUET_MAGIC) else "end (truncated?)"
    raise DataError(
        f"cannot be read as Parquet: no {PARQUET_MAGIC.decode()} marker at its {where}",
        source=path,
        fix="check that the file is a complete Parquet file (or a CSV with a .csv suffix)",
    )


def _sniff_csv(path: Path, head: bytes, size: int) -> None:
    for magic, what, fix in MAGIC:
        if head.startswith(magic):
            raise DataError(f"binary content ({what}), not CSV text", source=path, fix=fix)
    if b"\x00" in head or _control_share(head) > MAX_CONTROL_SHARE:
        raise DataError(
            "binary content, not CSV text",
            source=path,
            fix="export the measurements as CSV text, or give a Parquet file a .parquet suffix",
        )
    if size > len(head) and b"\n" not in head and b"\r" not in head:
        raise DataError(
            f"no line break in the first {HEAD_BYTES // 1024} KiB: not a CSV table",
            source=path,
            fix="save the measurements with one header line and one line per sample",
        )


_CONTROL = bytes(b for b in range(32) if b not in (9, 10, 12, 13)) + b"\x7f"


def _control_share(head: bytes) -> float:
    if not head:
        return 0.0
    return (len(head) - len(head.translate(None, _CONTROL))) / len(head)


__all__ = ["HEAD_BYTES", "sniff"]
