"""``training.surgery``: ``official_dit`` (``solaris-train official-dit``: the start of issue 23's control row),
``fresh_dit`` (``solaris-train fresh-dit``) and ``with_vae`` (``solaris-train with-vae``)."""

import dataclasses

import jax
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model.config import preset
from solaris_env.world_model.world_model import WorldModel
from training import cli


def _leaves(state):
    return [np.asarray(x) for x in jax.tree.leaves(state)]


def test_official_dit_keeps_the_autoencoder_and_starts_a_fresh_official_dit(tmp_path):
    base = preset("test")
    ours = base.replace(dit=dataclasses.replace(base.dit, camera_warp=(0.1, 0.06), walk_warp=0.1, previous_skip=True,
                                                warp_geometry="rotation", partner_map=10.0),
                        action=dataclasses.replace(base.action, mouse_input_gain=10.0),
                        sampler=dataclasses.replace(base.sampler, noise_warp=0.9, still_memory=0.5))  # as shipped
    WorldModel.from_config(ours, seed=3).save(tmp_path / "ours")

    assert cli.main(["official-dit", str(tmp_path / "ours"), "--out", str(tmp_path / "control"), "--seed", "5"]) == 0
    src, control = WorldModel.load(tmp_path / "ours"), WorldModel.load(tmp_path / "control")
    cfg = control.config
    assert cfg.dit.camera_warp == (0.0, 0.0) and not cfg.dit.camera_warp_enabled and cfg.dit.walk_warp == 0.0
    assert cfg.dit.partner_map == 0.0 and cfg.partner_channels == 0
    assert cfg.dit.warp_geometry == "shift"  # the rotation reads its field of view from the warp it no longer has
    assert not cfg.dit.previous_skip and "skip_gate" not in control.params[0]
    assert cfg.action.mouse_input_gain == 1.0
    assert cfg.sampler.noise_warp == 0.0 and cfg.sampler.still_memory == 0.0  # both need the camera warp
    # every other field is the source's: only our options changed
    assert cfg.replace(dit=ours.dit, action=ours.action, sampler=ours.sampler) == src.config
    # the autoencoder and the image encoder are the source's, bit for bit
    for mine, theirs in zip(control.params[1:], src.params[1:]):
        assert all(np.array_equal(a, b) for a, b in zip(_leaves(mine), _leaves(theirs)))
    # the DiT is a fresh one of the official layout: the random initialisation of that config and seed
    fresh = WorldModel.from_config(cfg, seed=5).params[0]
    assert all(np.array_equal(a, b) for a, b in zip(_leaves(control.params[0]), _leaves(fresh)))
    in_channels = control.params[0]["patch_embedding"]["kernel"].get_value().shape[-2]
    assert in_channels == cfg.in_channels < ours.patch_in_channels  # no warped-latent rows


def test_official_dit_names_a_missing_model(tmp_path):
    import pytest

    from training.surgery import official_dit

    with pytest.raises(FileNotFoundError, match="holds no model"):
        official_dit(tmp_path / "nothing", tmp_path / "control")


def test_with_vae_takes_the_whole_vae_and_keeps_the_dit_and_image_encoder(tmp_path):
    import pytest

    base = preset("test")
    codec = base.replace(vae=dataclasses.replace(base.vae, codec="linear_patch", latent_mean=(0.5,) * 4,
                                                 latent_std=(2.0,) * 4))
    WorldModel.from_config(base, seed=1).save(tmp_path / "model")
    WorldModel.from_config(codec, seed=2).save(tmp_path / "codec")
    assert cli.main(["with-vae", str(tmp_path / "model"), "--vae-from", str(tmp_path / "codec"),
                     "--out", str(tmp_path / "new")]) == 0
    src, donor, new = (WorldModel.load(tmp_path / name) for name in ("model", "codec", "new"))
    assert new.config == src.config.replace(vae=donor.config.vae)  # the donor's layout and latent statistics
    for got, want in [(new.params[0], src.params[0]), (new.params[1], donor.params[1]), (new.params[2], src.params[2])]:
        assert all(np.array_equal(a, b) for a, b in zip(_leaves(got), _leaves(want)))
    # the DiT needs latents of its own shape
    other = base.replace(vae=dataclasses.replace(base.vae, z_dim=8))
    WorldModel.from_config(other, seed=2).save(tmp_path / "z8")
    with pytest.raises(SystemExit, match="the DiT needs the same latent shape"):
        cli.main(["with-vae", str(tmp_path / "model"), "--vae-from", str(tmp_path / "z8"),
                  "--out", str(tmp_path / "x")])


