"""``solaris_env.wrappers``: single-agent Gymnasium envs (registered ids, Gymnasium and SB3 env checkers), action
flattening, opponents, resize / frame-stack on the parallel envs (PettingZoo's API and seed tests on the wrapped env),
and the mp4 and Rerun recorders."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from pettingzoo.test import parallel_api_test, parallel_seed_test

import solaris_env
from solaris_env.spaces import noop
from solaris_env.wrappers.actions import FlatActions
from solaris_env.wrappers.observations import ResizeFrames, StackFrames
from solaris_env.wrappers.opponents import (
    PolicyOpponent,
    ScriptedBotOpponent,
    make_opponent,
)
from solaris_env.wrappers.rerun_log import RerunRecorder
from solaris_env.wrappers.single_agent import SingleAgentEnv
from solaris_env.wrappers.video import RecordVideo


def dream_single(model, **kw):
    kw.setdefault("max_steps", 10)
    return gym.make("solaris_env/Dream-v0", model=model, **kw)


def real_single(**kw):
    kw.setdefault("resolution", 36)
    kw.setdefault("view_distance", 24.0)
    kw.setdefault("max_steps", 30)
    return gym.make("solaris_env/Real-v0", **kw)


def test_registered_ids_make_single_agent_envs(model):
    env = dream_single(model)
    assert isinstance(env.unwrapped, SingleAgentEnv) and env.unwrapped.agent == "Alpha"
    obs, info = env.reset(seed=0)
    assert obs.shape == (32, 32, 3) and info["start"] == "bundled"
    obs, reward, term, trunc, info = env.step(noop())
    assert obs.shape == (32, 32, 3) and reward == 0.0 and not term and not trunc
    assert info["frames"].shape[0] == 4 and set(info["others"]) == {"Bravo"}
    real = real_single()
    obs, _ = real.reset(seed=0)
    assert obs.shape == (36, 36, 3)
    assert isinstance(real.unwrapped.opponents["Bravo"], ScriptedBotOpponent)


def test_gymnasium_check_env_dream_and_real_with_default_arguments_on_a_headless_machine(model, monkeypatch):
    """check_env tries every render mode the env lists: a machine without a display lists only rgb_array."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gymnasium warns about 32x32 frames being small for CNNs
        for env in (dream_single(model), real_single()):
            assert env.unwrapped.metadata["render_modes"] == ["rgb_array"]
            gym_check_env(env.unwrapped)
    with pytest.raises(RuntimeError, match="no display"):
        dream_single(model, render_mode="human")


@pytest.mark.parametrize("kind", ["multidiscrete", "box"])
def test_sb3_check_env_on_flattened_actions(model, kind):
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    for env in (dream_single(model, flatten=kind), real_single(flatten=kind, resize=40)):
        assert isinstance(env.action_space, gym.spaces.MultiDiscrete if kind == "multidiscrete" else gym.spaces.Box)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sb3_check_env(env, warn=False)


def test_flat_actions_decode_to_env_actions(model):
    env = dream_single(model, flatten="multidiscrete", camera_bins=5, camera_max_deg=20.0)
    flat = env.get_wrapper_attr("codec")
    action = np.zeros(25, np.int64)
    action[0] = 1  # forward
    action[-2:] = [4, 0]  # camera: +20 deg pitch, -20 deg yaw
    decoded = flat.decode(action)
    assert decoded["forward"] == 1 and decoded["camera"].tolist() == [20.0, -20.0]
    env.reset(seed=0)
    env.step(action)
    bad = action.copy()
    bad[24] = 7  # camera yaw bin beyond the 5 bins
    with pytest.raises(ValueError, match="entry 24"):
        env.step(bad)
    assert FlatActions(SingleAgentEnv(solaris_env.DreamParallelEnv(model=model)), kind="box").action_space.shape == (25,)


def test_scripted_bot_opponent_acts_in_the_real_env_and_refuses_the_dream(model):
    env = real_single(max_steps=100)
    env.reset(seed=3)
    game = env.unwrapped.env.game
    alpha0, bravo0, yaw0 = game.players[0].pos.copy(), game.players[1].pos.copy(), game.players[1].yaw
    for _ in range(80):
        env.step(noop())
    alpha, bravo = game.players
    assert np.array_equal(alpha.pos, alpha0)  # the learner sent no-ops
    assert np.linalg.norm(bravo.pos - bravo0) > 0.5 or abs(bravo.yaw - yaw0) > 0.1  # the bot walked or turned
    dream = dream_single(model, opponent="bot")
    with pytest.raises(ValueError, match="real env"):
        dream.reset(seed=0)


