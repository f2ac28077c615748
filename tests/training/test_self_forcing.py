"""Stage 4, Self Forcing with DMD (``training/self_forcing.py``) on the ``test`` preset.

F = 3 latent frames > window 2, batch 1, f32, random non-degenerate weights (the real initialisation
zeroes the head, which would make every velocity and most gradients exactly 0). Programs are compiled
once per module and reused: one value-and-grad program per generator mode, one generator and one
critic step.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model import dit as dit_module
from solaris_env.world_model import kv_cache, masks, sampler
from solaris_env.world_model.action_module import (
    left_pad_actions,
    padded_action_length,
    window_at,
)
from solaris_env.world_model.attention import attention
from solaris_env.world_model.config import WorldModelConfig
from solaris_env.world_model.dit import WorldDiT
from training import self_forcing as sf
from training.step import check_finite

REPO = Path(__file__).resolve().parents[2]
FRAMES = 3
LR = 1e-3  # our tiny models need larger steps than the spec's 3e-6 / 3e-7 to move visibly
FORWARD_TOL = 1e-4


def _random_dit(cfg: WorldModelConfig, seed: int) -> WorldDiT:
    """Random weights without compiling an initialiser: kernels ~ N(0, 1/fan_in), gains 1 + noise."""
    graphdef, state = nnx.split(nnx.eval_shape(lambda: WorldDiT(cfg, rngs=nnx.Rngs(0))))
    rng = np.random.default_rng(seed)
    flat = []
    for path, value in nnx.to_flat_state(state):
        name, noise = str(path[-1]), rng.normal(size=value.shape)
        if name == "kernel":
            per_layer = value.shape[1:] if path[0] == "blocks" else value.shape
            noise = noise / np.sqrt(np.prod(per_layer[:-1]))
        elif name in ("scale", "weight"):
            noise = 1.0 + 0.1 * noise
        elif name != "embedding":
            noise = 0.1 * noise  # biases, modulation tables
        flat.append((path, jnp.asarray(noise, value.dtype)))
    return nnx.merge(graphdef, nnx.from_flat_state(flat))


@pytest.fixture(scope="module", autouse=True)
def _quick_compiles():
    """XLA compilation dominates this file (the programs run in milliseconds): compile with most
    optimisations off (~40 % faster here), and restore the setting for the other test modules."""
    previous = jax.config.values["jax_disable_most_optimizations"]
    jax.config.update("jax_disable_most_optimizations", True)
    yield
    jax.config.update("jax_disable_most_optimizations", previous)


@pytest.fixture(scope="module")
def cfg():
    cfg = WorldModelConfig.test()
    assert cfg.dit.window < FRAMES  # the sliding window must actually slide
    return cfg


def make_batch(cfg: WorldModelConfig) -> dict:
    """A ``prepare_batch``-shaped dict (same keys, shapes, action padding) of random values: the frozen
    VAE / image encoder are not under test here and compiling them would dominate this file's runtime
    (``tests/training/test_step.py`` covers ``prepare_batch`` itself)."""
    b, p, t_pad = 1, cfg.stream_players, padded_action_length(cfg, FRAMES)
    ks = jax.random.split(jax.random.key(0), 5)
    latent = (b, p, FRAMES, cfg.latent_height, cfg.latent_width)
    keyboard = jax.random.bernoulli(ks[4], 0.3, (b, p, t_pad - cfg.action_left_padding, cfg.keyboard_in_dim))
    mouse = jax.random.normal(ks[3], (b, p, t_pad - cfg.action_left_padding, cfg.action.mouse_dim))
    return {
        "x0": jax.random.normal(ks[0], latent + (cfg.out_channels,)),  # GT frames: unused by Self Forcing
        "cond": jax.random.normal(ks[1], latent + (cfg.in_channels - cfg.out_channels,)),
        "context": jax.random.normal(ks[2], (b, p, cfg.image_encoder.num_tokens, cfg.context_width)),
        "mouse": left_pad_actions(mouse, cfg.action_left_padding),
        "keyboard": left_pad_actions(keyboard.astype(jnp.float32), cfg.action_left_padding),
    }


@pytest.fixture(scope="module")
def batch(cfg):
    return make_batch(cfg)


@pytest.fixture(scope="module")
def generator(cfg):
    return nnx.split(_random_dit(cfg, seed=0), nnx.Param, ...)  # (graphdef, params, rest)


@pytest.fixture(scope="module")
def x0_and_grad(generator, batch):
    """mode -> jitted (exit_index) -> (x0, d sum(w * x0) / d params) at a fixed rollout key."""
    graphdef, params, rest = generator
    key = jax.random.key(11)
    w = jax.random.normal(jax.random.key(12), batch["cond"].shape[:5] + (batch["x0"].shape[-1],))
    modes = {
        "naive": sf.naive_generator_x0,
        "checkpointed": sf.checkpointed_generator_x0,
        "checkpointed_no_kv": lambda *a: sf.checkpointed_generator_x0(*a, kv_backprop=False),
    }

    def program(x0_fn):
        def x0_and_grad(p, exit_index, batch, w):  # everything an argument: no constant folding of weights
            def objective(p_):
                x0 = x0_fn(graphdef, p_, rest, batch, key, exit_index)
                return jnp.sum(w * x0), x0

            (_, x0), grads = jax.value_and_grad(objective, has_aux=True)(p)
            return x0, grads
        compiled = jax.jit(x0_and_grad)
        return lambda exit_index: compiled(params, jnp.int32(exit_index), batch, w)

    return {name: program(fn) for name, fn in modes.items()}


def _flat(tree) -> np.ndarray:
    return np.concatenate([np.ravel(a) for a in jax.tree.leaves(tree)])


# ---------------------------------------------------------------------------------------------
# Rollout and the two generator modes
# ---------------------------------------------------------------------------------------------


def test_exit_index_is_one_scalar_in_range(cfg):
    draws = np.array([int(sf.sample_exit_index(jax.random.key(i), cfg)) for i in range(64)])
    assert set(draws) == set(range(len(cfg.sampler.ar_timesteps)))


@pytest.mark.parametrize("exit_index", [0, 1, 3])
def test_checkpointed_recompute_equals_rollout_x0(x0_and_grad, exit_index):
    """The teacher-forcing recompute of the noisy half reproduces the rollout's x̂0 (forward, f32)."""
    x0_rollout, _ = x0_and_grad["naive"](jnp.int32(exit_index))  # naive x0 IS the rollout's x̂0
    x0_recomputed, _ = x0_and_grad["checkpointed"](jnp.int32(exit_index))
    assert x0_rollout.shape == (1, 2, FRAMES) + x0_rollout.shape[3:]
    assert float(jnp.abs(x0_rollout).mean()) > 0.1
    np.testing.assert_allclose(x0_recomputed, x0_rollout, atol=FORWARD_TOL, rtol=0)


