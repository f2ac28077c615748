"""A camera action means the same turn in the dream and in the engine, and nothing is clipped: a step's turn is
spread over its k ticks at up to ``CAMERA_TICK_LIMIT_DEG`` (the training data's per-tick range) and what does not
fit is carried over to the next steps (``spaces.step_ticks``), in ``DreamParallelEnv``, ``DreamVectorEnv`` and
``RealParallelEnv(ticks_per_step=k)``."""

import math

import numpy as np
import pytest

from solaris_env.spaces import (
    CAMERA_CLIP_DEG,
    CAMERA_SCALE_DEG,
    CAMERA_TICK_LIMIT_DEG,
    CAMERA_X_INDEX,
    CAMERA_Y_INDEX,
    noop,
    step_ticks,
)

LIMIT = CAMERA_TICK_LIMIT_DEG


def turn(dyaw: float = 0.0, dpitch: float = 0.0) -> dict:
    a = noop()
    a["camera"] = np.array([dpitch, dyaw], np.float32)
    return a


def test_the_per_tick_limit_is_the_bots_look_speed_and_within_the_models_input_clip():
    from solaris_env.engine.bots.controller import MAX_TURN_RAD

    assert LIMIT == pytest.approx(math.degrees(MAX_TURN_RAD)) and LIMIT < CAMERA_CLIP_DEG


@pytest.mark.parametrize("yaw", [20.0, 21.0, 45.0, 90.0, 180.0, -180.0, -20.0])
@pytest.mark.parametrize("k", [1, 4])
def test_step_ticks_turns_the_whole_action_over_steps_never_faster_than_the_trained_rate(yaw, k):
    pending, turned, steps = None, [], 0
    ticks, pending = step_ticks(turn(yaw, dpitch=-yaw / 4), k)
    while True:
        turned += [t["camera"] for t in ticks]
        steps += 1
        if not pending.any():
            break
        ticks, pending = step_ticks(noop(), k, pending)
    turned = np.array(turned, np.float64)
    assert np.abs(turned).max() <= np.float32(LIMIT)
    np.testing.assert_allclose(turned.sum(0), [-yaw / 4, yaw], atol=1e-4)
    assert steps == math.ceil(abs(yaw) / (k * LIMIT) - 1e-9)


def test_carried_turn_comes_before_the_next_steps_own_turn():
    _, pending = step_ticks(turn(100.0), 4)  # 100 - 4 * 8.59 = 65.6 left
    ticks, pending = step_ticks(turn(-10.0), 4, pending)  # 55.6 to go: all four ticks at the limit
    assert [t["camera"][1] for t in ticks] == [np.float32(LIMIT)] * 4
    assert pending[1] == pytest.approx(100.0 - 10.0 - 8 * LIMIT, abs=1e-4)
    with pytest.raises(ValueError, match="pending_deg"):
        step_ticks(noop(), 4, [math.nan, 0.0])


def model_ticks(model, monkeypatch) -> list:
    """Record the (B, P, k, 25) model ticks of every ``model.step`` call."""
    calls = []
    step = model.step

    def recording(state, ticks):
        calls.append(np.array(ticks))
        return step(state, ticks)

    monkeypatch.setattr(model, "step", recording)
    return calls


def engine_ticks(env) -> list:
    """Record the per-tick env actions the engine game of ``env`` (after reset) is stepped with."""
    calls = []
    step = env.game.step

    def recording(actions):
        calls.append([dict(a, camera=np.array(a["camera"])) for a in actions])
        return step(actions)

    env.game.step = recording
    return calls


