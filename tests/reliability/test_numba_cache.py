"""numba's cache=True raises at import where no cache folder is writable; the package then
caches the kernels in a private temporary folder (a system-wide install run by a service
account with a read-only home)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from drafttwin import _numba_cache


@pytest.fixture
def no_cache_dir(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    import numba.core.config

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setattr(numba.core.config, "CACHE_DIR", numba.core.config.CACHE_DIR)
    monkeypatch.setattr(_numba_cache.tempfile, "tempdir", str(tmp_path))
    return tmp_path


def test_numbas_own_places_stand_where_writable(no_cache_dir: Path) -> None:
    assert _numba_cache.ensure_numba_cache(writable=lambda _: True) is None
    assert "NUMBA_CACHE_DIR" not in os.environ
    user = no_cache_dir / "user"
    # The package's folder read-only, the user's cache writable: numba's user-wide choice.
    assert (
        _numba_cache.ensure_numba_cache(writable=lambda p: p == user, user_cache=lambda: user)
        is None
    )
    assert "NUMBA_CACHE_DIR" not in os.environ


def test_no_writable_place_gives_a_private_temporary_folder(no_cache_dir: Path) -> None:
    folder = _numba_cache.ensure_numba_cache(writable=lambda _: False, user_cache=lambda: Path("/"))
    assert folder is not None and folder.parent == no_cache_dir
    assert os.environ["NUMBA_CACHE_DIR"] == str(folder)
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    import numba.core.config

    assert str(folder) == numba.core.config.CACHE_DIR  # numba had read the variable already


def test_a_folder_others_can_write_is_never_used(no_cache_dir: Path) -> None:
    shared = no_cache_dir / f"drafttwin-numba-{os.getuid()}"
    shared.mkdir()
    shared.chmod(0o777)
    folder = _numba_cache.ensure_numba_cache(writable=lambda _: False, user_cache=lambda: Path("/"))
    assert folder is not None and folder != shared and folder.name.startswith("drafttwin-numba-")


def test_the_users_setting_wins(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NUMBA_CACHE_DIR", "/somewhere")
    assert _numba_cache.ensure_numba_cache(writable=lambda _: False) is None
    assert os.environ["NUMBA_CACHE_DIR"] == "/somewhere"
