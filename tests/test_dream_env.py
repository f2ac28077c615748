"""DreamParallelEnv: PettingZoo conformance, spaces shared with the real env, determinism, start frames,
errors, truncation, and the ``parallel_env`` factory. One test-preset model is built and compiled once
for the whole module and shared by every env (``model=``)."""

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

import solaris_env
from solaris_env import DreamParallelEnv, RealParallelEnv
from solaris_env.dream_env import ONCE_KEYS, expand_action
from solaris_env.spaces import (
    CAMERA_SCALE_DEG,
    CAMERA_TICK_LIMIT_DEG,
    CAMERA_X_INDEX,
    CAMERA_Y_INDEX,
    MODEL_INDEX,
    noop,
)


@pytest.fixture(scope="module")
def model():
    from solaris_env.world_model.world_model import WorldModel

    return WorldModel.from_preset("test", seed=0)


@pytest.fixture
def make(model):
    def make_env(**kw):
        return DreamParallelEnv(model=model, **kw)

    return make_env


def solid_frames(env, values):
    return {a: np.full((env.height, env.width, 3), v, np.uint8) for a, v in zip(env.possible_agents, values)}


def test_parallel_api_test(make):
    env = make(max_steps=20)
    parallel_api_test(env, num_cycles=50)


def test_parallel_seed_test(model):
    parallel_seed_test(lambda: DreamParallelEnv(model=model, max_steps=20))


def test_spaces_are_built_once_and_match_the_real_env(make):
    env = make(render_mode="rgb_array")
    real = RealParallelEnv(num_players=env.num_players, resolution=(env.height, env.width))
    assert env.possible_agents == real.possible_agents == ["Alpha", "Bravo"]
    for a in env.possible_agents:
        assert env.observation_space(a) is env.observation_space(a)
        assert env.action_space(a) is env.action_space(a)
        assert env.observation_space(a) == real.observation_space(a)
        assert env.action_space(a) == real.action_space(a)
    assert env.metadata["name"] == "solaris_dream_v0" and env.metadata["is_parallelizable"]
    assert env.metadata["render_fps"] == 20 / env.frames_per_step
    obs, infos = env.reset(seed=3)
    for a in env.agents:
        assert env.observation_space(a).contains(obs[a])
    sheet = env.render()
    assert sheet.shape == (env.height, 2 * env.width, 3) and sheet.dtype == np.uint8
    obs, _, _, _, infos = env.step({a: noop() for a in env.agents})
    k = env.frames_per_step
    for a in env.agents:
        assert infos[a]["frames"].shape == (k, env.height, env.width, 3)
        assert np.array_equal(infos[a]["frames"][-1], obs[a])


def test_same_seed_and_actions_give_identical_frames(make):
    def rollout():
        env = make()
        obs, _ = env.reset(seed=7)
        frames = [np.stack([obs[a] for a in env.possible_agents])]  # (P, H, W, 3)
        for i, a in enumerate(env.possible_agents):
            env.action_space(a).seed(11 + i)
        for _ in range(4):
            _, _, _, _, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
            for t in range(env.frames_per_step):
                frames.append(np.stack([infos[a]["frames"][t] for a in env.possible_agents]))
        return np.stack(frames)  # (1 + 4k, P, H, W, 3)

    a, b = rollout(), rollout()
    assert np.array_equal(a, b)
    assert not np.array_equal(a[0], a[-1])


def test_start_frames_from_options_go_to_model_init(make, model, monkeypatch):
    # With random-init weights the DiT's zero-initialised output layer makes frame 0 independent of the
    # conditioning, so check what init receives and the conditioning it builds, not the generated frame.
    seen = []
    real_init = model.init

    def spy_init(frames, rng, **kw):
        seen.append(np.asarray(frames))
        return real_init(frames, rng, **kw)

    monkeypatch.setattr(model, "init", spy_init)
    env = make()
    dark, bright = solid_frames(env, (0, 10)), solid_frames(env, (255, 200))
    env.reset(seed=0, options={"frames": dark})
    cond_dark = np.array(env._state.cond_BPFhwC)
    env.reset(seed=0, options={"frames": bright})
    cond_bright = np.array(env._state.cond_BPFhwC)
    for given, frames in zip((dark, bright), seen):
        assert frames.shape == (1, 2, env.height, env.width, 3)
        assert np.array_equal(frames[0], np.stack([given[a] for a in env.possible_agents]))
    assert not np.allclose(cond_dark, cond_bright)


