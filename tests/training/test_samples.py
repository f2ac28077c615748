"""training/samples.py: the free and the teacher-forced rollout, and the latents the DiT is trained on."""

import jax.numpy as jnp
import numpy as np
import pytest

from solaris_env.world_model.world_model import WorldModel
from training.samples import ground_truth_latents, rollout, write_stage_sample
from training.step import prepare_batch

K, STEPS = 4, 3


@pytest.fixture(scope="module")
def model():
    """The test preset with every DiT parameter perturbed: at initialisation the DiT's output head is zero,
    so its frames would not depend on the context at all."""
    import jax
    from flax import nnx

    base = WorldModel.from_preset("test", seed=0)
    dit, vae, encoder = base.modules()
    params = nnx.state(dit, nnx.Param)
    keys = iter(jax.random.split(jax.random.key(1), len(jax.tree.leaves(params))))
    nnx.update(dit, jax.tree.map(lambda x: x + 0.05 * jax.random.normal(next(keys), x.shape, x.dtype), params))
    return WorldModel(base.config, dit, vae, encoder)


@pytest.fixture(scope="module")
def segments(model):
    """Two segments with the same frames 0..K (so the same latent frames 0 and 1), different frames after,
    and the same actions."""
    cfg = model.config
    rng = np.random.default_rng(0)
    shape = (1 + K * STEPS, cfg.num_players, cfg.frame_height, cfg.frame_width, 3)
    a = rng.integers(0, 256, shape, dtype=np.uint8)
    b = a.copy()
    b[K + 1:] = rng.integers(0, 256, b[K + 1:].shape, dtype=np.uint8)
    act = np.concatenate([rng.integers(0, 2, shape[:2] + (23,)), rng.normal(size=shape[:2] + (2,))], -1)
    return np.stack([a, b]), np.stack([act, act]).astype(np.float32)


def test_ground_truth_latents_are_the_training_targets(model, segments):
    obs, act = segments
    _, vae, encoder = model.modules()
    x0 = prepare_batch(vae, encoder, jnp.asarray(obs), jnp.asarray(act), model.config)["x0"]
    lat = ground_truth_latents(model, obs, batch=3)  # batches that split the 4 clips unevenly
    assert lat.shape == x0.shape == (2, model.config.num_players, 1 + STEPS) + lat.shape[3:]
    np.testing.assert_allclose(lat, np.asarray(x0), rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(lat[0, :, :2], lat[1, :, :2])  # causal VAE: frames 0..K give latents 0, 1
    assert not np.allclose(lat[0, :, 2], lat[1, :, 2])


def test_teacher_forced_steps_see_the_true_past_and_only_the_past(model, segments):
    """A free rollout sees frame 0 and the actions only: both segments give the same video. Teacher-forced,
    step i is predicted from the true latents 0..i-1: steps 1-2 (true latents 0, 1 shared) stay equal, step
    3 (true latent 2 differs) does not; step 1 is the free rollout's. (One world per call: every world of a
    batch draws its own noise.)"""
    obs, act = segments
    free = [rollout(model, obs[i:i + 1], act[i:i + 1], seed=0)[0] for i in range(2)]
    forced = [rollout(model, obs[i:i + 1], act[i:i + 1], seed=0, teacher_forced=True)[0] for i in range(2)]
    assert forced[0].shape == free[0].shape == obs.shape[1:] and forced[0].dtype == np.uint8
    np.testing.assert_array_equal(free[0], free[1])
    np.testing.assert_array_equal(forced[0][:1 + K], free[0][:1 + K])
    np.testing.assert_array_equal(forced[0][:1 + 2 * K], forced[1][:1 + 2 * K])
    assert not np.array_equal(forced[0][1 + 2 * K:], forced[1][1 + 2 * K:])
    assert not np.array_equal(forced[0][1 + K:], free[0][1 + K:])


def test_stage_sample_without_held_out_episodes_is_skipped(model, tmp_path, caplog):
    """A dataset without (long enough) held-out episodes skips the sample with a warning: the stage that
    asked for it still saves its model."""
    (tmp_path / "data" / "duet" / "test").mkdir(parents=True)
    (tmp_path / "data" / "duet" / "train").mkdir(parents=True)
    dit, vae, encoder = model.modules()
    with caplog.at_level("WARNING"):
        out = write_stage_sample(tmp_path / "s" / "step_1", model.config, dit, vae, encoder, tmp_path / "data",
                                 "forward_causal")
    assert out is None and not (tmp_path / "s").exists()
    assert "skipped" in caplog.text
