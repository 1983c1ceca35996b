"""One parser for a physics source as a command names it: ``preset`` / ``preset:NAME``,
``config:FILE.toml`` (a drive train), simulator output file(s) ``FILE[,FILE...]`` or a
fitted model file (whose drive train it carries). ``fit``/``predict``/``evaluate``
(:meth:`MechanisticModel.from_option`), the diagnosis (``--model``) and the commands that take
``--preset``/``--config`` all read it here; the drive train a source names (a model file's
included) is :func:`drafttwin.models.registry.drive_train`, above the model classes, so this
parser stays a leaf that every model module may import."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drafttwin.errors import ConfigError, unknown_choice
from drafttwin.mechanics.config import PRESETS


@dataclass(frozen=True)
class PhysicsSource:
    """A parsed physics source.

    Attributes:
        kind: ``"preset"``, ``"config"`` (a drive-train TOML) or ``"files"`` (simulator output
            files, one per record, or one fitted model file).
        preset: the preset's name (``kind == "preset"``).
        paths: the TOML, or the files.
    """

    kind: str
    preset: str = "fa320a"
    paths: tuple[Path, ...] = ()


def parse_source(text: str, where: str = "--mechanistic") -> PhysicsSource:
    """``'preset:fa320a'``, ``'config:train.toml'`` or ``'a.csv,b.csv'`` as a
    :class:`PhysicsSource` (``where``: the option named in an error)."""
    text = text.strip()
    kind, sep, rest = text.partition(":")
    if text == "preset" or (sep and kind == "preset"):
        name = rest.strip().lower() or "fa320a"
        if name not in PRESETS:
            # Named here, where the option the user typed is known (mechanics names --preset).
            raise unknown_choice(f"unknown preset '{name}'", (f"preset:{p}" for p in PRESETS),
                                 where=where, fix_also=", config:FILE.toml or a file")  # fmt: skip
        return PhysicsSource("preset", preset=name)
    if sep and kind == "config":
        if not rest.strip():
            raise ConfigError("config: needs a file", where=where,
                              fix=f"write {where} config:my_train.toml")  # fmt: skip
        return PhysicsSource("config", paths=(Path(rest.strip()),))
    paths = tuple(Path(p.strip()) for p in text.split(",") if p.strip())
    if not paths:
        raise ConfigError("no physics source given", where=where,
                          fix=f"write {where} preset, config:FILE.toml or a file")  # fmt: skip
    return PhysicsSource("files", paths=paths)
