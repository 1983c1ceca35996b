"""Count how a drafttwin source tree handles the hostile CLI inputs of the reliability tests.

    python -m tests.reliability._measure [SRC] [--timeout S] [--jobs N]

Runs every numeric case (:func:`numeric_cases`) and every I/O scenario (:data:`IO_CASES`)
in a subprocess that imports drafttwin from SRC (default: the installed one) and prints one
line per case and the totals by outcome: clean (exit 2, one message), traceback, usage box,
accepted (exit 0), hang (time limit), other. Root is needed for the I/O scenarios.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tests.reliability._cli import ENDLESS, IO_CASES, OLD, argv_for, numeric_cases, run_cli


def _model(src: Path | None, folder: Path) -> Path:
    model = folder / "model.pt"
    out = run_cli(["fit", "--model", "persistence", "--quiet", "--out", str(model)], src=src)
    if out.exit_code != 0:
        sys.exit(f"cannot fit the model file the cases need:\n{out.stderr}")
    return model


def _numeric(case: tuple[str, str, str], src: Path | None, model: Path, timeout: float) -> str:
    command, option, label = case
    with tempfile.TemporaryDirectory() as tmp:
        out = run_cli(argv_for(command, option, label, Path(tmp), model), src=src,
                      timeout_s=timeout)  # fmt: skip
    return out.kind


def _endless(name: str, src: Path | None, timeout: float) -> str:
    with tempfile.TemporaryDirectory() as tmp:
        argv = [a.format(tmp=tmp) for a in ENDLESS[name]]
        return run_cli(argv, src=src, timeout_s=timeout).kind


def _io(index: int, src: Path | None, model: Path, timeout: float) -> str:
    case = IO_CASES[index]
    tmp = Path(tempfile.mkdtemp())
    try:
        with contextlib.ExitStack() as stack:
            argv, watched = case.setup(tmp, model, stack)
            out = run_cli(argv, src=src, timeout_s=timeout, preexec=case.preexec)
            kind = out.kind
            if case.expect == "written":
                ok = kind == "accepted" and watched is not None and watched.is_file()
                return "clean" if ok else kind
            if watched is not None and watched.is_file() and watched.read_text() != OLD:
                return "old file damaged"
            return kind
    finally:
        subprocess.run(["chmod", "-R", "u+rwx", str(tmp)], check=False)
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("src", nargs="?", type=Path)
    parser.add_argument("--timeout", type=float, default=30.0)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--only", choices=("numeric", "endless", "io"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        model = _model(args.src, Path(folder))
        cases = numeric_cases() if args.only in (None, "numeric") else []
        with ThreadPoolExecutor(args.jobs) as pool:
            kinds = list(pool.map(lambda c: _numeric(c, args.src, model, args.timeout), cases))
        for (command, option, label), kind in zip(cases, kinds, strict=True):
            print(f"{kind:12s} {command} {option} {label}", flush=True)
        endless = list(ENDLESS) if args.only in (None, "endless") else []
        with ThreadPoolExecutor(args.jobs) as pool:
            endless_kinds = list(pool.map(lambda n: _endless(n, args.src, args.timeout), endless))
        for name, kind in zip(endless, endless_kinds, strict=True):
            print(f"{kind:12s} {name}", flush=True)
        io_cases = range(len(IO_CASES)) if args.only in (None, "io") else range(0)
        io_kinds = [_io(i, args.src, model, args.timeout) for i in io_cases]
    for i, kind in zip(io_cases, io_kinds, strict=True):
        print(f"{kind:12s} {IO_CASES[i].name}")
    groups = (("numeric", kinds), ("endless", endless_kinds), ("I/O", io_kinds),
              ("all", kinds + endless_kinds + io_kinds))  # fmt: skip
    for name, group in groups:
        counts = collections.Counter(group)
        print(
            f"{name}: {len(group)} cases: " + ", ".join(f"{k} {v}" for k, v in counts.most_common())
        )


if __name__ == "__main__":
    main()
