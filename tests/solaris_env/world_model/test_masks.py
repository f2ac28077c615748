"""Masks checked exhaustively against brute-force loops (docs/model.md §5.1, §11.1)."""

import itertools

import jax.numpy as jnp
import numpy as np
import pytest

from solaris_env.world_model.masks import (bidirectional_frame_mask, causal_window_frame_mask, expand_to_tokens,
                                           teacher_forcing_frame_mask)

FRAMES = tuple(range(1, 7))
WINDOWS = tuple(range(1, 8))


def brute_causal(num_frames, window):
    return np.array([[j <= i and j >= i - window + 1 for j in range(num_frames)] for i in range(num_frames)])


def brute_teacher_forcing(num_frames, window):
    """Rule per (query role, query frame, key role, key frame); role 0 = clean, 1 = noisy."""
    def allowed(rq, i, rk, j):
        if rq == 0 and rk == 0:
            return i - window < j <= i
        if rq == 0 and rk == 1:
            return False
        if rq == 1 and rk == 0:
            return i - window < j < i
        return i == j

    idx = [(r, f) for r in (0, 1) for f in range(num_frames)]
    return np.array([[allowed(rq, i, rk, j) for rk, j in idx] for rq, i in idx])


@pytest.mark.parametrize("num_frames,window", list(itertools.product(FRAMES, WINDOWS)))
def test_causal_window_matches_brute_force(num_frames, window):
    np.testing.assert_array_equal(causal_window_frame_mask(num_frames, window), brute_causal(num_frames, window))


@pytest.mark.parametrize("num_frames,window", list(itertools.product(FRAMES, WINDOWS)))
def test_teacher_forcing_matches_brute_force(num_frames, window):
    got = teacher_forcing_frame_mask(num_frames, window)
    assert got.shape == (2 * num_frames, 2 * num_frames) and got.dtype == bool
    np.testing.assert_array_equal(got, brute_teacher_forcing(num_frames, window))


def test_bidirectional_is_full():
    for f in FRAMES:
        assert bidirectional_frame_mask(f).all() and bidirectional_frame_mask(f).shape == (f, f)


def _token_ids(num_roles, num_frames, players, tokens):
    """(role, frame, player, token) of every position of a packed sequence, in packing order."""
    return list(itertools.product(range(num_roles), range(num_frames), range(players), range(tokens)))


@pytest.mark.parametrize("players,tokens", list(itertools.product([1, 2, 3], [1, 3])))
@pytest.mark.parametrize("num_frames,window", [(3, 6), (4, 2), (5, 1), (1, 2), (4, 4)])
def test_expanded_masks_follow_the_frame_rule_per_token(players, tokens, num_frames, window):
    block = players * tokens
    causal = expand_to_tokens(causal_window_frame_mask(num_frames, window), block)
    ids = _token_ids(1, num_frames, players, tokens)
    want = np.array([[i - window < j <= i for (_, j, _, _) in ids] for (_, i, _, _) in ids])
    np.testing.assert_array_equal(causal, want)

    tf = expand_to_tokens(teacher_forcing_frame_mask(num_frames, window), block)
    ids = _token_ids(2, num_frames, players, tokens)
    rule = brute_teacher_forcing(num_frames, window)
    want = np.array([[rule[rq * num_frames + i, rk * num_frames + j] for (rk, j, _, _) in ids]
                     for (rq, i, _, _) in ids])
    np.testing.assert_array_equal(tf, want)


def test_cross_player_attention_within_a_frame_is_allowed():
    players, tokens, num_frames = 2, 3, 4
    causal = expand_to_tokens(causal_window_frame_mask(num_frames, 2), players * tokens)
    tf = expand_to_tokens(teacher_forcing_frame_mask(num_frames, 2), players * tokens)
    half = num_frames * players * tokens
    for f in range(num_frames):
        p0 = f * players * tokens  # first token of player 0 in frame f
        p1 = p0 + tokens  # first token of player 1 in frame f
        assert causal[p0, p1] and causal[p1, p0]
        assert tf[half + p0, half + p1] and tf[half + p1, half + p0]  # noisy players see each other
        assert not tf[half + p1, p0] and not tf[half + p0, p1]  # but never same-frame clean


def test_block_size_without_players_bug():
    """The kernel's block size is tokens * players (the reference's `test_mp_teacher_forcing_mask_bug`): with
    block_size = tokens it would see F*P 'frames' per half, a mask of the right shape that lets a noisy token see a
    same-frame clean token of the other player and blocks cross-player attention."""
    num_frames, window, tokens = 4, 2, 3
    for players in (1, 2):
        right = expand_to_tokens(teacher_forcing_frame_mask(num_frames, window), players * tokens)
        wrong = expand_to_tokens(teacher_forcing_frame_mask(num_frames * players, window), tokens)
        assert right.shape == wrong.shape
        if players == 1:
            np.testing.assert_array_equal(right, wrong)
            continue
        assert (right != wrong).any()
        half = num_frames * players * tokens
        ids = _token_ids(1, num_frames, players, tokens)
        leaks = [(q, k) for q, (_, fq, _, _) in enumerate(ids) for k, (_, fk, _, _) in enumerate(ids)
                 if fq == fk and wrong[half + q, k]]
        assert leaks, "the buggy mask should let noisy tokens see same-frame clean tokens"
        assert not any(right[half + q, k] for q, k in leaks)
        p0, p1 = 0, tokens  # frame 0, player 0 and player 1, noisy half
        assert right[half + p0, half + p1] and not wrong[half + p0, half + p1]


def test_window_one_and_single_frame():
    np.testing.assert_array_equal(causal_window_frame_mask(5, 1), np.eye(5, dtype=bool))
    tf = teacher_forcing_frame_mask(5, 1)
    assert not tf[5:, :5].any()  # strictly-past window of 1 frame is empty
    np.testing.assert_array_equal(tf[5:, 5:], np.eye(5, dtype=bool))
    np.testing.assert_array_equal(causal_window_frame_mask(1, 6), [[True]])
    np.testing.assert_array_equal(teacher_forcing_frame_mask(1, 6), [[True, False], [False, True]])


def test_every_query_sees_at_least_one_key():
    for f, w in itertools.product(FRAMES, WINDOWS):
        assert causal_window_frame_mask(f, w).any(axis=1).all()
        assert teacher_forcing_frame_mask(f, w).any(axis=1).all()


def test_expand_accepts_jax_arrays():
    frame = causal_window_frame_mask(3, 2)
    np.testing.assert_array_equal(np.asarray(expand_to_tokens(jnp.asarray(frame), 4)), expand_to_tokens(frame, 4))


@pytest.mark.parametrize("call", [lambda: causal_window_frame_mask(0, 2), lambda: causal_window_frame_mask(3, 0),
                                  lambda: teacher_forcing_frame_mask(2, 0), lambda: bidirectional_frame_mask(0),
                                  lambda: expand_to_tokens(np.ones((2, 2), bool), 0),
                                  lambda: expand_to_tokens(np.ones(3, bool), 2)])
def test_invalid_sizes_raise(call):
    with pytest.raises(ValueError):
        call()
