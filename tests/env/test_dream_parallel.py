"""DreamParallelEnv (issue 5): the default checkpoint, start states (bundled scenes, frames, engine states),
tasks and per-agent terminations, rendering, truncation, N-step determinism, parallel_api_test at 1000 cycles."""

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from solaris_env import dream_env
from solaris_env.dream_env import DreamParallelEnv
from solaris_env.spaces import noop
from solaris_env.start_scenes import load_start_scenes
from solaris_env.tasks import Task, TaskStep


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


def test_parallel_api_test_1000_cycles(dream):
    parallel_api_test(dream(max_steps=500), num_cycles=1000)


def test_parallel_api_test_with_a_terminating_agent(dream):
    parallel_api_test(dream(max_steps=20, task=TerminateAfter(who=0, steps=5)), num_cycles=100)


def test_without_checkpoint_or_preset_the_missing_default_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setattr(dream_env, "DEFAULT_CHECKPOINT", tmp_path / "default")
    with pytest.raises(FileNotFoundError, match="default.*preset='tiny'"):
        DreamParallelEnv()
    with pytest.raises(ValueError, match="either checkpoint or preset"):
        DreamParallelEnv(checkpoint=tmp_path, preset="test")


def test_spaces_are_the_same_object_each_call(dream):
    env = dream()
    for a in env.possible_agents:
        assert env.observation_space(a) is env.observation_space(a)
        assert env.action_space(a) is env.action_space(a)


def test_bundled_start_scenes_are_sampled_by_seed(dream, model):
    env = dream()
    scenes = load_start_scenes(env.num_players, env.height, env.width)
    assert len(scenes) >= 8 and scenes.frames_SPHW3.shape[1:] == (2, env.height, env.width, 3)
    picks = {}
    for seed in range(6):
        _, infos = env.reset(seed=seed)
        assert infos["Alpha"]["start"] == "bundled"
        picks[seed] = infos["Alpha"]["scene"]
        _, again = env.reset(seed=seed)
        assert again["Alpha"]["scene"] == picks[seed]
    assert len(set(picks.values())) > 1


def test_bundled_scene_frames_are_what_the_engine_renders_from_their_state():
    scenes = load_start_scenes(2, 32, 32)
    from solaris_env.real_env import render_game_views

    for i in (0, 1):  # a flat and a normal world
        state = scenes.engine_state(i)
        frames, _ = render_game_views(state.game(), 32, 32)
        assert np.array_equal(frames, scenes.frames_SPHW3[i]), f"scene {i}: rebuild the bundle (engine changed?)"


def test_start_scenes_resize_on_load_for_other_sizes():
    scenes = load_start_scenes(2, 48, 40)
    assert scenes.frames_SPHW3.shape[2:] == (48, 40, 3) and scenes.frames_SPHW3.dtype == np.uint8
    with pytest.raises(ValueError, match="num_players=7.*engine"):
        load_start_scenes(7, 32, 32)


def test_engine_state_start_renders_the_same_views_as_the_real_env(dream, real):
    env = dream()
    r = real(resolution=env.height, view_distance=48.0)  # the dream renders states as the training data
    obs_real, _ = r.reset(seed=5)
    for _ in range(3):
        obs_real, *_ = r.step({a: noop() for a in r.agents})
    state = r.engine_state()
    frames, start = env.start_frames.from_options({"engine_state": state})
    assert start == {"start": "engine_state"}
    assert np.array_equal(frames, np.stack([obs_real[a] for a in r.possible_agents]))
    obs, infos = env.reset(seed=0, options={"engine_state": state})
    assert infos["Bravo"]["start"] == "engine_state" and set(obs) == {"Alpha", "Bravo"}


def test_start_states_engine_and_given_arrays(dream):
    env = dream(start_states="engine")
    _, infos = env.reset(seed=1)
    assert infos["Alpha"]["start"] == "engine" and "engine_seed" in infos["Alpha"]
    given = np.random.default_rng(0).integers(0, 256, (3, 2, env.height, env.width, 3), dtype=np.uint8)
    env = dream(start_states=given)
    _, infos = env.reset(seed=1)
    assert infos["Alpha"]["start"] == "frames" and 0 <= infos["Alpha"]["scene"] < 3
    with pytest.raises(ValueError, match="start_states array"):
        dream(start_states=given[:, :1])
    with pytest.raises(ValueError, match="start_states must be one of"):
        dream(start_states="moon")


def test_render_modes(dream):
    env = dream(render_mode="rgb_array")
    env.reset(seed=0)
    sheet = env.render()
    assert sheet.shape == (env.height, 2 * env.width, 3) and sheet.dtype == np.uint8
    assert env.metadata["render_fps"] == 20 / env.frames_per_step
    assert dream().render() is None
    with pytest.raises(RuntimeError, match="human"):
        dream(render_mode="human")  # this machine has no display and a headless OpenCV


