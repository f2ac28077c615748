"""Few-step samplers (docs/model.md §5.3): schedules and the x0-prediction + fresh-noise re-noising rule."""

import ast
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from solaris_env.world_model import sampler
from solaris_env.world_model.config import SamplerConfig

SHAPE = (2, 3, 1, 4, 4, 5)  # (B, P, 1, H, W, C): one latent frame


# ---------------------------------------------------------------------------------------------
# Schedules
# ---------------------------------------------------------------------------------------------


def test_ar_schedule_is_reference_four_steps_plus_commit():
    t = sampler.ar_schedule(SamplerConfig())
    assert t.dtype == np.float32
    np.testing.assert_array_equal(t, [1000, 750, 500, 250, 0])
    np.testing.assert_array_equal(sampler.ar_schedule(SamplerConfig(ar_timesteps=(1000, 500))), [1000, 500, 0])


@pytest.mark.parametrize("steps", [(750, 1000), (1000, 500, 0), (1200, 500)])
def test_ar_schedule_rejects_bad_timesteps(steps):
    with pytest.raises(ValueError, match="ar_timesteps"):
        sampler.ar_schedule(SamplerConfig(ar_timesteps=steps))


def test_shifted_schedule_formula():
    n, shift = 10, 5.0
    t = sampler.shifted_schedule(n, shift)
    sigma = np.linspace(1, 0, n + 1)[:-1]
    expected = 1000 * shift * sigma / (1 + (shift - 1) * sigma)
    assert t.shape == (n + 1,) and t.dtype == np.float32
    np.testing.assert_allclose(t[:-1], expected, rtol=1e-6)
    assert t[0] == 1000 and t[-1] == 0 and np.all(np.diff(t) < 0)
    np.testing.assert_allclose(t[1], 1000 * 4.5 / 4.6, rtol=1e-6)  # sigma 0.9 -> 0.978


def test_shift_one_is_the_plain_linspace_and_shift_pushes_towards_noise():
    np.testing.assert_allclose(sampler.shifted_schedule(4, 1.0), [1000, 750, 500, 250, 0], rtol=1e-6)
    assert np.all(sampler.shifted_schedule(8, 5.0)[1:-1] > sampler.shifted_schedule(8, 1.0)[1:-1])


def test_bidirectional_schedule_uses_config_and_reference_list_is_shift_five_thirds():
    cfg = SamplerConfig()
    np.testing.assert_array_equal(sampler.bidirectional_schedule(cfg), sampler.shifted_schedule(10, 5.0))
    # the reference's hard-coded 10-step list is floor(shifted_schedule(10, 5/3))
    np.testing.assert_array_equal(np.floor(sampler.shifted_schedule(10, 5 / 3)), sampler.REFERENCE_BIDIRECTIONAL_10)


@pytest.mark.parametrize("call", [lambda: sampler.shifted_schedule(0, 5.0), lambda: sampler.shifted_schedule(4, 0.0)])
def test_shifted_schedule_rejects_bad_arguments(call):
    with pytest.raises(ValueError):
        call()


# ---------------------------------------------------------------------------------------------
# The re-noising rule
# ---------------------------------------------------------------------------------------------


def _recording_x0_predictor(x0_target, calls):
    """A denoiser that knows x0: v = (z - x0) / sigma, so every x0 prediction is x0_target."""

    def denoise(z, t):
        calls.append((np.asarray(z), float(t)))
        return (z - x0_target) / (t / 1000.0)

    return denoise


def test_sample_frame_renoises_with_fresh_noise_and_ends_exactly_at_x0():
    key_z, key_x0, key = jax.random.split(jax.random.key(0), 3)
    z0 = jax.random.normal(key_z, SHAPE)
    x0_target = jax.random.normal(key_x0, SHAPE)
    timesteps = sampler.ar_schedule(SamplerConfig())
    calls = []
    with jax.disable_jit():  # lax.scan runs as a Python loop: the fake denoiser sees concrete inputs
        out = sampler.sample_frame(_recording_x0_predictor(x0_target, calls), z0, key, timesteps)
    assert [t for _, t in calls] == [1000.0, 750.0, 500.0, 250.0]
    np.testing.assert_array_equal(calls[0][0], z0)
    noise_keys = jax.random.split(key, 4)
    for s in range(1, 4):
        sigma = timesteps[s] / 1000.0
        expected = (1 - sigma) * np.asarray(x0_target) + sigma * np.asarray(jax.random.normal(noise_keys[s - 1], SHAPE))
        np.testing.assert_allclose(calls[s][0], expected, atol=2e-6)
    assert out.dtype == jnp.float32 and out.shape == SHAPE
    np.testing.assert_allclose(out, x0_target, atol=2e-6)  # the last step returns the x0 prediction


