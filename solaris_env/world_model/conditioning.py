"""First-frame conditioning (docs/model.md §5.4): the ``cond`` channels concatenated to the DiT's noisy latent.

For one player with first frame ``first_frame_BHWC`` (in [-1, 1]) and F latent frames,
``cond_BFhwC = concat([mask_BFhwM, img_BFhwc], -1)`` with C = M + z_dim (4 + 16 = 20 for solaris) and:

- ``img``: the normalised VAE encoding of the pixel video [first_frame, 0, 0, ..., 0] of
  T = 1 + tf * (F - 1) frames. The zeros are in [-1, 1] space (mid-gray frames), so img latents 1..F-1
  are not zero: they are whatever a gray video encodes to, and latent 1 (and later ones, within the
  causal receptive field) also sees frame 0 through the causal time convolutions.
- ``mask`` (M = tf channels, Wan's i2v layout): a per-video-frame mask that is 1 for frame 0 only; frame 0
  is repeated tf times so the T frames become tf * F, which are then folded into channels in groups of tf:
  mask channel c of latent frame i <-> padded frame tf * i + c. Only frame 0 is set, so latent frame 0 has
  all M channels = 1 and every later latent frame has all channels = 0.

With ``cond_encoding="image"`` (VAEConfig; the tiny preset) ``img`` latent 0 is the encoding of the first
frame alone (identical to the "video" layout's latent 0, by causality) and latents 1..F-1 are zero: one
frame is encoded per start instead of 1 + tf * (F - 1), and per-clip training inputs can be cached.

Latent frame 0 is still generated from noise (conditioned on this), not replaced by the encoding.

Streaming (autoregressive rollouts of unbounded length): ``first_frame_cond_start`` encodes the first frame
once and returns the cond slice of latent 0 plus an explicit state (the VAE's causal conv cache);
``first_frame_cond_next`` encodes only the next tf gray frames against that cache and returns the slice for
the next latent frame. The slices equal the corresponding slices of ``first_frame_cond``.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from solaris_env.world_model.vae import CausalVideoVAE


def first_frame_mask(num_latent_frames: int, temporal_factor: int) -> jax.Array:
    """(F, M=temporal_factor) Wan i2v mask: 1 for latent frame 0 (all channels), 0 elsewhere."""
    num_frames = 1 + temporal_factor * (num_latent_frames - 1)
    mask_T = jnp.zeros((num_frames,), jnp.float32).at[0].set(1.0)  # 1 for the given (first) frame only
    padded = jnp.concatenate([jnp.repeat(mask_T[:1], temporal_factor), mask_T[1:]])  # (tf * F,)
    return padded.reshape(num_latent_frames, temporal_factor)  # channel c of latent i = frame tf*i + c


def conditioning_video(first_frame_BHWC: jax.Array, num_frames: int) -> jax.Array:
    """[first_frame, gray x (T - 1)] as a video (B, T, H, W, 3); gray = 0 in [-1, 1] space."""
    gray = jnp.zeros((first_frame_BHWC.shape[0], num_frames - 1, *first_frame_BHWC.shape[1:]), first_frame_BHWC.dtype)
    return jnp.concatenate([first_frame_BHWC[:, None], gray], axis=1)


def _with_mask(img_BFhwc: jax.Array, mask_FM: jax.Array) -> jax.Array:
    B, F, h, w, _ = img_BFhwc.shape
    mask = jnp.broadcast_to(mask_FM[None, :, None, None, :], (B, F, h, w, mask_FM.shape[-1]))
    return jnp.concatenate([mask.astype(img_BFhwc.dtype), img_BFhwc], axis=-1)


def first_frame_cond(vae: CausalVideoVAE, first_frame_BHWC: jax.Array, num_latent_frames: int) -> jax.Array:
    """First frame (B, H, W, 3) in [-1, 1] -> cond (B, F, h, w, M + z_dim), channels ordered [mask, img]."""
    tf = vae.cfg.temporal_factor
    if vae.cfg.cond_encoding == "image":
        img0 = vae.encode(first_frame_BHWC[:, None])  # (B, 1, h, w, c)
        img = jnp.concatenate([img0, jnp.zeros((img0.shape[0], num_latent_frames - 1) + img0.shape[2:],
                                               img0.dtype)], axis=1)
    else:
        img = vae.encode(conditioning_video(first_frame_BHWC, vae.cfg.video_frames(num_latent_frames)))
    return _with_mask(img, first_frame_mask(num_latent_frames, tf))


@struct.dataclass
class FirstFrameCondState:
    """Streaming state: the VAE encoder's causal conv cache after the frames encoded so far."""

    enc_cache: Any
    frame_shape: tuple[int, int, int, int] = struct.field(pytree_node=False)  # (B, H, W, 3)


def first_frame_cond_start(vae: CausalVideoVAE, first_frame_BHWC: jax.Array
                           ) -> tuple[jax.Array, FirstFrameCondState]:
    """Cond slice of latent frame 0, (B, 1, h, w, M + z_dim), and the state for the next latent frames."""
    img, cache = vae.encode_chunked(first_frame_BHWC[:, None])
    mask = jnp.ones((1, vae.cfg.temporal_factor), jnp.float32)
    return _with_mask(img, mask), FirstFrameCondState(cache, tuple(first_frame_BHWC.shape))


def first_frame_cond_next(vae: CausalVideoVAE, state: FirstFrameCondState
                          ) -> tuple[jax.Array, FirstFrameCondState]:
    """Cond slice of the next latent frame (i >= 1): encodes only its tf gray frames against the cache."""
    B, H, W, C = state.frame_shape
    tf = vae.cfg.temporal_factor
    if vae.cfg.cond_encoding == "image":
        h, w, z = H // vae.cfg.spatial_factor, W // vae.cfg.spatial_factor, vae.cfg.z_dim
        return _with_mask(jnp.zeros((B, 1, h, w, z), jnp.float32), jnp.zeros((1, tf), jnp.float32)), state
    img, cache = vae.encode_chunked(jnp.zeros((B, tf, H, W, C), jnp.float32), state.enc_cache)
    return _with_mask(img, jnp.zeros((1, tf), jnp.float32)), state.replace(enc_cache=cache)
