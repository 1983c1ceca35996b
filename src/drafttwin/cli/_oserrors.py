"""One error path for I/O: an OSError becomes one message naming the path, the option it
came from and the fix (exit code 2), whatever the command and wherever it was raised.

Path options register themselves while the command line is parsed (:func:`input_path`,
:func:`output_file`, :func:`output_dir` are their typer callbacks), so a failure deep in a
writer can still say "--out". Output paths are also checked at once, before any work: an
existing folder given for a file, a file where a folder is needed (as the target or as one
of its parents), a folder that cannot be written (read-only file system, no permission).
"""

from __future__ import annotations

import errno
import os
from collections.abc import Callable, Iterable
from pathlib import Path

from drafttwin.errors import ConfigError, DrafttwinError

PathCallback = Callable[[Path | None], Path | None]  # typer reads the returned callback's signature

_OPTIONS: dict[Path, str] = {}  # path as given (absolute) -> the option that named it
_INPUTS: dict[Path, str] = {}  # input files of this command -> their option
_OUTPUTS: dict[Path, str] = {}  # output files of this command -> their option

_REASONS: dict[int, tuple[str, str]] = {
    errno.EACCES: ("permission denied", "make it accessible to you (chmod, chown) or choose "
                   "another path"),
    errno.EPERM: ("operation not permitted", "choose another path"),
    errno.EROFS: ("read-only file system", "write to a folder on a writable file system"),
    errno.ENOSPC: ("no space left on device; nothing was written",
                   "free space on that disk or write elsewhere"),
    errno.EDQUOT: ("disk quota exceeded; nothing was written",
                   "free space within your quota or write elsewhere"),
    errno.EFBIG: ("file too large (the file-size limit, ulimit -f, or the file system's); "
                  "nothing was written", "raise the limit (ulimit -f) or write elsewhere"),
    errno.EISDIR: ("is a folder, a file is expected", "name a file (inside that folder)"),
    errno.ENOTDIR: ("a part of this path is a file, not a folder", "choose a path whose "
                    "parents are folders"),
    errno.EEXIST: ("a file is in the way of a folder on this path", "choose a path whose "
                   "parents are folders"),
    errno.ENOENT: ("no such file or folder", "check the path"),
    errno.ENAMETOOLONG: ("file name too long", "choose a shorter path"),
    errno.ELOOP: ("too many symbolic links", "check the links on this path"),
}  # fmt: skip


def remember(path: str | Path, option: str) -> None:
    """Note that ``option`` named ``path`` (for messages about it later)."""
    _OPTIONS[Path(os.path.abspath(path))] = option


