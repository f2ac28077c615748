"""Warped sampling noise (``SamplerConfig.noise_warp``, ``noise_warp``; docs/model.md §5.3): the pure functions,
and the streaming model carrying its noises from frame to frame along the camera turn."""

from __future__ import annotations

import dataclasses
import math
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from solaris_env.spaces import CAMERA_SCALE_DEG
from solaris_env.world_model import noise_warp
from solaris_env.world_model.config import SamplerConfig, WorldModelConfig

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from test_world_model import first_frames, host, random_model  # noqa: E402  (shared builders)

WARP = (0.1, 0.06)  # (height, width) latent pixels per degree


# ---------------------------------------------------------------------------------------------
# The pure functions
# ---------------------------------------------------------------------------------------------


def test_whole_pixel_moves_track_the_summed_shift():
    rng = np.random.default_rng(0)
    shifts = rng.uniform(-2.3, 2.3, (40, 3, 2)).astype(np.float32)
    shifts[:, 0] = [0.57, -0.2]  # a steady sub-pixel turn: the moves must add up to it
    remainder, total_move = jnp.zeros((3, 2)), np.zeros((3, 2))
    for s in shifts:
        move, remainder = noise_warp.whole_pixel_move(remainder, jnp.asarray(s))
        assert move.dtype == jnp.int32
        total_move += np.asarray(move)
        r = np.asarray(remainder)
        assert (r >= -0.5 - 1e-6).all() and (r < 0.5 + 1e-6).all()
    np.testing.assert_allclose(total_move + np.asarray(remainder), shifts.sum(axis=0), atol=1e-4)
    assert total_move[0].tolist() == [round(0.57 * 40), -8]
    move, remainder = noise_warp.whole_pixel_move(jnp.zeros((1, 2)), jnp.zeros((1, 2)))
    assert np.asarray(move).tolist() == [[0, 0]] and np.asarray(remainder).tolist() == [[0.0, 0.0]]


def test_move_noise_moves_by_whole_pixels_and_marks_the_uncovered_border():
    noise = jax.random.normal(jax.random.key(0), (3, 2, 5, 6, 4))
    moves = np.array([[1, -2], [0, 0], [-7, 3]], np.int32)  # down 1 / left 2; none; off the frame
    moved, inside = noise_warp.move_noise(noise, jnp.asarray(moves))
    n = np.asarray(noise)
    for i, (dy, dx) in enumerate(moves):
        for r in range(5):
            for c in range(6):
                src = (r - dy, c - dx)
                ok = 0 <= src[0] < 5 and 0 <= src[1] < 6
                assert bool(inside[i, r, c]) == ok
                if ok:
                    np.testing.assert_array_equal(moved[i, :, r, c], n[i, :, src[0], src[1]])
    assert int(inside[0].sum()) == 4 * 4 and bool(inside[1].all()) and not bool(inside[2].any())
    np.testing.assert_array_equal(moved[1], n[1])
    with pytest.raises(ValueError, match="move_noise"):
        noise_warp.move_noise(noise[0], jnp.asarray(moves))


def test_carry_noise_moves_mixes_and_keeps_every_element_a_unit_gaussian():
    shape = (2, 5, 16, 16, 64)
    prev, fresh = (jax.random.normal(jax.random.key(k), shape) for k in (0, 1))
    shift = jnp.asarray([[0.0, 1.3], [0.0, 0.0]])
    out, remainder = noise_warp.carry_noise(prev, jnp.zeros((2, 2)), fresh, shift, 1.0)
    np.testing.assert_allclose(remainder, [[0.0, 0.3], [0.0, 0.0]], atol=1e-6)
    np.testing.assert_array_equal(out[0, :, :, 1:], prev[0, :, :, :-1])  # moved one column right
    np.testing.assert_array_equal(out[0, :, :, 0], fresh[0, :, :, 0])  # the uncovered column is fresh
    np.testing.assert_array_equal(out[1], prev[1])  # no turn: the same noise, bit for bit
    fresh_only, _ = noise_warp.carry_noise(prev, jnp.zeros((2, 2)), fresh, shift, 0.0)
    np.testing.assert_array_equal(fresh_only, fresh)
    rho = 0.6
    mixed, _ = noise_warp.carry_noise(prev, jnp.zeros((2, 2)), fresh, shift, rho)
    inner = np.asarray(mixed[1]).ravel()
    assert abs(inner.std() - 1.0) < 0.01 and abs(np.corrcoef(inner, np.asarray(prev[1]).ravel())[0, 1] - rho) < 0.01
    np.testing.assert_array_equal(mixed[0, :, :, 0], fresh[0, :, :, 0])  # the border stays purely fresh
    np.testing.assert_allclose(mixed[1], rho * prev[1] + math.sqrt(1 - rho ** 2) * fresh[1], rtol=1e-6)
    with pytest.raises(ValueError, match="rho"):
        noise_warp.carry_noise(prev, jnp.zeros((2, 2)), fresh, shift, 1.5)
    with pytest.raises(ValueError, match="fresh"):
        noise_warp.carry_noise(prev, jnp.zeros((2, 2)), fresh[:1], shift, 1.0)


@pytest.mark.parametrize("rho", [-0.1, 1.01, float("nan")])
def test_noise_warp_must_be_in_the_unit_interval(rho):
    with pytest.raises(ValueError, match="noise_warp"):
        SamplerConfig(noise_warp=rho)


def test_noise_warp_needs_the_camera_warp():
    cfg = WorldModelConfig.test()
    assert not cfg.dit.camera_warp_enabled
    with pytest.raises(ValueError, match="noise_warp"):
        cfg.replace(sampler=SamplerConfig(noise_warp=0.5))


