"""Jitted train steps of the flow-matching stages (docs/model.md §6.1-§6.2), functional NNX.

    graphdef, state = TrainState.create(dit, make_optimizer(1e-4), rng=0)
    train_step = make_train_step(graphdef, "forward_causal", "diffusion_forcing", tx)
    batch = prepare_batch(vae, image_encoder, obs_BTPHW3, act_BTP25, cfg)   # frozen VAE / encoder
    for _ in range(num_steps):
        step = int(state.step)              # host copy before the state is donated
        state, metrics = train_step(state, batch)
        check_finite(metrics, step)         # raises NonFiniteError naming the step

The DiT is split once (``nnx.split``); the step is a pure function of ``(TrainState, batch)`` jitted with
the state donated, merging the module inside. The stage is the entry point name (bidirectional for
stages 1-2 with ``standard`` noise, causal for stage 3 with ``diffusion_forcing``), not a flag.
Randomness: the per-step key is ``fold_in(state.rng, state.step)`` split into (timesteps, noise), so a
run is deterministic given the seed and resumes exactly from a checkpointed state.
"""

from __future__ import annotations

import functools

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx, struct

from solaris_env.world_model.action_module import left_pad_actions
from solaris_env.world_model.conditioning import first_frame_cond
from solaris_env.world_model.config import WorldModelConfig
from solaris_env.world_model.dit import to_stream
from solaris_env.world_model.world_model import frames_to_model
from training.objectives import NOISE_TYPES, flow_matching_loss, sample_timesteps

# DiT entry points with the (x, t, cond, context, mouse, keyboard) signature of the objective.
FLOW_MATCHING_ENTRY_POINTS = ("forward_bidirectional", "forward_causal")
BATCH_KEYS = ("x0", "cond", "context", "mouse", "keyboard")

# ---------------------------------------------------------------------------------------------
# Optimiser and state
# ---------------------------------------------------------------------------------------------


def make_optimizer(lr: float) -> optax.GradientTransformation:
    """AdamW of every stage (docs/model.md §6.2): b1 0.9, b2 0.95, eps 1e-8, no weight decay, no clipping, the
    spec's constant LR."""
    return optax.adamw(optax.constant_schedule(lr), b1=0.9, b2=0.95, eps=1e-8, weight_decay=0.0)


@struct.dataclass
class TrainState:
    """Everything a train step carries; a pytree (checkpointable with orbax), the graphdef kept apart.

    params: the DiT's ``nnx.Param`` state (trained).
    rest: any other module state (not trained; empty for the DiT).
    opt_state: the optax state of ``params``.
    step: () int32, the number of updates applied so far.
    rng: (2,) uint32 raw base key; step n uses ``fold_in(rng, n)``.
    ema: an exponential moving average of ``params`` (``ema_update``), or None when the stage keeps none.
    """

    params: Any
    rest: Any
    opt_state: Any
    step: jax.Array
    rng: jax.Array
    ema: Any = None

    @classmethod
    def create(cls, model: nnx.Module, tx: optax.GradientTransformation, rng: int | jax.Array, ema: bool = False
               ) -> tuple[nnx.GraphDef, TrainState]:
        """Split ``model`` once -> (graphdef, state). The state owns copies of the parameters, so donating
        it to the train step never invalidates ``model``'s own arrays. ``ema``: keep a moving average of the
        parameters, starting from them."""
        graphdef, params, rest = nnx.split(model, nnx.Param, ...)
        key = jax.random.PRNGKey(rng) if isinstance(rng, (int, np.integer)) else jnp.asarray(rng, jnp.uint32)

        def build(params, rest, key):  # one program: eager, each leaf's copy and optimiser slots compile alone
            copy = lambda tree: jax.tree.map(jnp.copy, tree)
            return cls(params=copy(params), rest=copy(rest), opt_state=tx.init(params),
                       step=jnp.zeros((), jnp.int32), rng=key, ema=copy(params) if ema else None)

        return graphdef, jax.jit(build)(params, rest, key)

    @property
    def final_params(self) -> Any:
        """The parameters a finished stage saves: the moving average when kept, else the trained ones."""
        return self.params if self.ema is None else self.ema


