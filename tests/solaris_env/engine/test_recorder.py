"""``solaris_env.engine.recorder`` (names, split, mp4, atomic writes) and capture.ground_truth.

No renderer here: frames are synthetic, episodes are simulated only (~0.1 s each).
"""

import fnmatch
import json
import os
import re

import numpy as np
import pytest

from solaris_env.engine import recorder as rec
from solaris_env.engine.bots.runner import EpisodeConfig, run_episode
from solaris_env.engine.capture import REGION_LEFT_MAX_U, REGION_RIGHT_MIN_U, ground_truth, screen_region

# Layout name patterns (docs/data-format.md §2, §5).
TRAIN_RE = re.compile(r"batch_\d+_\d{6}_(Alpha|Bravo)_instance_\d{3}(\.mp4|\.json|_episode_info\.json)")
EVAL_RE = re.compile(r"\d{6}_(Alpha|Bravo)_instance_\d{3}(_camera\.mp4|\.json)")
SIDECAR_RE = re.compile(r"(batch_\d+_)?\d{6}_instance_\d{3}_groundtruth\.json")


@pytest.fixture(scope="module")
def episode():
    return run_episode(EpisodeConfig(seed=0, instance=0, episode=0, world_kind="flat", episode_type="rotationEval"))


def _frames(output, h=16, w=24):
    P, T = len(output.trace.player_names), output.trace.num_ticks
    ramp = np.linspace(0, 255, w, dtype=np.uint8)
    return np.broadcast_to(ramp[None, None, None, :, None], (P, T, h, w, 3)).copy()


def _files(root):
    return sorted(p for p in root.rglob("*") if p.is_file())


# ---------------------------------------------------------------------------------------------
# Names and split
# ---------------------------------------------------------------------------------------------


def test_training_names_match_spec():
    key = rec.EpisodeKey(episode=12, instance=3, batch=7)
    names = key.file_names()
    assert names[0] == "batch_7_000012_Alpha_instance_003.mp4"
    bot_files = [n for n in names if not n.endswith("_groundtruth.json")]
    assert len(bot_files) == 6 and all(TRAIN_RE.fullmatch(n) for n in bot_files)
    assert SIDECAR_RE.fullmatch(key.sidecar_name)
    assert names[-2:] == ["batch_7_000012_Alpha_instance_003_episode_info.json",
                          "batch_7_000012_Bravo_instance_003_episode_info.json"]  # commit markers last
    # the loader's glob and the counterpart rule never pick up the sidecar
    assert [n for n in names if fnmatch.fnmatch(n, "*_Alpha_*.mp4")] == ["batch_7_000012_Alpha_instance_003.mp4"]
    assert "_Alpha_" not in key.sidecar_name and "_Bravo_" not in key.sidecar_name


def test_eval_names_match_spec():
    key = rec.EpisodeKey(episode=5, instance=1, eval_type="rotationEval")
    names = key.file_names()
    assert names[:2] == ["000005_Alpha_instance_001_camera.mp4", "000005_Bravo_instance_001_camera.mp4"]
    assert names[-2:] == ["000005_Alpha_instance_001.json", "000005_Bravo_instance_001.json"]
    assert key.sidecar_name == "000005_instance_001_groundtruth.json"
    assert all(EVAL_RE.fullmatch(n) for n in names if n != key.sidecar_name)
    assert not any(n.endswith("_episode_info.json") for n in names)


def test_split_is_deterministic_and_about_the_fraction():
    keys = [(s, i, e) for s in range(2) for i in range(5) for e in range(500)]
    splits = [rec.split_of(*k) for k in keys]
    assert splits == [rec.split_of(*k) for k in keys]
    assert 0.005 < splits.count("test") / len(keys) < 0.016
    assert {rec.split_of(*k, test_fraction=0.0) for k in keys[:50]} == {"train"}
    assert {rec.split_of(*k, test_fraction=1.0) for k in keys[:50]} == {"test"}
    with pytest.raises(ValueError):
        rec.split_of(0, 0, 0, test_fraction=1.5)


