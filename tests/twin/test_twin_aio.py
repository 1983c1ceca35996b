"""The twin's event loop ends even when a library leaves a task that ignores cancellation."""

from __future__ import annotations

import asyncio
import time

import pytest

from drafttwin.twin.aio import run_bounded


async def _stubborn() -> None:
    while True:  # what asyncio.run would wait for forever
        try:
            await asyncio.sleep(10.0)
        except asyncio.CancelledError:
            continue


async def _main() -> int:
    asyncio.get_running_loop().create_task(_stubborn())
    await asyncio.sleep(0)
    return 7


def test_a_task_that_ignores_cancellation_is_abandoned_after_the_grace() -> None:
    start = time.monotonic()
    assert run_bounded(_main(), grace_s=0.3) == 7
    assert time.monotonic() - start < 5.0


def test_the_result_and_errors_of_the_coroutine_come_through() -> None:
    async def fail() -> None:
        raise ValueError("boom")

    assert run_bounded(asyncio.sleep(0, result="done")) == "done"
    with pytest.raises(ValueError, match="boom"):
        run_bounded(fail())
