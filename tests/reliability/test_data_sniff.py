"""Data files that are not what their suffix claims are refused from their first bytes.

Each junk file is refused with one line naming it (exit 2 on the command line), and the
refusal does not read the file whole: a junk file padded far beyond the 64 KiB the sniff
reads is refused as fast as a small one, and (checked in a subprocess) with flat memory.
Valid CSV and Parquet files, small ones and ones without a final line break, still load.
"""

from __future__ import annotations

import gzip
import io
import subprocess
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app
from drafttwin.data import read_measurements
from drafttwin.data.sniff import HEAD_BYTES
from drafttwin.errors import DataError

CSV_TEXT = "time,front,second,third,back\n" + "".join(
    f"{k * 0.01:.2f},1815,435,426,355\n" for k in range(50)
)


def _parquet_bytes() -> bytes:
    buf = io.BytesIO()
    pd.read_csv(io.StringIO(CSV_TEXT)).to_parquet(buf, index=False)
    return buf.getvalue()


def _zip_bytes() -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("sheet.xml", "<x/>" * 100)
    return buf.getvalue()


def _random(n: int) -> bytes:
    return np.random.default_rng(0).integers(0, 256, n, dtype=np.uint8).tobytes()


JUNK: dict[str, tuple[str, Callable[[int], bytes], str]] = {
    # name: (suffix, content of about n bytes, words of the refusal)
    "random binary named .csv": (".csv", _random, "binary content"),
    "zero bytes named .csv": (".csv", lambda n: b"\x00" * n, "binary content"),
    "gzip file named .csv": (
        ".csv",
        lambda n: gzip.compress(CSV_TEXT.encode()) + _random(n),
        "gzip",
    ),  # fmt: skip
    "zip archive named .csv": (".csv", lambda n: _zip_bytes() + _random(n), "zip archive"),
    "parquet file named .csv": (".csv", lambda n: _parquet_bytes() + _random(n), "Parquet"),
    "control characters named .csv": (
        ".csv",
        lambda n: b"\x01\x02abc\x03" * (n // 6),
        "binary content",
    ),  # fmt: skip
    "one endless line named .csv": (".csv", lambda n: b"1815," * (n // 5), "no line break"),
    "empty .csv": (".csv", lambda n: b"", "file is empty"),
    "text named .parquet": (
        ".parquet",
        lambda n: CSV_TEXT.encode() * (n // len(CSV_TEXT) + 1),
        "no PAR1 marker at its start",
    ),  # fmt: skip
    "parquet with its end cut off": (
        ".parquet",
        lambda n: _parquet_bytes()[:-10],
        "no PAR1 marker at its end",
    ),  # fmt: skip
    "random binary named .parquet": (".parquet", _random, "cannot be read as Parquet"),
}
"""Every kind of junk data file: what it is, how to make one, what the refusal says."""


def write_junk(name: str, folder: Path, size_bytes: int) -> Path:
    suffix, make, _ = JUNK[name]
    path = folder / ("junk" + suffix)
    path.write_bytes(make(size_bytes))
    return path


@pytest.mark.parametrize("name", sorted(JUNK))
def test_junk_data_file_is_refused_naming_it(tmp_path: Path, name: str) -> None:
    path = write_junk(name, tmp_path, 4 * HEAD_BYTES)
    with pytest.raises(DataError) as err:
        read_measurements(path)
    assert str(path) in str(err.value)
    assert JUNK[name][2] in str(err.value)


@pytest.mark.parametrize("name", ["random binary named .csv", "one endless line named .csv",
                                  "gzip file named .csv", "text named .parquet"])  # fmt: skip
def test_junk_data_file_ends_the_cli_with_one_line_and_exit_2(tmp_path: Path, name: str) -> None:
    path = write_junk(name, tmp_path, 4 * HEAD_BYTES)
    result = CliRunner().invoke(app, ["inspect", str(path)])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert str(path) in result.output and JUNK[name][2] in result.output


_PEAK_SCRIPT = """
import sys
from drafttwin.data import read_measurements
from drafttwin.errors import DataError
try:
    read_measurements(sys.argv[1])
except DataError:
    pass
status = open("/proc/self/status").read().split("VmHWM:")[1]
print(int(status.split()[0]))  # peak RSS of this process image, KiB (ru_maxrss would count
# the memory of the test process it was forked from)
"""


def _peak_rss_kib(path: Path) -> int:
    out = subprocess.run([sys.executable, "-c", _PEAK_SCRIPT, str(path)], capture_output=True,
                         text=True, check=True, timeout=120)  # fmt: skip
    return int(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("name", ["random binary named .csv", "one endless line named .csv"])
def test_refusing_a_large_junk_file_takes_no_memory_for_its_size(tmp_path: Path, name) -> None:
    """100 MB of junk costs no more memory to refuse than 256 KiB of it (within 30 MB)."""
    small = _peak_rss_kib(write_junk(name, tmp_path, 4 * HEAD_BYTES))
    big = write_junk(name, tmp_path, 100 * 2**20)
    try:
        large = _peak_rss_kib(big)
    finally:
        big.unlink()
    assert large - small < 30 * 1024, (small, large)


def test_valid_files_pass_the_sniff(tmp_path: Path) -> None:
    csv = tmp_path / "ok.csv"
    csv.write_text(CSV_TEXT)
    no_final_break = tmp_path / "nobreak.csv"
    no_final_break.write_text(CSV_TEXT.rstrip("\n"))
    crlf = tmp_path / "crlf.csv"
    crlf.write_bytes(CSV_TEXT.replace("\n", "\r\n").encode())
    latin = tmp_path / "latin.csv"
    latin.write_bytes(CSV_TEXT.replace("front", "fr\xf6nt").encode("latin-1"))
    parquet = tmp_path / "ok.parquet"
    parquet.write_bytes(_parquet_bytes())
    for path in (csv, no_final_break, crlf, parquet):
        assert len(read_measurements(path)) in (49, 50)
    assert read_measurements(latin, outputs=("fr\xf6nt",), check_units=False).channels


def test_a_long_csv_with_breaks_after_64_kib_of_header_is_refused(tmp_path: Path) -> None:
    """The line-break rule looks at the first 64 KiB only: a header longer than that is
    refused even though breaks follow."""
    path = tmp_path / "wide.csv"
    path.write_bytes(b"time," + b"x" * HEAD_BYTES + b"\n0,1\n")
    with pytest.raises(DataError, match="no line break"):
        read_measurements(path)
