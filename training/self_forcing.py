"""Stage 4: Self Forcing with DMD (docs/model.md §6.3), checkpointed (the paper's Algorithm 1) and naive.

    graphs, state = create_self_forcing_state(generator, critic, teacher, *make_optimizers(sf_cfg), rng=0)
    generator_step = make_checkpointed_generator_step(graphs, generator_tx, sf_cfg)   # or make_naive_...
    critic_step = make_critic_step(graphs, critic_tx, sf_cfg)
    iteration = make_iteration(generator_step, critic_step, sf_cfg)
    for _ in range(num_iterations):
        step = int(state.iteration)
        state, metrics = iteration(state, batch)       # batch = training.step.prepare_batch(...)
        check_finite(metrics, step)

Models: the generator G (causal, trained), the critic / fake score f (bidirectional, trained) and the
teacher / real score r (bidirectional, frozen). Every ``sf_cfg.generator_every``-th iteration does a
generator update; every iteration a critic update (ratio 5:1 in the reference).

Rollout (§5.3 loop, ``rollout``). An exit index ``s ~ randint(0, n)`` (n = len(ar_timesteps)) is drawn
once per rollout and shared by every frame, player and sample. Per latent frame i: steps 0..s-1 of the
x0 + fresh-noise sampler run without gradient; their result ``x_s^i`` (pure noise if s = 0) is the input
of step s, whose x0 prediction ``x̂0^i = x_s^i - sigma_s v`` is the frame's estimate; a commit pass at
t = 0 on ``sg(x̂0^i)`` writes the frame's keys/values into the rolling cache (window W = cfg.dit.window).

Generator modes are entry points (same signature ``(graphdef, params, rest, batch, key, exit_index)``):

- ``checkpointed_generator_x0`` (the default, "Checkpointed Self Forcing"): the rollout runs under
  stop-gradient and keeps only ``x̂0`` and ``x_s`` of every frame; one parallel teacher-forcing pass over
  ``[x̂0 ; x_s]`` recomputes ``x0 = x_s - sigma_s v(noisy half)``. Gradients flow through the recomputed
  clean keys/values (``kv_backprop=True``) or not (``False``: stop-gradient on the clean half's K/V in
  self-attention and both action branches). Memory O(F).
- ``naive_generator_x0``: differentiates the rolling rollout itself: the exit step and every commit pass
  are on the tape, so the gradient reaches the parameters through the cached keys/values of the window
  (steps before s and the commit *inputs* are stop-gradient, as in the reference). Memory O(F * W):
  every frame keeps its own copy of the W-frame caches for the backward pass.

Both see the same function of the parameters: the teacher-forcing mask reproduces the cached decode
steps exactly (the noisy frame sees the W-1 previous clean frames and itself; clean frame j sees clean
frames j-W+1..j like the commit pass), so with ``kv_backprop=True`` the two modes give the same x0 and
the same gradient up to float rounding (tested). ``kv_backprop=False`` is the original Self Forcing
gradient (no gradient through the cache).

DMD (``dmd_gradient`` / ``dmd_loss``): t' per sample shared over players and frames, x_t' from sg(x0),
``grad = fake_x0 - real_x0`` normalised by ``max(mean|x0 - real_x0|, eps)`` over the non-batch axes,
``nan_to_num`` (nan -> 0, +-inf -> +-clip), clipped to [-clip, clip];
``L_gen = 0.5 mean((x0 - sg(x0 - grad))^2)`` so dL/dx0 = grad / x0.size.
Critic: flow matching MSE of f on the sg'd rollout (t per sample), ``nan_to_num(posinf=1e6)``.

Randomness: iteration n uses ``fold_in(fold_in(state.rng, n), stream)`` with one stream for the generator
step and one for the critic step, each split into (exit index, rollout, t', noise). Deterministic given
the seed; resumes exactly from a checkpointed ``SelfForcingState``.
Shapes: the DiT's stream layout (``dit.py``): latents (B, P, F, h, w, C), t (B, P, F).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import nnx, struct

from solaris_env.world_model import flow_matching, kv_cache
from solaris_env.world_model.action_module import window_at
from solaris_env.world_model.config import WorldModelConfig
from solaris_env.world_model.dit import WorldDiT
from solaris_env.world_model.sampler import ar_schedule
from training.objectives import flow_matching_loss, sample_timesteps
from training.step import TrainState, make_optimizer

# ---------------------------------------------------------------------------------------------
# Configuration and state
# ---------------------------------------------------------------------------------------------

GENERATOR_STREAM, CRITIC_STREAM = 0, 1  # fold-in ids of the two steps' keys within an iteration
CONDITIONING_KEYS = ("cond", "context", "mouse", "keyboard")  # what the rollout reads from a batch


@dataclass(frozen=True, slots=True)
class SelfForcingConfig:
    """Stage-4 hyperparameters (docs/model.md §6.2-§6.3 defaults)."""

    generator_every: int = 5  # generator update every n-th iteration; the critic updates every iteration
    generator_lr: float = 3e-6
    critic_lr: float = 3e-7
    dmd_clip: float = 10.0  # DMD gradient clip, also the value of +-inf after nan_to_num
    dmd_norm_eps: float = 1e-8  # floor of the DMD normaliser mean|x0 - real_x0|
    critic_loss_posinf: float = 1e6  # nan_to_num of the critic loss

    def __post_init__(self):
        if self.generator_every < 1:
            raise ValueError(f"generator_every must be >= 1, got {self.generator_every}")
        for name in ("generator_lr", "critic_lr", "dmd_clip", "dmd_norm_eps"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")

    def replace(self, **kw) -> SelfForcingConfig:
        return dataclasses.replace(self, **kw)


def make_optimizers(sf_cfg: SelfForcingConfig) -> tuple[optax.GradientTransformation, optax.GradientTransformation]:
    """(generator_tx, critic_tx): AdamW of every stage (``step.make_optimizer``) at the two learning rates."""
    return make_optimizer(sf_cfg.generator_lr), make_optimizer(sf_cfg.critic_lr)


class SelfForcingGraphs(NamedTuple):
    """The static halves of the three DiTs (``nnx.split``), kept out of the state pytree."""
    generator: nnx.GraphDef
    critic: nnx.GraphDef
    teacher: nnx.GraphDef


@struct.dataclass
class SelfForcingState:
    """Everything an iteration carries; a pytree of arrays (checkpointable with orbax).

    generator: TrainState of G (its own AdamW state; ``step`` counts generator updates).
    critic: TrainState of f (its own AdamW state; ``step`` counts critic updates).
    teacher_params / teacher_rest: the frozen teacher r (never updated).
    iteration: () int32, iterations done (the critic step, which runs every iteration, increments it).
    rng: (2,) uint32 raw base key.
    """

    generator: TrainState
    critic: TrainState
    teacher_params: Any
    teacher_rest: Any
    iteration: jax.Array
    rng: jax.Array


def create_self_forcing_state(generator: WorldDiT, critic: WorldDiT, teacher: WorldDiT,
                              generator_tx: optax.GradientTransformation, critic_tx: optax.GradientTransformation,
                              rng: int | jax.Array) -> tuple[SelfForcingGraphs, SelfForcingState]:
    """Split the three models once -> (graphs, state). The state owns copies of every parameter.

    In the reference the critic and the teacher both start from the stage-2 (bidirectional) checkpoint,
    so the very first generator update has ``fake_x0 == real_x0`` and a zero DMD gradient.
    """
    for name, model in (("generator", generator), ("critic", critic), ("teacher", teacher)):
        if not isinstance(model, WorldDiT):
            raise TypeError(f"{name} must be a WorldDiT, got {type(model).__name__}")
    if generator.cfg.num_players != teacher.cfg.num_players or critic.cfg != teacher.cfg:
        raise ValueError("critic and teacher must share one config, and the generator's player count must match: "
                         f"generator {generator.cfg.name}/P={generator.cfg.num_players}, critic {critic.cfg.name}, "
                         f"teacher {teacher.cfg.name}")
    gen_def, gen_state = TrainState.create(generator, generator_tx, rng)
    critic_def, critic_state = TrainState.create(critic, critic_tx, rng)
    teacher_def, teacher_params, teacher_rest = nnx.split(teacher, nnx.Param, ...)
    teacher_params, teacher_rest = jax.tree.map(jnp.copy, (teacher_params, teacher_rest))
    state = SelfForcingState(generator=gen_state, critic=critic_state, teacher_params=teacher_params,
                             teacher_rest=teacher_rest, iteration=jnp.zeros((), jnp.int32), rng=jnp.copy(gen_state.rng))
    return SelfForcingGraphs(gen_def, critic_def, teacher_def), state


def step_keys(state: SelfForcingState, stream: int) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """(exit index, rollout, t', noise) keys of this iteration's ``stream`` step."""
    key = jax.random.fold_in(jax.random.fold_in(state.rng, state.iteration), stream)
    return tuple(jax.random.split(key, 4))


# ---------------------------------------------------------------------------------------------
# Rollout (docs/model.md §5.3 with a random exit step)
# ---------------------------------------------------------------------------------------------


class Rollout(NamedTuple):
    x0_BPFhwC: jax.Array  # x̂0 of every frame (the exit step's x0 prediction), f32
    xs_BPFhwC: jax.Array  # x_s of every frame: the exit step's noisy input, f32
    t_exit: jax.Array  # () f32 timestep of the exit step (0..1000 scale)


def sample_exit_index(key: jax.Array, cfg: WorldModelConfig) -> jax.Array:
    """() int32 s ~ randint(0, len(ar_timesteps)): one exit step per rollout."""
    return jax.random.randint(key, (), 0, len(cfg.sampler.ar_timesteps), dtype=jnp.int32)


def _frame_inputs(cfg: WorldModelConfig, batch: dict, i: jax.Array) -> tuple:
    """(cond, context, mouse window, keyboard window) of latent frame i (``decode`` takes the context's K/V)."""
    cond = jax.lax.dynamic_slice_in_dim(batch["cond"], i, 1, axis=2)  # (B, P, 1, h, w, Cc)
    return cond, batch["context"], window_at(batch["mouse"], cfg, i), window_at(batch["keyboard"], cfg, i)


def _denoise_to_exit(dit: WorldDiT, z: jax.Array, inputs: tuple, cache: kv_cache.DiTCache, i: jax.Array,
                     exit_index: jax.Array, timesteps: jax.Array, key: jax.Array) -> jax.Array:
    """Steps 0..s-1 of the x0 + fresh-noise sampler (``flow_matching.sampler_step``) from the noise ``z`` -> x_s
    (f32). No gradient: every input must already be stop-gradient (the dynamic trip count makes this a while
    loop). Step j re-noises with ``normal(split(key, n)[j])``, the convention of ``sampler.sample_frame``."""
    sigmas = flow_matching.sigma_of_timestep(timesteps, dit.cfg.sampler.num_train_timesteps)
    keys = jax.random.split(key, timesteps.shape[0] - 1)
    t_shape = z.shape[:3]

    def body(j, z_t):
        v, _ = dit.decode(z_t, jnp.full(t_shape, timesteps[j]), inputs[0], dit.context_kv(inputs[1]), *inputs[2:],
                          cache, i)
        fresh_eps = jax.random.normal(keys[j], z_t.shape, jnp.float32)
        return flow_matching.sampler_step(z_t, v, sigmas[j], sigmas[j + 1], fresh_eps)

    return jax.lax.fori_loop(0, exit_index, body, z)


def rollout(graphdef: nnx.GraphDef, params, rest, batch: dict, key: jax.Array, exit_index: jax.Array) -> Rollout:
    """The AR rollout with exit step ``exit_index`` over all F latent frames of ``batch``.

    Args:
        graphdef, params, rest: the generator (``nnx.split``); the function is differentiable w.r.t.
            ``params`` through the exit steps and the commit passes (``naive_generator_x0``); call it on
            stop-gradient parameters for the checkpointed mode.
        batch: ``prepare_batch`` output; reads cond (B, P, F, h, w, Cc), context, mouse, keyboard.
        key: frame i draws its noise from ``split(fold_in(key, i))`` = (initial noise, re-noising).
        exit_index: () int32 s in [0, len(ar_timesteps)).
    Returns:
        ``Rollout`` with x̂0 and x_s of shape (B, P, F, h, w, C), f32, and t_s.
    """
    dit = nnx.merge(graphdef, params, rest)
    frozen = nnx.merge(graphdef, jax.lax.stop_gradient(params), rest)  # the steps before the exit
    cfg = dit.cfg
    timesteps = jnp.asarray(ar_schedule(cfg.sampler))  # (n + 1,) ending in 0
    t_exit = timesteps[exit_index]
    sigma_exit = flow_matching.sigma_of_timestep(t_exit, cfg.sampler.num_train_timesteps)
    b, p, f = batch["cond"].shape[:3]
    frame_shape = (b, p, 1, cfg.latent_height, cfg.latent_width, cfg.out_channels)

    def frame(cache, i):
        k_init, k_renoise = jax.random.split(jax.random.fold_in(key, i))
        inputs = _frame_inputs(cfg, batch, i)
        z = jax.random.normal(k_init, frame_shape, jnp.float32)
        x_s = _denoise_to_exit(frozen, z, inputs, jax.lax.stop_gradient(cache), i, exit_index, timesteps, k_renoise)
        v, _ = dit.decode(x_s, jnp.full((b, p, 1), t_exit), inputs[0], dit.context_kv(inputs[1]), *inputs[2:],
                          cache, i)
        x0 = flow_matching.x0_from_velocity(x_s, v, sigma_exit)
        _, cache = dit.decode(jax.lax.stop_gradient(x0), jnp.zeros((b, p, 1)), inputs[0], dit.context_kv(inputs[1]),
                              *inputs[2:], cache, i, commit=1)  # commit
        return cache, (x0[:, :, 0], x_s[:, :, 0])

    cache = kv_cache.init_cache(cfg, b)
    _, (x0_FBPhwC, xs_FBPhwC) = jax.lax.scan(frame, cache, jnp.arange(f))
    to_bpf = lambda a: jnp.moveaxis(a, 0, 2)  # (F, B, P, h, w, C) -> (B, P, F, h, w, C)
    return Rollout(to_bpf(x0_FBPhwC), to_bpf(xs_FBPhwC), t_exit)


# ---------------------------------------------------------------------------------------------
# Generator x0: the two modes (same signature)
# ---------------------------------------------------------------------------------------------


def checkpointed_generator_x0(graphdef: nnx.GraphDef, params, rest, batch: dict, key: jax.Array,
                              exit_index: jax.Array, *, kv_backprop: bool = True) -> jax.Array:
    """Checkpointed Self Forcing: stop-gradient rollout, then ONE teacher-forcing pass over [x̂0 ; x_s].

    Returns x0 = x_s - sigma_s v(noisy half), (B, P, F, h, w, C) f32, differentiable w.r.t. ``params``
    (through the clean half's keys/values too unless ``kv_backprop=False``).
    """
    r = rollout(graphdef, jax.lax.stop_gradient(params), rest, batch, key, exit_index)
    x0_hat, x_s = jax.lax.stop_gradient(r.x0_BPFhwC), jax.lax.stop_gradient(r.xs_BPFhwC)
    dit = nnx.merge(graphdef, params, rest)
    t_BPF = jnp.zeros(x_s.shape[:3])
    v = dit.forward_teacher_forcing(x0_hat, x_s, t_BPF, t_BPF + r.t_exit, batch["cond"], batch["context"],
                                    batch["mouse"], batch["keyboard"], kv_grad=kv_backprop)
    sigma_exit = flow_matching.sigma_of_timestep(r.t_exit, dit.cfg.sampler.num_train_timesteps)
    return flow_matching.x0_from_velocity(x_s, v, sigma_exit)


def naive_generator_x0(graphdef: nnx.GraphDef, params, rest, batch: dict, key: jax.Array,
                       exit_index: jax.Array) -> jax.Array:
    """Naive sliding-window Self Forcing: x̂0 of the rollout itself, differentiated through the exit steps
    and the rolling caches of the commit passes. (B, P, F, h, w, C) f32."""
    return rollout(graphdef, params, rest, batch, key, exit_index).x0_BPFhwC


GeneratorX0 = Callable[..., jax.Array]  # (graphdef, params, rest, batch, key, exit_index) -> x0_BPFhwC

# ---------------------------------------------------------------------------------------------
# DMD and critic objectives (pure)
# ---------------------------------------------------------------------------------------------


def score_x0(dit: WorldDiT, x_t: jax.Array, t_BPF: jax.Array, batch: dict, clean_BPFhwC: jax.Array) -> jax.Array:
    """x0 prediction of a bidirectional score model: x_t - sigma v(x_t, t), f32. ``clean_BPFhwC``: the clean
    latents x_t was noised from, whose previous frames the camera warp reads, as the score models were trained on
    clean previous frames (``training.step``); the DiT ignores them without the warp."""
    v = dit.forward_bidirectional(x_t, t_BPF.astype(jnp.float32), *(batch[k] for k in CONDITIONING_KEYS),
                                  clean=jax.lax.stop_gradient(clean_BPFhwC))
    sigma = flow_matching.sigma_BPF111(t_BPF, dit.cfg.sampler.num_train_timesteps)
    return flow_matching.x0_from_velocity(x_t, v, sigma)


def dmd_gradient(x0: jax.Array, real_x0: jax.Array, fake_x0: jax.Array, sf_cfg: SelfForcingConfig) -> jax.Array:
    """``fake_x0 - real_x0`` / max(mean|x0 - real_x0| over non-batch axes, eps), nan -> 0, +-inf -> +-clip,
    clipped to [-clip, clip]. No gradient flows through the result."""
    x0, real_x0, fake_x0 = (jax.lax.stop_gradient(a.astype(jnp.float32)) for a in (x0, real_x0, fake_x0))
    axes = tuple(range(1, x0.ndim))
    normaliser = jnp.maximum(jnp.mean(jnp.abs(x0 - real_x0), axis=axes, keepdims=True), sf_cfg.dmd_norm_eps)
    grad = (fake_x0 - real_x0) / normaliser
    grad = jnp.nan_to_num(grad, nan=0.0, posinf=sf_cfg.dmd_clip, neginf=-sf_cfg.dmd_clip)
    return jnp.clip(grad, -sf_cfg.dmd_clip, sf_cfg.dmd_clip)


def dmd_loss(x0: jax.Array, grad: jax.Array) -> jax.Array:
    """0.5 mean((x0 - sg(x0 - grad))^2): its gradient w.r.t. x0 is grad / x0.size."""
    x0 = x0.astype(jnp.float32)
    return 0.5 * jnp.mean(jnp.square(x0 - jax.lax.stop_gradient(x0 - grad)))


def generator_dmd_loss(x0_fn: GeneratorX0, graphs: SelfForcingGraphs, params, state: SelfForcingState, batch: dict,
                       keys: tuple, sf_cfg: SelfForcingConfig) -> tuple[jax.Array, dict]:
    """The generator objective as a function of the generator ``params`` -> (L_gen, aux)."""
    k_exit, k_rollout, k_t, k_noise = keys
    cfg = state_cfg(graphs, state)
    exit_index = sample_exit_index(k_exit, cfg)
    x0 = x0_fn(graphs.generator, params, state.generator.rest, batch, k_rollout, exit_index)
    x0_sg = jax.lax.stop_gradient(x0)
    t_BPF = sample_timesteps(k_t, x0.shape[:3], "standard")  # t' per sample, shared over P and F
    sigma = flow_matching.sigma_BPF111(t_BPF, cfg.sampler.num_train_timesteps)
    x_t = flow_matching.noise(x0_sg, jax.random.normal(k_noise, x0.shape, jnp.float32), sigma)
    teacher = nnx.merge(graphs.teacher, state.teacher_params, state.teacher_rest)
    critic = nnx.merge(graphs.critic, jax.lax.stop_gradient(state.critic.params), state.critic.rest)
    real_x0 = jax.lax.stop_gradient(score_x0(teacher, x_t, t_BPF, batch, x0_sg))
    fake_x0 = jax.lax.stop_gradient(score_x0(critic, x_t, t_BPF, batch, x0_sg))
    grad = dmd_gradient(x0_sg, real_x0, fake_x0, sf_cfg)
    aux = {"exit_index": exit_index, "dmd_grad_abs_mean": jnp.mean(jnp.abs(grad))}
    return dmd_loss(x0, grad), aux


def critic_loss(critic: WorldDiT, generated_BPFhwC: jax.Array, batch: dict, t_BPF: jax.Array, noise: jax.Array,
                sf_cfg: SelfForcingConfig) -> jax.Array:
    """Flow matching MSE of the critic on sg(generated frames), nan -> 0, +inf -> ``critic_loss_posinf``."""
    generated = jax.lax.stop_gradient(generated_BPFhwC)  # the warp reads its clean previous frames from it
    forward = functools.partial(critic.forward_bidirectional, clean=generated)
    loss = flow_matching_loss(forward, generated, *(batch[k] for k in CONDITIONING_KEYS), t_BPF, noise)
    return jnp.nan_to_num(loss, nan=0.0, posinf=sf_cfg.critic_loss_posinf)


def state_cfg(graphs: SelfForcingGraphs, state: SelfForcingState) -> WorldModelConfig:
    """The generator's config (static; read from the merged module's ``cfg``)."""
    return nnx.merge(graphs.generator, state.generator.params, state.generator.rest).cfg


# ---------------------------------------------------------------------------------------------
# Jitted steps and the iteration
# ---------------------------------------------------------------------------------------------


def _apply(train: TrainState, grads, tx: optax.GradientTransformation) -> tuple[TrainState, dict]:
    updates, opt_state = tx.update(grads, train.opt_state, train.params)
    params = optax.apply_updates(train.params, updates)
    metrics = {"grad_norm": optax.tree.norm(grads), "param_norm": optax.tree.norm(params),
               "update_norm": optax.tree.norm(updates)}
    return train.replace(params=params, opt_state=opt_state, step=train.step + 1), metrics


def _make_generator_step(x0_fn: GeneratorX0, graphs: SelfForcingGraphs, tx: optax.GradientTransformation,
                         sf_cfg: SelfForcingConfig) -> Callable:
    def generator_step(state: SelfForcingState, batch: dict) -> tuple[SelfForcingState, dict]:
        keys = step_keys(state, GENERATOR_STREAM)
        loss_fn = lambda params: generator_dmd_loss(x0_fn, graphs, params, state, batch, keys, sf_cfg)
        (loss, aux), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.generator.params)
        generator, metrics = _apply(state.generator, grads, tx)
        return state.replace(generator=generator), {"loss": loss, **aux, **metrics}

    return jax.jit(generator_step, donate_argnums=(0,))


def make_checkpointed_generator_step(graphs: SelfForcingGraphs, tx: optax.GradientTransformation,
                                     sf_cfg: SelfForcingConfig, *, kv_backprop: bool = True) -> Callable:
    """-> jitted ``generator_step(state, batch) -> (state, metrics)`` with Checkpointed Self Forcing
    (``state`` donated). metrics: loss, exit_index, dmd_grad_abs_mean, grad/param/update norms."""
    x0_fn = lambda *a: checkpointed_generator_x0(*a, kv_backprop=kv_backprop)
    return _make_generator_step(x0_fn, graphs, tx, sf_cfg)


def make_naive_generator_step(graphs: SelfForcingGraphs, tx: optax.GradientTransformation,
                              sf_cfg: SelfForcingConfig) -> Callable:
    """-> jitted generator step that backpropagates through the rolling rollout (for comparison)."""
    return _make_generator_step(naive_generator_x0, graphs, tx, sf_cfg)


def make_critic_step(graphs: SelfForcingGraphs, tx: optax.GradientTransformation,
                     sf_cfg: SelfForcingConfig) -> Callable:
    """-> jitted ``critic_step(state, batch) -> (state, metrics)``: a stop-gradient rollout of the current
    generator (its own exit index), then one flow-matching update of the critic; increments
    ``state.iteration``. metrics: loss, exit_index, grad/param/update norms."""

    def critic_step(state: SelfForcingState, batch: dict) -> tuple[SelfForcingState, dict]:
        k_exit, k_rollout, k_t, k_noise = step_keys(state, CRITIC_STREAM)
        gen = state.generator
        exit_index = sample_exit_index(k_exit, state_cfg(graphs, state))
        generated = rollout(graphs.generator, gen.params, gen.rest, batch, k_rollout, exit_index).x0_BPFhwC
        t_BPF = sample_timesteps(k_t, generated.shape[:3], "standard")
        noise = jax.random.normal(k_noise, generated.shape, jnp.float32)

        def loss_fn(params):
            critic = nnx.merge(graphs.critic, params, state.critic.rest)
            return critic_loss(critic, generated, batch, t_BPF, noise, sf_cfg)

        loss, grads = jax.value_and_grad(loss_fn)(state.critic.params)
        critic, metrics = _apply(state.critic, grads, tx)
        new_state = state.replace(critic=critic, iteration=state.iteration + 1)
        return new_state, {"loss": loss, "exit_index": exit_index, **metrics}

    return jax.jit(critic_step, donate_argnums=(0,))


def make_iteration(generator_step: Callable, critic_step: Callable, sf_cfg: SelfForcingConfig) -> Callable:
    """-> ``iteration(state, batch) -> (state, metrics)``: a generator update when
    ``iteration % generator_every == 0``, then always a critic update. Reads ``state.iteration`` on the host;
    ``state`` is donated. metrics are namespaced ``generator/...`` (only on generator iterations) and
    ``critic/...``."""

    def iteration(state: SelfForcingState, batch: dict) -> tuple[SelfForcingState, dict]:
        metrics = {}
        if int(state.iteration) % sf_cfg.generator_every == 0:
            state, gen_metrics = generator_step(state, batch)
            metrics.update({f"generator/{k}": v for k, v in gen_metrics.items()})
        state, critic_metrics = critic_step(state, batch)
        metrics.update({f"critic/{k}": v for k, v in critic_metrics.items()})
        return state, metrics

    return iteration


def conditioning_batch(batch: dict) -> dict:
    """The part of a ``prepare_batch`` dict Self Forcing reads (the GT future frames x0 are unused)."""
    missing = [k for k in CONDITIONING_KEYS if k not in batch]
    if missing:
        raise ValueError(f"batch is missing {missing}; expected the keys {CONDITIONING_KEYS} of prepare_batch")
    return {k: batch[k] for k in CONDITIONING_KEYS}

