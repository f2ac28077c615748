"""benchmarks.eval_tasks: the five-task benchmark on a tiny engine eval set and a random test-preset model."""

import json

import numpy as np
import pytest

from benchmarks import eval_tasks as et
from solaris_env.judges import evaluate
from solaris_env.judges.episodes import find_episodes, read_video
from solaris_env.judges.features import FrameFeatures
from solaris_env.judges.judge import Judge
from solaris_env.judges.scoring import query_views
from solaris_env.spaces import camera_linear, mineflayer_records_to_vectors

TYPES = ("rotationEval", "oneLooksAwayEval")


@pytest.fixture(scope="module")
def model():
    from solaris_env.world_model.world_model import WorldModel

    return WorldModel.from_preset("test")


@pytest.fixture(scope="module")
def data_dir(collect_eval, model):
    """One episode of each of TYPES at the test model's resolution."""
    size = model.frame_shape[0]
    assert model.frame_shape == (size, size, 3)
    return collect_eval(TYPES, size, seed=3)


@pytest.fixture(scope="module")
def segments(data_dir):
    segs, skipped = et.make_segments(find_episodes(data_dir), et.EVAL_NUM_FRAMES)
    assert not skipped and sorted(s.episode.episode_type for s in segs) == sorted(TYPES)
    return segs


@pytest.fixture(scope="module")
def judge():
    return Judge.load()


@pytest.fixture(scope="module")
def features():
    return FrameFeatures.load()


@pytest.fixture(scope="module")
def result(data_dir, model, judge, features):
    return et.run_benchmark(data_dir, {"default": model, "concat": None}, seeds=(0, 1), worlds=2,
                            judge=judge, features=features)


def test_segment_window_follows_the_generated_video_alignment(segments):
    for seg in segments:
        ep, s, T = seg.episode, seg.start, seg.num_frames
        assert T == 257 and all(q.frame1 == s for q in ep.queries())  # the window starts at the judge's frame1
        assert seg.generated_index(s + 1) == 0 and seg.generated_index(s + 1 + 37) == 37
        assert seg.generated_index(s) == 0  # translation's first image: GT frame1 -> generated frame 0
        with pytest.raises(ValueError, match="outside"):
            seg.generated_index(s + 1 + T)
        with pytest.raises(ValueError, match="outside"):
            seg.generated_index(s - 1)
        gt = seg.ground_truth()
        assert gt.shape[:2] == (T, 2)
        for p, bot in enumerate(seg.players):
            video = read_video(ep.video_path(bot))
            np.testing.assert_array_equal(gt[:, p], video[s + 1:s + 1 + T])  # generated frame j <-> GT s + 1 + j
        act = seg.actions()
        assert act.shape == (T, 2, 25)
        for p, bot in enumerate(seg.players):  # action of tick s + j goes with generated frame j
            recorded_T25 = camera_linear(mineflayer_records_to_vectors(ep.records[bot]))
            np.testing.assert_array_equal(act[:, p], recorded_T25[s:s + T])


def test_copy_first_frame_is_the_frame_the_model_starts_from(segments):
    frames = et.copy_first_frame_source(segments)
    for seg in segments:
        for q in seg.episode.queries():
            for bot, g in query_views(q):
                first = read_video(seg.episode.video_path(bot))[seg.start + 1]
                np.testing.assert_array_equal(frames(seg.episode, bot, g), first)


def test_generated_videos_keep_exactly_the_query_frames(model, segments, features):
    videos = et.generate(model, segments, seed=0, worlds=2, features=features)
    wanted = {(seg.episode.key, bot, seg.generated_index(g)) for seg in segments
              for q in seg.episode.queries() for bot, g in query_views(q)}
    assert set(videos.frames) == wanted
    assert all(f.shape == model.frame_shape and f.dtype == np.uint8 for f in videos.frames.values())
    for seg in segments:  # features of all T frames of both players
        (f,) = videos.features[seg.episode.episode_type]
        assert f.shape == (seg.num_frames * 2, features.dim)
    other = et.generate(model, segments, seed=5, worlds=2)  # another sampling seed changes the frames
    assert any(not np.array_equal(videos.frames[k], other.frames[k]) for k in wanted)


