"""First-frame conditioning (docs/model.md §5.4): Wan mask layout, gray padding, streaming == full."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model.conditioning import (conditioning_video, first_frame_cond, first_frame_cond_next,
                                                  first_frame_cond_start, first_frame_mask)
from solaris_env.world_model.config import VAEConfig, WorldModelConfig
from solaris_env.world_model.vae import CausalVideoVAE

# temporal x4 (so 4 mask channels) and spatial x4, with few layers so it builds and compiles fast
VAE_CFG = VAEConfig(base_dim=4, z_dim=4, dim_mult=(1, 1, 1), num_res_blocks=1, temporal_downsample=(True, True),
                    middle_attention=False)
F = 4  # latent frames -> T = 13 video frames

cond_full = nnx.jit(first_frame_cond, static_argnums=2)
cond_start = nnx.jit(first_frame_cond_start)
cond_next = nnx.jit(first_frame_cond_next)
encode = nnx.jit(lambda vae, x: vae.encode(x))


@pytest.fixture(scope="module")
def vae():
    return CausalVideoVAE(VAE_CFG, rngs=nnx.Rngs(jax.random.key(0, impl="rbg")))  # rbg: faster init on CPU


@pytest.fixture(scope="module")
def trained_like_vae(vae):
    """A copy with random biases: at init all biases are 0, so a gray (all-zero) video encodes to exactly 0,
    unlike with trained weights."""
    rng = np.random.default_rng(1)
    is_bias = lambda path: any(getattr(k, "key", None) == "bias" for k in path)
    graphdef, state = nnx.split(vae)
    state = jax.tree_util.tree_map_with_path(
        lambda path, x: x + 0.1 * rng.normal(size=x.shape).astype(x.dtype) if is_bias(path) else x, state)
    return nnx.merge(graphdef, state)


@pytest.fixture(scope="module")
def first_frame():
    return jnp.asarray(np.random.default_rng(0).uniform(-1, 1, size=(2, 16, 16, 3)), jnp.float32)


def test_mask_layout_is_wan_i2v():
    """Frame 0 repeated tf times, frames folded in groups of tf: latent 0 all ones, the rest zeros."""
    mask = np.asarray(first_frame_mask(num_latent_frames=3, temporal_factor=4))
    np.testing.assert_array_equal(mask, [[1, 1, 1, 1], [0, 0, 0, 0], [0, 0, 0, 0]])
    assert first_frame_mask(1, 4).shape == (1, 4) and float(first_frame_mask(1, 4).min()) == 1.0


def test_conditioning_video_pads_with_mid_gray(first_frame):
    video = conditioning_video(first_frame, 5)
    assert video.shape == (2, 5, 16, 16, 3)
    np.testing.assert_array_equal(video[:, 0], first_frame)
    assert float(jnp.abs(video[:, 1:]).max()) == 0.0  # 0 in [-1, 1] = gray, not black (-1)


def test_cond_is_mask_then_normalised_encoding(vae, first_frame):
    cond = cond_full(vae, first_frame, F)
    tf = VAE_CFG.temporal_factor
    assert cond.shape == (2, F, 4, 4, tf + VAE_CFG.z_dim)
    np.testing.assert_array_equal(cond[:, 0, ..., :tf], 1.0)
    np.testing.assert_array_equal(cond[:, 1:, ..., :tf], 0.0)
    img = encode(vae, conditioning_video(first_frame, VAE_CFG.video_frames(F)))
    np.testing.assert_allclose(cond[..., tf:], img, atol=1e-6)


def test_latent_one_sees_frame_zero(vae, first_frame):
    """Even where gray encodes to exactly 0 (zero biases at init), cond latent 1 is not 0: the causal
    convs carry frame 0 forward."""
    tf = VAE_CFG.temporal_factor
    img = cond_full(vae, first_frame, F)[..., tf:]
    gray = encode(vae, jnp.zeros((2, VAE_CFG.video_frames(F), 16, 16, 3)))
    assert float(jnp.abs(gray).max()) == 0.0
    assert float(jnp.abs(img[:, 1]).mean(axis=(1, 2, 3)).min()) > 1e-3


def test_gray_latents_are_what_gray_encodes_to(trained_like_vae, first_frame):
    """With non-zero biases a gray video's latents are not 0, and neither are the cond latents of the gray
    frames; latent 1 still differs from the all-gray video's latent 1 (frame 0 leaks through)."""
    tf = VAE_CFG.temporal_factor
    img = cond_full(trained_like_vae, first_frame, F)[..., tf:]
    gray = encode(trained_like_vae, jnp.zeros((2, VAE_CFG.video_frames(F), 16, 16, 3)))
    assert float(jnp.abs(gray[:, 1:]).mean(axis=(2, 3, 4)).min()) > 1e-3
    assert float(jnp.abs(img[:, 1:]).mean(axis=(2, 3, 4)).min()) > 1e-3
    assert float(jnp.abs(img[:, 1] - gray[:, 1]).max()) > 1e-3


