"""``engine.minecraft.supervisor``: no orphans on success, failure, Ctrl-C, SIGTERM or SIGKILL of the parent."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from solaris_env.engine.minecraft.supervisor import (
    ProcessError,
    Supervisor,
    _group_alive,
)

REPO = Path(__file__).resolve().parents[4]  # the repository root
# A child that forks a grandchild in its own group and reports both pids.
TREE = ["sh", "-c", "sleep 60 & echo $$ $!; wait"]


def _pids(sup, child):
    return [int(p) for p in sup.read_line(child, 10).split()]


def _gone(pid, timeout=5.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    return True
        except FileNotFoundError:
            return True
        time.sleep(0.05)
    return False


def test_close_kills_the_whole_group():
    with Supervisor() as sup:
        child = sup.start("tree", TREE)
        parent, grandchild = _pids(sup, child)
        assert _group_alive(child.pid)
    assert _gone(parent) and _gone(grandchild)


def test_exception_inside_kills_children():
    with pytest.raises(RuntimeError, match="boom"), Supervisor() as sup:
        child = sup.start("tree", TREE)
        _, grandchild = _pids(sup, child)
        raise RuntimeError("boom")
    assert _gone(grandchild)


def test_early_exit_and_timeout_are_clear_errors():
    with Supervisor() as sup:
        dead = sup.start("dead", ["sh", "-c", "echo oops >&2; exit 3"])
        with pytest.raises(ProcessError, match=r"dead exited with status 3(.|\n)*oops"):
            sup.read_line(dead, 10)
        slow = sup.start("slow", ["sleep", "60"])
        with pytest.raises(ProcessError, match="no ready line within"):
            sup.read_line(slow, 0.3)
        with pytest.raises(ProcessError, match="still running"):
            sup.wait(slow, 0.2)
        assert not slow.alive()
        with pytest.raises(ProcessError, match="cannot start"):
            sup.start("nope", ["/nonexistent/binary"])


# The parent enters the supervisor's context before it reports the pids (no signal can land outside it) and
# restores Python's SIGINT handler: a parent started in the background (nohup, a CI runner) inherits SIGINT
# ignored, and Python then never raises KeyboardInterrupt (the case of a terminal's Ctrl-C is what we test).
SCRIPT = textwrap.dedent("""
    import signal, sys, time
    signal.signal(signal.SIGINT, signal.default_int_handler)
    from solaris_env.engine.minecraft.supervisor import Supervisor
    with Supervisor() as sup:
        child = sup.start("tree", ["sh", "-c", "sleep 60 & echo $$ $!; wait"])
        print(sup.read_line(child, 10), flush=True)
        time.sleep(60)
""")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL])
def test_parent_killed_leaves_no_orphans(sig):
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT], stdout=subprocess.PIPE, text=True,
                            cwd=REPO)
    try:
        parent, grandchild = (int(p) for p in proc.stdout.readline().split())
        proc.send_signal(sig)
        proc.wait(timeout=15)
        assert _gone(parent), f"child {parent} survived {sig.name}"
        if sig != signal.SIGKILL:  # a SIGKILLed parent takes down its child (PDEATHSIG), not the grandchild
            assert _gone(grandchild), f"grandchild {grandchild} survived {sig.name}"
        else:
            os.kill(grandchild, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


def test_status_line_protocol():
    with Supervisor() as sup:
        child = sup.start("talker", ["sh", "-c", "echo noise; echo '{\"event\": \"ready\", \"port\": 5}'; sleep 60"])
        line = sup.read_line(child, 10, lambda s: s.startswith("{"))
        assert json.loads(line)["port"] == 5
