"""Shared fixtures for the tests of ``solaris_env`` and its subpackages: ONE test-preset world model for the whole
session (its programs compile once per batch size: B = 1 for the parallel envs, B = 2 for the vector envs), env
factories on it, and a test task that ends one player's episode early.

JAX's persistent compilation cache is switched on for this session (``SOLARIS_JAX_CACHE``, default
``~/.cache/solaris_env/jax``; set it to an empty string to disable): the test model's programs take ~10-40 s
each to compile on 2 cores and are then loaded in ~1 s by later runs. It caches compiled executables only,
keyed by the program, so results are the same with or without it.
"""

import os
from pathlib import Path

import jax
import numpy as np
import pytest

from solaris_env.tasks import Task, TaskStep

_cache = os.environ.get("SOLARIS_JAX_CACHE", str(Path.home() / ".cache" / "solaris_env" / "jax"))
if _cache:
    jax.config.update("jax_compilation_cache_dir", _cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

VECTOR_WORLDS = 2  # every vector-env test uses this many worlds, so B = 2 compiles once


@pytest.fixture(scope="session")
def model():
    from solaris_env.world_model.world_model import WorldModel

    return WorldModel.from_preset("test", seed=0)


@pytest.fixture
def dream(model):
    """``dream(**kw)`` -> a DreamParallelEnv on the shared model."""
    from solaris_env.dream_env import DreamParallelEnv

    return lambda **kw: DreamParallelEnv(model=model, **kw)


@pytest.fixture
def vector(model):
    """``vector(**kw)`` -> a DreamVectorEnv of VECTOR_WORLDS worlds on the shared model."""
    from solaris_env.vector_env import DreamVectorEnv

    return lambda **kw: DreamVectorEnv(VECTOR_WORLDS, model=model, **kw)


@pytest.fixture
def real():
    """``real(**kw)`` -> a small, fast RealParallelEnv (36x36: the smallest SB3 CNN size; short view distance)."""
    from solaris_env.real_env import RealParallelEnv

    def make(**kw):
        kw.setdefault("resolution", 36)
        kw.setdefault("view_distance", 24.0)
        return RealParallelEnv(**kw)

    return make


class TerminateAfter(Task):
    """Test task: reward 1 for every player each step; ``who`` terminates after ``steps`` steps."""

    name = "terminate_after"

    def __init__(self, who: int = 0, steps: int = 2):
        self.who, self.steps = who, steps

    def reset(self, frames_PHW3, truth=None):
        super().reset(frames_PHW3, truth)
        self.t = 0

    def step(self, frames_PkHW3, actions, truth=None):
        self.t += 1
        self.seen_actions = actions
        done = np.zeros(frames_PkHW3.shape[0], bool)
        done[self.who] = self.t >= self.steps
        return TaskStep(np.ones(frames_PkHW3.shape[0], np.float32), done)


@pytest.fixture
def terminate_after():
    """``terminate_after(who, steps)`` -> a TerminateAfter task (player ``who`` ends its episode first)."""
    return TerminateAfter
