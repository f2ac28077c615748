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


def _panning(seed: int, steps: int, k: int, shift: int) -> np.ndarray:
    """(1, 1 + steps*k, 1, 32, 32, 3): a random blocky texture panned ``shift`` pixels left per frame."""
    rng = np.random.default_rng(seed)
    wide = np.kron(rng.integers(0, 256, (8, 40 + steps * k), dtype=np.uint8), np.ones((4, 4), np.uint8))
    frames = np.stack([wide[:, s * shift: s * shift + 32] for s in range(1 + steps * k)])
    return np.repeat(frames[None, :, None, :, :, None], 3, axis=-1)


def test_direction_by_rollout_scores_the_truth_one_a_frozen_rollout_zero_and_a_reversed_one_negative():
    from training.evaluate import direction_by_rollout

    truth = _panning(0, steps=4, k=2, shift=1)  # a steady pan: the camera turns
    frozen = np.repeat(truth[:, :1], truth.shape[1], axis=1)
    reversed_ = truth[:, ::-1]
    out = direction_by_rollout(truth, {"truth": (truth, truth), "frozen": (frozen, frozen),
                                       "reversed": (reversed_, reversed_),
                                       "one_step_from_truth": (truth, truth)}, k=2)
    assert out["direction_valid_steps"] == 4
    assert out["direction_agreement_truth"] == 1.0 and out["direction_agreement_one_step_from_truth"] == 1.0
    assert out["direction_agreement_frozen"] == 0.0
    assert out["direction_agreement_reversed"] < -0.5
