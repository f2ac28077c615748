"""The stage configs as frozen, validated dataclasses (``training.stage_config``; docs/training.md "Stage
configs"): the shipped files and the sprints' overrides validate, errors name the stage (or the ``collect`` /
``all`` block), the field and what it takes, and the defaults are those the code used before it had dataclasses."""

import argparse
import dataclasses
import json

import pytest

from training.cli import budget_settings
from training.config_files import read_json_config
from training.sprint import SprintConfig, stage_blocks
from training.stage_config import (
    CONFIG_DIR,
    ELASTIC_STAGES,
    STAGE_CONFIGS,
    STAGES,
    AllConfig,
    CollectConfig,
    FlowStageConfig,
    SelfForcingStageConfig,
    TrainingConfig,
    VAEDecoderStageConfig,
    VAEStageConfig,
    load_stage_config,
)

# every shipped stage config and sprint config, those with "extends" included
PRESETS = sorted(p.stem for p in CONFIG_DIR.glob("*.json") if not p.stem.startswith("sprint-"))
SPRINT_PRESETS = sorted(p.stem.removeprefix("sprint-") for p in CONFIG_DIR.glob("sprint-*.json"))
LOOP = {"steps": 3, "batch_size": 2, "num_frames": 9, "log_every": 1, "ckpt_every": 1}


@pytest.mark.parametrize("preset", PRESETS)
def test_every_shipped_config_validates_and_round_trips(preset):
    cfg = load_stage_config(preset)
    raw = read_json_config(CONFIG_DIR / f"{preset}.json")
    # "preset" names the model layout; a config that extends another (t16mix extends tiny16) trains its layout
    assert cfg.preset == raw["preset"] and set(cfg.stages) == set(STAGES)
    if "extends" not in json.loads((CONFIG_DIR / f"{preset}.json").read_text()):
        assert cfg.preset == preset
    assert all(isinstance(cfg.stages[s], STAGE_CONFIGS[s]) for s in cfg.stages)
    assert TrainingConfig.from_dict(cfg.to_dict(), preset) == cfg
    for stage in STAGE_CONFIGS:  # every key the file sets is a field, holding the file's value
        block = json.loads(json.dumps(dataclasses.asdict(cfg.stages[stage])))
        for key, value in raw[stage].items():
            got = {k: block[key][k] for k in value} if isinstance(value, dict) else block[key]
            assert got == value, (stage, key)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.stages["mp-causal"].lr = 1.0


def test_the_shipped_configs_include_those_that_extend_another():
    assert {"tiny", "tiny16", "test"} <= set(PRESETS) and {"tiny", "tiny16", "test"} <= set(SPRINT_PRESETS)
    assert any("extends" in json.loads((CONFIG_DIR / f"{p}.json").read_text()) for p in PRESETS)
    assert any("extends" in json.loads((CONFIG_DIR / f"sprint-{p}.json").read_text()) for p in SPRINT_PRESETS)


@pytest.mark.parametrize("preset", PRESETS)
def test_the_collect_and_all_blocks_are_typed_and_hold_the_files_values(preset):
    cfg = load_stage_config(preset)
    raw = read_json_config(CONFIG_DIR / f"{preset}.json")
    assert isinstance(cfg.all, AllConfig)
    assert isinstance(cfg.collect, CollectConfig) if "collect" in raw else cfg.collect is None
    for name in ("collect", "all"):
        for key, value in raw.get(name, {}).items():
            got = getattr(getattr(cfg, name), key)
            assert (list(got) if isinstance(got, tuple) else got) == value, (name, key)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.all.reserve_min = 1.0


@pytest.mark.parametrize("preset", SPRINT_PRESETS)
def test_every_sprint_config_loads_with_a_typed_collect_block(preset):
    sprint = SprintConfig.load(preset)
    raw = read_json_config(CONFIG_DIR / f"sprint-{preset}.json")
    assert isinstance(sprint.collect, CollectConfig)
    assert {k: getattr(sprint.collect, k) for k in raw["collect"]} == raw["collect"]


