"""3D RoPE and the action module's temporal RoPE (docs/model.md §3.5, §4.2; reference test_rope_consistency)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from solaris_env.world_model.config import DiTConfig, WorldModelConfig
from solaris_env.world_model.rope import (apply_rope, rope_3d_angles, rope_3d_angles_at,
                                          teacher_forcing_frame_positions, temporal_rope_angles)

SPLIT, THETA = (6, 5, 5), 10000.0  # head_dim 32, the `test` preset's split
HEADS, HEAD_DIM = 2, 32
GRID_H, GRID_W = 2, 3


def _rand(shape, seed=0):
    return jax.random.normal(jax.random.key(seed), shape, jnp.float32)


def _complex_reference(x, angles):
    """view_as_complex on interleaved pairs, multiply by exp(i * angle)."""
    x = np.asarray(x, np.float64)
    c = x[..., 0::2] + 1j * x[..., 1::2]
    c = c * np.exp(1j * np.asarray(angles, np.float64))[:, None, :]
    out = np.empty_like(x)
    out[..., 0::2], out[..., 1::2] = c.real, c.imag
    return out


def test_split_matches_wan_for_head_dim_128():
    assert WorldModelConfig.solaris().dit.rope_split == (22, 21, 21)
    assert DiTConfig(dim=64, num_heads=2).rope_split == SPLIT  # d=32: d - 4*(d//6) = 12 real dims for frames


def test_angles_follow_per_axis_tables():
    frames = 3
    ang = np.asarray(rope_3d_angles(SPLIT, THETA, frames, GRID_H, GRID_W, num_players=2, start_frame=1))
    assert ang.shape == (frames * 2 * GRID_H * GRID_W, sum(SPLIT))
    pf, ph, pw = SPLIT
    row = 0
    for f in range(frames):
        for _player in range(2):
            for h in range(GRID_H):
                for w in range(GRID_W):
                    want = np.concatenate([(1 + f) * THETA ** (-2 * np.arange(pf) / (2 * pf)),
                                           h * THETA ** (-2 * np.arange(ph) / (2 * ph)),
                                           w * THETA ** (-2 * np.arange(pw) / (2 * pw))])
                    np.testing.assert_allclose(ang[row], want, rtol=1e-6, atol=1e-6)
                    row += 1


def test_apply_rope_is_complex_multiplication_of_interleaved_pairs():
    angles = rope_3d_angles(SPLIT, THETA, 2, GRID_H, GRID_W, 1, start_frame=3)
    x = _rand((2, angles.shape[0], HEADS, HEAD_DIM))
    np.testing.assert_allclose(apply_rope(x, angles), _complex_reference(x, angles), atol=1e-5)


def test_apply_rope_keeps_dtype_and_rejects_bad_angles():
    angles = rope_3d_angles(SPLIT, THETA, 1, GRID_H, GRID_W, 1)
    x = _rand((1, angles.shape[0], HEADS, HEAD_DIM)).astype(jnp.bfloat16)
    assert apply_rope(x, angles).dtype == jnp.bfloat16
    with pytest.raises(ValueError):
        apply_rope(x[:, :-1], angles)


@pytest.mark.parametrize("players", [1, 2, 3])
def test_packed_players_equal_per_player_rope(players):
    """Packed (frame, player, token) application == applying to each player's own sequence."""
    frames, tokens = 3, GRID_H * GRID_W
    x = _rand((2, frames * players * tokens, HEADS, HEAD_DIM), seed=players)
    packed = apply_rope(x, rope_3d_angles(SPLIT, THETA, frames, GRID_H, GRID_W, players, start_frame=2))
    packed = packed.reshape(2, frames, players, tokens, HEADS, HEAD_DIM)
    single = rope_3d_angles(SPLIT, THETA, frames, GRID_H, GRID_W, 1, start_frame=2)
    x5 = x.reshape(2, frames, players, tokens, HEADS, HEAD_DIM)
    for p in range(players):
        own = apply_rope(x5[:, :, p].reshape(2, frames * tokens, HEADS, HEAD_DIM), single)
        np.testing.assert_allclose(packed[:, :, p].reshape(own.shape), own, atol=1e-6)


