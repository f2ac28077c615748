"""Checkpoints (docs/model.md §9): our safetensors + JSON format, and the official orbax directories
(``solaris.pt`` / ``vae.pt`` / ``clip.pt``) written here in the official trees and dtypes at reduced sizes
(the ``test`` preset with the layout switches the reference always has)."""

import ast
import dataclasses
import json
import os
import pathlib
import shutil
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model import checkpoint, official
from solaris_env.world_model.components import COMPONENTS, abstract_modules
from solaris_env.world_model.config import DiTConfig, WorldModelConfig, preset
from solaris_env.world_model.world_model import WorldModel

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from test_world_model import random_model  # noqa: E402  (shared random-weight builder)

TREE = pathlib.Path(__file__).parent / "fixtures" / "solaris-param-tree.txt"
CFG = WorldModelConfig.test()


@pytest.fixture(scope="module")
def model() -> WorldModel:
    return random_model(CFG, seed=3)


def _flat(model: WorldModel) -> dict:
    return {f"{name}/{k}": np.asarray(v) for name, state in zip(("dit", "vae", "image_encoder"), model.params)
            for k, v in checkpoint.flat_params(state).items()}


def _assert_same_params(a: WorldModel, b: WorldModel):
    fa, fb = _flat(a), _flat(b)
    assert fa.keys() == fb.keys()
    for key in fa:
        assert fa[key].dtype == fb[key].dtype, key
        np.testing.assert_array_equal(fa[key], fb[key], err_msg=key)


# ---------------------------------------------------------------------------------------------
# Config JSON
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["solaris", "tiny", "test"])
def test_config_json_round_trip(name):
    cfg = preset(name)
    data = json.loads(json.dumps(checkpoint.config_to_dict(cfg)))
    assert checkpoint.config_from_dict(data) == cfg


def test_config_round_trip_keeps_overrides():
    cfg = WorldModelConfig.test(num_players=3, dit=DiTConfig(dim=64, num_layers=2, num_heads=2, ffn_dim=128,
                                                              max_players=3, multiplayer="concat"))
    assert checkpoint.config_from_dict(checkpoint.config_to_dict(cfg)) == cfg


def test_config_from_dict_names_unknown_fields():
    data = checkpoint.config_to_dict(CFG)
    data["dit"]["bogus"] = 1
    with pytest.raises(ValueError, match=r"config.dit has unknown fields \['bogus'\]"):
        checkpoint.config_from_dict(data)


@pytest.mark.parametrize("field, kept, other", [("renoise_eta", 1.0, 0.0), ("action_guidance", 1.0, 1.5)])
def test_a_retired_field_loads_at_the_value_the_code_now_uses_and_fails_otherwise(field, kept, other):
    data = checkpoint.config_to_dict(CFG)
    data["sampler"][field] = kept  # written before the option was deleted, at the reference's value
    assert checkpoint.config_from_dict(data) == CFG
    data["sampler"][field] = other
    with pytest.raises(ValueError, match=rf"config.sampler.{field} = {other}: this option was removed"):
        checkpoint.config_from_dict(data)


# ---------------------------------------------------------------------------------------------
# Ours
# ---------------------------------------------------------------------------------------------


def test_ours_round_trip_is_bit_exact(model, tmp_path):
    path = tmp_path / "ckpt"
    model.save(path)
    assert sorted(os.listdir(path)) == ["config.json", "weights.safetensors"]
    meta = json.loads((path / "config.json").read_text())
    assert meta["format"] == checkpoint.FORMAT and meta["version"] == checkpoint.VERSION
    loaded = WorldModel.load(path)
    assert loaded.config == model.config
    _assert_same_params(model, loaded)


