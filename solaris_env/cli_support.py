"""What the command-line tools (``solaris-engine``, ``solaris-env``, ``solaris-train``) share: a clean exit on
Ctrl-C, one-line errors, and argument types that refuse nonsense.

Ctrl-C (``interrupts_exit_cleanly``). The first SIGINT raises ``KeyboardInterrupt`` in the main thread as usual,
so ``finally`` blocks and context managers close what they hold (worker pools, the Minecraft backend's processes);
the tool then prints one line (``<prog>: interrupted``), flushes and leaves with ``os._exit(130)`` -- without the
interpreter's teardown, which could race XLA's compiler threads and crash ("Fatal Python error: Segmentation
fault", seen when Ctrl-C hit a JAX compile). While the main thread sits in a long native call (an XLA compile does
not return to Python for tens of seconds) the interrupt cannot be raised there: a watcher thread woken by the
signal (``signal.set_wakeup_fd``) then ends the process the same way after ``INTERRUPT_GRACE_S`` seconds, or at
once on a second Ctrl-C, killing this process's ``multiprocessing`` children first. A Ctrl-C that lands where
Python cannot raise it (a garbage-collector callback, a ``__del__``: "Exception ignored in ...") ends the process
the same way at once (``sys.unraisablehook``). Output files are written
atomically (staging directories, temporary names), so an interrupted run leaves no half file behind and a re-run
resumes.

Errors (``run_command``): an exception from a command prints ``<prog>: error: <Type>: <message>`` on one line and
exits with status 1; ``--debug`` shows the traceback instead.
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

INTERRUPT_EXIT_STATUS = 130  # 128 + SIGINT, what shells report for a Ctrl-C'd program
INTERRUPT_GRACE_S = 5.0  # after Ctrl-C, how long the main thread gets to reach Python and clean up

_exit_lock = threading.Lock()


def _write_stderr(text: str) -> None:
    """Best effort, without Python's buffered stream locks (another thread may hold them)."""
    try:
        os.write(2, text.encode())
    except OSError:
        pass


def exit_interrupted(prog: str) -> None:
    """Print ``<prog>: interrupted`` on its own line, flush, stop this process's worker processes and leave with
    status 130 at once (no interpreter teardown). Safe from any thread; the first caller wins."""
    if not _exit_lock.acquire(blocking=False):
        threading.Event().wait()  # another thread is exiting the process
    in_main = threading.current_thread() is threading.main_thread()
    if in_main:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    with contextlib.suppress(Exception):
        for child in multiprocessing.active_children():
            child.kill()
    if in_main:  # multiprocessing's own exit hook: joins the killed workers, releases the pools' semaphores
        with contextlib.suppress(Exception):  # (else its resource tracker warns about "leaked semaphores")
            from multiprocessing import util

            util._exit_function()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    _write_stderr(f"\n{prog}: interrupted\n")
    os._exit(INTERRUPT_EXIT_STATUS)


@contextlib.contextmanager
def interrupts_exit_cleanly(prog: str, grace_s: float = INTERRUPT_GRACE_S) -> Iterator[None]:
    """Inside: Ctrl-C ends the process with one line and status 130 (see the module docstring). Outside, the
    signal handling is what it was (so calling a CLI's ``main`` from Python, e.g. in tests, leaves no trace).
    Needs the main thread; elsewhere (or with SIGINT ignored, e.g. a background job) it changes nothing."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        yield
        return
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    done = threading.Event()
    previous_handler = signal.signal(signal.SIGINT, signal.default_int_handler)
    previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)

    def watch() -> None:
        interrupted = False
        while True:
            try:
                data = os.read(read_fd, 64)  # one byte per caught signal: its number
            except OSError:
                return
            if not data or done.is_set():
                return
            if signal.SIGINT in data:
                if interrupted:  # a second Ctrl-C: stop at once
                    exit_interrupted(prog)
                interrupted = True
                threading.Thread(target=force_after_grace, daemon=True).start()

    def force_after_grace() -> None:
        if not done.wait(grace_s):
            exit_interrupted(prog)

    def unraisable(info) -> None:  # Ctrl-C landed where Python cannot raise it (a gc callback, a __del__)
        if isinstance(info.exc_value, KeyboardInterrupt):
            exit_interrupted(prog)
        previous_hook(info)

    previous_hook = sys.unraisablehook
    sys.unraisablehook = unraisable
    watcher = threading.Thread(target=watch, name="interrupt-watcher", daemon=True)
    watcher.start()
    try:
        yield
    except KeyboardInterrupt:
        exit_interrupted(prog)
    finally:
        sys.unraisablehook = previous_hook
        done.set()
        signal.set_wakeup_fd(previous_fd)
        signal.signal(signal.SIGINT, previous_handler)
        os.close(write_fd)  # the watcher reads EOF and returns
        watcher.join(timeout=1.0)
        os.close(read_fd)


def one_line(err: BaseException) -> str:
    """``Type: message`` on one line."""
    message = " ".join(str(err).split())
    return f"{type(err).__name__}: {message}" if message else type(err).__name__


def run_command(prog: str, command: Callable[[Any], int], args: Any, debug: bool = False) -> int:
    """Run ``command(args)`` with Ctrl-C handled (``interrupts_exit_cleanly``); an exception becomes one line
    ``<prog>: error: ...`` and status 1 (``SystemExit``), or, with ``debug``, propagates with its traceback."""
    with interrupts_exit_cleanly(prog):
        try:
            return command(args)
        except (SystemExit, KeyboardInterrupt):
            raise
        except Exception as err:  # a CLI's errors are reported in one line
            if debug:
                raise
            raise SystemExit(f"{prog}: error: {one_line(err)} (--debug shows the traceback)") from err


def add_debug_flag(parser: argparse.ArgumentParser, top: bool = False) -> None:
    """``--debug``: show a failing command's traceback. ``top``: the main parser (default False); subparsers
    leave the value alone unless given, so ``prog --debug cmd`` and ``prog cmd --debug`` both work."""
    parser.add_argument("--debug", action="store_true", default=False if top else argparse.SUPPRESS,
                        help="on an error, show the traceback instead of one line")


def positive_int(text: str) -> int:
    """argparse type: an int >= 1 (``--episodes -3`` is refused, not a run of nothing)."""
    return _int_at_least(text, 1)


def non_negative_int(text: str) -> int:
    """argparse type: an int >= 0."""
    return _int_at_least(text, 0)


def _int_at_least(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {value}")
    return value


def check_output_file(path: Any, suffix: str, flag: str) -> Path:
    """An output file the command will write: it must end in ``suffix``, must not be a directory, and its
    folder must be creatable and writable. Raises ValueError naming ``flag`` (checked before any slow work)."""
    path = Path(path)
    if path.suffix.lower() != suffix:
        raise ValueError(f"{flag}: expected a file name ending in {suffix}, got {str(path)!r}")
    if path.is_dir():
        raise ValueError(f"{flag}: {str(path)!r} is a directory; give a file name ending in {suffix}")
    parent = path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{flag}: cannot create {str(path)!r}: {str(parent)!r} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{flag}: cannot write {str(path)!r}: {str(parent)!r} is not writable")
    return path
