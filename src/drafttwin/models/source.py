"""One parser for a physics source as a command names it: ``preset`` / ``preset:NAME``,
``config:FILE.toml`` (a drive train), simulator output file(s) ``FILE[,FILE...]`` or a
fitted model file (whose drive train it carries). ``fit``/``predict``/``evaluate``
(:meth:`MechanisticModel.from_option`), the diagnosis (``--model``) and the commands that take
``--preset``/``--config`` all read it here."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from drafttwin.errors import ConfigError

if TYPE_CHECKING:
    from drafttwin.mechanics import DriveTrain


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
        return PhysicsSource("preset", preset=rest.strip() or "fa320a")
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


def drive_train(source: str | PhysicsSource, where: str = "--model") -> DriveTrain:
    """The drive train a source names: a preset, a TOML, or the train a fitted model file
    carries (a model fitted on simulator files carries none: refused)."""
    from drafttwin.mechanics import DriveTrain

    parsed = parse_source(source, where) if isinstance(source, str) else source
    if parsed.kind == "preset":
        return DriveTrain.preset(parsed.preset)
    if parsed.kind == "config":
        return DriveTrain.from_toml(parsed.paths[0])
    if len(parsed.paths) != 1:
        raise ConfigError("a drive train comes from one model file, not a list of files",
                          where=where, fix="give one model file, preset or config:FILE.toml")  # fmt: skip
    from drafttwin.models.registry import load_model

    path = parsed.paths[0]
    fitted = load_model(path)
    spec = getattr(fitted, "mechanistic_spec_", None) or {}
    if spec.get("kind") == "preset":
        return DriveTrain.preset(str(spec["name"]))
    if spec.get("kind") == "train":
        return DriveTrain.from_dict(dict(spec["spec"]), source=f"model file {path}")
    raise ConfigError(
        f"the model in this file ({type(fitted).__name__}) carries no drive train "
        f"(its physics: {spec.get('kind', 'none')})",
        source=path,
        where=where,
        fix="fit a model on a drive-train physics (fit --mechanistic preset or config:FILE.toml), "
        "or give --model preset / config:FILE.toml",
    )