def test_rollout_with_last_exit_is_the_sampler(cfg, generator, batch, x0_and_grad):
    """s = n-1 runs every step: frame 0 (empty cache) equals ``sampler.sample_frame`` over ``WorldDiT.decode``
    with the rollout's noise keys; an earlier exit gives a different frame."""
    graphdef, params, rest = generator
    n = len(cfg.sampler.ar_timesteps)
    k_init, k_renoise = jax.random.split(jax.random.fold_in(jax.random.key(11), 0))
    z = jax.random.normal(k_init, batch["cond"].shape[:2] + (1,) + batch["x0"].shape[3:], jnp.float32)
    cache = kv_cache.init_cache(cfg, 1)
    inputs = (batch["cond"][:, :, :1], batch["context"], window_at(batch["mouse"], cfg, 0),
              window_at(batch["keyboard"], cfg, 0))
    def decode(p, x, t):
        dit = nnx.merge(graphdef, p, rest)
        return dit.decode(x, t, inputs[0], dit.context_kv(inputs[1]), *inputs[2:], cache, 0)[0]

    decode = jax.jit(decode)
    denoise = lambda x, t: decode(params, x, jnp.full(x.shape[:3], t))
    expected = sampler.sample_frame(denoise, z, k_renoise, sampler.ar_schedule(cfg.sampler))
    x0_last, _ = x0_and_grad["naive"](jnp.int32(n - 1))
    np.testing.assert_allclose(x0_last[:, :, :1], expected, atol=FORWARD_TOL, rtol=0)
    x0_first, _ = x0_and_grad["naive"](jnp.int32(0))
    assert float(jnp.abs(x0_first[:, :, :1] - expected).mean()) > 1e-2


def test_naive_and_checkpointed_gradients_agree(x0_and_grad):
    """With gradients through the recomputed clean K/V, the parallel recompute is the same function of
    the parameters as the rolling rollout (the commit passes' caches), so the gradients are equal."""
    _, g_naive = x0_and_grad["naive"](jnp.int32(2))
    _, g_ckpt = x0_and_grad["checkpointed"](jnp.int32(2))
    a, b = _flat(g_naive), _flat(g_ckpt)
    assert np.linalg.norm(a) > 1.0
    assert np.linalg.norm(a - b) / np.linalg.norm(a) < 1e-4
    np.testing.assert_allclose(b, a, atol=1e-4 * np.abs(a).max(), rtol=0)