def test_last_step_output_is_exactly_the_x0_prediction():
    """With sigma_n = 0 the final carry is z - sigma * v bit for bit (no noise added)."""
    z0 = jax.random.normal(jax.random.key(1), SHAPE)
    v_const = jax.random.normal(jax.random.key(2), SHAPE)
    timesteps = [250.0, 0.0]  # one step
    out = sampler.sample_frame(lambda z, t: v_const, z0, jax.random.key(3), timesteps)
    np.testing.assert_array_equal(out, z0 - jnp.float32(0.25) * v_const)


def test_sampler_is_not_an_euler_solver():
    """Fresh noise each step: the result depends on the key, unlike a deterministic ODE step."""
    z0 = jax.random.normal(jax.random.key(4), SHAPE)
    denoise = lambda z, t: 0.5 * z  # a linear velocity field
    t = sampler.ar_schedule(SamplerConfig())
    a = sampler.sample_frame(denoise, z0, jax.random.key(5), t)
    b = sampler.sample_frame(denoise, z0, jax.random.key(6), t)
    assert not np.allclose(a, b)
    euler = z0
    for t_now, t_next in zip(t[:-1], t[1:]):
        euler = euler + (t_next - t_now) / 1000.0 * denoise(euler, t_now)
    assert not np.allclose(a, euler, atol=1e-3)


def test_sample_frame_jits_and_matches_eager():
    z0 = jax.random.normal(jax.random.key(7), SHAPE)
    denoise = lambda z, t: jnp.tanh(z) * (t / 1000.0)
    t = sampler.ar_schedule(SamplerConfig())
    jitted = jax.jit(lambda z, k: sampler.sample_frame(denoise, z, k, t))(z0, jax.random.key(8))
    np.testing.assert_allclose(jitted, sampler.sample_frame(denoise, z0, jax.random.key(8), t), atol=1e-6)


def test_sample_bidirectional_draws_its_noise_from_the_key_and_reaches_x0():
    shape = (1, 2, 3, 4, 4, 5)  # all frames at once
    key = jax.random.key(9)
    x0_target = jax.random.normal(jax.random.key(10), shape)
    calls = []
    with jax.disable_jit():
        out = sampler.sample_bidirectional(_recording_x0_predictor(x0_target, calls), shape, key,
                                           sampler.shifted_schedule(3, 5.0))
    k_init, _ = jax.random.split(key)
    np.testing.assert_array_equal(calls[0][0], jax.random.normal(k_init, shape))
    assert len(calls) == 3 and calls[0][1] == 1000.0
    np.testing.assert_allclose(out, x0_target, atol=2e-6)


@pytest.mark.parametrize("bad", [[1000, 500], [500, 1000, 0], [1000]])
def test_sample_frame_rejects_schedules_not_ending_in_zero(bad):
    with pytest.raises(ValueError, match="timesteps"):
        sampler.sample_frame(lambda z, t: z, jnp.zeros(SHAPE), jax.random.key(0), bad)


def test_sampler_takes_a_denoiser_and_never_imports_the_network():
    source = pathlib.Path(sampler.__file__).read_text()
    imported = {alias.name for node in ast.walk(ast.parse(source)) if isinstance(node, ast.ImportFrom)
                for alias in node.names}
    modules = {node.module for node in ast.walk(ast.parse(source)) if isinstance(node, ast.ImportFrom)}
    assert not imported & {"dit", "WorldDiT"} and not any(m and m.endswith(".dit") for m in modules)


def test_given_renoise_draws_replace_the_keys_draws():
    """``renoise`` = the draws the key would give: the same x0; other draws: another x0; the key is ignored."""
    z = jax.random.normal(jax.random.key(0), SHAPE)
    key = jax.random.key(1)
    timesteps = sampler.ar_schedule(SamplerConfig())
    x0_target = jnp.ones(SHAPE)
    denoise = lambda x, t: (x - 0.5 * x0_target) / (t / 1000.0) + 0.1 * x  # x0 depends on the noisy input
    draws = jnp.stack([jax.random.normal(k, SHAPE) for k in jax.random.split(key, len(timesteps) - 1)])
    want = sampler.sample_frame(denoise, z, key, timesteps)
    got = sampler.sample_frame(denoise, z, None, timesteps, renoise=draws)
    np.testing.assert_allclose(got, want, atol=1e-6, rtol=0)
    other = sampler.sample_frame(denoise, z, key, timesteps, renoise=-draws)
    assert not np.allclose(other, want)
    with pytest.raises(ValueError, match="renoise"):
        sampler.sample_frame(denoise, z, None, timesteps, renoise=draws[1:])
