"""The linear patch codec (VAEConfig.codec = "linear_patch", docs/model.md §7.1, "Linear patch codec"): the patch
layout, the codec's maps, streaming == cacheless, the world model's conditioning, and the principal-component fit."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model.config import VAEConfig, WorldModelConfig
from solaris_env.world_model.vae import CausalVideoVAE, latent_neighbourhood, patchify, unpatchify
from solaris_env.world_model.world_model import encoder_receptive_field, steady_cond_index
from training.vae import fit_linear_patch_codec, fit_patch_decoder

CFG = dataclasses.replace(WorldModelConfig.test().vae, codec="linear_patch")  # 32x32 -> 4x4x4, x8 space, x4 time
TF, SF = CFG.temporal_factor, CFG.spatial_factor


def rngs(seed: int = 0) -> nnx.Rngs:
    return nnx.Rngs(jax.random.key(seed, impl="rbg"))


@pytest.fixture(scope="module")
def vae():
    return CausalVideoVAE(CFG, rngs=rngs())


@pytest.fixture(scope="module")
def video():
    return jax.random.uniform(jax.random.key(1), (2, 9, 32, 32, 3), minval=-1, maxval=1)


def test_patchify_layout_and_round_trip():
    x = jnp.arange(1 * 8 * 4 * 4 * 3, dtype=jnp.float32).reshape(1, 8, 4, 4, 3)
    p = patchify(x, 4, 2, first=False)
    assert p.shape == (1, 2, 2, 2, 4 * 2 * 2 * 3)
    # entry (t, dy, dx, c) of the patch at latent (f, i, j) is pixel (4f + t, 2i + dy, 2j + dx, c)
    for f, i, j, t, dy, dx, c in [(0, 0, 0, 0, 0, 0, 0), (1, 1, 0, 3, 1, 1, 2), (1, 0, 1, 2, 0, 1, 1)]:
        assert p[0, f, i, j, ((t * 2 + dy) * 2 + dx) * 3 + c] == x[0, 4 * f + t, 2 * i + dy, 2 * j + dx, c]
    np.testing.assert_array_equal(unpatchify(p, 4, 2, first=False), x)


def test_a_stream_start_repeats_frame_zero_and_decodes_to_the_mean():
    x = jax.random.normal(jax.random.key(0), (2, 9, 8, 8, 3))
    p = patchify(x, 4, 2, first=True)
    assert p.shape == (2, 3, 4, 4, 48)
    np.testing.assert_array_equal(unpatchify(p, 4, 2, first=True), x)  # frame 0 repeated: its mean is itself
    np.testing.assert_array_equal(p[:, 0], patchify(jnp.repeat(x[:, :1], 4, axis=1), 4, 2, first=False)[:, 0])
    chunk = jnp.concatenate([jnp.zeros((1, 3, 8, 8, 3)), jnp.ones((1, 1, 8, 8, 3))], axis=1)
    np.testing.assert_allclose(unpatchify(patchify(chunk, 4, 2, False), 4, 2, True), jnp.full((1, 1, 8, 8, 3), 0.25))


def test_patchify_rejects_a_video_that_does_not_split():
    with pytest.raises(AssertionError, match="does not split"):
        patchify(jnp.zeros((1, 6, 8, 8, 3)), 4, 2, first=True)


def test_the_codec_is_one_linear_map_each_way(vae, video):
    mu, logvar = vae.encode_moments(video)
    np.testing.assert_allclose(mu, vae.patch_in(patchify(video, TF, SF, True)), atol=1e-6)
    np.testing.assert_allclose(vae.decode_raw(mu), unpatchify(vae.patch_out(mu), TF, SF, True), atol=1e-6)
    np.testing.assert_allclose(logvar, -8.0)
    names = {"/".join(map(str, path)) for path, _ in nnx.to_flat_state(nnx.state(vae, nnx.Param))}
    assert names == {"patch_in/kernel", "patch_in/bias", "patch_out/kernel", "patch_out/bias"}


def test_the_official_layout_is_wan_and_tiny16_is_the_codec():
    assert WorldModelConfig.solaris().vae.codec == "wan" and WorldModelConfig.tiny16().vae.codec == "linear_patch"
    with pytest.raises(ValueError, match="codec must be one of"):
        dataclasses.replace(CFG, codec="pca")


def test_streaming_equals_cacheless(vae, video):
    # float32 equality up to rounding: XLA blocks a matmul differently for a different number of rows, so a chunk
    # and the whole clip round differently (CI saw 1.4e-6 on values ~1)
    tol = dict(rtol=1e-5, atol=1e-5)
    mu = vae.encode(video)
    m0, cache = vae.encode_chunked(video[:, :5])
    m1, _ = vae.encode_chunked(video[:, 5:], cache)
    np.testing.assert_allclose(jnp.concatenate([m0, m1], 1), mu, **tol)
    full = vae.decode(mu)
    parts, cache = [], None
    for f in range(mu.shape[1]):
        out, cache = vae.decode_step(mu[:, f:f + 1], cache)
        parts.append(out)
    assert [p.shape[1] for p in parts] == [1, TF, TF]
    np.testing.assert_allclose(jnp.concatenate(parts, 1), full, **tol)


def test_a_latent_sees_only_its_own_frames(vae, video):
    """Changing frame t changes only the latent whose chunk holds it, and the conditioning is steady from
    latent 1 (its chunk is all gray)."""
    mu = vae.encode(video)
    changed = vae.encode(video.at[:, 3].set(0.5))
    diff = np.abs(np.asarray(changed - mu)).reshape(2, 3, -1).max(-1).max(0)
    assert diff[0] == 0 and diff[1] > 0 and diff[2] == 0  # frame 3 is in latent 1 (frames 1-4)
    assert encoder_receptive_field(CFG) == TF - 1 and steady_cond_index(CFG) == 1


# x2 space, x2 time: 24-dimensional patches, 4 latent channels
FIT = VAEConfig(base_dim=8, z_dim=4, dim_mult=(1, 2), num_res_blocks=1, temporal_downsample=(True,),
                middle_attention=False, codec="linear_patch")


def low_rank_clips(rng, n: int, rank: int) -> np.ndarray:
    """uint8 (n, 5, 8, 8, 3) still clips whose 2x2x3 pixel patches lie in a ``rank``-dimensional affine space."""
    basis = np.linalg.qr(rng.normal(size=(12, rank)))[0]
    coeff = rng.normal(size=(n, 4, 4, rank)) * np.linspace(2, 0.5, rank)
    patches = (0.15 * coeff @ basis.T).reshape(n, 4, 4, 2, 2, 3).transpose(0, 1, 3, 2, 4, 5).reshape(n, 8, 8, 3)
    frames = np.clip(np.round((patches + 0.1 + 1) * 127.5), 0, 255).astype(np.uint8)
    return np.repeat(frames[:, None], 5, axis=1)


def test_fit_finds_the_principal_components_of_a_low_rank_video():
    """Clips whose patches span z_dim dimensions are reconstructed exactly by the fitted codec; a codec of
    fewer dimensions keeps the directions of largest variance."""
    rng = np.random.default_rng(0)
    clips = low_rank_clips(rng, 16, FIT.z_dim)
    vae = CausalVideoVAE(FIT, rngs=rngs())
    fit = fit_linear_patch_codec(vae, [clips[:8], clips[8:]])
    assert fit["patches"] == 16 * 3 * 16 and fit["variance_kept"] > 0.999
    x = jnp.asarray(clips, jnp.float32) / 127.5 - 1
    rec = vae.decode_raw(vae.encode_moments(x)[0])
    assert float(jnp.max(jnp.abs(rec - x))) < 0.01  # up to the uint8 rounding of the clips
    vae2 = CausalVideoVAE(dataclasses.replace(FIT, z_dim=2), rngs=rngs())
    fit2 = fit_linear_patch_codec(vae2, [clips])
    assert 0.3 < fit2["variance_kept"] < 0.99 and fit2["component_std"][0] > fit2["component_std"][1]


def test_fit_needs_the_codec_and_enough_patches():
    with pytest.raises(ValueError, match="expected 'linear_patch'"):
        fit_linear_patch_codec(CausalVideoVAE(WorldModelConfig.test().vae, rngs=rngs()), [])
    with pytest.raises(ValueError, match="more clips"):
        fit_linear_patch_codec(CausalVideoVAE(FIT, rngs=rngs()), [np.zeros((1, 5, 4, 4, 3), np.uint8)])


# ---------------------------------------------------------------------------------------------
# The decoder's neighbourhood (VAEConfig.decoder_context)
# ---------------------------------------------------------------------------------------------


def test_latent_neighbourhood_layout_and_edge():
    z = jnp.arange(1 * 1 * 3 * 4 * 2, dtype=jnp.float32).reshape(1, 1, 3, 4, 2)
    assert latent_neighbourhood(z, 1) is z
    n = latent_neighbourhood(z, 3)
    assert n.shape == (1, 1, 3, 4, 9 * 2)
    # entry ((dy * 3 + dx) * C + c) of position (i, j) is z[clip(i + dy - 1), clip(j + dx - 1), c]
    for i, j, dy, dx, c in [(0, 0, 0, 0, 0), (1, 2, 1, 1, 1), (2, 3, 2, 2, 0), (0, 3, 0, 2, 1), (2, 0, 2, 0, 1)]:
        src = z[0, 0, min(max(i + dy - 1, 0), 2), min(max(j + dx - 1, 0), 3), c]
        assert n[0, 0, i, j, (dy * 3 + dx) * 2 + c] == src
    np.testing.assert_array_equal(n[..., 4 * 2:5 * 2], z)  # the centre tap is the position itself


def test_decoder_context_config_is_checked():
    assert dataclasses.replace(CFG, decoder_context=3).decoder_context == 3
    for bad in (0, 2, -1):
        with pytest.raises(ValueError, match="decoder_context must be an odd int >= 1"):
            dataclasses.replace(CFG, decoder_context=bad)
    with pytest.raises(ValueError, match="needs codec 'linear_patch'"):
        dataclasses.replace(WorldModelConfig.test().vae, decoder_context=3)


def test_a_wider_decoder_reads_the_neighbours_and_streams_like_cacheless(video):
    """decoder_context 3: patch_out reads 9 positions; the encoder (the latent space) is unchanged, decoding
    step by step still equals decoding the whole clip, and a decoder whose only non-zero tap is the centre one
    decodes exactly as the one-position decoder."""
    cfg3 = dataclasses.replace(CFG, decoder_context=3)
    one, three = CausalVideoVAE(CFG, rngs=rngs()), CausalVideoVAE(cfg3, rngs=rngs())
    assert three.patch_out.kernel[...].shape == (9 * CFG.z_dim, one.patch_out.kernel[...].shape[1])
    assert three.patch_in.kernel[...].shape == one.patch_in.kernel[...].shape
    three.patch_in.kernel[...], three.patch_in.bias[...] = one.patch_in.kernel[...], one.patch_in.bias[...]
    centre = np.zeros(three.patch_out.kernel[...].shape, np.float32)
    centre[4 * CFG.z_dim:5 * CFG.z_dim] = one.patch_out.kernel[...]
    three.patch_out.kernel[...], three.patch_out.bias[...] = jnp.asarray(centre), one.patch_out.bias[...]
    mu = one.encode(video)
    np.testing.assert_array_equal(three.encode(video), mu)
    np.testing.assert_allclose(three.decode(mu), one.decode(mu), atol=1e-5)
    three.patch_out.kernel[...] = jax.random.normal(jax.random.key(3), centre.shape) * 0.05
    full = three.decode(mu)
    parts, cache = [], None
    for f in range(mu.shape[1]):
        out, cache = three.decode_step(mu[:, f:f + 1], cache)
        parts.append(out)
    np.testing.assert_allclose(jnp.concatenate(parts, 1), full, rtol=1e-5, atol=1e-5)
    assert float(jnp.max(jnp.abs(full - one.decode(mu)))) > 1e-3  # the neighbours do count


def smooth_clips(rng, n: int) -> np.ndarray:
    """uint8 (n, 5, 8, 8, 3) still clips of smooth colour ramps: neighbouring patches predict each other."""
    yy, xx = np.meshgrid(np.linspace(-1, 1, 8), np.linspace(-1, 1, 8), indexing="ij")
    a = rng.normal(size=(n, 1, 1, 3, 3)) * 0.4
    frames = a[..., 0] + a[..., 1] * yy[None, :, :, None] + a[..., 2] * (xx * yy)[None, :, :, None]
    frames = np.clip(np.round((frames + 1) * 127.5), 0, 255).astype(np.uint8)
    return np.repeat(frames[:, None], 5, axis=1)


def test_fit_patch_decoder_lowers_the_error_of_the_components():
    """After the principal-component fit of a 2-channel codec, refitting a 3x3 decoder for the same encoder
    lowers the reconstruction error on the clips (least squares over a superset of the one-position decoder),
    never moves the encoder, and one position (context 1) gives the principal-component decoder back."""
    rng = np.random.default_rng(1)
    clips = smooth_clips(rng, 24)
    cfg3 = dataclasses.replace(FIT, z_dim=2, decoder_context=3)
    vae = CausalVideoVAE(cfg3, rngs=rngs())
    fit_linear_patch_codec(vae, [clips])
    encoder = np.asarray(vae.patch_in.kernel[...]).copy()
    x = jnp.asarray(clips, jnp.float32) / 127.5 - 1
    err = lambda v: float(jnp.mean(jnp.square(v.decode_raw(v.encode_moments(x)[0]) - x)))
    before = err(vae)
    fit = fit_patch_decoder(vae, [clips[:12], clips[12:]])
    assert fit["patches"] == 24 * 3 * 16 and fit["decoder_context"] == 3  # 3 latents of 4 x 4 positions
    assert fit["mse_after"] < 0.9 * fit["mse_before"]  # measured: 0.85
    assert err(vae) < 0.9 * before
    np.testing.assert_array_equal(vae.patch_in.kernel[...], encoder)
    one = CausalVideoVAE(dataclasses.replace(cfg3, decoder_context=1), rngs=rngs())
    fit_linear_patch_codec(one, [clips])
    pca = err(one)
    assert before == pytest.approx(pca, rel=1e-4)  # the components' fit leaves a wider decoder on its centre tap
    refit = fit_patch_decoder(one, [clips])
    assert refit["mse_after"] == pytest.approx(refit["mse_before"], rel=0.02) and err(one) == pytest.approx(pca, rel=0.02)
    with pytest.raises(ValueError, match="expected 'linear_patch'"):
        fit_patch_decoder(CausalVideoVAE(WorldModelConfig.test().vae, rngs=rngs()), [clips])


def test_relayout_patch_decoder_keeps_the_shared_taps():
    """Widening a decoder puts its taps at the centre of the new window (new taps zero); narrowing keeps the
    centre taps; widening then narrowing gives the kernel back."""
    from training.vae import relayout_patch_decoder

    rng = np.random.default_rng(0)
    one = rng.normal(size=(4, 6))
    three = relayout_patch_decoder(one, 4, 1, 3)
    assert three.shape == (36, 6)
    np.testing.assert_array_equal(three[16:20], one)
    assert not np.any(np.delete(three, np.s_[16:20], axis=0))
    wide = rng.normal(size=(36, 6))
    np.testing.assert_array_equal(relayout_patch_decoder(relayout_patch_decoder(wide, 4, 3, 5), 4, 5, 3), wide)
    np.testing.assert_array_equal(relayout_patch_decoder(three, 4, 3, 1), one)