def test_kv_backprop_off_changes_the_gradient(generator, x0_and_grad):
    """Stopping the gradient through the clean half's keys/values drops a real part of the gradient,
    and none of the parameters loses its gradient entirely (the noisy pass still uses all of them)."""
    _, g_kv = x0_and_grad["checkpointed"](jnp.int32(2))
    _, g_no_kv = x0_and_grad["checkpointed_no_kv"](jnp.int32(2))
    x0_kv, _ = x0_and_grad["checkpointed"](jnp.int32(2))
    x0_no_kv, _ = x0_and_grad["checkpointed_no_kv"](jnp.int32(2))
    np.testing.assert_array_equal(x0_kv, x0_no_kv)  # forward unchanged
    a, b = _flat(g_kv), _flat(g_no_kv)
    assert np.linalg.norm(a - b) / np.linalg.norm(a) > 0.05
    assert np.linalg.norm(b) > 0.1 * np.linalg.norm(a)


@pytest.mark.parametrize(("num_frames", "window"), [(1, 2), (3, 2), (4, 6), (5, 1), (6, 3)])
def test_banded_teacher_forcing_attention_equals_the_dense_mask(num_frames, window):
    """The recompute's O(F*W) self-attention (``dit._teacher_forcing_attention``) is exactly attention
    under the dense (2F*block)^2 teacher-forcing token mask."""
    block, heads, head_dim = 3, 2, 4
    ks = jax.random.split(jax.random.key(num_frames * 10 + window), 3)
    shape = (2, 2 * num_frames * block, heads, head_dim)
    q, k, v = (jax.random.normal(key, shape) for key in ks)
    dense_mask = masks.expand_to_tokens(masks.teacher_forcing_frame_mask(num_frames, window), block)
    want = attention(q, k, v, dense_mask)
    got = dit_module._teacher_forcing_attention(q, k, v, num_frames, window, block, "xla")
    np.testing.assert_allclose(got, want, atol=1e-5, rtol=0)


# ---------------------------------------------------------------------------------------------
# DMD objective on hand-built inputs
# ---------------------------------------------------------------------------------------------


def test_dmd_gradient_normalisation_and_clipping():
    sf_cfg = sf.SelfForcingConfig()
    shape = (3, 2, 2, 1, 1, 2)  # B, P, F, h, w, C: 8 elements per sample
    x0 = jnp.zeros(shape)
    real = jnp.zeros(shape).at[0].set(2.0).at[1].set(0.0).at[2].set(-4.0)  # mean|x0 - real| = 2, 0, 4
    fake = real + jnp.arange(8.0).reshape(shape[1:])[None] * jnp.array([1.0, 1e-3, 1.0])[:, None, None, None, None,
                                                                                           None]
    fake = fake.at[2, 0, 0, 0, 0, 0].set(jnp.nan).at[2, 0, 0, 0, 0, 1].set(jnp.inf)
    fake = fake.at[2, 0, 1, 0, 0, 0].set(-jnp.inf)
    grad = np.asarray(sf.dmd_gradient(x0, real, fake, sf_cfg))
    diff = np.arange(8.0).reshape(shape[1:])
    np.testing.assert_allclose(grad[0], diff / 2.0, rtol=1e-6)  # normalised by sample 0's mean |x0 - real|
    # sample 1: x0 == real -> normaliser floored at 1e-8 -> everything nonzero clips to 10
    np.testing.assert_array_equal(grad[1], np.where(diff > 0, 10.0, 0.0))
    # sample 2: nan -> 0, +inf -> +10, -inf -> -10, the rest (diff / 4) is within the clip
    want = diff / 4.0
    want[0, 0, 0, 0, 0], want[0, 0, 0, 0, 1], want[0, 1, 0, 0, 0] = 0.0, 10.0, -10.0
    np.testing.assert_allclose(grad[2], want, rtol=1e-6)
    assert np.abs(grad).max() <= sf_cfg.dmd_clip


def test_dmd_loss_value_and_gradient():
    key = jax.random.key(3)
    x0 = jax.random.normal(key, (2, 2, 3, 2, 2, 4))
    grad = jax.random.uniform(jax.random.key(4), x0.shape, minval=-10, maxval=10)
    loss, d_x0 = jax.value_and_grad(sf.dmd_loss)(x0, grad)
    np.testing.assert_allclose(loss, 0.5 * np.mean(np.square(grad)), rtol=1e-5)
    np.testing.assert_allclose(d_x0, grad / x0.size, rtol=1e-5, atol=1e-9)
    # the gradient does not flow into ``grad`` itself
    d_grad = jax.grad(sf.dmd_loss, argnums=1)(x0, grad)
    np.testing.assert_array_equal(d_grad, 0.0)


