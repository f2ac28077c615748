"""``solaris-train sprint`` on the CPU with the ``test`` preset: two ~1-minute sprints, the second continuing the
first, each training while the engine records episodes; then ``training/gpu_call.sh`` (two sprints side by side);
plus the sharded checkpoint writer and the planner."""

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest

from solaris_env.world_model import checkpoint
from training import cli
from training.sprint import LINEAGE_FILE, SprintConfig, plan_shares, stage_blocks

MIB = 2**20


@pytest.fixture(scope="module")
def test_model():
    from solaris_env.world_model.world_model import WorldModel

    return WorldModel.from_preset("test", seed=0)


def _params(model) -> dict:
    from solaris_env.world_model.components import COMPONENTS

    return dict(zip(COMPONENTS, model.params))


def test_sharded_save_round_trips_bit_exact_and_keeps_every_shard_under_the_cap(test_model, tmp_path):
    from solaris_env.world_model.world_model import WorldModel

    cap = 256 * 1024
    path = checkpoint.save(tmp_path / "model", test_model.config, _params(test_model), shard_bytes=cap,
                           extra_files={"lineage.json": "{}"})
    shards = checkpoint.weight_files(path)
    assert len(shards) > 3 and not (path / checkpoint.WEIGHTS_FILE).exists()
    assert [p.name for p in shards] == [f"weights-{i:05d}-of-{len(shards):05d}.safetensors"
                                        for i in range(1, len(shards) + 1)]
    assert all(p.stat().st_size <= cap for p in shards)
    assert (path / "lineage.json").read_text() == "{}"
    loaded = WorldModel.load(path)
    for a, b in zip(_leaves(test_model), _leaves(loaded)):
        np.testing.assert_array_equal(a, b)
    single = checkpoint.save(tmp_path / "single", test_model.config, _params(test_model))
    assert [p.name for p in checkpoint.weight_files(single)] == [checkpoint.WEIGHTS_FILE]


def _leaves(model):
    import jax

    return [np.asarray(x) for x in jax.tree.leaves(model.params)]


def test_shard_writer_refuses_what_does_not_fit_and_loader_refuses_incomplete_sets(test_model, tmp_path):
    with pytest.raises(ValueError, match="does not fit in a shard"):
        checkpoint.save(tmp_path / "a", test_model.config, _params(test_model), shard_bytes=1024)
    with pytest.raises(ValueError, match="max_total_bytes"):
        checkpoint.save(tmp_path / "b", test_model.config, _params(test_model), shard_bytes=MIB, max_total_bytes=MIB)
    assert not (tmp_path / "b").exists()
    path = checkpoint.save(tmp_path / "c", test_model.config, _params(test_model), shard_bytes=256 * 1024)
    checkpoint.weight_files(path)[1].unlink()
    with pytest.raises(ValueError, match="incomplete weight shards, missing"):
        checkpoint.load(path)
    with pytest.raises(ValueError, match="extra_files"):
        checkpoint.save(tmp_path / "d", test_model.config, _params(test_model), extra_files={"config.json": "{}"})


def test_the_default_model_fits_the_transport_as_float16_shards(tmp_path):
    """The shipped model: 16 MiB shards, 64 MiB in all, as the GPU sprint exports it."""
    from solaris_env.world_model.world_model import WorldModel
    from training.surgery import DEFAULT_MODEL_DIR

    model = WorldModel.load(DEFAULT_MODEL_DIR)
    path = checkpoint.save(tmp_path / "model", model.config, _params(model), storage_dtype="float16",
                           shard_bytes=16 * MIB, max_total_bytes=64 * MIB)
    shards = checkpoint.weight_files(path)
    assert len(shards) >= 3 and all(p.stat().st_size <= 16 * MIB for p in shards)


def test_plan_drops_the_smallest_shares_first_and_splits_the_rest_by_fraction():
    overhead = {"a": 10.0, "b": 20.0, "c": 30.0}
    shares, dropped = plan_shares([("a", 0.5), ("b", 0.2), ("c", 0.3)], overhead, 5.0, 160.0)
    assert dropped == [] and shares == pytest.approx({"a": 10 + 50, "b": 20 + 20, "c": 30 + 30})
    shares, dropped = plan_shares([("a", 0.5), ("b", 0.2), ("c", 0.3)], overhead, 5.0, 60.0)
    assert dropped == ["b"] and shares == pytest.approx({"a": 10 + 12.5, "c": 30 + 7.5})
    assert plan_shares([("a", 1.0)], overhead, 5.0, 14.0) == ({}, ["a"])