def test_ground_truth_row_equals_the_evaluate_cli(data_dir, result, tmp_path):
    out = tmp_path / "gt.json"
    assert evaluate.main(["--data", str(data_dir), "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    row = result["rows"]["ground_truth"]
    (trial,) = row["trials"]
    assert trial["per_type"] == report["episode_level"]
    assert trial["tasks"] == report["tasks"]
    assert all(v["std"] == 0.0 for v in row["accuracy"]["tasks"].values())


def test_trials_schema_and_table(result):
    assert set(result) >= {"rows", "table", "table_per_type", "episodes_per_type", "skipped", "num_frames", "seeds", "worlds", "timing_s"}
    assert result["episodes_per_type"] == {t: 1 for t in TYPES} and result["seeds"] == [0, 1]
    rows = result["rows"]
    assert list(rows) == ["default", "concat", "ground_truth", "copy_first_frame"]
    assert rows["concat"] == {"status": et.NO_CHECKPOINT}
    default = rows["default"]
    assert [t["seed"] for t in default["trials"]] == [0, 1] and len(default["timing"]) == 2
    for acc in default["accuracy"]["tasks"].values():
        assert len(acc["trials"]) == 2
        assert acc["mean"] == pytest.approx(np.mean(acc["trials"]))
        assert acc["std"] == pytest.approx(np.std(acc["trials"]))
    assert set(default["accuracy"]["tasks"]) == {"Movement", "Grounding"}
    assert set(default["frechet"]["tasks_mean"]) == {"Movement", "Grounding"}
    assert rows["ground_truth"]["frechet"]["tasks_mean"] == {"Movement": 0.0, "Grounding": 0.0}
    assert all(v > 0 for v in rows["copy_first_frame"]["frechet"]["tasks_mean"].values())
    json.dumps(result, allow_nan=False)  # serialisable, no NaN
    table = result["table"].splitlines()
    assert table[0].startswith("| model | Movement judge ↑ | Movement FD ↓ | Grounding judge ↑")
    assert table[3].startswith("| concat | no checkpoint")
    assert "± 0.0" in table[4]  # ground truth: deterministic
    per_type = result["table_per_type"].splitlines()
    assert per_type[0] == "| model | rotationEval | oneLooksAwayEval |" and len(per_type) == 2 + 3  # concat left out


def test_frechet_by_task_is_zero_for_a_set_with_itself_and_positive_otherwise(segments, features):
    real = et.features_by_type(features, segments)
    copy = et.features_by_type(features, segments, copy_first=True)
    same = et.frechet_by_task(real, real)
    assert all(v == pytest.approx(0.0, abs=1e-6) for v in same["tasks"].values())
    diff = et.frechet_by_task(real, copy)
    assert set(diff["per_type"]) == set(TYPES) and all(v > 0 for v in diff["tasks"].values())


def test_frame_size_mismatch_and_bad_inception_weights_fail_clearly(segments, tmp_path):
    class Wrong:
        frame_shape = (64, 64, 3)

    with pytest.raises(ValueError, match="--resolution 64"):
        et.check_frame_size(Wrong(), segments)
    out = str(tmp_path / "x.json")  # both fail before any world model is loaded
    with pytest.raises(FileNotFoundError, match="pt_inception.pth"):
        et.main(["--data", str(tmp_path), "--inception-weights", str(tmp_path / "pt_inception.pth"), "--out", out])
    torch = pytest.importorskip("torch")
    torch.save({"not_inception.weight": torch.zeros(1)}, tmp_path / "other.pth")
    with pytest.raises(ValueError, match="unexpected key 'not_inception.weight'"):
        et.main(["--data", str(tmp_path), "--inception-weights", str(tmp_path / "other.pth"), "--out", out])


def test_fid_features_add_a_fid_next_to_the_in_domain_fd(data_dir, model, judge, features, monkeypatch):
    """The --inception-weights wiring, with the judge features standing in for the FID Inception (~6 GFLOP a
    frame): every row's and trial's FID equals its in-domain FD, and the table gets a FID column per task."""
    import training.samples

    fast_videos = lambda model, obs, act, seed, poses_BP5=None: 255 - obs  # noqa: E731
    monkeypatch.setattr(training.samples, "rollout", fast_videos)
    res = et.run_benchmark(data_dir, {"default": model, "concat": None}, seeds=(0,), worlds=2, judge=judge,
                           features=features, fid_features=features)
    rows = res["rows"]
    for name in ("default", "ground_truth", "copy_first_frame"):
        assert rows[name]["fid"] == rows[name]["frechet"]
    (trial,) = rows["default"]["trials"]
    assert trial["fid"] == trial["frechet"] and set(trial["fid"]["per_type"]) == set(TYPES)
    assert all(v > 0 for v in rows["default"]["fid"]["tasks_mean"].values())
    assert rows["ground_truth"]["fid"]["tasks_mean"] == {"Movement": 0.0, "Grounding": 0.0}
    assert "ground_truth_fid_features_s" in res["timing_s"]
    json.dumps(res, allow_nan=False)
    table = res["table"].splitlines()
    num_tasks = len(et.questions.TASKS)
    assert table[0].startswith("| model | Movement judge ↑ | Movement FD ↓ | Movement FID ↓ | Grounding judge")
    assert table[1] == "|---|" + "---:|" * (3 * num_tasks)
    assert table[3] == "| concat | " + " | ".join([et.NO_CHECKPOINT, "–", "–"] * num_tasks) + " |"
    assert all(line.count("|") == 2 + 3 * num_tasks for line in table)


def test_a_partner_map_model_starts_from_the_recorded_poses(model, segments, tmp_path):
    """A partner-map model (docs/model.md §8.6) gets every player's pose at the start frame (record s + 1); with the
    map's row at zero it makes the frames of the model it was made from."""
    from solaris_env.world_model import checkpoint
    from solaris_env.world_model.components import COMPONENTS
    from solaris_env.world_model.world_model import WorldModel
    from training import cli
    from training.samples import rollout

    for seg in segments:
        poses = seg.start_poses()
        for p, bot in enumerate(seg.players):
            r = seg.episode.records[bot][seg.start + 1]
            np.testing.assert_allclose(poses[p], [r[k] for k in ("x", "y", "z", "yaw", "pitch")], rtol=1e-6)
    checkpoint.save(tmp_path / "base", model.config, dict(zip(COMPONENTS, model.params)))
    assert cli.main(["action-conditioning", str(tmp_path / "base"), "--partner-map", "10",
                     "--out", str(tmp_path / "pm")]) == 0
    pm = WorldModel.load(tmp_path / "pm")
    seg = segments[:1]
    with pytest.raises(ValueError, match="poses"):
        rollout(pm, seg[0].ground_truth()[None, :5], seg[0].actions()[None, :5])
    base_frames, pm_frames = et.generate(model, seg, seed=0, worlds=1), et.generate(pm, seg, seed=0, worlds=1)
    assert set(base_frames.frames) == set(pm_frames.frames)
    for key, frame in base_frames.frames.items():
        np.testing.assert_array_equal(pm_frames.frames[key], frame)
