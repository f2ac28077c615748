"""``solaris-train`` end to end on the ``test`` preset: every stage runs from the previous one's model and
writes its model, metrics and samples; a stage killed with SIGKILL resumes with the same next losses."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from training import cli
from training.metrics import read_metrics
from training.stage_config import STAGES
from training.train import model_dir

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def data(tiny_duet):
    return tiny_duet


@pytest.fixture(scope="module")
def run(data, tmp_path_factory):
    """The VAE (both stages) and stages 1-3 with the test preset (stage 4 has its own tests)."""
    out = tmp_path_factory.mktemp("run")
    for stage in ("vae", "vae-decoder", "sp", "mp-bidirectional", "mp-causal"):
        assert cli.main([stage, "--preset", "test", "--data", str(data), "--out", str(out)]) == 0
    return out


def test_stages_chain_and_write_their_outputs(run):
    cfg = json.loads((REPO / "training" / "configs" / "test.json").read_text())
    for stage in ("vae", "vae-decoder", "sp", "mp-bidirectional", "mp-causal"):
        assert (model_dir(run, stage) / "config.json").is_file(), stage
        metrics = read_metrics(run / stage / "metrics.jsonl")
        assert [m["step"] for m in metrics] == list(range(1, cfg[stage]["steps"] + 1)), stage
        assert all(m["loss"] > 0 and m["stage"] == stage for m in metrics)
    assert list((run / "vae" / "samples").glob("*.png"))
    for stage in ("sp", "mp-bidirectional", "mp-causal"):
        assert list((run / stage / "samples").glob("*.mp4")), stage
    summary = json.loads((run / "vae" / "summary.json").read_text())
    assert len(summary["latent_std"]) == 4 and all(s > 0 for s in summary["latent_std"])
    decoder = json.loads((run / "vae-decoder" / "summary.json").read_text())
    assert len(decoder["after"]["test_psnr_by_latent_db"]) == 1 + (cfg["vae-decoder"]["num_frames"] - 1) // 4
    assert set(STAGES) >= {"vae", "vae-decoder", "sp", "mp-bidirectional", "mp-causal", "self-forcing"}


def test_causal_stage_logs_its_constant_lr_and_saves_its_parameter_ema(run):
    """test.json's mp-causal: the logged LR is the configured constant; the saved model is the EMA of the
    parameters (kept in the checkpoint), not the last update."""
    import orbax.checkpoint as ocp
    from flax import nnx

    from solaris_env.world_model.world_model import WorldModel
    from training.checkpointing import tree_paths

    sc = json.loads((REPO / "training" / "configs" / "test.json").read_text())["mp-causal"]
    lrs = [m["lr"] for m in read_metrics(run / "mp-causal" / "metrics.jsonl")]
    assert lrs == pytest.approx([sc["lr"]] * sc["steps"])
    state = ocp.StandardCheckpointer().restore(run / "mp-causal" / "checkpoints" / str(sc["steps"]) / "state")
    dit = WorldModel.load(model_dir(run, "mp-causal")).modules()[0]
    saved = tree_paths(nnx.to_pure_dict(nnx.state(dit, nnx.Param)))
    unboxed = lambda tree: {k.removesuffix(".value"): v for k, v in tree_paths(tree).items()}  # orbax keeps nnx's boxes
    ema, params = unboxed(state["ema"]), unboxed(state["params"])
    assert saved.keys() == ema.keys()
    for key, value in saved.items():
        np.testing.assert_array_equal(np.asarray(value), np.asarray(ema[key]), err_msg=key)
    assert any(not np.array_equal(np.asarray(ema[k]), np.asarray(params[k])) for k in ema)


def test_sp_stage_keeps_the_player_embedding_at_zero_and_mp_learns_it(run):
    from flax import nnx

    from solaris_env.world_model.world_model import WorldModel

    sp_dit = WorldModel.load(model_dir(run, "sp")).modules()[0]
    mp_dit = WorldModel.load(model_dir(run, "mp-bidirectional")).modules()[0]
    assert WorldModel.load(model_dir(run, "sp")).config.num_players == 1
    assert np.all(np.asarray(nnx.state(sp_dit)["player_embed"]["embedding"][...]) == 0)
    assert np.any(np.asarray(nnx.state(mp_dit)["player_embed"]["embedding"][...]) != 0)


def _stage_cmd(data, out, steps, config):
    return [sys.executable, "-m", "training.cli", "mp-causal", "--preset", "test", "--config", str(config), "--data",
            str(data), "--out", str(out), "--steps", str(steps)]


@pytest.mark.slow
def test_kill_9_then_resume_gives_the_same_losses(run, data, tmp_path):
    """Copy the finished stages into a fresh run dir, start mp-causal, SIGKILL it after its first
    checkpoint, resume, and compare every logged loss with an uninterrupted run."""
    import shutil

    killed, clean = tmp_path / "killed", tmp_path / "clean"
    for out in (killed, clean):
        out.mkdir()
        shutil.copytree(run / "mp-bidirectional", out / "mp-bidirectional")
        shutil.copytree(run / "latents", out / "latents")
    config = json.loads((REPO / "training" / "configs" / "test.json").read_text())
    # no sampling: only the losses matter
    config["mp-causal"].update(log_every=1, ckpt_every=2, sample_every=10**6)
    config_path = tmp_path / "config.json"
    config_path.write_text(json.dumps(config))
    # the three runs share compiled programs through JAX's cache; low XLA optimisation compiles faster
    env = {**os.environ, "PYTHONPATH": str(REPO), "XLA_FLAGS": "--xla_backend_optimization_level=0",
           "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax_cache"), "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
           "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0"}
    proc = subprocess.Popen(_stage_cmd(data, killed, 1000, config_path), cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ckpts = killed / "mp-causal" / "checkpoints"
    deadline = time.time() + 240
    while time.time() < deadline and not any(p.name.isdigit() for p in ckpts.glob("*")):
        assert proc.poll() is None, "the run ended before its first checkpoint"
        time.sleep(0.2)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    done = max(int(p.name) for p in ckpts.glob("*") if p.name.isdigit())
    target = done + 3
    subprocess.run(_stage_cmd(data, killed, target, config_path), cwd=REPO, env=env, check=True, capture_output=True)
    subprocess.run(_stage_cmd(data, clean, target, config_path), cwd=REPO, env=env, check=True, capture_output=True)
    resumed = {m["step"]: m["loss"] for m in read_metrics(killed / "mp-causal" / "metrics.jsonl")}
    uninterrupted = {m["step"]: m["loss"] for m in read_metrics(clean / "mp-causal" / "metrics.jsonl")}
    assert sorted(resumed) == sorted(uninterrupted) == list(range(1, target + 1))
    for step in range(done + 1, target + 1):
        assert resumed[step] == pytest.approx(uninterrupted[step], rel=1e-6, abs=1e-7), step


def test_flow_stage_logs_the_held_out_loss_of_the_parameters_it_saves(run, data, tmp_path):
    """test_every = 2 over 3 steps: test_loss records at steps 2 and 3 (the last), and the last equals the loss
    of the saved model (the EMA) on the same fixed test-split batches; without a test split, a clear error."""
    import shutil

    from flax import nnx

    from solaris_env.world_model.world_model import WorldModel
    from training.latents import make_prepare_latents
    from training.step import make_test_loss
    from training.train import FLOW_STAGES, heldout_batches

    out = tmp_path / "run"
    out.mkdir()
    shutil.copytree(run / "mp-bidirectional", out / "mp-bidirectional")
    shutil.copytree(run / "latents", out / "latents")
    config = json.loads((REPO / "training" / "configs" / "test.json").read_text())
    config["mp-causal"].update(sample_every=10**6, test_every=2, test_batches=2)
    config_path = tmp_path / "config.json"
    config_path.write_text(json.dumps(config))
    argv = ["mp-causal", "--preset", "test", "--config", str(config_path), "--data", str(data), "--out", str(out)]
    assert cli.main(argv) == 0
    records = read_metrics(out / "mp-causal" / "metrics.jsonl")
    tests = {m["step"]: m["test_loss"] for m in records if "test_loss" in m}
    assert sorted(tests) == [2, 3] and all(v > 0 for v in tests.values())
    assert all("loss" in m for m in records if "test_loss" not in m)

    model = WorldModel.load(model_dir(out, "mp-causal"))
    dit, vae, encoder = model.modules()
    sc = config["mp-causal"]
    batches = heldout_batches(out, data, model.config, vae, make_prepare_latents(model.config, vae, encoder),
                              sc["num_frames"], sc["batch_size"], 2, config["seed"], single_player=False)
    graphdef, params, rest = nnx.split(dit, nnx.Param, ...)
    fs = FLOW_STAGES["mp-causal"]
    saved = float(make_test_loss(graphdef, fs.entry_point, fs.noise_type, batches)(params, rest))
    assert tests[3] == pytest.approx(saved, rel=1e-4)

    train_only = tmp_path / "train_only"
    shutil.copytree(data / "duet" / "train", train_only / "duet" / "train")
    bad = ["mp-causal", "--preset", "test", "--config", str(config_path), "--data", str(train_only), "--out",
           str(out), "--steps", "4"]
    with pytest.raises(SystemExit, match="test_every > 0 needs held-out episodes"):  # the CLI's error line
        cli.main(bad)


def test_action_conditioning_rewrites_a_model_that_computes_the_same(run, tmp_path):
    """``solaris-train action-conditioning --mouse-gain``: the new config, the mouse rows rescaled, the same
    generated frames (within one grey level) for a turning rollout."""

    from solaris_env.world_model.world_model import WorldModel

    src = model_dir(run, "mp-causal")
    dest = tmp_path / "g8"
    assert cli.main(["action-conditioning", str(src), "--mouse-gain", "8", "--out", str(dest)]) == 0
    base, new = WorldModel.load(src), WorldModel.load(dest)
    assert (base.config.action.mouse_input_gain, new.config.action.mouse_input_gain) == (1.0, 8.0)
    cfg = base.config
    rng = np.random.default_rng(0)
    first = rng.integers(0, 256, (1, cfg.num_players, cfg.frame_height, cfg.frame_width, 3), dtype=np.uint8)
    actions = np.zeros((1, cfg.num_players, base.frames_per_step, 25), np.float32)
    actions[..., 0, 23] = 0.6  # a yaw turn on the first tick (scaled camera units)
    actions[..., :, 0] = 1.0  # forward held
    outs = []
    for model in (base, new):
        frames, _ = model.step(model.init(first, 0), actions)
        outs.append(np.asarray(frames, np.int16))
    assert np.abs(outs[0] - outs[1]).max() <= 1


def third_step(model, first, actions):
    """The frames of a rollout's third step (from the second step on the warp reads a committed latent), int16."""

    state = model.init(first, 0)
    for _ in range(3):
        frames, state = model.step(state, actions)
    return np.asarray(frames, np.int16)


