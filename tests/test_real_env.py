"""RealParallelEnv: PettingZoo conformance, determinism, spaces, errors."""

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from solaris_env import RealParallelEnv
from solaris_env.spaces import noop


def make(**kw):
    kw.setdefault("resolution", 36)
    kw.setdefault("view_distance", 24.0)
    return RealParallelEnv(**kw)


def test_parallel_api_test_1000_cycles():
    env = make(max_steps=400)
    parallel_api_test(env, num_cycles=1000)


def test_spaces_are_built_once_and_match_the_frames():
    env = make(render_mode="rgb_array")
    assert env.possible_agents == ["Alpha", "Bravo"]
    assert env.observation_space("Alpha") is env.observation_space("Alpha")
    assert env.action_space("Bravo") is env.action_space("Bravo")
    obs, _ = env.reset(seed=3)
    for a in env.agents:
        assert env.observation_space(a).contains(obs[a])
    frame = env.render()
    assert frame.shape == (36, 72, 3) and frame.dtype == np.uint8


def test_players_see_each_other_at_reset():
    env = make(resolution=64, view_distance=48.0)
    _, infos = env.reset(seed=0)
    assert infos["Alpha"]["sees"]["Bravo"] and infos["Bravo"]["sees"]["Alpha"]


def test_same_seed_and_actions_give_identical_frames():
    def rollout():
        env = make()
        obs, _ = env.reset(seed=7)
        frames = [np.stack([obs[a] for a in env.possible_agents])]
        for a in env.possible_agents:
            env.action_space(a).seed(11)
        for _ in range(60):
            obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
            frames.append(np.stack([obs[a] for a in env.possible_agents]))
        return np.stack(frames)

    a, b = rollout(), rollout()
    assert np.array_equal(a, b)
    assert not np.array_equal(a[0], a[-1])  # random actions changed the views


def test_truncation_at_max_steps_and_step_after_end_raises():
    env = make(max_steps=3)
    env.reset(seed=1)
    for t in range(3):
        _, _, term, trunc, _ = env.step({a: noop() for a in env.agents})
    assert all(trunc.values()) and not any(term.values()) and env.agents == []
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})


def test_missing_agent_or_bad_action_raises_naming_it():
    env = make()
    env.reset(seed=1)
    with pytest.raises(ValueError, match="missing \\['Bravo'\\]"):
        env.step({"Alpha": noop()})
    bad = noop()
    bad["camera"] = np.array([np.nan, 0.0], np.float32)
    with pytest.raises(ValueError, match="Bravo.*camera|camera.*Bravo"):
        env.step({"Alpha": noop(), "Bravo": bad})


@pytest.mark.parametrize("kw,match", [
    ({"world": "moon"}, "world must be one of"),
    ({"num_players": 0}, "num_players"),
    ({"render_mode": "ascii"}, "render_mode"),
    ({"resolution": 4}, "resolution"),
])
def test_constructor_validates(kw, match):
    with pytest.raises(ValueError, match=match):
        make(**kw)
