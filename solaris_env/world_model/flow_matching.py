"""The flow-matching rules, once (objective: docs/model.md §6.1; sampler step: §5.3).

    x_σ = (1 − σ)·x0 + σ·ε,   v = ε − x0,   σ = t / NUM_TRAIN_TIMESTEPS   (t on the 0..1000 scale)

Pure jnp, results in f32; ``sigma`` is a scalar or broadcasts against the latents (``sigma_BPF111``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

# t runs over 0..NUM_TRAIN_TIMESTEPS; SamplerConfig.num_train_timesteps is the same number (config.py stays jax-free).
NUM_TRAIN_TIMESTEPS = 1000


def sigma_of_timestep(t, num_train_timesteps: int = NUM_TRAIN_TIMESTEPS) -> jax.Array:
    """σ = t / num_train_timesteps, f32, shaped like ``t``. Computed as t · (1 / num_train_timesteps), the form XLA
    compiles a division by a constant to, so eager, traced and compiled calls agree bit for bit."""
    return jnp.asarray(t).astype(jnp.float32) * (1.0 / num_train_timesteps)


def sigma_BPF111(t_BPF: jax.Array, num_train_timesteps: int = NUM_TRAIN_TIMESTEPS) -> jax.Array:
    """σ per (sample, player, frame): (B, P, F) -> (B, P, F, 1, 1, 1) f32, broadcasts over (B, P, F, h, w, C)."""
    return sigma_of_timestep(t_BPF, num_train_timesteps)[..., None, None, None]


def noise(x0: jax.Array, eps: jax.Array, sigma) -> jax.Array:
    """x_σ = (1 − σ)·x0 + σ·ε, f32 (σ = 0 gives x0, σ = 1 gives ε)."""
    return (1.0 - sigma) * x0.astype(jnp.float32) + sigma * eps.astype(jnp.float32)


def velocity_target(x0: jax.Array, eps: jax.Array) -> jax.Array:
    """v = ε − x0, f32: the regression target of the objective."""
    return eps.astype(jnp.float32) - x0.astype(jnp.float32)


def x0_from_velocity(x_t: jax.Array, v: jax.Array, sigma) -> jax.Array:
    """x0 = x_σ − σ·v, f32: the x0 prediction of a velocity."""
    return x_t.astype(jnp.float32) - sigma * v.astype(jnp.float32)


def eps_from_velocity(x_t: jax.Array, v: jax.Array, sigma) -> jax.Array:
    """ε = x_σ + (1 − σ)·v, f32: the noise a velocity predicts."""
    return x_t.astype(jnp.float32) + (1.0 - sigma) * v.astype(jnp.float32)


def sampler_step(x_t: jax.Array, v: jax.Array, sigma, sigma_next, fresh_eps: jax.Array) -> jax.Array:
    """One step of the few-step sampler: predict x0 at σ and re-noise it to σ_next with the fresh noise
    ``fresh_eps`` ~ N(0, I), ``noise(x0, fresh_eps, σ_next)``; f32 shaped like ``x_t``. σ_next = 0 returns x0
    exactly."""
    return noise(x0_from_velocity(x_t, v, sigma), fresh_eps, sigma_next)