@pytest.mark.parametrize("preset", SPRINT_PRESETS)
def test_every_sprint_override_is_a_field_and_validates(preset):
    sprint = SprintConfig.load(preset)
    for platform in sprint.devices:
        cfg = stage_blocks(sprint, sprint.device(platform))
        for stage, override in sprint.device(platform).stages.items():
            block = dataclasses.asdict(cfg.stages[stage])
            assert {k: block[k] for k in override} == override, (platform, stage)
        assert cfg.stages["mp-causal"].steps >= 10**9 and cfg.stages["mp-causal"].ckpt_every == 0
        assert cfg.stages["mp-causal"].rescan_s == sprint.rescan_s
        assert not hasattr(cfg.stages["vae"], "test_every")  # settings only where the stage has the key


def _tiny_with(stage: str, **changes) -> dict:
    data = load_stage_config("tiny").to_dict()
    data[stage] = {**data[stage], **changes}
    return data


@pytest.mark.parametrize("stage, changes, message", [
    ("mp-causal", {"batch": 4}, r"\[mp-causal\]: unknown keys \['batch'\]; FlowStageConfig takes"),
    ("mp-causal", {"batch_size": 0}, r"\[mp-causal\]: batch_size must be an int >= 1, got 0"),
    ("mp-causal", {"steps": 2.5}, r"\[mp-causal\]: steps must be an int >= 1, got 2.5"),
    ("mp-causal", {"steps": True}, r"\[mp-causal\]: steps must be an int >= 1, got True"),
    ("mp-causal", {"ema_decay": 1.0}, r"\[mp-causal\]: ema_decay must be a number in \[0, 1\), got 1.0"),
    ("sp", {"lr": "fast"}, r"\[sp\]: lr must be a number > 0, got 'fast'"),
    ("vae", {"ckpt_every": -1}, r"\[vae\]: ckpt_every must be an int >= 0, got -1"),
    ("vae-decoder", {"rescan_s": "often"}, r"\[vae-decoder\]: rescan_s must be a number >= 0 or null, got 'often'"),
    ("vae", {"test_every": 2}, r"\[vae\]: unknown keys \['test_every'\]"),
    ("self-forcing", {"generator": "fast"}, r"\[self-forcing\]: generator must be one of \('checkpointed', 'naive'\)"),
])
def test_a_bad_key_or_value_names_the_stage_the_field_and_what_it_takes(stage, changes, message):
    with pytest.raises(ValueError, match=message):
        TrainingConfig.from_dict(_tiny_with(stage, **changes), "tiny.json")


@pytest.mark.parametrize("block, value, message", [
    ("collect", {"instance": 10}, (r"tiny.json \[collect\]: unknown keys \['instance'\]; CollectConfig takes "
                                   r"\['episodes', 'instances', 'seed', 'test_fraction', 'time_of_day', 'types', "
                                   r"'world'\]")),
    ("collect", {"episodes": "many"}, r"tiny.json \[collect\]: episodes must be an int >= 1, got 'many'"),
    ("collect", {"episodes": 0}, r"\[collect\]: episodes must be an int >= 1, got 0"),
    ("collect", {"world": "moon"}, r"\[collect\]: world must be one of \('flat', 'normal', 'mixed'\), got 'moon'"),
    ("collect", {"seed": 1.5}, r"\[collect\]: seed must be an int >= 0, got 1.5"),
    ("collect", {"test_fraction": 1.5}, r"\[collect\]: test_fraction must be a number in \[0, 1\], got 1.5"),
    ("collect", {"instances": 10.0}, r"\[collect\]: instances must be an int >= 1 or null, got 10.0"),
    ("collect", {"types": "lookAround"},
     r"\[collect\]: types must be a non-empty list of strings or null, got 'lookAround'"),
    ("collect", {"types": [1]}, r"\[collect\]: types must be a non-empty list of strings or null, got \[1\]"),
    ("all", {"time_budget": 150}, (r"tiny.json \[all\]: unknown keys \['time_budget'\]; AllConfig takes "
                                   r"\['elastic_stage', 'reserve_min', 'time_budget_min'\]")),
    ("all", {"time_budget_min": "150"}, r"\[all\]: time_budget_min must be a number >= 0 or null, got '150'"),
    ("all", {"time_budget_min": -1}, r"\[all\]: time_budget_min must be a number >= 0 or null, got -1"),
    ("all", {"elastic_stage": "self-forcing"},
     r"\[all\]: elastic_stage must be one of \('sp', 'mp-bidirectional', 'mp-causal'\), got 'self-forcing'"),
    ("all", {"reserve_min": True}, r"\[all\]: reserve_min must be a number >= 0, got True"),
    ("all", {"reserve_min": -1}, r"\[all\]: reserve_min must be a number >= 0, got -1"),
])
def test_a_bad_collect_or_all_key_names_the_block_the_field_and_what_it_takes(block, value, message):
    data = load_stage_config("tiny").to_dict()
    with pytest.raises(ValueError, match=message):
        TrainingConfig.from_dict({**data, block: {**data[block], **value}}, "tiny.json")


