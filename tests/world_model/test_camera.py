"""The camera conditionings of ours: camera RoPE (``DiTConfig.camera_rope``) and the camera warp
(``DiTConfig.camera_warp``): the pure functions, and every DiT entry point agreeing with each on (cached decode ==
teacher forcing == causal), the cache carrying the accumulated offset / the previous latent."""

from __future__ import annotations

import dataclasses
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.spaces import CAMERA_SCALE_DEG
from solaris_env.world_model import camera as camera_lib
from solaris_env.world_model import kv_cache, rope
from solaris_env.world_model.action_module import action_windows, window_at
from solaris_env.world_model.config import DiTConfig, WorldModelConfig

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from test_dit import (BATCH, FRAMES, TOL, _build, _cfg, _inputs, _rollout, _seq_args,  # noqa: E402  (shared builders)
                      _teacher_forcing, causal_fn, decode_fn)

CAMERA = (0.05, 0.03)  # (height, width) positions per degree


def _camera_cfg(camera=CAMERA) -> WorldModelConfig:
    cfg = _cfg(players=2)
    return cfg.replace(dit=dataclasses.replace(cfg.dit, camera_rope=camera))


# ---------------------------------------------------------------------------------------------
# Pure functions
# ---------------------------------------------------------------------------------------------


def test_increments_sum_the_frames_last_k_turns_with_mineflayer_signs():
    k, window = 4, 12
    mouse = np.zeros((1, 2, 3, window, 2), np.float32)  # (B, P, F, W, [cameraX, cameraY])
    mouse[0, 0, 1, -k:, 0] = 0.5  # player 0, frame 1: k ticks of yaw left, 0.5 units each
    mouse[0, 0, 1, :-k, 0] = 9.0  # older ticks of the window belong to earlier frames: not counted
    mouse[0, 1, 2, -1, 1] = -1.0  # player 1, frame 2: one tick of pitch down
    inc = np.asarray(rope.camera_increments(camera_lib.frame_turns(jnp.asarray(mouse), k), CAMERA))
    assert inc.shape == (1, 2, 3, 2)
    want = np.zeros_like(inc)
    want[0, 0, 1, 1] = -CAMERA[1] * 4 * 0.5 * CAMERA_SCALE_DEG  # turn left: width position decreases
    want[0, 1, 2, 0] = CAMERA[0] * 1.0 * CAMERA_SCALE_DEG  # look down: height position increases
    np.testing.assert_allclose(inc, want, rtol=1e-6)


def test_positions_accumulate_from_the_base():
    inc = jnp.asarray(np.random.default_rng(0).normal(size=(2, 2, 5, 2)), jnp.float32)
    base = jnp.asarray([[[1.0, -2.0], [0.5, 0.0]], [[0.0, 0.0], [3.0, 1.0]]])
    np.testing.assert_allclose(rope.camera_positions(None, inc), np.cumsum(inc, axis=2), rtol=1e-6)
    np.testing.assert_allclose(rope.camera_positions(base, inc), np.cumsum(inc, axis=2) + np.asarray(base)[:, :, None],
                               rtol=1e-6)


def test_angles_offset_only_the_height_and_width_pairs_of_their_player():
    split, gh, gw, frames, players = (4, 3, 3), 2, 2, 2, 2
    pos = np.zeros((1, players, frames, 2), np.float32)
    pos[0, 1, 1] = [0.5, -1.5]  # player 1, frame 1
    extra = np.asarray(rope.camera_rope_angles(split, 10000.0, jnp.asarray(pos), gh, gw))
    assert extra.shape == (1, frames * players * gh * gw, sum(split))
    per = extra.reshape(frames, players, gh * gw, sum(split))
    assert np.abs(per[:, 0]).max() == 0 and np.abs(per[0]).max() == 0  # other player, other frame: untouched
    moved = per[1, 1]
    assert np.abs(moved[:, :4]).max() == 0  # frame pairs never move
    inv = 10000.0 ** (-np.arange(3) / 3)
    np.testing.assert_allclose(moved[:, 4:7], np.broadcast_to(0.5 * inv, (gh * gw, 3)), rtol=1e-6)
    np.testing.assert_allclose(moved[:, 7:], np.broadcast_to(-1.5 * inv, (gh * gw, 3)), rtol=1e-6)
    # the same offset on the base grid = that many positions along the axis (RoPE of a fractional position)
    base = rope.rope_3d_angles(split, 10000.0, 1, gh, gw, 1)
    one = rope.camera_rope_angles(split, 10000.0, jnp.full((1, 1, 1, 2), 1.0), gh, gw)
    shifted = np.asarray(base) + np.asarray(one)[0]
    np.testing.assert_allclose(shifted[0], np.asarray(base)[3], rtol=1e-6)  # token (0, 0) moved to (1, 1)


def test_apply_rope_takes_one_table_per_batch_row():
    x = jax.random.normal(jax.random.key(0), (3, 5, 2, 8))
    ang = jax.random.normal(jax.random.key(1), (3, 5, 4))
    per_row = rope.apply_rope(x, ang)
    for b in range(3):
        np.testing.assert_allclose(per_row[b], rope.apply_rope(x[b:b + 1], ang[b])[0], atol=1e-6)
    with pytest.raises(ValueError, match="angles shape"):
        rope.apply_rope(x, ang[:, :4])


