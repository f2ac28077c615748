"""Flow-matching objective of the bidirectional and causal stages (docs/model.md §6.1).

    x_sigma = (1 - sigma) * x0 + sigma * eps,   sigma = t / 1000,   target v = eps - x0,
    loss = mean over every element of (v_theta - (eps - x0))^2, in f32.

The rules themselves are ``solaris_env.world_model.flow_matching``.

Timesteps are integers ``t ~ randint(0, 1001)`` (0..1000 inclusive), no shift, no weighting; the DiT
receives ``t`` itself. Two noise types:

- ``standard`` (stages 1-2): one t per sample, shared by all players and latent frames;
- ``diffusion_forcing`` (stage 3): an independent t per (sample, player, latent frame).

The stage is chosen by the DiT entry point passed in (``dit.forward_bidirectional`` or
``dit.forward_causal``), never by a flag here: these functions know nothing about masks.
Shapes are the DiT's stream layout (``dit.py``): x0 (B, P, F, h, w, C), t (B, P, F).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from solaris_env.world_model import flow_matching
from solaris_env.world_model.flow_matching import NUM_TRAIN_TIMESTEPS

NOISE_TYPES = ("standard", "diffusion_forcing")

# dit_forward(x, t, cond, context, mouse, keyboard) -> v, shaped like x
DiTForward = Callable[[jax.Array, jax.Array, jax.Array, jax.Array, jax.Array, jax.Array], jax.Array]


def sample_timesteps(key: jax.Array, shape_BPF: tuple[int, int, int], noise_type: str) -> jax.Array:
    """Integer timesteps (B, P, F) int32 in [0, NUM_TRAIN_TIMESTEPS].

    ``standard`` draws one t per sample and broadcasts it over players and frames;
    ``diffusion_forcing`` draws every (sample, player, frame) independently.
    """
    if noise_type not in NOISE_TYPES:
        raise ValueError(f"noise_type must be one of {NOISE_TYPES}, got {noise_type!r}")
    if len(shape_BPF) != 3:
        raise ValueError(f"shape_BPF must be (B, P, F), got {shape_BPF}")
    b, p, f = shape_BPF
    draw_shape = (b, 1, 1) if noise_type == "standard" else (b, p, f)
    t = jax.random.randint(key, draw_shape, 0, NUM_TRAIN_TIMESTEPS + 1, dtype=jnp.int32)
    return jnp.broadcast_to(t, (b, p, f))


def noisy_latents(x0_BPFhwC: jax.Array, noise_BPFhwC: jax.Array, t_BPF: jax.Array) -> jax.Array:
    """x_sigma = (1 - sigma) x0 + sigma eps with sigma = t / 1000 per (sample, player, frame), f32."""
    return flow_matching.noise(x0_BPFhwC, noise_BPFhwC, flow_matching.sigma_BPF111(t_BPF))


def flow_matching_loss(dit_forward: DiTForward, x0: jax.Array, cond: jax.Array, context: jax.Array,
                       mouse: jax.Array, keyboard: jax.Array, t: jax.Array, noise: jax.Array,
                       weight: jax.Array | None = None) -> jax.Array:
    """Scalar f32 MSE between the predicted velocity and ``noise - x0``; with ``weight`` (B, P, F, h, w) >= 0 a
    weighted mean over the latent cells (sum(w * err) / sum(w), the channels averaged): a uniform weight gives
    the plain loss.

    Args:
        dit_forward: a DiT entry point (bound method), e.g. ``dit.forward_causal``.
        x0: clean latents (B, P, F, h, w, C).
        cond, context, mouse, keyboard: the DiT's conditioning inputs (shapes in ``dit.py``).
        t: integer timesteps (B, P, F) on the 0..1000 scale (``sample_timesteps``).
        noise: standard normal, shaped like ``x0``.
    """
    if noise.shape != x0.shape or t.shape != x0.shape[:3]:
        raise ValueError(f"noise {noise.shape} must equal x0 {x0.shape} and t {t.shape} must be x0's (B, P, F) "
                         f"{x0.shape[:3]}")
    x_sigma = noisy_latents(x0, noise, t)
    v_pred = dit_forward(x_sigma, t.astype(jnp.float32), cond, context, mouse, keyboard)
    err = jnp.square(v_pred.astype(jnp.float32) - flow_matching.velocity_target(x0, noise))
    if weight is None:
        return jnp.mean(err)
    if weight.shape != x0.shape[:-1]:
        raise ValueError(f"weight {weight.shape} must be x0's cells (B, P, F, h, w) {x0.shape[:-1]}")
    weight = weight.astype(jnp.float32)
    return jnp.sum(weight * jnp.mean(err, axis=-1)) / jnp.sum(weight)
