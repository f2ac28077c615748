"""Stage and sprint configs that extend another config (``training.config_files``)."""

import dataclasses
import json

import pytest

from training.config_files import merge, read_json_config
from training.sprint import SprintConfig
from training.stage_config import load_stage_config


def test_merge_overrides_leaves_and_merges_objects():
    base = {"a": 1, "b": {"x": 1, "y": {"p": 1, "q": 2}}, "c": [1, 2]}
    out = merge(base, {"b": {"y": {"q": 3}, "z": 4}, "c": [3]})
    assert out == {"a": 1, "b": {"x": 1, "y": {"p": 1, "q": 3}, "z": 4}, "c": [3]}
    assert base["b"]["y"]["q"] == 2  # the base is not modified


def test_extends_chain_resolves_in_order(tmp_path):
    (tmp_path / "a.json").write_text(json.dumps({"preset": "a", "vae": {"steps": 1, "lr": 0.1}, "seed": 0}))
    (tmp_path / "b.json").write_text(json.dumps({"extends": "a", "preset": "b", "vae": {"steps": 2}}))
    (tmp_path / "c.json").write_text(json.dumps({"extends": "b", "seed": 7}))
    assert read_json_config(tmp_path / "c.json") == {"preset": "b", "vae": {"steps": 2, "lr": 0.1}, "seed": 7}


def test_cycles_missing_bases_and_bad_names_are_named(tmp_path):
    (tmp_path / "x.json").write_text(json.dumps({"extends": "y"}))
    (tmp_path / "y.json").write_text(json.dumps({"extends": "x"}))
    with pytest.raises(ValueError, match="extends' cycle: x.json -> y.json -> x.json"):
        read_json_config(tmp_path / "x.json")
    (tmp_path / "m.json").write_text(json.dumps({"extends": "nothere"}))
    with pytest.raises(FileNotFoundError, match="nothere.json .extended by"):
        read_json_config(tmp_path / "m.json")
    (tmp_path / "p.json").write_text(json.dumps({"extends": "../a.json"}))
    with pytest.raises(ValueError, match="extends must be the name of a config"):
        read_json_config(tmp_path / "p.json")


def test_tiny16_trains_like_tiny():
    tiny, tiny16 = load_stage_config("tiny"), load_stage_config("tiny16")
    assert tiny16.preset == "tiny16" and dataclasses.replace(tiny16, preset="tiny") == tiny
    sprint = SprintConfig.load("tiny16")
    assert (sprint.preset, sprint.stage_config) == ("tiny16", "tiny16")
    # tiny16's VAE is a linear patch codec, fitted in closed form: almost all of the time goes to stage 3
    assert sprint.fractions["vae"] < 0.1 and sprint.fractions["mp-causal"] > 0.9
    assert {s for s, share in sprint.fractions_from_init.items() if share > 0} == {"mp-causal"}
    tiny_devices = SprintConfig.load("tiny").devices
    assert sprint.devices["cpu"] == tiny_devices["cpu"]
    assert sprint.devices["gpu"].stages == tiny_devices["gpu"].stages