def test_bad_start_frames_raise(make):
    env = make()
    with pytest.raises(ValueError, match="missing \\['Bravo'\\]"):
        env.reset(options={"frames": {"Alpha": np.zeros((env.height, env.width, 3), np.uint8)}})
    frames = solid_frames(env, (0, 0))
    frames["Bravo"] = frames["Bravo"].astype(np.float32)
    with pytest.raises(ValueError, match="'Bravo'.*uint8"):
        env.reset(options={"frames": frames})


def test_missing_agent_and_bad_action_raise_without_breaking_the_env(make):
    env = make()
    with pytest.raises(RuntimeError, match="reset"):
        env.step({a: noop() for a in env.possible_agents})
    env.reset(seed=0, options={"frames": solid_frames(env, (10, 20))})
    with pytest.raises(ValueError, match="missing \\['Bravo'\\]"):
        env.step({"Alpha": noop()})
    with pytest.raises(ValueError, match="unknown \\['Zulu'\\]"):
        env.step({"Alpha": noop(), "Bravo": noop(), "Zulu": noop()})
    bad = noop()
    bad["forward"] = 2
    with pytest.raises(ValueError, match="'Bravo'.*'forward'"):
        env.step({"Alpha": noop(), "Bravo": bad})
    bad = noop()
    del bad["camera"]
    with pytest.raises(ValueError, match="'Alpha'.*camera"):
        env.step({"Alpha": bad, "Bravo": noop()})
    obs, *_ = env.step({a: noop() for a in env.agents})  # the state was not donated by the failed calls
    assert set(obs) == {"Alpha", "Bravo"}


def test_truncation_at_max_steps_then_agents_leave(make):
    env = make(max_steps=3)
    env.reset(seed=1, options={"frames": solid_frames(env, (50, 90))})
    for t in range(3):
        obs, rewards, terms, truncs, _ = env.step({a: noop() for a in env.agents})
        assert set(obs) == {"Alpha", "Bravo"}
        assert all(r == 0.0 for r in rewards.values()) and not any(terms.values())
        assert all(truncs.values()) == (t == 2)
    assert env.agents == []
    with pytest.raises(RuntimeError):
        env.step({})


def test_expand_action_once_keys_on_the_first_tick_and_the_camera_spread_within_the_trained_range():
    action = noop()
    for key in ("forward", "sprint") + ONCE_KEYS:
        action[key] = 1
    action["camera"] = np.array([5.0, -10.0], np.float32)
    ticks, pending = expand_action(action, 4)
    assert ticks.shape == (4, 25) and not pending.any()
    assert (ticks[:, MODEL_INDEX["forward"]] == 1).all() and (ticks[:, MODEL_INDEX["sprint"]] == 1).all()
    for key in ONCE_KEYS:
        assert ticks[0, MODEL_INDEX[key]] == 1 and (ticks[1:, MODEL_INDEX[key]] == 0).all(), key
    # model units are degrees / CAMERA_SCALE_DEG, Mineflayer signs (+ = left / up); at most 8.59 deg a tick
    deg = ticks[:, [CAMERA_X_INDEX, CAMERA_Y_INDEX]] * CAMERA_SCALE_DEG
    np.testing.assert_allclose(deg.sum(0), [10.0, -5.0], atol=1e-5)
    assert np.abs(deg).max() <= CAMERA_TICK_LIMIT_DEG + 1e-5
    np.testing.assert_allclose(deg[0], [CAMERA_TICK_LIMIT_DEG, -5.0], atol=1e-5)
    assert not deg[2:].any()


def test_factory_and_constructor_checks(model):
    real = solaris_env.parallel_env("real", resolution=36)
    assert isinstance(real, RealParallelEnv)
    assert isinstance(solaris_env.parallel_env("real", backend="voxel", resolution=36), RealParallelEnv)
    with pytest.raises(ValueError, match="backend must be one of"):
        solaris_env.parallel_env("real", backend="unreal")
    dream = solaris_env.parallel_env("dream", preset="test")
    assert isinstance(dream, DreamParallelEnv) and dream.possible_agents == ["Alpha", "Bravo"]
    assert dream.observation_space("Alpha").shape == (32, 32, 3)
    with pytest.raises(ValueError, match="kind"):
        solaris_env.parallel_env("imaginary")
    with pytest.raises(ValueError, match="num_players"):
        DreamParallelEnv(model=model, num_players=3)
    with pytest.raises(ValueError, match="render_mode"):
        DreamParallelEnv(model=model, render_mode="ascii")
    with pytest.raises(ValueError, match="max_steps"):
        DreamParallelEnv(model=model, max_steps=0)
