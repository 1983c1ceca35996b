"""Helpers of the CLI reliability tests: run ``drafttwin`` (in-process or in a subprocess),
classify how it ended, and make hostile I/O conditions for real (a read-only or full tmpfs,
a file-size limit, a process without root's permission override).

The hostile inputs themselves (:data:`NUMERIC_CASES`, the I/O scenarios in
``test_cli_inputs.py``) are also run by ``python -m tests.reliability._measure`` against any
source tree, to count how a version of drafttwin handles them.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import resource
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

# the values every numeric option is tried with; those inside an option's range are skipped
HOSTILE = {"0": 0.0, "-1": -1.0, "nan": math.nan, "inf": math.inf, "1e300": 1e300, "text": None}

#: each command's cheapest valid invocation ({tmp}: a scratch folder; {model}: a model file
#: written by ``fit --model persistence``); a numeric option under test is put first
BASE: dict[str, list[str]] = {
    "kinematics": ["kinematics", "--json"],
    "simulate": ["simulate", "--duration", "0.1", "--quiet", "--out", "{tmp}/sim.csv"],
    "inspect": ["inspect", "default", "--json"],
    "generate": ["generate", "--duration", "0.5", "--quiet", "--out", "{tmp}/gen.csv"],
    "generate-faults": [
        "generate-faults",
        "--cases",
        "1",
        "--duration",
        "0.5",
        "--quiet",
        "--out",
        "{tmp}/faults",
    ],  # fmt: skip
    "diagnose": ["diagnose", "--model", "preset", "--data", "default", "--json"],
    "benchmark faults": ["benchmark", "faults", "--quick", "--quiet", "--out", "{tmp}/bf"],
    "benchmark generalisation": [
        "benchmark",
        "generalisation",
        "--quick",
        "--quiet",
        "--out",
        "{tmp}/bg",
    ],  # fmt: skip
    "fit": ["fit", "--model", "persistence", "--out", "{tmp}/fit.pt", "--quiet"],
    "predict": ["predict", "--model", "{model}", "--out", "{tmp}/pred.csv"],
    "evaluate": ["evaluate", "--model", "{model}", "--json"],
    "calibrate": ["calibrate", "--data", "default", "--out", "{tmp}/cal.toml", "--quiet"],
    "reproduce": ["reproduce", "--out", "{tmp}/study", "--quiet"],
    "grid-search": ["grid-search", "--out", "{tmp}/grid", "--quiet"],
    "benchmark emps": [
        "benchmark",
        "emps",
        "--data-dir",
        "{tmp}/no-emps",
        "--quiet",
        "--out",
        "{tmp}/emps",
    ],  # fmt: skip
    "twin run": ["twin", "run", "--model", "{model}", "--source", "replay:{tmp}/none.csv"],
    "twin query": ["twin", "query", "--store", "{tmp}/store"],
    "twin fit-detector": [
        "twin",
        "fit-detector",
        "--model",
        "{model}",
        "--healthy",
        "{tmp}/none.parquet",
    ],  # fmt: skip
    "plant serve": ["plant", "serve", "--opcua", "opc.tcp://127.0.0.1:1", "--duration", "0.1"],
    "sliver simulate": [
        "sliver",
        "simulate",
        "--duration",
        "0.5",
        "--fibre-scale",
        "100",
        "--quiet",
        "--out",
        "{tmp}/sl.csv",
    ],
    "sliver spectrogram": ["sliver", "spectrogram", "--data", "{tmp}/none.csv"],
    "sliver wavelengths": ["sliver", "wavelengths", "--json"],
    "sliver diagnose": ["sliver", "diagnose", "--data", "{tmp}/none.csv"],
    "plant replay": [
        "plant",
        "replay",
        "--mqtt",
        "127.0.0.1:1",
        "--records",
        "{tmp}/none.parquet",
    ],  # fmt: skip
    "sliver level": ["sliver", "level", "--data", "{tmp}/none.csv"],
    "benchmark leveller": ["benchmark", "leveller", "--quick", "--quiet", "--out", "{tmp}/bl"],
    "twin hall": [
        "twin",
        "hall",
        "--model",
        "{model}",
        "--source",
        "opcua:opc.tcp://127.0.0.1:1",
        "--mapping",
        "{tmp}/hall.toml",
        "--store",
        "{tmp}/hall",
        "--duration",
        "0.1",
    ],  # fmt: skip
}

#: every numeric option of every command, with whether 0 and -1 are in its range
NUMERIC_OPTIONS: dict[str, list[str]] = {
    "kinematics": ["--motor-rpm"],
    "simulate": ["--duration", "--rate", "--dt", "--settle", "--cutoff-hz"],
    "inspect": ["--rate-tolerance", "--rate", "--threshold"],
    "generate": ["--duration", "--rate", "--seed", "--machine-seed", "--fibre-scale"],
    "generate-faults": ["--cases", "--seed", "--duration", "--rate"],
    "diagnose": ["--far-per-day"],
    "benchmark faults": [
        "--seed",
        "--workers",
        "--healthy-hours",
        "--machines",
        "--speed",
        "--plant-machines",
    ],
    "benchmark generalisation": ["--seeds", "--workers"],
    "fit": [
        "--init-samples",
        "--rate-tolerance",
        "--tune-budget",
        "--tune-seed",
        "--tune-trials",
        "--train-fraction",
        "--seed",
        "--horizon",
        "--epochs",
    ],
    "predict": ["--init-samples", "--rate-tolerance"],
    "evaluate": ["--init-samples", "--rate-tolerance", "--train-fraction", "--score-from"],
    "calibrate": ["--rate-tolerance", "--block"],
    "reproduce": ["--workers"],
    "grid-search": ["--workers"],
    "benchmark emps": ["--seeds", "--workers", "--epochs", "--max-samples"],
    "twin run": [
        "--commit-ms",
        "--retention-hours",
        "--learn",
        "--silent",
        "--level-window",
        "--level-search",
        "--duration",
        "--max-samples",
    ],
    "twin query": ["--from", "--to"],
    "twin fit-detector": ["--far-per-day", "--reference", "--post"],
    "plant serve": [
        "--machines",
        "--seed",
        "--rate",
        "--ramp",
        "--duration",
        "--history",
        "--qos",
        "--max-lag",
        "--fibre-scale",
    ],
    "twin hall": [
        "--shards",
        "--commit-ms",
        "--duration",
        "--learn",
        "--level-window",
        "--level-search",
    ],
    "plant replay": ["--machines", "--speed", "--batch", "--gap", "--lead"],
    "sliver simulate": [
        "--duration",
        "--fineness-dtex",
        "--fineness-cv",
        "--doublings",
        "--feed-ktex",
        "--feed-cv",
        "--feed-correlation",
        "--step-mm",
        "--fibre-scale",
        "--seed",
    ],
    "sliver spectrogram": ["--fineness-dtex", "--fineness-cv", "--sensor-mm", "--fibre-scale"],
    "sliver wavelengths": ["--motor-rpm", "--harmonics"],
    "sliver diagnose": [
        "--fineness-dtex",
        "--fineness-cv",
        "--sensor-mm",
        "--harmonics",
        "--fibre-scale",
        "--tested-m",
        "--nominal-count",
    ],
    "sliver level": [
        "--action-point",
        "--intensity",
        "--reference-ktex",
        "--max-length",
        "--search",
        "--fineness-dtex",
        "--fineness-cv",
    ],
    "benchmark leveller": ["--machines", "--fault-cases", "--seed", "--workers"],
}

#: values inside the range of options that may be zero (these are not hostile there)
ZERO_OK = {"--settle", "--rate-tolerance", "--threshold", "--seed", "--machine-seed", "--from",
           "--to", "--history", "--feed-cv", "--fineness-cv", "--sensor-mm", "--qos", "--score-from",
           "--learn", "--gap", "--lead", "--plant-machines", "--tune-seed", "--action-point",
           "--intensity", "--fault-cases"}  # fmt: skip


def numeric_cases() -> list[tuple[str, str, str]]:
    """(command, option, hostile value) for every numeric option and every value outside
    its range."""
    out = []
    for command, options in NUMERIC_OPTIONS.items():
        for option in options:
            for label in HOSTILE:
                if label == "0" and option in ZERO_OK:
                    continue
                out.append((command, option, label))
    return out


#: numbers inside each option's own range that together ask for work that would never end
#: (or a file of tens of gigabytes): refused at once by :mod:`drafttwin._limits`
ENDLESS: dict[str, list[str]] = {
    "simulate --dt 1e-7": ["simulate", "--dt", "1e-7", "--duration", "1e5", "--quiet"],
    "simulate --duration 1e6": ["simulate", "--duration", "1e6", "--quiet"],
    "simulate --rate 1e6 --duration 1e5": [
        "simulate",
        "--rate",
        "1e6",
        "--duration",
        "1e5",
        "--quiet",
    ],  # fmt: skip
    "generate --duration 1e6": [
        "generate",
        "--duration",
        "1e6",
        "--quiet",
        "--out",
        "{tmp}/g.csv",
    ],  # fmt: skip
    "generate --rate 1e6 --duration 1e5": [
        "generate",
        "--rate",
        "1e6",
        "--duration",
        "1e5",
        "--quiet",
        "--out",
        "{tmp}/g.csv",
    ],  # fmt: skip
}


def argv_for(command: str, option: str, label: str, tmp: Path, model: Path) -> list[str]:
    """The command line of one numeric case: the hostile option first, then the base."""
    value = "abc" if label == "text" else label
    words = command.split()
    base = [a.format(tmp=tmp, model=model) for a in BASE[command]][len(words) :]
    if option in base:  # the base's own value would win (the last one given counts)
        i = base.index(option)
        del base[i : i + 2]
    return [*words, option, value, *base]


# -- running and classifying ------------------------------------------------------------


@dataclass
class Outcome:
    """How one run of the CLI ended."""

    exit_code: int | None  # None: killed at the time limit
    stdout: str
    stderr: str

    @property
    def kind(self) -> str:
        """clean (exit 2, one error message), traceback, usage box, accepted (exit 0),
        hang (time limit) or other."""
        err = self.stderr
        if self.exit_code is None:
            return "hang"
        if "Traceback (most recent call last)" in err:
            return "traceback"
        if self.exit_code == 0:
            return "accepted"
        if self.exit_code == 2 and ("╭" in err or "Usage:" in err):
            return "usage box"
        if self.exit_code == 2 and is_one_message(err):
            return "clean"
        return "other"


def is_one_message(stderr: str) -> bool:
    """One error: a line ``error: ...`` and at most its ``fix:`` line, nothing else."""
    lines = [ln for ln in stderr.strip().splitlines() if ln.strip()]
    if not lines or not lines[0].startswith("error: "):
        return False
    return len(lines) == 1 or (len(lines) == 2 and lines[1].strip().startswith("fix: "))


def run_cli(
    argv: list[str],
    *,
    src: Path | None = None,
    timeout_s: float = 60.0,
    preexec: Callable[[], None] | None = None,
    cwd: Path | None = None,
) -> Outcome:
    """``drafttwin ARGV`` in a fresh interpreter (``src``: the source tree to import)."""
    env = dict(
        os.environ, COLUMNS="100", NUMBA_DISABLE_JIT=os.environ.get("NUMBA_DISABLE_JIT", "0")
    )
    if src is not None:
        env["PYTHONPATH"] = str(src)
    cmd = [sys.executable, "-c", "from drafttwin.cli import main; main()", *argv]
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=env,
                             preexec_fn=preexec, cwd=cwd)  # fmt: skip
    except subprocess.TimeoutExpired as exc:
        return Outcome(None, _text(exc.stdout), _text(exc.stderr))
    return Outcome(res.returncode, res.stdout, res.stderr)


_BATCH = """
import json, sys
from typer.testing import CliRunner
from drafttwin.cli import app
out = []
for argv in json.loads(sys.argv[1]):
    r = CliRunner().invoke(app, argv)
    err = r.stderr
    if r.exception is not None and not isinstance(r.exception, SystemExit):
        import traceback
        err += "".join(traceback.format_exception(r.exception))
    out.append([r.exit_code, r.stdout, err])
