"""benchmarks.training_speed: the per-stage summary of metrics.jsonl (the compile interval left out)."""

import json

from benchmarks.training_speed import summarise_run, summarise_stage


def _write_metrics(path, rows):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_summary_leaves_out_the_compile_interval(tmp_path):
    rows = [{"step": 10 * (i + 1), "time": 100.0 + 10 * i, "steps_per_s": sps, "tokens_per_s": 100 * sps}
            for i, sps in enumerate([0.1, 2.0, 1.0, 3.0])]
    _write_metrics(tmp_path / "mp-causal" / "metrics.jsonl", rows)
    s = summarise_stage(tmp_path / "mp-causal" / "metrics.jsonl")
    assert s["steps"] == 40 and s["intervals"] == 3
    assert s["steps_per_s"] == 2.0 and s["tokens_per_s"] == 200.0  # median of 2, 1, 3 (0.1 = compile)
    assert s["wall_s"] == 30.0


def test_run_summary_lists_only_stages_with_metrics(tmp_path):
    _write_metrics(tmp_path / "vae" / "metrics.jsonl", [{"step": 5, "time": 0.0, "steps_per_s": 1.0,
                                                         "tokens_per_s": 9.0}])
    cfg = {"vae": {"batch_size": 4, "num_frames": 5}}
    stages = summarise_run(tmp_path, cfg)
    assert list(stages) == ["vae"] and stages["vae"]["batch_size"] == 4 and stages["vae"]["steps_per_s"] == 1.0


def test_project_all_scales_collection_and_the_latent_cache_by_episodes():
    from benchmarks.training_speed import project_all

    # measured on 4 episodes: sp ran 10 updates at 2/s in 25 s -> 20 s fixed, of which mp-bidirectional's 5 s
    # (compile, samples) recur and 15 s are the latent cache of 4 episodes
    stages = {"vae": {"steps": 10, "steps_per_s": 1.0, "stage_wall_s": 15.0},
              "sp": {"steps": 10, "steps_per_s": 2.0, "stage_wall_s": 25.0},
              "mp-bidirectional": {"steps": 10, "steps_per_s": 1.0, "stage_wall_s": 15.0}}
    shipped = {"collect": {"episodes": 40}, "vae": {"steps": 100}, "sp": {"steps": 200},
               "mp-bidirectional": {"steps": 50}}
    proj = project_all(stages, {"collect": 6.0}, episodes=4, shipped=shipped)
    assert proj["parts_s"] == {"collect_s": 60.0, "vae_s": 100.0 + 5.0, "latent_cache_s": 150.0,
                               "sp_s": 100.0 + 5.0 + 150.0, "mp-bidirectional_s": 50.0 + 5.0}
    assert proj["total_min"] == (60.0 + 105.0 + 255.0 + 55.0) / 60


def test_remat_ab_times_both_arms_and_checks_their_losses(tmp_path):
    """``--remat-ab``: one model's stage-3 train step with remat off and on, alternating; the same losses."""
    from benchmarks.training_speed import main
    from solaris_env.world_model.world_model import WorldModel

    WorldModel.from_preset("test", seed=0).save(tmp_path / "model")
    out = tmp_path / "remat.json"
    assert main(["--remat-ab", str(tmp_path / "model"), "--rounds", "2", "--steps-per-round", "1",
                 "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["preset"] == "test" and result["losses_equal"] and result["max_loss_difference"] < 1e-4
    assert len(result["s_per_step"]["off"]) == len(result["s_per_step"]["on"]) == 2
    assert result["speedup"] == result["median_s_per_step"]["off"] / result["median_s_per_step"]["on"] > 0