def test_camera_warp_retrofit_computes_the_same(run, tmp_path):
    """``action-conditioning --camera-warp``: the patch embedding gains the warped previous latent's rows at zero,
    so a turning rollout generates the same frames; turning the warp off again is refused."""
    import jax

    from solaris_env.world_model.world_model import WorldModel
    from training.surgery import with_action_conditioning

    src = model_dir(run, "mp-causal")
    dest = tmp_path / "warp"
    assert cli.main(["action-conditioning", str(src), "--camera-warp", "0.1", "0.06", "--out", str(dest)]) == 0
    base, new = WorldModel.load(src), WorldModel.load(dest)
    assert new.config.dit.camera_warp == (0.1, 0.06) and base.config.dit.camera_warp == (0.0, 0.0)
    kernel = np.asarray(new.params[0]["patch_embedding"]["kernel"].get_value())
    assert kernel.shape[-2] == base.config.in_channels + base.config.out_channels
    assert np.abs(kernel[..., base.config.in_channels:, :]).max() == 0
    cfg = base.config
    rng = np.random.default_rng(1)
    first = rng.integers(0, 256, (1, cfg.num_players, cfg.frame_height, cfg.frame_width, 3), dtype=np.uint8)
    actions = np.zeros((1, cfg.num_players, base.frames_per_step, 25), np.float32)
    actions[..., 23] = 0.6  # turning left every tick
    outs = [third_step(model, first, actions) for model in (base, new)]
    assert np.abs(outs[0] - outs[1]).max() <= 1
    with pytest.raises(ValueError, match="camera_warp"):
        with_action_conditioning(dest, tmp_path / "back", camera_warp=(0.0, 0.0))
    # the walk warp keeps the weights: without the movement keys the same frames (walking changes only the warp
    # input, whose rows are still zero here; test_camera.py checks that a trained warp reads the walk)
    walk = tmp_path / "walk"
    assert cli.main(["action-conditioning", str(dest), "--walk-warp", "0.1", "--out", str(walk)]) == 0
    walker = WorldModel.load(walk)
    assert walker.config.dit.walk_warp == 0.1 and walker.config.dit.camera_warp == (0.1, 0.06)
    outs = [third_step(model, first, actions) for model in (new, walker)]
    assert np.array_equal(outs[0], outs[1])
    with pytest.raises(ValueError, match="walk_warp"):
        with_action_conditioning(src, tmp_path / "nowarp", walk_warp=0.1)
    # the previous-frame skip starts with its gate at zero: the same frames while turning and walking
    skip = tmp_path / "skip"
    assert cli.main(["action-conditioning", str(walk), "--previous-skip", "--out", str(skip)]) == 0
    skipper = WorldModel.load(skip)
    assert skipper.config.dit.previous_skip and skipper.config.dit.walk_warp == 0.1
    assert all(np.abs(np.asarray(a)).max() == 0 for a in jax.tree.leaves(skipper.params[0]["skip_gate"]))
    from solaris_env.spaces import MODEL_INDEX
    actions[..., MODEL_INDEX["forward"]] = 1.0  # forward held, still turning
    outs = [third_step(model, first, actions) for model in (walker, skipper)]
    assert np.abs(outs[0] - outs[1]).max() <= 1
    with pytest.raises(ValueError, match="previous_skip"):
        with_action_conditioning(src, tmp_path / "noskip", previous_skip=True)  # no camera warp to read
    with pytest.raises(ValueError, match="previous_skip"):
        with_action_conditioning(skip, tmp_path / "drop", previous_skip=False)
    # the warp's interpolation and its geometry are config settings: the weights are kept, bit for bit
    # (test_camera.py checks the rotation itself)
    source, before = skip, skipper
    for flag, field, value in (("--warp-interp", "warp_interp", "cubic"),
                               ("--warp-geometry", "warp_geometry", "rotation")):
        out = tmp_path / value
        assert cli.main(["action-conditioning", str(source), flag, value, "--out", str(out)]) == 0
        after = WorldModel.load(out)
        assert getattr(after.config.dit, field) == value and getattr(before.config.dit, field) != value
        assert after.config.replace(dit=before.config.dit) == before.config
        assert all(np.array_equal(np.asarray(a), np.asarray(b))
                   for a, b in zip(jax.tree.leaves(after.params), jax.tree.leaves(before.params)))
        source, before = out, after
    cubic, cubist = tmp_path / "cubic", WorldModel.load(tmp_path / "cubic")
    # the jump warp too: the weights kept, the same frames; the streaming state carries the simulated jump from
    # step to step (test_camera.py checks that a trained warp reads it)
    jump = tmp_path / "jump"
    assert cli.main(["action-conditioning", str(cubic), "--jump-warp", "0.617", "--out", str(jump)]) == 0
    jumper = WorldModel.load(jump)
    assert jumper.config.dit.jump_warp == 0.617 and jumper.config.replace(dit=cubist.config.dit) == cubist.config
    assert all(np.array_equal(np.asarray(a), np.asarray(b))
               for a, b in zip(jax.tree.leaves(jumper.params), jax.tree.leaves(cubist.params)))
    actions[..., MODEL_INDEX["jump"]] = 1.0  # jump held: the warp input moves, its rows still at zero
    outs = [third_step(model, first, actions) for model in (cubist, jumper)]
    assert np.abs(outs[0] - outs[1]).max() <= 1
    state = jumper.init(first, 0)
    for _ in range(3):  # step i commits frame i - 1: frames 1 and 2 jumped, 8 ticks in the air
        _, state = jumper.step(state, actions)
    height = np.asarray(state.dit_cache.jump)[..., 0]
    np.testing.assert_allclose(height, 1.0245, atol=1e-3)  # the engine's height 8 ticks into a jump
    with pytest.raises(ValueError, match="jump_warp"):
        with_action_conditioning(src, tmp_path / "nojump", jump_warp=0.617)  # no camera warp to carry it


