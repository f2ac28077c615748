"""Training metrics: a JSON-lines log that resumes without duplicates, and a progress bar.

    log = MetricsLogger(stage_dir / "metrics.jsonl", resume_step=restored_step)   # 0 / None: fresh
    bar = log.progress(total=num_steps, initial=restored_step, desc="mp-causal")
    ...
    log.log(step, stage="mp-causal", loss=0.41, grad_norm=1.3, lr=1e-4, steps_per_s=2.1, tokens_per_s=7e3)
    bar.set_postfix(loss="0.4100", steps_s="2.10"); bar.update(1)
    ...
    bar.close(); log.close()

One line per :meth:`MetricsLogger.log` call, ``{"step": int, "time": unix seconds, **fields}``, flushed
at once (a ``kill -9`` loses at most the line being written). A run resumed from checkpoint step ``s``
first drops every line with ``step > s`` (and any torn last line), rewriting the file atomically
(temporary file + ``os.replace``), so steps it redoes are not logged twice.
"""

from __future__ import annotations

import json
import os
import secrets
import sys
import time
from pathlib import Path
from typing import Any, Self, TextIO

from tqdm.auto import tqdm


def _plain(value: Any) -> Any:
    """Python scalars for JSON: numpy / JAX 0-d values -> int / float / bool; other values unchanged."""
    if isinstance(value, (bool, int, float, str)) or value is None:
        return value
    if hasattr(value, "item") and getattr(value, "ndim", 0) == 0:  # numpy / jax scalar
        return value.item()
    return value


def read_metrics(path: str | Path) -> list[dict]:
    """The records of a metrics file in order; a torn (unparsable) line is skipped."""
    path = Path(path)
    if not path.is_file():
        return []
    records = []
    for line in path.read_text(encoding="utf-8").splitlines():
        record = _parse(line)
        if record is not None:
            records.append(record)
    return records


def _parse(line: str) -> dict | None:
    try:
        record = json.loads(line)
    except json.JSONDecodeError:
        return None
    if not isinstance(record, dict) or not isinstance(record.get("step"), int):
        return None
    return record


def truncate_after(path: str | Path, step: int) -> int:
    """Drop the lines of ``path`` whose step is > ``step`` (and torn lines); atomic. Returns lines kept."""
    path = Path(path)
    if not path.is_file():
        return 0
    kept = [line for line in path.read_text(encoding="utf-8").splitlines()
            if (record := _parse(line)) is not None and record["step"] <= step]
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write("".join(line + "\n" for line in kept))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return len(kept)


class MetricsLogger:
    """Appends one JSON object per logged step to ``path``.

    Args:
        path: the ``.jsonl`` file (its directory is created).
        resume_step: the step training restarts from (the restored checkpoint's step, 0 for a fresh
            start): lines with a larger step are dropped first. None keeps the file as it is.
    """

    def __init__(self, path: str | Path, resume_step: int | None = None) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if resume_step is not None:
            if int(resume_step) < 0:
                raise ValueError(f"resume_step must be >= 0 or None, got {resume_step}")
            truncate_after(self.path, int(resume_step))
        self._file: TextIO | None = open(self.path, "a", encoding="utf-8")  # noqa: SIM115 - kept open, closed by close()

    def log(self, step: int, **fields: Any) -> dict:
        """Write ``{"step", "time", **fields}`` as one line and flush. Returns the record."""
        if self._file is None:
            raise ValueError(f"MetricsLogger({self.path}) is closed")
        if "step" in fields or "time" in fields:
            raise ValueError("fields must not contain 'step' or 'time' (the logger sets them)")
        record = {"step": int(step), "time": time.time(), **{k: _plain(v) for k, v in fields.items()}}
        try:
            line = json.dumps(record)  # NaN / inf are written as Python's json reads them back
        except TypeError as err:
            bad = [k for k, v in record.items() if not isinstance(v, (bool, int, float, str, type(None), list, dict))]
            raise ValueError(f"metric fields {bad} are not JSON scalars: {err}") from None
        self._file.write(line + "\n")
        self._file.flush()
        return record

    def progress(self, total: int, initial: int = 0, desc: str | None = None, file: TextIO | None = None,
                 disable: bool | None = None) -> tqdm:
        """A tqdm bar over steps (``step/s`` rate; add loss with ``set_postfix``). It shows nothing when
        ``file`` (default stderr) is not a TTY, unless ``disable=False``."""
        file = sys.stderr if file is None else file
        if disable is None:
            disable = not (hasattr(file, "isatty") and file.isatty())
        return tqdm(total=total, initial=initial, desc=desc, unit="step", file=file, disable=disable,
                    dynamic_ncols=True, smoothing=0.1)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
