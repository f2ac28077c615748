"""Few-step flow-matching samplers (docs/model.md §5.3): x0-prediction with fresh-noise re-noising.

The flow and the step are ``flow_matching`` (``x_t = (1 - sigma) * x0 + sigma * eps``, ``v = eps - x0``,
sigma = t / num_train_timesteps, t on the 0..1000 scale). Every step of a schedule
``t_0 > t_1 > ... > t_n = 0`` does ``flow_matching.sampler_step``:

    v  = denoise_fn(z, t_s)
    x0 = z - sigma_s * v                                   # x0 prediction (f32)
    z  = (1 - sigma_{s+1}) * x0 + sigma_{s+1} * N(0, I)    # FRESH noise, not the previous eps

so after the last step (sigma_n = 0) ``z == x0`` exactly. This is the DMD / consistency-style sampler
of the reference, NOT an Euler ODE solver (docs/model.md §5.3).

A sampler takes a denoiser, never the reverse: ``denoise_fn(x_t, t) -> v`` is any callable (the DiT's
``decode`` closed over its cache and conditioning, a fake predictor in tests, ...); ``t`` is a
scalar f32 array and ``v`` has the shape of ``x_t``. Nothing here imports the network.

Noise keys: ``sample_frame(denoise_fn, z, key, timesteps)`` splits ``key`` into one key per step
(``jax.random.split(key, n_steps)``); step s re-noises with ``jax.random.normal(keys[s], z.shape)``
(drawn for the last step too, where it is multiplied by sigma = 0). Tests replicate this schedule. A caller
may pass the re-noising draws themselves instead (``renoise``: warped noise, ``noise_warp``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from solaris_env.world_model.config import SamplerConfig
from solaris_env.world_model.flow_matching import NUM_TRAIN_TIMESTEPS, sampler_step, sigma_of_timestep

DenoiseFn = Callable[[jax.Array, jax.Array], jax.Array]

# The reference's hard-coded 10-step bidirectional list (docs/model.md §5.3). It is not the shift-5 N-step
# formula: it is floor(shifted_schedule(10, 5/3)) (tested).
REFERENCE_BIDIRECTIONAL_10 = (1000, 937, 869, 795, 714, 625, 526, 416, 294, 156, 0)

# ---------------------------------------------------------------------------------------------
# Schedules (timesteps on the 0..num_train_timesteps scale, final 0 included)
# ---------------------------------------------------------------------------------------------


def ar_schedule(cfg: SamplerConfig) -> np.ndarray:
    """The autoregressive few-step schedule plus the final 0: [1000, 750, 500, 250, 0] by default.

    The commit pass that writes the KV cache runs at the final t = 0 on the x0 of the last step.
    """
    steps = tuple(cfg.ar_timesteps)
    if not steps or any(b >= a for a, b in zip(steps, steps[1:])) or steps[-1] <= 0:
        raise ValueError(f"ar_timesteps must be strictly decreasing and positive, got {steps}")
    if steps[0] > cfg.num_train_timesteps:
        raise ValueError(f"ar_timesteps[0]={steps[0]} exceeds num_train_timesteps={cfg.num_train_timesteps}")
    return np.asarray(steps + (0,), np.float32)


def shifted_schedule(num_steps: int, shift: float, num_train_timesteps: int = NUM_TRAIN_TIMESTEPS) -> np.ndarray:
    """N-step schedule: sigma_k = linspace(1, 0, N + 1)[:-1], sigma' = shift*sigma / (1 + (shift-1)*sigma),
    t = num_train_timesteps * sigma', then 0 appended -> (N + 1,) f32, decreasing from 1000 to 0."""
    if num_steps < 1:
        raise ValueError(f"num_steps must be >= 1, got {num_steps}")
    if shift <= 0:
        raise ValueError(f"shift must be > 0, got {shift}")
    sigma = np.linspace(1.0, 0.0, num_steps + 1, dtype=np.float64)[:-1]
    shifted = shift * sigma / (1.0 + (shift - 1.0) * sigma)
    return np.append(num_train_timesteps * shifted, 0.0).astype(np.float32)


def bidirectional_schedule(cfg: SamplerConfig) -> np.ndarray:
    """The configured N-step shifted schedule (``cfg.bidirectional_steps`` steps, ``cfg.shift``)."""
    return shifted_schedule(cfg.bidirectional_steps, cfg.shift, cfg.num_train_timesteps)