def test_self_forcing_stage_runs_from_stages_2_and_3(run, data):
    assert cli.main(["self-forcing", "--preset", "test", "--data", str(data), "--out", str(run)]) == 0
    assert (model_dir(run, "self-forcing") / "config.json").is_file()
    metrics = read_metrics(run / "self-forcing" / "metrics.jsonl")
    assert [m["step"] for m in metrics] == [1, 2]
    assert "generator/loss" in metrics[0] and "critic/loss" in metrics[0]  # iteration 0 updates both
    assert "generator/loss" not in metrics[1] and "critic/loss" in metrics[1]
    assert list((run / "self-forcing" / "samples").glob("*.mp4"))


def test_evaluate_scores_rollouts_against_copy_last_and_the_vae_ceiling(run, data, tmp_path):
    from training.evaluate import evaluate

    result = evaluate(model_dir(run, "mp-causal"), data, tmp_path, num_segments=2, steps=2, long_steps=3,
                      sheet_steps=2)
    r = result["rollout"]
    assert r["segments"] == 2 and r["frames"] == 1 + 4 * 2
    for key in ("psnr_model_by_step_db", "psnr_copy_last_frame_by_step_db", "psnr_vae_reconstruction_by_step_db",
                "psnr_teacher_forced_by_step_db"):
        assert len(r[key]) == 2, key
    # the by-step means average to the overall means (every step has the same number of frames)
    assert sum(r["psnr_copy_last_frame_by_step_db"]) / 2 == pytest.approx(r["psnr_copy_last_frame_db"])
    # the VAE's reconstruction is a real decode of the clip: a finite PSNR in the range of a trained codec
    assert 10.0 < r["psnr_vae_reconstruction_db"] < 60.0
    assert r["beats_copy_last_frame"] == (r["psnr_model_db"] > r["psnr_copy_last_frame_db"])
    for name in ("model", "teacher_forced", "vae_reconstruction"):  # the fade: sharpness and contrast per step
        assert len(r[f"sharpness_ratio_{name}_by_step"]) == len(r[f"pixel_std_{name}_by_step"]) == 2, name
        assert 0.0 <= r[f"sharpness_ratio_{name}"] and min(r[f"pixel_std_{name}_by_step"]) >= 0.0
    assert len(r["pixel_std_truth_by_step"]) == 2 and min(r["pixel_std_truth_by_step"]) > 0.0
    # direction agreement of every rollout, on the steps where the truth's motion shows (None when none does)
    assert 0 <= r["direction_valid_steps"] <= 2 * 2 * 2  # segments x players x steps
    for name in ("model", "zero_actions", "teacher_forced", "teacher_forced_zero_actions", "vae_reconstruction"):
        v = r[f"direction_agreement_{name}"]
        assert (v is None) == (r["direction_valid_steps"] == 0), name
    assert len(result["long_rollout"]["psnr_db"]) == 1
    assert json.loads((tmp_path / "eval.json").read_text())["rollout"] == r
    assert (tmp_path / "contact_sheet.png").is_file() and (tmp_path / "rollout_0.mp4").is_file()