@pytest.mark.parametrize("camera", [(float("nan"), 0.0), (0.0,), (0.0, float("inf"))])
def test_config_rejects_bad_camera_rope(camera):
    with pytest.raises(ValueError, match="camera_rope"):
        DiTConfig(camera_rope=camera)


def test_config_rejects_camera_rope_with_stacked_players():
    with pytest.raises(ValueError, match="camera_rope"):
        DiTConfig(multiplayer="concat", camera_rope=(0.1, 0.1))


def test_off_by_default_and_the_cache_has_no_camera():
    cfg = WorldModelConfig.test()
    assert cfg.dit.camera_rope == (0.0, 0.0) and not cfg.dit.camera_rope_enabled
    assert kv_cache.init_cache(cfg, 1).camera is None
    cache = kv_cache.init_cache(_camera_cfg(), 3)
    assert cache.camera.shape == (cfg.dit.num_layers, 3, cfg.num_players, 2)


# ---------------------------------------------------------------------------------------------
# The DiT with camera RoPE on
# ---------------------------------------------------------------------------------------------


def _turning(cfg: WorldModelConfig, seed: int):
    """(cfg, random-weight model, inputs) with turns of up to ~135 degrees per latent frame (offsets and shifts
    of several tokens)."""
    inp = _inputs(cfg, seed=seed)
    inp["mouse"] = inp["mouse"] * 3.0
    return cfg, _build(cfg, seed=seed), inp


def _cached_rollout_agrees(cfg, model, inp) -> dict:
    """The cached rollout (denoise / commit passes) == teacher forcing == the causal forward; returns it."""
    out = _rollout(cfg, model, inp)
    np.testing.assert_allclose(out["denoise"], _teacher_forcing(model, inp), atol=TOL, rtol=0)
    v_causal = causal_fn(model, *_seq_args(inp, "clean", jnp.zeros_like(inp["t"])))
    np.testing.assert_allclose(out["commit"], v_causal, atol=TOL, rtol=0)
    return out


@pytest.fixture(scope="module")
def camera_model():
    return _turning(_camera_cfg(), seed=21)


def test_cached_rollout_equals_teacher_forcing_and_causal(camera_model):
    cfg, model, inp = camera_model
    out = _cached_rollout_agrees(cfg, model, inp)
    # the cache ends at the last frame's accumulated offset, in every layer
    windows = action_windows(inp["mouse"], cfg, FRAMES)
    turns = camera_lib.frame_turns(windows, cfg.frames_per_step)
    want = rope.camera_positions(None, rope.camera_increments(turns, cfg.dit.camera_rope))[:, :, -1]
    np.testing.assert_allclose(out["cache"].camera, jnp.broadcast_to(want, out["cache"].camera.shape), rtol=1e-5)


def test_camera_rope_changes_the_output_and_zero_turns_do_not(camera_model):
    cfg, model, inp = camera_model
    off = nnx.merge(nnx.graphdef(_build(_cfg(players=2))), nnx.state(model))  # same weights, camera RoPE off
    still = dict(inp, mouse=jnp.zeros_like(inp["mouse"]))
    np.testing.assert_allclose(causal_fn(model, *_seq_args(still)), causal_fn(off, *_seq_args(still)), atol=1e-5)
    delta = jnp.abs(causal_fn(model, *_seq_args(inp)) - causal_fn(off, *_seq_args(inp))).max(axis=(0, 1, 3, 4, 5))
    assert float(delta[1:].min()) > 1e-3, delta


def test_a_common_offset_of_every_frame_cancels(camera_model):
    """Only offset differences matter: the cached rollout from a cache whose camera base is shifted gives the
    same velocities (RoPE is relative)."""
    cfg, model, inp = camera_model

    def run(base_shift):
        cache = kv_cache.init_cache(cfg, BATCH, jnp.float32)
        cache = cache.replace(camera=cache.camera + jnp.asarray(base_shift, jnp.float32))
        outs = []
        for i in range(FRAMES):
            sl = slice(i, i + 1)
            common = (inp["cond"][:, :, sl], inp["context"], window_at(inp["mouse"], cfg, i),
                      window_at(inp["keyboard"], cfg, i))
            v, _ = decode_fn(model, inp["noisy"][:, :, sl], inp["t"][:, :, sl], *common, cache, i)
            _, cache = decode_fn(model, inp["clean"][:, :, sl], jnp.zeros_like(inp["t"][:, :, sl]), *common, cache, i)
            outs.append(v)
        return jnp.concatenate(outs, axis=2)

    np.testing.assert_allclose(run([0.0, 0.0]), run([7.25, -3.5]), atol=TOL, rtol=0)


# ---------------------------------------------------------------------------------------------
# Camera warp
# ---------------------------------------------------------------------------------------------

WARP = (0.1, 0.06)  # (height, width) latent pixels per degree


