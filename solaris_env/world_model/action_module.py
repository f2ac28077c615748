"""The per-player action module (docs/model.md §4; Matrix-Game 2.0 design).

It runs per player (players folded into the batch: B' = B * P) on tokens ``x_BFLD`` (F latent frames,
L spatial tokens) and adds two residuals:

- mouse branch: for every spatial location, the token features of each latent frame are concatenated
  with that frame's window of mouse actions, mapped by ``mouse_mlp`` and ``t_qkv``, and attended over
  time (windowed, with the temporal RoPE), then ``proj_mouse``;
- keyboard branch: the window's keyboard actions are embedded per action frame (``keyboard_embed``),
  flattened per latent frame into one key/value (``keyboard_attn_kv``); every token queries them over
  time with ``mouse_attn_q``, then ``proj_keyboard``.

Action/frame alignment (§4.3): actions come left-padded by repeating action 0 ``action_left_padding``
times, so a sequence for F latent frames has ``T_pad = k * (F - 1) + action_window`` entries (k video
frames per latent frame). Latent frame i sees padded actions ``[k * i, k * i + action_window)``, whose
last entry is the original action ``k * i``.

Two entry points: ``__call__`` (a whole sequence with a frame-level mask) and ``decode`` (one frame
against rolling caches). Both share the projections below.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import nnx

from solaris_env.world_model import kv_cache
from solaris_env.world_model.attention import RMSNorm, attention, attention_heads_major, dense, stop_gradient_where
from solaris_env.world_model.config import WorldModelConfig
from solaris_env.world_model.rope import apply_rope

# ---------------------------------------------------------------------------------------------
# Action windows (pure)
# ---------------------------------------------------------------------------------------------


def left_pad_actions(actions_BPTA: jax.Array, padding: int) -> jax.Array:
    """Repeat action 0 ``padding`` times in front: (B, P, T, A) -> (B, P, T + padding, A)."""
    first = jnp.repeat(actions_BPTA[:, :, :1], padding, axis=2)
    return jnp.concatenate([first, actions_BPTA], axis=2)


def padded_action_length(cfg: WorldModelConfig, num_frames: int) -> int:
    """T_pad for F latent frames: k * (F - 1) + action_window (4F + 8 for solaris)."""
    return cfg.frames_per_step * (num_frames - 1) + cfg.action_window


def action_windows(actions_pad_BPTA: jax.Array, cfg: WorldModelConfig, num_frames: int) -> jax.Array:
    """(B, P, T_pad, A) left-padded actions -> (B, P, F, action_window, A); frame i gets [k*i, k*i + window)."""
    expected = padded_action_length(cfg, num_frames)
    if actions_pad_BPTA.shape[2] != expected:
        raise ValueError(f"padded action length {actions_pad_BPTA.shape[2]} != k*(F-1)+action_window = "
                         f"{cfg.frames_per_step}*({num_frames}-1)+{cfg.action_window} = {expected}")
    idx = cfg.frames_per_step * jnp.arange(num_frames)[:, None] + jnp.arange(cfg.action_window)[None]
    return actions_pad_BPTA[:, :, idx]


def window_at(actions_pad_BPTA: jax.Array, cfg: WorldModelConfig, frame_index: int | jax.Array) -> jax.Array:
    """(B, P, T_pad, A) -> (B, P, action_window, A): the window of latent frame ``frame_index`` (traceable)."""
    start = cfg.frames_per_step * jnp.asarray(frame_index, jnp.int32)
    return jax.lax.dynamic_slice_in_dim(actions_pad_BPTA, start, cfg.action_window, axis=2)


def _per_location(x_BFLNK: jax.Array) -> jax.Array:
    """(B, F, L, N, K) -> (B * L, F, N, K): one temporal sequence per spatial location."""
    b, f, s, n, k = x_BFLNK.shape
    return x_BFLNK.transpose(0, 2, 1, 3, 4).reshape(b * s, f, n, k)


def _from_locations(y_bFNK: jax.Array, batch: int) -> jax.Array:
    """(b = B * L, F, N, K) -> (B, F, L, N * K)."""
    bs, f, n, k = y_bFNK.shape
    return y_bFNK.reshape(batch, bs // batch, f, n * k).transpose(0, 2, 1, 3)


def mouse_kernel_rows(cfg: WorldModelConfig) -> slice:
    """The rows of ``mouse_mlp``'s first kernel that read the mouse window (its input is [tokens, mouse])."""
    return slice(cfg.dit.dim, cfg.mouse_in_dim)


def rescaled_mouse_kernel(kernel_LIO: jax.Array, cfg: WorldModelConfig, new_gain: float) -> jax.Array:
    """``mouse_mlp``'s first kernel (layers stacked first) for ``mouse_input_gain = new_gain`` computing the
    same function as ``kernel_LIO`` under ``cfg.action.mouse_input_gain``: the mouse rows times old / new."""
    if not (math.isfinite(new_gain) and new_gain > 0):
        raise ValueError(f"mouse_input_gain must be a finite number > 0, got {new_gain}")
    rows = mouse_kernel_rows(cfg)
    return kernel_LIO.at[..., rows, :].multiply(cfg.action.mouse_input_gain / new_gain)


