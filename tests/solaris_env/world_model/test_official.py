"""Official VAE / CLIP checkpoints (docs/model.md §9.3): the key mapping covers the reference trees exactly,
and an official-layout orbax checkpoint written from our modules loads back to identical outputs."""

import dataclasses
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model import official
from solaris_env.world_model.config import WorldModelConfig
from solaris_env.world_model.image_encoder import ImageEncoder
from solaris_env.world_model.vae import CausalVideoVAE

FIXTURES = pathlib.Path(__file__).parent / "fixtures"
SOLARIS = WorldModelConfig.solaris()
TEST = WorldModelConfig.test()
# the official layouts always have the VAE middle attention and CLIP's post_norm + head
VAE_CFG = dataclasses.replace(TEST.vae, middle_attention=True)
CLIP_CFG = dataclasses.replace(TEST.image_encoder, num_layers=2, blocks_applied=1, proj_dim=8)


def read_tree(name: str) -> dict[str, tuple[tuple[int, ...], str]]:
    tree = {}
    for line in (FIXTURES / name).read_text().splitlines():
        if line and not line.startswith("#"):
            key, shape, dtype = line.split()
            tree[key] = (tuple(int(d) for d in shape.strip("()").split(",") if d), dtype)
    return tree


def count(tree) -> int:
    return sum(int(np.prod(shape)) for shape, _ in tree.values())


def num_params(module) -> int:
    return sum(int(np.prod(p.shape)) for p in jax.tree.leaves(nnx.state(module, nnx.Param)))


def random_module(build, seed: int):
    """``build()`` with every parameter random (no init run): distinct values per leaf (init leaves
    ones/zeros that a swapped mapping would not reveal), bf16-representable so that the official dtypes
    (mostly bf16) round-trip losslessly."""
    graphdef, abstract = nnx.split(nnx.eval_shape(build))
    rng, flat = np.random.default_rng(seed), []
    for path, v in nnx.to_flat_state(abstract):  # numpy: no per-shape compiles
        x = rng.standard_normal(v.shape, np.float32)
        x = x * np.prod(v.shape[:-1]) ** -0.5 if len(v.shape) > 1 else (path[-1] in ("gamma", "scale")) + 0.1 * x
        flat.append((path, jnp.asarray(np.asarray(x, np.float32).astype(jnp.bfloat16), v.dtype)))
    return nnx.merge(graphdef, nnx.from_flat_state(flat))


encode_moments = nnx.jit(lambda vae, x: vae.encode_moments(x))
decode_raw = nnx.jit(lambda vae, z: vae.decode_raw(z))
encode_tokens = nnx.jit(lambda encoder, frames: encoder(frames))


def assert_same_params(a, b):
    fa, fb = official.flat_params(a), official.flat_params(b)
    assert fa.keys() == fb.keys()
    for key in fa:
        assert fa[key].dtype == fb[key].dtype, key
        np.testing.assert_array_equal(np.asarray(fa[key]), np.asarray(fb[key]), err_msg=key)


# ---------------------------------------------------------------------------------------------
# The mapping covers the reference trees (solaris preset, abstract only)
# ---------------------------------------------------------------------------------------------


def test_vae_mapping_is_the_reference_tree():
    fixture = read_tree("vae-param-tree.txt")
    assert official.official_vae_tree(SOLARIS.vae) == fixture  # keys, shapes and dtypes, incl. the 2 rng leaves
    assert count(fixture) == 126_892_533  # docs/model.md §2.3 (the key counts as one element)
    abstract = nnx.eval_shape(lambda: CausalVideoVAE(SOLARIS.vae, rngs=nnx.Rngs(0)))
    leaf_map = official.vae_leaf_map(SOLARIS.vae)
    assert len({o for o, _, _ in leaf_map.values()}) == len(leaf_map) == len(fixture) - 2  # a bijection
    assert num_params(abstract) == count(official.official_vae_tree(SOLARIS.vae, rng=False)) == 126_892_533 - 2


def test_clip_mapping_is_the_reference_tree():
    fixture = read_tree("clip-param-tree.txt")
    assert official.official_image_encoder_tree(SOLARIS.image_encoder) == fixture
    abstract = nnx.eval_shape(lambda: ImageEncoder(SOLARIS.image_encoder, rngs=nnx.Rngs(0)))
    leaf_map = official.image_encoder_leaf_map(SOLARIS.image_encoder)
    assert len({o for o, _, _ in leaf_map.values()}) == len(leaf_map) == len(fixture)
    assert num_params(abstract) == count(fixture) == 632_076_800


