"""Judge features (probe penultimate activations) and the Fréchet distance."""

import numpy as np
import pytest

from solaris_env.judges.features import FrameFeatures, frechet_distance, frechet_distance_stats, probe_penultimate
from solaris_env.judges.judge import DEFAULT_WEIGHTS
from solaris_env.judges.probe import load_probe


def test_frechet_distance_of_a_set_with_itself_is_zero_and_grows_with_a_shift():
    rng = np.random.default_rng(0)
    f = rng.normal(size=(500, 6))
    assert frechet_distance(f, f) == pytest.approx(0.0, abs=1e-8)
    assert frechet_distance(f, f + 1.0) == pytest.approx(6.0, rel=1e-6)  # mean shift of 1 on 6 axes
    assert frechet_distance(f, 2 * f) > frechet_distance(f, 1.1 * f) > 0


def test_frechet_distance_matches_the_closed_form_for_diagonal_gaussians():
    mu1, mu2 = np.array([0.0, 1.0]), np.array([2.0, -1.0])
    c1, c2 = np.diag([1.0, 4.0]), np.diag([9.0, 1.0])
    # |dmu|^2 + sum (sqrt(a) - sqrt(b))^2 for diagonal covariances
    expected = 8.0 + (1 - 3) ** 2 + (2 - 1) ** 2
    assert frechet_distance_stats(mu1, c1, mu2, c2) == pytest.approx(expected)
    singular = np.diag([1.0, 0.0])
    assert frechet_distance_stats(mu1, singular, mu1, singular) == pytest.approx(0.0, abs=1e-12)


def test_frechet_distance_rejects_bad_shapes():
    with pytest.raises(ValueError, match="width"):
        frechet_distance(np.zeros((4, 3)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="N >= 2"):
        frechet_distance(np.zeros((1, 3)), np.zeros((4, 3)))


def test_frame_features_are_the_probes_hidden_layer():
    feats = FrameFeatures.load()
    assert feats.names == ("visible", "position", "structure") and feats.dim == 192
    rng = np.random.default_rng(1)
    frames = rng.integers(0, 256, (5, 64, 64, 3), dtype=np.uint8)
    f = feats(frames)
    assert f.shape == (5, 192) and f.dtype == np.float64 and (f >= 0).all()
    # the "visible" block of the features feeds the probe's head: head(features) = the probe's logits
    _, visible, _ = load_probe(DEFAULT_WEIGHTS / "visible.safetensors")
    h = np.asarray(probe_penultimate(visible, frames))
    np.testing.assert_allclose(f[:, :64], h, rtol=1e-5, atol=1e-5)
    logits = np.asarray(visible.head(h))
    np.testing.assert_allclose(logits, np.asarray(visible(frames[:, None])), rtol=1e-4, atol=1e-4)
    # other sizes are resized; an empty batch gives an empty array
    assert feats(rng.integers(0, 256, (3, 32, 32, 3), dtype=np.uint8)).shape == (3, 192)
    assert feats(np.zeros((0, 64, 64, 3), np.uint8)).shape == (0, 192)
    with pytest.raises(ValueError, match="uint8"):
        feats(frames.astype(np.float32))