print(json.dumps(out))
"""


def run_batch(argvs: list[list[str]], *, preexec: Callable[[], None] | None,
              timeout_s: float = 180.0) -> list[Outcome]:  # fmt: skip
    """Several command lines in one fresh interpreter (made by ``preexec``: a file-size
    limit, no permission override), each run as by ``drafttwin ARGV``: one start-up for all."""
    import json

    res = subprocess.run([sys.executable, "-c", _BATCH, json.dumps(argvs)], capture_output=True,
                         text=True, timeout=timeout_s, preexec_fn=preexec, check=False)  # fmt: skip
    if res.returncode != 0:
        raise RuntimeError(f"the batch failed:\n{res.stderr}")
    return [Outcome(code, out, err) for code, out, err in json.loads(res.stdout)]


def _text(data: bytes | str | None) -> str:
    if isinstance(data, bytes):
        return data.decode(errors="replace")
    return data or ""


def leftovers(folder: Path) -> list[Path]:
    """Temporary files an atomic write left behind in ``folder`` (they start with a dot)."""
    if not folder.is_dir():
        return []
    return [p for p in folder.rglob(".*") if p.is_file()]


# -- hostile conditions, made for real ----------------------------------------------------

_PR_CAPBSET_DROP = 24
_CAP_DAC_OVERRIDE, _CAP_DAC_READ_SEARCH = 1, 2


def without_root_override() -> None:
    """preexec: drop the capabilities that let root ignore file permissions, so that a
    folder or file without the permission bits refuses this process (EACCES) as it would
    any user."""
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (_CAP_DAC_OVERRIDE, _CAP_DAC_READ_SEARCH):
        if libc.prctl(_PR_CAPBSET_DROP, cap, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")


def file_size_limit(limit_bytes: int) -> Callable[[], None]:
    """preexec: ``ulimit -f`` (a write past ``limit_bytes`` fails with EFBIG)."""

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return limit


def can_drop_root_override() -> bool:
    """True when a child process without DAC override really is refused (we are root, and
    may drop capabilities)."""
    if os.geteuid() != 0:
        return False
    probe = subprocess.run(["cat", "/proc/self/status"], capture_output=True, text=True,
                           preexec_fn=without_root_override, check=False)  # fmt: skip
    return probe.returncode == 0


@contextlib.contextmanager
def tmpfs(folder: Path, *, size: str = "64k", read_only: bool = False) -> Iterator[Path]:
    """A real tmpfs mounted on ``folder`` (root only); unmounted on exit."""
    folder.mkdir(parents=True, exist_ok=True)
    opts = f"size={size}" + (",ro" if read_only else "")
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(folder)],
                         capture_output=True, text=True, check=False)  # fmt: skip
    if res.returncode != 0:
        import pytest

        pytest.skip(f"cannot mount a tmpfs (needs root): {res.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def fill(folder: Path) -> None:
    """Fill the file system of ``folder`` to the last byte."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize
    with open(folder / "filler.bin", "wb", buffering=0) as f:  # noqa: PTH123
        with contextlib.suppress(OSError):
            f.write(b"\0" * free)
        with contextlib.suppress(OSError):
            while True:  # what statvfs did not count (metadata rounding)
                f.write(b"\0" * 512)


