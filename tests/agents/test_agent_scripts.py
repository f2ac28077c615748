"""The agent scripts end to end on tiny budgets (in-process, as ``python -m agents.<script>`` runs them): PPO in the
real engine and in the dream writes checkpoints that load and act; evaluate.py and transfer.py write their JSON
(and plot) atomically with the promised fields."""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from agents import evaluate, ppo_dream, ppo_real, transfer
from agents.common import parse_args
from agents.plots import FRAME_SCALE
from agents.policies import PPOPolicy, make_policy
from agents.ppo_common import TASK_CAMERA_AXES, TASK_KEYS
from solaris_env.spaces import BINARY_KEYS, validate_action
from solaris_env.tasks import JUDGED_TASKS

TINY_PPO = ["--total-timesteps", "64", "--n-steps", "16", "--batch-size", "16", "--n-epochs", "1",
            "--checkpoint-every", "32", "--max-steps", "8", "--start-states", "4"]


@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    """A 64-step ppo_real run (2 envs x 16 steps x 2 updates) at 36x36."""
    out = tmp_path_factory.mktemp("ppo_real")
    ppo_real.main([*TINY_PPO, "--task", "face_partner", "--num-envs", "2", "--resolution", "36", "--out", str(out)])
    return out


def test_ppo_real_writes_checkpoints_that_load_and_act(real_run, real):
    checkpoints = real_run / "checkpoints"
    assert sorted(p.name for p in checkpoints.iterdir()) == [
        "step_000000032.json", "step_000000032.zip", "step_000000064.json", "step_000000064.zip"]
    assert not list(real_run.rglob(".*tmp*"))  # atomic writes leave no temporary files
    rows = (real_run / "progress.csv").read_text().splitlines()
    assert "rollout/ep_rew_mean" in rows[0] and len(rows) == 3  # header + one row per update
    meta = json.loads((checkpoints / "step_000000064.json").read_text())
    assert meta["env"] == "real" and meta["task"] == "face_partner" and meta["step"] == 64
    assert meta["frames_per_step"] == 4 and meta["obs_shape"] == [36, 36, 3]
    assert meta["codec"]["keys"] == [] and meta["codec"]["camera_axes"] == ["yaw"]  # face_partner: turn only
    # the run's arguments name its directory without the machine's folders (agents.ppo_common.args_record)
    assert meta["args"]["out"] == "/".join(real_run.parts[-2:])
    assert json.loads((real_run / "args.json").read_text())["out"] == meta["args"]["out"]

    policy = make_policy(f"ppo:{checkpoints / 'step_000000064.zip'}")
    assert isinstance(policy, PPOPolicy) and policy.model.num_timesteps == 64
    env = real(ticks_per_step=4)
    obs, _ = env.reset(seed=0)
    policy.reset(env, "Alpha", 0)
    for _ in range(3):
        action = policy.act(obs["Alpha"])
        validate_action(action)
        assert np.abs(action["camera"]).max() <= 10.0 and action["camera"][0] == 0.0
        assert not any(action[k] for k in BINARY_KEYS)
        obs, *_ = env.step({"Alpha": action, "Bravo": make_policy("noop").act(obs["Bravo"])})
    big = cv2.resize(obs["Alpha"], (64, 64))  # another resolution: resized to the policy's input
    assert policy.act(big).keys() == action.keys()
    assert all(np.array_equal(policy.act(obs["Alpha"])[k], policy.act(obs["Alpha"])[k]) for k in action)