def test_evaluate_starts_a_partner_map_model_from_the_recorded_poses(data, tmp_path):
    """A partner-map model (``DiTConfig.partner_map``) needs the players' poses at each segment's first frame:
    ``evaluate`` reads them from the recordings (record start + 1, the frame ``DuetDataset.segment`` starts at)."""
    import dataclasses

    from solaris_env.world_model.config import preset
    from solaris_env.world_model.world_model import WorldModel
    from training.duet import DuetDataset
    from training.episodes import SegmentMP
    from training.evaluate import evaluate, start_poses

    base = preset("test")
    cfg = base.replace(dit=dataclasses.replace(base.dit, partner_map=10.0))
    WorldModel.from_config(cfg, seed=0).save(tmp_path / "pm")
    result = evaluate(tmp_path / "pm", data, tmp_path / "out", num_segments=2, steps=2, long_steps=3, sheet_steps=2)
    assert result["rollout"]["segments"] == 2 and (tmp_path / "out" / "contact_sheet.png").is_file()
    dataset = DuetDataset(data, "test", obs_size=(cfg.frame_height, cfg.frame_width))
    ep = dataset.valid_ids[0]
    recs = dataset.recordings(ep)
    poses = start_poses(dataset, SegmentMP(ep, 3, 5))
    np.testing.assert_array_equal(poses, np.stack([recs[0].pose_T5[4], recs[1].pose_T5[6]]))
    assert poses.shape == (2, 5) and np.isfinite(poses).all()


