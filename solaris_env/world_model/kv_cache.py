"""Rolling key/value caches for the cached decode step (docs/model.md §5.2).

A cache is plain data (``flax.struct.dataclass``); functions return new caches, nothing mutates.
``KVCache`` holds ``k``/``v`` of shape ``(B, S, N, K)`` (``layout="BSNK"``, S = cache slots) or
``(B, N, S, K)`` (``layout="BNSK"``, heads-major: what an attention dot reads without a transpose)
and a scalar ``length``; the functions also accept leading axes (``(..., B, S, N, K)``, ``length`` (...)).

Rolling FIFO: ``update`` appends the new entries at the end and keeps the last S, so the newest entry
is always in the last slot; ``length`` counts the valid (filled) slots, which are the *last* ``length``
slots: ``valid_mask = arange(S) >= S - length``. With S = W frames, a step that updates with frame i
and attends to the result sees frames ``[max(0, i - W + 1), i]``, the same frames as the training
causal window mask (``masks.causal_window_frame_mask``).

The DiT's cache (``DiTCache``, what ``WorldDiT.decode`` reads and writes) is one ``LayerCache`` per layer,
each its own buffers (a layer's attention reads its cache in place; no per-layer slice of a stacked
array, no stacking copy after a commit), with three caches per layer:

| cache | k / v shape | slots |
|---|---|---|
| self_attn | (B, N, cache_tokens, K), heads-major | window * stream players * tokens per frame (post-RoPE k) |
| mouse | (B * P * tokens, Na, window, Ka), heads-major | one per frame, per spatial location |
| keyboard | (B * P, Na, window, Ka), heads-major | one per frame |

With the camera warp (``DiTConfig.camera_warp``) the cache also carries ``latent``, the last cached frame's
latent (or, with ``still_memory``, its blend with the previous ones while the view held still), which the next
frame sees shifted.

Mouse/keyboard caches exist for every layer but only the first ``num_action_blocks`` layers touch them;
the others stay empty.

``kept_mask`` tells which current slots stay valid after an update with n entries, so a pass that only
*reads* "cache + new entries" (the denoising passes) can attend to the old cache and the new entries
as two blocks without building the updated cache (``attention.attention_heads_major``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from solaris_env.world_model.camera import JUMP_STATE
from solaris_env.world_model.config import WorldModelConfig


LAYOUTS = ("BSNK", "BNSK")


@struct.dataclass
class KVCache:
    k: jax.Array  # (..., B, S, N, K) or, layout "BNSK", (..., B, N, S, K)
    v: jax.Array  # same as k
    length: jax.Array  # (...) int32: valid slots, counted from the end
    layout: str = struct.field(pytree_node=False, default="BSNK")

    @property
    def slot_axis(self) -> int:
        return -3 if self.layout == "BSNK" else -2

    @property
    def size(self) -> int:
        return self.k.shape[self.slot_axis]


@struct.dataclass
class LayerCache:
    """One DiT layer's caches."""
    self_attn: KVCache
    mouse: KVCache
    keyboard: KVCache


@struct.dataclass
class DiTCache:
    layers: tuple[LayerCache, ...]  # one per DiT layer
    # camera warp only (``DiTConfig.camera_warp``): (B, P, h, w, C) the next frame's previous latent: the last
    # cached frame's latent as the commit pass got it (with ``still_memory``, blended with the one before it
    # while the view held still; ``WorldDiT.decode``); None otherwise
    latent: jax.Array | None = None
    # jump warp only (``DiTConfig.jump_warp``): (B, P, ``JUMP_STATE``) the jump state after the last cached
    # frame (height, vertical velocity, that frame's mean height; ``camera.frame_lifts``); None otherwise
    jump: jax.Array | None = None


def empty_cache(lead_shape: tuple[int, ...], batch: int, slots: int, heads: int, head_dim: int,
                dtype, layout: str = "BSNK") -> KVCache:
    """Zero K/V of shape lead_shape + (batch, slots, heads, head_dim) (``layout="BNSK"``: heads before
    slots), length 0."""
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    inner = (batch, slots, heads, head_dim) if layout == "BSNK" else (batch, heads, slots, head_dim)
    shape = tuple(lead_shape) + inner
    return KVCache(k=jnp.zeros(shape, dtype), v=jnp.zeros(shape, dtype),
                   length=jnp.zeros(tuple(lead_shape), jnp.int32), layout=layout)


def init_cache(cfg: WorldModelConfig, batch: int, dtype=None) -> DiTCache:
    """Empty caches for every DiT layer; ``dtype`` defaults to the DiT compute dtype."""
    dtype = jnp.dtype(cfg.dit.dtype if dtype is None else dtype)
    players = cfg.stream_players
    a = cfg.action

    def layer() -> LayerCache:
        return LayerCache(
            self_attn=empty_cache((), batch, cfg.cache_tokens, cfg.dit.num_heads, cfg.dit.head_dim, dtype,
                                  layout="BNSK"),
            mouse=empty_cache((), batch * players * cfg.tokens_per_frame, cfg.dit.window, a.num_heads, a.head_dim,
                              dtype, layout="BNSK"),
            keyboard=empty_cache((), batch * players, cfg.dit.window, a.num_heads, a.keyboard_head_dim, dtype,
                                 layout="BNSK"))

    latent = (jnp.zeros((batch, players, cfg.latent_height, cfg.latent_width, cfg.out_channels), jnp.float32)
              if cfg.dit.camera_warp_enabled else None)
    jump = jnp.zeros((batch, players, JUMP_STATE), jnp.float32) if cfg.dit.jump_warp else None  # on the floor
    return DiTCache(layers=tuple(layer() for _ in range(cfg.dit.num_layers)), latent=latent, jump=jump)


def update(cache: KVCache, k_new: jax.Array, v_new: jax.Array) -> KVCache:
    """Append ``k_new``/``v_new`` (..., B, n, N, K), or (..., B, N, n, K) for layout "BNSK", and keep the
    last S slots; length saturates at S."""
    axis = cache.slot_axis % cache.k.ndim
    other = lambda shape: shape[:axis] + shape[axis + 1:]
    if k_new.shape != v_new.shape or k_new.ndim != cache.k.ndim or other(k_new.shape) != other(cache.k.shape):
        raise ValueError(f"new k/v {k_new.shape}/{v_new.shape} do not fit cache {cache.k.shape} "
                         f"(layout {cache.layout})")
    size, n_new = cache.size, k_new.shape[axis]
    keep = lambda old, new: jax.lax.slice_in_dim(jnp.concatenate([old, new.astype(old.dtype)], axis=axis),
                                                 n_new, n_new + size, axis=axis)
    return KVCache(k=keep(cache.k, k_new), v=keep(cache.v, v_new),
                   length=jnp.minimum(cache.length + n_new, size).astype(jnp.int32), layout=cache.layout)


def valid_mask(cache: KVCache) -> jax.Array:
    """(..., S) bool: True for filled slots (the last ``length`` ones)."""
    return jnp.arange(cache.size) >= (cache.size - cache.length)[..., None]


def kept_mask(cache: KVCache, n_new: int) -> jax.Array:
    """(..., S) bool over the CURRENT slots: those still valid after ``update`` with ``n_new`` entries
    (the oldest ``n_new`` slots are evicted). Attending to these slots plus the new entries equals
    attending to ``update(cache, ...)`` under ``valid_mask``."""
    return valid_mask(cache) & (jnp.arange(cache.size) >= n_new)