def forget_paths() -> None:
    """Forget the paths remembered so far (a new command starts)."""
    _OPTIONS.clear()
    _INPUTS.clear()
    _OUTPUTS.clear()


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two paths name one file (the same absolute path, or a link to it)."""
    a, b = Path(os.path.abspath(a)), Path(os.path.abspath(b))
    if a == b:
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _companions(path: Path) -> list[Path]:
    """A plant record's sidecar (``<stem>.json``) and the files it names (truth, sliver): they
    are read with the record, so they are inputs too."""
    import json

    sidecar = path.with_suffix(".json")
    if path.suffix == ".json" or not sidecar.is_file():
        return []
    try:
        files = json.loads(sidecar.read_text(encoding="utf-8")).get("files", {})
    except (OSError, ValueError, AttributeError):
        return [sidecar]
    names = files.values() if isinstance(files, dict) else ()
    return [sidecar, *(path.with_name(n) for n in names
                       if isinstance(n, str) and n and Path(n).name == n)]  # fmt: skip


def _no_clash(path: Path, option: str, *, output: bool) -> None:
    """Refuse an output file that is also an input of the same command, or a file of an
    input's record (whichever option the parser reads first): writing it would destroy what
    the command reads."""
    mine, others = (_OUTPUTS, _INPUTS) if output else (_INPUTS, _OUTPUTS)
    p = Path(os.path.abspath(path))
    for other, other_option in others.items():
        if same_file(p, other):
            out_option, in_option = (option, other_option) if output else (other_option, option)
            raise ConfigError(f"is both {in_option} and {out_option}: writing it would replace "
                              "the input", source=path, where=out_option,
                              fix=f"give {out_option} another file name")  # fmt: skip
    mine[p] = option
    if not output:
        for companion in _companions(p):
            companion = Path(os.path.abspath(companion))
            if companion not in mine:
                _no_clash(companion, f"{option} (a file of its record)", output=False)


def no_input_among(folder: Path, names: Iterable[str], option: str) -> None:
    """Refuse an output folder in which a file the command writes under a fixed name is one
    of its inputs (or a file of an input's record): writing it would replace the input."""
    for name in names:
        path = Path(os.path.abspath(folder / name))
        for other, other_option in _INPUTS.items():
            if same_file(path, other):
                raise ConfigError(f"is {other_option}, and the command writes its {name} in "
                                  f"{option}: writing it would replace the input", source=other,
                                  where=option, fix=f"give {option} another folder, or move "
                                  "the input out of it")  # fmt: skip


def option_of(path: str | Path) -> str | None:
    """The option that named ``path``, a file beside it (a temporary file) or a file under it
    (a missing or unusable parent folder); ``None`` when none did."""
    p = Path(os.path.abspath(path))
    if p in _OPTIONS:
        return _OPTIONS[p]
    for known, option in _OPTIONS.items():
        if p == known.parent or p in known.parents or known in p.parents:
            return option
    return None


def describe(exc: OSError) -> DrafttwinError:
    """The user error for ``exc``: path, option, reason, fix."""
    path = exc.filename if exc.filename is not None else exc.filename2
    reason, fix = _REASONS.get(exc.errno or -1, (None, None))
    if reason is None:
        reason = exc.strerror or str(exc) or type(exc).__name__
        fix = "check the path and the disk"
    if path is None:
        return ConfigError(reason, fix=fix)
    return ConfigError(reason, source=path, where=option_of(path), fix=fix)


# -- typer callbacks of path options -----------------------------------------------------


def input_path(option: str) -> PathCallback:
    """Callback of an input file option: remember it (the reading reports errors)."""

    def callback(value: Path | None) -> Path | None:
        if value is not None:
            remember(value, option)
            if not value.is_dir():
                _no_clash(value, option, output=False)
        return value

    return callback


def input_paths(option: str) -> Callable[[str | None], str | None]:
    """Callback of a comma-separated list of input files (``--data a.csv,b.csv``)."""

    def callback(value: str | None) -> str | None:
        if value is not None and not any(part.strip() for part in value.split(",")):
            raise ConfigError(f"names no file ({value!r})", where=option,
                              fix="name a file, or several separated by commas")  # fmt: skip
        for part in (value or "").split(","):
            if part.strip() and part.strip() != "default":
                remember(part.strip(), option)
                _no_clash(Path(part.strip()), option, output=False)
        return value

    return callback


def output_file(option: str) -> PathCallback:
    """Callback of an output file option: refuse a folder, a file as parent, an unwritable
    folder, now rather than after the work."""
    return _output(option, folder=False)


def output_dir(option: str) -> PathCallback:
    """Callback of an output folder option (created when missing)."""
    return _output(option, folder=True)


def _output(option: str, *, folder: bool) -> PathCallback:
    def callback(value: Path | None) -> Path | None:
        if value is not None:
            remember(value, option)
            check_output(value, option, folder=folder)
            if not folder:
                _no_clash(value, option, output=True)
        return value

    return callback


def check_output(path: Path, option: str, *, folder: bool) -> None:
    """Refuse an output path that cannot be written, naming it and ``option``."""
    if path.exists():
        if folder and not path.is_dir():
            raise ConfigError("is a file, a folder is expected", source=path, where=option,
                              fix="name a folder (it is created when missing)")  # fmt: skip
        if not folder and path.is_dir():
            raise ConfigError("is a folder, a file is expected", source=path, where=option,
                              fix=f"name a file inside it, e.g. {path / 'out'}{path.suffix}")  # fmt: skip
    parent = Path(os.path.abspath(path)).parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"{parent} is a file, not a folder", source=path, where=option,
                          fix="choose a path whose parents are folders")  # fmt: skip
    target = path if folder and path.is_dir() else parent
    if not os.access(target, os.W_OK | os.X_OK):
        why = "read-only file system" if _read_only(target) else "permission denied"
        raise ConfigError(f"cannot write in {target} ({why})", source=path, where=option,
                          fix="choose a folder you can write to")  # fmt: skip


def _read_only(folder: Path) -> bool:
    return bool(os.statvfs(folder).f_flag & os.ST_RDONLY)


def physics_paths(option: str) -> Callable[[str | None], str | None]:
    """Callback of ``--mechanistic``: its files (``config:FILE`` or simulator files) are
    inputs like the data's; a preset names none."""
    files = input_paths(option)

    def callback(value: str | None) -> str | None:
        from drafttwin.models.mechanistic.source import parse_source

        if value is not None:
            files(",".join(str(p) for p in parse_source(value, where=option).paths) or None)
        return value

    return callback