def test_all_keeps_within_its_time_budget(run, data, tmp_path, monkeypatch):
    """``all`` with a budget already spent: the finished stages are skipped, stage 3 (the elastic stage) stops
    after its first step with a checkpoint and a model, Self Forcing still runs and writes the final model, and
    the clock is on disk."""
    import shutil

    from solaris_env.world_model.world_model import WorldModel

    out = tmp_path / "run"
    for stage in ("vae", "vae-decoder", "sp", "mp-bidirectional", "latents"):
        shutil.copytree(run / stage, out / stage)
    config = json.loads((REPO / "training" / "configs" / "test.json").read_text())
    config["all"] = {"time_budget_min": 1e-4, "elastic_stage": "mp-causal", "reserve_min": 0}
    config["mp-causal"].update(sample_every=10**6)
    config["self-forcing"].update(steps=1, sample_every=10**6)
    config_path = tmp_path / "config.json"
    config_path.write_text(json.dumps(config))
    monkeypatch.setattr(cli, "collect_if_missing", lambda *a: None)  # the data is there; collection is not tested here
    assert cli.main(["all", "--preset", "test", "--config", str(config_path), "--data", str(data),
                     "--out", str(out)]) == 0
    assert [m["step"] for m in read_metrics(out / "mp-causal" / "metrics.jsonl")] == [1]  # of 3 configured
    assert (model_dir(out, "mp-causal") / "config.json").is_file()
    assert WorldModel.load(model_dir(out, "self-forcing")).config.name == "test"  # the last stage: the final model
    clock = json.loads((out / "all_clock.json").read_text())
    assert clock["stages"]["mp-causal_steps"] == 1
    assert clock["spent_s"] >= clock["stages"]["mp-causal_s"] + clock["stages"]["self-forcing_s"] > 0
    assert "vae_s" not in clock["stages"]  # skipped stages cost nothing