# ---------------------------------------------------------------------------------------------
# Module
# ---------------------------------------------------------------------------------------------


class ActionModule(nnx.Module):
    """Mouse + keyboard conditioning of one DiT block (parameter names follow the official tree).

    Args:
        cfg: the world-model config; sizes come from ``cfg.action`` and the derived properties
            ``mouse_in_dim``, ``keyboard_in_dim``, ``action_window``.
        rngs: parameter initialisation.
    """

    def __init__(self, cfg: WorldModelConfig, *, rngs: nnx.Rngs):
        a, d = cfg.action, cfg.dit
        kw = dict(dtype=jnp.dtype(d.dtype), param_dtype=jnp.dtype(d.param_dtype), rngs=rngs)
        self.num_heads, self.impl, self.dtype = a.num_heads, d.attention_impl, kw["dtype"]
        self.mouse_input_gain = a.mouse_input_gain
        self.keyboard_embed = nnx.Sequential(
            dense(cfg.keyboard_in_dim, a.keyboard_embed_dim, use_bias=True, **kw), jax.nn.silu,
            dense(a.keyboard_embed_dim, a.keyboard_embed_dim, use_bias=True, **kw))
        self.mouse_mlp = nnx.Sequential(
            dense(cfg.mouse_in_dim, a.mouse_hidden_dim, use_bias=True, **kw), jax.nn.gelu,  # tanh GELU
            dense(a.mouse_hidden_dim, a.mouse_hidden_dim, use_bias=True, **kw),
            nnx.LayerNorm(a.mouse_hidden_dim, epsilon=a.mouse_mlp_eps, dtype=kw["dtype"],
                          param_dtype=kw["param_dtype"], rngs=rngs))
        self.t_qkv = dense(a.mouse_hidden_dim, 3 * a.mouse_hidden_dim, use_bias=False, **kw)
        norm = lambda dim: RMSNorm(dim, a.eps, param_dtype=kw["param_dtype"], rngs=rngs) if a.qk_norm else None
        self.img_attn_q_norm, self.img_attn_k_norm = norm(a.head_dim), norm(a.head_dim)
        self.key_attn_q_norm, self.key_attn_k_norm = norm(a.keyboard_head_dim), norm(a.keyboard_head_dim)
        self.proj_mouse = dense(a.mouse_hidden_dim, d.dim, use_bias=False, **kw)
        self.mouse_attn_q = dense(d.dim, a.keyboard_hidden_dim, use_bias=False, **kw)
        self.keyboard_attn_kv = dense(cfg.action_window * a.keyboard_embed_dim, 2 * a.keyboard_hidden_dim,
                                      use_bias=False, **kw)
        self.proj_keyboard = dense(a.keyboard_hidden_dim, d.dim, use_bias=False, **kw)

    # -- shared pieces ---------------------------------------------------------------------------
    @staticmethod
    def _norm(norm: RMSNorm | None, x: jax.Array) -> jax.Array:
        return x if norm is None else norm(x)

    def _mouse_qkv(self, x_BFLD, mouse_BFWA, angles_FJ):
        """-> q, k, v of shape (B * L, F, N, K); q and k normed and rotated."""
        b, f, s, _ = x_BFLD.shape
        m_BF1E = mouse_BFWA.reshape(b, f, 1, -1).astype(x_BFLD.dtype)  # frame-major [m0_0, m0_1, m1_0, ...]
        if self.mouse_input_gain != 1.0:
            m_BF1E = m_BF1E * self.mouse_input_gain
        m_BFLE = jnp.broadcast_to(m_BF1E, (b, f, s, m_BF1E.shape[-1]))
        h = self.mouse_mlp(jnp.concatenate([x_BFLD, m_BFLE], axis=-1))
        qkv = self.t_qkv(h).reshape(b, f, s, 3, self.num_heads, -1)  # layout (3, N, K)
        q = _per_location(self._norm(self.img_attn_q_norm, qkv[..., 0, :, :]))
        k = _per_location(self._norm(self.img_attn_k_norm, qkv[..., 1, :, :]))
        return apply_rope(q, angles_FJ), apply_rope(k, angles_FJ), _per_location(qkv[..., 2, :, :])

    def _mouse_out(self, x_BFLD, attn_bFNK):
        return x_BFLD + self.proj_mouse(_from_locations(attn_bFNK, x_BFLD.shape[0]))

    def _keyboard_q(self, x_BFLD, angles_FJ):
        """-> (B * L, F, N, K) normed, rotated queries."""
        b, f, s, _ = x_BFLD.shape
        q = self.mouse_attn_q(x_BFLD).reshape(b, f, s, self.num_heads, -1)
        return apply_rope(_per_location(self._norm(self.key_attn_q_norm, q)), angles_FJ)

    def _keyboard_kv(self, keyboard_BFWA, angles_FJ):
        """-> k, v of shape (B, F, N, K): one key/value per latent frame from its action window."""
        b, f = keyboard_BFWA.shape[:2]
        emb = self.keyboard_embed(keyboard_BFWA.astype(self.dtype))  # (B, F, W, E)
        kv = self.keyboard_attn_kv(emb.reshape(b, f, -1)).reshape(b, f, 2, self.num_heads, -1)  # [K | V]
        k = apply_rope(self._norm(self.key_attn_k_norm, kv[:, :, 0]), angles_FJ)
        return k, kv[:, :, 1]

    def _keyboard_out(self, x_BFLD, attn_bFNK):
        return x_BFLD + self.proj_keyboard(_from_locations(attn_bFNK, x_BFLD.shape[0]))

    # -- entry points ------------------------------------------------------------------------------
    def __call__(self, x_BFLD: jax.Array, mouse_BFWA: jax.Array, keyboard_BFWA: jax.Array, angles_FJ: jax.Array,
                 frame_mask_FF, kv_stop_F=None) -> jax.Array:
        """Whole-sequence pass.

        Args:
            x_BFLD: tokens, players folded into B.
            mouse_BFWA / keyboard_BFWA: per-latent-frame action windows (``action_windows``).
            angles_FJ: temporal RoPE angles of the F frames (``rope.temporal_rope_angles_at``).
            frame_mask_FF: (F, F) bool frame mask or None (bidirectional).
            kv_stop_F: optional (F,) bool, frames whose keys/values get no gradient.
        Returns:
            x_BFLD with the mouse and keyboard residuals added.
        """
        s = x_BFLD.shape[2]
        q, k, v = self._mouse_qkv(x_BFLD, mouse_BFWA, angles_FJ)
        k, v = stop_gradient_where(k, kv_stop_F), stop_gradient_where(v, kv_stop_F)
        x_BFLD = self._mouse_out(x_BFLD, attention(q, k, v, frame_mask_FF, self.impl))
        q = self._keyboard_q(x_BFLD, angles_FJ)
        k, v = self._keyboard_kv(keyboard_BFWA, angles_FJ)
        k, v = stop_gradient_where(k, kv_stop_F), stop_gradient_where(v, kv_stop_F)
        k, v = jnp.repeat(k, s, axis=0), jnp.repeat(v, s, axis=0)  # one copy per spatial location
        return self._keyboard_out(x_BFLD, attention(q, k, v, frame_mask_FF, self.impl))

    def decode(self, x_BFLD: jax.Array, mouse_BFWA: jax.Array, keyboard_BFWA: jax.Array, angles_FJ: jax.Array,
               cache_mouse: kv_cache.KVCache, cache_keyboard: kv_cache.KVCache, commit: int):
        """F new frames against the rolling caches, heads-major (mouse (B*L, N, W, K), keyboard (B, N, W, K)).

        Frame f attends to the cache slots still valid after f + 1 frames are appended and to the new
        frames <= f (for F = 1: the cache with the frame appended). Returns (x_BFLD, new_cache_mouse,
        new_cache_keyboard); the caches get the first ``commit`` new frames (0: the caches as they were).
        """
        f, s = x_BFLD.shape[1], x_BFLD.shape[2]

        def attend(q, k_new, v_new, cache, repeat):
            # the caches are heads-major (B', N, W, K): the cache and the new frames are two key blocks of one
            # softmax (no concatenation, no transposed copy of the cache); frame f sees the slots kept after
            # f + 1 appends and the new frames <= f
            if cache.length.ndim != 0:
                raise ValueError(f"action caches take one fill level per layer; got length {cache.length.shape}")
            kept = jnp.stack([kv_cache.kept_mask(cache, i + 1) for i in range(f)], axis=-2)  # (F, W)
            causal = None if f == 1 else jnp.tril(jnp.ones((f, f), bool))
            k_h, v_h = (a.transpose(0, 2, 1, 3).astype(cache.k.dtype) for a in (k_new, v_new))  # (B', N, F, K)
            blocks = [(cache.k, cache.v, kept), (k_h, v_h, causal)]
            if repeat > 1:
                blocks = [(jnp.repeat(k, repeat, axis=0), jnp.repeat(v, repeat, axis=0), m) for k, v, m in blocks]
            new_cache = kv_cache.update(cache, k_h[:, :, :commit], v_h[:, :, :commit]) if commit else cache
            return attention_heads_major(q, blocks), new_cache

        q, k, v = self._mouse_qkv(x_BFLD, mouse_BFWA, angles_FJ)
        attn, cache_mouse = attend(q, k, v, cache_mouse, 1)
        x_BFLD = self._mouse_out(x_BFLD, attn)
        q = self._keyboard_q(x_BFLD, angles_FJ)
        k, v = self._keyboard_kv(keyboard_BFWA, angles_FJ)
        attn, cache_keyboard = attend(q, k, v, cache_keyboard, s)
        return self._keyboard_out(x_BFLD, attn), cache_mouse, cache_keyboard
