"""VAE stages: the full VAE step learns; the vae-decoder step trains only the decoder side."""

import dataclasses

import jax
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model.world_model import WorldModel
from training import vae as V
from training.step import TrainState, make_optimizer


@pytest.fixture(scope="module")
def vae_and_clip():
    model = WorldModel.from_preset("test", seed=0)
    _, vae, _ = model.modules()
    k = model.frames_per_step
    rng = np.random.default_rng(0)
    # a smooth moving gradient (learnable in a few steps), 2 clips of 1 + 2k frames
    t = np.arange(1 + 2 * k)[:, None, None]
    y, x = np.mgrid[0:32, 0:32]
    base = (x[None] + 2 * t + y[None]) % 64 * 4
    clip = np.stack([base, 255 - base, (base // 2 + 60)], axis=-1).astype(np.uint8)
    clips = np.stack([clip, np.roll(clip, 5, axis=2)]) + rng.integers(0, 3, (2,) + clip.shape, dtype=np.uint8)
    return vae, clips, k


def _run(step_fn, state, clips, n):
    losses = []
    for _ in range(n):
        state, m = step_fn(state, clips)
        losses.append(float(m["loss"]))
    return state, losses


def test_vae_step_reduces_loss(vae_and_clip):
    vae, clips, _ = vae_and_clip
    tx = make_optimizer(3e-3)
    graphdef, state = TrainState.create(vae, tx, rng=0)
    state, losses = _run(V.make_vae_train_step(graphdef, tx, V.VAELossWeights()), state, clips, 12)
    assert np.isfinite(losses).all() and min(losses[-3:]) < 0.7 * losses[0]


def test_decoder_step_freezes_the_encoder_side(vae_and_clip):
    vae, clips, _ = vae_and_clip
    params = nnx.state(vae, nnx.Param)
    tx = V.make_decoder_optimizer(3e-3, params)
    graphdef, state = TrainState.create(vae, tx, rng=0)
    before = jax.tree.map(np.asarray, state.params)
    state, losses = _run(V.make_decoder_train_step(graphdef, tx, V.VAELossWeights()), state, clips, 12)
    after = jax.tree.map(np.asarray, state.params)
    assert min(losses[-3:]) < 0.8 * losses[0]
    for name in before:
        same = all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(before[name]), jax.tree.leaves(after[name])))
        assert same == (name not in V.DECODER_MODULES), name  # encoder side untouched, decoder side trained


def test_psnr_per_latent_step_spans():
    k = 4
    gt = np.zeros((1, 1 + 2 * k, 2, 2, 3), np.uint8)
    rec = gt.copy()
    rec[:, 1 + k:] = 10  # latent 2 wrong, latents 0 and 1 exact
    p = V.psnr_per_latent_step(rec, gt, k)
    assert len(p) == 3 and p[0] > 100 and p[1] > 100 and abs(p[2] - 10 * np.log10(255 ** 2 / 100)) < 1e-9


def _perturbed(model, module: str, seed: int) -> WorldModel:
    """A copy of ``model`` whose VAE ``module`` parameters are shifted."""
    dit, vae, enc = model.modules()
    graphdef, params, rest = nnx.split(vae, nnx.Param, ...)
    params = jax.tree.map(lambda x: x, params)
    params[module] = jax.tree.map(lambda x: x + 0.01 * (seed + 1), params[module])
    return WorldModel(model.config, dit, nnx.merge(graphdef, params, rest), enc)


def test_with_decoder_takes_the_decoder_and_refuses_another_encoder(tmp_path):
    from training.surgery import with_decoder

    base = WorldModel.from_preset("test", seed=0)
    base.save(tmp_path / "base")
    _perturbed(base, "decoder", 0).save(tmp_path / "donor")
    out = with_decoder(tmp_path / "base", tmp_path / "donor", tmp_path / "out")
    got, donor = WorldModel.load(out), WorldModel.load(tmp_path / "donor")
    leaves = lambda m, i: jax.tree.leaves(nnx.state(m.modules()[i], nnx.Param))
    assert all(np.array_equal(a, b) for a, b in zip(leaves(got, 1), leaves(donor, 1)))  # the donor's VAE
    assert all(np.array_equal(a, b) for a, b in zip(leaves(got, 0), leaves(base, 0)))  # the base's DiT

    _perturbed(base, "encoder", 1).save(tmp_path / "other")
    with pytest.raises(ValueError, match="'encoder' differs"):
        with_decoder(tmp_path / "base", tmp_path / "other", tmp_path / "out2")


def test_relayout_decoder_keeps_the_latent_space_and_warm_starts_the_decoder(tmp_path):
    """A trained VAE rebuilt with another decoder layout (vae-decoder stage): the encoder side is copied bit
    for bit, decoder leaves of the same path and shape are copied, the rest (the new head) is fresh; and
    with_decoder puts that decoder and its layout into a model of the same encoder."""
    from training.surgery import relayout_decoder, with_decoder

    base = WorldModel.from_preset("test", seed=0)
    cfg = base.config
    target = cfg.vae.with_decoder_layout(dataclasses.replace(cfg.vae, decoder_head_upscale=2))
    old_vae = base.modules()[1]
    new_vae, copied = relayout_decoder(old_vae, target, seed=1)
    old, new = (dict(nnx.to_flat_state(nnx.state(v, nnx.Param))) for v in (old_vae, new_vae))
    for path, var in new.items():
        name = "/".join(map(str, path))
        if path[0] in ("encoder", "conv1"):
            assert np.array_equal(var.get_value(), old[path].get_value()), name
        if name in copied:
            assert np.array_equal(var.get_value(), old[path].get_value()), name
    assert "decoder/conv_in/kernel" in copied and "decoder/head/conv/kernel" not in copied
    assert new[("decoder", "head", "conv", "kernel")].get_value().shape[-1] == 12

    base.save(tmp_path / "base")
    WorldModel(cfg.replace(vae=target), base.modules()[0], new_vae, base.modules()[2]).save(tmp_path / "donor")
    out = WorldModel.load(with_decoder(tmp_path / "base", tmp_path / "donor", tmp_path / "out"))
    assert out.config.vae == target and out.config.dit == cfg.dit
    frames, _ = out.step(out.init(np.zeros((1, 2) + out.frame_shape, np.uint8), 0), np.zeros((1, 2, 4, 25)))
    assert frames.shape == (1, 2, 4) + out.frame_shape
