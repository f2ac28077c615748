"""The latent cache of the DiT stages (training/latents.py) against encoding clips directly, on a tiny
real dataset (32x32, 2 engine episodes) and the ``test`` preset with ``cond_encoding="image"``."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from solaris_env.world_model.config import preset
from solaris_env.world_model.world_model import WorldModel, frames_to_model
from training.duet import DuetDataset
from training.episodes import EpisodeError, SegmentMP, SegmentSP
from training.latents import latent_clips, make_prepare_latents, snap_start
from training.samplers import MultiplayerSegmentSampler
from training.step import prepare_batch
from training.video_io import read_frames
from training.vpt import VPTDataset

F16_ATOL = 2e-2  # latents are stored in float16


@pytest.fixture(scope="module")
def root(tiny_duet):
    return tiny_duet


@pytest.fixture(scope="module")
def cfg():
    c = preset("test")
    return c.replace(vae=dataclasses.replace(c.vae, cond_encoding="image"))


@pytest.fixture(scope="module")
def modules(cfg):
    return WorldModel.from_config(cfg, seed=0).modules()


@pytest.fixture(scope="module")
def clips(root, cfg, modules, tmp_path_factory):
    dataset = DuetDataset(root, "train", obs_size=(32, 32))
    return latent_clips(dataset, cfg, modules[1], tmp_path_factory.mktemp("latents"), canonical_dir=root / "duet")


def test_snap_start_puts_the_first_frame_on_the_anchor_grid():
    assert [snap_start(s, 4) for s in range(-1, 9)] == [-1, -1, -1, -1, 3, 3, 3, 3, 7, 7]
    assert all((snap_start(s, 4) + 1) % 4 == 0 and snap_start(s, 4) <= s for s in range(50))


def test_clip_from_frame_zero_equals_encoding_the_clip(clips, modules, cfg):
    num_frames = 9
    x0, first, act = clips.load(SegmentMP(0, 0, 0), num_frames)
    # start 0 snaps to -1: frames [0, 9) of each bot, a no-op action in front
    rec1, rec2 = clips.dataset.recordings(0)
    video = np.stack([read_frames(r.video, 0, num_frames, (32, 32)) for r in (rec1, rec2)])  # (P, T, H, W, 3)
    expected = np.asarray(modules[1].encode(frames_to_model(jnp.asarray(video))))
    np.testing.assert_allclose(x0, expected, atol=F16_ATOL)
    np.testing.assert_array_equal(first, video[:, 0])
    assert act.shape == (num_frames, 2, 25)
    np.testing.assert_array_equal(act[0], 0)  # the action before the recording is a no-op
    np.testing.assert_array_equal(act[1:, 0], rec1.act_T25[: num_frames - 1])


def test_anchored_clip_latent_zero_is_its_first_frame_alone(clips, modules):
    x0, first, _ = clips.load(SegmentMP(0, 10, 10), 9)  # snaps to 7: first frame 8
    rec1 = clips.dataset.recordings(0)[0]
    frame8 = read_frames(rec1.video, 8, 9, (32, 32))
    np.testing.assert_array_equal(first[0], frame8[0])
    alone = np.asarray(modules[1].encode(frames_to_model(jnp.asarray(frame8[None]))))[0, 0]
    np.testing.assert_allclose(x0[0, 0], alone, atol=F16_ATOL)


def test_prepared_batch_matches_prepare_batch(clips, modules, cfg):
    x0, first, act = clips.load(SegmentMP(0, 0, 0), 9)  # a clip from frame 0: exactly the clip's stream
    assert len(clips.next_batch(MultiplayerSegmentSampler(clips.dataset, 9, seed=0), 2, 9)["x0"]) == 2
    rec = clips.dataset.recordings(0)
    obs = np.stack([read_frames(r.video, 0, 9, (32, 32)) for r in rec], axis=1)  # (T, P, H, W, 3)
    got = make_prepare_latents(cfg, modules[1], modules[2])({"x0": x0[None], "first": first[None], "act": act[None]})
    want = prepare_batch(modules[1], modules[2], jnp.asarray(obs[None]), jnp.asarray(act[None]), cfg)
    for key in ("x0", "cond"):
        np.testing.assert_allclose(got[key], want[key], atol=F16_ATOL, err_msg=key)
    for key in ("context", "mouse", "keyboard"):
        np.testing.assert_allclose(got[key], want[key], atol=1e-5, err_msg=key)


def test_vpt_export_shares_the_duet_latents(root, cfg, modules, clips):
    clips.build()
    vpt = VPTDataset(root, "train", obs_size=(32, 32))
    shared = latent_clips(vpt, cfg, modules[1], clips.cache.dir.parent, canonical_dir=root / "duet")
    shared.build()
    assert shared.cache.stats["misses"] == 0 and shared.cache.stats["hits"] == 2 * clips.dataset.num_episodes
    x0, _, act = shared.load(SegmentSP(1, 20), 9)
    assert x0.shape == (1, 3, 4, 4, cfg.latent_channels) and act.shape == (9, 1, 25)


def test_build_with_threads_writes_the_same_cache_as_one_worker(root, cfg, modules, tmp_path):
    dataset = DuetDataset(root, "train", obs_size=(32, 32))
    one = latent_clips(dataset, cfg, modules[1], tmp_path / "one", canonical_dir=root / "duet")
    many = latent_clips(dataset, cfg, modules[1], tmp_path / "many", canonical_dir=root / "duet")
    videos = 2 * dataset.num_episodes
    assert one.build(workers=1) == many.build(workers=3) == videos
    assert many.cache.stats["misses"] == videos and many.build() == videos  # all in memory: nothing looked up again
    assert many.cache.stats["misses"] + many.cache.stats["hits"] == videos
    assert sorted(p.name for p in one.cache.dir.iterdir()) == sorted(p.name for p in many.cache.dir.iterdir())
    for video, tensors in one._latents.items():
        assert sorted(tensors) == ["anchor_frames", "latents"]
        for name, value in tensors.items():
            np.testing.assert_array_equal(many._latents[video][name], value)
    with pytest.raises(ValueError, match="workers must be >= 1"):
        latent_clips(dataset, cfg, modules[1], tmp_path / "bad", canonical_dir=root / "duet").build(workers=0)


def test_build_stops_at_its_time_limit_and_the_rest_encode_on_first_use(root, cfg, modules, tmp_path):
    import time

    dataset = DuetDataset(root, "train", obs_size=(32, 32))
    late = latent_clips(dataset, cfg, modules[1], tmp_path / "late", canonical_dir=root / "duet")
    assert late.build(workers=1, until=time.time() - 1) == 0  # past the limit: nothing started
    full = latent_clips(dataset, cfg, modules[1], tmp_path / "full", canonical_dir=root / "duet")
    full.build(workers=1)
    segment = SegmentMP(dataset.valid_ids[0], 8, 8)
    for a, b in zip(late.load(segment, 9), full.load(segment, 9)):  # encoded on demand, the same latents
        np.testing.assert_array_equal(a, b)


def _gated(clips, gate):
    """Make ``clips``' encoder wait for ``gate`` (the test decides when the background catches up)."""
    encode = clips._cached_or_encoded

    def wait_then_encode(video):
        assert gate.wait(120)
        return encode(video)

    clips._cached_or_encoded = wait_then_encode


