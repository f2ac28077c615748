"""Rollout regression: flow matching on ground-truth targets with the model's OWN rollout as the context.

Stage 3 (Diffusion Forcing) always shows the DiT the true past frames, but an env rollout commits the
model's own frames to the KV cache, and its errors compound (exposure bias). On the shipped tiny model a
rollout whose KV cache holds the true past latents (``training.samples.rollout(teacher_forced=True)``) scores
19.7 dB on held-out segments against 18.1 dB for the free rollout and 19.4 for copy-last-frame: the drift, not
the one-step error, is what loses. Self Forcing (stage 4) attacks the same gap with a distribution-matching
loss through a teacher; this objective is its supervised counterpart (DAgger / scheduled sampling for a
causal video diffusion model), for our small CPU runs whose stage-2 teacher is weak:

    x̂0_0..F-1 = sg(rollout of the generator, every sampler step, committing x̂0 as inference does)
    x_t       = (1 - sigma) x0 + sigma eps,  t independent per (sample, player, frame)  (Diffusion Forcing)
    v         = DiT.forward_teacher_forcing(clean = x̂0, noisy = x_t)  (noisy frame i sees x̂0_{i-W..i-1})
    loss      = mean (v - (eps - x0))^2

i.e. exactly the stage-3 loss, with the clean context frames replaced by what the model itself generated
from the same first frame and actions. The rollout is ``self_forcing.rollout`` with the exit at the last
sampler step (the x0 a rollout commits); its noise comes from the step key.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from flax import nnx

from solaris_env.world_model import flow_matching
from training.objectives import noisy_latents, sample_timesteps
from training.self_forcing import rollout
from training.step import TrainState, apply_gradients


def rollout_regression_loss(graphdef: nnx.GraphDef, params, rest, batch: dict, key: jax.Array) -> jax.Array:
    """Scalar f32 loss (module docstring). ``batch``: ``prepare_batch`` output (x0, cond, context, mouse,
    keyboard; x0 (B, P, F, h, w, C)). Differentiable w.r.t. ``params`` through the teacher-forcing pass only."""
    k_roll, k_t, k_noise = jax.random.split(key, 3)
    cfg = nnx.merge(graphdef, params, rest).cfg
    last = jnp.int32(len(cfg.sampler.ar_timesteps) - 1)
    own = jax.lax.stop_gradient(rollout(graphdef, jax.lax.stop_gradient(params), rest, batch, k_roll, last).x0_BPFhwC)
    x0 = batch["x0"].astype(jnp.float32)
    t_BPF = sample_timesteps(k_t, x0.shape[:3], "diffusion_forcing")
    noise = jax.random.normal(k_noise, x0.shape, jnp.float32)
    dit = nnx.merge(graphdef, params, rest)
    v = dit.forward_teacher_forcing(own, noisy_latents(x0, noise, t_BPF), jnp.zeros(t_BPF.shape, jnp.float32),
                                    t_BPF.astype(jnp.float32), batch["cond"], batch["context"], batch["mouse"],
                                    batch["keyboard"])
    return jnp.mean(jnp.square(v.astype(jnp.float32) - flow_matching.velocity_target(x0, noise)))


def make_rollout_regression_step(graphdef: nnx.GraphDef, tx: optax.GradientTransformation,
                                 ema_decay: float = 0.999) -> Callable:
    """-> jitted ``step(state, batch) -> (state, metrics)`` (``state`` donated), the contract of
    ``training.step.make_train_step``: step n draws its key from ``fold_in(state.rng, n)``."""
    if not 0.0 <= ema_decay < 1.0:
        raise ValueError(f"ema_decay must be in [0, 1), got {ema_decay}")

    def step(state: TrainState, batch: dict) -> tuple[TrainState, dict]:
        key = jax.random.fold_in(state.rng, state.step)
        loss, grads = jax.value_and_grad(lambda p: rollout_regression_loss(graphdef, p, state.rest, batch, key))(
            state.params)
        return apply_gradients(state, loss, grads, tx, ema_decay)

    return jax.jit(step, donate_argnums=(0,))
