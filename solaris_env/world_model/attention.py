"""Attention kernel entry point, and the norms and Linear factory shared by the DiT and the action module.

``attention`` is the one place a kernel is chosen (``cfg.dit.attention_impl``); model code never
branches on the platform. Norms compute their statistics in f32 and cast back (model-spec §2.1-§2.2).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
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