def test_start_frame_on_one_frame_equals_that_frame_of_a_longer_pass():
    players, tokens, frames = 2, GRID_H * GRID_W, 7
    x = _rand((1, frames * players * tokens, HEADS, HEAD_DIM), seed=5)
    full = apply_rope(x, rope_3d_angles(SPLIT, THETA, frames, GRID_H, GRID_W, players))
    per_frame = players * tokens
    one = apply_rope(x[:, 5 * per_frame:6 * per_frame],
                     rope_3d_angles(SPLIT, THETA, 1, GRID_H, GRID_W, players, start_frame=5))
    np.testing.assert_allclose(one, full[:, 5 * per_frame:6 * per_frame], atol=1e-6)
    traced = jax.jit(lambda s: rope_3d_angles(SPLIT, THETA, 1, GRID_H, GRID_W, players, start_frame=s))(5)
    np.testing.assert_allclose(traced, rope_3d_angles(SPLIT, THETA, 1, GRID_H, GRID_W, players, 5), atol=1e-6)


def test_teacher_forcing_halves_count_from_zero():
    players, frames = 2, 3
    pos = teacher_forcing_frame_positions(frames)
    np.testing.assert_array_equal(pos, [0, 1, 2, 0, 1, 2])
    ang = rope_3d_angles_at(SPLIT, THETA, pos, GRID_H, GRID_W, players)
    half = ang.shape[0] // 2
    np.testing.assert_allclose(ang[:half], ang[half:])  # clean j and noisy j share position j
    np.testing.assert_allclose(ang[half:], rope_3d_angles(SPLIT, THETA, frames, GRID_H, GRID_W, players))
    naive = rope_3d_angles(SPLIT, THETA, 2 * frames, GRID_H, GRID_W, players)  # RoPE over the concatenation
    assert not np.allclose(naive[half:], ang[half:])


def test_scores_depend_only_on_relative_frame_offset():
    q, k = _rand((1, 1, 1, HEAD_DIM), 1), _rand((1, 1, 1, HEAD_DIM), 2)

    def score(fq, fk):
        aq = rope_3d_angles(SPLIT, THETA, 1, 1, 1, 1, start_frame=fq)
        ak = rope_3d_angles(SPLIT, THETA, 1, 1, 1, 1, start_frame=fk)
        return float(jnp.sum(apply_rope(q, aq) * apply_rope(k, ak)))

    assert score(3, 1) == pytest.approx(score(10, 8), abs=1e-4)
    assert score(3, 1) != pytest.approx(score(3, 2), abs=1e-4)


def test_temporal_rope_rotates_only_the_first_dims():
    rope_dims, theta = (8, 28, 28), 256.0
    ang = np.asarray(temporal_rope_angles(rope_dims, theta, 4, start_frame=2))
    assert ang.shape == (4, 32)
    np.testing.assert_allclose(ang[:, :4], np.arange(2, 6)[:, None] * theta ** (-np.arange(0, 8, 2) / 8)[None],
                               rtol=1e-6)
    assert not ang[:, 4:].any()
    x = _rand((3, 4, 2, 64))
    y = apply_rope(x, jnp.asarray(ang))
    np.testing.assert_array_equal(y[..., 8:], x[..., 8:])
    # rotate_half pairing: out[2k] = x[2k] cos - x[2k+1] sin, out[2k+1] = x[2k+1] cos + x[2k] sin
    cos, sin = np.cos(ang[:, 0])[None, :, None], np.sin(ang[:, 0])[None, :, None]
    np.testing.assert_allclose(y[..., 0], x[..., 0] * cos - x[..., 1] * sin, atol=1e-5)
    np.testing.assert_allclose(y[..., 1], x[..., 1] * cos + x[..., 0] * sin, atol=1e-5)


def test_temporal_rope_start_frame_matches_longer_pass():
    full = temporal_rope_angles((8, 12, 12), 256.0, 6)
    np.testing.assert_allclose(temporal_rope_angles((8, 12, 12), 256.0, 1, start_frame=4), full[4:5])
