"""The model options of ``fit``: ``--set NAME=VALUE,...`` over the profile's hyperparameters,
and the tuning options (``--tune``, ``--tune-budget``, ``--tune-seed``, ``--tune-storage``).
The command only parses them: the application layer (:mod:`drafttwin.application`) builds the
model, and errors name the options through one table (:mod:`drafttwin.cli._terms`)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from drafttwin.cli._data import pairs
from drafttwin.cli._options import number

SetOpt = Annotated[
    str | None,
    typer.Option(
        "--set",
        help="Hyperparameters NAME=VALUE[,...] over the profile's (e.g. window=30,patience=20; "
        "numbers, true/false, none or a word): any the profile sets (window, hidden, layers, "
        "dropout, lr, batch_size, patience, val_fraction, clip_norm, folds, skip, "
        "sk_channels, data_window, data_hidden, data_layers; the epochs are --epochs) and the "
        "model's own (accumulate, structure, fade, fallback, val_folds, ...). A wrong name is "
        "refused with the valid ones.",
    ),
]


def parse_settings(text: str | None) -> dict[str, Any]:
    """``'window=30,patience=none,fade=strict'`` -> ``{'window': 30, 'patience': None,
    'fade': 'strict'}`` (integers, floats, true/false and none read as such)."""
    return {k: _value(v) for k, v in pairs(text, "--set", "window=30,patience=20").items()}


def _value(text: str) -> Any:
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    if low in ("none", "null"):
        return None
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


TuneOpt = Annotated[bool, typer.Option(
    "--tune", help="Search the hyperparameters (windows, sizes, layers, learning rate, epochs and "
    "patience, the hybrid's structure, several seeds) on validation data of the training records "
    "first, within --tune-budget CPU-minutes; resumable, its trial table kept in the model file. "
    "On small data the thing to do.")]  # fmt: skip
TuneBudgetOpt = Annotated[float | None, number(
    "--tune-budget", "CPU-minutes (user + system time of this process) the search may take "
    "(default 10).")]  # fmt: skip
TuneSeedOpt = Annotated[int | None, number(
    "--tune-seed", "Seed of the search: same seed, same trials (default 0).")]  # fmt: skip
TuneTrialsOpt = Annotated[int | None, number(
    "--tune-trials", "At most this many trials (a budget that does not depend on the "
    "machine's speed: with --tune-seed the same search anywhere).")]  # fmt: skip
TuneStorageOpt = Annotated[Path | None, typer.Option(
    "--tune-storage", help="The search's journal: a second run with the same file and request "
    "resumes it (default: OUT.tune.jsonl beside --out).")]  # fmt: skip


@dataclass(frozen=True)
class TuneOptions:
    """The tuning options of ``fit`` (an option group)."""

    tune: TuneOpt = False
    tune_budget: TuneBudgetOpt = None
    tune_seed: TuneSeedOpt = None
    tune_trials: TuneTrialsOpt = None
    tune_storage: TuneStorageOpt = None

    def storage(self, out: Path) -> Path | None:
        """The journal file: ``--tune-storage``, else ``OUT.tune.jsonl`` (with --tune only)."""
        if not self.tune:
            return None
        return self.tune_storage or out.with_name(out.name + ".tune.jsonl")

    def check(self, out: Path) -> None:
        """Tuning options without --tune are refused."""
        from drafttwin.errors import ConfigError

        given = [f for f, v in (("--tune-budget", self.tune_budget), ("--tune-seed", self.tune_seed),
                                ("--tune-trials", self.tune_trials),
                                ("--tune-storage", self.tune_storage)) if v is not None]  # fmt: skip
        if given and not self.tune:
            raise ConfigError(f"{', '.join(given)} without --tune", where=given[0],
                              fix="add --tune, or leave the tuning options out")  # fmt: skip
        if self.tune_storage is not None and self.tune_storage.resolve() == out.resolve():
            # the model file would replace the journal, and the next run refuse it
            raise ConfigError("names the --out file: the model would replace the search's "
                              "journal", where="--tune-storage", source=self.tune_storage,
                              fix="name another file (or leave --tune-storage out: "
                              "OUT.tune.jsonl)")  # fmt: skip

    @contextlib.contextmanager
    def stoppable(self) -> Iterator[None]:
        """A fit stops cleanly on SIGTERM / SIGINT (one line, exit 128 + signal, no model
        file); a search's journal keeps the finished trials, so the same command resumes it."""
        from drafttwin.execution.interrupt import stop_on_signals

        note = ("the same command resumes the search from its journal" if self.tune
                else "no model file was written")  # fmt: skip
        with stop_on_signals(note):
            yield

    @contextlib.contextmanager
    def progress(self, quiet: bool) -> Iterator[Callable[[dict[str, Any]], None] | None]:
        """A progress line per finished trial on stderr (``None`` when quiet or not tuning)."""
        if quiet or not self.tune:
            yield None
            return
        from rich.markup import escape

        from drafttwin.cli.typer_app import err_console

        def told(event: dict[str, Any]) -> None:
            score = event.get("score")
            shown = "failed" if score is None else f"score {score:.4g}"
            best = event.get("best")
            err_console.print(
                f"tune: trial {event['number']} {shown} (best {best:.4g}), "
                f"{event['cpu_s'] / 60:.1f}/{event['budget_min']:g} CPU-min: "
                f"{escape(event['params'])}" if best is not None else
                f"tune: trial {event['number']} {shown}, {event['cpu_s'] / 60:.1f}/"
                f"{event['budget_min']:g} CPU-min: {escape(event['params'])}",
                highlight=False, soft_wrap=True,
            )  # fmt: skip

        yield told
