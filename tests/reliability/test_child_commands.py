"""Child commands die with the command that started them (``die_with_parent``): a live
benchmark killed outright leaves no twin, replay or broker running."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from drafttwin.execution.interrupt import die_with_parent

PARENT = """
import subprocess, sys, time
from drafttwin.execution.interrupt import die_with_parent
child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"],
                         preexec_fn=die_with_parent() if sys.argv[1] == "yes" else None)
print(child.pid, flush=True)
time.sleep(60)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:  # a zombie has ended
        return f.read().split()[2] != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
@pytest.mark.parametrize("tied", ["yes", "no"])
def test_a_child_command_ends_when_its_parent_is_killed(tied: str) -> None:
    parent = subprocess.Popen([sys.executable, "-c", PARENT, tied], stdout=subprocess.PIPE,
                              text=True)  # fmt: skip
    assert parent.stdout is not None
    child = int(parent.stdout.readline())
    try:
        parent.send_signal(signal.SIGKILL)
        parent.wait(10)
        deadline = time.monotonic() + 5.0
        while _alive(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _alive(child) is (tied == "no")  # without it the child is left behind
    finally:
        if _alive(child):
            os.kill(child, signal.SIGKILL)


def test_elsewhere_it_is_nothing_and_here_a_callable() -> None:
    fn = die_with_parent()
    assert (fn is None) is (not sys.platform.startswith("linux"))