def _check_timesteps(timesteps) -> np.ndarray:
    t = np.asarray(timesteps, np.float32)
    if t.ndim != 1 or t.shape[0] < 2 or t[-1] != 0 or np.any(np.diff(t) >= 0):
        raise ValueError(f"timesteps must be a strictly decreasing 1-D sequence ending in 0, got {t.tolist()}")
    return t


# ---------------------------------------------------------------------------------------------
# Samplers
# ---------------------------------------------------------------------------------------------


def sample_frame(denoise_fn: DenoiseFn, z: jax.Array, key: jax.Array | None, timesteps: Sequence[float],
                 num_train_timesteps: int = NUM_TRAIN_TIMESTEPS, unroll: bool = False,
                 first_v: jax.Array | None = None, renoise: jax.Array | None = None) -> jax.Array:
    """Run the x0 + fresh-noise rule from ``z`` (pure noise at timesteps[0]) down to t = 0.

    Args:
        denoise_fn: ``(x_t, t) -> v``, t a scalar f32 array on the 0..num_train_timesteps scale.
        z: the starting noise, any shape (the AR rollout uses one latent frame, (B, P, 1, H, W, C)).
        key: PRNG key for the re-noising draws (split into one key per step).
        timesteps: decreasing, ending in 0 (``ar_schedule`` / ``shifted_schedule``).
        unroll: trace the steps as straight-line code instead of a loop (same result; lets XLA's cost
            analysis, which counts a loop body once, count every step).
        first_v: the velocity of the first step, ``denoise_fn(z, timesteps[0])``, when the caller has
            computed it already (in a pass fused with other work); the same result.
        renoise: the re-noising draws themselves, (len(timesteps) - 1, *z.shape), step s using ``renoise[s]``,
            instead of drawing them from ``key`` (then ignored; may be None). Warped noise
            (``SamplerConfig.noise``, ``noise_warp``) passes them.
    Returns:
        x0 (f32, shape of z): the prediction of the last step. The denoiser runs len(timesteps) - 1
        times (len(timesteps) - 2 with ``first_v``) inside one ``lax.scan`` (traced once).
    """
    t = _check_timesteps(timesteps)
    if renoise is None:
        keys = jax.random.split(key, t.shape[0] - 1)
        draw = lambda k: jax.random.normal(k, z.shape, jnp.float32)
    else:
        if renoise.shape != (t.shape[0] - 1, *z.shape):
            raise ValueError(f"renoise has shape {renoise.shape}; expected (steps, *z.shape) = "
                             f"{(t.shape[0] - 1, *z.shape)}")
        keys, draw = renoise.astype(jnp.float32), lambda eps: eps

    def update(z_t, v, t_now, t_next, k):
        sigma, sigma_next = (sigma_of_timestep(s, num_train_timesteps) for s in (t_now, t_next))
        z_next = sampler_step(z_t, v, sigma, sigma_next, draw(k))
        return z_next.astype(z_t.dtype)

    def body(z_t, step):
        t_now, t_next, k = step
        return update(z_t, denoise_fn(z_t, t_now), t_now, t_next, k), None

    first = 0
    if first_v is not None:
        if first_v.shape != z.shape:
            raise ValueError(f"first_v has shape {first_v.shape}; expected the shape of z, {z.shape}")
        z, first = update(z, first_v, jnp.float32(t[0]), jnp.float32(t[1]), keys[0]), 1
    # sigma_n = 0, so the final carry is exactly the last x0.
    x0, _ = jax.lax.scan(body, z, (jnp.asarray(t[first:-1]), jnp.asarray(t[first + 1:]), keys[first:]), unroll=unroll)
    return x0.astype(jnp.float32)


def sample_bidirectional(denoise_fn: DenoiseFn, shape: tuple[int, ...], key: jax.Array,
                         timesteps: Sequence[float], num_train_timesteps: int = NUM_TRAIN_TIMESTEPS) -> jax.Array:
    """Sample all frames at once with the same rule (bidirectional model, e.g. x_BPFHWC).

    ``key`` is split into (initial noise, re-noising); returns x0 (f32) of ``shape``.
    """
    k_init, k_steps = jax.random.split(key)
    z = jax.random.normal(k_init, shape, jnp.float32)
    return sample_frame(denoise_fn, z, k_steps, timesteps, num_train_timesteps)
