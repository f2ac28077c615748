"""Camera geometry of the player's view, for the two camera conditionings of ours (both off in the official
model): the per-latent-frame turn read from the mouse windows, and the previous latent shifted by it.

Mouse convention (``spaces.env_action_to_model_vector``, Mineflayer signs): the model's mouse vector is
[cameraX, cameraY] in units of ``CAMERA_SCALE_DEG`` degrees, + = turn left / look up. Turning left moves the
view's content right, looking up moves it down.

``frame_turns`` gives each latent frame's turn (the last ``k`` ticks of its action window are the ticks between
latent frames i - 1 and i; docs/model.md §4.3), ``content_shift`` how far it moves the view's content (camera RoPE
moves the token positions by minus that, ``rope.camera_increments``). ``shift_latents`` moves a latent frame's content by a fractional
number of latent pixels (linear interpolation, edges repeated): ``DiTConfig.camera_warp`` feeds the previous
latent frame shifted by the frame's turn to the patch embedding, so following the camera is a copy of an input
channel instead of a sub-token interpolation the DiT has to learn.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from solaris_env.spaces import CAMERA_SCALE_DEG


def frame_turns(mouse_BPFWA: jax.Array, frames_per_step: int) -> jax.Array:
    """(B, P, F, 2) [yaw (+ left), pitch (+ up)] degrees turned between latent frames i - 1 and i."""
    if mouse_BPFWA.shape[-1] != 2:
        raise ValueError(f"the camera reads [cameraX, cameraY]; the mouse windows have {mouse_BPFWA.shape[-1]} dims")
    return mouse_BPFWA[..., -frames_per_step:, :].astype(jnp.float32).sum(axis=-2) * CAMERA_SCALE_DEG


def content_shift(turns_BPF2: jax.Array, pixels_per_degree: tuple[float, float]) -> jax.Array:
    """(B, P, F, 2) (down, right) latent pixels the view's content moves for the turns: a left turn (+ yaw)
    moves it right, looking up (+ pitch) moves it down. ``pixels_per_degree`` is (height, width)."""
    return jnp.stack([turns_BPF2[..., 1] * pixels_per_degree[0], turns_BPF2[..., 0] * pixels_per_degree[1]], axis=-1)


def _shift_axis(x: jax.Array, shift: jax.Array, axis: int) -> jax.Array:
    """out[i] = x[i - shift] along ``axis`` with linear interpolation, indices clamped (edges repeated).
    ``x`` (N, h, w, C), ``shift`` (N,)."""
    n = x.shape[axis]
    src = jnp.arange(n, dtype=jnp.float32)[None] - shift[:, None]  # (N, n)
    lo = jnp.floor(src)
    frac = src - lo
    lo = jnp.clip(lo.astype(jnp.int32), 0, n - 1)
    hi = jnp.clip(lo + 1, 0, n - 1)
    shape = [x.shape[0], 1, 1, 1]
    shape[axis] = n
    take = lambda idx: jnp.take_along_axis(x, idx.reshape(shape), axis=axis)
    frac = frac.reshape(shape).astype(x.dtype)
    return (1 - frac) * take(lo) + frac * take(hi)


def shift_latents(x_NhwC: jax.Array, shift_N2: jax.Array) -> jax.Array:
    """Move each latent frame's content by (down, right) latent pixels (fractional: linear interpolation;
    the uncovered border repeats the edge). Integer shifts inside the frame are exact."""
    if x_NhwC.ndim != 4 or shift_N2.shape != (x_NhwC.shape[0], 2):
        raise ValueError(f"shift_latents takes x (N, h, w, C) and shift (N, 2); got {x_NhwC.shape}, {shift_N2.shape}")
    shift = shift_N2.astype(jnp.float32)
    return _shift_axis(_shift_axis(x_NhwC, shift[:, 0], 1), shift[:, 1], 2)
