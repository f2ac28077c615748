"""agents.policies: the spec registry, seeding, and scripted seekers that really find the partner in the engine."""

import numpy as np
import pytest

from agents.policies import (
    EngineSeekerBot,
    JudgeSeekerPolicy,
    PPOPolicy,
    RandomPolicy,
    SpinPolicy,
    make_policy,
)
from agents.rollouts import run_episode
from solaris_env.spaces import validate_action


def test_make_policy_specs_and_errors():
    assert isinstance(make_policy("random"), RandomPolicy) and make_policy("random").name == "random"
    seeker = make_policy("seeker-walk:0.25")
    assert isinstance(seeker, JudgeSeekerPolicy) and seeker.noise == 0.25 and seeker.walk
    assert seeker.name == "seeker-walk:0.25"
    assert isinstance(make_policy("bot:0"), EngineSeekerBot) and make_policy("bot:0").needs_engine
    assert make_policy("spin:12").deg == 12.0 and isinstance(make_policy("spin"), SpinPolicy)
    with pytest.raises(ValueError, match="unknown policy 'dance'"):
        make_policy("dance")
    with pytest.raises(ValueError, match="ppo:PATH"):
        make_policy("ppo")
    with pytest.raises(ValueError, match="seeker:2.*noise"):
        make_policy("seeker:2")
    with pytest.raises(ValueError, match="20"):
        SpinPolicy(45.0)  # more than the world model's per-tick camera clip
    with pytest.raises(FileNotFoundError, match="sidecar"):
        PPOPolicy("/nonexistent/step_000000001.zip")


def test_random_policy_is_seeded_and_keeps_the_camera_small():
    a, b = RandomPolicy(), RandomPolicy()
    a.reset(None, "Alpha", 3)
    b.reset(None, "Alpha", 3)
    for _ in range(20):
        x, y = a.act(np.zeros((8, 8, 3), np.uint8)), b.act(np.zeros((8, 8, 3), np.uint8))
        validate_action(x)
        assert all(np.array_equal(x[k], y[k]) for k in x) and np.abs(x["camera"]).max() <= 10.0


def test_engine_bot_refuses_the_dream(model):
    from solaris_env.dream_env import DreamParallelEnv

    with pytest.raises(ValueError, match="RealParallelEnv"):
        EngineSeekerBot().reset(DreamParallelEnv(model=model), "Alpha", 0)


def test_seekers_find_the_partner_and_beat_random(real, start_states):
    """From start states where Alpha was turned away, the scripted seekers (ground truth and judge) end up facing
    the partner most of the time; random rarely does."""
    env = real(task="face_partner_truth", ticks_per_step=4, max_steps=30)

    def mean_return(spec):
        return np.mean([run_episode(env, make_policy(spec), s, seed=i).env_return for i, s in enumerate(start_states)])

    bot, random = mean_return("bot:0"), mean_return("random")
    assert bot >= 15 and random < 0.5 * bot, (bot, random)
    assert mean_return("bot:1") < 0.5 * bot  # noise 1 is the random policy


def test_judge_seeker_finds_the_partner_at_the_judges_resolution(real, start_states):
    """Reading only its 64x64 frames through the judges, the seeker turns to the partner and stays on it. (On the
    red-sand flat variant the shipped judges see a partner "right" in every view: those starts are left out.)"""
    from solaris_env.judges.config import ProbeConfig

    env = real(resolution=ProbeConfig().image_size, task="face_partner_truth", ticks_per_step=4, max_steps=30)
    usable = [s for s in start_states if s.game().world.variant != "desert_red"]
    assert len(usable) >= 2
    returns = [run_episode(env, make_policy("seeker:0"), s, seed=i).env_return for i, s in enumerate(usable[:2])]
    assert min(returns) >= 8, returns


def test_frames_png_lays_engine_over_dream_rows(tmp_path):
    """The policy-eval contact sheet: per policy an engine row over a dream row, evenly spaced frames, first and
    last included; bad input names what is wrong."""
    import cv2

    from agents.plots import FRAME_SCALE, LABEL_WIDTH, frames_png

    def episode(value_of_step, steps):
        return [np.full((8, 8, 3), value_of_step(t), np.uint8) for t in range(steps + 1)]

    real = [episode(lambda t: 10 * t, 20)]
    dream = [episode(lambda t: 255 - 10 * t, 20)]
    path = frames_png(tmp_path / "sheet.png", ["seeker:0"], real, dream, columns=3)
    img = cv2.imread(str(path))
    assert img.shape == (2 * 8 * FRAME_SCALE, LABEL_WIDTH + 3 * 8 * FRAME_SCALE, 3)
    frames = img[:, LABEL_WIDTH:].reshape(2, 8 * FRAME_SCALE, 3, 8 * FRAME_SCALE, 3)[:, 0, :, 0, 0]
    assert frames.tolist() == [[0, 100, 200], [255, 155, 55]]  # steps 0, 10, 20 of each row
    with pytest.raises(ValueError, match="one real and one dream episode per policy"):
        frames_png(tmp_path / "x.png", ["a", "b"], real, dream)
    with pytest.raises(ValueError, match="columns must be an int >= 2"):
        frames_png(tmp_path / "x.png", ["a"], real, dream, columns=1)
    with pytest.raises(ValueError, match="one \\(H, W, 3\\) shape"):
        frames_png(tmp_path / "x.png", ["a"], real, [[np.zeros((4, 4, 3), np.uint8)]])