def test_save_overwrites_atomically_and_leaves_no_temporaries(model, tmp_path, monkeypatch):
    path = tmp_path / "ckpt"
    model.save(path)
    other = random_model(CFG, seed=4)
    other.save(path)  # replace an existing checkpoint
    assert os.listdir(tmp_path) == ["ckpt"]
    _assert_same_params(other, WorldModel.load(path))

    import safetensors.numpy

    def crash(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(safetensors.numpy, "save_file", crash)
    with pytest.raises(OSError, match="disk full"):
        model.save(path)
    assert os.listdir(tmp_path) == ["ckpt"]  # the temporary directory is gone
    _assert_same_params(other, WorldModel.load(path))  # the old checkpoint is intact


def test_load_lists_missing_unexpected_and_misshaped_keys_together(model, tmp_path):
    from safetensors.numpy import load_file, save_file

    path = tmp_path / "ckpt"
    model.save(path)
    tensors = load_file(str(path / checkpoint.WEIGHTS_FILE))
    del tensors["dit/head/head/bias"]
    del tensors["vae/conv1/kernel"]
    tensors["dit/extra/kernel"] = np.zeros((2, 2), np.float32)
    tensors["dit/patch_embedding/bias"] = np.zeros((3,), np.float32)
    tensors["image_encoder/cls_embedding"] = tensors["image_encoder/cls_embedding"].astype(np.float16)
    save_file(tensors, str(path / checkpoint.WEIGHTS_FILE))
    with pytest.raises(ValueError) as err:
        WorldModel.load(path)
    msg = str(err.value)
    assert "missing keys (2): ['dit/head/head/bias', 'vae/conv1/kernel']" in msg
    assert "unexpected keys (1): ['dit/extra/kernel']" in msg
    assert "mis-shaped keys (2)" in msg
    assert f"dit/patch_embedding/bias: expected ({CFG.dit.dim},) float32, found (3,) float32" in msg
    assert "image_encoder/cls_embedding: expected" in msg and "float16" in msg


def test_load_rejects_other_versions_and_unknown_directories(model, tmp_path):
    path = tmp_path / "ckpt"
    model.save(path)
    meta = json.loads((path / "config.json").read_text())
    meta["version"] = 99
    (path / "config.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="version 99"):
        WorldModel.load(path)
    with pytest.raises(ValueError, match="neither our checkpoint"):
        WorldModel.load(tmp_path / "nothing-here")


# the deleted temporal refiner as checkpoints written before its deletion hold it: a config block, its weights
LEGACY_REFINER_BLOCK = {"width": 4, "pool": 4, "action_dim": 25, "camera_shift": [0.8, 0.45]}
LEGACY_REFINER_TENSORS = {"vae/refiner/conv_in/kernel": np.ones((3, 3, 7, 4), np.float32),
                          "vae/refiner/conv_in/bias": np.zeros((4,), np.float32),
                          "vae/refiner/conv_mid/0/kernel": np.ones((3, 3, 4, 4), np.float32)}


def _legacy_checkpoint(model: WorldModel, path: pathlib.Path, block=LEGACY_REFINER_BLOCK, extra=None):
    """``model`` saved, then given the deleted refiner's config block (unless None) and weights, plus ``extra``."""
    from safetensors.numpy import load_file, save_file

    model.save(path)
    meta = json.loads((path / checkpoint.CONFIG_FILE).read_text())
    if block is not None:
        meta["config"]["vae"]["refiner"] = block
    (path / checkpoint.CONFIG_FILE).write_text(json.dumps(meta))
    tensors = load_file(str(path / checkpoint.WEIGHTS_FILE))
    save_file({**tensors, **LEGACY_REFINER_TENSORS, **(extra or {})}, str(path / checkpoint.WEIGHTS_FILE))
    return path


def test_a_legacy_refiner_checkpoint_loads_with_the_refiner_dropped_and_logged(model, tmp_path, caplog):
    """The one legacy rule: a config's ``vae.refiner`` block and the tensors ``vae/refiner/...`` are dropped, with
    one INFO line naming how many tensors went; every other parameter loads unchanged."""
    path = _legacy_checkpoint(model, tmp_path / "ckpt")
    assert checkpoint.read_config(path) == model.config
    with caplog.at_level("INFO", logger="solaris_env.world_model.checkpoint"):
        loaded = WorldModel.load(path)
    assert loaded.config == model.config
    _assert_same_params(model, loaded)
    lines = [r for r in caplog.records if r.name == "solaris_env.world_model.checkpoint"]
    assert len(lines) == 1 and lines[0].levelname == "INFO"
    assert "deleted temporal refiner" in lines[0].getMessage() and "3 weight tensors" in lines[0].getMessage()
    caplog.clear()
    model.save(tmp_path / "current")
    with caplog.at_level("INFO", logger="solaris_env.world_model.checkpoint"):
        WorldModel.load(tmp_path / "current")
    assert not caplog.records  # a current checkpoint: nothing dropped, nothing logged


def test_the_legacy_rule_drops_nothing_else(model, tmp_path):
    """An unrelated unknown tensor or config field still raises, as do refiner tensors without the config block
    and a refiner block anywhere but ``vae``."""
    path = _legacy_checkpoint(model, tmp_path / "extra", extra={"vae/decoder/extra/kernel": np.zeros((2,), np.float32)})
    with pytest.raises(ValueError, match=r"unexpected keys \(1\): \['vae/decoder/extra/kernel'\]"):
        WorldModel.load(path)
    path = _legacy_checkpoint(model, tmp_path / "no-block", block=None)
    with pytest.raises(ValueError, match=r"unexpected keys \(3\): \['vae/refiner/conv_in/bias'"):
        WorldModel.load(path)
    path = _legacy_checkpoint(model, tmp_path / "bad-block", block=32)
    with pytest.raises(ValueError, match=r"config.vae.refiner must be the deleted temporal refiner's object, got 32"):
        WorldModel.load(path)
    path = _legacy_checkpoint(model, tmp_path / "other-field")
    meta = json.loads((path / checkpoint.CONFIG_FILE).read_text())
    for section, field, cls in (("vae", "bogus", "VAEConfig"), ("dit", "refiner", "DiTConfig")):
        edited = json.loads(json.dumps(meta))
        edited["config"][section][field] = LEGACY_REFINER_BLOCK
        (path / checkpoint.CONFIG_FILE).write_text(json.dumps(edited))
        with pytest.raises(ValueError, match=rf"config.{section} has unknown fields \['{field}'\] for {cls}"):
            WorldModel.load(path)


def test_from_preset_initialises_and_round_trips(tmp_path):
    fresh = WorldModel.from_preset("test", seed=0)
    dit = fresh.modules()[0]
    assert not np.asarray(dit.head.head.kernel[...]).any()  # zero head (Wan init): v = 0 before training
    assert np.asarray(dit.blocks.modulation[...]).std() > 0
    fresh.save(tmp_path / "ckpt")
    _assert_same_params(fresh, WorldModel.load(tmp_path / "ckpt"))
    _assert_same_params(fresh, WorldModel.from_preset("test", seed=0))  # seeded


# ---------------------------------------------------------------------------------------------
# Official orbax layout
# ---------------------------------------------------------------------------------------------

# reduced sizes with an official layout: the reference VAE always has the middle attention and CLIP
# always has post_norm + head (``official``)
OFFICIAL_CFG = CFG.replace(vae=dataclasses.replace(CFG.vae, middle_attention=True),
                           image_encoder=dataclasses.replace(CFG.image_encoder, num_layers=2, proj_dim=8))


@pytest.fixture(scope="module")
def official_model() -> WorldModel:
    return random_model(OFFICIAL_CFG, seed=5)


def _official_keys() -> set:
    keys = set()
    for line in TREE.read_text().splitlines():
        if line.strip() and not line.startswith("TOTAL"):
            keys.add(ast.literal_eval(line)[0])
    return keys


def _official_dit(model: WorldModel) -> dict:
    """The DiT's flat state as the official file stores it: our tree, ``proj_mouse`` in bf16."""
    flat = dict(checkpoint.flat_params(model.params[0]))
    key = "blocks/action_model/proj_mouse/kernel"
    flat[key] = flat[key].astype(jnp.bfloat16)
    return flat


def _write_official(model: WorldModel, directory: pathlib.Path, value_suffix: bool = True, edit=None):
    """solaris.pt / vae.pt / clip.pt in the reference layouts and dtypes (``edit`` may tamper a flat tree)."""
    _, vae, encoder = model.modules()
    trees = {"solaris.pt": _official_dit(model), "vae.pt": official.to_official_vae(vae),
             "clip.pt": official.to_official_image_encoder(encoder)}
    for name, flat in trees.items():
        official.save_official(directory / name, edit(name, flat) if edit else flat, value_suffix=value_suffix)


def test_solaris_pt_saved_like_the_reference_has_the_reference_tree(official_model, tmp_path):
    """The reference saves ``nnx.split(model)[1]`` with orbax; its leaves end in ``value``."""
    import orbax.checkpoint as ocp

    checkpointer = ocp.StandardCheckpointer()
    checkpointer.save((tmp_path / "solaris.pt").resolve(), nnx.state(official_model.modules()[0]))
    checkpointer.wait_until_finished()
    meta = checkpointer.metadata((tmp_path / "solaris.pt").resolve()).item_metadata.tree
    assert all(path[-1].key == "value" for path, _ in jax.tree_util.tree_flatten_with_path(meta)[0])
    assert set(checkpoint._stored_specs(tmp_path / "solaris.pt")) == _official_keys()
    # the writer the other tests use produces the same stored tree
    official.save_official(tmp_path / "written.pt", _official_dit(official_model))
    written = checkpoint._stored_specs(tmp_path / "written.pt")
    assert set(written) == _official_keys()
    assert written["blocks/action_model/proj_mouse/kernel"][1] == "bfloat16"


@pytest.mark.parametrize("value_suffix", [True, False])
def test_official_orbax_round_trip_at_reduced_size(official_model, tmp_path, value_suffix):
    _write_official(official_model, tmp_path, value_suffix=value_suffix)
    loaded = WorldModel.load(tmp_path, config=OFFICIAL_CFG)
    assert loaded.config == OFFICIAL_CFG
    # what the official files hold: reference dtypes (bf16 proj_mouse, mostly-bf16 VAE), cast back to f32
    stored_dtype = {f"vae/{ours}": dtype for ours, (_, _, dtype) in official.vae_leaf_map(OFFICIAL_CFG.vae).items()}
    stored_dtype["dit/blocks/action_model/proj_mouse/kernel"] = "bfloat16"
    original, restored = _flat(official_model), _flat(loaded)
    assert original.keys() == restored.keys()
    for key, want in original.items():
        want = want.astype(stored_dtype.get(key, "float32")).astype(want.dtype)
        assert restored[key].dtype == original[key].dtype, key
        np.testing.assert_array_equal(restored[key], want, err_msg=key)


def test_official_load_lists_every_mismatch_of_every_file_in_one_error(official_model, tmp_path):
    def edit(name, flat):
        flat = dict(flat)
        if name == "solaris.pt":
            del flat["player_embed/embedding"]
            flat["extra_module/kernel"] = jnp.zeros((2, 2))
            flat["head/head/bias"] = jnp.zeros((5,))
        if name == "vae.pt":
            del flat["conv2/kernel"], flat["conv2/bias"]
        return flat

    _write_official(official_model, tmp_path, edit=edit)
    with pytest.raises(ValueError) as err:
        WorldModel.load(tmp_path, config=OFFICIAL_CFG)
    msg = str(err.value)
    dit_part, vae_part = msg.split("vae.pt does not match")
    assert "solaris.pt does not match" in dit_part
    assert "missing keys (1): ['player_embed/embedding']" in dit_part
    assert "unexpected keys (1): ['extra_module/kernel']" in dit_part
    assert f"head/head/bias: expected ({4 * OFFICIAL_CFG.out_channels},) float32, found (5,)" in dit_part
    assert "missing keys (2): ['conv2/bias', 'conv2/kernel']" in vae_part
    assert "clip.pt" not in msg


def test_official_directory_must_hold_all_three(official_model, tmp_path):
    _write_official(official_model, tmp_path)
    shutil.rmtree(tmp_path / "clip.pt")
    with pytest.raises(ValueError, match=r"lacks the orbax directories \['clip.pt'\]"):
        WorldModel.load(tmp_path, config=OFFICIAL_CFG)


def test_official_load_rejects_configs_without_an_official_layout(official_model, tmp_path):
    _write_official(official_model, tmp_path)
    with pytest.raises(ValueError, match="middle_attention=False"):
        WorldModel.load(tmp_path, config=CFG)  # the test preset's VAE has no middle attention


def test_solaris_preset_dit_tree_is_the_reference_tree():
    """The default official config is the solaris preset; its DiT tree is the reference tree."""
    dit = abstract_modules(WorldModelConfig.solaris())[0]
    assert set(checkpoint.flat_params(nnx.state(dit))) == _official_keys()


def test_float16_storage_round_trips_within_half_precision(tmp_path):
    """``save(storage_dtype="float16")`` halves the file and loads back as float32 close to the original;
    out-of-range values are an error."""
    import numpy as np

    from solaris_env.world_model import checkpoint

    model = WorldModel.from_preset("test", seed=0)
    params = dict(zip(COMPONENTS, model.params))
    checkpoint.save(tmp_path / "f32", model.config, params)
    checkpoint.save(tmp_path / "f16", model.config, params, storage_dtype="float16")
    size = lambda d: (d / checkpoint.WEIGHTS_FILE).stat().st_size
    assert size(tmp_path / "f16") < 0.6 * size(tmp_path / "f32")
    loaded = WorldModel.load(tmp_path / "f16")
    for a, b in zip(model.params, loaded.params):
        for key, value in checkpoint.flat_params(a).items():
            got = checkpoint.flat_params(b)[key]
            assert got.dtype == value.dtype
            np.testing.assert_allclose(np.asarray(got), np.asarray(value), rtol=1e-3, atol=1e-4)
    with pytest.raises(ValueError, match="storage_dtype"):
        checkpoint.save(tmp_path / "bad", model.config, params, storage_dtype="int8")


def test_a_damaged_checkpoint_names_the_file_and_what_is_wrong(tmp_path):
    """A broken config.json or a truncated weights file gives a ValueError naming the file, not a bare
    JSONDecodeError or safetensors' header error."""
    import shutil

    import pytest as _pytest

    from solaris_env.world_model import checkpoint as ckpt
    from solaris_env.world_model.world_model import WorldModel

    src = tmp_path / "model"
    WorldModel.from_preset("test", seed=0).save(src)
    broken = tmp_path / "broken_json"
    shutil.copytree(src, broken)
    (broken / "config.json").write_text('{"format": ')
    with _pytest.raises(ValueError, match=r"broken_json/config\.json: not valid JSON .*line 1"):
        ckpt.load(broken)
    (broken / "config.json").write_text("[1, 2]")
    with _pytest.raises(ValueError, match=r"config\.json: expected a JSON object"):
        ckpt.load(broken)
    truncated = tmp_path / "truncated"
    shutil.copytree(src, truncated)
    weights = next(truncated.glob("weights*.safetensors"))
    weights.write_bytes(weights.read_bytes()[:100])
    with _pytest.raises(ValueError, match=rf"{weights.name}: not a readable safetensors file .*truncated or corrupt"):
        ckpt.load(truncated)
