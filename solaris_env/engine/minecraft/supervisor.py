"""Process supervision for the Minecraft backend: Xvfb, the server and the recorder, never orphaned.

Every child is started in its own process group (``start_new_session``) with ``PR_SET_PDEATHSIG =
SIGKILL`` (Linux: the kernel kills it if this process dies, even by SIGKILL) and with a pipe on its
stdin (the Node scripts exit when it closes). :class:`Supervisor` is a context manager: leaving it
(normally, by an exception, or by Ctrl-C's KeyboardInterrupt) sends SIGTERM to each child's whole
process group, then SIGKILL after a grace period. Open supervisors are also closed by an ``atexit``
hook and, while one is open, SIGTERM is turned into ``SystemExit`` so that those hooks run.
"""

from __future__ import annotations

import atexit
import ctypes
import os
import queue
import select
import signal
import subprocess
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Self

STOP_GRACE_S = 3.0  # SIGTERM -> SIGKILL
STDERR_TAIL_LINES = 40
_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:  # runs in the child between fork and exec
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except OSError:
        pass


class ProcessError(RuntimeError):
    """A supervised process failed to start, exited early, or did not get ready in time."""


@dataclass
class Child:
    """One supervised process (its pid is also its process-group id)."""

    name: str
    popen: subprocess.Popen
    stderr_tail: deque = field(default_factory=lambda: deque(maxlen=STDERR_TAIL_LINES))
    stdout_lines: queue.Queue = field(default_factory=queue.Queue)  # None = stdout closed

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def tail(self) -> str:
        return "\n".join(self.stderr_tail)


_OPEN: weakref.WeakSet[Supervisor] = weakref.WeakSet()
_SIGTERM_INSTALLED = False


def _close_all_open() -> None:
    for sup in list(_OPEN):
        sup.close()


def _on_sigterm(signum, frame) -> None:
    raise SystemExit(128 + signum)


def _install_handlers() -> None:
    global _SIGTERM_INSTALLED
    if _SIGTERM_INSTALLED:
        return
    atexit.register(_close_all_open)
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _on_sigterm)
    _SIGTERM_INSTALLED = True


class Supervisor:
    """Starts processes and guarantees they (and their children) are gone when it closes."""

    def __init__(self):
        self.children: list[Child] = []
        self.closed = False
        _install_handlers()
        _OPEN.add(self)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self, name: str, argv: list[str], env: dict | None = None, cwd: str | None = None,
              pass_fds: tuple[int, ...] = ()) -> Child:
        """Start ``argv`` in a new process group; stdout is a pipe (read it with :meth:`read_line`),
        stderr is kept (last lines) for error messages."""
        if self.closed:
            raise ProcessError("supervisor is closed")
        try:
            popen = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     env=env, cwd=cwd, start_new_session=True,
                                     preexec_fn=_die_with_parent,  # noqa: PLW1509 - prctl must run in the child
                                     pass_fds=pass_fds, text=True, bufsize=1)
        except FileNotFoundError as e:
            raise ProcessError(f"{name}: cannot start {argv[0]!r} ({e.strerror}); is it installed?") from None
        child = Child(name, popen)
        self.children.append(child)
        threading.Thread(target=self._drain_stderr, args=(child,), daemon=True).start()
        threading.Thread(target=self._drain_stdout, args=(child,), daemon=True).start()
        return child

    @staticmethod
    def _drain_stderr(child: Child) -> None:
        for line in child.popen.stderr:
            child.stderr_tail.append(line.rstrip("\n"))

    @staticmethod
    def _drain_stdout(child: Child) -> None:
        try:
            for line in child.popen.stdout:
                child.stdout_lines.put(line.strip())
        except (OSError, ValueError):
            pass
        child.stdout_lines.put(None)

    def read_line(self, child: Child, timeout_s: float, predicate: Callable[[str], bool] = lambda s: True) -> str:
        """The first stdout line of ``child`` satisfying ``predicate``; ProcessError on exit or timeout."""
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise ProcessError(f"{child.name}: no ready line within {timeout_s:.0f} s; stderr:\n{child.tail()}")
            try:
                line = child.stdout_lines.get(timeout=min(left, 0.5))
            except queue.Empty:
                continue
            if line is None:  # stdout closed: the process exited
                child.popen.wait(timeout=STOP_GRACE_S)
                time.sleep(0.1)  # let the stderr thread catch up
                raise ProcessError(f"{child.name} exited with status {child.popen.returncode}; stderr:\n{child.tail()}")
            if predicate(line):
                return line

    def wait(self, child: Child, timeout_s: float) -> int:
        """Wait for ``child`` to exit; ProcessError (after stopping it) if it takes longer than ``timeout_s``."""
        try:
            return child.popen.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.stop(child)
            raise ProcessError(f"{child.name}: still running after {timeout_s:.0f} s (stopped); "
                               f"stderr:\n{child.tail()}") from None

    def stop(self, child: Child, grace_s: float = STOP_GRACE_S) -> None:
        """SIGTERM the child's process group, SIGKILL it after ``grace_s``; reaps the child."""
        for sig, wait_s in ((signal.SIGTERM, grace_s), (signal.SIGKILL, grace_s)):
            try:
                os.killpg(child.pid, sig)
            except ProcessLookupError:
                break
            deadline = time.monotonic() + wait_s
            while time.monotonic() < deadline and _group_alive(child.pid):
                child.popen.poll()
                time.sleep(0.02)
            if not _group_alive(child.pid):
                break
        try:
            child.popen.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            pass
        for f in (child.popen.stdin,):
            try:
                if f is not None:
                    f.close()
            except OSError:
                pass

    def close(self) -> None:
        """Stop every child (last started first). Idempotent."""
        if self.closed:
            return
        self.closed = True
        for child in reversed(self.children):
            self.stop(child)
        _OPEN.discard(self)


def _group_alive(pgid: int) -> bool:
    """True while any process of the group exists (zombies of already-reaped children excluded)."""
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # killpg(0) also succeeds for zombies; check the members' states.
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[2]) == pgid and fields[0] != "Z":
            return True
    return False


# ---------------------------------------------------------------------------------------------
# The backend's processes
# ---------------------------------------------------------------------------------------------

XVFB_SCREEN = "64x64x24"  # headless-gl draws into its own framebuffer; the screen only has to exist


def start_xvfb(sup: Supervisor, timeout_s: float = 20.0) -> tuple[Child, str]:
    """Start Xvfb on a free display (``-displayfd``); returns (child, ':N')."""
    r, w = os.pipe()
    try:
        child = sup.start("Xvfb", ["Xvfb", "-displayfd", str(w), "-screen", "0", XVFB_SCREEN, "-nolisten", "tcp"],
                        pass_fds=(w,))
    finally:
        os.close(w)
    try:
        deadline = time.monotonic() + timeout_s
        buf = b""
        while not buf.endswith(b"\n"):
            left = deadline - time.monotonic()
            ready, _, _ = select.select([r], [], [], max(0.0, min(left, 0.5)))
            if ready:
                chunk = os.read(r, 64)
                if not chunk:
                    break
                buf += chunk
            elif left <= 0 or not child.alive():
                break
    finally:
        os.close(r)
    if not buf.strip().isdigit():
        raise ProcessError(f"Xvfb did not report a display within {timeout_s:.0f} s; stderr:\n{child.tail()}")
    return child, f":{int(buf)}"
