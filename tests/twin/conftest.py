"""Session fixtures of the live-twin tests: one short plant record, one tiny hybrid."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("duckdb", reason="the live twin needs the 'twin' extra")
pytest.importorskip("asyncua", reason="the live twin needs the 'twin' extra")

from ._twin import plant_record, tiny_hybrid  # noqa: E402


@pytest.fixture(scope="session")
def twin_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(plant record of 6 s with a speed change, tiny parallel hybrid fitted on it)."""
    folder = tmp_path_factory.mktemp("twin")
    record = plant_record(folder)
    return record, tiny_hybrid(folder, record)