def ema_decay_at(decay: float, step):
    """The EMA decay applied after update ``step`` (0-based): ``min(decay, (1 + step) / (10 + step))``, so the
    average forgets its starting point (the previous stage's weights) within the first ~100 updates instead of
    weighting it by ``decay ** steps``."""
    return jnp.minimum(decay, (1.0 + step) / (10.0 + step))


def ema_update(ema: Any, params: Any, decay) -> Any:
    """``ema + (1 - decay) * (params - ema)`` leaf by leaf, in each leaf's dtype."""
    return jax.tree.map(lambda e, p: (e + (1.0 - decay) * (p - e)).astype(e.dtype), ema, params)


# ---------------------------------------------------------------------------------------------
# Batch -> model inputs (frozen VAE and image encoder)
# ---------------------------------------------------------------------------------------------


def prepare_batch(vae, image_encoder, obs_BTPHW3: jax.Array, act_BTP25: jax.Array, cfg: WorldModelConfig
                  ) -> dict[str, jax.Array]:
    """Video + actions -> the DiT's inputs in its stream layout (docs/model.md §7.3, §5.4). Traceable.

    Args:
        vae: the frozen ``CausalVideoVAE`` (x0 = normalised posterior mean, no sampling).
        image_encoder: the frozen ``ImageEncoder`` (context tokens of each player's first frame).
        obs_BTPHW3: uint8 frames, T = 1 + k * (F - 1), H/W = the config's frame size.
        act_BTP25: model action vectors (keyboard 23 flags, then mouse yaw/pitch), one per frame.
        cfg: the world-model config.
    Returns:
        dict with x0 (B, P, F, h, w, C), cond (B, P, F, h, w, Cc), context (B, P, M, Ce) and left-padded
        mouse (B, P, T_pad, 2) / keyboard (B, P, T_pad, 23), T_pad = k * (F - 1) + action_window;
        P and channels as ``dit.to_stream`` gives them (players in channels for ``concat``).
    """
    b, t, p, h, w, _ = obs_BTPHW3.shape
    if (p, h, w) != (cfg.num_players, cfg.frame_height, cfg.frame_width) or act_BTP25.shape[:3] != (b, t, p):
        raise ValueError(f"obs {obs_BTPHW3.shape} / act {act_BTP25.shape} do not match (B, T, P={cfg.num_players}, "
                         f"H={cfg.frame_height}, W={cfg.frame_width}, 3) / (B, T, P, 25)")
    num_frames = cfg.vae.latent_frames(t)  # raises unless T = 1 + k * (F - 1)
    if cfg.dit.partner_map:
        raise ValueError("dit.partner_map needs the players' poses, which frames and actions do not carry: train and "
                         "sample it from latent clips (training.latents, LatentClips.with_poses)")
    video = frames_to_model(obs_BTPHW3).transpose(0, 2, 1, 3, 4, 5).reshape(b * p, t, h, w, 3)  # (B*P, T, H, W, 3)
    first_frames = video[:, 0]
    x0 = vae.encode(video)  # (B*P, F, h, w, C)
    cond = first_frame_cond(vae, first_frames, num_frames)  # (B*P, F, h, w, mask + C)
    context = image_encoder(first_frames)  # (B*P, M, Ce)
    unfold = lambda a: to_stream(cfg, jax.lax.stop_gradient(a).reshape((b, p) + a.shape[1:]))
    actions = left_pad_actions(act_BTP25.astype(jnp.float32).transpose(0, 2, 1, 3), cfg.action_left_padding)
    kb = cfg.action.keyboard_dim
    return {"x0": unfold(x0), "cond": unfold(cond), "context": unfold(context),
            "mouse": to_stream(cfg, actions[..., kb:]), "keyboard": to_stream(cfg, actions[..., :kb])}


