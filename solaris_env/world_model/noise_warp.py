"""Warped sampling noise (``SamplerConfig.noise_warp``; ours, docs/model.md §5.3): each latent frame's sampler
noises carry the previous frame's, moved with the view's content by the camera turn.

With fresh noise (the reference) every latent frame starts from new Gaussian noise, and the part of a frame that
the few-step sampler takes from its noise changes at random from one frame to the next, also where the view only
turned. Here the noises of frame i (its initial noise and each re-noising draw) are those of frame i - 1 moved
by whole latent pixels along the camera turn, so that noise-made texture travels with the scene; the strip that a
turn uncovers gets fresh noise. Moving by whole pixels keeps the noise exactly white (a permutation plus fresh
draws: interpolating noise would blur and shrink it), and the fractional part of the turn's shift is carried
(``remainder``) so that over several frames the noise moves as far as the content. Walking leaves the noise in
place (moving it with the walk warp measured worse, docs/history.md session 49). ``noise_warp`` = rho mixes:
``rho * moved + sqrt(1 - rho^2) * fresh`` (unit variance for any rho; 1 = moved only, 0 = fresh only).

Pure functions on per-player arrays (leading axis N); ``world_model.Programs`` calls them once per step.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


def whole_pixel_move(remainder_N2: jax.Array, shift_N2: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Split the content shift of this frame plus the carried remainder into whole latent pixels and a new
    remainder: ``move = floor(remainder + shift + 1/2)`` (int32), ``remainder' = remainder + shift - move``,
    in [-1/2, 1/2). Summed over frames the moves track the summed shifts to within half a pixel."""
    total = remainder_N2.astype(jnp.float32) + shift_N2.astype(jnp.float32)
    move = jnp.floor(total + 0.5)
    return move.astype(jnp.int32), total - move


def move_noise(noise_NShwC: jax.Array, move_N2: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(moved, inside): ``moved[..., r, c, :] = noise[..., r - dy, c - dx, :]`` for the (down, right) whole-pixel
    move (dy, dx) of each of the N rows, and ``inside`` (N, h, w) bool, whether ``(r - dy, c - dx)`` is in the
    frame (False: the border the move uncovers, where ``moved`` repeats the edge and must not be used).
    ``noise`` (N, S, h, w, C): S noise draws per frame share the move."""
    if noise_NShwC.ndim != 5 or move_N2.shape != (noise_NShwC.shape[0], 2):
        raise ValueError(f"move_noise takes noise (N, S, h, w, C) and move (N, 2); got {noise_NShwC.shape}, "
                         f"{move_N2.shape}")
    h, w = noise_NShwC.shape[2:4]
    rows = jnp.arange(h)[None, :] - move_N2[:, :1]  # (N, h)
    cols = jnp.arange(w)[None, :] - move_N2[:, 1:]  # (N, w)
    inside = ((rows >= 0) & (rows < h))[:, :, None] & ((cols >= 0) & (cols < w))[:, None, :]
    gather = lambda x, r, c: x[:, r][:, :, c]  # (S, h, w, C): rows, then columns
    return jax.vmap(gather)(noise_NShwC, jnp.clip(rows, 0, h - 1), jnp.clip(cols, 0, w - 1)), inside


def carry_noise(noise_NShwC: jax.Array, remainder_N2: jax.Array, fresh_NShwC: jax.Array, shift_N2: jax.Array,
                rho: float) -> tuple[jax.Array, jax.Array]:
    """The next frame's noises (N, S, h, w, C) and remainder (N, 2): ``rho * moved + sqrt(1 - rho^2) * fresh``
    where ``moved`` (the previous noises moved by the whole-pixel part of ``remainder + shift``,
    ``whole_pixel_move``, ``move_noise``) is inside the frame, ``fresh`` alone in the uncovered border. ``rho``
    is a Python float in [0, 1]; every element stays a unit Gaussian, independent of the others."""
    if not 0.0 <= rho <= 1.0:
        raise ValueError(f"rho must be in [0, 1], got {rho}")
    if fresh_NShwC.shape != noise_NShwC.shape:
        raise ValueError(f"fresh has shape {fresh_NShwC.shape}; expected the noise's, {noise_NShwC.shape}")
    move, remainder = whole_pixel_move(remainder_N2, shift_N2)
    moved, inside = move_noise(noise_NShwC, move)
    mixed = rho * moved + math.sqrt(1.0 - rho * rho) * fresh_NShwC
    return jnp.where(inside[:, None, :, :, None], mixed, fresh_NShwC), remainder