def test_opponent_kinds():
    still = make_opponent("noop").act(None)
    assert not any(still[k] for k in still if k != "camera") and not still["camera"].any()
    random = make_opponent("random")
    random.reset(None, "Bravo", 1)
    a = random.act(None)
    assert np.abs(a["camera"]).max() <= 10.0
    frozen = make_opponent(lambda obs: {**noop(), "jump": 1})
    assert isinstance(frozen, PolicyOpponent) and frozen.act(None)["jump"] == 1
    with pytest.raises(ValueError, match="unknown opponent"):
        make_opponent("ghost")
    with pytest.raises(TypeError, match="opponent"):
        make_opponent(3)


def test_parallel_api_test_on_resized_and_stacked_frames(dream):
    parallel_api_test(StackFrames(ResizeFrames(dream(max_steps=5), 36), 2), num_cycles=10)


def test_parallel_seed_test_on_resized_and_stacked_frames(dream):
    parallel_seed_test(lambda: StackFrames(ResizeFrames(dream(max_steps=5), 36), 2))


def test_resize_and_stack_frames(dream, real):
    env = StackFrames(ResizeFrames(real(), (40, 48)), 3)
    assert env.observation_space("Alpha").shape == (40, 48, 9)
    obs, _ = env.reset(seed=0)
    assert obs["Alpha"].shape == (40, 48, 9) and np.array_equal(obs["Alpha"][..., :3], obs["Alpha"][..., 6:])
    turn = noop()
    turn["camera"] = np.array([0.0, 40.0], np.float32)
    obs2, *_ = env.step({"Alpha": turn, "Bravo": noop()})
    assert np.array_equal(obs2["Alpha"][..., :6], obs["Alpha"][..., 3:])  # shifted by one frame
    assert not np.array_equal(obs2["Alpha"][..., 6:], obs["Alpha"][..., 6:])
    with pytest.raises(ValueError, match="n must be"):
        StackFrames(real(), 0)
    with pytest.raises(ValueError, match="size"):
        ResizeFrames(real(), (0, 4))


def test_record_video_writes_every_frame_of_every_player(dream, tmp_path):
    import cv2

    env = RecordVideo(dream(max_steps=3), tmp_path, name_prefix="dream")
    env.reset(seed=0)
    for _ in range(3):
        env.step({a: noop() for a in env.agents})
    assert env.paths == [tmp_path / "dream-episode-0.mp4"]
    cap = cv2.VideoCapture(str(env.paths[0]))
    n, w, h = (int(cap.get(p)) for p in (cv2.CAP_PROP_FRAME_COUNT, cv2.CAP_PROP_FRAME_WIDTH,
                                          cv2.CAP_PROP_FRAME_HEIGHT))
    cap.release()
    assert (n, w, h) == (1 + 3 * 4, 2 * 32, 32)
    assert not list(tmp_path.glob(".*tmp*"))


def test_rerun_recorder_logs_views_actions_and_rewards(real, tmp_path):
    from rerun.chunk import RrdReader

    path = tmp_path / "run.rrd"
    env = RerunRecorder(real(task="visual_novelty"), path=path)
    env.reset(seed=0)
    for _ in range(3):
        env.step({a: noop() for a in env.agents})
    env.close()
    assert path.exists() and not list(tmp_path.glob(".*tmp*"))
    entities, timelines = set(), set()
    for chunk in RrdReader(path).stream():
        entities.add(str(chunk.entity_path))
        timelines |= set(chunk.timeline_names)
    for agent in ("Alpha", "Bravo"):
        for leaf in ("view", "reward", "return", "action/forward", "action/camera/yaw"):
            assert f"/players/{agent}/{leaf}" in entities
    assert {"tick", "step", "episode"} <= timelines
    with pytest.raises(ValueError, match="exactly one"):
        RerunRecorder(real())