# ---------------------------------------------------------------------------------------------
# Train step
# ---------------------------------------------------------------------------------------------


def make_loss_fn(graphdef: nnx.GraphDef, entry_point_name: str, remat: bool = False) -> Callable:
    """Pure ``loss(params, rest, batch, t, noise) -> scalar`` through the named DiT entry point; ``remat``: its
    gradient recomputes each DiT layer instead of storing its activations (the same loss and gradient)."""
    if entry_point_name not in FLOW_MATCHING_ENTRY_POINTS:
        raise ValueError(f"entry_point_name must be one of {FLOW_MATCHING_ENTRY_POINTS}, got {entry_point_name!r}")

    def loss_fn(params, rest, batch, t_BPF, noise, clean=None, weight=None):
        dit = nnx.merge(graphdef, params, rest)
        forward = functools.partial(getattr(dit, entry_point_name), remat=remat)
        if dit.cfg.dit.camera_warp_enabled:  # the warp reads the clean previous frame, as a rollout commits it
            forward = functools.partial(forward, clean=batch["x0"] if clean is None else clean)
        return flow_matching_loss(forward, *(batch[k] for k in BATCH_KEYS), t_BPF, noise, weight)

    return loss_fn


def make_test_loss(graphdef: nnx.GraphDef, entry_point_name: str, noise_type: str, batches: list[dict],
                   seed: int = 0) -> Callable:
    """-> jitted ``test_loss(params, rest) -> scalar``: the flow-matching loss of the train step (the same entry
    point, noise type and clean warp input), averaged over ``batches`` (each a ``prepare_batch`` dict), batch i
    with its timesteps and noise drawn from ``fold_in(PRNGKey(seed), i)``: the same draws at every call, so
    two calls differ only by the parameters."""
    if noise_type not in NOISE_TYPES:
        raise ValueError(f"noise_type must be one of {NOISE_TYPES}, got {noise_type!r}")
    if not batches:
        raise ValueError("make_test_loss needs at least one batch")
    loss_fn = make_loss_fn(graphdef, entry_point_name)

    def one(params, rest, batch, i):
        k_t, k_noise = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(seed), i))
        x0 = batch["x0"]
        t_BPF = sample_timesteps(k_t, x0.shape[:3], noise_type)
        return loss_fn(params, rest, batch, t_BPF, jax.random.normal(k_noise, x0.shape, jnp.float32))

    jitted = jax.jit(one)
    return lambda params, rest: jnp.mean(jnp.stack([jitted(params, rest, b, i) for i, b in enumerate(batches)]))


def partner_cells(cond: jax.Array, mask_channels: int) -> jax.Array:
    """(B, P, F, h, w) bool: the latent cells the partner map marks (``DiTConfig.partner_map``, the conditioning
    channel after the mask), grown by one cell (the box is the body's, the decoder's reach is wider)."""
    marked = cond[..., mask_channels] > 0
    return jax.lax.reduce_window(marked.astype(jnp.float32), 0.0, jax.lax.max, (1, 1, 1, 3, 3), (1, 1, 1, 1, 1),
                                 "SAME") > 0


def drop_partner(x0: jax.Array, cond: jax.Array, mask_channels: int, key: jax.Array, share: float) -> jax.Array:
    """The clean latents the camera warp reads (``clean``), in a ``share`` of the frames (B, P, F) with the
    ``partner_cells`` replaced by the frame's mean over its other cells: the next frame must then draw the partner
    from the map, as a rollout must where its own frame lost it."""
    grown = partner_cells(cond, mask_channels)
    chosen = jax.random.bernoulli(key, share, x0.shape[:3])[..., None, None]
    drop = (grown & chosen)[..., None]
    keep = (~grown)[..., None].astype(x0.dtype)
    fill = (x0 * keep).sum(axis=(-3, -2), keepdims=True) / jnp.maximum(keep.sum(axis=(-3, -2), keepdims=True), 1.0)
    return jnp.where(drop, fill, x0)


