"""Flat memory: 1000-step rollouts whose resident memory does not grow after warm-up.

A leak of one step's frames would add 2 players x 4 frames x 32 x 32 x 3 B = 24 KB per dream step, i.e. 24 MB
over 1000 steps (and one 36x36 frame per player per real step, 7.6 MB); the bound is well below the former
and leaves room for allocator noise.
"""

import gc
import os

import numpy as np
import pytest

from solaris_env.spaces import noop

WARMUP_STEPS = 300  # allocator pools and caches fill during the first ~250 steps
STEPS = 1000  # measured after the warm-up, within one episode (a new engine world per reset adds allocator
#               noise that levels off after ~5 resets; the vector test covers repeated resets)
GROWTH_BOUND_MB = 8.0


def rss_mb() -> float:
    gc.collect()
    with open("/proc/self/statm") as f:
        resident_pages = int(f.read().split()[1])
    return resident_pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def rollout_growth(env, make_actions, steps: int) -> tuple[float, float]:
    """Run warm-up + ``steps`` steps (resetting when the episode ends); RSS after warm-up, growth after it."""
    env.reset(seed=0)
    after_warmup = None
    for t in range(WARMUP_STEPS + steps):
        if t == WARMUP_STEPS:
            after_warmup = rss_mb()
        env.step(make_actions(env))
        if not env.agents:
            env.reset()
    return after_warmup, rss_mb() - after_warmup


def test_dream_env_memory_is_flat_over_1000_steps(dream):
    rng = np.random.default_rng(0)

    def actions(env):
        out = {}
        for a in env.agents:
            act = noop()
            act["forward"] = int(rng.integers(2))
            act["camera"] = rng.uniform(-10, 10, 2).astype(np.float32)
            out[a] = act
        return out

    base, growth = rollout_growth(dream(max_steps=WARMUP_STEPS + STEPS, task="visual_novelty"), actions, STEPS)
    assert growth < GROWTH_BOUND_MB, f"RSS grew {growth:.1f} MB after warm-up (from {base:.0f} MB)"


def test_real_env_memory_is_flat_over_1000_steps(real):
    base, growth = rollout_growth(real(max_steps=WARMUP_STEPS + STEPS), lambda env: {a: noop() for a in env.agents}, STEPS)
    assert growth < GROWTH_BOUND_MB, f"RSS grew {growth:.1f} MB after warm-up (from {base:.0f} MB)"


def test_vector_env_memory_is_flat(vector):
    env = vector(max_steps=50)
    env.reset(seed=0)
    steps = [{a: noop() for a in env.possible_agents} for _ in range(env.num_envs)]
    for t in range(WARMUP_STEPS + 300):  # 12 autoresets per world
        if t == WARMUP_STEPS:
            base = rss_mb()
        env.step(steps)
    growth = rss_mb() - base
    assert growth < GROWTH_BOUND_MB, f"RSS grew {growth:.1f} MB after warm-up (from {base:.0f} MB)"


SOAK_STEPS = int(os.environ.get("SOLARIS_SOAK_STEPS", "10000"))


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("SOLARIS_SOAK") != "1",
                    reason="soak: set SOLARIS_SOAK=1 (10,000 dream steps; SOLARIS_SOAK_STEPS=N for another length)")
def test_soak_dream_rollout_with_random_actions_keeps_memory_and_step_time_flat(dream):
    """SOAK_STEPS steps of uniformly random actions (the whole +-180 deg camera box, so turns are carried over
    most of the time) in one episode: RSS within +5 % of its value after the warm-up, and the median step time
    of the last tenth within +30 % of the first tenth's (medians: the machine is shared)."""
    import time

    env = dream(max_steps=WARMUP_STEPS + SOAK_STEPS + 1)
    env.reset(seed=0)
    for i, a in enumerate(env.possible_agents):
        env.action_space(a).seed(i)
    times, base = [], None
    for t in range(WARMUP_STEPS + SOAK_STEPS):
        if t == WARMUP_STEPS:
            base = rss_mb()
        actions = {a: env.action_space(a).sample() for a in env.agents}
        start = time.perf_counter()
        env.step(actions)
        times.append(time.perf_counter() - start)
    end = rss_mb()
    tenth = max(1, SOAK_STEPS // 10)
    first, last = np.median(times[WARMUP_STEPS:WARMUP_STEPS + tenth]), np.median(times[-tenth:])
    print(f"soak: {SOAK_STEPS} steps, RSS {base:.0f} -> {end:.0f} MB ({100 * (end / base - 1):+.1f} %), "
          f"median step {1e3 * first:.1f} -> {1e3 * last:.1f} ms")
    assert end <= 1.05 * base, f"RSS grew from {base:.0f} to {end:.0f} MB"
    assert last <= 1.3 * first, f"step time grew from {1e3 * first:.1f} to {1e3 * last:.1f} ms"