@pytest.mark.parametrize("block", ["collect", "all"])
def test_a_collect_or_all_block_that_is_not_an_object_is_named(block):
    data = load_stage_config("tiny").to_dict()
    with pytest.raises(ValueError, match=rf"tiny.json \[{block}\]: expected an object with the keys of"):
        TrainingConfig.from_dict({**data, block: [1, 2]}, "tiny.json")
    del data["collect"]["episodes"]
    with pytest.raises(ValueError, match=r"tiny.json \[collect\]: missing keys \['episodes'\]"):
        TrainingConfig.from_dict(data, "tiny.json")


def test_a_bad_collect_or_all_block_in_a_file_names_the_file(tmp_path):
    data = load_stage_config("tiny").to_dict()
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**data, "all": {"elastic_stage": "mp-causl"}}))
    with pytest.raises(ValueError, match=r"bad.json \[all\]: elastic_stage must be one of"):
        load_stage_config("tiny", path)
    (tmp_path / "child.json").write_text(json.dumps({"extends": "bad", "collect": {"worlds": "flat"}}))
    with pytest.raises(ValueError, match=r"child.json \[collect\]: unknown keys \['worlds'\]"):
        load_stage_config("tiny", tmp_path / "child.json")


def test_a_bad_sprint_collect_block_is_named():
    data = read_json_config(CONFIG_DIR / "sprint-test.json")
    with pytest.raises(ValueError, match=r"sprint config: collect: unknown keys \['instance'\]"):
        SprintConfig.from_dict({**data, "collect": {**data["collect"], "instance": 3}})
    with pytest.raises(ValueError, match=r"sprint config: collect: world must be one of"):
        SprintConfig.from_dict({**data, "collect": {**data["collect"], "world": "Flat"}})


def test_file_level_errors_name_the_file(tmp_path):
    data = load_stage_config("tiny").to_dict()
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**data, "mp-causal": {**data["mp-causal"], "lr": -1}}))
    with pytest.raises(ValueError, match=r"bad.json \[mp-causal\]: lr must be a number > 0, got -1"):
        load_stage_config("tiny", path)
    with pytest.raises(ValueError, match=r"unknown keys \['stage3'\]"):
        TrainingConfig.from_dict({**data, "stage3": {}}, "x.json")
    with pytest.raises(ValueError, match=r"x.json: missing keys \['self-forcing'\]"):
        TrainingConfig.from_dict({k: v for k, v in data.items() if k != "self-forcing"}, "x.json")
    del data["mp-causal"]["lr"]
    with pytest.raises(ValueError, match=r"\[mp-causal\]: missing keys \['lr'\]"):
        TrainingConfig.from_dict(data, "x.json")
    with pytest.raises(ValueError, match="seed must be an int >= 0"):
        TrainingConfig.from_dict({**load_stage_config("tiny").to_dict(), "seed": -1}, "x.json")


def test_sprint_override_errors_name_the_override():
    sprint = SprintConfig.load("test")
    device = dataclasses.replace(sprint.device("cpu"), stages={"self-forcing": {"critic_lr": 0}})
    with pytest.raises(ValueError, match=r"sprint stage override self-forcing: critic_lr must be a number > 0"):
        stage_blocks(sprint, device)
    device = dataclasses.replace(sprint.device("cpu"), stages={"mp-causal": {"batch": 4}})
    with pytest.raises(ValueError, match=r"sprint stage override mp-causal: unknown keys \['batch'\]"):
        stage_blocks(sprint, device)


