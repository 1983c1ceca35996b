"""A hall's private Ray starts its workers at the caller's priority: at Ray's default
niceness of 15 the shards yielded to every other process and fell seconds behind a `twin run`
at 0 on a busy machine."""

from __future__ import annotations

import os
from typing import Any

import pytest

from drafttwin.execution import executor


class _FakeRay:
    def __init__(self) -> None:
        self.seen: str | None = None

    def is_initialized(self) -> bool:
        return False

    def init(self, **kwargs: Any) -> None:
        self.seen = os.environ.get("RAY_worker_niceness")  # noqa: SIM112  (Ray's own name)

    def shutdown(self) -> None:
        pass


@pytest.mark.parametrize(("foreground", "address", "niceness"),
                         [(True, None, "0"), (False, None, None), (True, "10.0.0.1:6379", None)])  # fmt: skip
def test_the_hall_s_private_ray_runs_its_workers_at_the_caller_s_priority(
    monkeypatch: pytest.MonkeyPatch, foreground: bool, address: str | None, niceness: str | None
) -> None:
    fake = _FakeRay()
    monkeypatch.setenv("RAY_worker_niceness", "restored at teardown")  # (then removed here)
    monkeypatch.delenv("RAY_worker_niceness")
    monkeypatch.setattr(executor, "_import_ray", lambda: fake)
    monkeypatch.setattr(executor, "_start_guard", lambda: None)
    with executor.ray_session(1, address, foreground=foreground):
        pass
    assert fake.seen == niceness
