"""``solaris_env.real_env`` (RealParallelEnv; its PettingZoo conformance is in ``test_conformance.py``): spaces, determinism, engine-state snapshots, ``ticks_per_step`` (one step plays k
engine ticks as the dream env does: the whole action on the first tick, then only the held movement keys, the camera
turn spread over the ticks; every tick rendered, the task scored once), truncation and errors."""

import numpy as np
import pytest

from solaris_env.real_env import EngineState
from solaris_env.spaces import noop, step_ticks


def act(dyaw: float = 0.0, **keys) -> dict:
    a = noop()
    a["camera"] = np.array([0.0, dyaw], np.float32)
    a.update(keys)
    return a


def test_spaces_are_built_once_and_match_the_frames(real):
    env = real(render_mode="rgb_array")
    assert env.possible_agents == ["Alpha", "Bravo"]
    assert env.observation_space("Alpha") is env.observation_space("Alpha")
    assert env.action_space("Bravo") is env.action_space("Bravo")
    obs, _ = env.reset(seed=3)
    for a in env.agents:
        assert env.observation_space(a).contains(obs[a])
    frame = env.render()
    assert frame.shape == (36, 72, 3) and frame.dtype == np.uint8


def test_players_see_each_other_at_reset(real):
    env = real(resolution=64, view_distance=48.0)
    _, infos = env.reset(seed=0)
    assert infos["Alpha"]["sees"]["Bravo"] and infos["Bravo"]["sees"]["Alpha"]


def test_same_seed_and_actions_give_identical_frames(real):
    def rollout():
        env = real()
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


def test_truncation_at_max_steps_and_step_after_end_raises(real):
    env = real(max_steps=3)
    env.reset(seed=1)
    for t in range(3):
        _, _, term, trunc, _ = env.step({a: noop() for a in env.agents})
    assert all(trunc.values()) and not any(term.values()) and env.agents == []
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})


def test_missing_agent_or_bad_action_raises_naming_it(real):
    env = real()
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
def test_constructor_validates(real, kw, match):
    with pytest.raises(ValueError, match=match):
        real(**kw)


def test_engine_state_round_trip_then_identical_futures(real):
    env = real()
    env.reset(seed=4)
    for t in range(10):
        obs, *_ = env.step({"Alpha": act(3.0, forward=1), "Bravo": act(-2.0, jump=int(t % 3 == 0))})
    state = env.engine_state()
    assert isinstance(state, EngineState) and state.player_names == ["Alpha", "Bravo"] and state.tick == 10
    script = [{"Alpha": act(5.0, forward=1, sprint=1), "Bravo": act(-4.0, left=1)} for _ in range(15)]

    def replay(e):
        first, _ = e.reset(options={"engine_state": state})
        frames = [np.stack([first[a] for a in e.possible_agents])]
        for actions in script:
            o, *_ = e.step(actions)
            frames.append(np.stack([o[a] for a in e.possible_agents]))
        return np.stack(frames)

    a, b = replay(env), replay(real())
    assert np.array_equal(a[0], np.stack([obs[x] for x in ("Alpha", "Bravo")]))  # starts where it was taken
    assert np.array_equal(a, b)  # the snapshot is not changed by playing from it
    assert not np.array_equal(a[0], a[-1])


def test_engine_state_errors(real):
    env = real()
    with pytest.raises(RuntimeError, match="reset"):
        env.engine_state()
    three = real(num_players=3)
    three.reset(seed=0)
    with pytest.raises(ValueError, match="players"):
        env.reset(options={"engine_state": three.engine_state()})
    with pytest.raises(TypeError, match="EngineState"):
        env.reset(options={"engine_state": {"world": 1}})


def test_a_step_of_k_ticks_equals_k_single_ticks(real):
    k = 4
    script = [{"Alpha": act(7.0, forward=1, sprint=1), "Bravo": act(-5.0, left=1, use=1)},
              {"Alpha": act(0.0, jump=1, back=1), "Bravo": act(3.0, forward=1)}]
    multi = real(ticks_per_step=k)
    single = real()
    multi.reset(seed=3)
    single.reset(seed=3)
    for actions in script:
        obs_k, *_ , infos_k = multi.step(actions)
        assert multi.step_frames().shape == (2, k, 36, 36, 3)
        per_agent = {a: step_ticks(x, k)[0] for a, x in actions.items()}  # every turn fits: nothing pending
        frames = []
        for t in range(k):
            obs_1, *_ , infos_1 = single.step({a: ticks[t] for a, ticks in per_agent.items()})
            frames.append(single.step_frames()[:, 0])
        assert np.array_equal(multi.step_frames(), np.stack(frames, axis=1))
        for a in multi.possible_agents:
            assert np.array_equal(obs_k[a], obs_1[a])
            assert np.allclose(infos_k[a]["pos"], infos_1[a]["pos"]) and infos_k[a]["yaw"] == infos_1[a]["yaw"]
    assert multi.game.tick == single.game.tick == k * len(script)
    assert multi.metadata["render_fps"] == 20 / k and single.metadata["render_fps"] == 20


def test_ticks_per_step_must_be_positive(real):
    with pytest.raises(ValueError, match="ticks_per_step"):
        real(ticks_per_step=0)