@pytest.mark.parametrize("yaw,pitch", [(90.0, 0.0), (-180.0, 30.0), (21.0, -45.0)])
def test_a_large_turn_means_the_same_in_the_dream_and_the_engine(dream, real, model, monkeypatch, yaw, pitch):
    k = model.frames_per_step
    d, r = dream(), real(ticks_per_step=k)
    d.reset(seed=0)
    r.reset(seed=0)
    sent = model_ticks(model, monkeypatch)
    played = engine_ticks(r)
    yaw0 = r.game.players[0].yaw
    script = [{"Alpha": turn(yaw, pitch), "Bravo": turn(-yaw / 2)}] + [{"Alpha": noop(), "Bravo": noop()}] * 6
    for actions in script:
        *_, infos_d = d.step(actions)
        *_, infos_r = r.step(actions)
        for a in d.possible_agents:  # the same turn still to make after every step
            np.testing.assert_allclose(infos_d[a]["camera_pending"], infos_r[a]["camera_pending"], atol=1e-6)
    # the dream's model ticks (Mineflayer signs, CAMERA_SCALE_DEG units) are the engine's ticks (MineRL degrees)
    dream_deg = np.concatenate([c[0][:, :, [CAMERA_Y_INDEX, CAMERA_X_INDEX]] for c in sent], axis=1) * -CAMERA_SCALE_DEG
    engine_deg = np.stack([[p["camera"] for p in tick] for tick in played], axis=1)  # (P, ticks, 2)
    np.testing.assert_allclose(dream_deg, engine_deg, atol=1e-4)
    np.testing.assert_allclose(engine_deg.sum(1), [[pitch, yaw], [0.0, -yaw / 2]], atol=1e-3)
    assert np.abs(engine_deg).max() <= np.float32(LIMIT)
    turned = math.degrees(yaw0 - r.game.players[0].yaw)  # Mineflayer yaw: + = left
    assert (turned - yaw + 180) % 360 - 180 == pytest.approx(0.0, abs=1e-3)


def test_turns_beyond_20_degrees_reach_the_model_in_full(dream, model, monkeypatch):
    """Before: 21, 45, 90 and 180 deg gave the model exactly what 20 deg gave (camera_linear's clip)."""
    env = dream()
    sent = model_ticks(model, monkeypatch)
    totals = {}
    for yaw in (20.0, 21.0, 45.0, 90.0, 180.0, -20.0, -180.0):
        env.reset(seed=0)
        sent.clear()
        env.step({"Alpha": turn(yaw), "Bravo": noop()})
        while env.step({"Alpha": noop(), "Bravo": noop()})[4]["Alpha"]["camera_pending"].any():
            pass
        totals[yaw] = -sum(c[0, 0, :, CAMERA_X_INDEX].sum() for c in sent) * CAMERA_SCALE_DEG
    for yaw, total in totals.items():
        assert total == pytest.approx(yaw, abs=1e-3)


def test_reset_clears_the_carried_turn(dream, real, vector):
    for env in (dream(), real(ticks_per_step=4)):
        env.reset(seed=0)
        *_, infos = env.step({"Alpha": turn(180.0), "Bravo": turn(dpitch=-90.0)})
        assert infos["Alpha"]["camera_pending"][1] > 100 and infos["Bravo"]["camera_pending"][0] < -50
        _, infos = env.reset(seed=0)
        assert not infos["Alpha"]["camera_pending"].any() and not infos["Bravo"]["camera_pending"].any()
    fresh, used = dream(), dream()
    fresh.reset(seed=0)
    used.reset(seed=0)
    used.step({"Alpha": turn(180.0), "Bravo": noop()})
    used.reset(seed=0)
    noops = {"Alpha": noop(), "Bravo": noop()}
    a, b = fresh.step(noops)[0], used.step(noops)[0]
    assert all(np.array_equal(a[x], b[x]) for x in a)
    venv = vector()
    venv.reset(seed=0)
    big = [{"Alpha": turn(180.0), "Bravo": noop()}, {"Alpha": noop(), "Bravo": turn(-90.0)}]
    *_, infos = venv.step(big)
    assert infos["camera_pending"][0, 0, 1] > 100 and infos["camera_pending"][1, 1, 1] < -50
    venv.reset(options={"reset_mask": np.array([True, False])})
    *_, infos = venv.step([{"Alpha": noop(), "Bravo": noop()}] * 2)
    assert not infos["camera_pending"][0].any() and infos["camera_pending"][1, 1, 1] < -20