def test_config_validation():
    with pytest.raises(ValueError, match="generator_every"):
        sf.SelfForcingConfig(generator_every=0)
    with pytest.raises(ValueError, match="critic_lr"):
        sf.SelfForcingConfig(critic_lr=0.0)


# ---------------------------------------------------------------------------------------------
# Full iterations
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sf_setup(cfg):
    """(sf_cfg, create(seed) -> (graphs, state), iteration) with the programs compiled once."""
    sf_cfg = sf.SelfForcingConfig(generator_lr=LR, critic_lr=LR)
    gen_tx, critic_tx = sf.make_optimizers(sf_cfg)
    models = [_random_dit(cfg, seed) for seed in (0, 1, 2)]  # generator, critic, teacher (critic != teacher)

    def create(seed):
        return sf.create_self_forcing_state(*models, gen_tx, critic_tx, rng=seed)

    graphs, _ = create(0)
    iteration = sf.make_iteration(sf.make_checkpointed_generator_step(graphs, gen_tx, sf_cfg),
                                  sf.make_critic_step(graphs, critic_tx, sf_cfg), sf_cfg)
    return sf_cfg, create, iteration


def _run(sf_setup, batch, num_iterations, seed):
    _, create, iteration = sf_setup
    _, state = create(seed)
    before = jax.tree.map(np.asarray, state)  # host copy: the state is donated
    history = []
    for _ in range(num_iterations):
        step = int(state.iteration)
        state, metrics = iteration(state, batch)
        history.append(check_finite(metrics, step))
    return before, state, history


def test_iteration_updates_generator_and_critic_keeps_teacher(sf_setup, batch):
    before, state, history = _run(sf_setup, batch, 2, seed=0)
    after = jax.tree.map(np.asarray, state)
    assert int(state.iteration) == 2
    assert int(state.generator.step) == 1 and int(state.critic.step) == 2  # generator only at iteration 0
    assert "generator/loss" in history[0] and "generator/loss" not in history[1]
    assert history[0]["generator/grad_norm"] > 0 and history[0]["generator/dmd_grad_abs_mean"] > 0
    assert not np.array_equal(_flat(before.generator.params), _flat(after.generator.params))
    assert not np.array_equal(_flat(before.critic.params), _flat(after.critic.params))
    np.testing.assert_array_equal(_flat(before.teacher_params), _flat(after.teacher_params))
    assert history[0]["critic/loss"] > 0


def test_iterations_are_deterministic_given_the_seed(sf_setup, batch):
    _, state_a, hist_a = _run(sf_setup, batch, 1, seed=5)
    _, state_b, hist_b = _run(sf_setup, batch, 1, seed=5)
    _, _, hist_c = _run(sf_setup, batch, 1, seed=6)
    assert hist_a == hist_b
    np.testing.assert_array_equal(_flat(state_a.generator.params), _flat(state_b.generator.params))
    np.testing.assert_array_equal(_flat(state_a.critic.params), _flat(state_b.critic.params))
    assert hist_a != hist_c


def test_state_is_a_pytree_of_arrays(sf_setup):
    _, create, _ = sf_setup
    _, state = create(0)
    leaves = jax.tree.leaves(state)
    assert leaves and all(isinstance(a, jax.Array) for a in leaves)
    restored = jax.tree.unflatten(jax.tree.structure(state), [np.asarray(a) for a in leaves])
    assert isinstance(restored, sf.SelfForcingState)


# ---------------------------------------------------------------------------------------------
# With the camera warp (the tiny preset's layout): the previous latent, moved by the turn, is an input
# ---------------------------------------------------------------------------------------------


def make_warp_cfg() -> WorldModelConfig:
    return WorldModelConfig.test(dit=dataclasses.replace(WorldModelConfig.test().dit, camera_warp=(0.3, 0.5)))


def make_warp_batch(batch: dict) -> dict:
    """``batch`` with turning mice (a few degrees per frame, so the warp moves latents by fractions of a pixel
    and more) and the warp's conditioning channels."""
    return {**batch, "mouse": 4.0 * batch["mouse"]}


@pytest.fixture(scope="module")
def warp_cfg():
    return make_warp_cfg()


@pytest.fixture(scope="module")
def warp_batch(batch):
    return make_warp_batch(batch)


