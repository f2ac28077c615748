"""CausalVideoVAE (docs/model.md §7.1): shapes, causality, streaming == cacheless, normalisation, training."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from flax import nnx

from solaris_env.world_model.config import VAEConfig, WorldModelConfig
from solaris_env.world_model.vae import (
    LOGVAR_INIT,
    CausalVideoVAE,
    SpatialAttention,
    _run_layers,
    denormalize_latents,
    kl_divergence,
    normalize_latents,
    sample_posterior,
)

CFG = WorldModelConfig.test()  # 32x32 frames -> 4x4x4 latents, temporal x4
TF = CFG.vae.temporal_factor
# temporal x2, spatial x2: small enough that its training step compiles in a few seconds
MICRO = VAEConfig(base_dim=8, z_dim=4, dim_mult=(1, 2), num_res_blocks=1, temporal_downsample=(True,),
                  middle_attention=False)

encode = nnx.jit(lambda vae, x: vae.encode(x))
decode = nnx.jit(lambda vae, z: vae.decode(z))
encode_chunked = nnx.jit(lambda vae, x, cache: vae.encode_chunked(x, cache))
decode_step = nnx.jit(lambda vae, z, cache: vae.decode_step(z, cache))


def rngs(seed: int = 0) -> nnx.Rngs:
    """rbg keys: parameter init compiles ~3x faster on CPU than with threefry (one compile per shape)."""
    return nnx.Rngs(jax.random.key(seed, impl="rbg"))


def num_params(module) -> int:
    return sum(int(np.prod(p.shape)) for p in jax.tree.leaves(nnx.state(module, nnx.Param)))


@pytest.fixture(scope="module")
def vae():
    return CausalVideoVAE(CFG.vae, rngs=rngs())


@pytest.fixture(scope="module")
def micro_vae():
    return CausalVideoVAE(MICRO, rngs=rngs())


@pytest.fixture(scope="module")
def video():
    """(1, 9, 32, 32, 3) in [-1, 1]: T = 1 + 4 * (3 - 1)."""
    return jax.random.uniform(jax.random.key(1), (1, 9, CFG.frame_height, CFG.frame_width, 3), minval=-1, maxval=1)


def test_solaris_preset_param_count():
    abstract = nnx.eval_shape(lambda: CausalVideoVAE(WorldModelConfig.solaris().vae, rngs=nnx.Rngs(0)))
    # docs/model.md §2.3: 126,892,533 state leaves; the reference's shared dropout Rngs adds 2 scalars (key, count).
    assert num_params(abstract) == 126_892_531


@pytest.mark.parametrize("preset,T", [("solaris", 5), ("tiny", 9), ("tiny16", 9), ("test", 1)])
def test_preset_shapes_abstract(preset, T):
    cfg = WorldModelConfig.__dict__[preset].__func__(WorldModelConfig)
    abstract = nnx.eval_shape(lambda: CausalVideoVAE(cfg.vae, rngs=nnx.Rngs(0)))
    F = cfg.vae.latent_frames(T)
    x = jax.ShapeDtypeStruct((2, T, cfg.frame_height, cfg.frame_width, 3), jnp.float32)
    z = nnx.eval_shape(lambda m, x: m.encode(x), abstract, x)
    assert z.shape == (2, F, cfg.latent_height, cfg.latent_width, cfg.latent_channels)
    assert nnx.eval_shape(lambda m, z: m.decode(z), abstract, z).shape == x.shape


def test_tiny_is_64px_to_8x8x16_with_temporal_4():
    cfg = WorldModelConfig.tiny()
    assert (cfg.latent_height, cfg.latent_width, cfg.latent_channels, cfg.vae.temporal_factor) == (8, 8, 16, 4)


def test_tiny16_is_64px_to_16x16x16_with_temporal_4_and_keeps_16_tokens():
    cfg, tiny = WorldModelConfig.tiny16(), WorldModelConfig.tiny()
    assert (cfg.latent_height, cfg.latent_width, cfg.latent_channels, cfg.vae.temporal_factor) == (16, 16, 16, 4)
    assert cfg.tokens_per_frame == tiny.tokens_per_frame == 16
    assert cfg.dit.camera_warp == tuple(2 * w for w in tiny.dit.camera_warp)  # latent pixels per degree


def test_decoder_base_dim_changes_only_the_decoder():
    """tiny: encoder at base_dim 16, decoder at decoder_base_dim 8; 0 means base_dim (solaris unchanged)."""
    tiny = WorldModelConfig.tiny().vae
    assert tiny.base_dim == 16 and tiny.decoder_base_dim == 8 and tiny.decoder_dim == 8
    assert WorldModelConfig.solaris().vae.decoder_dim == WorldModelConfig.solaris().vae.base_dim
    same = dataclasses.replace(tiny, decoder_base_dim=0)
    shapes = lambda cfg: {"/".join(map(str, k)): v.shape for k, v in nnx.to_flat_state(
        nnx.state(nnx.eval_shape(lambda: CausalVideoVAE(cfg, rngs=nnx.Rngs(0))), nnx.Param))}
    narrow, wide = shapes(tiny), shapes(same)
    assert narrow.keys() == wide.keys()
    changed = {k for k in narrow if narrow[k] != wide[k]}
    assert changed and all(k.startswith("decoder/") for k in changed)
    assert narrow["decoder/conv_in/kernel"][-1] == 8 * tiny.dim_mult[-1]
    assert narrow["encoder/conv_in/kernel"][-1] == 16
    with pytest.raises(ValueError, match="decoder_base_dim"):
        dataclasses.replace(tiny, decoder_base_dim=-1)


def test_decoder_head_upscale_replaces_the_last_spatial_stages():
    """decoder_head_upscale=u: the decoder loses its last log2(u) (spatial-only) upsampling stages, the head
    predicts u*u*3 channels; shapes, causality of streaming and the encoder side are unchanged."""
    wan = dataclasses.replace(CFG.vae, decoder_head_upscale=1)
    up2 = dataclasses.replace(CFG.vae, decoder_head_upscale=2, temporal_downsample=(False, True, True))
    assert up2.head_upscale_stages == 1 and up2.decoder_layout() == {"decoder_base_dim": 0, "decoder_head_upscale": 2}
    shapes = lambda cfg: {"/".join(map(str, k)): v.shape for k, v in nnx.to_flat_state(
        nnx.state(nnx.eval_shape(lambda: CausalVideoVAE(cfg, rngs=nnx.Rngs(0))), nnx.Param))}
    a, b = shapes(dataclasses.replace(wan, temporal_downsample=(False, True, True))), shapes(up2)
    assert {k: v for k, v in a.items() if not k.startswith("decoder/")} == \
           {k: v for k, v in b.items() if not k.startswith("decoder/")}
    assert b["decoder/head/conv/kernel"][-1] == 3 * 2 * 2 and a["decoder/head/conv/kernel"][-1] == 3
    assert len({k.split("/")[2] for k in b if k.startswith("decoder/up/")}) < \
           len({k.split("/")[2] for k in a if k.startswith("decoder/up/")})
    vae2 = CausalVideoVAE(up2, rngs=rngs(3))
    z = jax.random.normal(jax.random.key(2), (1, 3, CFG.latent_height, CFG.latent_width, CFG.latent_channels))
    y_full = decode(vae2, z)
    assert y_full.shape == (1, 9, CFG.frame_height, CFG.frame_width, 3)
    cache, frames = None, []
    for i in range(z.shape[1]):
        y, cache = decode_step(vae2, z[:, i:i + 1], cache)
        frames.append(y)
    np.testing.assert_allclose(jnp.concatenate(frames, axis=1), y_full, atol=1e-4)


def test_decoder_head_upscale_is_depth_to_space():
    """Output pixel (u*i + dy, u*j + dx, c) is head channel (dy*u + dx)*3 + c at position (i, j)."""
    cfg = dataclasses.replace(MICRO, decoder_head_upscale=2, temporal_downsample=(False,))
    vae2 = CausalVideoVAE(cfg, rngs=rngs(4))
    z = jax.random.normal(jax.random.key(5), (1, 1, 4, 4, cfg.z_dim))
    x, _ = vae2.conv2(z, None)
    d = vae2.decoder
    h, _ = _run_layers([d.conv_in, *d.middle, *d.up, d.head], x, None)  # (1, 1, 4, 4, 12)
    y = vae2.decode_raw(z)  # (1, 1, 8, 8, 3)
    for dy in range(2):
        for dx in range(2):
            np.testing.assert_allclose(y[0, 0, dy::2, dx::2], h[0, 0, :, :, (dy * 2 + dx) * 3:(dy * 2 + dx) * 3 + 3],
                                       atol=1e-6)


@pytest.mark.parametrize("upscale", [0, 3, 16])
def test_decoder_head_upscale_must_be_a_power_of_two_within_the_spatial_factor(upscale):
    with pytest.raises(ValueError, match=r"decoder_head_upscale must be a power of 2 in \[1, 8\]"):
        dataclasses.replace(CFG.vae, decoder_head_upscale=upscale)


def test_decoder_head_upscale_cannot_drop_a_temporal_stage():
    with pytest.raises(ValueError, match="decoder_head_upscale=2 would drop a temporal upsampling stage"):
        dataclasses.replace(CFG.vae, decoder_head_upscale=2, temporal_downsample=(True, True, False))
    dataclasses.replace(CFG.vae, decoder_head_upscale=4, temporal_downsample=(False, False, True))  # fine


def test_temporal_factor_one_keeps_frame_count():
    vcfg = VAEConfig(base_dim=4, z_dim=4, dim_mult=(1, 2), num_res_blocks=1, temporal_downsample=(False,),
                     middle_attention=False)
    abstract = nnx.eval_shape(lambda: CausalVideoVAE(vcfg, rngs=nnx.Rngs(0)))
    x = jax.ShapeDtypeStruct((1, 3, 8, 8, 3), jnp.float32)
    z = nnx.eval_shape(lambda m, x: m.encode(x), abstract, x)
    assert z.shape == (1, 3, 4, 4, 4)
    assert nnx.eval_shape(lambda m, z: m.decode(z), abstract, z).shape == x.shape


def test_encode_decode_shapes_and_range(vae, video):
    z = encode(vae, video)
    assert z.shape == (1, 3, 4, 4, 4) and CFG.vae.video_frames(3) == 9
    y = decode(vae, z)
    assert y.shape == video.shape
    assert float(jnp.abs(y).max()) <= 1.0 and bool(jnp.isfinite(y).all())


@pytest.mark.parametrize("t", [1, 4, 5, 8])
def test_encoder_is_causal(vae, video, t):
    """Changing video frame t changes latent ceil(t / tf) but none before it."""
    z = encode(vae, video)
    z2 = encode(vae, video.at[:, t].add(0.5))
    first_affected = -(-t // TF)
    diff = jnp.abs(z2 - z).reshape(3, -1).max(-1)
    assert float(diff[:first_affected].max(initial=0.0)) == 0.0
    assert float(diff[first_affected]) > 1e-4


def test_decoder_is_causal(vae, video):
    """Changing latent frame 2 leaves decoded frames 0 .. 1 + tf of latents 0, 1 unchanged."""
    z = encode(vae, video)
    y, y2 = decode(vae, z), decode(vae, z.at[:, 2].add(1.0))
    diff = jnp.abs(y2 - y).reshape(9, -1).max(-1)
    assert float(diff[:1 + TF].max()) == 0.0 and float(diff[1 + TF:].max()) > 1e-4


def test_chunked_encode_matches_cacheless(vae, video):
    z_full = encode(vae, video)
    z0, cache = encode_chunked(vae, video[:, :1], None)  # chunks [1, 4, 4]
    z1, cache = encode_chunked(vae, video[:, 1:5], cache)
    z2, _ = encode_chunked(vae, video[:, 5:9], cache)
    np.testing.assert_allclose(jnp.concatenate([z0, z1, z2], axis=1), z_full, atol=1e-4)


def test_chunk_lengths_are_checked(vae, video):
    with pytest.raises(AssertionError, match="1 \\+ 4"):
        vae.encode(video[:, :4])


def test_step_decode_matches_full_decode(vae, video):
    z = encode(vae, video)
    y_full = decode(vae, z)
    cache, frames = None, []
    for i in range(z.shape[1]):
        y, cache = decode_step(vae, z[:, i:i + 1], cache)
        assert y.shape[1] == (1 if i == 0 else TF)
        frames.append(y)
    np.testing.assert_allclose(jnp.concatenate(frames, axis=1), y_full, atol=1e-4)


def test_spatial_attention_matches_naive_per_frame_attention():
    """Single head over the h*w positions of each frame, residual; checked against a numpy loop."""
    dim = 8
    attn = SpatialAttention(dim, dtype=jnp.float32, param_dtype=jnp.float32, rngs=rngs())
    attn.proj.kernel[...] = jnp.asarray(np.random.default_rng(0).normal(size=(dim, dim)), jnp.float32)  # not 0
    x = np.random.default_rng(1).normal(size=(2, 3, 2, 3, dim)).astype(np.float32)  # (B, T, H, W, C)
    y, cache = attn(jnp.asarray(x), None)
    w_qkv, b_qkv = np.asarray(attn.to_qkv.kernel[...]), np.asarray(attn.to_qkv.bias[...])
    w_o, b_o = np.asarray(attn.proj.kernel[...]), np.asarray(attn.proj.bias[...])
    expected = np.empty_like(x)
    for b in range(2):
        for t in range(3):
            tok = x[b, t].reshape(-1, dim)
            n = tok / np.linalg.norm(tok, axis=-1, keepdims=True) * np.sqrt(dim)  # gamma = 1
            q, k, v = np.split(n @ w_qkv + b_qkv, 3, axis=-1)
            logits = q @ k.T / np.sqrt(dim)
            p = np.exp(logits - logits.max(-1, keepdims=True))
            o = (p / p.sum(-1, keepdims=True)) @ v
            expected[b, t] = (tok + o @ w_o + b_o).reshape(2, 3, dim)
    assert cache is None
    np.testing.assert_allclose(y, expected, atol=1e-4)


def test_latent_normalisation_round_trip():
    vcfg = WorldModelConfig.solaris().vae
    mu = jnp.asarray(np.random.default_rng(0).normal(size=(2, 3, 4, 5, vcfg.z_dim)), jnp.float32)
    z = normalize_latents(mu, vcfg)
    np.testing.assert_allclose(z[..., 0], (mu[..., 0] + 0.7571) / 2.8184, rtol=1e-5)
    np.testing.assert_allclose(denormalize_latents(z, vcfg), mu, atol=1e-5)
    assert normalize_latents(mu, CFG.vae) is mu and denormalize_latents(mu, CFG.vae) is mu  # no stats: identity


def test_encode_decode_apply_config_stats(micro_vae, video):
    stats = dataclasses.replace(MICRO, latent_mean=(1.0, -1.0, 0.5, 0.0), latent_std=(2.0, 0.5, 1.0, 4.0))
    # same parameters, different statistics: build abstractly and load the state (as a checkpoint restore does)
    vae = nnx.merge(nnx.graphdef(nnx.eval_shape(lambda: CausalVideoVAE(stats, rngs=rngs()))), nnx.state(micro_vae))
    x = video[:, :5, :8, :8]

    @nnx.jit
    def run(vae, x):
        mu, _ = vae.encode_moments(x)
        z = vae.encode(x)
        return mu, z, vae.decode(z), vae.decode_raw(mu)

    mu, z, y, y_raw = run(vae, x)
    np.testing.assert_allclose(z, (mu - jnp.array(stats.latent_mean)) / jnp.array(stats.latent_std), atol=1e-6)
    np.testing.assert_allclose(y, jnp.clip(y_raw, -1, 1), atol=1e-5)


def test_sample_posterior_and_kl():
    mu, logvar = jnp.full((4, 2, 8, 8, 4), 0.5), jnp.full((4, 2, 8, 8, 4), np.log(0.25))
    s = sample_posterior(mu, logvar, key=jax.random.key(0, impl="rbg"))
    assert abs(float(s.mean()) - 0.5) < 0.05 and abs(float(s.std()) - 0.5) < 0.05
    assert float(jnp.abs(kl_divergence(jnp.zeros_like(mu), jnp.zeros_like(mu))).max()) == 0.0
    assert kl_divergence(mu, logvar).shape == (4,)


def test_a_fresh_vae_has_a_near_deterministic_posterior(micro_vae):
    """At initialisation the log-variance is LOGVAR_INIT for every input and latent (its weights are 0), so a
    posterior sample is the mean up to noise of std exp(LOGVAR_INIT / 2), while the mean depends on the input."""
    x = jax.random.uniform(jax.random.key(3), (2, 5, 16, 16, 3), minval=-1, maxval=1)
    mu, logvar = micro_vae.encode_moments(x)
    np.testing.assert_array_equal(np.asarray(logvar), np.full(logvar.shape, LOGVAR_INIT, np.float32))
    assert float(jnp.std(mu)) > 20 * float(np.exp(LOGVAR_INIT / 2))
    z = sample_posterior(mu, logvar, key=jax.random.key(0, impl="rbg"))
    assert float(jnp.abs(z - mu).max()) < 6 * float(np.exp(LOGVAR_INIT / 2))


@pytest.mark.slow  # ~5-10 s on 2 shared cores, nearly all of it compiling the training step
def test_few_adam_steps_reduce_reconstruction_mse(micro_vae):
    """The micro VAE starts to overfit one clip: its reconstruction MSE drops within a few Adam steps."""
    vae = nnx.merge(*nnx.split(micro_vae))  # a copy: the fixture stays at its init
    opt = nnx.Optimizer(vae, optax.adam(3e-3), wrt=nnx.Param)
    t = jnp.linspace(0, 1, 5)[:, None, None, None]
    clip = jnp.sin(6 * t + jnp.linspace(-3, 3, 16)[None, :, None, None] + jnp.arange(3) * 2.0)[None]  # (1,5,16,16,3)
    clip = jnp.broadcast_to(clip, (1, 5, 16, 16, 3)) * 0.8

    @nnx.jit
    def step(vae, opt, x, key):
        def loss_fn(vae):
            mu, logvar = vae.encode_moments(x)
            z = sample_posterior(mu, logvar, key=key)
            return jnp.mean(jnp.square(vae.decode_raw(z) - x)) + 1e-6 * kl_divergence(mu, logvar).mean()
        loss, grads = nnx.value_and_grad(loss_fn)(vae)
        opt.update(vae, grads)
        return loss

    key = jax.random.key(0, impl="rbg")
    losses = [float(step(vae, opt, clip, jax.random.fold_in(key, i))) for i in range(10)]
    assert losses[-1] < 0.7 * losses[0], losses
