"""The wall-clock budget of ``solaris-train all``: its clock, and the deadline of its one elastic stage.

``all`` must finish within a budget (150 min for the tiny preset on a 2-core CPU), but the same step counts
take 1.3-1.7x longer on one of our machines than on another. Every stage keeps its configured step count
except one, the *elastic* stage (stage 3, where extra minutes pay most): it trains until its configured
steps or until its deadline, whichever comes first,

    deadline = now + budget - spent - reserve

where ``spent`` is the wall time ``all`` has already run in this run directory (across interruptions: the
clock is persisted) and ``reserve`` the minutes kept for the stages after it (Self Forcing). A stage stopped
by its deadline saves its checkpoint and its model as if it had reached its last step; the step it reached is
recorded in ``OUT/all_clock.json``.

The clock counts the time ``all`` runs, not the time between runs: it is saved every ``SAVE_EVERY_S``
seconds and at every stage's end, so an interruption loses at most that much from the account.
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

CLOCK_FILE = "all_clock.json"
SAVE_EVERY_S = 30.0


def elastic_deadline(now: float, budget_s: float, spent_s: float, reserve_s: float) -> float:
    """Epoch time at which the elastic stage must stop: ``now + budget - spent - reserve`` (may be <= now:
    the stage then stops after its first step)."""
    for name, value in (("budget_s", budget_s), ("spent_s", spent_s), ("reserve_s", reserve_s)):
        if not value >= 0:
            raise ValueError(f"{name} must be >= 0, got {value}")
    return now + budget_s - spent_s - reserve_s


def _write_json_atomic(path: Path, obj: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1))
    os.replace(tmp, path)


class RunClock:
    """Wall time spent by ``all`` in a run directory, persisted in ``OUT/all_clock.json``.

    ``spent()`` = the time recorded by earlier invocations + the time since this one started. ``start()``
    runs a daemon thread that saves it every ``save_every_s``; ``record(key, value)`` adds an entry
    (a stage's wall time, the step an elastic stage reached) and saves.
    """

    def __init__(self, out: str | Path, save_every_s: float = SAVE_EVERY_S) -> None:
        self.path = Path(out) / CLOCK_FILE
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.data = json.loads(self.path.read_text()) if self.path.is_file() else {"spent_s": 0.0, "stages": {}}
        self._before = float(self.data["spent_s"])
        self._t0 = time.time()
        self._save_every_s = save_every_s
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def spent(self) -> float:
        return self._before + (time.time() - self._t0)

    def save(self) -> None:
        with self._lock:
            self.data["spent_s"] = self.spent()
            _write_json_atomic(self.path, self.data)

    def record(self, key: str, value) -> None:
        with self._lock:
            self.data["stages"][key] = value
        self.save()

    def start(self) -> RunClock:
        def tick():
            while not self._stop.wait(self._save_every_s):
                self.save()

        self._thread = threading.Thread(target=tick, name="run-clock", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.save()