def test_defaults_are_the_ones_the_stages_used_before():
    """Before the dataclasses: ``sc.get("ema_decay", 0.0)``,
    ``sc.get("rescan_s")``, ``sc.get("generator", "checkpointed")``; the CLI's ``get("seed", 0)``,
    ``get("collect")``, ``get("all", {})`` and, in the ``all`` block, ``get("time_budget_min")``,
    ``get("elastic_stage", "mp-causal")``, ``get("reserve_min", 0.0)``; ``collect_argv``'s optional
    ``instances``, ``types`` and ``time_of_day`` (absent: the engine's defaults)."""
    flow = FlowStageConfig.from_dict({**LOOP, "lr": 1e-3, "sample_every": 1}, "flow")
    assert (flow.ema_decay, flow.rescan_s) == (0.0, None)
    decoder = {**LOOP, "lr": 1e-3, "sample_every": 1, "eval_clips": 2}
    assert VAEStageConfig.from_dict({**decoder, "stats_clips": 2}, "vae").rescan_s is None
    assert VAEDecoderStageConfig.from_dict(decoder, "vae-decoder").rescan_s is None
    sf = SelfForcingStageConfig.from_dict({**LOOP, "generator_lr": 1e-4, "critic_lr": 1e-4, "sample_every": 1}, "sf")
    assert (sf.generator, sf.rescan_s) == ("checkpointed", None)
    data = load_stage_config("test").to_dict()
    for key in ("seed", "all", "collect"):
        data.pop(key)
    cfg = TrainingConfig.from_dict(data, "test")
    assert (cfg.seed, cfg.collect, cfg.all) == (0, None, AllConfig())
    assert AllConfig() == AllConfig.from_dict({}, "all")
    assert (cfg.all.time_budget_min, cfg.all.elastic_stage, cfg.all.reserve_min) == (None, "mp-causal", 0.0)
    collect = CollectConfig.from_dict({"episodes": 4, "world": "flat", "seed": 3, "test_fraction": 0.25}, "collect")
    assert (collect.instances, collect.types, collect.time_of_day) == (None, None, None)
    cfg = TrainingConfig.from_dict({**data, "all": {}}, "test")
    assert budget_settings(argparse.Namespace(time_budget_min=None), cfg.all) == (None, "mp-causal", 0.0)


def test_the_all_block_and_the_time_budget_flag():
    """``--time-budget-min`` overrides the ``all`` block's budget, as before; 0 means none."""
    block = load_stage_config("tiny").all
    assert budget_settings(argparse.Namespace(time_budget_min=None), block) == (150 * 60.0, "mp-causal", 12 * 60.0)
    assert budget_settings(argparse.Namespace(time_budget_min=30.0), block) == (30 * 60.0, "mp-causal", 12 * 60.0)
    assert budget_settings(argparse.Namespace(time_budget_min=0.0), block)[0] is None
    assert budget_settings(argparse.Namespace(time_budget_min=None), dataclasses.replace(block, time_budget_min=0.0)
                           )[0] is None
    with pytest.raises(ValueError, match="time budget must be >= 0"):
        budget_settings(argparse.Namespace(time_budget_min=-1.0), block)


def test_the_collect_block_choices_match_the_engine():
    from solaris_env.engine import cli as engine_cli

    sub = next(a for a in engine_cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    engine_world = next(a for a in sub.choices["collect"]._actions if a.dest == "world")
    world = next(f for f in dataclasses.fields(CollectConfig) if f.name == "world")
    assert world.metadata["choices"] == tuple(engine_world.choices)
    assert set(ELASTIC_STAGES) <= set(STAGES)


def test_the_stage_kinds_match_the_stage_functions():
    from training.train import FLOW_STAGES

    assert set(STAGE_CONFIGS) == set(STAGES)
    assert {s for s, c in STAGE_CONFIGS.items() if c is FlowStageConfig} == set(FLOW_STAGES)
    assert STAGES[-1] == "self-forcing"  # ``all``'s last stage writes the final model
