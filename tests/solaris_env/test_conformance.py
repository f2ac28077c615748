"""PettingZoo conformance of the package's parallel envs, each checked the same way: ``DreamParallelEnv`` (on the
test-preset model) and ``RealParallelEnv`` (the voxel engine). The wrappers' conformance is in
``wrappers/test_wrappers.py``; ``MinecraftParallelEnv``'s in ``test_minecraft_env.py`` (it runs in real time, so
it has no seed test)."""

import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

ENVS = ["dream", "real"]  # the env-factory fixtures of conftest.py


@pytest.mark.parametrize("env", ENVS)
@pytest.mark.parametrize("terminating", [False, True], ids=["1000_cycles_with_a_task", "a_terminating_agent"])
def test_parallel_api_test(request, env, terminate_after, terminating):
    """PettingZoo's API test: 1000 cycles (two 500-step episodes) with a task scoring every step, and short episodes
    in which Alpha terminates after 5 steps while Bravo plays on to the truncation."""
    make = request.getfixturevalue(env)
    if terminating:
        parallel_api_test(make(max_steps=20, task=terminate_after(who=0, steps=5)), num_cycles=100)
    else:
        parallel_api_test(make(max_steps=500, task="visual_novelty"), num_cycles=1000)


@pytest.mark.parametrize("env", ENVS)
def test_parallel_seed_test(request, env):
    """Two envs reset with the same seed and stepped with the same actions give the same observations, rewards
    and flags."""
    make = request.getfixturevalue(env)
    parallel_seed_test(lambda: make(max_steps=20))