def test_warp_checkpointed_recompute_equals_rollout_x0(warp_cfg, warp_batch):
    """The teacher-forcing pass reads each noisy frame's previous frame from the clean half, as the rollout's
    cache holds the committed x̂0: the recompute reproduces the rollout under the warp too."""
    graphdef, params, rest = nnx.split(_random_dit(warp_cfg, seed=0), nnx.Param, ...)
    key = jax.random.key(11)
    x0s = {name: jax.jit(lambda p, e, fn=fn: fn(graphdef, p, rest, warp_batch, key, e))(params, jnp.int32(1))
           for name, fn in (("naive", sf.naive_generator_x0), ("checkpointed", sf.checkpointed_generator_x0))}
    assert float(jnp.abs(x0s["naive"]).mean()) > 0.1
    np.testing.assert_allclose(x0s["checkpointed"], x0s["naive"], atol=FORWARD_TOL, rtol=0)


def test_warp_score_models_read_the_clean_previous_frames(warp_cfg, warp_batch):
    """DMD's teacher / critic were trained with clean previous frames (``training.step``): ``score_x0`` must
    pass the generated x0 as ``clean``; with the warp off the argument changes nothing."""
    x0 = jax.random.normal(jax.random.key(3), warp_batch["x0"].shape)
    x_t = 0.5 * x0 + 0.5 * jax.random.normal(jax.random.key(4), x0.shape)
    t = jnp.full(x0.shape[:3], 500.0)
    dit = _random_dit(warp_cfg, seed=2)
    ours = sf.score_x0(dit, x_t, t, warp_batch, x0)
    v = dit.forward_bidirectional(x_t, t, *(warp_batch[k] for k in sf.CONDITIONING_KEYS), clean=x0)
    np.testing.assert_allclose(ours, x_t - 0.5 * v, atol=1e-4, rtol=0)  # sigma = 500 / 1000
    assert float(jnp.abs(ours - sf.score_x0(dit, x_t, t, warp_batch, x_t)).mean()) > 1e-3
    plain = _random_dit(WorldModelConfig.test(), seed=2)
    np.testing.assert_array_equal(sf.score_x0(plain, x_t, t, warp_batch, x0),
                                  sf.score_x0(plain, x_t, t, warp_batch, x_t))


def warp_iteration() -> dict:
    """One Self Forcing iteration on the warp layout -> its generator grad norm, critic loss, and whether the
    generator's parameters moved."""
    warp_cfg = make_warp_cfg()
    sf_cfg = sf.SelfForcingConfig(generator_lr=LR, critic_lr=LR)
    gen_tx, critic_tx = sf.make_optimizers(sf_cfg)
    graphs, state = sf.create_self_forcing_state(*(_random_dit(warp_cfg, s) for s in (0, 1, 2)), gen_tx, critic_tx,
                                                 rng=0)
    before = _flat(jax.tree.map(np.asarray, state.generator.params))
    iteration = sf.make_iteration(sf.make_checkpointed_generator_step(graphs, gen_tx, sf_cfg),
                                  sf.make_critic_step(graphs, critic_tx, sf_cfg), sf_cfg)
    state, metrics = iteration(state, make_warp_batch(make_batch(WorldModelConfig.test())))
    metrics = check_finite(metrics, 0)
    return {"generator_grad_norm": float(metrics["generator/grad_norm"]),
            "critic_loss": float(metrics["critic/loss"]),
            "generator_moved": not np.array_equal(before, _flat(state.generator.params))}


def test_warp_iteration_trains_generator_and_critic(tmp_path):
    """Run in a fresh process: inside the full suite's long-lived process this program (among the suite's
    largest, optimisations off) crashed it three times, loading it from JAX's compilation cache (SIGSEGV: session
    32's CI run, and here) or compiling it (SIGABRT), while it compiles and runs alone every time."""
    out = tmp_path / "warp_iteration.json"
    proc = subprocess.run([sys.executable, __file__, str(out)], check=False, cwd=REPO, capture_output=True,
                          text=True, timeout=900, env=dict(os.environ, JAX_PLATFORMS="cpu"))
    assert proc.returncode == 0, proc.stderr[-4000:]
    result = json.loads(out.read_text())
    assert result["generator_grad_norm"] > 0 and result["critic_loss"] > 0 and result["generator_moved"]


if __name__ == "__main__":  # the worker of test_warp_iteration_trains_generator_and_critic
    jax.config.update("jax_disable_most_optimizations", True)  # as _quick_compiles
    Path(sys.argv[1]).write_text(json.dumps(warp_iteration()))
