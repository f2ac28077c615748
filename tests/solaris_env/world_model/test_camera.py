"""The camera warp of ours (``DiTConfig.camera_warp``): the pure functions, and every DiT entry point agreeing
with it on (cached decode == teacher forcing == causal), the cache carrying the previous latent."""

from __future__ import annotations

import dataclasses
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model import camera as camera_lib
from solaris_env.world_model import kv_cache
from solaris_env.world_model.config import DiTConfig, WorldModelConfig

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from test_dit import (TOL, _build, _cfg, _inputs, _rollout, _seq_args,  # noqa: E402  (shared builders)
                      _teacher_forcing, causal_fn)


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
    assert cache.latent.shape == (3, 2, cfg.latent_height, cfg.latent_width, cfg.out_channels)  # once, not per layer
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
