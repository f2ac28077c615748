"""Rotary position embeddings (docs/model.md §3.5 and §4.2).

Both RoPEs rotate interleaved pairs ``(x[2k], x[2k+1])`` by an angle ``pos * inv_freq[k]``, in f32:

- DiT 3D RoPE: the head dim's K/2 pairs are split ``rope_split`` = (frame, height, width) pairs
  (22/21/21 for K=128). Each axis has its own table ``inv_freq[k] = theta ** (-2k / axis_dim)`` with
  ``axis_dim = 2 * pairs`` (theta 10000). Tokens are packed ``(frame, player, h, w)`` and every
  player gets the same (frame, h, w) position: players are told apart only by the player embedding.
- Action-module temporal RoPE (Hunyuan ``rotate_half`` with repeat-interleaved cos/sin, which is the
  same interleaved pairing): only the first ``rope_dims[0]`` dims rotate, by the frame index, with
  theta 256; the height/width parts have position 0 (identity).

Angle builders return ``angles_LJ`` (L positions, J = K/2 pairs); ``apply_rope`` applies them to
``x_BLNK``. ``start_frame`` may be a traced scalar (the cached decode step).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np



def _inv_freq(num_pairs: int, theta: float) -> np.ndarray:
    """(num_pairs,) theta ** (-2k / (2 * num_pairs)) for one axis with its own dim."""
    return theta ** (-np.arange(num_pairs, dtype=np.float64) / num_pairs)


def frame_positions(num_frames: int, start_frame: int | jax.Array = 0) -> jax.Array:
    """(F,) int32 temporal positions start_frame + [0..F)."""
    return jnp.asarray(start_frame, jnp.int32) + jnp.arange(num_frames, dtype=jnp.int32)


def rope_3d_angles_at(rope_split: tuple[int, int, int], theta: float, frame_pos_F: jax.Array, grid_h: int,
                      grid_w: int, num_players: int) -> jax.Array:
    """Angles for tokens packed (frame, player, h, w) with frame f at temporal position frame_pos_F[f].

    Returns (F * P * h * w, sum(rope_split)) f32.
    """
    pf, ph, pw = rope_split
    freq_f = jnp.asarray(_inv_freq(pf, theta), jnp.float32)
    freq_h = jnp.asarray(np.arange(grid_h)[:, None] * _inv_freq(ph, theta)[None], jnp.float32)  # (h, ph)
    freq_w = jnp.asarray(np.arange(grid_w)[:, None] * _inv_freq(pw, theta)[None], jnp.float32)  # (w, pw)
    num_frames = frame_pos_F.shape[0]
    ang_f = frame_pos_F.astype(jnp.float32)[:, None] * freq_f[None]  # (F, pf)
    shape = (num_frames, num_players, grid_h, grid_w)
    ang = jnp.concatenate([
        jnp.broadcast_to(ang_f[:, None, None, None, :], shape + (pf,)),
        jnp.broadcast_to(freq_h[None, None, :, None, :], shape + (ph,)),
        jnp.broadcast_to(freq_w[None, None, None, :, :], shape + (pw,)),
    ], axis=-1)
    return ang.reshape(-1, pf + ph + pw)


def rope_3d_angles(rope_split: tuple[int, int, int], theta: float, num_frames: int, grid_h: int, grid_w: int,
                   num_players: int, start_frame: int | jax.Array = 0) -> jax.Array:
    """(F * P * h * w, K/2) angles for F consecutive frames starting at ``start_frame``."""
    return rope_3d_angles_at(rope_split, theta, frame_positions(num_frames, start_frame), grid_h, grid_w,
                             num_players)


def teacher_forcing_frame_positions(num_frames: int) -> jax.Array:
    """(2F,) positions of ``[clean ; noisy]``: each half counts from 0, so clean j and noisy j share j."""
    half = frame_positions(num_frames, 0)
    return jnp.concatenate([half, half])


def temporal_rope_angles_at(rope_dims: tuple[int, int, int], theta: float, frame_pos_F: jax.Array) -> jax.Array:
    """(F, sum(rope_dims)/2) angles of the action module: the first rope_dims[0]/2 pairs rotate by the
    frame position with theta ** (-2k / rope_dims[0]); the remaining pairs stay at angle 0."""
    rot_pairs = rope_dims[0] // 2
    still_pairs = sum(rope_dims) // 2 - rot_pairs
    inv = jnp.asarray(_inv_freq(rot_pairs, theta), jnp.float32)
    ang = frame_pos_F.astype(jnp.float32)[:, None] * inv[None]
    return jnp.concatenate([ang, jnp.zeros((frame_pos_F.shape[0], still_pairs), jnp.float32)], axis=-1)


def temporal_rope_angles(rope_dims: tuple[int, int, int], theta: float, num_frames: int,
                         start_frame: int | jax.Array = 0) -> jax.Array:
    return temporal_rope_angles_at(rope_dims, theta, frame_positions(num_frames, start_frame))


def apply_rope(x_BLNK: jax.Array, angles_LJ: jax.Array) -> jax.Array:
    """Rotate pairs (x[2k], x[2k+1]) of every head by angles_LJ[l, k] (f32), cast back to x's dtype."""
    *lead, length, heads, head_dim = x_BLNK.shape
    if angles_LJ.shape != (length, head_dim // 2):
        raise ValueError(f"angles shape {angles_LJ.shape} does not match x {x_BLNK.shape}: expected "
                         f"({length}, {head_dim // 2})")
    pairs = x_BLNK.astype(jnp.float32).reshape(*lead, length, heads, head_dim // 2, 2)
    re, im = pairs[..., 0], pairs[..., 1]
    cos = jnp.cos(angles_LJ)[..., None, :]  # (L, 1, J): same rotation for every head
    sin = jnp.sin(angles_LJ)[..., None, :]
    out = jnp.stack([re * cos - im * sin, re * sin + im * cos], axis=-1)
    return out.reshape(x_BLNK.shape).astype(x_BLNK.dtype)