# ---------------------------------------------------------------------------------------------
# The streaming model
# ---------------------------------------------------------------------------------------------


def _warp_model(rho: float):
    cfg = WorldModelConfig.test()
    cfg = cfg.replace(dit=dataclasses.replace(cfg.dit, camera_warp=WARP),
                      sampler=dataclasses.replace(cfg.sampler, noise_warp=rho))
    return random_model(cfg)


@pytest.fixture(scope="module")
def warped():
    return _warp_model(1.0)


def _actions(model, batch: int, yaw_deg_per_step: float = 0.0) -> np.ndarray:
    """(B, P, k, A): no keys; a steady yaw (+ = left) spread over the step's k ticks."""
    a = np.zeros((batch, model.num_players, model.frames_per_step, model.action_dim), np.float32)
    a[..., model.config.action.keyboard_dim] = yaw_deg_per_step / model.frames_per_step / CAMERA_SCALE_DEG
    return a


def test_fresh_noise_carries_no_noise_state():
    state = random_model(WorldModelConfig.test()).init(np.zeros((1, 2, 32, 32, 3), np.uint8), jax.random.key(0))
    assert state.noise_BPShwC is None and state.noise_shift_BP2 is None


def test_the_state_carries_the_noises_from_the_key_schedule_moved_by_the_turn(warped):
    cfg, b = warped.config, 2
    state = warped.init(first_frames(warped, b), jax.random.key(3))
    s = len(cfg.sampler.ar_timesteps) + 1
    assert state.noise_BPShwC.shape == (b, 2, s, cfg.latent_height, cfg.latent_width, cfg.latent_channels)
    np.testing.assert_array_equal(state.noise_shift_BP2, np.zeros((b, 2, 2)))
    yaw = 1.0 / WARP[1]  # one latent column per step: the content moves right
    for _ in range(3):
        before = host(state)
        _, state = warped.step(state, _actions(warped, b, yaw))
        after = host(state)
        for w in range(b):
            frame_key = jax.random.split(before.key_B[w])[1]
            fresh = jax.random.normal(frame_key, before.noise_BPShwC[w].shape)
            want, shift = noise_warp.carry_noise(jnp.asarray(before.noise_BPShwC[w]),
                                                 jnp.asarray(before.noise_shift_BP2[w]), fresh,
                                                 jnp.asarray([[0.0, 1.0]] * 2), 1.0)
            np.testing.assert_allclose(after.noise_BPShwC[w], want, atol=1e-6, rtol=0)
            np.testing.assert_allclose(after.noise_shift_BP2[w], shift, atol=1e-5)
        np.testing.assert_array_equal(after.noise_BPShwC[..., 1:, :], before.noise_BPShwC[..., :-1, :])


def test_standing_still_keeps_the_noise_and_the_key_no_longer_matters(warped):
    """With rho = 1 and no turn the frame's noises are the carried ones: two worlds that differ only in their
    keys give the same frame; with rho = 0.5 they differ."""
    state = warped.init(first_frames(warped, 1), jax.random.key(0))
    _, state = warped.step(state, _actions(warped, 1))
    noise = np.asarray(state.noise_BPShwC)
    twin = jax.tree.map(lambda x: jnp.concatenate([x, x]), state)
    twin = twin.replace(key_B=jnp.stack([state.key_B[0], jax.random.split(state.key_B[0])[0]]))
    frames, after = warped.step(twin, _actions(warped, 2))
    np.testing.assert_array_equal(np.asarray(after.noise_BPShwC)[:1], noise)
    np.testing.assert_array_equal(np.asarray(frames)[0], np.asarray(frames)[1])
    half = _warp_model(0.5)
    state = half.init(first_frames(half, 1), jax.random.key(0))
    _, state = half.step(state, _actions(half, 1))
    twin = jax.tree.map(lambda x: jnp.concatenate([x, x]), state)
    twin = twin.replace(key_B=jnp.stack([state.key_B[0], jax.random.split(state.key_B[0])[0]]))
    frames, _ = half.step(twin, _actions(half, 2))
    assert not np.array_equal(np.asarray(frames)[0], np.asarray(frames)[1])


def test_reset_worlds_restarts_the_noise_of_the_reset_world_only(warped):
    state = warped.init(first_frames(warped, 2), jax.random.key(7))
    _, state = warped.step(state, _actions(warped, 2, 25.0))
    before = host(state)
    state = warped.reset_worlds(state, np.array([False, True]), first_frames(warped, 2, seed=4),
                                rng=jax.random.key(11))
    after = host(state)
    np.testing.assert_array_equal(after.noise_BPShwC[0], before.noise_BPShwC[0])
    fresh = host(warped.init(first_frames(warped, 2, seed=4), jax.random.key(11)))
    np.testing.assert_array_equal(after.noise_BPShwC[1], fresh.noise_BPShwC[1])
    np.testing.assert_array_equal(after.noise_shift_BP2[1], np.zeros((2, 2)))


def test_a_state_of_the_other_noise_setting_is_refused(warped):
    fresh_model = warped.with_sampler(dataclasses.replace(warped.config.sampler, noise_warp=0.0))
    state = fresh_model.init(first_frames(warped, 1), jax.random.key(0))
    with pytest.raises(ValueError, match="noise_BPShwC is missing.*noise_warp=1.0"):
        warped.step(state, _actions(warped, 1))
    state = warped.init(first_frames(warped, 1), jax.random.key(0))
    with pytest.raises(ValueError, match="noise_BPShwC is set.*noise_warp=0.0"):
        fresh_model.step(state, _actions(warped, 1))