def test_step_infos_hold_all_k_frames_and_truncation_at_max_steps(dream):
    env = dream(max_steps=3)
    env.reset(seed=2)
    for t in range(3):
        obs, rewards, terms, truncs, infos = env.step({a: noop() for a in env.agents})
        for a in ("Alpha", "Bravo"):
            assert infos[a]["frames"].shape == (env.frames_per_step, env.height, env.width, 3)
            assert np.array_equal(infos[a]["frames"][-1], obs[a])
            assert infos[a]["step"] == t + 1
        assert rewards == {"Alpha": 0.0, "Bravo": 0.0} and not any(terms.values())
        assert all(truncs.values()) == (t == 2)
    assert env.agents == []
    assert env.step_frames().shape == (2, env.frames_per_step, env.height, env.width, 3)
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})


def test_a_terminated_agent_leaves_and_its_player_gets_noops(dream):
    task = TerminateAfter(who=0, steps=2)
    env = dream(max_steps=10, task=task)
    env.reset(seed=0)
    walk = noop()
    walk["forward"] = 1
    _, rewards, terms, truncs, _ = env.step({"Alpha": walk, "Bravo": walk})
    assert rewards == {"Alpha": 1.0, "Bravo": 1.0} and not any(terms.values())
    _, _, terms, truncs, _ = env.step({"Alpha": walk, "Bravo": walk})
    assert terms == {"Alpha": True, "Bravo": False} and not any(truncs.values())
    assert env.agents == ["Bravo"]
    with pytest.raises(ValueError, match="unknown \\['Alpha'\\]"):
        env.step({"Alpha": walk, "Bravo": walk})
    obs, rewards, *_ = env.step({"Bravo": walk})
    assert set(obs) == set(rewards) == {"Bravo"}
    assert env.task.seen_actions[0]["forward"] == 0 and env.task.seen_actions[1]["forward"] == 1


def test_ground_truth_tasks_are_refused(dream):
    with pytest.raises(ValueError, match="ground truth"):
        dream(task="see_other_player")
    with pytest.raises(ValueError, match="unknown task"):
        dream(task="fly")


def test_visual_novelty_task_rewards_in_the_dream(dream):
    env = dream(task="visual_novelty", max_steps=5)
    env.reset(seed=0)
    total = 0.0
    for _ in range(5):
        _, rewards, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
        assert all(r >= 0.0 for r in rewards.values())
        total += sum(rewards.values())
    assert total > 0.0  # random-init frames change a lot between steps


def test_n_step_determinism_same_seed_same_frames_other_seed_differs(dream):
    def rollout(seed, steps=25):
        env = dream(max_steps=steps)
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(123)
        frames = [np.stack([obs[a] for a in env.possible_agents])]
        for _ in range(steps):
            actions = {}
            for a in env.agents:
                act = noop()
                for key in ("forward", "left", "jump", "attack"):
                    act[key] = int(rng.integers(2))
                act["camera"] = rng.uniform(-15, 15, 2).astype(np.float32)
                actions[a] = act
            env.step(actions)
            frames.append(env.step_frames().reshape(-1, env.height, env.width, 3))
        return np.concatenate(frames)

    a, b = rollout(7), rollout(7)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, rollout(8))


ROLLOUT_IN_A_PROCESS = """
import os, sys
import jax
cache = os.environ.get("SOLARIS_JAX_CACHE", os.path.expanduser("~/.cache/solaris_env/jax"))
if cache:
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
import numpy as np
from solaris_env.dream_env import DreamParallelEnv, build_model
from solaris_env.spaces import noop

env = DreamParallelEnv(model=build_model(None, "test", num_players=2))
obs, _ = env.reset(seed=7)
frames = [np.stack([obs[a] for a in env.possible_agents])]
rng = np.random.default_rng(123)
for _ in range(6):
    actions = {}
    for a in env.agents:
        act = noop()
        act["forward"], act["jump"] = int(rng.integers(2)), int(rng.integers(2))
        act["camera"] = rng.uniform(-40, 40, 2).astype(np.float32)
        actions[a] = act
    env.step(actions)
    frames.append(env.step_frames().reshape(-1, env.height, env.width, 3))
np.save(sys.argv[1], np.concatenate(frames))
"""


@pytest.mark.slow  # ~20-40 s: two fresh processes load the test model's programs
def test_same_seed_and_actions_give_identical_frames_in_two_processes(tmp_path):
    """The README's promise across processes (the dream env docstring: bit-exact on one machine and JAX build)."""
    import subprocess
    import sys

    paths = [tmp_path / f"frames_{i}.npy" for i in range(2)]
    procs = [subprocess.Popen([sys.executable, "-c", ROLLOUT_IN_A_PROCESS, str(p)], stderr=subprocess.PIPE, text=True)
             for p in paths]
    for proc in procs:
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err
    a, b = (np.load(p).astype(np.int16) for p in paths)
    diff = np.abs(a - b)
    assert a.shape == b.shape and diff.max() == 0, \
        f"frames differ across processes: max {diff.max()} grey levels on {(diff > 0).mean():.4%} of the values"
