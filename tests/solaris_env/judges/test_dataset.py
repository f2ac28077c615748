"""``judges.dataset``: featureless frames and the examples made of them (their answer, their share, their bank
rows), and that they leave the real examples as they were."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from solaris_env.judges import questions
from solaris_env.judges.config import JudgeConfig, TrainConfig
from solaris_env.judges.dataset import (
    FEATURELESS_ANSWER,
    FEATURELESS_KINDS,
    build,
    featureless,
)
from solaris_env.judges.episodes import find_episodes


def _frame(seed=0, size=64):
    rng = np.random.default_rng(seed)
    x = rng.integers(0, 256, (size, size, 3), dtype=np.uint8)
    x[20:40, 28:36] = (200, 30, 30)  # a "player"
    return x


def _sharpness(x):
    return float(np.abs(cv2.Laplacian(x.astype(np.float32), cv2.CV_32F)).mean())


def test_featureless_kinds_remove_the_content():
    x, rng = _frame(), np.random.default_rng(0)
    flat = featureless(x, "flat", rng)
    assert flat.dtype == np.uint8 and flat.shape == x.shape
    assert (flat == flat[0, 0]).all() and np.abs(flat[0, 0] - x.reshape(-1, 3).mean(0)).max() <= 0.5
    rows = featureless(x, "rows", rng)
    assert (rows == rows[:, :1]).all() and not (rows == rows[:1]).all()
    columns = featureless(x, "columns", rng)
    assert (columns == columns[:1]).all() and not (columns == columns[:, :1]).all()
    blur = featureless(x, "blur", rng)
    assert _sharpness(blur) < 0.05 * _sharpness(x)
    assert np.abs(blur.astype(float).mean((0, 1)) - x.mean((0, 1))).max() < 3  # the frame's colours stay
    with pytest.raises(ValueError, match="kind must be one of"):
        featureless(x, "noise", rng)


def test_every_question_has_a_featureless_answer():
    assert set(FEATURELESS_ANSWER) == set(questions.QUESTIONS)
    for name, answer in FEATURELESS_ANSWER.items():
        questions.get(name).index(answer)
    assert FEATURELESS_KINDS == ("flat", "rows", "columns", "blur")


def test_build_adds_featureless_examples_and_keeps_the_real_ones(collected):
    episodes = find_episodes(collected)
    base = JudgeConfig(train=replace(TrainConfig(), featureless_fraction=0.0))
    cfg = JudgeConfig(train=replace(TrainConfig(), featureless_fraction=0.1))
    bank0, ex0 = build(episodes, base, seed=3)
    bank, ex = build(episodes, cfg, seed=3)
    n_real = len(bank0.frames_NHW3)
    assert np.array_equal(bank.frames_NHW3[:n_real], bank0.frames_NHW3)
    assert bank.where[n_real:] == [(-1, "featureless", -1)] * (len(bank.where) - n_real)
    for name in questions.QUESTIONS:
        q, real = questions.get(name), ex[name].episode_N >= 0
        assert np.array_equal(ex[name].index_NF[real], ex0[name].index_NF)
        assert np.array_equal(ex[name].label_N[real], ex0[name].label_N)
        fake = ~real
        assert fake.sum() == round(0.1 * len(ex0[name])) > 0
        assert (ex[name].label_N[fake] == q.index(FEATURELESS_ANSWER[name])).all()
        made_up = ex[name].index_NF[fake] >= n_real
        if name == "same_scenery":  # one or both views
            assert made_up.any(axis=1).all() and made_up.all(axis=1).any() and not made_up.all()
        else:
            assert made_up.all()
    with pytest.raises(ValueError, match="featureless_fraction must be in"):
        TrainConfig(featureless_fraction=1.5)


def test_motion_has_still_pairs_labelled_no_motion(collected):
    episodes = find_episodes(collected)
    cfg = JudgeConfig(train=replace(TrainConfig(), featureless_fraction=0.0, still_pair_prob=1.0))
    _, ex = build(episodes, cfg, seed=0, wanted=["motion"])
    m = ex["motion"]
    still = m.index_NF[:, 0] == m.index_NF[:, 1]
    assert still.sum() > 10
    assert (m.label_N[still] == questions.get("motion").index("no motion")).all()
    _, ex0 = build(episodes, JudgeConfig(train=replace(cfg.train, still_pair_prob=0.0)), seed=0, wanted=["motion"])
    assert not (ex0["motion"].index_NF[:, 0] == ex0["motion"].index_NF[:, 1]).any()