def test_decoder_context_refits_the_decoder_and_keeps_everything_else(tmp_path, tiny_duet):
    """`solaris-train decoder-context`: the linear patch codec's decoder reads 3x3 latent positions, fitted to the
    data; the encoder, the latent statistics, the DiT and the image encoder are the source's bit for bit, and
    on the data's clips it reconstructs no worse than the source's one-position decoder."""
    from training.vae import fit_linear_patch_codec

    cfg = preset("test")
    cfg = cfg.replace(vae=dataclasses.replace(cfg.vae, codec="linear_patch"))
    src = WorldModel.from_config(cfg, seed=0)
    dit, vae, encoder = src.modules()
    rng = np.random.default_rng(0)
    fit_linear_patch_codec(vae, [rng.integers(0, 256, (64, 9, 32, 32, 3), dtype=np.uint8)])
    WorldModel(cfg, dit, vae, encoder).save(tmp_path / "src")
    assert cli.main(["decoder-context", str(tmp_path / "src"), "--context", "3", "--data", str(tiny_duet),
                     "--clips", "16", "--out", str(tmp_path / "dst")]) == 0
    a, b = WorldModel.load(tmp_path / "src"), WorldModel.load(tmp_path / "dst")
    assert b.config.vae.decoder_context == 3 and b.config.replace(vae=a.config.vae) == a.config
    (dit_a, vae_a, enc_a), (dit_b, vae_b, enc_b) = a.modules(), b.modules()
    for x, y in ((dit_a, dit_b), (enc_a, enc_b)):
        for u, v in zip(jax.tree.leaves(nnx.state(x)), jax.tree.leaves(nnx.state(y))):
            np.testing.assert_array_equal(np.asarray(u), np.asarray(v))
    np.testing.assert_array_equal(vae_a.patch_in.kernel[...], vae_b.patch_in.kernel[...])
    assert vae_b.patch_out.kernel[...].shape[0] == 9 * cfg.vae.z_dim

    from training.decoder_context import with_decoder_context
    _, fit = with_decoder_context(tmp_path / "src", tmp_path / "dst2", 3, tiny_duet, clips=16)
    assert fit["mse_after"] <= fit["mse_before"]
    with pytest.raises(ValueError, match="decoder-context needs 'linear_patch'"):
        WorldModel.from_preset("test", seed=0).save(tmp_path / "wan")
        with_decoder_context(tmp_path / "wan", tmp_path / "dst3", 3, tiny_duet, clips=16)


def test_fresh_dit_changes_the_sizes_and_keeps_every_option_and_the_autoencoder(tmp_path):
    base = preset("test")
    ours = base.replace(dit=dataclasses.replace(base.dit, camera_warp=(0.1, 0.06), walk_warp=0.1, previous_skip=True,
                                                warp_geometry="rotation", partner_map=10.0),
                        sampler=dataclasses.replace(base.sampler, noise_warp=0.9, still_memory=0.5))
    WorldModel.from_config(ours, seed=3).save(tmp_path / "ours")
    src = WorldModel.load(tmp_path / "ours")
    old = src.config
    patch = old.dit.patch_size[1] // 2 or 1
    dim = 2 * old.dit.dim
    argv = ["fresh-dit", str(tmp_path / "ours"), "--out", str(tmp_path / "fresh"), "--patch", str(patch),
            "--dim", str(dim), "--layers", "1", "--seed", "4"]
    assert cli.main(argv) == 0
    fresh = WorldModel.load(tmp_path / "fresh")
    cfg = fresh.config
    assert cfg.dit.patch_size == (old.dit.patch_size[0], patch, patch)
    assert (cfg.dit.dim, cfg.dit.num_layers, cfg.dit.head_dim) == (dim, 1, old.dit.head_dim)
    assert cfg.dit.ffn_dim * old.dit.dim == old.dit.ffn_dim * dim
    assert cfg.action.mouse_hidden_dim == cfg.action.keyboard_hidden_dim == dim
    assert cfg.action.head_dim == old.action.head_dim and cfg.action.num_action_blocks == 1
    # every option, the codec and the sampler are the source's: only the DiT's and action module's sizes changed
    assert cfg.replace(dit=old.dit, action=old.action) == old
    assert dataclasses.replace(cfg.dit, dim=old.dit.dim, num_heads=old.dit.num_heads, num_layers=old.dit.num_layers,
                               ffn_dim=old.dit.ffn_dim, patch_size=old.dit.patch_size) == old.dit
    for mine, theirs in zip(fresh.params[1:], src.params[1:]):
        assert all(np.array_equal(a, b) for a, b in zip(_leaves(mine), _leaves(theirs)))
    init = WorldModel.from_config(cfg, seed=4).params[0]
    assert all(np.array_equal(a, b) for a, b in zip(_leaves(fresh.params[0]), _leaves(init)))


@pytest.mark.parametrize("kwargs, field", [({"patch": 3}, "patch=3"), ({"dim": 100}, "dim=100"),
                                           ({"num_layers": 0}, "num_layers=0")])
def test_fresh_dit_names_the_bad_size(tmp_path, kwargs, field):
    from training.surgery import fresh_dit

    WorldModel.from_config(preset("test"), seed=0).save(tmp_path / "ours")
    with pytest.raises(ValueError, match=field):
        fresh_dit(tmp_path / "ours", tmp_path / "fresh", **kwargs)
