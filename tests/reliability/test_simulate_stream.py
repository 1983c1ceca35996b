"""``simulate`` in pieces: bit-identical to one run, written piece by piece, memory flat.

* :func:`simulate_chunks` carries the full state from piece to piece: for every piece size
  (dividing the duration or not, smaller or larger than the kernel's block) the joined
  pieces equal :func:`simulate`'s arrays bit for bit, full and reduced trains alike;
* ``drafttwin simulate --out`` writes CSV text identical to the whole-frame writer and a
  Parquet file with the same table; nothing is left behind when the run fails;
* ``--rate`` defaults to the drive train's ``[solver] output_rate_hz``;
* a simulation that produces a non-finite value stops with one line naming the node and the
  time, exit 2, instead of writing NaN and exiting 0;
* peak memory of a ten-times-longer run is the same (checked on the reduced train).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from drafttwin.cli import app, mechanics_cmds
from drafttwin.cli._common import write_frame
from drafttwin.mechanics import (
    DriveTrain,
    NonFiniteSimulationError,
    reduce,
    simulate,
    simulate_chunks,
)

BELT = Path(__file__).resolve().parents[2] / "docs" / "examples" / "belt_drive.toml"
FIELDS = ("time_s", "node_rpm", "point_rpm", "energy_j")


@pytest.fixture(scope="module")
def fa320a() -> DriveTrain:
    return DriveTrain.preset("fa320a")


def _joined(pieces: list) -> dict[str, np.ndarray]:
    return {
        "time_s": np.concatenate([p.time_s for p in pieces]),
        **{f: np.vstack([getattr(p, f) for p in pieces]) for f in FIELDS[1:]},
    }


@pytest.mark.parametrize("chunk_s", [0.01, 0.07, 0.25, 0.5, 1.3, 2.3, 100.0])
def test_chunked_run_is_bit_identical_to_one_run(fa320a: DriveTrain, chunk_s: float) -> None:
    whole = simulate(fa320a, 2.3, output_rate_hz=200, settle_s=0.2)
    pieces = list(simulate_chunks(fa320a, 2.3, chunk_s=chunk_s, output_rate_hz=200, settle_s=0.2))
    joined = _joined(pieces)
    for name in FIELDS:
        np.testing.assert_array_equal(joined[name], getattr(whole, name), err_msg=name)
    assert [p.start_row for p in pieces] == list(
        np.cumsum([0, *[len(p.time_s) for p in pieces]])[:-1]
    )
    expected = int(np.ceil(460 / max(1, round(chunk_s * 200)))) if chunk_s * 200 < 460 else 1
    assert len(pieces) == expected


@pytest.mark.parametrize("chunk_s", [0.3, 1.0])
def test_chunked_reduced_train_is_bit_identical(fa320a: DriveTrain, chunk_s: float) -> None:
    train = reduce(fa320a, 200.0)
    whole = simulate(train, 3.0, output_rate_hz=100)
    joined = _joined(list(simulate_chunks(train, 3.0, chunk_s=chunk_s, output_rate_hz=100)))
    for name in FIELDS:
        np.testing.assert_array_equal(joined[name], getattr(whole, name), err_msg=name)


def _cli(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, ["simulate", "--quiet", *args])
    return result.exit_code, result.output


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_streamed_file_equals_the_whole_frame(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fa320a: DriveTrain, suffix: str
) -> None:
    """Pieces of 0.35 s (not dividing the 1.2 s run), written one by one, give the file the
    whole-frame writer gives."""
    monkeypatch.setattr(mechanics_cmds, "SIMULATE_CHUNK_S", 0.35)
    out = tmp_path / f"streamed{suffix}"
    code, output = _cli("--duration", "1.2", "--rate", "500", "--settle", "0.1", "--out", str(out))
    assert code == 0, output
    reference = tmp_path / f"whole{suffix}"
    write_frame(simulate(fa320a, 1.2, output_rate_hz=500, settle_s=0.1).to_frame(), reference)
    if suffix == ".csv":
        assert out.read_bytes() == reference.read_bytes()
    else:
        pd.testing.assert_frame_equal(pd.read_parquet(out), pd.read_parquet(reference))
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_summary_matches_the_whole_run(monkeypatch: pytest.MonkeyPatch, fa320a) -> None:
    """The running statistics print the numbers numpy gives for the whole run."""
    monkeypatch.setattr(mechanics_cmds, "SIMULATE_CHUNK_S", 0.3)
    code, output = _cli("--duration", "1", "--rate", "500", "--settle", "0.1")
    assert code == 0, output
    frame = simulate(fa320a, 1.0, output_rate_hz=500, settle_s=0.1).to_frame()
    for name in ("front", "back", "motor"):
        x = frame[name].to_numpy()
        row = re.search(rf"{name}\s*│\s*rpm\s*│\s*(\S+)\s*│\s*(\S+)\s*│\s*(\S+)", output)
        assert row is not None, output
        assert row.group(1) == f"{np.mean(x):.4g}"
        assert row.group(2) == f"{np.std(x) / abs(np.mean(x)) * 100:.4f}"


def _belt(tmp_path: Path, **solver: float) -> Path:
    text = BELT.read_text()
    for key, value in solver.items():
        text = re.sub(rf"^{key} = \S+", f"{key} = {value!r}", text, flags=re.M)
    path = tmp_path / "belt.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("rate_hz", [50.0, 250.0])
def test_rate_defaults_to_the_config_output_rate(tmp_path: Path, rate_hz: float) -> None:
    config = _belt(tmp_path, output_rate_hz=rate_hz)
    out = tmp_path / "y.csv"
    code, output = _cli("--config", str(config), "--duration", "2", "--out", str(out))
    assert code == 0, output
    frame = pd.read_csv(out)
    assert len(frame) == int(2 * rate_hz)
    np.testing.assert_allclose(np.diff(frame["time"]), 1 / rate_hz, rtol=1e-6)
    assert f"at {rate_hz:g} Hz" in output


def test_rate_option_still_overrides_the_config(tmp_path: Path) -> None:
    out = tmp_path / "y.csv"
    code, output = _cli("--config", str(_belt(tmp_path)), "--duration", "1", "--rate", "20",
                        "--out", str(out))  # fmt: skip
    assert code == 0, output
    assert len(pd.read_csv(out)) == 20


def _unstable(tmp_path: Path) -> Path:
    """The belt drive with a motor inertia 300x smaller and a 1 ms step: RK4 beyond its
    stability limit on the belt mode, so the speeds blow up within a few steps."""
    text = re.sub(r"^inertia_kgm2 = 0\.0030", "inertia_kgm2 = 0.00001", BELT.read_text(),
                  flags=re.M)  # fmt: skip
    text = re.sub(r"^dt_s = \S+", "dt_s = 1.0e-3", text, flags=re.M)
    path = tmp_path / "unstable.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("suffix", [".csv", ".parquet", None])
def test_non_finite_simulation_exits_2_naming_node_and_time(tmp_path: Path, suffix) -> None:
    out = tmp_path / f"y{suffix}" if suffix else None
    code, output = _cli("--config", str(_unstable(tmp_path)), "--duration", "5",
                        *(["--out", str(out)] if out else []))  # fmt: skip
    assert code == 2, output
    assert "Traceback" not in output
    assert re.search(r"produced (nan|inf|-inf) .*at t = -?[0-9.]+ s: \w+ of node 'motor'", output)
    assert "--dt" in output
    assert list(tmp_path.iterdir()) == [tmp_path / "unstable.toml"]  # nothing half-written


def test_non_finite_simulation_raises_from_the_api(tmp_path: Path) -> None:
    train = DriveTrain.from_toml(_unstable(tmp_path))
    with pytest.raises(NonFiniteSimulationError, match="node 'motor'"):
        simulate(train, 2.0)
    stream = simulate_chunks(train, 2.0, chunk_s=0.5)
    with pytest.raises(NonFiniteSimulationError):
        list(stream)


def test_non_finite_while_settling_is_named_as_such(tmp_path: Path) -> None:
    train = DriveTrain.from_toml(_unstable(tmp_path))
    with pytest.raises(NonFiniteSimulationError, match="while settling"):
        simulate(train, 1.0, settle_s=1.0)


_PEAK = """
import sys
from drafttwin.cli import app
try:
    app(sys.argv[1:])
except SystemExit:
    pass
print(int(open("/proc/self/status").read().split("VmHWM:")[1].split()[0]))
"""


def _peak_kib(tmp_path: Path, duration_s: float) -> int:
    out = tmp_path / "sim.parquet"
    argv = [sys.executable, "-c", _PEAK, "simulate", "--reduced", "--quiet", "--duration",
            f"{duration_s:g}", "--out", str(out)]  # fmt: skip
    done = subprocess.run(argv, capture_output=True, text=True, check=True, timeout=300)
    assert out.is_file()
    out.unlink()
    return int(done.stdout.strip().splitlines()[-1])


def test_peak_memory_is_flat_in_duration(tmp_path: Path) -> None:
    """40 s and 400 s of machine time (reduced train, 1 kHz) peak within 25 MB of each other;
    whole arrays of 400 s would add about 200 MB."""
    short, long = _peak_kib(tmp_path, 40.0), _peak_kib(tmp_path, 400.0)
    assert long - short < 25 * 1024, (short, long)
