"""The fade readout of ``training.evaluate`` on hand-made rollouts (the whole evaluation runs in test_pipeline)."""

import numpy as np

from training.evaluate import fade_by_step


def test_fade_by_step_scores_the_truth_as_one_and_a_flat_rollout_as_zero():
    truth = np.random.default_rng(0).integers(0, 256, (2, 9, 2, 16, 16, 3), dtype=np.uint8)  # 2 steps of k = 4
    fading = truth.copy()
    fading[:, 5:] = 100  # the second step's frames are flat
    out = fade_by_step(truth, {"same": truth, "flat": np.full_like(truth, 100), "fading": fading}, steps=2, k=4)
    assert out["sharpness_ratio_same_by_step"] == [1.0, 1.0] and out["sharpness_ratio_same"] == 1.0
    assert out["pixel_std_same_by_step"] == out["pixel_std_truth_by_step"]
    assert out["sharpness_ratio_flat_by_step"] == [0.0, 0.0] and out["pixel_std_flat_by_step"] == [0.0, 0.0]
    assert out["sharpness_ratio_fading_by_step"] == [1.0, 0.0] and out["pixel_std_fading_by_step"][1] == 0.0
    assert abs(out["sharpness_ratio_fading"] - 0.5) < 0.02  # half the frames keep their edges