def test_streaming_slices_match_full_cond(vae, first_frame):
    full = cond_full(vae, first_frame, F)
    cond, state = cond_start(vae, first_frame)
    slices = [cond]
    for _ in range(F - 1):
        cond, state = cond_next(vae, state)
        slices.append(cond)
    np.testing.assert_allclose(jnp.concatenate(slices, axis=1), full, atol=1e-4)


def test_solaris_cond_has_the_dit_input_channels():
    cfg = WorldModelConfig.solaris()
    vae = nnx.eval_shape(lambda: CausalVideoVAE(cfg.vae, rngs=nnx.Rngs(0)))
    x = jax.ShapeDtypeStruct((1, cfg.frame_height, cfg.frame_width, 3), jnp.float32)
    cond = nnx.eval_shape(lambda v, x: first_frame_cond(v, x, 9), vae, x)
    assert cond.shape == (1, 9, 44, 80, 20) == (1, 9, cfg.latent_height, cfg.latent_width,
                                                 cfg.in_channels - cfg.latent_channels)


def test_image_cond_encoding_is_the_video_layouts_latent_zero_then_zeros():
    """cond_encoding="image": latent 0 equals the "video" layout's latent 0 (causal encoder), later latents
    are 0; the streaming start/next slices equal the full computation; the steady index is 1."""
    import dataclasses

    from solaris_env.world_model.vae import CausalVideoVAE
    from solaris_env.world_model.world_model import steady_cond_index

    video_cfg = WorldModelConfig.test().vae
    image_cfg = dataclasses.replace(video_cfg, cond_encoding="image")
    video_vae = CausalVideoVAE(video_cfg, rngs=nnx.Rngs(0))
    image_vae = CausalVideoVAE(image_cfg, rngs=nnx.Rngs(0))
    first = jax.random.uniform(jax.random.PRNGKey(1), (2, 32, 32, 3), minval=-1, maxval=1)
    full_video = first_frame_cond(video_vae, first, 3)
    full_image = first_frame_cond(image_vae, first, 3)
    assert full_image.shape == full_video.shape
    np.testing.assert_allclose(full_image[:, 0], full_video[:, 0], atol=1e-5)
    m = image_cfg.temporal_factor
    assert np.all(np.asarray(full_image[:, 1:, ..., m:]) == 0)
    np.testing.assert_array_equal(full_image[..., :m], full_video[..., :m])  # the mask is unchanged
    c0, state = first_frame_cond_start(image_vae, first)
    c1, _ = first_frame_cond_next(image_vae, state)
    np.testing.assert_allclose(c0[:, 0], full_image[:, 0], atol=1e-5)
    np.testing.assert_array_equal(c1[:, 0], full_image[:, 1])
    assert steady_cond_index(image_cfg) == 1 < steady_cond_index(video_cfg)
