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


def test_walk_fit_finds_the_true_walk_and_keeps_turning_and_strafing_frames_apart():
    """Hand-made latents walked forward by a known number of eye heights per tick: the scan finds it; frames
    that also turn, and strafing frames, are not counted as forward."""
    import jax.numpy as jnp

    from benchmarks.camera_warp_fit import WALK_SCAN, walk_frames
    from solaris_env.world_model import camera

    rng = np.random.default_rng(2)
    coarse = rng.normal(size=(30, 4, 4, 4)).astype(np.float32)
    prev = np.kron(coarse, np.ones((1, 4, 4, 1), np.float32))  # (30, 16, 16, 4)
    moves = np.zeros((30, 2), np.float32)
    moves[:20, 0] = 4.0  # 20 frames walk forward 4 ticks
    moves[20:, 1] = 3.0  # 10 strafe right
    nxt = np.asarray(camera.walk_latents(jnp.asarray(prev), jnp.asarray(0.133 * moves)))
    turns = np.zeros((30, 2), np.float32)
    turns[15:20, 0] = 10.0  # 5 of the forward frames also turn: left out
    rows = {r["walk"] + str(r["ticks"]): r for r in walk_frames(prev, nxt, moves, turns, configured=0.133)}
    fwd, strafe = rows["forward[2.0, 4.5]"], rows["strafe[2.0, 9.0]"]
    assert fwd["frames"] == 15 and strafe["frames"] == 10 and rows["back[-9.0, -2.0]"]["frames"] == 0
    for row in (fwd, strafe):
        assert row["best_per_tick"] == 0.133 and row["mse_best"] < 1e-6 < row["mse_no_walk"]
        assert row["configured_helps"]
    assert 0.133 in WALK_SCAN and WALK_SCAN[0] == 0.0


def test_the_engines_walks_follow_the_walk_geometry():
    """On the engine's own frames a held forward / back / strafe key is fitted by a walk of the right sign:
    the best scale is positive and beats standing still (the geometry and the key signs agree)."""
    from benchmarks.camera_warp_fit import engine_walk_fit

    rows = engine_walk_fit(steps=5, warmup=2, starts=((11, "flat"), (12, "normal")))
    assert [r["key"] for r in rows] == ["forward", "back", "right"]
    for r in rows:
        assert r["frames"] == 6 and r["best_per_tick"] > 0 and r["mse_best"] < r["mse_no_walk"], r
