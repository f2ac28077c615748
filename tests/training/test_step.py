"""``training.objectives`` and ``training.step``: flow-matching objectives and jitted train steps on the
``test`` preset (B=2, 5 frames -> F=2)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from solaris_env.world_model.action_module import padded_action_length
from solaris_env.world_model.config import preset
from solaris_env.world_model.world_model import WorldModel
from training.objectives import NUM_TRAIN_TIMESTEPS, sample_timesteps
from training.samplers import make_batch
from training.step import (NonFiniteError, TrainState, check_finite, ema_decay_at, ema_update, make_loss_fn,
                           make_optimizer, make_test_loss, make_train_step, prepare_batch)

B, T = 2, 5
LR = 3e-3
VARIANTS = {  # stage -> (DiT entry point, noise type)
    "bidirectional": ("forward_bidirectional", "standard"),
    "causal": ("forward_causal", "diffusion_forcing"),
}


@pytest.fixture(scope="module")
def cfg():
    return preset("test")


@pytest.fixture(scope="module")
def modules(cfg):
    """(dit, vae, image_encoder), initialised by one compiled program (much faster than eager init)."""
    return WorldModel.from_preset("test", seed=0).modules()


@pytest.fixture(scope="module")
def batch(cfg, modules):
    rng = np.random.default_rng(0)
    samples = []
    for _ in range(B):
        obs = rng.integers(0, 256, (T, cfg.num_players, cfg.frame_height, cfg.frame_width, 3), dtype=np.uint8)
        act = np.concatenate([rng.integers(0, 2, (T, cfg.num_players, 23)).astype(np.float32),
                              rng.normal(size=(T, cfg.num_players, 2)).astype(np.float32)], axis=-1)
        samples.append((obs, act))
    raw = make_batch(samples)
    _, vae, encoder = modules
    # eager: compiling the VAE encoder costs more than running it once at this size
    return prepare_batch(vae, encoder, jnp.asarray(raw["obs"]), jnp.asarray(raw["act"]), cfg)


def _fresh(modules, seed=0):
    """A new TrainState (own parameter copies, so donation is safe) whose step RNG is ``seed``."""
    tx = make_optimizer(LR)
    graphdef, state = TrainState.create(modules[0], tx, rng=seed)
    return graphdef, state, tx


@pytest.fixture(scope="module")
def steps(modules):
    """One jitted step per variant, compiled once and shared by the tests below."""
    out = {}
    for name, (entry, noise_type) in VARIANTS.items():
        graphdef, _, tx = _fresh(modules)
        out[name] = (graphdef, make_train_step(graphdef, entry, noise_type, tx))
    return out


def _run(modules, train_step, batch, num_steps, seed=0):
    _, state, _ = _fresh(modules, seed)
    losses = []
    for _ in range(num_steps):
        step = int(state.step)
        state, metrics = train_step(state, batch)
        losses.append(check_finite(metrics, step)["loss"])
    return state, losses


def _expected_loss(graphdef, entry, noise_type, batch, num_draws=16):
    """Jitted ``(params, rest) -> loss`` averaged over fixed (t, noise) draws of the training distribution:
    a low-variance estimate to compare before / after training."""
    loss_fn = make_loss_fn(graphdef, entry)
    x0 = batch["x0"]
    keys = jax.random.split(jax.random.PRNGKey(123), num_draws)

    def expected(params, rest):
        def one(key):
            k_t, k_noise = jax.random.split(key)
            t = sample_timesteps(k_t, x0.shape[:3], noise_type)
            return loss_fn(params, rest, batch, t, jax.random.normal(k_noise, x0.shape))
        return jnp.mean(jax.lax.map(one, keys))

    return jax.jit(expected)


# ---------------------------------------------------------------------------------------------


def test_prepare_batch_shapes(cfg, batch):
    p, f, h, w = cfg.num_players, 2, cfg.latent_height, cfg.latent_width
    t_pad = padded_action_length(cfg, f)
    assert batch["x0"].shape == (B, p, f, h, w, cfg.latent_channels)
    assert batch["cond"].shape == (B, p, f, h, w, cfg.in_channels - cfg.out_channels)
    assert batch["context"].shape == (B, p, cfg.image_encoder.num_tokens, cfg.context_width)
    assert batch["mouse"].shape == (B, p, t_pad, 2) and batch["keyboard"].shape == (B, p, t_pad, 23)
    # left padding repeats action 0, and the last entry is the last real action
    np.testing.assert_array_equal(batch["keyboard"][:, :, 0], batch["keyboard"][:, :, cfg.action_left_padding])
    assert all(np.isfinite(np.asarray(v)).all() for v in batch.values())


def test_timesteps_standard_shared_and_diffusion_forcing_independent():
    key = jax.random.PRNGKey(0)
    t_std = np.asarray(sample_timesteps(key, (8, 2, 4), "standard"))
    t_df = np.asarray(sample_timesteps(key, (8, 2, 4), "diffusion_forcing"))
    for t in (t_std, t_df):
        assert t.shape == (8, 2, 4) and t.dtype == np.int32
        assert t.min() >= 0 and t.max() <= NUM_TRAIN_TIMESTEPS
    assert (t_std == t_std[:, :1, :1]).all()  # one t per sample
    assert len(np.unique(t_std[:, 0, 0])) > 1  # ... that differs between samples
    assert (t_df[:, 0] != t_df[:, 1]).any()  # differs across players
    assert (t_df[:, :, 1:] != t_df[:, :, :1]).any()  # and across frames
    with pytest.raises(ValueError, match="noise_type"):
        sample_timesteps(key, (2, 2, 2), "teacher_forcing")


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_loss_finite_at_init_and_overfits(modules, batch, steps, variant):
    graphdef, train_step = steps[variant]
    entry, noise_type = VARIANTS[variant]
    expected_loss = _expected_loss(graphdef, entry, noise_type, batch)
    _, init_state, _ = _fresh(modules)
    loss0 = float(expected_loss(init_state.params, init_state.rest))
    assert np.isfinite(loss0)

    state, losses = _run(modules, train_step, batch, 20)
    loss20 = float(expected_loss(state.params, state.rest))
    assert int(state.step) == 20
    assert np.isfinite(losses).all()
    # measured on this batch: ~1.10 -> ~1.00 after 20 steps (~0.2 after 200)
    assert loss20 < 0.95 * loss0, (variant, loss0, loss20, losses)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_remat_gives_the_same_loss_and_gradient(modules, batch, variant):
    """``remat`` recomputes each layer in the backward pass instead of storing it: the same function and the same
    gradient (to float rounding), for both entry points."""
    graphdef, state, _ = _fresh(modules)
    entry, noise_type = VARIANTS[variant]
    x0 = batch["x0"]
    k_t, k_noise = jax.random.split(jax.random.PRNGKey(5))
    t = sample_timesteps(k_t, x0.shape[:3], noise_type)
    noise = jax.random.normal(k_noise, x0.shape)
    out = {}
    for remat in (False, True):
        grad_fn = jax.jit(jax.value_and_grad(make_loss_fn(graphdef, entry, remat=remat)))
        out[remat] = grad_fn(state.params, state.rest, batch, t, noise)
    assert float(out[True][0]) == pytest.approx(float(out[False][0]), rel=1e-6)
    grads = [jax.tree.leaves(out[r][1]) for r in (False, True)]
    assert len(grads[0]) == len(grads[1]) > 0
    for a, b in zip(*grads):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-4, atol=1e-6)
    assert max(float(jnp.abs(g).max()) for g in grads[1]) > 0  # the gradient is not trivially zero


def test_same_seed_same_losses(modules, batch, steps):
    _, train_step = steps["causal"]
    _, losses_a = _run(modules, train_step, batch, 3, seed=7)
    _, losses_b = _run(modules, train_step, batch, 3, seed=7)
    _, losses_c = _run(modules, train_step, batch, 3, seed=8)
    assert losses_a == losses_b
    assert losses_a != losses_c


def test_nan_raises_naming_the_step(modules, batch, steps):
    _, train_step = steps["bidirectional"]
    state, _ = _run(modules, train_step, batch, 2)
    poisoned = dict(batch, x0=batch["x0"].at[0, 0, 0, 0, 0, 0].set(jnp.nan))
    step = int(state.step)
    state, metrics = train_step(state, poisoned)
    with pytest.raises(NonFiniteError, match="step 2"):
        check_finite(metrics, step)


# ---------------------------------------------------------------------------------------------
# The parameter EMA (the tiny preset's short runs)
# ---------------------------------------------------------------------------------------------


def test_ema_decay_warms_up_and_update_is_the_average():
    assert [float(ema_decay_at(0.999, s)) for s in (0, 10, 10**5)] == pytest.approx([0.1, 11 / 20, 0.999])
    ema, params = {"a": jnp.array([1.0, 3.0])}, {"a": jnp.array([3.0, -1.0])}
    np.testing.assert_allclose(ema_update(ema, params, 0.75)["a"], [1.5, 2.0])
    with pytest.raises(ValueError, match="ema_decay"):
        make_train_step(None, "forward_causal", "diffusion_forcing", make_optimizer(LR), ema_decay=1.0)


def test_train_step_keeps_the_parameter_ema(modules, batch):
    """A state created with ``ema=True`` starts its average at the parameters and moves it by
    ``ema_decay_at`` after every update; ``final_params`` is the average; the trained parameters are
    those of a state without one."""
    tx = make_optimizer(LR)
    graphdef, state = TrainState.create(modules[0], tx, rng=0, ema=True)
    _, plain = TrainState.create(modules[0], tx, rng=0)
    assert plain.ema is None and plain.final_params is plain.params
    step = make_train_step(graphdef, "forward_causal", "diffusion_forcing", tx, ema_decay=0.9)
    expected = jax.tree.map(np.asarray, state.params)
    for n in range(3):
        state, _ = step(state, batch)
        plain, _ = step(plain, batch)
        decay = float(ema_decay_at(0.9, n))
        expected = jax.tree.map(lambda e, p: e + (1 - decay) * (np.asarray(p) - e), expected, state.params)
    for got, want, trained, ref in zip(jax.tree.leaves(state.final_params), jax.tree.leaves(expected),
                                       jax.tree.leaves(state.params), jax.tree.leaves(plain.params)):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(trained, ref)
    assert any(not np.allclose(a, b) for a, b in zip(jax.tree.leaves(state.ema), jax.tree.leaves(state.params)))


def test_a_step_compiled_ahead_is_not_compiled_again_by_the_loop():
    """``train.compile_ahead`` compiles for ``run_loop``'s placement (``shard_train_state``, ``shard_batch``), so
    the first step runs the kept executable; with another batch shape it would compile again."""
    from jax import monitoring

    from training.distributed import make_mesh, shard_batch, shard_train_state
    from training.train import compile_ahead

    step = jax.jit(lambda st, b: ({"w": st["w"] * 0.5 + b["x"].mean(0)}, {"loss": b["x"].sum()}), donate_argnums=(0,))
    state = {"w": jnp.ones((8, 16), jnp.float32)}
    shapes = {"x": jax.ShapeDtypeStruct((4, 8, 16), np.float32)}
    compile_ahead(step, state, shapes, fsdp=False).join()
    compiles = []
    listener = lambda name, secs, **kw: compiles.append(name) if name.endswith("backend_compile_duration") else None
    monitoring.register_event_duration_secs_listener(listener)
    try:
        mesh = make_mesh()
        state, metrics = step(shard_train_state(state, mesh), shard_batch({"x": np.ones((4, 8, 16), np.float32)}, mesh))
        assert float(metrics["loss"]) == 4 * 8 * 16 and compiles == []
        step(state, shard_batch({"x": np.ones((2, 8, 16), np.float32)}, mesh))  # another shape: compiled now
        assert len(compiles) == 1
    finally:
        monitoring.unregister_event_duration_listener(listener)


def test_test_loss_is_the_train_objective_on_fixed_draws(modules, batch):
    """make_test_loss: the mean over its batches of the train step's loss, batch i with timesteps and noise from
    fold_in(PRNGKey(seed), i), the same at every call; other parameters give another value."""
    entry, noise_type = VARIANTS["causal"]
    graphdef, state, _ = _fresh(modules)
    other = jax.tree.map(lambda a: a + 0.01, state.params)  # (a fresh head is zero: scaling would not move it)
    batches = [batch, jax.tree.map(lambda a: a[::-1], batch)]  # two different batches (the rows swapped)
    test_loss = make_test_loss(graphdef, entry, noise_type, batches, seed=3)
    loss_fn = make_loss_fn(graphdef, entry)
    expected = []
    for i, b in enumerate(batches):
        k_t, k_noise = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(3), i))
        t = sample_timesteps(k_t, b["x0"].shape[:3], noise_type)
        expected.append(float(loss_fn(state.params, state.rest, b, t, jax.random.normal(k_noise, b["x0"].shape))))
    first = float(test_loss(state.params, state.rest))
    assert first == pytest.approx(np.mean(expected), rel=1e-5)
    assert float(test_loss(state.params, state.rest)) == first  # fixed draws
    assert float(test_loss(other, state.rest)) != pytest.approx(first, rel=1e-6)
    with pytest.raises(ValueError, match="at least one batch"):
        make_test_loss(graphdef, entry, noise_type, [])
    with pytest.raises(ValueError, match="noise_type"):
        make_test_loss(graphdef, entry, "uniform", batches)


def test_drop_partner_fills_the_marked_cells_of_the_chosen_frames():
    """``drop_partner`` (the partner map's training dropout): the marked cells grown by one, in the chosen frames
    only, take the mean of the frame's other cells; share 0 keeps the latents."""
    from training.step import drop_partner

    x0 = jax.random.normal(jax.random.key(0), (2, 2, 3, 6, 6, 4))
    cond = jnp.zeros((2, 2, 3, 6, 6, 5)).at[:, :, :, 2, 3, 4].set(0.5)  # channel 4: the map, one cell marked
    np.testing.assert_array_equal(drop_partner(x0, cond, 4, jax.random.key(1), 0.0), x0)
    out = np.asarray(drop_partner(x0, cond, 4, jax.random.key(1), 1.0))
    region = np.zeros((6, 6), bool)
    region[1:4, 2:5] = True
    np.testing.assert_array_equal(out[..., ~region, :], np.asarray(x0)[..., ~region, :])
    fill = np.asarray(x0)[..., ~region, :].mean(axis=-2)  # (B, P, F, C)
    np.testing.assert_allclose(out[..., region, :], np.broadcast_to(fill[..., None, :], out[..., region, :].shape),
                               atol=1e-5)
    half = np.asarray(drop_partner(x0, cond, 4, jax.random.key(3), 0.5))
    changed = np.abs(half - np.asarray(x0)).sum(axis=(-3, -2, -1)) > 0  # (B, P, F)
    assert 0 < changed.sum() < changed.size


def test_partner_weight_is_a_weighted_mean_over_the_marked_cells():
    """``flow_matching_loss`` with a cell weight: a uniform weight gives the plain loss; a weight w on the
    ``partner_cells`` (the map's marked cells grown by one) and 1 elsewhere gives (w * their error + the rest's)
    / (w * their count + the rest's); a weight of the wrong shape is refused."""
    from training.objectives import flow_matching_loss
    from training.step import partner_cells

    x0 = jax.random.normal(jax.random.key(0), (1, 2, 3, 6, 6, 4))
    noise = jax.random.normal(jax.random.key(1), x0.shape)
    cond = jnp.zeros((1, 2, 3, 6, 6, 5)).at[:, :, :, 2, 3, 4].set(0.5)
    t = jnp.full((1, 2, 3), 500, jnp.int32)
    forward = lambda x, *_: jnp.zeros_like(x)  # predicts v = 0: the error is (noise - x0)^2
    err = np.asarray(jnp.mean(jnp.square(noise - x0), axis=-1))  # (B, P, F, h, w)
    plain = float(flow_matching_loss(forward, x0, cond, None, None, None, t, noise))
    assert plain == pytest.approx(err.mean(), rel=1e-5)
    ones = jnp.ones(x0.shape[:-1])
    assert float(flow_matching_loss(forward, x0, cond, None, None, None, t, noise, 3 * ones)) == \
        pytest.approx(plain, rel=1e-5)
    cells = np.asarray(partner_cells(cond, 4))
    region = np.zeros((6, 6), bool)
    region[1:4, 2:5] = True
    assert (cells == region).all()
    weight = jnp.where(cells, 5.0, 1.0)
    expected = (5 * err[..., region].sum() + err[..., ~region].sum()) / (5 * cells.sum() + (~cells).sum())
    assert float(flow_matching_loss(forward, x0, cond, None, None, None, t, noise, weight)) == \
        pytest.approx(expected, rel=1e-5)
    with pytest.raises(ValueError, match="weight"):
        flow_matching_loss(forward, x0, cond, None, None, None, t, noise, ones[..., 0])
