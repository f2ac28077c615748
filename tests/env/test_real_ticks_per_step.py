"""RealParallelEnv(ticks_per_step=k): one step plays k engine ticks as the dream env does (the whole action on the
first tick, then only the held movement keys; the camera turn spread over the ticks), renders every tick, and scores
the task once."""

import numpy as np
import pytest

from solaris_env.spaces import CAMERA_TICK_LIMIT_DEG, ONCE_KEYS, noop, step_ticks


def act(dyaw: float = 0.0, **keys) -> dict:
    a = noop()
    a["camera"] = np.array([0.0, dyaw], np.float32)
    a.update(keys)
    return a


def test_step_ticks_hold_movement_send_once_keys_once_and_spread_the_camera():
    ticks, pending = step_ticks(act(12.0, forward=1, jump=1, attack=1, **{"hotbar.2": 1}), 4)
    assert len(ticks) == 4 and ticks[0]["attack"] == 1 and np.array_equal(pending, [0.0, 0.0])
    yaw = [t["camera"][1] for t in ticks]  # at most CAMERA_TICK_LIMIT_DEG a tick, from the first tick on
    assert yaw[0] == np.float32(CAMERA_TICK_LIMIT_DEG) and yaw[2:] == [0.0, 0.0]
    assert yaw[1] == pytest.approx(12.0 - CAMERA_TICK_LIMIT_DEG, abs=1e-5)
    for t in ticks[1:]:
        assert t["forward"] == 1 and t["jump"] == 1 and t["attack"] == 1  # held: digging needs every tick
        assert all(t[k] == 0 for k in ONCE_KEYS)
    with pytest.raises(ValueError, match="ticks per step"):
        step_ticks(noop(), 0)
    ticks, pending = step_ticks(act(40.0), 4)  # 40 deg does not fit in 4 ticks: the rest is carried, never dropped
    assert all(t["camera"][1] == np.float32(CAMERA_TICK_LIMIT_DEG) for t in ticks)
    assert pending[1] == pytest.approx(40.0 - 4 * CAMERA_TICK_LIMIT_DEG, abs=1e-5)


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
