"""The first-frame image encoder: a CLIP ViT vision tower (docs/model.md §7.2).

Frames (B, H, W, 3) in [-1, 1] -> tokens (B, num_tokens, width), un-pooled: CLS + one token per patch.

- Preprocessing: x * 0.5 + 0.5 -> ``jax.image.resize`` to image_size x image_size (cubic; the aspect
  ratio is NOT preserved, a 352x640 frame is squeezed to 224x224) -> (x - pixel_mean) / pixel_std.
- Patch embedding without bias, CLS token prepended, learned positional embedding, then the pre-LayerNorm.
- Pre-norm transformer blocks (LayerNorm -> MHA, LayerNorm -> MLP with tanh-approximate GELU), of which
  only the first ``blocks_applied`` run. Solaris uses 1 of 32 (the official quirk, parity-critical: its
  DiT was trained against that feature); the other blocks exist only so the tree matches the checkpoint.
- ``post_norm`` and ``head`` (width -> proj_dim) complete CLIP's vision tower but never run; with them the
  solaris preset has the official 632,076,800 parameters. ``proj_dim=0`` leaves them out (tiny, test).

For our own tiny models the same class is used with small sizes (``WorldModelConfig.tiny``: 64x64 input,
patch 8 -> 65 tokens of width 128, 2 blocks, both applied).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from solaris_env.world_model.config import ImageEncoderConfig


def preprocess_frames(frames_BHWC: jax.Array, cfg: ImageEncoderConfig) -> jax.Array:
    """Frames in [-1, 1] of any size -> normalised pixels (B, image_size, image_size, 3), f32."""
    B, _, _, C = frames_BHWC.shape
    x = frames_BHWC.astype(jnp.float32) * 0.5 + 0.5
    x = jax.image.resize(x, (B, cfg.image_size, cfg.image_size, C), method="cubic")
    return (x - jnp.asarray(cfg.pixel_mean, jnp.float32)) / jnp.asarray(cfg.pixel_std, jnp.float32)


class SelfAttention(nnx.Module):
    """Multi-head self-attention; the fused qkv output is laid out (3, heads, head_dim)."""

    def __init__(self, cfg: ImageEncoderConfig, *, rngs: nnx.Rngs):
        kw = dict(dtype=jnp.dtype(cfg.dtype), param_dtype=jnp.dtype(cfg.param_dtype), rngs=rngs)
        self.num_heads, self.head_dim = cfg.num_heads, cfg.head_dim
        self.to_qkv = nnx.Linear(cfg.width, 3 * cfg.width, **kw)
        self.proj = nnx.Linear(cfg.width, cfg.width, **kw)

    def __call__(self, x_BLD: jax.Array) -> jax.Array:
        B, L, D = x_BLD.shape
        qkv = self.to_qkv(x_BLD).reshape(B, L, 3, self.num_heads, self.head_dim)  # (B, L, 3, N, K)
        o_BLNK = jax.nn.dot_product_attention(qkv[:, :, 0], qkv[:, :, 1], qkv[:, :, 2])
        return self.proj(o_BLNK.reshape(B, L, D))


class ViTBlock(nnx.Module):
    """x + attn(norm1(x)), then x + mlp(norm2(x)); mlp = Linear -> GELU(tanh) -> Linear."""

    def __init__(self, cfg: ImageEncoderConfig, *, rngs: nnx.Rngs):
        kw = dict(dtype=jnp.dtype(cfg.dtype), param_dtype=jnp.dtype(cfg.param_dtype), rngs=rngs)
        hidden = int(cfg.width * cfg.mlp_ratio)
        self.norm1 = nnx.LayerNorm(cfg.width, epsilon=cfg.eps, **kw)
        self.attn = SelfAttention(cfg, rngs=rngs)
        self.norm2 = nnx.LayerNorm(cfg.width, epsilon=cfg.eps, **kw)
        self.fc1 = nnx.Linear(cfg.width, hidden, **kw)
        self.fc2 = nnx.Linear(hidden, cfg.width, **kw)

    def __call__(self, x_BLD: jax.Array) -> jax.Array:
        x_BLD = x_BLD + self.attn(self.norm1(x_BLD))
        return x_BLD + self.fc2(jax.nn.gelu(self.fc1(self.norm2(x_BLD)), approximate=True))


class ImageEncoder(nnx.Module):
    """CLIP ViT vision tower returning un-pooled tokens after ``blocks_applied`` blocks.

    Args:
      cfg: sizes, the number of blocks that run, and the pixel statistics (``ImageEncoderConfig``).
      rngs: parameter initialisation.
    """

    def __init__(self, cfg: ImageEncoderConfig, *, rngs: nnx.Rngs):
        kw = dict(dtype=jnp.dtype(cfg.dtype), param_dtype=jnp.dtype(cfg.param_dtype), rngs=rngs)
        pdt, std = jnp.dtype(cfg.param_dtype), cfg.width ** -0.5
        self.cfg = cfg
        p = cfg.patch_size
        self.patch_embed = nnx.Conv(3, cfg.width, (p, p), strides=p, padding="VALID", use_bias=False, **kw)
        self.cls_embedding = nnx.Param(std * jax.random.normal(rngs.params(), (cfg.width,), pdt))
        self.pos_embedding = nnx.Param(std * jax.random.normal(rngs.params(), (cfg.num_tokens, cfg.width), pdt))
        self.pre_norm = nnx.LayerNorm(cfg.width, epsilon=cfg.eps, **kw)
        self.blocks = nnx.List([ViTBlock(cfg, rngs=rngs) for _ in range(cfg.num_layers)])
        if cfg.proj_dim:  # CLIP's pooled-embedding head: carried for checkpoint parity, never called
            self.post_norm = nnx.LayerNorm(cfg.width, epsilon=cfg.eps, **kw)
            self.head = nnx.Param(std * jax.random.normal(rngs.params(), (cfg.width, cfg.proj_dim), pdt))

    def embed(self, frames_BHWC: jax.Array) -> jax.Array:
        """Frames in [-1, 1] -> pre-normed token embeddings (B, num_tokens, width), before any block."""
        x = self.patch_embed(preprocess_frames(frames_BHWC, self.cfg))  # (B, S/p, S/p, D)
        B, D = x.shape[0], x.shape[-1]
        cls = jnp.broadcast_to(self.cls_embedding[...].astype(x.dtype), (B, 1, D))
        x = jnp.concatenate([cls, x.reshape(B, -1, D)], axis=1) + self.pos_embedding[...].astype(x.dtype)
        return self.pre_norm(x)

    def __call__(self, frames_BHWC: jax.Array) -> jax.Array:
        """Frames (B, H, W, 3) in [-1, 1] -> tokens (B, num_tokens, width) after the first blocks_applied."""
        x_BLD = self.embed(frames_BHWC)
        for block in self.blocks[:self.cfg.blocks_applied]:
            x_BLD = block(x_BLD)
        return x_BLD