# ---------------------------------------------------------------------------------------------
# mp4
# ---------------------------------------------------------------------------------------------


def test_write_mp4_exact_frame_count(tmp_path):
    import cv2

    frames = np.zeros((37, 32, 48, 3), np.uint8)
    frames[..., 0] = np.arange(37)[:, None, None] * 6  # a red ramp over time
    path = tmp_path / "v.mp4"
    rec.write_mp4(path, frames)
    cap = cv2.VideoCapture(str(path))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 37
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(rec.VIDEO_FPS)
    decoded = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        decoded.append(bgr[..., ::-1])
    assert len(decoded) == 37
    assert np.abs(np.asarray(decoded, float) - frames).mean() < 8  # RGB order kept (lossy codec)


def test_write_mp4_rejects_bad_frames(tmp_path):
    with pytest.raises(ValueError):
        rec.write_mp4(tmp_path / "v.mp4", np.zeros((3, 8, 8, 3), np.float32))


# ---------------------------------------------------------------------------------------------
# Atomic episode writes
# ---------------------------------------------------------------------------------------------


def test_write_episode_complete_and_commit_order(tmp_path, episode, monkeypatch):
    key = rec.EpisodeKey(episode=0, instance=0, batch=3)
    moved = []
    real_replace = os.replace
    monkeypatch.setattr(rec.os, "replace", lambda a, b: (moved.append(os.path.basename(b)), real_replace(a, b)))
    assert not rec.episode_complete(tmp_path, key)
    paths = rec.write_episode(tmp_path, key, episode, _frames(episode), {"extra": 1}, split="train")
    assert rec.episode_complete(tmp_path, key)
    assert moved == key.file_names() and moved[-1].endswith("_episode_info.json")
    assert [p.name for p in paths] == key.file_names()
    assert _files(tmp_path) == sorted(paths)  # no staging leftovers
    info = json.loads((tmp_path / "duet/train/batch_3_000000_Alpha_instance_000_episode_info.json").read_text())
    assert info == episode.infos[0]
    side = json.loads((tmp_path / "duet/train" / key.sidecar_name).read_text())
    assert side["episode_type"] == "rotationEval" and side["extra"] == 1 and side["aborted"] is False


def test_crash_while_staging_leaves_nothing(tmp_path, episode, monkeypatch):
    key = rec.EpisodeKey(episode=0, instance=0, eval_type="rotationEval")
    calls, real_write_mp4 = [], rec.write_mp4

    def failing_mp4(path, frames):
        calls.append(path)
        if len(calls) == 2:  # the first video is written, the second one crashes half-way
            path.write_bytes(b"partial")
            raise OSError("disk full")
        real_write_mp4(path, frames)

    monkeypatch.setattr(rec, "write_mp4", failing_mp4)
    with pytest.raises(OSError, match="disk full"):
        rec.write_episode(tmp_path, key, episode, _frames(episode), {})
    assert _files(tmp_path) == []
    assert not rec.episode_complete(tmp_path, key)


def test_crash_while_committing_is_incomplete_then_repaired(tmp_path, episode, monkeypatch):
    key = rec.EpisodeKey(episode=0, instance=0, batch=0)
    real_replace = os.replace
    n = []

    def flaky_replace(a, b):
        n.append(b)
        if len(n) == 3:
            raise OSError("power cut")
        real_replace(a, b)

    monkeypatch.setattr(rec.os, "replace", flaky_replace)
    with pytest.raises(OSError):
        rec.write_episode(tmp_path, key, episode, _frames(episode), {})
    final = tmp_path / "duet" / "train"
    assert len(list(final.iterdir())) == 2 and not rec.episode_complete(tmp_path, key)  # markers never moved
    monkeypatch.setattr(rec.os, "replace", real_replace)
    rec.write_episode(tmp_path, key, episode, _frames(episode), {}, split="test")  # e.g. another fraction
    assert rec.episode_complete(tmp_path, key)
    assert list(final.iterdir()) == []  # leftovers of the crash were removed
    assert sorted(p.name for p in (tmp_path / "duet" / "test").iterdir()) == sorted(key.file_names())


