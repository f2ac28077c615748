"""The multiplayer video DiT (docs/model.md §3): velocity prediction in VAE latent space.

The network knows nothing about noise schedules or sampling; it maps noisy latents, timesteps on the
0..1000 scale, first-frame conditioning, image-encoder tokens and actions to a velocity.

Shapes (legend in ``shapes.md``): B batch, P stream players, F latent frames, H/W latent height/width,
L = h*w tokens per frame per player (or a packed sequence length), D width, M context tokens,
A action channels, W action window. Inputs of every entry point:

| name | shape | notes |
|---|---|---|
| x | (B, P, F, H, W, out_channels) | noisy latents |
| t | (B, P, F) | one timestep per player and latent frame (diffusion forcing) |
| cond | (B, P, F, H, W, in_channels - out_channels) | [mask ; first-frame latent] |
| context | (B, P, M, context_width) | image-encoder tokens of each player's first frame |
| mouse | (B, P, T_pad, mouse channels) | left-padded actions, T_pad = k*(F-1) + action_window |
| keyboard | (B, P, T_pad, keyboard channels) | same alignment (see ``action_module``) |

The ``concat`` variant (docs/model.md §3.7) is the same network with one stream player and players stacked in
channels; ``to_stream`` / ``from_stream`` convert (B, num_players, ...) tensors.

Modes are entry points: ``forward_bidirectional``, ``forward_causal``, ``forward_teacher_forcing`` and
``decode``. The first three run the whole sequence with a frame-level mask; ``decode`` runs new frames
against a rolling cache (``kv_cache``), with the context given as its per-layer cross-attention keys/values
(``context_kv``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from solaris_env.world_model import camera as camera_lib
from solaris_env.world_model import kv_cache, masks, rope
from solaris_env.world_model.action_module import ActionModule, action_windows, padded_action_length
from solaris_env.world_model.attention import (RMSNorm, attention, attention_heads_major, dense, layer_norm,
                                               stop_gradient_where)
from solaris_env.world_model.config import WorldModelConfig

# ---------------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------------


def sinusoidal_embedding(t: jax.Array, dim: int) -> jax.Array:
    """(...,) timesteps -> (..., dim) f32 ``[cos(t w), sin(t w)]`` with w_i = 10000^(-i / (dim/2))."""
    half = dim // 2
    omega = jnp.power(10000.0, -jnp.arange(half, dtype=jnp.float32) / half)
    arg = t.astype(jnp.float32)[..., None] * omega
    return jnp.concatenate([jnp.cos(arg), jnp.sin(arg)], axis=-1)


def modulate(x: jax.Array, shift: jax.Array, scale: jax.Array) -> jax.Array:
    return x * (1 + scale) + shift


def pack_players(x_BPFLD: jax.Array) -> jax.Array:
    """(B, P, F, L, D) -> (B, F*P*L, D): for every frame, player 0's tokens then player 1's."""
    b, p, f, s, d = x_BPFLD.shape
    return x_BPFLD.transpose(0, 2, 1, 3, 4).reshape(b, f * p * s, d)


def unpack_players(x_BLD: jax.Array, num_players: int, num_frames: int) -> jax.Array:
    """(B, F*P*L, D) -> (B, P, F, L, D)."""
    b, _, d = x_BLD.shape
    return x_BLD.reshape(b, num_frames, num_players, -1, d).transpose(0, 2, 1, 3, 4)


def to_stream(cfg: WorldModelConfig, a_BP_C: jax.Array) -> jax.Array:
    """(B, num_players, ..., C) -> what the DiT sees: unchanged for ``attn``; (B, 1, ..., P*C) for
    ``concat`` (channels player-major). Works for x, cond, context, mouse and keyboard."""
    if cfg.dit.multiplayer == "attn":
        return a_BP_C
    moved = jnp.moveaxis(a_BP_C, 1, -2)  # (B, ..., P, C)
    return moved.reshape(moved.shape[:-2] + (-1,))[:, None]


def from_stream(cfg: WorldModelConfig, a_B1_C: jax.Array) -> jax.Array:
    """Inverse of ``to_stream``: (B, 1, ..., P*C) -> (B, P, ..., C) for ``concat``."""
    if cfg.dit.multiplayer == "attn":
        return a_B1_C
    split = a_B1_C[:, 0].reshape(a_B1_C.shape[:1] + a_B1_C.shape[2:-1] + (cfg.num_players, -1))
    return jnp.moveaxis(split, -2, 1)


def timesteps_to_stream(cfg: WorldModelConfig, t_BPF: jax.Array) -> jax.Array:
    """(B, num_players, F) -> (B, stream_players, F); ``concat`` shares one timestep (player 0's)."""
    return t_BPF if cfg.dit.multiplayer == "attn" else t_BPF[:, :1]


def _fold(a_BP_: jax.Array) -> jax.Array:
    """Fold players into the batch: (B, P, ...) -> (B*P, ...)."""
    return a_BP_.reshape((-1,) + a_BP_.shape[2:])


# The layer scan and the action-block switch use plain jax.lax control flow with the module merged
# inside the traced function (functional NNX), so the model also works when callers split it and
# differentiate or jit a pure function of part of its state (e.g. jax.grad w.r.t. inputs only).


def _run_if(pred: jax.Array, module: nnx.Module, run, skip, *operands):
    """``run(module, *operands)`` if ``pred`` (traced) else ``skip(*operands)``; one branch executes."""
    graphdef, state = nnx.split(module)
    return jax.lax.cond(pred, lambda st, *ops: run(nnx.merge(graphdef, st), *ops),
                        lambda st, *ops: skip(*ops), state, *operands)


def _scan_layers(blocks: nnx.Module, step, carry, per_layer, remat: bool = False):
    """Scan ``step(block, carry, layer_inputs) -> (carry, layer_outputs)`` over the stacked layer axis.
    ``remat``: under differentiation keep only each layer's input and recompute the layer in the backward
    pass (``jax.checkpoint``); no effect on forward-only calls."""
    graphdef, state = nnx.split(blocks)

    def body(c, xs):
        layer_state, layer_inputs = xs
        return step(nnx.merge(graphdef, layer_state), c, layer_inputs)

    return jax.lax.scan(jax.checkpoint(body, prevent_cse=False) if remat else body, carry, (state, per_layer))


def _teacher_forcing_band(num_frames: int, window: int) -> tuple[np.ndarray, np.ndarray]:
    """The keys a frame of ``[clean ; noisy]`` may see, as a band: for frame i the key frames are clean
    ``i-band+1 .. i`` (band = min(W, F); indices clipped at 0) then noisy ``i``.

    Returns (clean_idx (F, band) int, mask (F, 2, band + 1) bool: [query frame, query half, key slot]),
    read off ``masks.teacher_forcing_frame_mask`` (checked to hold every allowed pair)."""
    f, band = num_frames, min(window, num_frames)
    dense = masks.teacher_forcing_frame_mask(f, window)  # (2F, 2F) over [clean ; noisy]
    clean = np.arange(f)[:, None] - band + 1 + np.arange(band)[None]  # (F, band), < 0 = before frame 0
    keys = np.concatenate([np.maximum(clean, 0), f + np.arange(f)[:, None]], axis=1)  # (F, band + 1)
    valid = np.concatenate([clean >= 0, np.ones((f, 1), bool)], axis=1)
    rows = np.arange(2)[None, :] * f + np.arange(f)[:, None]  # (F, 2) query rows
    band_mask = dense[rows[:, :, None], keys[:, None, :]] & valid[:, None, :]
    if band_mask.sum() != dense.sum():
        raise AssertionError("teacher-forcing mask reaches outside the band")  # cannot happen for this mask
    return np.maximum(clean, 0), band_mask


def _teacher_forcing_attention(q_BLNK, k_BLNK, v_BLNK, num_frames: int, window: int, block: int, impl: str):
    """Self-attention over ``[clean ; noisy]`` (L = 2 * F * block tokens) under the teacher-forcing mask,
    computed frame by frame against its band of <= W clean frames plus its own noisy frame: O(F * W)
    scores and mask instead of O(F^2); the same result as ``attention`` with the dense token mask."""
    b, _, n, kd = q_BLNK.shape
    f = num_frames
    clean_idx, band_mask = _teacher_forcing_band(f, window)
    frames = lambda a: a.reshape(b, 2, f, block, n, kd)  # (B, half, F, block, N, K)

    def banded(a_BLNK):  # -> (B, F, (band + 1) * block, N, K): clean band then own noisy frame
        a = frames(a_BLNK)
        both = jnp.concatenate([a[:, 0][:, clean_idx], a[:, 1][:, :, None]], axis=2)
        return both.reshape(b, f, -1, n, kd)

    q = frames(q_BLNK).transpose(0, 2, 1, 3, 4, 5).reshape(b, f, 2 * block, n, kd)  # both halves of frame i
    mask = jnp.repeat(jnp.repeat(jnp.asarray(band_mask), block, axis=1), block, axis=2)[:, None]  # (F, 1, 2blk, S)
    y = jax.vmap(lambda q_, k_, v_: attention(q_, k_, v_, mask, impl))(q, banded(k_BLNK), banded(v_BLNK))
    return y.reshape(b, f, 2, block, n, kd).transpose(0, 2, 1, 3, 4, 5).reshape(q_BLNK.shape)


def _previous_frames(x_BPFhwC: jax.Array) -> jax.Array:
    """Each frame's previous frame along F, zeros before the first (the camera warp's input)."""
    return jnp.concatenate([jnp.zeros_like(x_BPFhwC[:, :, :1]), x_BPFhwC[:, :, :-1]], axis=2)


def _still_memories(previous_BPhwC: jax.Array, x_BPFhwC: jax.Array, still_BPF: jax.Array | None,
                    memory: float) -> tuple[jax.Array, jax.Array]:
    """(each new frame's previous latent, each new frame's latent as the next frame's previous latent), both like
    ``x``, for a cached pass whose cache holds ``previous`` (the camera warp's input, docs/model.md §8.5). Frame f
    passes on itself, or where ``still_BPF`` holds, ``memory`` * its own previous latent + (1 - ``memory``) *
    itself. ``still_BPF`` None or ``memory`` 0: the frames themselves, as teacher forcing reads them."""
    prev = previous_BPhwC.astype(x_BPFhwC.dtype)
    if not memory or still_BPF is None:
        return jnp.concatenate([prev[:, :, None], x_BPFhwC[:, :, :-1]], axis=2), x_BPFhwC
    prevs, memories = [], []
    for f in range(x_BPFhwC.shape[2]):  # F is 1 or 2 in a rollout: a frame's memory is the next one's input
        own = x_BPFhwC[:, :, f]
        blend = memory * prev.astype(jnp.float32) + (1.0 - memory) * own.astype(jnp.float32)
        own = jnp.where(still_BPF[:, :, f, None, None, None], blend.astype(own.dtype), own)
        prevs.append(prev)
        memories.append(own)
        prev = own
    return jnp.stack(prevs, axis=2), jnp.stack(memories, axis=2)


class _Conditioning(NamedTuple):
    """Per-forward inputs every block reads (constant across layers)."""
    e0_BPF6D: jax.Array  # per-(player, frame) adaLN modulation
    player_PD: jax.Array  # player embedding rows
    context_BPMD: jax.Array | None  # projected image tokens (None when cross-attention K/V come precomputed)
    mouse_BPFWA: jax.Array  # action windows per latent frame
    keyboard_BPFWA: jax.Array


class ContextKV(NamedTuple):
    """Cross-attention keys/values of the image context, one entry per layer (``WorldDiT.context_kv``).

    They depend only on the context (the first frames), so a stream computes them once per world
    instead of re-projecting the context in every DiT pass; each layer's are their own buffers, read in
    place by that layer.
    """
    k_BPNMK: tuple[jax.Array, ...]  # per layer (B, P, N, M, K): normed keys, heads-major (read by the dots as they are)
    v_BPNMK: tuple[jax.Array, ...]  # per layer (B, P, N, M, K)


class _SequencePlan(NamedTuple):
    """What distinguishes the whole-sequence modes (bidirectional / causal / teacher forcing)."""
    angles_LJ: jax.Array  # 3D RoPE of the packed (frame, player, token) sequence
    token_mask: jax.Array | None  # (L, L) self-attention mask; None = full
    action_angles_FJ: jax.Array  # temporal RoPE of the action module
    frame_mask: jax.Array | None  # (F, F) action-module mask; None = full
    kv_stop_F: jax.Array | None  # frames whose keys/values get no gradient
    kv_stop_L: jax.Array | None
    attend: Callable | None = None  # (q, k, v) -> y replacing the dense token mask (teacher forcing)


# ---------------------------------------------------------------------------------------------
# Blocks
# ---------------------------------------------------------------------------------------------


def _dtypes(cfg: WorldModelConfig) -> dict:
    return dict(dtype=jnp.dtype(cfg.dit.dtype), param_dtype=jnp.dtype(cfg.dit.param_dtype))


class _QKVProjection(nnx.Module):
    """q/k/v/o Linear(D, D) with bias and RMSNorm over the full width of q and k (Wan)."""

    def __init__(self, cfg: WorldModelConfig, *, rngs: nnx.Rngs):
        d = cfg.dit
        kw = dict(use_bias=True, rngs=rngs, **_dtypes(cfg))
        self.num_heads, self.impl = d.num_heads, d.attention_impl
        self.q, self.k, self.v, self.o = (dense(d.dim, d.dim, **kw) for _ in range(4))
        norm = lambda: RMSNorm(d.dim, d.eps, param_dtype=kw["param_dtype"], rngs=rngs) if d.qk_norm else None
        self.norm_q, self.norm_k = norm(), norm()

    def _heads(self, x_BLD: jax.Array) -> jax.Array:
        return x_BLD.reshape(x_BLD.shape[:2] + (self.num_heads, -1))

    def _project(self, x_BLD, norm, linear) -> jax.Array:
        y = linear(x_BLD)
        return self._heads(y if norm is None else norm(y))

    def _out(self, y_BLNK: jax.Array) -> jax.Array:
        return self.o(y_BLNK.reshape(y_BLNK.shape[:2] + (-1,)))


class SelfAttention(_QKVProjection):
    """Joint self-attention over the packed (frame, player, token) sequence, 3D RoPE on q and k."""

    def _qkv(self, x_BLD, angles_LJ):
        q = rope.apply_rope(self._project(x_BLD, self.norm_q, self.q), angles_LJ)
        k = rope.apply_rope(self._project(x_BLD, self.norm_k, self.k), angles_LJ)
        return q, k, self._heads(self.v(x_BLD))

    def __call__(self, x_BLD: jax.Array, angles_LJ: jax.Array, mask_LL, kv_stop_L=None, attend=None) -> jax.Array:
        q, k, v = self._qkv(x_BLD, angles_LJ)
        k, v = stop_gradient_where(k, kv_stop_L), stop_gradient_where(v, kv_stop_L)
        return self._out(attention(q, k, v, mask_LL, self.impl) if attend is None else attend(q, k, v))

    def decode(self, x_BLD: jax.Array, angles_LJ: jax.Array, cache: kv_cache.KVCache, num_frames: int, commit: int):
        """Attend from ``num_frames`` new frames (tokens packed frame-major) to the heads-major ``cache``
        and to themselves, block-causally: frame f sees the cache slots still valid after f + 1 frames
        are appended, and new frames <= f. Returns (y, the cache with the (post-RoPE) keys of the first
        ``commit`` new frames appended; ``cache`` itself for ``commit`` = 0).

        The attention reads the old cache and the new keys as two blocks (``attention_heads_major``),
        so a pass that commits nothing never builds an updated cache."""
        q, k, v = self._qkv(x_BLD, angles_LJ)
        k_BNLK, v_BNLK = k.transpose(0, 2, 1, 3), v.transpose(0, 2, 1, 3)
        per_frame = k_BNLK.shape[2] // num_frames
        kept = jnp.stack([kv_cache.kept_mask(cache, (f + 1) * per_frame) for f in range(num_frames)], axis=-2)
        kept = jnp.repeat(kept, per_frame, axis=-2)  # (L, S) or (B, L, S): one row per query token
        kept = kept[None] if kept.ndim == 2 else kept[:, None]  # broadcast over (B,) N
        causal = None if num_frames == 1 else masks.expand_to_tokens(np.tril(np.ones((num_frames,) * 2, bool)),
                                                                     per_frame)
        y = attention_heads_major(q, [(cache.k, cache.v, kept), (k_BNLK, v_BNLK, causal)])
        if commit:
            new = slice(0, commit * per_frame)
            cache = kv_cache.update(cache, k_BNLK[:, :, new], v_BNLK[:, :, new])
        return self._out(y), cache


class CrossAttention(_QKVProjection):
    """Per-player attention from the tokens to that player's image-context tokens (no mask, no RoPE).

    ``kv`` (the normed keys and values of the context) depends only on the context, so a stream can
    compute it once per world (``WorldDiT.context_kv``) and ``attend`` with it in every pass.
    """

    def kv(self, context_BMD: jax.Array) -> tuple[jax.Array, jax.Array]:
        """-> (k, v), each (B, M, N, K)."""
        return self._project(context_BMD, self.norm_k, self.k), self._heads(self.v(context_BMD))

    def attend(self, x_BLD: jax.Array, k_BMNK: jax.Array, v_BMNK: jax.Array) -> jax.Array:
        q = self._project(x_BLD, self.norm_q, self.q)
        return self._out(attention(q, k_BMNK.astype(q.dtype), v_BMNK.astype(q.dtype), None, self.impl))

    def attend_heads_major(self, x_BLD: jax.Array, k_BNMK: jax.Array, v_BNMK: jax.Array) -> jax.Array:
        """``attend`` with heads-major keys/values (B, N, M, K) (the decode step's form)."""
        q = self._project(x_BLD, self.norm_q, self.q)
        return self._out(attention_heads_major(q, [(k_BNMK, v_BNMK, None)]))

    def __call__(self, x_BLD: jax.Array, context_BMD: jax.Array) -> jax.Array:
        return self.attend(x_BLD, *self.kv(context_BMD))


class DiTBlock(nnx.Module):
    """adaLN block (docs/model.md §3.3): player embedding, modulated self-attention, cross-attention,
    action module (blocks < num_action_blocks only), modulated FFN.

    Args:
        cfg: world-model config.
        rngs: parameter initialisation.
    """

    def __init__(self, cfg: WorldModelConfig, *, rngs: nnx.Rngs):
        d = cfg.dit
        kw = dict(rngs=rngs, **_dtypes(cfg))
        self.eps, self.num_action_blocks = d.eps, cfg.action.num_action_blocks
        # Wan init: randn / sqrt(dim); the six rows are shift/scale/gate of attention then FFN.
        self.modulation = nnx.Param(jax.random.normal(rngs.params(), (1, 6, d.dim), kw["param_dtype"])
                                    / math.sqrt(d.dim))
        self.self_attn = SelfAttention(cfg, rngs=rngs)
        self.cross_attn = CrossAttention(cfg, rngs=rngs)
        self.norm3 = nnx.LayerNorm(d.dim, epsilon=d.eps, **kw) if d.cross_attn_norm else None
        self.ffn = nnx.Sequential(dense(d.dim, d.ffn_dim, use_bias=True, **kw), jax.nn.gelu,  # tanh GELU
                                  dense(d.ffn_dim, d.dim, use_bias=True, **kw))
        self.action_model = ActionModule(cfg, rngs=rngs)

    # -- shared pieces ---------------------------------------------------------------------------
    def _modulation(self, e0_BPF6D: jax.Array) -> list[jax.Array]:
        """-> [shift_msa, scale_msa, gate_msa, shift_ffn, scale_ffn, gate_ffn], each (B, P, F, 1, D)."""
        mod = self.modulation[...].astype(e0_BPF6D.dtype)[None, None] + e0_BPF6D
        return [mod[:, :, :, i, None, :] for i in range(6)]

    def _attn_input(self, x_BPFLD, mods) -> jax.Array:
        """Player embedding is already in x; returns the packed, modulated self-attention input."""
        return pack_players(modulate(layer_norm(x_BPFLD, self.eps), mods[0], mods[1]))

    def _cross_and_actions_input(self, x_BPFLD, y_BLD, mods, cross) -> jax.Array:
        """Self-attention residual, then cross-attention ``cross``: (B*P, F*L, D) -> (B*P, F*L, D)."""
        b, p, f, s, d = x_BPFLD.shape
        x_BPFLD = x_BPFLD + unpack_players(y_BLD, p, f) * mods[2]
        h = x_BPFLD if self.norm3 is None else self.norm3(x_BPFLD)
        y = cross(h.reshape(b * p, f * s, d))
        return x_BPFLD + y.reshape(x_BPFLD.shape)

    def _ffn_residual(self, x_BPFLD, mods) -> jax.Array:
        return x_BPFLD + self.ffn(modulate(layer_norm(x_BPFLD, self.eps), mods[3], mods[4])) * mods[5]

    # -- entry points ------------------------------------------------------------------------------
    def __call__(self, x_BPFLD: jax.Array, cond: _Conditioning, plan: _SequencePlan, layer: jax.Array) -> jax.Array:
        """Whole-sequence block; ``layer`` (traced int) selects whether the action module runs."""
        mods = self._modulation(cond.e0_BPF6D)
        x_BPFLD = x_BPFLD + cond.player_PD[None, :, None, None].astype(x_BPFLD.dtype)
        y = self.self_attn(self._attn_input(x_BPFLD, mods), plan.angles_LJ, plan.token_mask, plan.kv_stop_L,
                           plan.attend)
        kv = self.cross_attn.kv(_fold(cond.context_BPMD))
        x_BPFLD = self._cross_and_actions_input(x_BPFLD, y, mods, lambda h: self.cross_attn.attend(h, *kv))
        b, p, f, s, d = x_BPFLD.shape

        def run_actions(module, x):
            x = module(x.reshape(b * p, f, s, d), _fold(cond.mouse_BPFWA), _fold(cond.keyboard_BPFWA),
                       plan.action_angles_FJ, plan.frame_mask, plan.kv_stop_F)
            return x.reshape(b, p, f, s, d)

        x_BPFLD = _run_if(layer < self.num_action_blocks, self.action_model, run_actions, lambda x: x, x_BPFLD)
        return self._ffn_residual(x_BPFLD, mods)

    def decode(self, x_BPFLD: jax.Array, cond: _Conditioning, angles_LJ: jax.Array, action_angles_FJ: jax.Array,
               layer: int, cache: kv_cache.LayerCache, cross_kv: tuple[jax.Array, jax.Array], commit: int):
        """F new latent frames against this layer's caches -> (x_BPFLD, the caches with the first ``commit``
        new frames written; ``cache`` itself for ``commit`` = 0).

        The new frames are block-causal: frame f sees the cache slots still valid after f + 1 frames
        are appended, and new frames <= f (F = 1: one frame against cache + itself). ``layer`` (a Python
        int) decides whether the action module runs; ``cross_kv`` = this layer's context keys/values,
        heads-major, each (B*P, N, M, K)."""
        mods = self._modulation(cond.e0_BPF6D)
        x_BPFLD = x_BPFLD + cond.player_PD[None, :, None, None].astype(x_BPFLD.dtype)
        b, p, f, s, d = x_BPFLD.shape
        y, self_cache = self.self_attn.decode(self._attn_input(x_BPFLD, mods), angles_LJ, cache.self_attn, f, commit)
        x_BPFLD = self._cross_and_actions_input(x_BPFLD, y, mods,
                                                lambda h: self.cross_attn.attend_heads_major(h, *cross_kv))
        mouse_cache, keyboard_cache = cache.mouse, cache.keyboard
        if layer < self.num_action_blocks:
            x, mouse_cache, keyboard_cache = self.action_model.decode(
                x_BPFLD.reshape(b * p, f, s, d), _fold(cond.mouse_BPFWA), _fold(cond.keyboard_BPFWA),
                action_angles_FJ, mouse_cache, keyboard_cache, commit)
            x_BPFLD = x.reshape(b, p, f, s, d)
        new_cache = kv_cache.LayerCache(self_attn=self_cache, mouse=mouse_cache, keyboard=keyboard_cache)
        return self._ffn_residual(x_BPFLD, mods), new_cache


# ---------------------------------------------------------------------------------------------
# Embeddings and head
# ---------------------------------------------------------------------------------------------


class ImageContextProjection(nnx.Module):
    """``img_emb``: LayerNorm -> Linear -> GELU(tanh) -> Linear -> LayerNorm, per player (docs/model.md §3.2)."""

    def __init__(self, cfg: WorldModelConfig, *, rngs: nnx.Rngs):
        d, cw, eps = cfg.dit, cfg.context_width, cfg.dit.context_norm_eps
        kw = dict(rngs=rngs, **_dtypes(cfg))
        self.proj = nnx.List([
            nnx.LayerNorm(cw, epsilon=eps, **kw),
            dense(cw, cw, use_bias=True, **kw),
            dense(cw, d.dim, use_bias=True, **kw),
            nnx.LayerNorm(d.dim, epsilon=eps, **kw),
        ])

    def __call__(self, context_BPMC: jax.Array) -> jax.Array:
        norm_in, fc1, fc2, norm_out = self.proj
        return norm_out(fc2(jax.nn.gelu(fc1(norm_in(context_BPMC)))))


class Head(nnx.Module):
    """Output head: LayerNorm (no affine) modulated by the time embedding ``e`` (not e0), then Linear."""

    def __init__(self, cfg: WorldModelConfig, *, rngs: nnx.Rngs):
        d = cfg.dit
        kw = _dtypes(cfg)
        self.eps = d.eps
        self.modulation = nnx.Param(jax.random.normal(rngs.params(), (1, 2, d.dim), kw["param_dtype"])
                                    / math.sqrt(d.dim))
        # Zero-initialised like Wan: the untrained network predicts zero velocity.
        self.head = dense(d.dim, math.prod(d.patch_size) * cfg.out_channels, use_bias=True, rngs=rngs,
                          kernel_init=nnx.initializers.zeros_init(), **kw)

    def __call__(self, x_BPFLD: jax.Array, e_BPFD: jax.Array) -> jax.Array:
        mod = self.modulation[...].astype(e_BPFD.dtype)[None, None] + e_BPFD[..., None, :]  # (B, P, F, 2, D)
        shift, scale = mod[:, :, :, 0, None], mod[:, :, :, 1, None]
        return self.head(modulate(layer_norm(x_BPFLD, self.eps), shift, scale))


# ---------------------------------------------------------------------------------------------
# Model
# ---------------------------------------------------------------------------------------------


class WorldDiT(nnx.Module):
    """The Solaris DiT. Parameter names follow the official checkpoint tree (docs/model.md §9.2).

    Args:
        cfg: world-model config; ``cfg.dit.multiplayer`` picks ``attn`` (players on their own axis,
            joint self-attention) or ``concat`` (one stream player, players in channels).
        rngs: parameter initialisation (``rngs.params``).
    """

    def __init__(self, cfg: WorldModelConfig, *, rngs: nnx.Rngs):
        d = cfg.dit
        if d.patch_size[0] != 1:
            raise ValueError(f"temporal patch size must be 1 (one latent frame per token frame), got {d.patch_size}")
        kw = dict(rngs=rngs, **_dtypes(cfg))
        self.cfg = cfg
        self.patch_embedding = nnx.Conv(cfg.patch_in_channels, d.dim, kernel_size=d.patch_size, strides=d.patch_size,
                                        padding="VALID", kernel_init=nnx.initializers.xavier_uniform(), **kw)
        normal = nnx.initializers.normal(0.02)
        self.time_embedding = nnx.Sequential(
            dense(d.freq_dim, d.dim, use_bias=True, kernel_init=normal, **kw), jax.nn.silu,
            dense(d.dim, d.dim, use_bias=True, kernel_init=normal, **kw))
        self.time_projection = nnx.Sequential(jax.nn.silu, dense(d.dim, 6 * d.dim, use_bias=True, **kw))
        self.img_emb = ImageContextProjection(cfg, rngs=rngs)
        self.player_embed = nnx.Embed(d.max_players, d.dim, **kw)
        self.blocks = _stacked_blocks(cfg, rngs)
        self.head = Head(cfg, rngs=rngs)
        if d.previous_skip:
            self.skip_gate = skip_gate(cfg, rngs)

    # -- entry points ------------------------------------------------------------------------------
    def forward_bidirectional(self, x, t, cond, context, mouse, keyboard, clean=None, *,
                              remat: bool = False) -> jax.Array:
        """Full attention over all frames (stages 1-2, the DMD teacher). Returns v like x. ``clean``: the clean
        latents of ``x`` (training), whose previous frames the camera warp reads (a rollout's committed frames are
        clean); default ``x`` itself. ``remat``: under differentiation the backward pass recomputes each layer
        from its input instead of reading stored activations (the same values; docs/model.md §10.2)."""
        num_frames = self._validate(x, t, cond, context, mouse, keyboard)
        mouse_w = self._windows(mouse, num_frames)
        return self._forward_sequence(
            x, t, cond, context, mouse_w, self._windows(keyboard, num_frames),
            rope.frame_positions(num_frames), frame_mask=None, kv_stop_F=None, remat=remat,
            prev=_previous_frames(x if clean is None else clean), lift=self._clip_lifts(keyboard, num_frames))

    def forward_causal(self, x, t, cond, context, mouse, keyboard, clean=None, *, remat: bool = False) -> jax.Array:
        """Block-causal sliding window over frames (diffusion forcing: t varies per frame). Returns v like x.
        ``clean`` and ``remat`` as ``forward_bidirectional``."""
        num_frames = self._validate(x, t, cond, context, mouse, keyboard)
        mouse_w = self._windows(mouse, num_frames)
        return self._forward_sequence(
            x, t, cond, context, mouse_w, self._windows(keyboard, num_frames),
            rope.frame_positions(num_frames), masks.causal_window_frame_mask(num_frames, self.cfg.dit.window),
            kv_stop_F=None, remat=remat, prev=_previous_frames(x if clean is None else clean),
            lift=self._clip_lifts(keyboard, num_frames))

    def forward_teacher_forcing(self, clean, noisy, t_clean, t_noisy, cond, context, mouse, keyboard, *,
                                kv_grad: bool = True, remat: bool = True) -> jax.Array:
        """One pass over ``[clean ; noisy]`` with the teacher-forcing mask and per-half RoPE (docs/model.md
        §6.3). Noisy frame i sees clean frames (i-W, i) and itself, exactly like a cached decode step.
        ``kv_grad=False`` stops the gradient through the clean half's keys/values. Returns v of the
        noisy half, shaped like ``noisy``.

        Memory (Checkpointed Self Forcing differentiates this pass): the self-attention runs per frame
        against its band of W clean frames + itself (``_teacher_forcing_attention``, no (2FL)^2 mask or
        scores), and with ``remat`` the backward pass keeps only each layer's input."""
        num_frames = self._validate(noisy, t_noisy, cond, context, mouse, keyboard)
        if clean.shape != noisy.shape or t_clean.shape != t_noisy.shape:
            raise ValueError(f"clean {clean.shape} / t_clean {t_clean.shape} must match noisy {noisy.shape} / "
                             f"t_noisy {t_noisy.shape}")
        twice = lambda a: jnp.concatenate([a, a], axis=2)
        kv_stop_F = None if kv_grad else np.repeat([True, False], num_frames)
        mouse_w = self._windows(mouse, num_frames)
        lift = self._clip_lifts(keyboard, num_frames)
        v = self._forward_sequence(
            jnp.concatenate([clean, noisy], axis=2), jnp.concatenate([t_clean, t_noisy], axis=2), twice(cond),
            context, twice(mouse_w), twice(self._windows(keyboard, num_frames)),
            rope.teacher_forcing_frame_positions(num_frames),
            masks.teacher_forcing_frame_mask(num_frames, self.cfg.dit.window), kv_stop_F,
            attend=functools.partial(_teacher_forcing_attention, num_frames=num_frames, window=self.cfg.dit.window,
                                     block=noisy.shape[1] * math.prod(self._grid()), impl=self.cfg.dit.attention_impl),
            remat=remat, prev=twice(_previous_frames(clean)), lift=None if lift is None else twice(lift))
        return v[:, :, num_frames:]

    def decode(self, x, t, cond, context_kv: ContextKV, mouse, keyboard, cache: kv_cache.DiTCache,
               start_frame: int | jax.Array, *, commit: int = 0,
               layers: "tuple[DiTBlock, ...] | None" = None,
               still_memory: float = 0.0) -> tuple[jax.Array, kv_cache.DiTCache]:
        """F new latent frames at absolute positions ``start_frame``.. against the rolling ``cache``: every
        pass of a causal rollout (docs/model.md §3.6, §5.2, §5.5).

        Shapes as the class docstring, the context given as its per-layer keys/values (``context_kv``);
        ``mouse``/``keyboard`` are the (B, P, k * (F - 1) + action_window, A) action sequence of the F
        frames, frame f's window being [k f, k f + action_window) (F = 1: the frame's window,
        ``action_module.window_at``). The new frames are block-causal: frame f sees the cache slots still
        valid after f + 1 frames are appended, and the new frames <= f.

        ``commit`` (a Python int, 0..F): how many of the new frames, from the first, are written to the
        cache. Returns ``(v of the F frames, the cache)``:

        - ``commit=0``: a denoising pass; the cache comes back as it was (the updated one is never built);
        - one clean frame at t = 0 with ``commit=1``: the reference's commit pass;
        - [clean frame i - 1 at t = 0 ; noisy frame i] with ``commit=1``: that commit and frame i's first
          denoising pass as one pass (the streaming model). Frame 0 never sees frame 1, so its keys/values
          are the separate commit pass's, and frame 1 sees the cache with frame 0 appended: the two passes
          up to float rounding, with one pass's fixed costs.

        ``layers``: the blocks as one module per layer; default ``layer_blocks()`` (this DiT's weights);
        the streaming model passes its per-layer parameters (``unstack_blocks``). The layers run as a
        Python loop with static indices: every layer reads its weights, cache and context K/V in place,
        and the action module runs in the first ``num_action_blocks`` layers without a ``lax.cond``.

        ``still_memory`` (a Python float in [0, 1), the rollout setting ``SamplerConfig.still_memory``; camera warp
        only): each new frame's own previous latent, and the cache's ``latent`` after a commit, is the frame's
        latent blended with the previous latent where the frame holds still (``_still_memories``). 0 = the
        frames as they are (teacher forcing's previous latents).
        """
        c, d = self.cfg, self.cfg.dit
        layers = self.layer_blocks() if layers is None else layers
        num_frames = x.shape[2]
        if not 0 <= commit <= num_frames:
            raise ValueError(f"commit={commit} must be in [0, {num_frames}] (the number of new frames)")
        for name, n in (("layers", len(layers)), ("cache", len(cache.layers))):
            if n != d.num_layers:
                raise ValueError(f"{name} has {n} layers; the config has num_layers={d.num_layers}")
        if not 0.0 <= still_memory < 1.0:
            raise ValueError(f"still_memory must be in [0, 1), got {still_memory}")
        cond_in, tokens, e, base, jump_after, memories = self._prepare_cached(x, t, cond, context_kv, mouse,
                                                                              keyboard, cache, still_memory)
        gh, gw = self._grid()
        angles = rope.rope_3d_angles(d.rope_split, d.rope_theta, num_frames, gh, gw, tokens.shape[1], start_frame)
        action_angles = rope.temporal_rope_angles(c.action.rope_dims, c.action.rope_theta, num_frames, start_frame)
        new_layers = []
        for i, (block, layer_cache, k, v) in enumerate(zip(layers, cache.layers, context_kv.k_BPNMK,
                                                           context_kv.v_BPNMK)):
            tokens, layer_cache = block.decode(tokens, cond_in, angles, action_angles, i, layer_cache,
                                               (_fold(k), _fold(v)), commit)
            new_layers.append(layer_cache)
        v = self._output(tokens, e, x, base)
        if not commit:
            return v, cache
        # the camera warp's latent: the newest committed frame's (blended while still: ``_still_memories``)
        latent = None if cache.latent is None else memories[:, :, commit - 1].astype(cache.latent.dtype)
        jump = None if jump_after is None else jump_after[:, :, commit - 1]  # the jump state after that frame
        return v, kv_cache.DiTCache(layers=tuple(new_layers), latent=latent, jump=jump)

    def layer_blocks(self) -> "tuple[DiTBlock, ...]":
        """The stacked blocks as one module per layer (``unstack_blocks``: each layer's weights sliced out
        once; under differentiation their gradients are stacked back in one piece)."""
        graphdef, state = nnx.split(self.blocks)
        return tuple(nnx.merge(graphdef, s) for s in unstack_blocks(self.cfg, state))

    def context_kv(self, context, layers: "tuple[DiTBlock, ...] | None" = None) -> ContextKV:
        """The cross-attention keys/values of every layer for ``context`` (B, P, M, context_width), computed
        once (``img_emb`` then each layer's k/v): what ``decode`` reads instead of the context.
        ``layers`` as ``decode``."""
        c = self.cfg
        if context.ndim != 4 or context.shape[1] != c.stream_players or context.shape[3] != c.context_width:
            raise ValueError(f"context has shape {context.shape}; expected (B, {c.stream_players}, M, "
                             f"{c.context_width})")
        b, p = context.shape[:2]
        projected = _fold(self.img_emb(context.astype(jnp.dtype(c.dit.dtype))))  # (B*P, M, D)
        heads_major = lambda a: a.transpose(0, 2, 1, 3).reshape((b, p) + a.shape[2:3] + a.shape[1:2] + a.shape[3:])
        kv = [block.cross_attn.kv(projected) for block in (self.layer_blocks() if layers is None else layers)]
        return ContextKV(tuple(heads_major(k) for k, _ in kv), tuple(heads_major(v) for _, v in kv))

    # -- internals -----------------------------------------------------------------------------------
    def _prepare_cached(self, x, t, cond, context_kv: ContextKV, mouse, keyboard, cache: kv_cache.DiTCache,
                        still_memory: float = 0.0):
        """Shape checks and ``_prepare`` for ``decode`` (no context projection); also returns the jump state after
        each new frame (``camera.frame_lifts``; None without the jump warp) and each new frame's latent as the next
        frame's previous latent (``_still_memories``; None without the camera warp)."""
        c = self.cfg
        b, p, num_frames = x.shape[:3]
        want = (b, p, c.dit.num_heads, None, c.dit.head_dim)
        for name, arrays in (("context_kv.k", context_kv.k_BPNMK), ("context_kv.v", context_kv.v_BPNMK)):
            shapes = {a.shape for a in arrays}
            shape = next(iter(shapes)) if len(shapes) == 1 else None
            if (len(arrays) != c.dit.num_layers or shape is None or len(shape) != 5
                    or any(w is not None and g != w for g, w in zip(shape, want))):
                raise ValueError(f"{name} has {len(arrays)} layers of shapes {sorted(shapes)}; expected "
                                 f"num_layers={c.dit.num_layers} of (B, P, N, M, K) = "
                                 f"{tuple('M' if w is None else w for w in want)}")
        context_shape = jax.ShapeDtypeStruct((b, p, context_kv.k_BPNMK[0].shape[3], c.context_width), jnp.float32)
        self._validate(x, t, cond, context_shape, mouse, keyboard)
        k, w = c.frames_per_step, c.action_window
        windows = lambda a: jnp.stack([a[:, :, k * f:k * f + w] for f in range(num_frames)], axis=2)
        lift = jump_after = None
        if self.cfg.dit.jump_warp:
            if cache.jump is None:
                raise ValueError("jump_warp is on but the cache has no jump state (kv_cache.init_cache)")
            lift, jump_after = camera_lib.frame_lifts(keyboard, num_frames, k, cache.jump)
        mouse_w, keyboard_w = windows(mouse), windows(keyboard)
        prev = memories = None
        if self.cfg.dit.camera_warp_enabled:
            if cache.latent is None:
                raise ValueError("camera_warp is on but the cache has no latent (kv_cache.init_cache)")
            still = None
            if still_memory:
                given = cond[:, :, :, 0, 0, 0] > 0  # mask channel 0: 1 where the frame is given
                still = camera_lib.holds_still(mouse_w, keyboard_w, k, lift) & ~given
            prev, memories = _still_memories(cache.latent, x, still, still_memory)
        return (*self._prepare(x, t, cond, None, mouse_w, keyboard_w, prev, lift), jump_after, memories)

    def _clip_lifts(self, keyboard, num_frames: int) -> jax.Array | None:
        """(B, P, F, 2) each frame's [previous, own] height from the jump key, the clip starting on the floor
        (``camera.frame_lifts``); None without the jump warp."""
        if not self.cfg.dit.jump_warp:
            return None
        return camera_lib.frame_lifts(keyboard, num_frames, self.cfg.frames_per_step)[0]

    def _warped(self, prev_BPFhwC, mouse_BPFWA, keyboard_BPFWA, lift_BPF2=None) -> jax.Array:
        """Each frame's previous latent, its content moved by the frame's walk (``walk_warp``) and jump
        (``jump_warp``, ``lift_BPF2``) and then by its camera turn (``camera_warp``)."""
        if prev_BPFhwC is None:
            raise ValueError("camera_warp is on but no previous latents were given")
        lead = prev_BPFhwC.shape[:3]
        flat = lambda a: a.reshape((-1,) + a.shape[3:])
        dit = self.cfg.dit
        lift = None if lift_BPF2 is None else lift_BPF2.reshape(-1, 2)
        return camera_lib.warp_previous(flat(prev_BPFhwC), flat(mouse_BPFWA), flat(keyboard_BPFWA),
                                        self.cfg.frames_per_step, dit.camera_warp, dit.walk_warp,
                                        dit.warp_interp, lift, dit.jump_warp,
                                        dit.warp_geometry).reshape(lead + prev_BPFhwC.shape[3:])

    def _grid(self) -> tuple[int, int]:
        _, ph, pw = self.cfg.dit.patch_size
        return self.cfg.latent_height // ph, self.cfg.latent_width // pw

    def _windows(self, actions_BPTA: jax.Array, num_frames: int) -> jax.Array:
        return action_windows(actions_BPTA, self.cfg, num_frames)

    def _validate(self, x, t, cond, context, mouse, keyboard) -> int:
        """Raise ValueError on any shape mismatch; return F."""
        c = self.cfg
        if x.ndim != 6 or x.shape[1] != c.stream_players or x.shape[3:] != (c.latent_height, c.latent_width,
                                                                             c.out_channels):
            raise ValueError(f"x has shape {x.shape}; expected (B, {c.stream_players}, F, {c.latent_height}, "
                             f"{c.latent_width}, {c.out_channels})")
        b, p, f = x.shape[:3]
        t_pad = padded_action_length(c, f)
        expected = {
            "t": (t.shape, (b, p, f)),
            "cond": (cond.shape, x.shape[:5] + (c.in_channels - c.out_channels,)),
            "context": (context.shape[:2] + context.shape[3:], (b, p, c.context_width)),
            "mouse": (mouse.shape, (b, p, t_pad, c.players_in_channels * c.action.mouse_dim)),
            "keyboard": (keyboard.shape, (b, p, t_pad, c.keyboard_in_dim)),
        }
        for name, (got, want) in expected.items():
            if tuple(got) != tuple(want):
                raise ValueError(f"{name} has shape {got}; expected {want} (F={f}, T_pad = k*(F-1)+window = {t_pad})")
        return f

    def _prepare(self, x, t, cond, context, mouse_BPFWA, keyboard_BPFWA, prev=None, lift=None):
        """Patchify, embed time/context/players -> (conditioning, tokens_BPFLD, e_BPFD, skip base or None);
        ``context=None`` leaves the projected context out (the caller brings per-layer cross-attention K/V).
        ``prev``: each frame's previous latent (like x), read with the camera warp only. The skip base
        (``previous_skip``): the warped previous latent, the first-frame latent where the mask gives the frame.
        ``lift``: (B, P, F, 2) the frames' heights for the jump warp (``camera.frame_lifts``), or None."""
        b, p, f = x.shape[:3]
        dtype = jnp.dtype(self.cfg.dit.dtype)
        parts = [x, cond]  # channel order: [x, mask, first-frame latent (, warped previous latent)]
        base = None
        if self.cfg.dit.camera_warp_enabled:
            warped = self._warped(prev, mouse_BPFWA, keyboard_BPFWA, lift)
            parts.append(warped)
            if self.cfg.dit.previous_skip:
                given = cond[..., :1].astype(jnp.float32)  # mask channel 0: 1 where the frame is given
                first = cond[..., cond.shape[-1] - x.shape[-1]:].astype(jnp.float32)
                base = given * first + (1.0 - given) * warped.astype(jnp.float32)
        xc = jnp.concatenate(parts, axis=-1).astype(dtype)
        tokens = self.patch_embedding(xc.reshape((b * p,) + xc.shape[2:]))  # (B*P, F, h, w, D)
        tokens = tokens.reshape(b, p, f, -1, tokens.shape[-1])
        e = self.time_embedding(sinusoidal_embedding(t, self.cfg.dit.freq_dim).astype(dtype))  # (B, P, F, D)
        e0 = self.time_projection(e).reshape(b, p, f, 6, -1)
        player = self.player_embed(jnp.arange(p))
        projected = None if context is None else self.img_emb(context.astype(dtype))
        cond_in = _Conditioning(e0, player, projected, mouse_BPFWA, keyboard_BPFWA)
        return cond_in, tokens, e, base

    def _sequence_plan(self, frame_pos_F, frame_mask, kv_stop_F, num_players: int) -> _SequencePlan:
        c, d = self.cfg, self.cfg.dit
        gh, gw = self._grid()
        angles = rope.rope_3d_angles_at(d.rope_split, d.rope_theta, frame_pos_F, gh, gw, num_players)
        block = num_players * gh * gw  # all players of a frame form one mask block
        frame_mask = None if frame_mask is None else jnp.asarray(frame_mask)
        token_mask = None if frame_mask is None else masks.expand_to_tokens(frame_mask, block)
        kv_stop_L = None if kv_stop_F is None else np.repeat(kv_stop_F, block)
        return _SequencePlan(
            angles, token_mask,
            rope.temporal_rope_angles_at(c.action.rope_dims, c.action.rope_theta, frame_pos_F), frame_mask,
            kv_stop_F, kv_stop_L)

    def _forward_sequence(self, x, t, cond, context, mouse_BPFWA, keyboard_BPFWA, frame_pos_F, frame_mask,
                          kv_stop_F, attend=None, remat: bool = False, prev=None, lift=None) -> jax.Array:
        cond_in, tokens, e, base = self._prepare(x, t, cond, context, mouse_BPFWA, keyboard_BPFWA, prev, lift)
        plan = self._sequence_plan(frame_pos_F, frame_mask, kv_stop_F, x.shape[1])
        if attend is not None:  # the self-attention brings its own mask; no dense token mask
            plan = plan._replace(token_mask=None, attend=attend)

        def step(block, h, layer):
            return block(h, cond_in, plan, layer), None

        tokens, _ = _scan_layers(self.blocks, step, tokens, jnp.arange(self.cfg.dit.num_layers), remat)
        return self._output(tokens, e, x, base)

    def _output(self, tokens_BPFLD, e_BPFD, x, base) -> jax.Array:
        """The head's velocity, plus the previous-frame skip g_x(t) * x - g_b(t) * base where ``base`` is given."""
        v = self._unpatchify(self.head(tokens_BPFLD, e_BPFD))
        if base is None:
            return v
        gates_BPF11G = self.skip_gate(jax.nn.silu(e_BPFD))[:, :, :, None, None, :].astype(jnp.float32)
        gx, gb = jnp.split(gates_BPF11G, 2, axis=-1)
        return (v.astype(jnp.float32) + gx * x.astype(jnp.float32) - gb * base.astype(jnp.float32)).astype(v.dtype)

    def _unpatchify(self, y_BPFLO: jax.Array) -> jax.Array:
        """(B, P, F, h*w, pf*ph*pw*C) -> (B, P, F*pf, h*ph, w*pw, C), channels fastest."""
        b, p, f = y_BPFLO.shape[:3]
        gh, gw = self._grid()
        pf, ph, pw = self.cfg.dit.patch_size
        y = y_BPFLO.reshape(b, p, f, gh, gw, pf, ph, pw, -1).transpose(0, 1, 2, 5, 3, 6, 4, 7, 8)
        return y.reshape(b, p, f * pf, gh * ph, gw * pw, -1)


def skip_gate(cfg: WorldModelConfig, rngs: nnx.Rngs) -> nnx.Module:
    """The previous-frame skip's two gates, Linear(dim -> 2 x latent channels) of silu(e): g_x on the noisy
    latent (the first half of the outputs), g_b on the previous one; at zero, the untrained gates leave the
    velocity as the head's (docs/model.md §8.3)."""
    return dense(cfg.dit.dim, 2 * cfg.out_channels, use_bias=True, kernel_init=nnx.initializers.zeros_init(), rngs=rngs,
                 **_dtypes(cfg))


def _stacked_blocks(cfg: WorldModelConfig, rngs: nnx.Rngs) -> DiTBlock:
    """num_layers DiTBlocks with parameters stacked on a leading layer axis (for nnx.scan)."""

    @nnx.split_rngs(splits=cfg.dit.num_layers)
    @nnx.vmap(in_axes=(0,), out_axes=0)
    def create(r: nnx.Rngs) -> DiTBlock:
        return DiTBlock(cfg, rngs=r)

    return create(rngs)


def block_graphdef(cfg: WorldModelConfig):
    """The graphdef of ONE DiTBlock of ``cfg`` (no parameters are created)."""
    return nnx.split(nnx.eval_shape(lambda: DiTBlock(cfg, rngs=nnx.Rngs(0))))[0]


def unstack_blocks(cfg: WorldModelConfig, blocks_state) -> tuple:
    """The stacked blocks' state (leaves (num_layers, ...), ``nnx.state(dit.blocks)``) as one state per
    layer, each its own buffers; ``nnx.merge(block_graphdef(cfg), states[i])`` is layer i. Differentiable:
    the gradients of the layers' states come back stacked in one piece (``jnp.unstack``'s transpose)."""
    leaves, treedef = jax.tree.flatten(blocks_state)
    per_leaf = [jnp.unstack(a) for a in leaves]
    if any(len(a) != cfg.dit.num_layers for a in per_leaf):
        raise ValueError(f"the blocks' state is not stacked on num_layers={cfg.dit.num_layers} layers")
    return tuple(jax.tree.unflatten(treedef, [a[i] for a in per_leaf]) for i in range(cfg.dit.num_layers))


def stack_blocks(layer_states: tuple):
    """Inverse of ``unstack_blocks``."""
    return jax.tree.map(lambda *a: jnp.stack(a), *layer_states)


def count_params(model: nnx.Module) -> int:
    return sum(math.prod(v.shape) for v in jax.tree.leaves(nnx.state(model, nnx.Param)))
