"""Rolling key/value caches for the cached decode step (model-spec §5.2).

A cache is plain data (``flax.struct.dataclass``); functions return new caches, nothing mutates.
``KVCache`` holds ``k``/``v`` of shape ``(..., B, S, N, K)`` (S = cache slots) and ``length`` of shape
``(...)``. The leading ``...`` is the layer axis of the DiT's stacked caches; inside a block the
leading axis is gone and the same functions apply.

Rolling FIFO: ``update`` appends the new entries at the end and keeps the last S, so the newest entry
is always in the last slot; ``length`` counts the valid (filled) slots, which are the *last* ``length``
slots: ``valid_mask = arange(S) >= S - length``. With S = W frames, a step that updates with frame i
and attends to the result sees frames ``[max(0, i - W + 1), i]``, the same frames as the training
causal window mask (``masks.causal_window_frame_mask``).

Three caches per DiT (``DiTCache``), each with one entry per layer:

| cache | k / v shape | slots |
|---|---|---|
| self_attn | (layers, B, cache_tokens, N, K) | window * stream players * tokens per frame (post-RoPE keys) |
| mouse | (layers, B * P * tokens, window, Na, Ka) | one per frame, per spatial location |
| keyboard | (layers, B * P, window, Na, Ka) | one per frame |

Mouse/keyboard caches exist for every layer (uniform scan) but only the first ``num_action_blocks``
layers touch them; the others stay empty.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from solaris_env.world_model.config import WorldModelConfig


@struct.dataclass
class KVCache:
    k: jax.Array  # (..., B, S, N, K)
    v: jax.Array  # (..., B, S, N, K)
    length: jax.Array  # (...) int32: valid slots, counted from the end

    @property
    def size(self) -> int:
        return self.k.shape[-3]


@struct.dataclass
class DiTCache:
    self_attn: KVCache
    mouse: KVCache
    keyboard: KVCache


def empty_cache(lead_shape: tuple[int, ...], batch: int, slots: int, heads: int, head_dim: int,
                dtype) -> KVCache:
    """Zero K/V of shape lead_shape + (batch, slots, heads, head_dim), length 0."""
    shape = tuple(lead_shape) + (batch, slots, heads, head_dim)
    return KVCache(k=jnp.zeros(shape, dtype), v=jnp.zeros(shape, dtype),
                   length=jnp.zeros(tuple(lead_shape), jnp.int32))


def init_cache(cfg: WorldModelConfig, batch: int, dtype=None) -> DiTCache:
    """Empty caches for every DiT layer; ``dtype`` defaults to the DiT compute dtype."""
    dtype = jnp.dtype(cfg.dit.dtype if dtype is None else dtype)
    layers = (cfg.dit.num_layers,)
    players = cfg.stream_players
    a = cfg.action
    return DiTCache(
        self_attn=empty_cache(layers, batch, cfg.cache_tokens, cfg.dit.num_heads, cfg.dit.head_dim, dtype),
        mouse=empty_cache(layers, batch * players * cfg.tokens_per_frame, cfg.dit.window, a.num_heads,
                          a.head_dim, dtype),
        keyboard=empty_cache(layers, batch * players, cfg.dit.window, a.num_heads, a.keyboard_head_dim, dtype),
    )


def update(cache: KVCache, k_new: jax.Array, v_new: jax.Array) -> KVCache:
    """Append ``k_new``/``v_new`` (..., B, n, N, K) and keep the last S slots; length saturates at S."""
    if k_new.shape != v_new.shape or k_new.shape[:-3] != cache.k.shape[:-3] or \
            k_new.shape[-2:] != cache.k.shape[-2:]:
        raise ValueError(f"new k/v {k_new.shape}/{v_new.shape} do not fit cache {cache.k.shape}")
    size, n_new = cache.size, k_new.shape[-3]
    k = jnp.concatenate([cache.k, k_new.astype(cache.k.dtype)], axis=-3)[..., -size:, :, :]
    v = jnp.concatenate([cache.v, v_new.astype(cache.v.dtype)], axis=-3)[..., -size:, :, :]
    return KVCache(k=k, v=v, length=jnp.minimum(cache.length + n_new, size).astype(jnp.int32))


def valid_mask(cache: KVCache) -> jax.Array:
    """(..., S) bool: True for filled slots (the last ``length`` ones)."""
    return jnp.arange(cache.size) >= (cache.size - cache.length)[..., None]
