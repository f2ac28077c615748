"""RealParallelEnv engine states and tasks; the task API on its own (visual novelty, ground truth, registry)."""

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from solaris_env.real_env import EngineState
from solaris_env.spaces import noop
from solaris_env.tasks import NoTask, SeeOtherPlayerTask, VisualNoveltyTask, make_task


def turn(dyaw_deg: float, **keys) -> dict:
    a = noop()
    a["camera"] = np.array([0.0, dyaw_deg], np.float32)
    a.update(keys)
    return a


def test_engine_state_round_trip_then_identical_futures(real):
    env = real()
    env.reset(seed=4)
    for t in range(10):
        obs, *_ = env.step({"Alpha": turn(3.0, forward=1), "Bravo": turn(-2.0, jump=int(t % 3 == 0))})
    state = env.engine_state()
    assert isinstance(state, EngineState) and state.player_names == ["Alpha", "Bravo"] and state.tick == 10
    script = [{"Alpha": turn(5.0, forward=1, sprint=1), "Bravo": turn(-4.0, left=1)} for _ in range(15)]

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


def test_parallel_api_test_1000_cycles_with_a_task(real):
    parallel_api_test(real(max_steps=500, task="visual_novelty"), num_cycles=1000)


def test_see_other_player_task_uses_ground_truth(real):
    env = real(resolution=64, view_distance=48.0, task="see_other_player")
    env.reset(seed=0)  # spawned facing each other
    _, rewards, *_ = env.step({a: noop() for a in env.agents})
    assert rewards == {"Alpha": 1.0, "Bravo": 1.0}
    for _ in range(6):  # Alpha turns 180 degrees away (at 8.59 deg per tick: the rest is carried over)
        _, rewards, _, _, infos = env.step({"Alpha": turn(30.0), "Bravo": noop()})
    while infos["Alpha"]["camera_pending"].any():
        _, rewards, _, _, infos = env.step({"Alpha": noop(), "Bravo": noop()})
    assert rewards == {"Alpha": 0.0, "Bravo": 1.0}
    assert infos["Alpha"]["sees"] == {"Bravo": False}


def test_visual_novelty_rewards_new_views_only(real):
    # a hilly world with trees: a flat world looks the same in every direction (distances < 0.02)
    # 4 ticks a step: a 30 deg turn fits in one step (at most 8.59 deg a tick; spaces.CAMERA_TICK_LIMIT_DEG)
    env = real(resolution=64, view_distance=48.0, world="normal", task="visual_novelty", ticks_per_step=4)
    env.reset(seed=1)
    _, rewards, *_ = env.step({a: noop() for a in env.agents})
    assert rewards == {"Alpha": 0.0, "Bravo": 0.0}  # nothing moved: the same view
    gained = []
    for _ in range(6):  # Alpha turns to new directions
        _, rewards, *_ = env.step({"Alpha": turn(30.0), "Bravo": noop()})
        gained.append(rewards["Alpha"])
        assert rewards["Bravo"] == 0.0
    assert sum(r > 0 for r in gained) >= 4
    back = []
    for _ in range(6):  # and back over views it has seen
        _, rewards, *_ = env.step({"Alpha": turn(-30.0), "Bravo": noop()})
        back.append(rewards["Alpha"])
    assert sum(back) < 0.25 * sum(gained)


def test_visual_novelty_target_terminates_and_memory_is_a_ring():
    task = VisualNoveltyTask(threshold=0.01, memory=3, target=2)
    rng = np.random.default_rng(0)
    task.reset(np.zeros((2, 16, 16, 3), np.uint8))
    frames = rng.integers(0, 256, (2, 1, 16, 16, 3), dtype=np.uint8)
    out = task.step(frames, [noop(), noop()])
    assert (out.rewards_P > 0).all() and not out.terminations_P.any()
    out = task.step(frames, [noop(), noop()])  # the same view again: nothing new
    assert (out.rewards_P == 0).all()
    out = task.step(rng.integers(0, 256, (2, 1, 16, 16, 3), dtype=np.uint8), [noop(), noop()])
    assert out.terminations_P.all()
    for _ in range(3):
        task.step(rng.integers(0, 256, (2, 1, 16, 16, 3), dtype=np.uint8), [noop(), noop()])
    assert task.distance_to_memory(np.zeros((2, 8, 8, 3), np.float32)).min() > 0.01  # black view forgotten


def test_task_registry_and_errors():
    assert isinstance(make_task(None), NoTask) and isinstance(make_task("visual_novelty"), VisualNoveltyTask)
    assert isinstance(make_task(SeeOtherPlayerTask), SeeOtherPlayerTask)
    given = VisualNoveltyTask(threshold=0.1)
    copy = make_task(given)
    assert copy is not given and copy.threshold == 0.1
    with pytest.raises(ValueError, match="unknown task"):
        make_task("win")
    with pytest.raises(ValueError, match="task must be"):
        make_task(3)
    with pytest.raises(ValueError, match="threshold"):
        VisualNoveltyTask(threshold=1.5)
    with pytest.raises(ValueError, match="ground truth"):
        SeeOtherPlayerTask().step(np.zeros((2, 1, 8, 8, 3), np.uint8), [noop(), noop()], truth=None)
