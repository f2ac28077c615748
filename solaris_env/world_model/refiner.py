"""Temporal refiner (ours; off in the official layout, ``VAEConfig.refiner``): keep the pixels of the last
output frame wherever the view has not changed.

Every frame the env shows is a decode of a latent, so even a static view pays the codec's loss (the tiny
VAE reconstructs held-out frames at ~20.5 dB) and the jitter of a freshly sampled latent each step, while the
first frame the user gave is exact. The refiner blends each decoded frame ``D_t`` with the previous output
frame ``Y_{t-1}``, starting from the given first frame:

    Y_0 = first frame
    Y_t = g_t * S_t(Y_{t-1}) + (1 - g_t) * D_t,    g_t = sigmoid(gate(D_t, S_t(D_{t-1}), a_t)) in (0, 1)

``S_t`` moves a frame's content by frame t's camera turn (``camera_shift`` pixels per degree of pitch / yaw,
``camera.content_shift``; linear interpolation, edges repeated), so a turning view carries its kept pixels
along with the turn instead of holding them still; with ``camera_shift`` (0, 0) it is the identity.
``g_t`` is one value per ``pool x pool`` cell of pixels (upsampled by repetition), from a small CNN on the
cell means of the two decoded frames and of their absolute difference, plus the frame's action vector
(``action_dim``) as a per-channel bias: where the decoded view moves or the player acts, g -> 0 (the new
decode); where both say "unchanged", g -> 1 (the earlier pixels, exact at the start). The gate reads only
decoded frames, never its own output, so the gates of a whole clip are one batched call and the blend is an
elementwise scan (``blend``). Trained after the DiT, on the model's own rollouts (``training/refine.py``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from solaris_env.spaces import CAMERA_X_INDEX, CAMERA_Y_INDEX, CAMERA_SCALE_DEG
from solaris_env.world_model.camera import content_shift, shift_latents
from solaris_env.world_model.config import RefinerConfig


def cell_mean(x_NHWC: jax.Array, pool: int) -> jax.Array:
    """Mean over ``pool x pool`` pixel cells: (N, H / pool, W / pool, C)."""
    n, h, w, c = x_NHWC.shape
    if h % pool or w % pool:
        raise ValueError(f"frame {h}x{w} is not divisible by the refiner's pool={pool}")
    return x_NHWC.reshape(n, h // pool, pool, w // pool, pool, c).mean(axis=(2, 4))


def frame_shifts(actions_NTA: jax.Array, pixels_per_degree: tuple[float, float]) -> jax.Array:
    """(N, T, 2) (down, right) pixels each frame's camera turn moves the view's content (its action's mouse)."""
    turns = actions_NTA[..., jnp.array([CAMERA_X_INDEX, CAMERA_Y_INDEX])].astype(jnp.float32) * CAMERA_SCALE_DEG
    return content_shift(turns, pixels_per_degree)


def blend(gates_NTHW1: jax.Array, decoded_NTHW3: jax.Array, prev_NHW3: jax.Array,
          shifts_NT2: jax.Array | None = None) -> jax.Array:
    """Y_t = g_t S_t(Y_{t-1}) + (1 - g_t) D_t over the T frames, Y_{-1} = ``prev``: (N, T, H, W, 3); ``S_t``
    moves the content by ``shifts[:, t]`` pixels (down, right), the identity when ``shifts`` is None."""
    def step(y_prev, inputs):
        g, d, shift = inputs
        if shift is not None:
            y_prev = shift_latents(y_prev, shift)
        y = g * y_prev + (1.0 - g) * d
        return y, y

    tm = lambda x: None if x is None else jnp.moveaxis(x, 1, 0)
    _, ys = jax.lax.scan(step, prev_NHW3, (tm(gates_NTHW1), tm(decoded_NTHW3), tm(shifts_NT2)))
    return jnp.moveaxis(ys, 0, 1)


class Refiner(nnx.Module):
    """The gate network and the blend (module docstring). Frames are model-range floats in [-1, 1]."""

    def __init__(self, cfg: RefinerConfig, *, rngs: nnx.Rngs):
        self.cfg = cfg
        w = cfg.width
        self.conv_in = nnx.Conv(3 + 3 + 1, w, (3, 3), rngs=rngs)  # cell means of D_t, D_{t-1}, |D_t - D_{t-1}|
        self.actions = nnx.Linear(cfg.action_dim, w, rngs=rngs) if cfg.action_dim else None
        self.conv_mid = nnx.List([nnx.Conv(w, w, (3, 3), kernel_dilation=2, rngs=rngs) for _ in range(2)])
        self.conv_out = nnx.Conv(w, 1, (3, 3), rngs=rngs)

    def shifts(self, actions_NTA: jax.Array) -> jax.Array | None:
        """(N, T, 2) pixels each frame moves the previous one (``frame_shifts``), None without camera_shift."""
        return frame_shifts(actions_NTA, self.cfg.camera_shift) if self.cfg.camera_shift_enabled else None

    def gates(self, decoded_NTHW3: jax.Array, prev_decoded_NHW3: jax.Array, actions_NTA: jax.Array) -> jax.Array:
        """g_t of every frame: (N, T, H, W, 1) in (0, 1); frame t's previous decode is frame t - 1's
        (``prev_decoded`` for t = 0), moved by frame t's turn."""
        return self._gates(decoded_NTHW3, prev_decoded_NHW3, actions_NTA, self.shifts(actions_NTA))

    def _gates(self, decoded_NTHW3, prev_decoded_NHW3, actions_NTA, shifts_NT2) -> jax.Array:
        n, t, h, w, _ = decoded_NTHW3.shape
        pool = self.cfg.pool
        before = jnp.concatenate([prev_decoded_NHW3[:, None], decoded_NTHW3[:, :-1]], axis=1)
        flat = lambda x: x.reshape((n * t,) + x.shape[2:])
        d, d_prev = flat(decoded_NTHW3), flat(before)
        if shifts_NT2 is not None:
            d_prev = shift_latents(d_prev, flat(shifts_NT2))  # any (N, H, W, C) frames, not only latents
        change = jnp.abs(d - d_prev).mean(axis=-1, keepdims=True)
        x = self.conv_in(jnp.concatenate([cell_mean(d, pool), cell_mean(d_prev, pool), cell_mean(change, pool)], -1))
        if self.actions is not None:
            x = x + self.actions(flat(actions_NTA.astype(jnp.float32)))[:, None, None, :]
        x = nnx.gelu(x)
        for conv in self.conv_mid:
            x = nnx.gelu(conv(x))
        g = nnx.sigmoid(self.conv_out(x))  # (N*T, H/pool, W/pool, 1)
        g = jnp.repeat(jnp.repeat(g, pool, axis=1), pool, axis=2)
        return g.reshape(n, t, h, w, 1)

    def __call__(self, decoded_NTHW3: jax.Array, prev_decoded_NHW3: jax.Array, prev_frame_NHW3: jax.Array,
                 actions_NTA: jax.Array) -> jax.Array:
        """The refined frames (N, T, H, W, 3) of T decoded frames following ``prev_frame`` (the last output
        frame) and ``prev_decoded`` (the decode it was made from). Streaming in chunks gives the same frames
        as one call on the whole clip."""
        shifts = self.shifts(actions_NTA)
        g = self._gates(decoded_NTHW3, prev_decoded_NHW3, actions_NTA, shifts)
        return blend(g, decoded_NTHW3.astype(jnp.float32), prev_frame_NHW3.astype(jnp.float32), shifts)
