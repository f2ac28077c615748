"""Attention kernel entry point, and the norms and Linear factory shared by the DiT and the action module.

``attention`` is the one place a kernel is chosen (``cfg.dit.attention_impl``); model code never
branches on the platform. ``attention_heads_major`` is the decode step's form (plain XLA ops: several
key blocks, heads-major keys, no concatenation). Norms compute their statistics in f32 and cast back
(docs/model.md §3.3-§3.4).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx


def attention(q_BLNK: jax.Array, k_BSNK: jax.Array, v_BSNK: jax.Array, mask: jax.Array | None = None,
              impl: str = "xla") -> jax.Array:
    """Softmax attention with scale 1/sqrt(K) -> (B, L, N, K).

    ``mask`` is boolean, True = attend, broadcastable to (B, N, L, S): pass (L, S) for one mask shared
    by the batch, (S,) for a key-validity mask, or None for full attention. Every query row must allow
    at least one key.
    """
    if mask is not None:
        mask = jnp.asarray(mask, bool)
        mask = mask.reshape((1,) * (4 - mask.ndim) + mask.shape)
    return jax.nn.dot_product_attention(q_BLNK, k_BSNK, v_BSNK, mask=mask, implementation=impl)


def attention_heads_major(q_BLNK: jax.Array, blocks) -> jax.Array:
    """Softmax attention (scale 1/sqrt(K)) over several key/value blocks at once -> (B, L, N, K).

    ``blocks``: a sequence of ``(k_BNSK, v_BNSK, mask)``, keys/values heads-major (B, N, S_i, K) and
    ``mask`` None or bool broadcastable to (B, N, L, S_i) (True = attend; an (S_i,) key-validity mask
    or a (B, 1, 1, S_i) one). The softmax runs jointly over all blocks, so the result equals
    ``attention`` over the concatenated keys, without building the concatenation; heads-major keys
    feed the dots without a transpose on XLA:CPU (the decode step's cached keys and the context).
    Logits and the softmax are f32. Every query row must allow at least one key.
    """
    scale = 1.0 / np.sqrt(q_BLNK.shape[-1])
    q = q_BLNK.astype(jnp.float32) * scale
    # logits key-major, (B, N, S, L): the keys are the dot's row-major left operand as stored (computing
    # (B, N, L, S) made XLA:CPU transpose every cached key block in every pass, ~30 % of a batched step)
    logits = []
    for k_BNSK, _, mask in blocks:
        s = jnp.einsum("bnsk,blnk->bnsl", k_BNSK.astype(jnp.float32), q)
        logits.append(s if mask is None else jnp.where(_key_major(mask), s, -jnp.inf))
    peak = functools.reduce(jnp.maximum, [jnp.max(s, axis=-2, keepdims=True) for s in logits])
    probs = [jnp.exp(s - peak) for s in logits]
    total = functools.reduce(jnp.add, [jnp.sum(p, axis=-2, keepdims=True) for p in probs])  # (B, N, 1, L)
    y = functools.reduce(jnp.add, [jnp.einsum("bnsl,bnsk->blnk", p, v_BNSK.astype(jnp.float32))
                                   for p, (_, v_BNSK, _) in zip(probs, blocks)])
    return (y / total.transpose(0, 3, 1, 2)).astype(q_BLNK.dtype)


def _key_major(mask) -> jax.Array:
    """A mask broadcastable to (B, N, L, S) -> broadcastable to (B, N, S, L)."""
    mask = jnp.asarray(mask, bool)
    return mask[:, None] if mask.ndim == 1 else jnp.swapaxes(mask, -1, -2)


def stop_gradient_where(x_BLNK: jax.Array, stop_L) -> jax.Array:
    """Stop the gradient of the sequence entries (axis 1) whose flag in ``stop_L`` is set; None = keep all."""
    if stop_L is None:
        return x_BLNK
    stop = jnp.asarray(stop_L, bool).reshape((1, -1) + (1,) * (x_BLNK.ndim - 2))
    return jnp.where(stop, jax.lax.stop_gradient(x_BLNK), x_BLNK)


def layer_norm(x: jax.Array, eps: float) -> jax.Array:
    """LayerNorm without affine parameters over the last axis, computed in f32."""
    x32 = x.astype(jnp.float32)
    mean = x32.mean(axis=-1, keepdims=True)
    var = jnp.square(x32 - mean).mean(axis=-1, keepdims=True)
    return ((x32 - mean) * jax.lax.rsqrt(var + eps)).astype(x.dtype)


class RMSNorm(nnx.Module):
    """x * rsqrt(mean(x^2) + eps) in f32, cast back to x's dtype, times a learned ``weight`` (Wan)."""

    def __init__(self, dim: int, eps: float, *, param_dtype, rngs: nnx.Rngs):
        del rngs  # deterministic init (ones); kept for the constructor convention
        self.eps = eps
        self.weight = nnx.Param(jnp.ones((dim,), param_dtype))

    def __call__(self, x: jax.Array) -> jax.Array:
        x32 = x.astype(jnp.float32)
        normed = (x32 * jax.lax.rsqrt(jnp.mean(jnp.square(x32), axis=-1, keepdims=True) + self.eps)).astype(x.dtype)
        return normed * self.weight[...].astype(x.dtype)


def dense(in_dim: int, out_dim: int, *, use_bias: bool, dtype, param_dtype, rngs: nnx.Rngs,
          kernel_init=nnx.initializers.xavier_uniform()) -> nnx.Linear:
    """Linear layer with the Wan initialisation (xavier-uniform kernel, zero bias)."""
    return nnx.Linear(in_dim, out_dim, use_bias=use_bias, dtype=dtype, param_dtype=param_dtype,
                      kernel_init=kernel_init, bias_init=nnx.initializers.zeros_init(), rngs=rngs)