def test_clean_staging(tmp_path):
    stale = tmp_path / rec.STAGING_DIR / "batch_0_000001_000-123-abcd"
    stale.mkdir(parents=True)
    (stale / "x.mp4").write_bytes(b"junk")
    assert rec.clean_staging(tmp_path) == 1
    assert not stale.exists()
    assert rec.clean_staging(tmp_path, remove_root=True) == 0 and not (tmp_path / rec.STAGING_DIR).exists()


def test_mismatched_frames_rejected(tmp_path, episode):
    key = rec.EpisodeKey(episode=0, instance=0)
    with pytest.raises(ValueError):
        rec.write_episode(tmp_path, key, episode, _frames(episode)[:, :-1], {})
    assert _files(tmp_path) == []


# ---------------------------------------------------------------------------------------------
# Ground truth from a synthetic avatar-id buffer
# ---------------------------------------------------------------------------------------------


def test_screen_region_thresholds():
    assert screen_region(None) == "none"
    assert screen_region(0.0) == screen_region(REGION_LEFT_MAX_U - 1e-6) == "left"
    assert screen_region(REGION_LEFT_MAX_U) == screen_region(0.5) == "center"
    assert screen_region(REGION_RIGHT_MIN_U) == screen_region(1.0) == "right"


def test_ground_truth_from_synthetic_ids(episode):
    trace = episode.trace
    T, H, W = trace.num_ticks, 10, 30
    aid = np.full((2, T, H, W), -1, np.int8)
    aid[0, 0, 2:4, 0:3] = 1  # Alpha sees Bravo at the left edge in frame 0 (6 pixels)
    aid[1, :, 5, 27:30] = 0  # Bravo sees Alpha on the right in every frame
    ev = episode.tick_events
    gt = ground_truth(trace, aid, ev)
    json.dumps(gt)  # serialisable
    a2b, b2a = gt["sight"]["Alpha"]["Bravo"], gt["sight"]["Bravo"]["Alpha"]
    assert set(gt["sight"]["Alpha"]) == {"Bravo"}  # no self entry
    assert a2b["visible"][:2] == [True, False] and a2b["region"][:2] == ["left", "none"]
    assert a2b["pixel_fraction"][0] == pytest.approx(6 / (H * W), abs=1e-5)
    assert a2b["u"][0] == pytest.approx(1.5 / W, abs=1e-4) and a2b["v"][0] == pytest.approx(3.0 / H, abs=1e-4)
    assert a2b["u"][1] is None and a2b["v"][1] is None
    assert all(r == "right" for r in b2a["region"]) and all(b2a["visible"])
    assert all(len(v) == T for v in a2b.values()) and len(gt["pose"]["Alpha"]["yaw"]) == T
    feet = trace.feet_TP3
    assert a2b["distance"][0] == pytest.approx(float(np.linalg.norm(feet[0, 1] - feet[0, 0])), abs=1e-3)
    assert gt["pose"]["Bravo"]["x"][0] == pytest.approx(episode.trace.records[1][0]["x"], abs=1e-3)


def test_ground_truth_block_events(episode):
    from solaris_env.engine.game import TickEvents, empty_record

    T = episode.trace.num_ticks
    events = [[TickEvents(empty_record()), TickEvents(empty_record())] for _ in range(T)]
    events[4][1].placed.append((1, 64, 2, 1))
    events[9][0].mined.append((1, 64, 2, 1))
    events[9][0].hit_player = 1
    gt = ground_truth(episode.trace, np.full((2, T, 4, 4), -1, np.int8), events)
    assert gt["blocks"]["tick"] == [4, 9] and gt["blocks"]["player"] == ["Bravo", "Alpha"]
    assert gt["blocks"]["action"] == ["place", "mine"] and gt["blocks"]["x"] == [1, 1]
    assert gt["hits"] == {"tick": [9], "attacker": ["Alpha"], "victim": ["Bravo"]}
