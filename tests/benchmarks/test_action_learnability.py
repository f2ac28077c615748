"""``benchmarks.action_learnability``: the synthetic clips move exactly as their actions say, and a short run on
the test preset scores every variant."""

import json

import numpy as np
import pytest

from benchmarks import action_learnability as AL
from solaris_env.world_model.config import WorldModelConfig


def test_synthetic_clips_shift_by_the_action_of_their_frame():
    cfg = WorldModelConfig.tiny()
    x0, act, shifts = AL.synthetic_clips(np.random.default_rng(0), cfg, 3, 5, yaw=0.5, sigma=1.0)
    k = cfg.frames_per_step
    assert x0.shape == (3, cfg.num_players, 5, cfg.latent_height, cfg.latent_width, cfg.latent_channels)
    assert act.shape == (3, k * 4 + 1, cfg.num_players, 25)
    assert np.all(act[:, 0] == 0) and np.all(act[..., :23] == 0) and np.all(act[..., 24] == 0)
    np.testing.assert_allclose(x0[:, :, 0].std(axis=(2, 3, 4)), 1.0, rtol=1e-4)
    for b in range(3):
        for p in range(cfg.num_players):
            for f in range(1, 5):
                np.testing.assert_array_equal(x0[b, p, f], np.roll(x0[b, p, f - 1], shifts[b, p, f], axis=1))
                np.testing.assert_array_equal(act[b, k * (f - 1) + 1:k * f + 1, p, 23], 0.5 * shifts[b, p, f])
    assert set(np.unique(shifts[:, :, 1:])) == {-1, 0, 1}


def test_short_run_scores_every_variant(tmp_path):
    out = tmp_path / "a.json"
    result = AL.main(["--preset", "test", "--steps", "2", "--batch", "2", "--latent-frames", "3", "--eval-every", "1",
                      "--out", str(out)])
    assert [r["variant"] for r in json.loads(out.read_text())["runs"]] == list(AL.VARIANTS)
    for run in result["runs"]:
        assert [row["step"] for row in run["curve"]] == [1, 2]
        f = run["final"]
        assert f["action_gain"] == pytest.approx(f["loss_negated"] / f["loss_true"] - 1.0)
        assert all(np.isfinite(f[k]) and f[k] > 0 for k in ("loss_true", "loss_negated", "loss_zeroed"))


def test_variants_fix_both_settings_whatever_the_preset():
    """Every variant sets the mouse gain itself, whatever the preset's own: with the tiny preset's gain of 10, an
    empty "official" override would train at gain 10."""
    for name, override in AL.VARIANTS.items():
        assert set(override) == {"mouse_input_gain"}, name
    assert AL.VARIANTS["official"] == {"mouse_input_gain": 1.0}


def test_bad_sizes_are_refused(tmp_path):
    with pytest.raises(ValueError, match="latent-frames"):
        AL.main(["--preset", "test", "--latent-frames", "1", "--out", str(tmp_path / "x.json")])
