"""Flat memory: 1000-step rollouts whose resident memory does not grow after warm-up.

A leak of one step's frames would add 2 players x 4 frames x 32 x 32 x 3 B = 24 KB per dream step, i.e. 24 MB
over 1000 steps (and one 36x36 frame per player per real step, 7.6 MB); the bound is well below the former
and leaves room for allocator noise.
"""

import gc
import os

import numpy as np

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
