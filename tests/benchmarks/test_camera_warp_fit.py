"""The camera-warp fit on hand-made latents whose content moves by a known number of pixels per degree."""

import numpy as np

from benchmarks.camera_warp_fit import FRAME_SCAN, fit, latent_scan, shift_frames

LATENT_SCAN = latent_scan(8)


def _moving_field(per_degree: float, axis: int, seed: int = 0):
    """Smooth random 12x12x4 latents and their next frames: the content moved by per_degree * turn."""
    rng = np.random.default_rng(seed)
    coarse = rng.normal(size=(24, 4, 4, 4)).astype(np.float32)
    prev = np.kron(coarse, np.ones((1, 3, 3, 1), np.float32))  # (24, 12, 12, 4), blocky but interpolable
    turns = np.zeros((24, 2), np.float32)
    turns[:, 0 if axis == 1 else 1] = rng.choice([-1, 1], 24) * rng.uniform(8, 19, 24)  # yaw or pitch only
    shift = np.zeros((24, 2), np.float32)
    shift[:, axis] = per_degree * turns[:, 0 if axis == 1 else 1]
    return prev, shift_frames(prev, shift), turns


def test_fit_finds_the_true_scale_and_says_a_matched_warp_helps_and_a_reversed_one_does_not():
    prev, nxt, turns = _moving_field(0.05, axis=1)  # a yaw moves content right 0.05 px per degree
    out = fit(prev, nxt, turns, configured=(0.0, 0.05), scales=LATENT_SCAN)
    row = next(r for r in out["yaw"]["bins"] if r["frames"])
    assert row["frames"] == 24 and row["best_per_degree"] == 0.05
    assert row["mse_best"] < 1e-6 < row["mse_no_warp"] and row["configured_helps"]
    reversed_ = fit(prev, nxt, turns, configured=(0.0, -0.05), scales=LATENT_SCAN)
    assert not next(r for r in reversed_["yaw"]["bins"] if r["frames"])["configured_helps"]
    assert all(r["frames"] == 0 for r in out["pitch"]["bins"])  # no frame turns about the other axis


def test_fit_reads_pitch_as_a_downward_move():
    prev, nxt, turns = _moving_field(0.1, axis=0, seed=1)
    row = next(r for r in fit(prev, nxt, turns, configured=(0.1, 0.0), scales=LATENT_SCAN)["pitch"]["bins"]
               if r["frames"])
    assert row["best_per_degree"] == 0.1 and row["configured_helps"]


def test_the_scan_scales_with_the_latent_resolution():
    assert latent_scan(8)[0] == -0.06 and latent_scan(8)[-1] == 0.12 and 0.05 in latent_scan(8)
    assert latent_scan(4) == tuple(round(2 * s, 4) for s in latent_scan(8)) and len(FRAME_SCAN) == 19
    assert min(latent_scan(4)) < 0 < 0.1122 < 0.1996 < max(latent_scan(4))  # the tiny16 warp (yaw, pitch) lies inside