def _warp_cfg() -> WorldModelConfig:
    cfg = _cfg(players=2)
    return cfg.replace(dit=dataclasses.replace(cfg.dit, camera_warp=WARP))


def test_frame_turns_and_content_shift_signs():
    mouse = np.zeros((1, 1, 2, 12, 2), np.float32)
    mouse[0, 0, 1, -4:, 0] = 0.5  # yaw left, 4 ticks of 7.5 degrees
    mouse[0, 0, 1, -1, 1] = 0.2  # look up 3 degrees
    mouse[0, 0, 1, 0, 0] = 9.0  # an older tick: not this frame's turn
    turns = camera_lib.frame_turns(jnp.asarray(mouse), 4)
    np.testing.assert_allclose(turns[0, 0], [[0, 0], [30.0, 3.0]], rtol=1e-6)
    shift = camera_lib.content_shift(turns, WARP)
    np.testing.assert_allclose(shift[0, 0, 1], [3.0 * WARP[0], 30.0 * WARP[1]], rtol=1e-6)  # down, right


def test_shift_latents_moves_content_exactly_by_whole_pixels_and_interpolates_between():
    x = jax.random.normal(jax.random.key(0), (2, 5, 6, 3))
    out = camera_lib.shift_latents(x, jnp.asarray([[0.0, 2.0], [-1.0, 0.0]]))
    np.testing.assert_allclose(out[0, :, 2:], x[0, :, :-2], atol=1e-6)  # content moved right by 2
    np.testing.assert_allclose(out[0, :, :2], np.repeat(x[0, :, :1], 2, axis=1), atol=1e-6)  # edge repeated
    np.testing.assert_allclose(out[1, :-1], x[1, 1:], atol=1e-6)  # moved up by 1
    half = camera_lib.shift_latents(x, jnp.asarray([[0.0, 0.5], [0.0, 0.0]]))
    np.testing.assert_allclose(half[0, :, 1:], 0.5 * (x[0, :, 1:] + x[0, :, :-1]), atol=1e-6)
    np.testing.assert_allclose(half[1], x[1], atol=1e-6)
    with pytest.raises(ValueError, match="shift_latents"):
        camera_lib.shift_latents(x, jnp.zeros((2, 3)))


def test_camera_warp_config_and_cache():
    with pytest.raises(ValueError, match="camera_warp"):
        DiTConfig(camera_warp=(float("nan"), 0.0))
    with pytest.raises(ValueError, match="camera_warp"):
        DiTConfig(multiplayer="concat", camera_warp=(0.1, 0.1))
    cfg = _warp_cfg()
    assert cfg.patch_in_channels == cfg.in_channels + cfg.out_channels
    assert WorldModelConfig.test().patch_in_channels == WorldModelConfig.test().in_channels
    cache = kv_cache.init_cache(cfg, 3)
    assert cache.latent.shape == (cfg.dit.num_layers, 3, 2, cfg.latent_height, cfg.latent_width, cfg.out_channels)
    assert kv_cache.init_cache(WorldModelConfig.test(), 1).latent is None


@pytest.fixture(scope="module")
def warp_model():
    return _turning(_warp_cfg(), seed=31)


def test_warp_cached_rollout_equals_teacher_forcing_and_causal(warp_model):
    cfg, model, inp = warp_model
    out = _cached_rollout_agrees(cfg, model, inp)
    last = inp["clean"][:, :, -1]
    np.testing.assert_allclose(out["cache"].latent, jnp.broadcast_to(last, out["cache"].latent.shape), atol=1e-6)


def test_warp_input_reaches_the_next_frame_only(warp_model):
    """Changing frame i's latent changes frame i + 1's output through the warp even with the attention unable
    to see it (a bidirectional pass has no mask; compare causal outputs of frame i + 1 with and without)."""
    cfg, model, inp = warp_model
    i = 1
    x = inp["clean"]
    moved = x.at[:, :, i].add(1.0)
    t = jnp.zeros_like(inp["t"])
    base = causal_fn(model, x, t, inp["cond"], inp["context"], inp["mouse"], inp["keyboard"])
    other = causal_fn(model, moved, t, inp["cond"], inp["context"], inp["mouse"], inp["keyboard"])
    delta = jnp.abs(other - base).max(axis=(0, 1, 3, 4, 5))
    assert float(delta[:i].max()) == 0.0 and float(delta[i + 1]) > 1e-4, delta


def test_warp_reads_the_given_clean_latents(warp_model):
    """Training hands the clean latents (what a rollout commits) to the warp; by default it reads x itself."""
    cfg, model, inp = warp_model
    args = _seq_args(inp)
    fn = nnx.jit(lambda m, *a, clean=None: m.forward_causal(*a, clean=clean))
    base = fn(model, *args)
    np.testing.assert_array_equal(fn(model, *args, clean=inp["noisy"]), base)
    delta = jnp.abs(fn(model, *args, clean=inp["clean"]) - base).max(axis=(0, 1, 3, 4, 5))
    assert float(delta[0]) == 0.0 and float(delta[1:].min()) > 1e-4, delta  # frame 0 has no previous frame
