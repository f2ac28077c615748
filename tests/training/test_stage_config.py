"""The stage configs as frozen, validated dataclasses (``training.stage_config``; docs/training.md "Stage
configs"): the shipped files and the sprints' overrides validate, errors name the stage, the field and what it
takes, and the defaults are those the stage functions used before they had dataclasses."""

import dataclasses
import json

import pytest

from training.config_files import read_json_config
from training.sprint import SprintConfig, stage_blocks
from training.stage_config import (
    CONFIG_DIR,
    EXTRA_STAGES,
    STAGE_CONFIGS,
    STAGES,
    FlowStageConfig,
    RefinerLayout,
    RefinerStageConfig,
    SelfForcingStageConfig,
    TrainingConfig,
    VAEDecoderStageConfig,
    VAEStageConfig,
    load_stage_config,
)

PRESETS = ("tiny", "tiny16", "test")
LOOP = {"steps": 3, "batch_size": 2, "num_frames": 9, "log_every": 1, "ckpt_every": 1}


@pytest.mark.parametrize("preset", PRESETS)
def test_every_shipped_config_validates_and_round_trips(preset):
    cfg = load_stage_config(preset)
    assert cfg.preset == preset and set(cfg.stages) == set(STAGES + EXTRA_STAGES)
    assert all(isinstance(cfg.stages[s], STAGE_CONFIGS[s]) for s in cfg.stages)
    assert TrainingConfig.from_dict(cfg.to_dict(), preset) == cfg
    raw = read_json_config(CONFIG_DIR / f"{preset}.json")
    for stage in STAGE_CONFIGS:  # every key the file sets is a field, holding the file's value
        block = json.loads(json.dumps(dataclasses.asdict(cfg.stages[stage])))
        for key, value in raw[stage].items():
            got = {k: block[key][k] for k in value} if isinstance(value, dict) else block[key]
            assert got == value, (stage, key)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.stages["mp-causal"].lr = 1.0


@pytest.mark.parametrize("preset", PRESETS)
def test_every_sprint_override_is_a_field_and_validates(preset):
    sprint = SprintConfig.load(preset)
    for platform in sprint.devices:
        cfg = stage_blocks(sprint, sprint.device(platform))
        for stage, override in sprint.device(platform).stages.items():
            block = dataclasses.asdict(cfg.stages[stage])
            assert {k: block[k] for k in override} == override, (platform, stage)
        assert cfg.stages["mp-causal"].steps >= 10**9 and cfg.stages["mp-causal"].ckpt_every == 0
        assert cfg.stages["mp-causal"].rescan_s == sprint.rescan_s
        assert not hasattr(cfg.stages["refiner"], "rescan_s")  # settings only where the stage has the key


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
    ("vae", {"lr_decay_steps": 2}, r"\[vae\]: unknown keys \['lr_decay_steps'\]"),
    ("self-forcing", {"generator": "fast"}, r"\[self-forcing\]: generator must be one of \('checkpointed', 'naive'\)"),
    ("refiner", {"loss": "l1"}, r"\[refiner\]: loss must be one of \('mse', 'log_mse'\), got 'l1'"),
    ("refiner", {"init_from": "refiner"}, r"\[refiner\]: init_from must be one of"),
    ("refiner", {"refiner": {"width": 0, "pool": 4, "actions": True}},
     r"\[refiner\]: refiner: width must be an int >= 1, got 0"),
    ("refiner", {"refiner": {"width": 8, "pool": 4, "actions": True, "camera_shift": [1.0]}},
     r"\[refiner\]: refiner: camera_shift must be a list of 2 numbers"),
])
def test_a_bad_key_or_value_names_the_stage_the_field_and_what_it_takes(stage, changes, message):
    with pytest.raises(ValueError, match=message):
        TrainingConfig.from_dict(_tiny_with(stage, **changes), "tiny.json")


def test_file_level_errors_name_the_file(tmp_path):
    data = load_stage_config("tiny").to_dict()
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**data, "mp-causal": {**data["mp-causal"], "lr": -1}}))
    with pytest.raises(ValueError, match=r"bad.json \[mp-causal\]: lr must be a number > 0, got -1"):
        load_stage_config("tiny", path)
    with pytest.raises(ValueError, match=r"unknown keys \['stage3'\]"):
        TrainingConfig.from_dict({**data, "stage3": {}}, "x.json")
    with pytest.raises(ValueError, match=r"x.json: missing keys \['refiner'\]"):
        TrainingConfig.from_dict({k: v for k, v in data.items() if k != "refiner"}, "x.json")
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


def test_defaults_are_the_ones_the_stages_used_before():
    """Before the dataclasses: ``sc.get("lr_decay_steps", 0)``, ``sc.get("ema_decay", 0.0)``,
    ``sc.get("rescan_s")``, ``sc.get("generator", "checkpointed")``, ``sc.get("init_from", "self-forcing")``,
    ``sc.get("loss", "mse")``, ``r.get("camera_shift", (0.0, 0.0))``; the CLI's ``get("seed", 0)`` and
    ``get("all", {})``."""
    flow = FlowStageConfig.from_dict({**LOOP, "lr": 1e-3, "sample_every": 1}, "flow")
    assert (flow.lr_decay_steps, flow.ema_decay, flow.rescan_s) == (0, 0.0, None)
    decoder = {**LOOP, "lr": 1e-3, "sample_every": 1, "eval_clips": 2}
    assert VAEStageConfig.from_dict({**decoder, "stats_clips": 2}, "vae").rescan_s is None
    assert VAEDecoderStageConfig.from_dict(decoder, "vae-decoder").rescan_s is None
    sf = SelfForcingStageConfig.from_dict({**LOOP, "generator_lr": 1e-4, "critic_lr": 1e-4, "sample_every": 1}, "sf")
    assert (sf.generator, sf.rescan_s) == ("checkpointed", None)
    refiner = RefinerStageConfig.from_dict({**LOOP, "lr": 1e-3, "rollout_parts": 1, "segments_per_part": 2,
                                            "refiner": {"width": 4, "pool": 4, "actions": True}}, "refiner")
    assert (refiner.init_from, refiner.loss) == ("self-forcing", "mse")
    assert refiner.refiner == RefinerLayout(width=4, pool=4, actions=True, camera_shift=(0.0, 0.0))
    data = load_stage_config("test").to_dict()
    for key in ("seed", "all"):
        data.pop(key)
    cfg = TrainingConfig.from_dict(data, "test")
    assert (cfg.seed, cfg.all) == (0, {})


def test_the_stage_kinds_match_the_stage_functions():
    from training.refine import LOSSES
    from training.train import FLOW_STAGES

    assert set(STAGE_CONFIGS) == set(STAGES + EXTRA_STAGES)
    assert {s for s, c in STAGE_CONFIGS.items() if c is FlowStageConfig} == set(FLOW_STAGES)
    loss = next(f for f in dataclasses.fields(RefinerStageConfig) if f.name == "loss")
    assert loss.metadata["choices"] == LOSSES
