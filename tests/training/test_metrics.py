"""training/metrics.py: the JSON-lines metrics log (append, flush, resume without duplicates) and the bar."""

from __future__ import annotations

import io
import json
import math
import time

import numpy as np
import pytest

from training.metrics import MetricsLogger, read_metrics, truncate_after


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def _log_steps(path, steps, **kw):
    with MetricsLogger(path, **kw) as log:
        for step in steps:
            log.log(step, stage="mp-causal", loss=1.0 / step, grad_norm=np.float32(0.5), lr=1e-4,
                    steps_per_s=2.0, tokens_per_s=7040.0)


def test_lines_are_written_and_flushed_at_once(tmp_path):
    path = tmp_path / "stage" / "metrics.jsonl"  # the directory is created
    log = MetricsLogger(path)
    record = log.log(10, stage="sp", loss=np.float32(0.25), grad_norm=1.5, lr=1e-4, steps_per_s=3.0)
    # readable before close: flushed per line
    lines = path.read_text().splitlines()
    assert len(lines) == 1 and json.loads(lines[0]) == record
    assert record["step"] == 10 and record["stage"] == "sp" and record["loss"] == 0.25
    assert isinstance(record["loss"], float) and abs(record["time"] - time.time()) < 60
    log.log(20, loss=float("nan"))
    assert math.isnan(read_metrics(path)[-1]["loss"])
    with pytest.raises(ValueError, match="'step' or 'time'"):
        log.log(30, time=3.0)
    with pytest.raises(ValueError, match=r"\['loss'\] are not JSON scalars"):
        log.log(30, loss=object())
    log.close()
    with pytest.raises(ValueError, match="closed"):
        log.log(40, loss=1.0)


def test_resume_drops_lines_after_the_restored_step(tmp_path):
    path = tmp_path / "metrics.jsonl"
    _log_steps(path, [10, 20, 30, 40, 50])
    with open(path, "a") as f:  # a line torn by kill -9
        f.write('{"step": 60, "loss": 0.0')
    _log_steps(path, [40, 50], resume_step=30)  # restored from the step-30 checkpoint, redoes 40 and 50
    assert [r["step"] for r in read_metrics(path)] == [10, 20, 30, 40, 50]
    assert all(line.startswith("{") and line.endswith("}") for line in path.read_text().splitlines())
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.jsonl"]  # no temporary file left behind
    # resume_step=0: a fresh start over an old log; None: append as is
    _log_steps(path, [10], resume_step=0)
    assert [r["step"] for r in read_metrics(path)] == [10]
    _log_steps(path, [20])
    assert [r["step"] for r in read_metrics(path)] == [10, 20]
    with pytest.raises(ValueError, match="resume_step"):
        MetricsLogger(path, resume_step=-1)


def test_truncate_after_is_atomic_and_keeps_lines_verbatim(tmp_path):
    path = tmp_path / "m.jsonl"
    _log_steps(path, [1, 2, 3])
    before = path.read_text().splitlines()
    assert truncate_after(path, 2) == 2
    assert path.read_text().splitlines() == before[:2]
    assert truncate_after(tmp_path / "absent.jsonl", 5) == 0
    assert read_metrics(tmp_path / "absent.jsonl") == []


def test_progress_bar_shows_step_loss_and_rate_on_a_tty(tmp_path):
    tty = _Tty()
    with MetricsLogger(tmp_path / "m.jsonl") as log:
        bar = log.progress(total=10, initial=3, desc="mp-causal", file=tty)
        bar.update(1)
        bar.set_postfix(loss="0.4100", steps_s="2.10")
        bar.refresh()
        bar.close()
    out = tty.getvalue()
    assert "mp-causal" in out and "4/10" in out and "loss=0.4100" in out and "steps_s=2.10" in out
    assert "step/s" in out or "s/step" in out


def test_progress_bar_is_silent_when_not_a_tty(tmp_path):
    plain = io.StringIO()
    with MetricsLogger(tmp_path / "m.jsonl") as log:
        bar = log.progress(total=10, file=plain)
        assert bar.disable
        bar.update(5)
        bar.set_postfix(loss="1.0")
        bar.close()
    assert plain.getvalue() == ""