def test_ppo_real_resumes_from_its_newest_checkpoint(real_run, tmp_path):
    out = tmp_path / "run"
    shutil.copytree(real_run, out)
    first = (out / "progress.csv").read_text()
    ppo_real.main([*TINY_PPO, "--task", "face_partner", "--num-envs", "2", "--resolution", "36", "--out", str(out),
                   "--total-timesteps", "96"])
    names = sorted(p.name for p in (out / "checkpoints").glob("*.zip"))
    assert names == ["step_000000032.zip", "step_000000064.zip", "step_000000096.zip"]
    assert PPOPolicy(out / "checkpoints" / "step_000000096.zip").model.num_timesteps == 96
    assert (out / "progress-000000064.csv").read_text() == first  # the first run's log is kept
    assert len((out / "progress.csv").read_text().splitlines()) == 2  # header + the one update of this run
    ppo_real.main([*TINY_PPO, "--task", "face_partner", "--num-envs", "2", "--resolution", "36", "--out", str(out),
                   "--total-timesteps", "96"])  # already there: nothing to train, nothing new saved
    assert len(list((out / "checkpoints").glob("*.zip"))) == 3


@pytest.mark.slow
def test_ppo_dream_trains_in_the_test_world_model_and_acts(tmp_path):
    ppo_dream.main([*TINY_PPO, "--task", "approach_partner", "--preset", "test", "--num-worlds", "2",
                    "--obs-size", "36", "--out", str(tmp_path)])
    meta = json.loads((tmp_path / "checkpoints" / "step_000000064.json").read_text())
    assert meta["env"] == "dream" and meta["frames_per_step"] == 4 and meta["obs_shape"] == [36, 36, 3]
    policy = PPOPolicy(tmp_path / "checkpoints" / "step_000000064.zip")
    validate_action(policy.act(np.zeros((32, 32, 3), np.uint8)))  # the test model's frame size


def test_evaluate_end_to_end(real_run, tmp_path):
    out = tmp_path / "policy_eval.json"
    ckpt = real_run / "checkpoints" / "step_000000064.zip"
    results = evaluate.main(["--preset", "test", "--policies", "random", "--ppo-checkpoints", str(ckpt),
                             "--episodes", "2", "--max-steps", "3", "--resamples", "200", "--out", str(out)])
    saved = json.loads(out.read_text())
    # the checkpoint is named without the machine's directories (solaris_env.paths), in the JSON and the legend
    assert [p["name"] for p in saved["policies"]] == ["random", "ppo:" + "/".join(ckpt.parts[-3:])]
    assert str(tmp_path) not in out.read_text() and str(real_run) not in out.read_text()
    assert out.with_suffix(".png").is_file()
    for row in saved["policies"]:
        for kind in ("dream", "real", "real_judge"):
            s = row[kind]
            assert s["n"] == 2 and s["ci_low"] <= s["mean"] <= s["ci_high"]
            assert all(0.0 <= r <= 3.0 for r in s["returns"])  # face_partner: 0/1 per step, 3 steps
        assert row["gap"] == pytest.approx(row["dream"]["mean"] - row["real"]["mean"])
    for pair in ("dream_vs_real", "real_judge_vs_real", "dream_vs_real_judge"):
        assert set(saved["agreement"][pair]) == {"pearson", "spearman", "mmrv", "mean_gap", "mean_abs_gap"}
    assert saved["setup"]["frames_per_step"] == 4 and saved["setup"]["frame_size"] == [32, 32]
    assert saved["goal"]["spearman_min"] == 0.8 and isinstance(saved["goal"]["met"], bool)
    assert results["policies"][0]["real"]["returns"] == saved["policies"][0]["real"]["returns"]
    plot = cv2.imread(str(out.with_suffix(".png")))
    assert plot is not None and plot.shape[2] == 3 and plot.std() > 0
    # the contact sheet: per policy an engine row over a dream row of the first episode (32x32 frames, FRAME_SCALE)
    sheet = cv2.imread(str(tmp_path / "policy_eval_frames.png"))
    assert sheet is not None and sheet.shape[0] == 2 * (2 * FRAME_SCALE * 32) + 4 and sheet.std() > 0


