"""``solaris_env.vector_env`` (DreamVectorEnv): spaces, the batched model call, the three autoreset modes, partial
resets, action formats, per-world tasks and determinism. Every test uses VECTOR_WORLDS = 2 worlds on the shared test
model."""

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from solaris_env.dream_env import DreamParallelEnv
from solaris_env.spaces import noop
from solaris_env.tasks import Task, TaskStep

N = 2


def noops(env):
    return [{a: noop() for a in env.possible_agents} for _ in range(env.num_envs)]


class EndWorldAt(Task):
    """Test task: the reward is the step count; world ends (player 1 terminates) at ``steps``."""

    def __init__(self, steps: int):
        self.steps = steps

    def reset(self, frames_PHW3, truth=None):
        super().reset(frames_PHW3, truth)
        self.t = 0

    def step(self, frames_PkHW3, actions, truth=None):
        self.t += 1
        p = frames_PkHW3.shape[0]
        done = np.zeros(p, bool)
        done[-1] = self.t >= self.steps
        return TaskStep(np.full(p, self.t, np.float32), done)


def test_spaces_metadata_and_shapes(vector):
    env = vector(max_steps=5)
    assert env.num_envs == N and env.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    p, h, w = env.num_players, env.height, env.width
    assert env.single_observation_space.shape == (p, h, w, 3)
    assert env.observation_space.shape == (N, p, h, w, 3)
    assert set(env.single_action_space.spaces) == {"Alpha", "Bravo"}
    obs, infos = env.reset(seed=0)
    assert obs.shape == (N, p, h, w, 3) and obs.dtype == np.uint8 and env.observation_space.contains(obs)
    assert [s["start"] for s in infos["start"]] == ["bundled"] * N
    env.action_space.seed(0)
    obs, rewards, terms, truncs, infos = env.step(env.action_space.sample())
    assert obs.shape == (N, p, h, w, 3) and rewards.shape == (N, p) and rewards.dtype == np.float32
    assert terms.shape == truncs.shape == (N,) and not terms.any() and not truncs.any()
    assert infos["frames"].shape == (N, p, env.frames_per_step, h, w, 3)
    assert np.array_equal(infos["frames"][:, :, -1], obs)
    assert list(infos["step"]) == [1, 1]
    assert env.render() is None
    sheet = vector(render_mode="rgb_array")
    sheet.reset(seed=0)
    assert sheet.render().shape == (N * h, p * w, 3)


def test_same_step_autoreset_reports_final_obs_and_restarts(vector):
    env = vector(max_steps=3)
    env.reset(seed=1)
    for t in range(3):
        obs, _, terms, truncs, infos = env.step(noops(env))
    assert truncs.all() and not terms.any()
    assert infos["_final_obs"].all() and infos["final_obs"][0].shape == obs[0].shape
    assert np.array_equal(infos["final_obs"][1], infos["frames"][1, :, -1])  # the last frame of the episode
    assert not np.array_equal(obs, infos["frames"][:, :, -1])  # obs is the new episode's frame 0
    assert list(infos["final_info"]["step"]) == [3, 3]
    _, _, _, truncs, infos = env.step(noops(env))
    assert not truncs.any() and list(infos["step"]) == [1, 1]


def test_task_ends_one_world_and_only_it_restarts(vector):
    env = vector(max_steps=50, task=EndWorldAt(2))
    env.reset(seed=0)
    env.step(noops(env))
    # end world 0 only: reset world 1 by hand to shift its episode
    env.reset(options={"reset_mask": np.array([False, True])})
    _, rewards, terms, _, infos = env.step(noops(env))
    assert list(terms) == [True, False] and list(rewards[:, 0]) == [2.0, 1.0]
    assert list(infos["_final_obs"]) == [True, False]
    _, rewards, terms, _, infos = env.step(noops(env))
    assert list(terms) == [False, True] and list(rewards[:, 0]) == [1.0, 2.0]


def test_next_step_autoreset(vector):
    env = vector(max_steps=2, autoreset_mode="NextStep")
    assert env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    env.reset(seed=0)
    env.step(noops(env))
    _, _, _, truncs, infos = env.step(noops(env))
    assert truncs.all() and "final_obs" not in infos
    _, rewards, terms, truncs, infos = env.step(noops(env))  # the reset step: actions ignored
    assert not truncs.any() and not terms.any() and (rewards == 0).all() and list(infos["step"]) == [0, 0]
    _, _, _, _, infos = env.step(noops(env))
    assert list(infos["step"]) == [1, 1]


def test_disabled_autoreset_needs_a_masked_reset(vector):
    env = vector(max_steps=1, autoreset_mode=AutoresetMode.DISABLED)
    env.reset(seed=0)
    _, _, _, truncs, _ = env.step(noops(env))
    assert truncs.all()
    with pytest.raises(RuntimeError, match="reset_mask"):
        env.step(noops(env))
    before = env._obs_NPHW3.copy()
    obs, infos = env.reset(options={"reset_mask": np.array([True, False])})
    assert np.array_equal(obs[1], before[1]) and infos["start"][1] is None
    with pytest.raises(RuntimeError, match="reset_mask"):
        env.step(noops(env))  # world 1 still ended
    env.reset(options={"reset_mask": np.array([False, True])})
    env.step(noops(env))


def test_batched_and_per_world_actions_agree(vector):
    def run(batched):
        env = vector(max_steps=10)
        env.reset(seed=3)
        env.action_space.seed(5)
        out = []
        for _ in range(3):
            batch = env.action_space.sample()
            per_world = [{a: {k: v[i] for k, v in batch[a].items()} for a in batch} for i in range(N)]
            obs, *_ = env.step(batch if batched else per_world)
            out.append(obs)
        return np.stack(out)

    assert np.array_equal(run(True), run(False))


def test_worlds_are_independent_and_deterministic(vector):
    def rollout(seed):
        env = vector(max_steps=4)
        obs, _ = env.reset(seed=seed)
        frames = [obs]
        for _ in range(6):  # crosses an autoreset
            obs, _, _, _, infos = env.step(noops(env))
            frames.append(infos["frames"].reshape(N, -1, env.height, env.width, 3))
        return frames

    a, b, c = rollout(9), rollout(9), rollout(10)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))
    assert not np.array_equal(a[1][0], a[1][1])  # two worlds, two different streams


def test_vector_env_constructor_checks(model):
    from solaris_env.vector_env import DreamVectorEnv

    with pytest.raises(ValueError, match="num_worlds"):
        DreamVectorEnv(0, model=model)
    with pytest.raises(ValueError, match="autoreset_mode"):
        DreamVectorEnv(N, model=model, autoreset_mode="sometimes")
    with pytest.raises(ValueError, match="ground truth"):
        DreamVectorEnv(N, model=model, task="see_other_player")
    with pytest.raises(ValueError, match="render_mode"):
        DreamVectorEnv(N, model=model, render_mode="human")
    assert isinstance(DreamParallelEnv(model=model), DreamParallelEnv)