def make_train_step(graphdef: nnx.GraphDef, entry_point_name: str, noise_type: str,
                    tx: optax.GradientTransformation, ema_decay: float = 0.999, remat: bool = False,
                    partner_dropout: float = 0.0, mask_channels: int = 0, partner_weight: float = 1.0) -> Callable:
    """-> jitted ``train_step(state, batch) -> (state, metrics)``; ``state`` is donated. ``remat``: the backward
    pass recomputes each DiT layer (``make_loss_fn``): the same update, in less memory; on our 2-core CPUs, whose
    train step waits on memory, also 1.3-1.4x the steps per second (docs/training.md, "Stage configs").

    ``batch`` holds ``BATCH_KEYS`` (``prepare_batch``). metrics: loss, grad_norm, param_norm (after the
    update), update_norm, all f32 scalars on device; pass them to ``check_finite`` on the host. A state
    created with ``ema=True`` also moves its average towards the new parameters (``ema_decay_at``).
    """
    if noise_type not in NOISE_TYPES:
        raise ValueError(f"noise_type must be one of {NOISE_TYPES}, got {noise_type!r}")
    if not 0.0 <= ema_decay < 1.0:
        raise ValueError(f"ema_decay must be in [0, 1), got {ema_decay}")
    loss_fn = make_loss_fn(graphdef, entry_point_name, remat)

    def train_step(state: TrainState, batch: dict) -> tuple[TrainState, dict]:
        k_t, k_noise = jax.random.split(jax.random.fold_in(state.rng, state.step))
        x0 = batch["x0"]
        t_BPF = sample_timesteps(k_t, x0.shape[:3], noise_type)
        noise = jax.random.normal(k_noise, x0.shape, jnp.float32)
        clean = weight = None
        if partner_dropout:
            clean = drop_partner(x0, batch["cond"], mask_channels, jax.random.fold_in(k_t, 7), partner_dropout)
        if partner_weight != 1.0:
            weight = jnp.where(partner_cells(batch["cond"], mask_channels), partner_weight, 1.0)
        loss, grads = jax.value_and_grad(loss_fn)(state.params, state.rest, batch, t_BPF, noise, clean, weight)
        return apply_gradients(state, loss, grads, tx, ema_decay)

    return jax.jit(train_step, donate_argnums=(0,))


def apply_gradients(state: TrainState, loss: jax.Array, grads: Any, tx: optax.GradientTransformation,
                    ema_decay: float) -> tuple[TrainState, dict]:
    """One optimiser update (and the EMA when the state keeps one) -> (next state, metrics): loss, grad_norm,
    param_norm (after the update), update_norm. Shared by every DiT objective's train step."""
    updates, opt_state = tx.update(grads, state.opt_state, state.params)
    params = optax.apply_updates(state.params, updates)
    metrics = {"loss": loss, "grad_norm": optax.tree.norm(grads), "param_norm": optax.tree.norm(params),
               "update_norm": optax.tree.norm(updates)}
    ema = None if state.ema is None else ema_update(state.ema, params, ema_decay_at(ema_decay, state.step))
    return state.replace(params=params, opt_state=opt_state, step=state.step + 1, ema=ema), metrics


class NonFiniteError(RuntimeError):
    """A train step produced a non-finite loss or norm."""


def check_finite(metrics: dict, step: int) -> dict[str, float]:
    """Fetch ``metrics`` to the host; raise ``NonFiniteError`` naming ``step`` if any is NaN/inf.
    Returns the metrics as Python floats (for logging)."""
    host = {k: float(v) for k, v in jax.device_get(metrics).items()}
    bad = {k: v for k, v in host.items() if not math.isfinite(v)}
    if bad:
        raise NonFiniteError(f"non-finite metrics at step {step}: {bad} (all: {host})")
    return host