def test_transfer_end_to_end(real_run, tmp_path):
    out = tmp_path / "transfer.json"
    results = transfer.main(["--dream-ppo", str(real_run), "--real-ppo", str(real_run / "checkpoints"),
                             "--references", "random", "bot:0", "--episodes", "2", "--max-steps", "3",
                             "--resolution", "36", "--resamples", "200", "--out", str(out)])
    saved = json.loads(out.read_text())
    assert saved == json.loads(json.dumps(results))
    assert set(saved["returns"]) == {"dream_ppo", "real_ppo", "random", "bot:0"}
    for row in saved["returns"].values():
        assert row["n"] == 2 and row["ci_low"] <= row["mean"] <= row["ci_high"]
    assert saved["returns"]["dream_ppo"]["trained_steps"] == 64  # a run directory stands for its last checkpoint
    assert str(real_run) not in out.read_text() and str(tmp_path) not in out.read_text()  # solaris_env.paths
    assert saved["setup"]["frames_per_step"] == 4


def test_script_arguments_are_checked():
    with pytest.raises(ValueError, match="task must be one of"):
        parse_args(ppo_real.Args, ["--task", "dance"])
    with pytest.raises(ValueError, match="resolution must be >= 36"):
        parse_args(ppo_real.Args, ["--resolution", "32"])
    with pytest.raises(ValueError, match="partner"):
        parse_args(ppo_dream.Args, ["--partner", "bot"])
    with pytest.raises(ValueError, match="keys must be 'task', 'all', 'none' or a comma list"):
        parse_args(ppo_real.Args, ["--keys", "forward,fly"])
    assert set(TASK_KEYS) == set(JUDGED_TASKS)
    assert parse_args(ppo_real.Args, ["--task", "approach_partner"]).policy_keys() == TASK_KEYS["approach_partner"]
    assert parse_args(ppo_real.Args, ["--keys", "jump, use"]).codec().keys == ("jump", "use")
    assert parse_args(ppo_real.Args, ["--keys", "all", "--camera", "both"]).codec().space.shape == (25,)
    assert parse_args(ppo_real.Args, ["--keys", "none"]).codec().space.shape == (1,)  # + yaw
    assert parse_args(ppo_real.Args, ["--keys", "none", "--camera", "both"]).codec().space.shape == (2,)
    assert set(TASK_CAMERA_AXES) == set(JUDGED_TASKS)
    with pytest.raises(ValueError, match="camera must be"):
        parse_args(ppo_real.Args, ["--camera", "roll"])
    args = parse_args(ppo_dream.Args, ["--preset", "test", "--obs-size", "none", "--seed", "3"])
    assert args.preset == "test" and args.obs_size is None and args.seed == 3 and args.checkpoint is None
    assert parse_args(evaluate.Args, ["--policies", "noop", "spin:5"]).policies == ["noop", "spin:5"]
    for task in ("face_partner", "approach_partner"):  # each task's scripted policies and its own results file
        args = parse_args(evaluate.Args, ["--task", task])
        assert args.policies == evaluate.DEFAULT_POLICIES[task] and len(set(args.policies)) >= 7
        assert Path(args.out).name == f"policy_eval_{task}.json"
        assert [make_policy(spec).name for spec in args.policies] == args.policies  # every spec builds
    assert len(evaluate.DEFAULT_POLICIES["face_partner"]) >= 12  # the count without PPO checkpoints
    assert any(p.startswith("seeker-walk") for p in evaluate.DEFAULT_POLICIES["approach_partner"])
    undefaulted = sorted(set(JUDGED_TASKS) - set(evaluate.DEFAULT_POLICIES))
    if undefaulted:
        with pytest.raises(ValueError, match="no default policies"):
            parse_args(evaluate.Args, ["--task", undefaulted[0]])
    with pytest.raises(ValueError, match="--dream-ppo and --real-ppo"):
        parse_args(transfer.Args, [])
    with pytest.raises(FileNotFoundError, match="neither"):
        evaluate.expand_checkpoints(["/nonexistent.zip"])
