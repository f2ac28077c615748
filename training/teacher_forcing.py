"""Teacher forcing: flow matching of each frame from the TRUE past, the condition a rollout step is in.

Stage 3 (Diffusion Forcing) noises every latent frame of a clip at its own level and runs one causal pass, so
the frame a loss term denoises sees a past that is itself noised at random levels: a clean past, the case of
every env step (the rollout commits its frames at t = 0), is a rare draw. This objective separates the two
roles with the DiT's teacher-forcing pass (``WorldDiT.forward_teacher_forcing``, docs/model.md §6.3): the
past frames are the true latents, lightly noised as augmentation, and every frame is denoised from them:

    c_i  = (1 - s_i) x0_i + s_i eps'_i,   t'_i ~ U{0..CONTEXT_NOISE_MAX} independent per (sample, player, frame)
    x_i  = (1 - sigma_i) x0_i + sigma_i eps_i,   t_i ~ U{0..1000} independent (as Diffusion Forcing)
    v    = DiT.forward_teacher_forcing(clean = c, noisy = x, t_clean = t', t_noisy = t)   (frame i sees c_{i-W..i-1})
    loss = mean (v - (eps - x0))^2

The context noise (GameNGen's noise augmentation) shows the model imperfect pasts with their noise level, so
it learns to correct them instead of copying them. One pass covers twice the frames of a stage-3 pass. Run by
name on a finished stage 3 (``solaris-train mp-teacher``); docs/training.md.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from flax import nnx

from solaris_env.world_model import flow_matching
from training.objectives import noisy_latents, sample_timesteps
from training.step import TrainState, apply_gradients

# The largest timestep of the context's noise augmentation (sigma <= 0.25; 0 = a clean past).
CONTEXT_NOISE_MAX = 250


def teacher_forcing_loss(graphdef: nnx.GraphDef, params, rest, batch: dict, key: jax.Array,
                         context_noise_max: int = CONTEXT_NOISE_MAX) -> jax.Array:
    """Scalar f32 loss (module docstring). ``batch``: ``prepare_batch`` output (x0 (B, P, F, h, w, C), cond,
    context, mouse, keyboard)."""
    k_ctx_t, k_ctx_noise, k_t, k_noise = jax.random.split(key, 4)
    x0 = batch["x0"].astype(jnp.float32)
    t_ctx = jax.random.randint(k_ctx_t, x0.shape[:3], 0, context_noise_max + 1, dtype=jnp.int32)
    past = noisy_latents(x0, jax.random.normal(k_ctx_noise, x0.shape, jnp.float32), t_ctx)
    t_BPF = sample_timesteps(k_t, x0.shape[:3], "diffusion_forcing")
    noise = jax.random.normal(k_noise, x0.shape, jnp.float32)
    dit = nnx.merge(graphdef, params, rest)
    v = dit.forward_teacher_forcing(past, noisy_latents(x0, noise, t_BPF), t_ctx.astype(jnp.float32),
                                    t_BPF.astype(jnp.float32), batch["cond"], batch["context"], batch["mouse"],
                                    batch["keyboard"], remat=False)
    return jnp.mean(jnp.square(v.astype(jnp.float32) - flow_matching.velocity_target(x0, noise)))


def make_teacher_forcing_step(graphdef: nnx.GraphDef, tx: optax.GradientTransformation,
                              ema_decay: float = 0.999) -> Callable:
    """-> jitted ``step(state, batch) -> (state, metrics)`` (``state`` donated), the contract of
    ``training.step.make_train_step``: step n draws its key from ``fold_in(state.rng, n)``."""
    if not 0.0 <= ema_decay < 1.0:
        raise ValueError(f"ema_decay must be in [0, 1), got {ema_decay}")

    def step(state: TrainState, batch: dict) -> tuple[TrainState, dict]:
        key = jax.random.fold_in(state.rng, state.step)
        loss, grads = jax.value_and_grad(lambda p: teacher_forcing_loss(graphdef, p, state.rest, batch, key))(
            state.params)
        return apply_gradients(state, loss, grads, tx, ema_decay)

    return jax.jit(step, donate_argnums=(0,))