# -- I/O scenarios ------------------------------------------------------------------------

OLD = "old content\n"


@dataclass(frozen=True)
class IoCase:
    """One hostile I/O condition: ``setup(tmp)`` makes it and returns the command line and
    the file that must keep its old content (or be written, when ``expect`` is 'written')."""

    name: str
    setup: Callable[[Path, Path, contextlib.ExitStack], tuple[list[str], Path | None]]
    preexec: Callable[[], None] | None = None
    expect: str = "clean"


def _sim(out: Path) -> list[str]:
    return ["simulate", "--duration", "0.5", "--quiet", "--out", str(out)]


def old_file(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(OLD)
    return path


def _ro(tmp: Path, stack: contextlib.ExitStack) -> Path:
    return stack.enter_context(tmpfs(tmp / "ro", read_only=True))


def _full(tmp: Path, stack: contextlib.ExitStack) -> Path:
    disk = stack.enter_context(tmpfs(tmp / "full", size="64k"))
    return disk


def _unreadable(path: Path) -> Path:
    path.chmod(0)
    return path


def _no_write(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    folder.chmod(0o555)
    return folder


def _io_cases() -> list[IoCase]:
    def full_sim(tmp: Path, model: Path, st: contextlib.ExitStack) -> tuple[list[str], Path]:
        disk = _full(tmp, st)
        old = old_file(disk / "x.csv")
        fill(disk)
        return _sim(old), old

    def full_gen(tmp: Path, model: Path, st: contextlib.ExitStack) -> tuple[list[str], Path]:
        disk = _full(tmp, st)
        old = old_file(disk / "g.csv")
        fill(disk)
        return ["generate", "--duration", "2", "--quiet", "--out", str(old)], old

    def full_fit(tmp: Path, model: Path, st: contextlib.ExitStack) -> tuple[list[str], Path]:
        disk = _full(tmp, st)
        old = old_file(disk / "m.pt")
        fill(disk)
        return ["fit", "--model", "persistence", "--quiet", "--out", str(old)], old

    def fsize(tmp: Path, model: Path, st: contextlib.ExitStack) -> tuple[list[str], Path]:
        old = old_file(tmp / "big" / "x.csv")
        return ["simulate", "--duration", "1", "--rate", "4000", "--quiet", "--out",
                str(old)], old  # fmt: skip

    cases = [
        IoCase("simulate --out on a read-only file system",
               lambda t, m, st: (_sim(_ro(t, st) / "x.csv"), None)),
        IoCase("simulate --out is a directory",
               lambda t, m, st: (_sim(t), None)),
        IoCase("simulate --out's parent is a file",
               lambda t, m, st: (_sim(old_file(t / "f.txt") / "x.csv"), t / "f.txt")),
        IoCase("simulate --out on a full disk (old file kept)", full_sim),
        IoCase("simulate --out past the file-size limit (ulimit -f)", fsize,
               preexec=file_size_limit(16 * 1024)),
        IoCase("simulate --out in a folder without write permission",
               lambda t, m, st: (_sim(_no_write(t / "nw") / "x.csv"), None),
               preexec=without_root_override),
        IoCase("simulate --out in missing folders (created)",
               lambda t, m, st: (_sim(t / "a" / "b" / "x.csv"), t / "a" / "b" / "x.csv"),
               expect="written"),
        IoCase("simulate --config unreadable",
               lambda t, m, st: (["simulate", "--config", str(_unreadable(old_file(t / "c.toml"))),
                                  "--duration", "0.1"], None),
               preexec=without_root_override),
        IoCase("simulate --config is a directory",
               lambda t, m, st: (["simulate", "--config", str(t), "--duration", "0.1"], None)),
        IoCase("generate --out on a read-only file system",
               lambda t, m, st: (["generate", "--duration", "0.5", "--quiet", "--out",
                                  str(_ro(t, st) / "g.csv")], None)),
        IoCase("generate --out on a full disk (old file kept)", full_gen),
        IoCase("generate --out is a directory",
               lambda t, m, st: (["generate", "--duration", "0.5", "--quiet", "--out", str(t)],
                                 None)),
        IoCase("inspect an unreadable file",
               lambda t, m, st: (["inspect", str(_unreadable(old_file(t / "d.csv")))], None),
               preexec=without_root_override),
        IoCase("inspect a directory",
               lambda t, m, st: (["inspect", str(t)], None)),
        IoCase("fit --out on a read-only file system",
               lambda t, m, st: (["fit", "--model", "persistence", "--quiet", "--out",
                                  str(_ro(t, st) / "m.pt")], None)),
        IoCase("fit --out on a full disk (old file kept)", full_fit),
        IoCase("fit --out is a directory",
               lambda t, m, st: (["fit", "--model", "persistence", "--quiet", "--out", str(t)],
                                 None)),
        IoCase("fit --data unreadable",
               lambda t, m, st: (["fit", "--model", "persistence", "--quiet", "--out",
                                  str(t / "m.pt"), "--data",
                                  str(_unreadable(old_file(t / "d.csv")))], None),
               preexec=without_root_override),
        IoCase("fit --data is a directory",
               lambda t, m, st: (["fit", "--model", "persistence", "--quiet", "--out",
                                  str(t / "m.pt"), "--data", str(t)], None)),
        IoCase("predict --model unreadable",
               lambda t, m, st: (["predict", "--model", str(_unreadable(old_file(t / "m.pt"))),
                                  "--out", str(t / "p.csv")], None),
               preexec=without_root_override),
        IoCase("predict --out is a directory",
               lambda t, m, st: (["predict", "--model", str(m), "--out", str(t)], None)),
        IoCase("predict --out on a read-only file system",
               lambda t, m, st: (["predict", "--model", str(m), "--out",
                                  str(_ro(t, st) / "p.csv")], None)),
        IoCase("calibrate --out is a directory",
               lambda t, m, st: (["calibrate", "--data", "default", "--quiet", "--out",
                                  str(_no_write(t / "cal.toml"))], None)),
        IoCase("reproduce --out is a file",
               lambda t, m, st: (["reproduce", "--quiet", "--out", str(old_file(t / "s"))],
                                 t / "s")),
        IoCase("grid-search --out is a file",
               lambda t, m, st: (["grid-search", "--quiet", "--out", str(old_file(t / "g"))],
                                 t / "g")),
        IoCase("reproduce --out on a read-only file system",
               lambda t, m, st: (["reproduce", "--quiet", "--out", str(_ro(t, st) / "s")],
                                 None)),
    ]  # fmt: skip
    return cases


IO_CASES = _io_cases()
