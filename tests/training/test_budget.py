"""The wall-clock budget of ``solaris-train all`` (``training.budget``; ``training.cli.budget_settings`` with the
``all`` block: tests/training/test_stage_config.py)."""

import json
import time

import pytest

from training.budget import CLOCK_FILE, RunClock, elastic_deadline


def test_elastic_deadline_is_the_budget_left_after_the_reserve():
    assert elastic_deadline(1000.0, budget_s=600.0, spent_s=100.0, reserve_s=50.0) == 1450.0
    assert elastic_deadline(1000.0, budget_s=60.0, spent_s=100.0, reserve_s=0.0) == 960.0  # already past: <= now


@pytest.mark.parametrize("field", ["budget_s", "spent_s", "reserve_s"])
def test_elastic_deadline_rejects_negative_or_nan(field):
    kw = {"budget_s": 10.0, "spent_s": 1.0, "reserve_s": 1.0}
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match=field):
            elastic_deadline(0.0, **{**kw, field: bad})


def test_run_clock_accumulates_across_invocations(tmp_path):
    first = RunClock(tmp_path).start()
    time.sleep(0.05)
    first.record("collect_s", 0.05)
    first.stop()
    spent = json.loads((tmp_path / CLOCK_FILE).read_text())["spent_s"]
    assert spent >= 0.05
    second = RunClock(tmp_path)  # a resumed `all`: counts from where the first stopped
    assert second.spent() >= spent
    assert second.data["stages"] == {"collect_s": 0.05}
    time.sleep(0.05)
    second.save()
    assert json.loads((tmp_path / CLOCK_FILE).read_text())["spent_s"] >= spent + 0.05
    assert not list(tmp_path.glob("*.tmp"))  # atomic writes leave no partial file


def test_run_clock_saves_in_the_background(tmp_path):
    clock = RunClock(tmp_path, save_every_s=0.02).start()
    time.sleep(0.2)
    on_disk = json.loads((tmp_path / CLOCK_FILE).read_text())["spent_s"]  # written by the thread, not by stop()
    clock.stop()
    assert on_disk > 0


def _timed_loop(tmp_path, step_s: float, deadline_in_s: float, steps: int = 100) -> tuple[int, float, float]:
    """``train.run_loop`` over a stand-in step that takes ``step_s``: (steps run, deadline, when it returned)."""
    import jax.numpy as jnp
    import numpy as np

    from training.train import LoopSpec, run_loop

    ran = []

    def step_fn(state, batch):
        time.sleep(step_s)
        ran.append(1)
        return state, {"loss": jnp.float32(0.0)}

    deadline = time.time() + deadline_in_s
    spec = LoopSpec("mp-causal", steps, log_every=1, ckpt_every=0, sample_every=0, tokens_per_step=1, lr=1e-3,
                    deadline=deadline)
    run_loop(spec, tmp_path, {"w": jnp.zeros(2)}, step_fn, lambda: {"x": np.zeros((1, 1))}, sampler=None,
             resume=False)
    return len(ran), deadline, time.time()


def test_run_loop_stops_before_a_step_that_would_end_past_its_deadline(tmp_path):
    """Steps of 0.3 s and a deadline 1.15 s away: after step 3 (at ~0.9 s) the next would end at ~1.2 s, so the
    loop stops there, before its deadline (the rule 'stop after the step that ends past it' ran a fourth, to
    ~1.2 s)."""
    n, deadline, returned = _timed_loop(tmp_path, 0.3, 1.15)
    assert 2 <= n <= 3 and returned <= deadline, (n, returned - deadline)


def test_run_loop_runs_one_step_when_its_deadline_has_passed(tmp_path):
    n, _, _ = _timed_loop(tmp_path / "late", 0.05, -1.0)
    assert n == 1


def test_run_loop_counts_a_slow_hook_before_starting_another_step(tmp_path):
    """Steps of 0.5 s, a 1.5 s hook after step 2 (a sprint's export) and a deadline 2.9 s away: the hook ends at
    ~2.5 s, and a third step would end at ~3 s, so the loop stops after the hook (judged before the hook, the
    third step looked safe and ended past the deadline)."""
    import jax.numpy as jnp
    import numpy as np

    from training.train import LoopSpec, run_loop

    ran = []

    def step_fn(state, batch):
        time.sleep(0.5)
        ran.append(1)
        return state, {"loss": jnp.float32(0.0)}

    def on_step(state, step):
        if step == 2:
            time.sleep(1.5)

    deadline = time.time() + 2.9
    spec = LoopSpec("mp-causal", 100, log_every=5, ckpt_every=0, sample_every=0, tokens_per_step=1, lr=1e-3,
                    deadline=deadline)
    run_loop(spec, tmp_path, {"w": jnp.zeros(2)}, step_fn, lambda: {"x": np.zeros((1, 1))}, sampler=None,
             resume=False, on_step=on_step)
    returned = time.time()
    logged = [json.loads(line)["step"] for line in (tmp_path / "mp-causal" / "metrics.jsonl").read_text().splitlines()]
    assert len(ran) == 2 and returned <= deadline, (len(ran), returned - deadline)
    assert logged == [2]  # the last step is logged though log_every is 5