def test_the_sprint_records_its_data_at_noon():
    """Every env, start scene and eval set is at noon; the sprint's collect matches (docs/training.md)."""
    data = json.loads((cli.Path(__file__).resolve().parents[2] / "training/configs/sprint-tiny.json").read_text())
    assert SprintConfig.from_dict(data).collect.time_of_day == "day"


def test_config_errors_name_the_field():
    data = json.loads((cli.Path(__file__).resolve().parents[2] / "training/configs/sprint-tiny.json").read_text())
    cfg = SprintConfig.from_dict(data)
    assert stage_blocks(cfg, cfg.device("gpu")).stages["mp-causal"].steps >= 10**9
    # remat (recompute in the backward pass) pays on the memory-bound CPU only; a GPU would just add arithmetic
    for stage in ("sp", "mp-bidirectional", "mp-causal"):
        assert stage_blocks(cfg, cfg.device("gpu")).stages[stage].remat is False
        assert stage_blocks(cfg, cfg.device("cpu")).stages[stage].remat is True
    with pytest.raises(ValueError, match="fractions_from_init must not name"):
        SprintConfig.from_dict({**data, "fractions_from_init": {"vae": 1.0}})
    with pytest.raises(ValueError, match=r"devices.gpu.reserve_s must be a number >= 0"):
        SprintConfig.from_dict({**data, "devices": {"gpu": {**data["devices"]["gpu"], "reserve_s": -1}}})
    bad = {**data["devices"]["cpu"], "stages": {"mp-causal": {"batch": 4}}}
    with pytest.raises(ValueError, match=r"override mp-causal: unknown keys \['batch'\]"):
        stage_blocks(SprintConfig.from_dict({**data, "devices": {"cpu": bad}}), SprintConfig.from_dict(
            {**data, "devices": {"cpu": bad}}).device("cpu"))
    with pytest.raises(ValueError, match="no devices.tpu block"):
        cfg.device("tpu")


def test_growing_stream_picks_up_the_episodes_written_meanwhile(tiny_duet, tmp_path):
    """What every sprint stage reads: an episode joins at the first draw ``rescan_s`` after its commit markers
    (the ``_episode_info.json`` files the recorder moves in last) are there, not before; each bot's view of it
    joins the single-player stream."""
    import time

    from solaris_env.world_model.config import preset
    from training import growing_data

    src, dst = tiny_duet / "duet" / "train", tmp_path / "duet" / "train"
    dst.mkdir(parents=True)
    alphas = sorted(src.glob("*_Alpha_*.mp4"))

    def move_in(alpha, commit: bool):
        stems = [alpha.name.removesuffix(".mp4"), alpha.name.removesuffix(".mp4").replace("_Alpha_", "_Bravo_")]
        names = [f"{x}{suffix}" for suffix in (".mp4", ".json") for x in stems]
        for name in names if not commit else [f"{x}_episode_info.json" for x in stems]:
            shutil.copy2(src / name, dst / name)

    for alpha in alphas[:2]:
        move_in(alpha, commit=False)
        move_in(alpha, commit=True)
    move_in(alphas[2], commit=False)
    n_streams = len(growing_data.STREAMS)
    cfg = preset("test")
    dataset, sampler = growing_data.growing_stream(tmp_path, cfg, 9, seed=0, rescan_s=0.05, single_player=False)
    players, player_sampler = growing_data.growing_stream(tmp_path, cfg, 9, seed=0, rescan_s=0.05, single_player=True)
    assert dataset.valid_ids == [0, 1] and sampler.state_dict()["num_candidates"] == 2
    time.sleep(0.1)
    sampler.next()
    assert dataset.valid_ids == [0, 1]  # moved in, not committed yet
    move_in(alphas[2], commit=True)
    time.sleep(0.1)
    sampler.next()
    player_sampler.next()
    assert dataset.valid_ids == [0, 1, 2] and sampler.state_dict()["num_candidates"] == 3
    assert [h[1] for h in dataset.history] == [2, 3]
    assert players.valid_ids == list(range(6)) and player_sampler.state_dict()["num_candidates"] == 6
    np.testing.assert_array_equal(players.episode(5).act_T25, dataset.recordings(2)[1].act_T25)
    assert players.episode(4).video == dataset.recordings(2)[0].video
    del growing_data.STREAMS[n_streams:]


