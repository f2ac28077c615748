"""The training data (``training.video_io``, ``duet``, ``vpt``, ``samplers``, ``latent_cache``, ``episodes``: loaders,
samplers, batching, latent cache) and the engine's VPT export, on a tiny real dataset collected once per module
(32x32, 2 walkLook episodes + 1 rotationEval eval episode, in-process so the renderer compiles once)."""

import json
import os
import shutil

import cv2
import numpy as np
import pytest

from solaris_env import spaces as sp
from solaris_env.engine import cli
from solaris_env.engine.vpt_export import records_to_vpt_ticks
from training import video_io
from training.duet import DuetDataset
from training.episodes import (
    BAD_JSON,
    BAD_RENDER_TIME,
    COUNT_MISMATCH,
    DECODE_ERROR,
    MISSING_FILE,
    TOO_SHORT,
    UNREADABLE_VIDEO,
    EpisodeError,
    SegmentMP,
)
from training.latent_cache import LatentCache
from training.samplers import (
    EvalSegments,
    MultiplayerSegmentSampler,
    SinglePlayerSegmentSampler,
    make_batch,
    next_batch,
)
from training.video_io import FrameReader, read_frames
from training.vpt import VPTDataset, vpt_camera_to_mineflayer

RES = 32
NUM_FRAMES = 16


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    out = tmp_path_factory.mktemp("data")
    common = ["--out", str(out), "--resolution", str(RES), "--seed", "3"]
    assert cli.main(["collect", *common, "--episodes", "2", "--world", "flat", "--types", "walkLook"]) == 0
    assert cli.main(["collect", *common, "--eval", "--eval-types", "rotationEval", "--episodes", "1"]) == 0
    assert cli.main(["export-vpt", str(out), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def duet(root):
    return DuetDataset(root, "train")


def _decode_all(path):
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        frames.append(bgr[..., ::-1])
    cap.release()
    return np.stack(frames)


def _records(path):
    return json.loads(path.read_text())


def _copy(root, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(root / "duet", dst / "duet")
    return dst, dst / "duet" / "train"


# ---------------------------------------------------------------------------------------------
# Duet loader
# ---------------------------------------------------------------------------------------------


def test_pairing_sorting_and_ids(root, duet):
    alphas = sorted((root / "duet" / "train").glob("*_Alpha_*.mp4"), key=lambda p: p.name)
    assert duet.num_episodes == len(alphas) == 2 and duet.valid_ids == [0, 1] and not duet.skipped
    for episode_id, alpha in enumerate(alphas):
        rec1, rec2 = duet.recordings(episode_id)
        assert duet.stems[episode_id] == alpha.stem
        assert rec1.video == alpha and rec1.actions == alpha.with_suffix(".json")
        assert rec2.video.name == alpha.name.replace("_Alpha_", "_Bravo_")
        assert rec2.actions.name == rec2.video.name.replace(".mp4", ".json")


def test_segment_is_frames_after_actions(duet):
    rec1, rec2 = duet.recordings(1)
    start1, start2 = 40, 43
    obs_TPHW3, act_TP25 = duet.segment(1, start1, start2, NUM_FRAMES)
    assert obs_TPHW3.shape == (NUM_FRAMES, 2, RES, RES, 3) and obs_TPHW3.dtype == np.uint8
    assert act_TP25.shape == (NUM_FRAMES, 2, 25) and act_TP25.dtype == np.float32
    for p, (rec, start) in enumerate(((rec1, start1), (rec2, start2))):
        frames = _decode_all(rec.video)
        np.testing.assert_array_equal(obs_TPHW3[:, p], frames[start + 1 : start + 1 + NUM_FRAMES])
        expected = sp.camera_linear(sp.mineflayer_records_to_vectors(_records(rec.actions)))
        np.testing.assert_array_equal(act_TP25[:, p], expected[start : start + NUM_FRAMES])
    # the end of a recording shortens the segment (frames stop at the last frame)
    n = rec1.num_records
    obs_TPHW3, act_TP25 = duet.segment(1, n - 5, n - 5, NUM_FRAMES)
    assert len(obs_TPHW3) == len(act_TP25) == 4
    with pytest.raises(ValueError):
        duet.segment(1, n - 1, 0, NUM_FRAMES)


def test_resize_uses_inter_area(root, duet):
    small = DuetDataset(root, "train", obs_size=(16, 24), frame_cache_mb=0)
    obs_TPHW3, _ = small.segment(0, 10, 10, 4)
    assert obs_TPHW3.shape == (4, 2, 16, 24, 3)
    frame = _decode_all(duet.recordings(0)[0].video)[11]
    np.testing.assert_array_equal(obs_TPHW3[0, 0], cv2.resize(frame, (24, 16), interpolation=cv2.INTER_AREA))


def test_frame_reader_cache_paths(duet):
    """Cached (LRU), uncached and too-big-to-cache reads return the same frames."""
    video1, video2 = (r.video for r in duet.recordings(0))
    n_bytes = len(_decode_all(video1)) * RES * RES * 3
    expected = _decode_all(video1)[7:12]
    for cache_mb in (0, n_bytes / 2**20 / 2, n_bytes / 2**20 * 1.5):
        reader = FrameReader(cache_mb=cache_mb)
        for path in (video1, video2, video1):
            frames_THW3 = reader.read(path, 7, 12)
        np.testing.assert_array_equal(frames_THW3, expected)
        assert reader._bytes <= reader.max_bytes and len(reader._cache) == (cache_mb > n_bytes / 2**20)


def test_eval_layout_and_view_changes_after_camera_action(root):
    """rotationEval: Alpha stands still, then turns for a few ticks; with the ``_camera`` eval layout
    the loader must show the view change at the frame *after* each camera action (frame t+1 <-> action t)."""
    ds = DuetDataset(root, "test", name="eval/rotationEval")
    assert ds.num_episodes == 1 and not ds.skipped
    rec1, _ = ds.recordings(0)
    assert rec1.video.name.endswith("_Alpha_instance_000_camera.mp4")
    cam_T = np.flatnonzero(np.abs(rec1.act_T25[:, 23:]).sum(1))
    start = int(cam_T[0]) - 3
    n = int(cam_T[-1] - cam_T[0]) + 6  # 2 idle ticks each side (a wider window meets mp4v keyframe jumps)
    obs_TPHW3, act_TP25 = ds.segment(0, start, start, n)
    diff_T = np.abs(np.diff(obs_TPHW3[:, 0].astype(np.float32), axis=0)).mean((1, 2, 3))  # diff_T[k-1]: effect of act k
    turning = np.abs(act_TP25[1:, 0, 23:]).sum(1) > 0
    idle = np.abs(act_TP25[1:, 0]).sum(1) == 0
    assert turning.sum() == len(cam_T) and idle.sum() == 4
    assert diff_T[turning].min() > 2.0 and diff_T[idle].max() < 1.0, (diff_T, turning)

    segments = EvalSegments(root / "eval" / "eval_ids_rotationEval.json").segments()
    assert len(segments) == 1 and isinstance(segments[0], SegmentMP)
    obs_TPHW3, _ = ds.load(segments[0], NUM_FRAMES)
    assert obs_TPHW3.shape == (NUM_FRAMES, 2, RES, RES, 3)


# ---------------------------------------------------------------------------------------------
# Samplers
# ---------------------------------------------------------------------------------------------


def _shift_render_times(path, offset_ms):
    records = _records(path)
    for r in records:
        r["renderTime"] += offset_ms
    path.write_text(json.dumps(records))


def test_render_time_alignment(root, tmp_path):
    """Bravo's clock 5 ticks ahead of Alpha's: aligned segments start 5 records later for Alpha."""
    data_dir, split = _copy(root, tmp_path)
    for bravo in split.glob("*_Bravo_instance_*[0-9].json"):
        _shift_render_times(bravo, 5 * 50)
    ds = DuetDataset(data_dir, "train")
    sampler = MultiplayerSegmentSampler(ds, NUM_FRAMES, seed=0)
    for seg in sampler.sample(40):
        times1_T, times2_T = ds.render_times(seg.episode_id)
        assert seg.start1 == seg.start2 + 5 and times1_T[seg.start1] == times2_T[seg.start2]
        assert seg.start1 + NUM_FRAMES < len(times1_T) and seg.start2 + NUM_FRAMES < len(times2_T) - 5
    # an offset off the tick grid: starts are bisect_left of a common time, at most one tick apart
    for bravo in split.glob("*_Bravo_instance_*[0-9].json"):
        _shift_render_times(bravo, -250 + 20)
    ds = DuetDataset(data_dir, "train")
    for seg in MultiplayerSegmentSampler(ds, NUM_FRAMES, seed=0).sample(40):
        times1_T, times2_T = ds.render_times(seg.episode_id)
        assert abs(times1_T[seg.start1] - times2_T[seg.start2]) < 50
        assert seg.start1 + NUM_FRAMES < len(times1_T) and seg.start2 + NUM_FRAMES < len(times2_T)


def test_sampler_is_seeded_and_resumable(duet):
    def sampler(seed=7):
        return MultiplayerSegmentSampler(duet, NUM_FRAMES, seed=seed)

    first = sampler()
    head = first.sample(5)
    state = json.loads(json.dumps(first.state_dict()))
    tail = first.sample(5)
    assert sampler().sample(10) == head + tail
    resumed = sampler()
    resumed.load_state_dict(state)
    assert resumed.sample(5) == tail
    assert sampler(seed=8).sample(10) != head + tail
    with pytest.raises(ValueError, match="seed"):
        sampler(seed=8).load_state_dict(state)
    # batches resume with the sampler
    a, b = sampler(), sampler()
    next_batch(duet, a, 2)
    b.load_state_dict(a.state_dict())
    np.testing.assert_array_equal(next_batch(duet, a, 2)["obs"], next_batch(duet, b, 2)["obs"])


def test_sampler_draws_among_a_subset_on_the_same_stream(duet):
    full, same, one = (MultiplayerSegmentSampler(duet, NUM_FRAMES, seed=3) for _ in range(3))
    assert len(full.candidates) >= 2
    assert [same.next(full.candidates) for _ in range(8)] == full.sample(8)
    only = full.candidates[-1]
    segments = [one.next([only]) for _ in range(8)]
    assert {s.episode_id for s in segments} == {only} and one.step == 8


def test_sampler_rank_partition(duet):
    for rank in (0, 1):
        segs = MultiplayerSegmentSampler(duet, NUM_FRAMES, seed=0, rank=rank, num_ranks=2).sample(10)
        assert {s.episode_id for s in segs} == {rank}
    too_long = 10_000
    with pytest.raises(ValueError, match="holds a segment"):
        MultiplayerSegmentSampler(duet, too_long)


# ---------------------------------------------------------------------------------------------
# Corrupt and missing files
# ---------------------------------------------------------------------------------------------


def _truncate_mp4(split):
    path = next(split.glob("*_000000_Alpha_*.mp4"))
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _bad_json(split):
    next(split.glob("*_000000_Bravo_*[0-9].json")).write_text('[{"action": ')


def _delete_bravo(split):
    next(split.glob("*_000000_Bravo_*.mp4")).unlink()


def _count_mismatch(split):
    path = next(split.glob("*_000000_Alpha_*[0-9].json"))
    path.write_text(json.dumps(_records(path)[:-1]))


def _time_goes_back(split):
    path = next(split.glob("*_000000_Alpha_*[0-9].json"))
    records = _records(path)
    records[10]["renderTime"] = records[9]["renderTime"]
    path.write_text(json.dumps(records))


@pytest.mark.parametrize("corrupt, reason, num_episodes", [
    (_truncate_mp4, UNREADABLE_VIDEO, 2),
    (_bad_json, BAD_JSON, 2),
    (_delete_bravo, MISSING_FILE, 1),
    (_count_mismatch, COUNT_MISMATCH, 2),
    (_time_goes_back, BAD_RENDER_TIME, 2),
])
def test_corrupt_episode_is_skipped_and_counted(root, tmp_path, caplog, corrupt, reason, num_episodes):
    data_dir, split = _copy(root, tmp_path)
    corrupt(split)
    ds = DuetDataset(data_dir, "train")
    assert dict(ds.skipped) == {reason: 1}
    assert ds.num_episodes == num_episodes and len(ds.valid_ids) == 1
    assert reason in caplog.text
    # ids of the other episodes do not shift when a complete episode is corrupt
    assert ds.stems[ds.valid_ids[0]].startswith("batch_3_000001_Alpha")
    assert {s.episode_id for s in MultiplayerSegmentSampler(ds, NUM_FRAMES).sample(5)} == set(ds.valid_ids)


def test_decode_error_marks_episode_and_batch_continues(duet, monkeypatch):
    ds = DuetDataset(duet.directory.parent.parent, "train", frame_cache_mb=0)
    bad_video = ds.recordings(0)[1].video
    real_read = read_frames

    def flaky_read(path, start, stop, size=None):
        if path == bad_video:
            raise EpisodeError(DECODE_ERROR, "simulated")
        return real_read(path, start, stop, size)

    monkeypatch.setattr(video_io, "read_frames", flaky_read)
    sampler = MultiplayerSegmentSampler(ds, NUM_FRAMES, seed=0)
    for _ in range(3):
        batch = next_batch(ds, sampler, 2)
        assert batch["obs"].shape == (2, NUM_FRAMES, 2, RES, RES, 3)
    assert dict(ds.skipped) == {DECODE_ERROR: 1} and ds.valid_ids == [1]


# ---------------------------------------------------------------------------------------------
# Batching
# ---------------------------------------------------------------------------------------------


def test_make_batch_pads_right(duet):
    short, full = duet.segment(0, 5, 5, 3), duet.segment(1, 5, 5, 5)
    batch = make_batch([short, full], num_frames=6, batch_size=4)
    assert batch["obs"].shape == (4, 6, 2, RES, RES, 3) and batch["act"].shape == (4, 6, 2, 25)
    assert batch["real_lengths"].tolist() == [3, 5, 0, 0]
    np.testing.assert_array_equal(batch["obs"][0, :3], short[0])
    assert not batch["obs"][0, 3:].any() and not batch["act"][1, 5:].any() and not batch["obs"][2:].any()


# ---------------------------------------------------------------------------------------------
# VPT export and loader
# ---------------------------------------------------------------------------------------------


def test_vpt_export_layout(root):
    split = root / "vpt" / "train"
    info = json.loads((split / "episodes_info.json").read_text())
    duet_videos = sorted((root / "duet" / "train").glob("*.mp4"), key=lambda p: p.name)
    assert info["num_episodes"] == len(info["episodes"]) == len(duet_videos) == 4
    for i, (entry, src) in enumerate(zip(info["episodes"], duet_videos)):
        assert entry["episode_id"] == i and entry["video_path"] == f"engine/{src.name}"
        assert os.path.samefile(split / entry["video_path"], src)  # hard link
        lines = (split / entry["actions_path"]).read_text().splitlines()
        assert entry["length"] == len(lines) == len(_records(src.with_suffix(".json")))
    tick = json.loads(lines[0])
    assert set(tick) == {"mouse", "keyboard", "isGuiOpen", "isGuiInventory", "hotbar", "yaw", "pitch", "xpos",
                         "ypos", "zpos", "tick", "milli", "inventory", "serverTick", "serverTickDurationMs", "stats"}
    assert set(tick["mouse"]) == {"x", "y", "dx", "dy", "scaledX", "scaledY", "dwheel", "buttons", "newButtons"}
    assert set(tick["keyboard"]) == {"keys", "newKeys", "chars"}


def test_vpt_round_trip_matches_mineflayer(root):
    """records -> VPT JSONL -> vpt_jsonl_to_vectors (+ sign flip) == mineflayer_records_to_vectors, all dims;
    tick 0 may differ only by VPT's hotbar pulse for an initial slot != 0."""
    for path in sorted((root / "duet" / "train").glob("*_instance_[0-9][0-9][0-9].json")):
        records = _records(path)
        expected_T25 = sp.mineflayer_records_to_vectors(records)
        lines = [json.dumps(t) for t in records_to_vpt_ticks(records)]
        got_T25 = vpt_camera_to_mineflayer(sp.vpt_jsonl_to_vectors(lines))
        np.testing.assert_allclose(got_T25[1:], expected_T25[1:], rtol=0, atol=1e-5)
        slot0 = records[0]["inventory"]["quickBarSlot"]
        pulse = np.zeros(25, np.float32)
        if slot0 != 0:
            pulse[sp.MODEL_INDEX[f"hotbar.{slot0 + 1}"]] = 1.0
        np.testing.assert_allclose(got_T25[0], np.maximum(expected_T25[0], pulse), atol=1e-5)
        assert np.abs(expected_T25[:, 23:]).sum() > 0  # the camera was exercised


def test_round_trip_collapsed_keys():
    """Keys VPT has no slot for collapse exactly as in the Mineflayer conversion; the sign flip is exact."""
    base = {k: False for k in sp.RECORDED_ACTION_KEYS}
    base["camera"] = [0.0, 0.0]
    rows = [dict(base), dict(base, mount=True), dict(base, dismount=True), dict(base, place_entity=True),
            dict(base, mine=True), dict(base, place_block=True, attack=True, camera=[0.05, -0.02]),
            dict(base, **{"hotbar.3": True}), dict(base, forward=True, sprint=True, jump=True, left=True)]
    records = [{"action": a, "x": 0.0, "y": 64.0, "z": 0.0, "yaw": 0.0, "pitch": 0.0} for a in rows]
    got_T25 = vpt_camera_to_mineflayer(sp.vpt_jsonl_to_vectors(records_to_vpt_ticks(records)))
    np.testing.assert_allclose(got_T25, sp.mineflayer_records_to_vectors(records), rtol=0, atol=1e-5)


def test_vpt_dataset_segments_and_sign(root, duet):
    vpt = VPTDataset(root, "train")
    assert vpt.num_episodes == 4 and not vpt.skipped
    obs_T1HW3, act_T125 = vpt.segment(2, 30, NUM_FRAMES)  # episode 2 = Alpha of Duet episode 1
    assert obs_T1HW3.shape == (NUM_FRAMES, 1, RES, RES, 3) and act_T125.shape == (NUM_FRAMES, 1, 25)
    duet_obs, duet_act = duet.segment(1, 30, 30, NUM_FRAMES)
    np.testing.assert_array_equal(obs_T1HW3[:, 0], duet_obs[:, 0])
    np.testing.assert_allclose(act_T125[:, 0], duet_act[:, 0], atol=1e-6)
    reference = VPTDataset(root, "train", reference_camera_sign=True)
    full = reference.episode(2).act_T25
    np.testing.assert_allclose(full[:, 23:], -vpt.episode(2).act_T25[:, 23:], atol=1e-6)
    np.testing.assert_array_equal(full[:, :23], vpt.episode(2).act_T25[:, :23])

    lengths = [vpt.episode(i).length for i in vpt.valid_ids]
    sampler = SinglePlayerSegmentSampler(vpt, max(lengths) - 1, seed=0)  # only start 0 of the longest fits
    assert {(s.episode_id, s.start) for s in sampler.sample(8)} <= {(i, 0) for i, n in enumerate(lengths)
                                                                    if n == max(lengths)}
    assert sampler.skipped[TOO_SHORT] == lengths.count(min(lengths))
    sampler = SinglePlayerSegmentSampler(vpt, NUM_FRAMES, seed=1)
    head = sampler.sample(5)
    state = sampler.state_dict()
    tail = sampler.sample(5)
    assert SinglePlayerSegmentSampler(vpt, NUM_FRAMES, seed=1).sample(10) == head + tail
    resumed = SinglePlayerSegmentSampler(vpt, NUM_FRAMES, seed=1)
    resumed.load_state_dict(state)
    assert resumed.sample(5) == tail
    batch = next_batch(vpt, resumed, 3)
    assert batch["obs"].shape == (3, NUM_FRAMES, 1, RES, RES, 3)


def test_vpt_corrupt_and_cp1252(root, tmp_path):
    split = tmp_path / "vpt" / "train"
    shutil.copytree(root / "vpt" / "train", split)
    info = json.loads((split / "episodes_info.json").read_text())
    paths = [split / e["actions_path"] for e in info["episodes"]]
    lines = paths[0].read_text().splitlines()
    lines[3] = lines[3].replace('"chars":""', '"chars":"\u00e9"')
    paths[0].write_bytes("\n".join(lines).encode("windows-1252"))  # not utf-8: decoded by the fallback
    paths[1].write_text("{broken\n")
    paths[2].write_text("\n".join(paths[2].read_text().splitlines()[:-2]))
    (split / info["episodes"][3]["video_path"]).unlink()
    vpt = VPTDataset(tmp_path, "train")
    assert vpt.valid_ids == [0]
    assert dict(vpt.skipped) == {BAD_JSON: 1, COUNT_MISMATCH: 1, MISSING_FILE: 1}


# ---------------------------------------------------------------------------------------------
# Latent cache
# ---------------------------------------------------------------------------------------------


def test_latent_cache_hit_miss_invalidation(duet, tmp_path):
    calls = []

    def encode(frames_THW3):
        calls.append(frames_THW3.shape)
        return {"latents": frames_THW3.reshape(len(frames_THW3), -1).mean(1).astype(np.float32),
                "first": frames_THW3[0]}

    src = tmp_path / "ep.mp4"
    shutil.copy2(duet.recordings(0)[0].video, src)
    cache = LatentCache(tmp_path / "cache", fingerprint="fake-v1", tensors=("latents", "first"))
    first = cache.get_or_encode(src, encode)["latents"]
    assert len(calls) == 1 and calls[0][1:] == (RES, RES, 3) and first.shape == (calls[0][0],)
    hit = cache.get_or_encode(src, encode)
    np.testing.assert_array_equal(hit["latents"], first)
    assert hit["first"].shape == (RES, RES, 3) and hit["first"].dtype == np.uint8
    assert len(calls) == 1 and cache.stats == {"misses": 1, "hits": 1}
    # a file of another layout (only the latents) is stale; an encoder that returns other names is an error
    assert LatentCache(tmp_path / "cache", fingerprint="fake-v1").get(src) is None
    with pytest.raises(ValueError, match=r"returned tensors \['first', 'latents'\], expected \['latents'\]"):
        LatentCache(tmp_path / "cache", fingerprint="fake-v1").get_or_encode(src, encode)

    calls.clear()
    cache.get_or_encode(src, encode, obs_size=(16, 16))  # another frame size: stale, re-encoded
    assert len(calls) == 1 and calls[0][1:] == (16, 16, 3)
    LatentCache(tmp_path / "cache", fingerprint="fake-v2", tensors=("latents", "first")).get_or_encode(src, encode)
    assert len(calls) == 2  # another encoder
    st = src.stat()
    os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # the video changed
    np.testing.assert_array_equal(cache.get_or_encode(src, encode)["latents"], first)
    assert len(calls) == 3 and cache.stats["stale"] == 2
    cache.get_or_encode(src, encode)
    assert len(calls) == 3
    assert sorted(p.name for p in (tmp_path / "cache").iterdir() if p.name.startswith(".")) == []  # no temp files


def test_the_episode_index_is_kept_beside_the_data_and_follows_the_files(root, tmp_path, monkeypatch):
    """A validated recording is written to ``<split>/.index/<video>.npz``; a later read takes it instead of the
    JSON, and a file that changed since is validated again."""
    from training import duet as D

    split = tmp_path / "duet" / "train"
    shutil.copytree(root / "duet" / "train", split)
    first = DuetDataset(tmp_path, "train")
    sidecars = sorted((split / D.INDEX_DIR).glob("*.npz"))
    assert len(sidecars) == 2 * first.num_episodes

    monkeypatch.setattr(D, "_read_records", lambda path: pytest.fail(f"{path.name} was read again"))
    again = DuetDataset(tmp_path, "train")
    for i in first.valid_ids:
        for a, b in zip(first.recordings(i), again.recordings(i)):
            np.testing.assert_array_equal(a.act_T25, b.act_T25)
            np.testing.assert_array_equal(a.times_T, b.times_T)
    monkeypatch.undo()

    actions = first.recordings(0)[0].actions
    records = json.loads(actions.read_text())
    records[0]["action"]["forward"] = not records[0]["action"]["forward"]  # the recording changed: validated again
    actions.write_text(json.dumps(records))
    changed = DuetDataset(tmp_path, "train").recordings(0)[0]
    assert changed.act_T25[0].tolist() != first.recordings(0)[0].act_T25[0].tolist()