def test_the_vae_stage_fits_a_linear_patch_codec_and_steps_0_keeps_the_fit(data, tmp_path, monkeypatch):
    """A ``linear_patch`` codec (VAEConfig.codec) is fitted to the data's patches before any update; ``--steps
    0`` writes that fit with its latent statistics, and it reconstructs the held-out clips far better than
    the codec's random start; the vae-decoder stage refuses it by name."""
    import dataclasses

    from solaris_env.world_model import config as config_module
    from solaris_env.world_model.world_model import WorldModel
    from training import train as train_module
    from training.stage_config import load_stage_config

    def codec_preset(name, **override):
        cfg = config_module.preset(name, **override)
        return cfg.replace(vae=dataclasses.replace(cfg.vae, codec="linear_patch"))

    monkeypatch.setattr(train_module, "make_preset", codec_preset)
    sc = load_stage_config("test").stages["vae"]
    path = train_module.train_vae(tmp_path, data, "test", sc, steps=0)
    fit = json.loads((tmp_path / "vae" / "codec_fit.jsonl").read_text().splitlines()[0])
    assert fit["patches"] > 192 and 0.5 < fit["variance_kept"] < 1
    summary = json.loads((tmp_path / "vae" / "summary.json").read_text())
    assert summary["steps"] == 0 and len(summary["latent_std"]) == 4 and summary["test_psnr_db"] > 20
    model = WorldModel.load(path)
    assert model.config.vae.codec == "linear_patch" and model.config.vae.latent_std == tuple(summary["latent_std"])
    with pytest.raises(ValueError, match="'linear_patch' codec"):
        train_module.train_vae_decoder(tmp_path, data, "test", load_stage_config("test").stages["vae-decoder"])
