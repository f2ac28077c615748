"""ImageEncoder (docs/model.md §7.2): CLIP ViT tower, the blocks_applied quirk, preprocessing."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model.config import ImageEncoderConfig, WorldModelConfig
from solaris_env.world_model.image_encoder import ImageEncoder, preprocess_frames

CFG = WorldModelConfig.test().image_encoder  # 32x32, patch 8 -> 17 tokens of width 32
TWO_BLOCKS = dataclasses.replace(CFG, num_layers=2, blocks_applied=2)


def rngs(seed: int = 0) -> nnx.Rngs:
    return nnx.Rngs(jax.random.key(seed, impl="rbg"))  # rbg: faster init compiles on CPU


def num_params(module) -> int:
    return sum(int(np.prod(p.shape)) for p in jax.tree.leaves(nnx.state(module, nnx.Param)))


def frames(shape, seed=0):
    return jnp.asarray(np.random.default_rng(seed).uniform(-1, 1, size=shape), jnp.float32)


@pytest.fixture(scope="module")
def two_block_encoder():
    return ImageEncoder(TWO_BLOCKS, rngs=rngs())


def test_solaris_preset_param_count():
    cfg = WorldModelConfig.solaris().image_encoder
    assert num_params(nnx.eval_shape(lambda: ImageEncoder(cfg, rngs=nnx.Rngs(0)))) == 632_076_800  # spec, exact
    no_head = dataclasses.replace(cfg, proj_dim=0)  # minus post-LayerNorm (2 * 1280) and head (1280 * 1024)
    assert num_params(nnx.eval_shape(lambda: ImageEncoder(no_head, rngs=nnx.Rngs(0)))) == 630_763_520


@pytest.mark.parametrize("preset,frame_hw", [("solaris", (352, 640)), ("tiny", (64, 64)), ("test", (32, 32))])
def test_token_count_and_width(preset, frame_hw):
    cfg = WorldModelConfig.__dict__[preset].__func__(WorldModelConfig).image_encoder
    model = nnx.eval_shape(lambda: ImageEncoder(cfg, rngs=nnx.Rngs(0)))
    x = jax.ShapeDtypeStruct((3, *frame_hw, 3), jnp.float32)
    out = nnx.eval_shape(lambda m, x: m(x), model, x)
    assert out.shape == (3, cfg.num_tokens, cfg.width)
    assert cfg.num_tokens == (cfg.image_size // cfg.patch_size) ** 2 + 1  # 257 for solaris


def test_blocks_applied_one_is_block_zero_only(two_block_encoder):
    """blocks_applied=1 (the official quirk) == block 0 on the embedding; != running both blocks."""
    one = dataclasses.replace(TWO_BLOCKS, blocks_applied=1)
    enc1 = nnx.merge(nnx.graphdef(nnx.eval_shape(lambda: ImageEncoder(one, rngs=rngs()))),
                     nnx.state(two_block_encoder))  # same weights
    x = frames((2, 32, 32, 3))
    out1, out2 = enc1(x), two_block_encoder(x)
    emb = two_block_encoder.embed(x)
    np.testing.assert_allclose(out1, two_block_encoder.blocks[0](emb), atol=1e-5)
    np.testing.assert_allclose(out2, two_block_encoder.blocks[1](two_block_encoder.blocks[0](emb)), atol=1e-5)
    assert float(jnp.abs(out1 - out2).max()) > 1e-2


def _layer_norm(x, eps):
    return (x - x.mean(-1, keepdims=True)) / np.sqrt(x.var(-1, keepdims=True) + eps)  # scale 1, bias 0 at init


def test_block_matches_naive_pre_norm_transformer(two_block_encoder):
    """LayerNorm -> MHA (qkv laid out (3, heads, head_dim)) -> residual; LayerNorm -> MLP(GELU tanh) -> residual."""
    block, n, k = two_block_encoder.blocks[0], CFG.num_heads, CFG.head_dim
    x0 = np.asarray(frames((1, 5, CFG.width), seed=3))[0]
    p = lambda m: (np.asarray(m.kernel[...]), np.asarray(m.bias[...]))
    (wqkv, bqkv), (wo, bo) = p(block.attn.to_qkv), p(block.attn.proj)
    (w1, b1), (w2, b2) = p(block.fc1), p(block.fc2)
    qkv = (_layer_norm(x0, CFG.eps) @ wqkv + bqkv).reshape(5, 3, n, k)
    heads = []
    for h in range(n):
        q, kk, v = qkv[:, 0, h], qkv[:, 1, h], qkv[:, 2, h]
        logits = q @ kk.T / math.sqrt(k)
        a = np.exp(logits - logits.max(-1, keepdims=True))
        heads.append((a / a.sum(-1, keepdims=True)) @ v)
    x = x0 + np.concatenate(heads, -1) @ wo + bo
    hdn = _layer_norm(x, CFG.eps) @ w1 + b1
    gelu = 0.5 * hdn * (1 + np.tanh(math.sqrt(2 / math.pi) * (hdn + 0.044715 * hdn ** 3)))
    expected = x + gelu @ w2 + b2
    np.testing.assert_allclose(block(jnp.asarray(x0)[None])[0], expected, atol=1e-4)


def test_preprocess_constant_frame_is_normalised_exactly():
    out = preprocess_frames(jnp.full((1, 24, 40, 3), 0.2), CFG)  # 0.2 in [-1, 1] -> 0.6 in [0, 1]
    expected = (0.6 - np.array(CFG.pixel_mean)) / np.array(CFG.pixel_std)
    assert out.shape == (1, CFG.image_size, CFG.image_size, 3)
    np.testing.assert_allclose(out, np.broadcast_to(expected, out.shape), atol=1e-5)


def test_preprocess_squeezes_aspect_instead_of_cropping():
    """A 16x64 frame whose left quarter is black is resized (not cropped) to SxS: the black band keeps
    its quarter of the width and all rows look alike."""
    x = jnp.ones((1, 16, 64, 3)).at[:, :, :16].set(-1.0)
    out = np.asarray(preprocess_frames(x, CFG))[0, :, :, 0] * CFG.pixel_std[0] + CFG.pixel_mean[0]  # back to [0,1]
    s = CFG.image_size
    np.testing.assert_allclose(out, np.broadcast_to(out[:1], out.shape), atol=1e-5)  # rows identical
    assert np.all(out[:, : s // 4 - 2] < 0.05) and np.all(out[:, s // 4 + 2:] > 0.95)  # cubic overshoot aside


def test_encoder_accepts_frames_of_any_size(two_block_encoder):
    out = two_block_encoder(frames((2, 20, 44, 3)))
    assert out.shape == (2, TWO_BLOCKS.num_tokens, TWO_BLOCKS.width) and bool(jnp.isfinite(out).all())


def test_config_rejects_width_not_divisible_by_heads():
    with pytest.raises(ValueError, match="divisible by num_heads"):
        ImageEncoderConfig(width=30, num_heads=4)
