"""``solaris_env.wrappers.sb3`` (SB3VecEnv): the slot layout, SB3's episode-end conventions, opponents, and PPO running
2 updates on the dream vector env (test preset, 2 worlds)."""

import numpy as np
import pytest
import torch

from solaris_env.spaces import FlatActionCodec
from solaris_env.wrappers.opponents import NoopOpponent
from solaris_env.wrappers.sb3 import SB3VecEnv

torch.set_num_threads(1)  # docs/model.md §10.2: small torch ops are far faster single-threaded on these VMs


def test_slots_and_episode_end_conventions(vector):
    venv = SB3VecEnv(vector(max_steps=3))
    assert venv.num_envs == 4 and venv.action_space == FlatActionCodec().space
    assert venv.observation_space.shape == (32, 32, 3)
    obs = venv.reset()
    assert obs.shape == (4, 32, 32, 3) and obs.dtype == np.uint8
    assert np.array_equal(obs[1], venv._world_obs_NPHW3[0, 1]) and np.array_equal(obs[2], venv._world_obs_NPHW3[1, 0])
    venv.action_space.seed(0)
    for t in range(3):
        obs, rewards, dones, infos = venv.step(np.stack([venv.action_space.sample() for _ in range(4)]))
        assert rewards.shape == dones.shape == (4,) and len(infos) == 4
    assert dones.all()
    for info in infos:
        assert info["TimeLimit.truncated"] is True and info["terminal_observation"].shape == (32, 32, 3)
    assert not any(np.array_equal(i["terminal_observation"], o) for i, o in zip(infos, obs))
    with pytest.raises(ValueError, match="shape"):
        venv.step(np.zeros((3, 25), np.int64))
    with pytest.raises(ValueError, match="slot 1 \\(world 0, agent 'Bravo'\\).*camera"):
        bad = np.zeros((4, 25), np.int64)
        bad[1, -1] = 99
        venv.step(bad)


def test_one_learner_and_opponents(vector):
    venv = SB3VecEnv(vector(max_steps=10), learners=["Bravo"], opponent=NoopOpponent)
    assert venv.num_envs == 2 and venv.others == ["Alpha"]
    obs = venv.reset()
    assert np.array_equal(obs[0], venv._world_obs_NPHW3[0, 1])
    venv.step(np.zeros((2, 25), np.int64))
    with pytest.raises(ValueError, match="learners"):
        SB3VecEnv(vector(), learners=["Zulu"])
    with pytest.raises(ValueError, match="SAME_STEP"):
        SB3VecEnv(vector(autoreset_mode="NextStep"))


def test_ppo_runs_two_updates_on_the_dream_vector_env(vector):
    from stable_baselines3 import PPO

    venv = SB3VecEnv(vector(max_steps=6, task="visual_novelty"))
    ppo = PPO("MlpPolicy", venv, n_steps=8, batch_size=16, n_epochs=1, seed=0, device="cpu",
              policy_kwargs={"net_arch": [32]})
    ppo.learn(total_timesteps=2 * 8 * venv.num_envs)
    assert ppo._n_updates == 2 and ppo.num_timesteps == 64
    assert ppo.rollout_buffer.rewards.shape == (8, 4) and ppo.rollout_buffer.rewards.sum() > 0
    action, _ = ppo.predict(venv.reset(), deterministic=True)
    assert action.shape == (4, 25)