def test_the_background_encoder_serves_ready_episodes_only_then_catches_up(root, cfg, modules, tmp_path):
    import threading
    import time

    dataset = DuetDataset(root, "train", obs_size=(32, 32))
    clips = latent_clips(dataset, cfg, modules[1], tmp_path / "bg", canonical_dir=root / "duet")
    ready, *others = dataset.valid_ids
    assert others and clips.build([ready], workers=1) == 2
    gate = threading.Event()
    _gated(clips, gate)
    loaded = []
    load = clips.load

    def recording_load(segment, n):
        out = load(segment, n)
        loaded.append(segment.episode_id)  # only the draws that loaded
        return out

    clips.load = recording_load
    clips.encode_in_background(workers=1)
    try:
        with pytest.raises(EpisodeError, match="not_ready"):
            load(SegmentMP(others[0], 8, 8), 9)  # never encoded in the training thread
        sampler = MultiplayerSegmentSampler(dataset, 9, seed=0)
        batch = clips.next_batch(sampler, 6, 9)
        assert batch["x0"].shape[0] == 6 and loaded == [ready] * 6
        assert clips.ready_candidates(sampler) == [ready]
        assert sampler.step == 6  # drawn among the ready episodes: no draw was rejected
        gate.set()
        until = time.time() + 120
        while clips.pending() and time.time() < until:
            time.sleep(0.1)
        assert clips.pending() == [] and clips.num_ready == 2 * len(dataset.valid_ids)
        full = latent_clips(dataset, cfg, modules[1], tmp_path / "full", canonical_dir=root / "duet")
        for a, b in zip(load(SegmentMP(others[0], 8, 8), 9), full.load(SegmentMP(others[0], 8, 8), 9)):
            np.testing.assert_array_equal(a, b)  # what the background wrote is what the caller would encode
    finally:
        gate.set()
        clips.close()
    assert not clips._background.is_alive()
    with pytest.raises(RuntimeError, match="already running"):
        clips.encode_in_background()


