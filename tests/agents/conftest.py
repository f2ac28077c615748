"""Shared fixtures of the agent tests: small real envs, held-out start states, the test-preset world model.

JAX's persistent compilation cache is on, as in ``tests/solaris_env/conftest.py`` (``SOLARIS_JAX_CACHE``, default
``~/.cache/solaris_env/jax``; empty disables it): the renderer and the test model compile once per machine.
"""

import os
from pathlib import Path

import jax
import pytest
import torch

_cache = os.environ.get("SOLARIS_JAX_CACHE", str(Path.home() / ".cache" / "solaris_env" / "jax"))
if _cache:
    jax.config.update("jax_compilation_cache_dir", _cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
torch.set_num_threads(1)  # docs/model.md §10.2: small torch ops are far faster single-threaded on these VMs

SMALL = 36  # the smallest frame SB3's CNN takes; the real env renders it fast


@pytest.fixture
def real():
    """``real(**kw)`` -> a two-player RealParallelEnv, 36x36 unless given."""
    from solaris_env.real_env import RealParallelEnv

    def make(**kw):
        kw.setdefault("resolution", SMALL)
        return RealParallelEnv(num_players=2, **kw)

    return make


@pytest.fixture(scope="session")
def start_states():
    """Four held-out start states (Alpha turned by a random yaw), rendered on the way at 36x36."""
    from agents.common import EVAL_START_SEED, make_start_states

    return make_start_states(4, EVAL_START_SEED, "flat", SMALL)


@pytest.fixture(scope="session")
def model():
    from solaris_env.world_model.world_model import WorldModel

    return WorldModel.from_preset("test", seed=0)