@pytest.fixture(scope="module")
def sprints(tiny_duet, test_model, tmp_path_factory):
    """Sprint A (1 min; on this CPU its cold JIT compile alone may take longer) from a random-init model, then
    sprint B (0.75 min) from A's output; one data directory, seeded with the 3 + 1 recorded episodes so training
    starts at once, and one work directory (its JAX compilation cache and latent cache serve B and B's engine
    worker)."""
    root = tmp_path_factory.mktemp("sprint")
    data = root / "data"
    shutil.copytree(tiny_duet / "duet", data / "duet")
    # stored as the sprints store theirs: B's VAE is A's, bit for bit, so B finds A's latents cached
    checkpoint.save(root / "init", test_model.config, _params(test_model), storage_dtype="float16")
    common = ["sprint", "--preset", "test", "--data", str(data), "--work", str(root / "work")]
    for name, init, minutes in (("a", root / "init", "1"), ("b", root / "a" / "model", "0.75")):
        assert cli.main([*common, "--init", str(init), "--out", str(root / name), "--budget-min", minutes]) == 0
    return root


@pytest.mark.slow
def test_sprint_writes_a_sharded_model_that_steps_in_the_dream_env(sprints):
    from solaris_env.dream_env import DreamParallelEnv, build_model

    model_dir = sprints / "a" / "model"
    names = sorted(p.name for p in model_dir.iterdir())
    assert "config.json" in names and LINEAGE_FILE in names and checkpoint.WEIGHTS_FILE not in names
    shards = checkpoint.weight_files(model_dir)
    assert len(shards) >= 2 and all(p.stat().st_size <= MIB // 4 for p in shards)  # sprint-test.json: 0.25 MiB
    env = DreamParallelEnv(model=build_model(model_dir))
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step({a: env.action_space(a).sample() for a in env.agents})
    assert set(obs) == {"Alpha", "Bravo"} and all(env.observation_space(a).contains(obs[a]) for a in obs)


def _lineages(sprints) -> tuple[dict, dict]:
    return tuple(json.loads((sprints / name / "model" / LINEAGE_FILE).read_text()) for name in ("a", "b"))


@pytest.mark.slow
def test_sprint_trains_while_the_engine_records_and_keeps_its_time(sprints):
    a, b = _lineages(sprints)
    for lineage in (a, b):
        (stage,) = [s for s in lineage["stages"] if s["status"] == "ran"]  # sprint-test.json: mp-causal only
        assert stage["stage"] == "mp-causal" and stage["steps"] >= 1 and stage["share_s"] > 0
        assert 0 < stage["first_step_s"] <= stage["wall_s"]  # from the step hook, whatever the stage's log_every
        # within the budget (the final export follows within reserve_s), unless this machine took longer than the
        # stage's whole share to set up and take its first step (the cold JIT compile): then that step was its last
        overran_on_first_step = stage["steps"] == 1 and stage["first_step_s"] >= stage["share_s"]
        assert lineage["training_wall_s"] <= lineage["budget_s"] or overran_on_first_step, json.dumps(lineage)
        assert lineage["exports"][-1]["final"] and not any(e["final"] for e in lineage["exports"][:-1])
    # a periodic export (every 0.2 min) from the live train state, then the final; A makes none when its first step
    # ends past its deadline (the cold compile on a loaded host), B always has the time
    assert len(b["exports"]) >= 2 and b["exports"][0]["step"] is not None, b["exports"]
    assert a["platform"] == "cpu" and a["generation"] == 1 and a["init"]["lineage"] is None
    (a_stage,), (b_stage,) = ([s["data"] for s in x["stages"] if s["status"] == "ran"] for x in (a, b))
    assert a_stage["episodes_at_start"] >= 3  # the seeded ones: training started without waiting
    # A's engine worker recorded while A trained: A's stage picked episodes up (a rescan after its first step)
    # or B started with more than A did
    grew = [d["episodes_at_end"] - d["episodes_at_start"] for d in (a_stage, b_stage)]
    assert max(grew) > 0 or b_stage["episodes_at_start"] > a_stage["episodes_at_start"], (a_stage, b_stage)
    assert a["collected"]["train"] >= 1


@pytest.mark.slow
def test_a_sprint_from_a_sprint_continues_its_lineage(sprints):
    a, b = _lineages(sprints)
    # the lineage names the init model without the machine's directories (solaris_env.paths.portable_text)
    assert b["generation"] == 2 and b["init"]["model"] == "/".join((sprints / "a" / "model").parts[-3:])
    assert not any(arg.startswith("/") for arg in a["command"] + b["command"]), (a["command"], b["command"])
    assert b["init"]["lineage"] == a
    assert b["collect"]["seed"] == a["collect"]["seed"] + 1000  # new episodes for the continued model
    assert [s["stage"] for s in b["stages"] if s["status"] == "ran"] == ["mp-causal"]


def test_install_takes_a_sharded_sprint_model_with_its_lineage(test_model, tmp_path):
    from solaris_env.world_model.world_model import WorldModel

    src = checkpoint.save(tmp_path / "sprint" / "model", test_model.config, _params(test_model),
                          storage_dtype="float16", shard_bytes=256 * 1024,
                          extra_files={LINEAGE_FILE: '{"generation": 1}'})
    assert cli.main(["install", str(src), "--dest", str(tmp_path / "default")]) == 0
    installed = tmp_path / "default"
    assert sorted(p.name for p in installed.iterdir()) == ["config.json", LINEAGE_FILE, checkpoint.WEIGHTS_FILE]
    assert json.loads((installed / LINEAGE_FILE).read_text()) == {"generation": 1}
    for a, b in zip(_leaves(WorldModel.load(src)), _leaves(WorldModel.load(installed))):
        np.testing.assert_array_equal(a, b)


def test_install_writes_the_rollout_settings_into_the_shipped_sampler(test_model, tmp_path):
    from solaris_env.world_model.world_model import WorldModel

    src = checkpoint.save(tmp_path / "stage" / "model", test_model.config, _params(test_model),
                          storage_dtype="float16")
    with pytest.raises(SystemExit, match="noise_warp=0.5 .* needs dit.camera_warp on"):  # the test preset has none
        cli.main(["install", str(src), "--dest", str(tmp_path / "bad"), "--noise-warp", "0.5"])
    assert not (tmp_path / "bad").exists()
    cfg = test_model.config.replace(dit=dataclasses.replace(test_model.config.dit, camera_warp=(0.1, 0.06)))
    src = checkpoint.save(tmp_path / "warp" / "model", cfg, _params(WorldModel.from_config(cfg, seed=0)),
                          storage_dtype="float16")
    assert cli.main(["install", str(src), "--dest", str(tmp_path / "w"), "--noise-warp", "0.9",
                     "--still-memory", "0.5"]) == 0
    installed = WorldModel.load(tmp_path / "w")
    assert installed.config.sampler.noise_warp == 0.9 and installed.config.sampler.still_memory == 0.5
    assert installed.config.replace(sampler=cfg.sampler) == cfg  # nothing else moved
    with pytest.raises(SystemExit, match="still_memory must be in"):
        cli.main(["install", str(src), "--dest", str(tmp_path / "bad"), "--still-memory", "1"])


@pytest.mark.slow
def test_a_vae_sprint_from_scratch_records_its_first_step_speed_and_held_out_psnr(tiny_duet, tmp_path):
    """A sprint of the VAE alone, from scratch, on the test preset: its lineage says when the first step ended,
    the speed, and the held-out PSNR."""
    from training.config_files import read_json_config
    from training.sprint import CONFIG_DIR

    config = read_json_config(CONFIG_DIR / "sprint-test.json")
    config["fractions"] = {"vae": 1.0}
    (tmp_path / "vae.json").write_text(json.dumps(config))
    shutil.copytree(tiny_duet / "duet", tmp_path / "data" / "duet")
    assert cli.main(["sprint", "--preset", "test", "--config", str(tmp_path / "vae.json"), "--data",
                     str(tmp_path / "data"), "--out", str(tmp_path / "out"), "--budget-min", "1.5"]) == 0
    lineage = json.loads((tmp_path / "out" / "model" / LINEAGE_FILE).read_text())
    (stage,) = [s for s in lineage["stages"] if s["status"] == "ran"]
    assert stage["stage"] == "vae" and stage["steps"] >= 1 and 0 < stage["first_step_s"] <= stage["wall_s"]
    assert stage["steps_per_s"] > 0
    held_out = stage["held_out"]  # the test preset's VAE clips: 5 frames, 1 + 1 latents
    assert held_out["num_frames"] == 5 and len(held_out["test_psnr_by_latent_db"]) == 2
    assert 0 < held_out["test_psnr_db"] < 60


def test_workers_must_be_positive(tmp_path):
    from training.sprint import SprintArgs, run_sprint

    with pytest.raises(ValueError, match="--workers must be an integer >= 1"):
        run_sprint(SprintArgs("test", tmp_path / "out", 1.0, workers=0))
    assert SprintArgs("test", tmp_path, 1.0, workers=3).command()[-2:] == ["--workers", "3"]


REPO = Path(__file__).resolve().parents[2]


# ``training/gpu_call.sh``, the GPU session's one call, on the CPU with the ``test`` preset: the candidate sprint
# and the official-layout control side by side, each returned as its shards plus one ``meta.tar``. In this file so
# that it never runs beside the sprints above (two more sprints on a 2-core host starve their engine workers).


@pytest.mark.slow
def test_gpu_call_returns_the_candidate_and_the_control_packed(tiny_duet, test_model, tmp_path):
    from solaris_env.world_model.world_model import WorldModel

    init = checkpoint.save(tmp_path / "init", test_model.config, _params(test_model), storage_dtype="float16")
    for run in ("sprint", "control"):  # seeded with recorded episodes, so both train at once
        shutil.copytree(tiny_duet / "duet", tmp_path / "data" / run / "duet")
    out = tmp_path / "out"
    env = {**os.environ, "OUT": str(out), "PYTHON": sys.executable, "SPRINT_PRESET": "test", "SPRINT_INIT": str(init),
           "SPRINT_BUDGET_MIN": "2.5", "SPRINT_WORKERS": "1", "SPRINT_DATA": str(tmp_path / "data"),
           "TMPDIR": str(tmp_path)}
    done = subprocess.run(["bash", "training/gpu_call.sh"], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "== sprint: exit 0" in done.stdout and "== control: exit 0" in done.stdout, done.stdout
    assert sorted(p.name for p in out.iterdir()) == ["control", "sprint"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("solaris-call.")]  # its scratch folder removed
    models = {}
    for run in ("sprint", "control"):
        files = sorted(str(p.relative_to(out / run)) for p in (out / run).rglob("*") if p.is_file())
        shards = [f for f in files if f.startswith("model/weights-")]
        assert files == sorted(shards + ["meta.tar"]) and shards, files
        with tarfile.open(out / run / "meta.tar") as tar:
            assert sorted(tar.getnames()) == ["log.txt", "model/config.json", "model/lineage.json"]
            tar.extractall(out / run, filter="data")
        assert "sprint: model written to" in (out / run / "log.txt").read_text()
        lineage = json.loads((out / run / "model" / "lineage.json").read_text())
        assert "--workers" in lineage["command"] and [s["status"] for s in lineage["stages"]].count("ran") == 1
        models[run] = WorldModel.load(out / run / "model")
    # the control kept the init's codec bit for bit and trained a fresh DiT of its own
    vae = [np.asarray(x) for x in _component_leaves(test_model, "vae")]
    for run, model in models.items():
        for a, b in zip(vae, [np.asarray(x) for x in _component_leaves(model, "vae")]):
            np.testing.assert_array_equal(a.astype(np.float16), b.astype(np.float16))
    dit = [np.asarray(x) for x in _component_leaves(models["sprint"], "dit")]
    assert any(not np.array_equal(a, b) for a, b in zip(dit, _component_leaves(models["control"], "dit")))


def _component_leaves(model, component: str):
    import jax

    return jax.tree.leaves(_params(model)[component])
