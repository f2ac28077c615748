"""The flow-matching rules (``solaris_env/world_model/flow_matching.py``; docs/model.md §5.3, §6.1)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from solaris_env.world_model import flow_matching as fm
from solaris_env.world_model.config import SamplerConfig

SHAPE = (2, 3, 4, 4, 4, 5)  # (B, P, F, h, w, C)


def _normals(seed: int, n: int, shape=SHAPE):
    return [jax.random.normal(k, shape, jnp.float32) for k in jax.random.split(jax.random.key(seed), n)]


def test_sigma_of_timestep_is_t_over_1000_in_f32():
    assert fm.NUM_TRAIN_TIMESTEPS == 1000 == SamplerConfig().num_train_timesteps
    t = jnp.array([0, 250, 500, 750, 1000], jnp.int32)
    sigma = fm.sigma_of_timestep(t)
    assert sigma.dtype == jnp.float32
    # t * f32(1 / 1000), as XLA compiles t / 1000: exact up to one f32 ulp (750 -> 0.75000006)
    np.testing.assert_allclose(sigma, [0.0, 0.25, 0.5, 0.75, 1.0], rtol=1.2e-7, atol=0)
    assert sigma[0] == 0.0 and sigma[-1] == 1.0
    np.testing.assert_allclose(fm.sigma_of_timestep(jnp.float32(300.0), 600), 0.5, rtol=1.2e-7, atol=0)
    t_BPF = jnp.arange(2 * 3 * 4, dtype=jnp.int32).reshape(2, 3, 4) * 40
    sigma_BPF111 = fm.sigma_BPF111(t_BPF)
    assert sigma_BPF111.shape == (2, 3, 4, 1, 1, 1)
    np.testing.assert_array_equal(sigma_BPF111[..., 0, 0, 0], fm.sigma_of_timestep(t_BPF))


def test_noise_at_sigma_zero_is_x0_and_at_one_is_eps():
    x0, eps = _normals(0, 2)
    np.testing.assert_array_equal(fm.noise(x0, eps, 0.0), x0)
    np.testing.assert_array_equal(fm.noise(x0, eps, 1.0), eps)
    np.testing.assert_allclose(fm.noise(x0, eps, 0.25), 0.75 * x0 + 0.25 * eps, atol=1e-6)


def test_noise_per_frame_sigma_matches_each_frame():
    x0, eps = _normals(1, 2)
    t_BPF = jax.random.randint(jax.random.key(2), SHAPE[:3], 0, 1001)
    x_t = fm.noise(x0, eps, fm.sigma_BPF111(t_BPF))
    for idx in [(0, 0, 0), (1, 2, 3), (0, 1, 2)]:
        want = fm.noise(x0[idx], eps[idx], fm.sigma_of_timestep(t_BPF[idx]))
        np.testing.assert_allclose(x_t[idx], want, atol=1e-6, rtol=0)


def test_velocity_target_is_the_derivative_of_noising_in_sigma():
    x0, eps = _normals(3, 2)
    _, d_dsigma = jax.jvp(lambda s: fm.noise(x0, eps, s), (jnp.float32(0.3),), (jnp.float32(1.0),))
    np.testing.assert_allclose(d_dsigma, fm.velocity_target(x0, eps), atol=1e-6)
    np.testing.assert_array_equal(fm.velocity_target(x0, eps), eps - x0)


@pytest.mark.parametrize("sigma", [0.0, 0.1, 0.5, 0.9, 1.0])
def test_x0_and_eps_from_the_true_velocity_invert_noising(sigma):
    x0, eps = _normals(4, 2)
    x_t, v = fm.noise(x0, eps, sigma), fm.velocity_target(x0, eps)
    np.testing.assert_allclose(fm.x0_from_velocity(x_t, v, sigma), x0, atol=1e-5)
    np.testing.assert_allclose(fm.eps_from_velocity(x_t, v, sigma), eps, atol=1e-5)


def test_rules_compute_in_f32():
    x0, eps = (a.astype(jnp.bfloat16) for a in _normals(5, 2))
    for out in (fm.noise(x0, eps, 0.5), fm.velocity_target(x0, eps), fm.x0_from_velocity(x0, eps, 0.5),
                fm.eps_from_velocity(x0, eps, 0.5), fm.sampler_step(x0, eps, 0.5, 0.25, eps)):
        assert out.dtype == jnp.float32


def test_sampler_step_to_sigma_zero_returns_the_x0_prediction():
    x_t, v, fresh = _normals(6, 3)
    np.testing.assert_array_equal(fm.sampler_step(x_t, v, 0.75, 0.0, fresh), fm.x0_from_velocity(x_t, v, 0.75))


def test_sampler_step_with_the_true_velocity_renoises_x0_with_the_fresh_noise():
    x0, eps, fresh = _normals(7, 3)
    x_t = fm.noise(x0, eps, 0.75)
    out = fm.sampler_step(x_t, fm.velocity_target(x0, eps), 0.75, 0.5, fresh)
    np.testing.assert_allclose(out, 0.5 * x0 + 0.5 * fresh, atol=1e-5)


def _previous_sampler_update(z_t, v, sigma, sigma_next, fresh):
    """The sampler's update written out on its own (sigma given: x0 from the velocity, re-noised to sigma_next
    with the fresh noise): what ``flow_matching.sampler_step`` must compute."""
    x0 = z_t.astype(jnp.float32) - sigma * v.astype(jnp.float32)
    return (1.0 - sigma_next) * x0 + sigma_next * fresh


def test_sampler_step_equals_the_previous_sampler_formula():
    x_t, v, fresh = _normals(8, 3)
    for t_now, t_next in [(1000.0, 750.0), (750.0, 500.0), (937.0, 869.0), (156.0, 0.0)]:
        sigma, sigma_next = fm.sigma_of_timestep(jnp.float32(t_now)), fm.sigma_of_timestep(jnp.float32(t_next))
        want = _previous_sampler_update(x_t, v, sigma, sigma_next, fresh)
        got = fm.sampler_step(x_t, v, sigma, sigma_next, fresh)
        np.testing.assert_array_equal(got, want)
        jitted = jax.jit(fm.sampler_step)(x_t, v, sigma, sigma_next, fresh)
        np.testing.assert_allclose(jitted, want, atol=1e-6, rtol=0)
