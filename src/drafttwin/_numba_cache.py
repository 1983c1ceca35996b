"""Where numba keeps the compiled kernels.

The kernels are compiled with ``cache=True``, and numba raises at import (a traceback before
any command runs) where it finds no writable place for them: neither the package's own
``__pycache__`` (a system-wide install) nor the user's cache folder (a service account with a
read-only home). There the kernels are cached in a private folder of the temporary directory
instead; ``NUMBA_CACHE_DIR``, where set, always wins."""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def _writable(folder: Path) -> bool:
    """numba's own test of a cache folder: it can be made and a file written in it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


def _user_cache_folder() -> Path:
    from numba.misc.appdirs import AppDirs  # only where the package's folder is read-only

    return Path(AppDirs(appname="numba", appauthor=False).user_cache_dir)  # type: ignore[no-untyped-call]


def _private_temp_folder() -> Path:
    """A folder of the temporary directory only this user can write: numba's index files are
    pickles, so a folder another user could have made first is never used."""
    uid = os.getuid() if hasattr(os, "getuid") else 0
    folder = Path(tempfile.gettempdir()) / f"drafttwin-numba-{uid}"
    try:
        folder.mkdir(mode=0o700, exist_ok=True)
        info = folder.lstat()
        if folder.is_symlink() or info.st_uid != uid or info.st_mode & 0o022:
            raise PermissionError(folder)
    except OSError:
        return Path(tempfile.mkdtemp(prefix="drafttwin-numba-"))
    return folder


def ensure_numba_cache(
    package: Path = _PACKAGE,
    writable: Callable[[Path], bool] = _writable,
    user_cache: Callable[[], Path] = _user_cache_folder,
) -> Path | None:
    """Point numba at a private temporary folder where neither of its own places is writable;
    return that folder, or None where numba's own choice stands."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    if writable(package / "mechanics" / "__pycache__") or writable(user_cache()):
        return None
    folder = _private_temp_folder()
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    if "numba.core.config" in sys.modules:  # numba read the variable already
        sys.modules["numba.core.config"].CACHE_DIR = str(folder)  # type: ignore[attr-defined]
    return folder