def test_configs_without_an_official_layout_are_rejected():
    with pytest.raises(ValueError, match="middle_attention"):
        official.official_vae_tree(TEST.vae)
    with pytest.raises(ValueError, match="proj_dim"):
        official.official_image_encoder_tree(TEST.image_encoder)


# ---------------------------------------------------------------------------------------------
# Round trips at reduced sizes: ours -> official layout -> orbax -> ours
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def vae():
    return random_module(lambda: CausalVideoVAE(VAE_CFG, rngs=nnx.Rngs(0)), seed=1)


@pytest.fixture(scope="module")
def clip():
    return random_module(lambda: ImageEncoder(CLIP_CFG, rngs=nnx.Rngs(0)), seed=2)


def test_converters_are_inverse_without_orbax(vae, clip):
    flat = official.to_official_vae(vae, official_dtypes=False)
    assert_same_params(official.from_official_vae(flat, VAE_CFG), vae)
    flat = official.to_official_image_encoder(clip, official_dtypes=False)
    assert_same_params(official.from_official_image_encoder(flat, CLIP_CFG), clip)


def test_official_dtypes_are_the_reference_ones(vae):
    flat = official.to_official_vae(vae)
    expected = official.official_vae_tree(VAE_CFG, rng=False)
    assert {k: str(v.dtype) for k, v in flat.items() if k in expected} == {k: d for k, (_, d) in expected.items()}
    assert flat["decoder/upsamples/2/conv/kernel"].dtype == jnp.float32  # temporal upsampler: f32 conv
    assert flat["decoder/upsamples/8/conv/kernel"].dtype == jnp.bfloat16  # spatial-only upsampler: bf16


@pytest.mark.parametrize("value_suffix,rng", [(True, True), (False, False)])
def test_vae_orbax_round_trip_gives_identical_outputs(vae, tmp_path, value_suffix, rng):
    flat = official.to_official_vae(vae, rng=rng)  # rng: the Rngs leaves as orbax writes them
    path = official.save_official(tmp_path / "vae.pt", flat, value_suffix=value_suffix)
    loaded = official.load_official_vae(path, VAE_CFG)
    assert_same_params(loaded, vae)
    video = jax.random.uniform(jax.random.key(3), (1, 5, TEST.frame_height, TEST.frame_width, 3), minval=-1, maxval=1)
    mu, logvar = encode_moments(vae, video)
    mu2, logvar2 = encode_moments(loaded, video)
    np.testing.assert_array_equal(np.asarray(mu2), np.asarray(mu))
    np.testing.assert_array_equal(np.asarray(logvar2), np.asarray(logvar))
    np.testing.assert_array_equal(np.asarray(decode_raw(loaded, mu)), np.asarray(decode_raw(vae, mu)))


def test_clip_orbax_round_trip_gives_identical_outputs(clip, tmp_path):
    path = official.save_official(tmp_path / "clip.pt", official.to_official_image_encoder(clip))
    loaded = official.load_official_image_encoder(path, CLIP_CFG)
    assert_same_params(loaded, clip)
    frames = jax.random.uniform(jax.random.key(4), (2, 40, 48, 3), minval=-1, maxval=1)
    np.testing.assert_array_equal(np.asarray(encode_tokens(loaded, frames)), np.asarray(encode_tokens(clip, frames)))


def test_mismatched_checkpoint_lists_every_difference(vae, tmp_path):
    flat = official.to_official_vae(vae)
    del flat["encoder/conv1/bias"]  # missing
    flat["encoder/extra/kernel"] = jnp.zeros((2,))  # unexpected
    flat["decoder/head/0/gamma"] = jnp.ones((8,))  # mis-shaped: the reference has (C, 1, 1, 1)
    path = official.save_official(tmp_path / "vae.pt", flat)
    with pytest.raises(ValueError) as err:
        official.load_official_vae(path, VAE_CFG)
    message = str(err.value)
    assert "missing keys (1): ['encoder/conv1/bias']" in message
    assert "unexpected keys (1): ['encoder/extra/kernel']" in message
    assert "decoder/head/0/gamma: expected (8, 1, 1, 1) float32, found (8,) float32" in message


def test_loading_a_directory_that_is_not_there_fails_clearly(tmp_path):
    with pytest.raises(ValueError, match="not an orbax directory"):
        official.load_official_image_encoder(tmp_path / "clip.pt", CLIP_CFG)
