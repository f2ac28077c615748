"""The temporal refiner (``world_model/refiner.py``, ``VAEConfig.refiner``): the blend, the gate, its config
and its place in the streaming world model."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model.config import RefinerConfig, preset
from solaris_env.world_model.refiner import Refiner, blend, cell_mean
from solaris_env.world_model.world_model import WorldModel, frames_to_model

A = 25  # the model's action vector


def _refiner(action_dim=A, seed=0):
    return Refiner(RefinerConfig(width=8, pool=4, action_dim=action_dim), rngs=nnx.Rngs(seed))


def _clip(seed, n=2, t=6, hw=16):
    rng = np.random.default_rng(seed)
    return jnp.asarray(rng.uniform(-1, 1, (n, t, hw, hw, 3)), jnp.float32)


def test_blend_keeps_the_previous_frame_at_gate_one_and_the_decode_at_zero():
    decoded, prev = _clip(0), _clip(1)[:, 0]
    ones, zeros = jnp.ones(decoded.shape[:-1] + (1,)), jnp.zeros(decoded.shape[:-1] + (1,))
    np.testing.assert_array_equal(blend(ones, decoded, prev), jnp.broadcast_to(prev[:, None], decoded.shape))
    np.testing.assert_array_equal(blend(zeros, decoded, prev), decoded)


def test_blend_is_the_recursion_frame_by_frame():
    decoded, prev = _clip(0, t=4), _clip(1)[:, 0]
    g = jax.random.uniform(jax.random.key(0), decoded.shape[:-1] + (1,))
    y, expected = prev, []
    for t in range(4):
        y = g[:, t] * y + (1 - g[:, t]) * decoded[:, t]
        expected.append(y)
    np.testing.assert_allclose(blend(g, decoded, prev), jnp.stack(expected, 1), atol=1e-6)


def test_cell_mean_averages_each_cell_and_rejects_a_ragged_frame():
    x = jnp.arange(2 * 8 * 8 * 1, dtype=jnp.float32).reshape(2, 8, 8, 1)
    m = cell_mean(x, 4)
    assert m.shape == (2, 2, 2, 1)
    np.testing.assert_allclose(m[1, 0, 1, 0], x[1, :4, 4:, 0].mean())
    with pytest.raises(ValueError, match="pool=3"):
        cell_mean(x, 3)


def test_gates_lie_in_the_unit_interval_and_are_constant_on_each_cell():
    refiner = _refiner()
    decoded = _clip(0)
    g = refiner.gates(decoded[:, 1:], decoded[:, 0], jnp.zeros((2, 5, A)))
    assert g.shape == (2, 5, 16, 16, 1)
    assert float(g.min()) > 0.0 and float(g.max()) < 1.0
    cells = g.reshape(2, 5, 4, 4, 4, 4)  # (.., cell row, row in cell, cell col, col in cell)
    np.testing.assert_array_equal(cells, jnp.broadcast_to(cells[:, :, :, :1, :, :1], cells.shape))


def test_gates_read_the_actions_only_when_configured():
    decoded = _clip(0)
    noop, act = jnp.zeros((2, 5, A)), jnp.ones((2, 5, A))
    with_actions, without = _refiner(A), _refiner(0)
    gates = lambda r, a: r.gates(decoded[:, 1:], decoded[:, 0], a)
    assert float(jnp.abs(gates(with_actions, noop) - gates(with_actions, act)).max()) > 1e-4
    np.testing.assert_array_equal(gates(without, noop), gates(without, act))


def test_frame_shifts_follow_the_camera_convention():
    """+ cameraX (turn left) moves the content right, + cameraY (look up) moves it down, in pixels per degree."""
    from solaris_env.spaces import CAMERA_SCALE_DEG, CAMERA_X_INDEX, CAMERA_Y_INDEX
    from solaris_env.world_model.refiner import frame_shifts

    a = np.zeros((1, 2, A), np.float32)
    a[0, 0, CAMERA_X_INDEX] = 0.5
    a[0, 1, CAMERA_Y_INDEX] = -1.0
    s = np.asarray(frame_shifts(jnp.asarray(a), (0.8, 0.45)))
    np.testing.assert_allclose(s[0, 0], [0.0, 0.5 * CAMERA_SCALE_DEG * 0.45], rtol=1e-6)
    np.testing.assert_allclose(s[0, 1], [-CAMERA_SCALE_DEG * 0.8, 0.0], rtol=1e-6)


def test_blend_moves_the_kept_frame_with_the_turn():
    prev = _clip(1)[:, 0]
    decoded = _clip(0, t=2)
    ones = jnp.ones(decoded.shape[:-1] + (1,))
    shifts = jnp.asarray(np.tile([[0.0, 2.0], [1.0, 0.0]], (2, 1, 1)), jnp.float32)  # 2 px right, then 1 down
    y = np.asarray(blend(ones, decoded, prev, shifts))
    np.testing.assert_array_equal(y[:, 0, :, 2:], np.asarray(prev)[:, :, :-2])  # integer shifts are exact
    np.testing.assert_array_equal(y[:, 1, 1:, 2:], np.asarray(prev)[:, :-1, :-2])


@pytest.mark.parametrize("camera_shift", [(0.0, 0.0), (0.8, 0.45)])
def test_refiner_in_chunks_equals_one_call_on_the_clip(camera_shift):
    refiner = Refiner(RefinerConfig(width=8, pool=4, action_dim=A, camera_shift=camera_shift), rngs=nnx.Rngs(0))
    decoded, first = _clip(0, t=9), _clip(1)[:, 0]
    actions = jax.random.normal(jax.random.key(2), (2, 9, A))
    whole = refiner(decoded[:, 1:], decoded[:, 0], first, actions[:, 1:])
    prev_frame, prev_decoded, chunks = first, decoded[:, 0], []
    for start in (1, 5):  # two steps of k = 4 frames
        y = refiner(decoded[:, start:start + 4], prev_decoded, prev_frame, actions[:, start:start + 4])
        chunks.append(y)
        prev_frame, prev_decoded = y[:, -1], decoded[:, start + 3]
    np.testing.assert_allclose(jnp.concatenate(chunks, 1), whole, atol=1e-6)


def test_refiner_config_errors_name_the_field():
    with pytest.raises(ValueError, match="refiner.width"):
        RefinerConfig(width=-1)
    with pytest.raises(ValueError, match="refiner.pool"):
        RefinerConfig(width=4, pool=0)
    with pytest.raises(ValueError, match="refiner.camera_shift"):
        RefinerConfig(width=4, camera_shift=(float("nan"), 0.0))
    cfg = preset("test")
    with pytest.raises(ValueError, match="refiner.action_dim must be 0 or the action size 25"):
        cfg.replace(vae=dataclasses.replace(cfg.vae, refiner=RefinerConfig(width=4, action_dim=7)))
    with pytest.raises(ValueError, match="divisible by vae.refiner.pool=5"):
        cfg.replace(vae=dataclasses.replace(cfg.vae, refiner=RefinerConfig(width=4, pool=5)))


@pytest.fixture(scope="module")
def models():
    """The test preset without and with a refiner, every other parameter shared."""
    from training.refine import with_refiner

    plain = WorldModel.from_preset("test", seed=0)
    refined = with_refiner(plain, RefinerConfig(width=8, pool=4, action_dim=A, camera_shift=(0.8, 0.45)), seed=3)
    return plain, refined


def test_world_model_refines_its_decodes_starting_from_the_first_frame(models):
    """The streaming model with a refiner returns the first frames as frame 0 and then exactly the refiner
    applied offline to the frames the same model without one decodes (up to their uint8 rounding)."""
    plain, refined = models
    rng = np.random.default_rng(0)
    first = rng.integers(0, 256, (2, 2, 32, 32, 3), dtype=np.uint8)
    actions = (rng.random((3, 2, 2, 4, A)) < 0.3).astype(np.float32)  # 3 steps of (B, P, k, 25)
    actions[..., 23:] = rng.uniform(-1, 1, actions.shape[:-1] + (2,))  # and camera turns
    runs = []
    for model in (plain, refined):
        state = model.init(first, 7)
        frames = [np.asarray(state.frame0_BPHW3)[:, :, None]]
        for a in actions:
            f, state = model.step(state, a)
            frames.append(np.asarray(f))
        runs.append(np.concatenate(frames, axis=2))  # (B, P, 13, H, W, 3)
    decoded, out = runs
    np.testing.assert_array_equal(out[:, :, 0], first)
    refiner = refined.modules()[1].refiner
    flat = lambda x: x.reshape((4,) + x.shape[2:])
    act = flat(np.concatenate([np.zeros((2, 2, 1, A), np.float32), np.moveaxis(actions, 0, 2).reshape(2, 2, 12, A)], 2))
    d = frames_to_model(jnp.asarray(flat(decoded)))
    offline = refiner(d[:, 1:], d[:, 0], frames_to_model(jnp.asarray(flat(first))), jnp.asarray(act[:, 1:]))
    offline = np.clip(np.round((np.asarray(offline) + 1) * 127.5), 0, 255)
    assert np.abs(offline - flat(out)[:, 1:].astype(np.float64)).max() <= 2  # uint8 rounding of the decodes
    assert np.abs(out.astype(int) - decoded.astype(int)).max() > 10  # and the refiner did change the frames


def test_with_refiner_keeps_every_other_parameter_and_round_trips(models, tmp_path):
    from training.refine import with_refiner

    plain, refined = models
    flat = lambda m: {"/".join(map(str, p)): np.asarray(v) for c in m.params for p, v in nnx.to_flat_state(c)}
    a, b = flat(plain), flat(refined)
    assert set(b) - set(a) and all(k.startswith("refiner/") for k in set(b) - set(a))
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    refined.save(tmp_path / "m")
    loaded = WorldModel.load(tmp_path / "m")
    assert loaded.config.vae.refiner == RefinerConfig(width=8, pool=4, action_dim=A, camera_shift=(0.8, 0.45))
    c = flat(loaded)
    for k in b:
        np.testing.assert_array_equal(b[k], c[k], err_msg=k)
    stripped = with_refiner(loaded, None)
    assert not stripped.config.vae.refiner.enabled and set(flat(stripped)) == set(a)
    kept = with_refiner(loaded, loaded.config.vae.refiner)  # same config: the trained gate is kept
    d = flat(kept)
    for k in b:
        np.testing.assert_array_equal(b[k], d[k], err_msg=k)


def test_reset_worlds_restarts_the_refiner_from_the_new_first_frames(models):
    _, refined = models
    rng = np.random.default_rng(1)
    first, new = (rng.integers(0, 256, (2, 2, 32, 32, 3), dtype=np.uint8) for _ in range(2))
    state = refined.init(first, 5)
    _, state = refined.step(state, np.zeros((2, 2, 4, A), np.float32))
    kept = np.asarray(state.frame_BPHW3[0])
    state = refined.reset_worlds(state, np.array([False, True]), new, rng=9)
    fresh = refined.init(new, 9)
    np.testing.assert_array_equal(np.asarray(state.frame_BPHW3[0]), kept)  # the untouched world
    np.testing.assert_array_equal(np.asarray(state.frame0_BPHW3[1]), new[1])
    np.testing.assert_allclose(np.asarray(state.frame_BPHW3[1]), np.asarray(fresh.frame_BPHW3[1]), atol=1e-6)
    np.testing.assert_allclose(np.asarray(state.decoded_BPHW3[1]), np.asarray(fresh.decoded_BPHW3[1]), atol=1e-4)
