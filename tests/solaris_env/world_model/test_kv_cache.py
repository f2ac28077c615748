"""Rolling KV cache (docs/model.md §5.2; reference test_kv_cache_analysis)."""

import dataclasses
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from solaris_env.world_model import kv_cache
from solaris_env.world_model.config import DiTConfig, WorldModelConfig
from solaris_env.world_model.masks import causal_window_frame_mask, expand_to_tokens


def _frame_tokens(frame, players, tokens):
    """K/V (1, P*S, 1, 2) for one frame; entry = (frame id, player*S + token) to recognise it later."""
    ids = np.stack([np.full(players * tokens, frame), np.arange(players * tokens)], axis=-1).astype(np.float32)
    return jnp.asarray(ids)[None, :, None, :]


@pytest.mark.parametrize("players,tokens,window", list(itertools.product([1, 2], [1, 3], [1, 2, 3])))
def test_cache_holds_exactly_the_training_window(players, tokens, window):
    block, steps = players * tokens, 8
    cache = kv_cache.empty_cache((), 1, window * block, 1, 2, jnp.float32)
    training = expand_to_tokens(causal_window_frame_mask(steps, window), block)
    for i in range(steps):
        k = _frame_tokens(i, players, tokens)
        cache = kv_cache.update(cache, k, -k)
        valid = np.asarray(kv_cache.valid_mask(cache))
        held = np.asarray(cache.k[0, valid, 0])  # (n_valid, 2) in slot order
        frames = list(range(max(0, i - window + 1), i + 1))
        want = np.concatenate([np.asarray(_frame_tokens(f, players, tokens))[0, :, 0] for f in frames])
        np.testing.assert_array_equal(held, want)  # oldest first, (player, token) order inside a frame
        np.testing.assert_array_equal(np.asarray(cache.v[0, valid, 0]), -want)
        # The keys a query of frame i sees == the keys the training mask allows (any query token of i).
        allowed_frames = np.unique(np.nonzero(training[i * block])[0] // block)
        np.testing.assert_array_equal(np.unique(held[:, 0]), allowed_frames)
        assert int(cache.length) == min((i + 1) * block, window * block)


def test_shapes_fixed_and_length_saturates():
    cache = kv_cache.empty_cache((3,), 2, 4, 2, 8, jnp.float32)  # leading layer axis
    for step in range(5):
        cache = kv_cache.update(cache, jnp.ones((3, 2, 1, 2, 8)), jnp.ones((3, 2, 1, 2, 8)))
        assert cache.k.shape == cache.v.shape == (3, 2, 4, 2, 8)
        np.testing.assert_array_equal(cache.length, [min(step + 1, 4)] * 3)
    assert cache.length.dtype == jnp.int32


def test_update_of_several_entries_at_once_keeps_the_last():
    cache = kv_cache.empty_cache((), 1, 3, 1, 1, jnp.float32)
    cache = kv_cache.update(cache, jnp.arange(5.0).reshape(1, 5, 1, 1), jnp.zeros((1, 5, 1, 1)))
    np.testing.assert_array_equal(cache.k[0, :, 0, 0], [2.0, 3.0, 4.0])
    assert int(cache.length) == 3


def test_valid_mask_is_arange_ge_size_minus_length():
    cache = kv_cache.empty_cache((2,), 1, 5, 1, 1, jnp.float32)
    for length in range(6):
        cache = dataclasses.replace(cache, length=jnp.array([length, 5 - length], jnp.int32))
        got = np.asarray(kv_cache.valid_mask(cache))
        np.testing.assert_array_equal(got[0], np.arange(5) >= 5 - length)
        np.testing.assert_array_equal(got[1], np.arange(5) >= length)


def test_update_is_jittable_and_pure():
    cache = kv_cache.empty_cache((), 1, 2, 1, 1, jnp.float32)
    new = jax.jit(kv_cache.update)(cache, jnp.ones((1, 1, 1, 1)), jnp.ones((1, 1, 1, 1)))
    assert int(cache.length) == 0 and not cache.k.any()  # the input is untouched
    assert int(new.length) == 1


def test_update_rejects_mismatched_shapes():
    cache = kv_cache.empty_cache((), 1, 2, 1, 4, jnp.float32)
    with pytest.raises(ValueError):
        kv_cache.update(cache, jnp.ones((1, 1, 1, 3)), jnp.ones((1, 1, 1, 3)))


@pytest.mark.parametrize("method,players", [("attn", 2), ("concat", 2), ("attn", 1)])
def test_init_cache_shapes_for_solaris(method, players):
    cfg = WorldModelConfig.solaris(num_players=players, dit=DiTConfig(multiplayer=method))
    cache = jax.eval_shape(lambda: kv_cache.init_cache(cfg, batch=3))  # no 2 GB allocation
    p = players if method == "attn" else 1
    assert len(cache.layers) == 30  # one cache per layer
    for layer in cache.layers:
        assert layer.self_attn.k.shape == (3, 12, 6 * p * 880, 128)  # heads-major
        assert layer.self_attn.size == 6 * p * 880
        assert layer.mouse.k.shape == (3 * p * 880, 16, 6, 64)  # heads-major
        assert layer.keyboard.v.shape == (3 * p, 16, 6, 64)
        assert layer.self_attn.length.shape == () and layer.self_attn.length.dtype == jnp.int32
    assert cfg.cache_tokens == 6 * p * 880


def test_init_cache_is_empty_and_uses_requested_dtype():
    cfg = WorldModelConfig.test()
    cache = kv_cache.init_cache(cfg, batch=1, dtype=jnp.bfloat16)
    assert len(cache.layers) == cfg.dit.num_layers
    for layer in cache.layers:
        assert layer.self_attn.k.dtype == jnp.bfloat16 and not layer.self_attn.k.any()
        assert not np.asarray(kv_cache.valid_mask(layer.mouse)).any()


def test_heads_major_layout_rolls_like_the_default():
    """layout "BNSK" holds the same entries as "BSNK", heads before slots."""
    a = kv_cache.empty_cache((), 2, 3, 2, 4, jnp.float32)
    b = kv_cache.empty_cache((), 2, 3, 2, 4, jnp.float32, layout="BNSK")
    assert b.k.shape == (2, 2, 3, 4) and b.size == a.size == 3
    rng = np.random.default_rng(0)
    for n in (1, 2, 1, 3):
        k, v = (jnp.asarray(rng.normal(size=(2, n, 2, 4)), jnp.float32) for _ in range(2))
        a = kv_cache.update(a, k, v)
        b = kv_cache.update(b, k.transpose(0, 2, 1, 3), v.transpose(0, 2, 1, 3))
        np.testing.assert_array_equal(b.k, a.k.transpose(0, 2, 1, 3))
        np.testing.assert_array_equal(b.v, a.v.transpose(0, 2, 1, 3))
        np.testing.assert_array_equal(kv_cache.valid_mask(b), kv_cache.valid_mask(a))
    with pytest.raises(ValueError, match="layout"):
        kv_cache.empty_cache((), 1, 2, 1, 1, jnp.float32, layout="SBNK")


@pytest.mark.parametrize("length,n_new", [(0, 1), (2, 1), (3, 2), (5, 2), (5, 5), (4, 3)])
def test_kept_mask_marks_the_slots_valid_after_an_update(length, n_new):
    """Slots j of the current cache with kept_mask[j] are exactly those at j - n_new, valid, after update."""
    size = 5
    cache = kv_cache.empty_cache((), 1, size, 1, 1, jnp.float32)
    cache = dataclasses.replace(cache, k=jnp.arange(size, dtype=jnp.float32).reshape(1, size, 1, 1),
                                length=jnp.int32(length))
    updated = kv_cache.update(cache, jnp.full((1, n_new, 1, 1), -1.0), jnp.zeros((1, n_new, 1, 1)))
    kept = np.asarray(kv_cache.kept_mask(cache, n_new))
    after = np.asarray(updated.k[0, :, 0, 0])[np.asarray(kv_cache.valid_mask(updated))]
    np.testing.assert_array_equal(np.arange(size)[kept], after[after >= 0])  # old entries still seen
