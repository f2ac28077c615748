"""Attention masks as pure functions of integers (docs/model.md §5.1).

Every mask is a boolean NumPy array, True = "query may attend to key". Masks are built at frame level
(one row/column per latent frame) and expanded to tokens with ``expand_to_tokens``. A frame block holds
every token of that latent frame for *all* players, packed ``(frame, player, token)``, so the block size
is ``tokens_per_frame * players``; using only ``tokens_per_frame`` is the bug recorded in
``test_masks.py::test_block_size_without_players_bug``.

Conventions: ``i`` is the query frame, ``j`` the key frame, ``W`` the sliding window in latent frames.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def _check_sizes(num_frames: int, window: int | None = None) -> None:
    if num_frames < 1:
        raise ValueError(f"num_frames must be >= 1, got {num_frames}")
    if window is not None and window < 1:
        raise ValueError(f"window must be >= 1, got {window}")


def _frame_grid(num_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Query index i (column vector) and key index j (row vector) for an F x F grid."""
    idx = np.arange(num_frames)
    return idx[:, None], idx[None, :]


def bidirectional_frame_mask(num_frames: int) -> np.ndarray:
    """(F, F) all True: every frame sees every frame (stages 1-2, the teacher)."""
    _check_sizes(num_frames)
    return np.ones((num_frames, num_frames), dtype=bool)


def causal_window_frame_mask(num_frames: int, window: int) -> np.ndarray:
    """(F, F) block-causal sliding window: frame i sees frames j with ``i - W < j <= i``."""
    _check_sizes(num_frames, window)
    i, j = _frame_grid(num_frames)
    return (j <= i) & (j > i - window)


def teacher_forcing_frame_mask(num_frames: int, window: int) -> np.ndarray:
    """(2F, 2F) mask over the sequence ``[clean frames 0..F-1 ; noisy frames 0..F-1]``.

    clean -> clean: ``i - W < j <= i`` (the causal window);
    clean -> noisy: never;
    noisy -> clean: ``i - W < j < i`` (strictly past: the same W-1 committed frames a cached step sees);
    noisy -> noisy: ``j == i`` (each noisy frame sees only itself).
    """
    _check_sizes(num_frames, window)
    i, j = _frame_grid(num_frames)
    clean_to_clean = (j <= i) & (j > i - window)
    clean_to_noisy = np.zeros((num_frames, num_frames), dtype=bool)
    noisy_to_clean = (j < i) & (j > i - window)
    noisy_to_noisy = j == i
    return np.block([[clean_to_clean, clean_to_noisy], [noisy_to_clean, noisy_to_noisy]])


def expand_to_tokens(frame_mask, block_size: int):
    """(Fq, Fk) frame mask -> (Fq * block_size, Fk * block_size) token mask.

    ``block_size`` is the number of consecutive tokens that form one frame: ``tokens_per_frame *
    players`` for the DiT self-attention (players packed inside the frame), 1 for the action module.
    NumPy in gives NumPy out; a ``jax.Array`` in gives a jnp result, which the model uses so that a
    large token mask is computed on device instead of being baked into the compiled program.
    """
    if block_size < 1:
        raise ValueError(f"block_size must be >= 1, got {block_size}")
    xp = jnp if isinstance(frame_mask, jax.Array) else np
    frame_mask = xp.asarray(frame_mask, dtype=bool)
    if frame_mask.ndim != 2:
        raise ValueError(f"frame_mask must be 2-D, got shape {frame_mask.shape}")
    return xp.repeat(xp.repeat(frame_mask, block_size, axis=0), block_size, axis=1)