def test_close_stops_the_video_in_flight_at_its_next_chunk_and_caches_nothing_for_it(root, cfg, modules, tmp_path):
    """A stage's teardown must not wait for a whole video's encode (seconds on a loaded CPU: the sprint's stage
    overran its share by that much): ``close()`` interrupts it between chunks; the video is not marked failed
    and is encoded whole the next time."""
    import threading
    import time

    from training.latents import EncodeStopped

    dataset = DuetDataset(root, "train", obs_size=(32, 32))
    clips = latent_clips(dataset, cfg, modules[1], tmp_path / "bg", canonical_dir=root / "duet")
    encoder, in_flight, chunks = clips.encoder, threading.Event(), []
    step = encoder._next

    def slow_next(*args):
        chunks.append(time.time())
        in_flight.set()
        time.sleep(0.5)
        return step(*args)

    encoder._next = slow_next
    clips.encode_in_background(workers=1)
    assert in_flight.wait(120)
    t0 = time.time()
    clips.close()
    assert time.time() - t0 < 2.0 and not clips._background.is_alive()
    assert len(chunks) <= 2, len(chunks)  # the chunk in flight (and at most one raced with close) ran
    assert clips.num_ready == 0 and not clips._failed and list(clips.cache.dir.glob("*.safetensors")) == []
    encoder._next = step
    video = clips.pending()[0]
    stop = threading.Event()
    stop.set()
    with pytest.raises(EncodeStopped):
        encoder(read_frames(video, 0, None, (32, 32)), stop=stop)
    again = latent_clips(dataset, cfg, modules[1], tmp_path / "bg", canonical_dir=root / "duet")
    assert again.build(workers=1) == 2 * dataset.num_episodes  # nothing was lost: every video encodes whole


def test_a_video_that_cannot_be_encoded_is_tried_once_and_its_draws_are_skipped(root, cfg, modules, tmp_path):
    from training.episodes import DECODE_ERROR

    dataset = DuetDataset(root, "train", obs_size=(32, 32))
    clips = latent_clips(dataset, cfg, modules[1], tmp_path / "bad", canonical_dir=root / "duet")
    bad_episode = dataset.valid_ids[-1]
    bad = dataset.recordings(bad_episode)[0].video
    encode, tried = clips._cached_or_encoded, []

    def failing(video):
        tried.append(video)
        if video == bad:
            raise EpisodeError(DECODE_ERROR, f"{video.name}: frame 3 could not be decoded")
        return encode(video)

    clips._cached_or_encoded = failing
    videos = 2 * len(dataset.valid_ids)
    assert clips.build(workers=1) == videos - 1
    assert clips.pending() == [] and clips.build(workers=1) == videos - 1 and tried.count(bad) == 1
    with pytest.raises(EpisodeError, match="decode_error: .*frame 3"):
        clips.load(SegmentMP(bad_episode, 8, 8), 9)


def test_a_stage_with_a_deadline_starts_from_at_least_a_few_episodes(root, cfg, modules, tmp_path):
    import time

    from training.latents import MIN_READY_EPISODES

    dataset = DuetDataset(root, "train", obs_size=(32, 32))
    assert len(dataset.valid_ids) <= MIN_READY_EPISODES
    late = latent_clips(dataset, cfg, modules[1], tmp_path / "late", canonical_dir=root / "duet")
    assert late.build_for_stage(deadline=time.time() - 1) == 2 * len(dataset.valid_ids)  # past it: still the few
    broken = latent_clips(dataset, cfg, modules[1], tmp_path / "broken", canonical_dir=root / "duet")

    def unreadable(video):
        raise EpisodeError("unreadable_video", f"{video.name}: OpenCV cannot open it")

    broken._cached_or_encoded = unreadable
    with pytest.raises(RuntimeError, match="none of the .* videos tried could be encoded"):
        broken.build_for_stage(deadline=time.time() + 60)


def test_an_error_in_the_background_encoder_is_raised_in_the_training_thread(root, cfg, modules, tmp_path):
    import time

    dataset = DuetDataset(root, "train", obs_size=(32, 32))
    clips = latent_clips(dataset, cfg, modules[1], tmp_path / "err", canonical_dir=root / "duet")

    def bug(video):
        raise TypeError("a bug in the encoder")

    clips._cached_or_encoded = bug
    clips.encode_in_background(workers=1)
    until = time.time() + 60
    while clips._background.is_alive() and time.time() < until:
        time.sleep(0.05)
    with pytest.raises(RuntimeError, match="background latent encoder failed") as info:
        clips.load(SegmentMP(dataset.valid_ids[0], 8, 8), 9)
    assert isinstance(info.value.__cause__, TypeError)
    clips.close()
