"""Pre-encoded training clips for the DiT stages: every video encoded once by the frozen VAE.

Encoding each training clip on the fly costs more than the DiT step itself on our CPU (the VAE encoder
runs at full resolution), so stages 1-4 read latents from a cache made once per VAE:

* per recorded video (one bot's view) of N frames, ``Ns = 1 + (N - 1) // k`` rows, each holding two
  latents (normalised posterior means, stored f16):
  ``stream[j]`` = latent j of the whole video encoded as one causal stream (latent 0 = frame 0, latent
  j >= 1 = frames k(j-1)+1 .. kj), and ``image[j]`` = frame kj encoded alone (a clip's latent 0).
* a clip whose first frame is video frame ``f0 = k*a`` (an *anchor*) is then
  ``x0 = [image[a], stream[a+1], ..., stream[a+F-1]]``: latent 0 exactly as the world model encodes
  a start frame, later latents as the streaming encoder sees them (with the video's causal history
  instead of the clip's, a negligible difference beyond the encoder's receptive field).
* the anchor frames themselves (``anchor_frames[a]`` = frame ``k*a``, uint8): a clip's first frame, which the
  image encoder reads. Kept with the latents, a batch needs no video decoded. Read from the videos, each
  frame-cache miss decoded a whole video (~60 ms on this CPU): a cold batch of 64 clips took 2.1 s, and with a
  sprint's ~2300 videos against a 4 GB frame cache about 5 s per batch (an estimate), far longer than a GPU's
  step.

Segments come from the usual resumable samplers (``training.samplers``); their starts are snapped down
to the anchor grid: record start ``s`` becomes ``s' = k * floor((s + 1) / k) - 1`` so that the first
frame ``s' + 1`` is an anchor (``s' = -1`` means the clip starts at frame 0; its first action, which
precedes the recording, is a no-op). The first-frame conditioning is made from ``image[a]`` when the
config uses ``cond_encoding="image"`` (the tiny preset); the image-encoder context is computed from the
anchor frame's pixels per batch (it is cheap).

A stage with a deadline or a growing dataset (``solaris-train sprint``) does not wait for the whole cache:
``LatentClips.build`` encodes what fits a short share of the stage's time (at least ``MIN_READY_EPISODES``
episodes), then ``encode_in_background`` keeps encoding the rest and every episode the background collect adds,
while batches are drawn among the episodes whose latents are ready (``LatentClips.ready_candidates``). Encoding
a video inside the training step instead stalled the DiT stages: on 2 CPU cores, 5 steps in 11 minutes.
"""

from __future__ import annotations

import hashlib
import logging
import os
import threading
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from solaris_env.spaces import MODEL_ACTION_DIM
from solaris_env.world_model.action_module import left_pad_actions
from solaris_env.world_model.conditioning import first_frame_mask
from solaris_env.world_model import partner as partner_lib
from solaris_env.world_model.config import WorldModelConfig
from solaris_env.world_model.dit import to_stream
from solaris_env.world_model.world_model import frames_to_model
from training.duet import DuetDataset
from training.episodes import (
    DECODE_ERROR,
    NOT_READY,
    EpisodeError,
    SegmentMP,
    SegmentSP,
)
from training.latent_cache import LatentCache
from training.samplers import draw_loaded

logger = logging.getLogger(__name__)

STREAM_CHUNK_LATENTS = 32  # latent frames encoded per streaming call (k * 32 video frames)
IMAGE_BATCH = 64  # anchor frames encoded per call
BUILD_WORKERS = 4  # videos encoded at once when the cache is built (at most the CPU count)
MIN_READY_EPISODES = 8  # encoded before a stage starts drawing, whatever its time (or all there are)
BACKGROUND_IDLE_S = 2.0  # the background encoder looks for new episodes this often when it has caught up


def vae_fingerprint(cfg: WorldModelConfig, vae_state) -> str:
    """Identifies a VAE: its config and a hash of its weights."""
    h = hashlib.sha1(repr(cfg.vae).encode())
    for leaf in jax.tree.leaves(vae_state):
        h.update(np.asarray(leaf).tobytes())
    return f"{cfg.name}-{cfg.frame_height}x{cfg.frame_width}-{h.hexdigest()[:16]}"


class EncodeStopped(Exception):
    """``VideoEncoder`` was told to stop before the video was encoded (nothing is cached for it)."""


class VideoEncoder:
    """Jitted streaming + per-anchor encoding of whole videos (fixed chunk shapes: one compile each)."""

    def __init__(self, cfg: WorldModelConfig, vae) -> None:
        self.cfg = cfg
        self.k = cfg.frames_per_step
        graphdef, state = nnx.split(vae)
        self._state = state
        self.fingerprint = vae_fingerprint(cfg, state)

        def first(st, video):
            return nnx.merge(graphdef, st).encode_chunked(frames_to_model(video))

        def nxt(st, video, cache):
            return nnx.merge(graphdef, st).encode_chunked(frames_to_model(video), cache)

        def image(st, frames):
            return nnx.merge(graphdef, st).encode(frames_to_model(frames)[:, None])[:, 0]

        self._first, self._next, self._image = jax.jit(first), jax.jit(nxt), jax.jit(image)

    tensors = ("latents", "anchor_frames")  # what ``__call__`` returns, by name (the cache files' tensors)

    def __call__(self, frames_THW3: np.ndarray, stop: threading.Event | None = None) -> dict[str, np.ndarray]:
        """(N, H, W, 3) uint8 -> {"latents": (Ns, 2, h, w, C) f16 ([:, 0] stream latents, [:, 1] anchor
        images), "anchor_frames": (Ns, H, W, 3) uint8 (frames 0, k, 2k, ...)}. When ``stop`` is set, raises
        ``EncodeStopped`` before the next chunk (a whole video takes seconds on a loaded CPU; a stage's
        teardown waits for one chunk instead)."""
        k, c = self.k, STREAM_CHUNK_LATENTS

        def check() -> None:
            if stop is not None and stop.is_set():
                raise EncodeStopped()

        n = len(frames_THW3)
        ns = 1 + (n - 1) // k
        usable = frames_THW3[: 1 + k * (ns - 1)]
        pad = lambda v, length: np.concatenate([v, np.repeat(v[-1:], length - len(v), axis=0)]) if len(v) < length else v
        stream = []
        head = pad(usable[: 1 + k * c], 1 + k * c)
        z, cache = self._first(self._state, jnp.asarray(head[None]))
        stream.append(np.asarray(z[0]))
        for start in range(1 + k * c, len(usable), k * c):
            check()
            chunk = pad(usable[start:start + k * c], k * c)
            z, cache = self._next(self._state, jnp.asarray(chunk[None]), cache)
            stream.append(np.asarray(z[0]))
        stream = np.concatenate(stream)[:ns]
        anchors = usable[::k]
        images = []
        for start in range(0, len(anchors), IMAGE_BATCH):
            check()
            batch = pad(anchors[start:start + IMAGE_BATCH], IMAGE_BATCH)
            images.append(np.asarray(self._image(self._state, jnp.asarray(batch))))
        images = np.concatenate(images)[:ns]
        return {"latents": np.stack([stream, images], axis=1).astype(np.float16), "anchor_frames": anchors[:ns]}


def snap_start(start: int, k: int) -> int:
    """Record start -> the anchored start ``k * floor((start + 1) / k) - 1`` (>= -1)."""
    return k * ((start + 1) // k) - 1


class LatentClips:
    """Clips of a Duet (P players) or VPT-layout (1 player) dataset served from the latent cache.

    Args:
        dataset: a ``DuetDataset`` or ``VPTDataset`` (frames at the config's size).
        cache: a ``training.latent_cache.LatentCache`` whose fingerprint names the VAE.
        encoder: the ``VideoEncoder`` used on a cache miss.
    """

    def __init__(self, dataset, cache: LatentCache, encoder: VideoEncoder, canonical_dir: Path | None = None) -> None:
        self.dataset, self.cache, self.encoder = dataset, cache, encoder
        self.k = encoder.k
        self._latents: dict[Path, dict[str, np.ndarray]] = {}  # video -> its cache tensors
        # the VPT export hard-links the Duet videos: latents are shared through the inode
        self._canonical = {}
        if canonical_dir is not None and Path(canonical_dir).is_dir():
            for mp4 in sorted(Path(canonical_dir).glob("*/*.mp4")):
                st = mp4.stat()
                self._canonical[(st.st_dev, st.st_ino)] = mp4
        self._failed: dict[Path, str] = {}  # videos the background encoder could not encode -> why
        self._stop = threading.Event()
        self._background: threading.Thread | None = None
        self._background_error: BaseException | None = None
        self._ready_memo: tuple | None = None  # (key, ready_candidates' answer), see there
        # the clips also carry both players' poses (``DiTConfig.partner_map``): ``load`` and ``next_batch`` "pose"
        self.with_poses = False

    def _player_recordings(self, segment) -> list[tuple[Path, np.ndarray, int, np.ndarray | None]]:
        """[(video, act_T25, start, pose_T5 or None)] per player."""
        if isinstance(segment, SegmentMP):
            recs = self.dataset.recordings(segment.episode_id)
            return [(r.video, r.act_T25, s, r.pose_T5) for r, s in zip(recs, (segment.start1, segment.start2))]
        episode = self.dataset.episode(segment.episode_id)
        return [(episode.video, episode.act_T25, segment.start, None)]

    def latents(self, video: Path) -> dict[str, np.ndarray]:
        """The video's cache tensors (``VideoEncoder.tensors``); encoded now if they are not ready, unless the
        background encoder runs: then EpisodeError(NOT_READY) (the draw is repeated), or DECODE_ERROR for a
        video it could not encode."""
        lat = self._latents.get(video)
        if lat is None:
            if self._background_error is not None:
                raise RuntimeError("the background latent encoder failed") from self._background_error
            if video in self._failed:
                raise EpisodeError(DECODE_ERROR, f"{video.name}: {self._failed[video]}")
            if self._background is not None:
                raise EpisodeError(NOT_READY, f"{video.name}: latents not encoded yet")
            lat = self._latents[video] = self._cached_or_encoded(video)
        return lat

    @property
    def num_ready(self) -> int:
        """Videos whose latents are ready."""
        return len(self._latents)

    def pending(self, episode_ids=None) -> list[Path]:
        """The videos of ``episode_ids`` (default: every valid episode) whose latents are not ready, in
        episode order."""
        ids = self.dataset.valid_ids if episode_ids is None else episode_ids
        videos = []
        for episode_id in ids:
            videos += [video for video, *_ in self._player_recordings(self._probe_segment(episode_id))
                       if video not in self._latents and video not in self._failed]
        return videos

    def _cached_or_encoded(self, video: Path) -> dict[str, np.ndarray]:
        """The video's cache tensors. While the background encoder runs (the only time anything encodes then),
        ``close()`` interrupts the encode before its next chunk (``EncodeStopped``); otherwise it finishes."""
        st = video.stat()
        source = self._canonical.get((st.st_dev, st.st_ino), video)
        stop = self._stop if self._background is not None else None
        encode = lambda frames: self.encoder(frames, stop=stop)  # noqa: E731
        return self.cache.get_or_encode(source, encode, self.dataset.frames.size)

    def build(self, episode_ids=None, workers: int | None = None, until: float | None = None,
              stop: threading.Event | None = None) -> int:
        """Encode every (valid) episode's videos now; returns the number of videos ready.

        ``workers`` videos are decoded and encoded at once (threads: the video decoder and XLA release the GIL,
        and one batch-1 streaming encode keeps about one CPU core busy); default: the CPU count, at most
        ``BUILD_WORKERS``. The cache files are the same whatever the number. ``until`` (epoch seconds) stops
        starting new videos after that time, ``stop`` when it is set; the rest are encoded when a clip first
        needs them (``latents``), or by ``encode_in_background``.
        """
        from concurrent.futures import ThreadPoolExecutor

        ids = self.dataset.valid_ids if episode_ids is None else episode_ids
        videos = self.pending(ids)
        workers = min(BUILD_WORKERS, os.cpu_count() or 1) if workers is None else workers
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        per_episode = max(1, len(videos) // max(1, len(ids)))
        done = 0
        with ThreadPoolExecutor(workers) as pool:  # map keeps the order; results arrive as they are ready
            for start in range(0, len(videos), workers):
                if (until is not None and time.time() >= until) or (stop is not None and stop.is_set()):
                    logger.info("latent cache: stopped at %d/%d videos (%s)", done, len(videos),
                                "time" if stop is None or not stop.is_set() else "stop")
                    break
                chunk = videos[start:start + workers]
                for video, lat in zip(chunk, pool.map(self._encode_or_fail, chunk)):
                    if lat is not None:
                        self._latents[video] = lat
                    done += 1
                    if done % (20 * per_episode) == 0:
                        logger.info("latent cache: %d/%d videos (%s)", done, len(videos), dict(self.cache.stats))
        return self.num_ready

    def _encode_or_fail(self, video: Path) -> dict[str, np.ndarray] | None:
        """The video's latents, or None after recording why it could not be encoded (``latents`` then
        raises DECODE_ERROR for it, so a bad video is tried once, not at every draw)."""
        try:
            return self._cached_or_encoded(video)
        except EncodeStopped:  # close(): not a failure, the video is encoded next time
            return None
        except (EpisodeError, FileNotFoundError) as err:
            logger.warning("latent cache: %s not encoded: %s", video.name, err)
            self._failed[video] = str(err)
            return None

    def build_for_stage(self, deadline: float | None, share: float = 0.1) -> int:
        """The cache before a stage draws its first batch. Without a ``deadline``: every video, now. With one:
        the first ``MIN_READY_EPISODES`` episodes, then more until ``share`` of the time left has passed; the
        rest are left to ``encode_in_background``."""
        if deadline is None:
            return self.build()
        now = time.time()
        self.build(self.dataset.valid_ids[:MIN_READY_EPISODES])
        ready = self.build(until=now + share * max(0.0, deadline - now))
        if ready == 0:
            raise RuntimeError(f"latent cache: none of the {len(self._failed)} videos tried could be encoded "
                               f"({sorted(set(self._failed.values()))[:3]})")
        return ready

    def encode_in_background(self, workers: int | None = None) -> None:
        """Start a daemon thread that encodes every pending video, then every episode the dataset adds
        (``rescan``), until ``close()``; from now on ``latents`` never encodes in the caller's thread.
        ``workers`` default: one less than ``build``'s (a core is left to the training step), at least 1."""
        if self._background is not None:
            raise RuntimeError("the background encoder is already running")
        workers = max(1, min(BUILD_WORKERS, os.cpu_count() or 1) - 1) if workers is None else workers

        def run():
            try:
                while not self._stop.is_set():
                    try:
                        pending = self.pending()
                    except RuntimeError:  # the dataset grew while we read it (a rescan in the training thread)
                        pending = None
                    if pending:
                        self.build(workers=workers, stop=self._stop)
                    else:
                        self._stop.wait(BACKGROUND_IDLE_S)
            except BaseException as err:  # raised again in the training thread by ``latents``
                logger.exception("latent cache: the background encoder stopped")
                self._background_error = err

        self._background = threading.Thread(target=run, name="latent-cache", daemon=True)
        self._background.start()

    def close(self) -> None:
        """Stop the background encoder: the videos in flight stop at their next chunk and are not cached (the
        cache files stay consistent); the thread is joined."""
        self._stop.set()
        if self._background is not None:
            self._background.join()

    def ready_candidates(self, sampler) -> list[int] | None:
        """The sampler's valid candidates whose videos all have latents, in the sampler's order; None when that
        is all of them or none (then draws go to every candidate, those not ready drawn again). Drawing among
        the ready ones instead: the first batches of a sprint's stage have a few ready episodes out of a
        thousand, and rejecting the rest cost 0.24 s per batch of 64 at 450 episodes (measured on the CPU)."""
        key = (id(sampler), self.num_ready, len(sampler.candidates), len(self._failed))
        if self._ready_memo is None or self._ready_memo[0] != key:
            ready = [e for e in sampler.candidates if self.dataset.is_valid(e) and all(
                video in self._latents for video, *_ in self._player_recordings(self._probe_segment(e)))]
            self._ready_memo = (key, ready if 0 < len(ready) < len(sampler.candidates) else None)
        return self._ready_memo[1]

    def _probe_segment(self, episode_id: int):
        """A segment of the episode, to list its videos."""
        return SegmentMP(episode_id, 0, 0) if isinstance(self.dataset, DuetDataset) else SegmentSP(episode_id, 0)

    def load(self, segment, num_frames: int) -> tuple[np.ndarray, ...]:
        """-> (x0 (P, F, h, w, C) f32, first frames (P, H, W, 3) uint8, actions (T, P, 25) f32), and with
        ``with_poses`` the poses of the clip's T frames (T, P, 5) f32 (frame j is record s + 1 + j)."""
        k = self.k
        num_latent = 1 + (num_frames - 1) // k
        x0s, firsts, acts, poses = [], [], [], []
        for video, act_T25, start, pose_T5 in self._player_recordings(segment):
            s = snap_start(start, k)
            a = (s + 1) // k
            cached = self.latents(video)
            lat = cached["latents"]
            if a + num_latent > len(lat):
                raise EpisodeError(DECODE_ERROR, f"{video.name}: {len(lat)} latents, clip needs {a + num_latent}")
            x0s.append(np.concatenate([lat[a:a + 1, 1], lat[a + 1:a + num_latent, 0]]).astype(np.float32))
            firsts.append(cached["anchor_frames"][a])  # frame s + 1 = k * a
            act = act_T25[max(s, 0): s + num_frames]
            if s < 0:
                act = np.concatenate([np.zeros((1, act_T25.shape[1]), np.float32), act])
            acts.append(act)
            if self.with_poses:
                if pose_T5 is None:
                    raise ValueError(f"{video.name}: its records carry no pose (x, y, z, yaw, pitch); the partner map "
                                     "(dit.partner_map) trains on Duet recordings with poses")
                poses.append(pose_T5[s + 1:s + 1 + num_frames])
        out = (np.stack(x0s), np.stack(firsts), np.stack(acts, axis=1))
        return out + (np.stack(poses, axis=1),) if self.with_poses else out

    def next_batch(self, sampler, batch_size: int, num_frames: int) -> dict[str, np.ndarray]:
        """Draw ``batch_size`` clips (skipping episodes that fail, like ``training.samplers.next_batch``);
        shaped as ``batch_spec`` says. While the background encoder runs, the episodes are drawn among those
        whose latents are ready (``ready_candidates``)."""
        among = self.ready_candidates(sampler) if self._background is not None else None
        out = draw_loaded(sampler, lambda segment: self.load(segment, num_frames), batch_size, among=among)
        arrays = [np.stack(parts) for parts in zip(*out)]
        return dict(zip(("x0", "first", "act", "pose"), arrays))


def batch_spec(cfg: WorldModelConfig, batch_size: int, num_frames: int) -> dict[str, jax.ShapeDtypeStruct]:
    """The shapes and dtypes of ``LatentClips.next_batch`` (P = ``cfg.num_players``), for compiling ahead."""
    b, p, f = batch_size, cfg.num_players, cfg.vae.latent_frames(num_frames)
    return {"x0": jax.ShapeDtypeStruct((b, p, f, cfg.latent_height, cfg.latent_width, cfg.latent_channels), np.float32),
            "first": jax.ShapeDtypeStruct((b, p, cfg.frame_height, cfg.frame_width, 3), np.uint8),
            "act": jax.ShapeDtypeStruct((b, num_frames, p, MODEL_ACTION_DIM), np.float32),
            **({"pose": jax.ShapeDtypeStruct((b, num_frames, p, 5), np.float32)} if cfg.dit.partner_map else {})}


def make_prepare_latents(cfg: WorldModelConfig, vae, encoder):
    """Jitted ``(x0 (B,P,F,h,w,C), first (B,P,H,W,3) uint8, act (B,T,P,25)) -> DiT batch`` (the dict of
    ``training.step.prepare_batch``) from cached latents; the image encoder runs on the first frames."""
    (vg, vs), (eg, es) = nnx.split(vae), nnx.split(encoder)

    def prepare(vae_state, enc_state, x0, first, act, pose=None):
        b, p, f = x0.shape[:3]
        first_flat = frames_to_model(first.reshape((b * p,) + first.shape[2:]))
        context = nnx.merge(eg, enc_state)(first_flat)
        if cfg.vae.cond_encoding == "image":
            img = jnp.concatenate([x0[:, :, :1], jnp.zeros_like(x0[:, :, 1:])], axis=2)
            mask = first_frame_mask(f, cfg.frames_per_step)
            mask = jnp.broadcast_to(mask[None, None, :, None, None, :], (b, p, f) + x0.shape[3:5] + mask.shape[-1:])
            cond = jnp.concatenate([mask, img], axis=-1)
        else:  # the Wan layout encodes gray frames after the first: run the VAE
            from solaris_env.world_model.conditioning import first_frame_cond
            cond = first_frame_cond(nnx.merge(vg, vae_state), first_flat, f).reshape((b, p, f) + x0.shape[3:5] + (-1,))
        if cfg.dit.partner_map:  # each player's view of the other, per latent frame (partner.py)
            maps = partner_lib.partner_maps(pose, *x0.shape[3:5])  # (B, T, P, h, w)
            maps = partner_lib.latent_frame_maps(jnp.moveaxis(maps, 1, 2), cfg.frames_per_step)  # (B, P, F, h, w)
            cond = partner_lib.with_partner(cond, maps, cfg.mask_channels, cfg.dit.partner_map)
        actions = left_pad_actions(act.astype(jnp.float32).transpose(0, 2, 1, 3), cfg.action_left_padding)
        kb = cfg.action.keyboard_dim
        unfold = lambda a: to_stream(cfg, jax.lax.stop_gradient(a))
        return {"x0": unfold(x0), "cond": unfold(cond),
                "context": unfold(context.reshape((b, p) + context.shape[1:])),
                "mouse": to_stream(cfg, actions[..., kb:]), "keyboard": to_stream(cfg, actions[..., :kb])}

    jitted = jax.jit(prepare)

    def run(batch):
        if cfg.dit.partner_map and "pose" not in batch:
            raise ValueError("dit.partner_map is on but the batch has no 'pose' (LatentClips.with_poses)")
        pose = jnp.asarray(batch["pose"]) if cfg.dit.partner_map else None
        return jitted(vs, es, jnp.asarray(batch["x0"]), jnp.asarray(batch["first"]), jnp.asarray(batch["act"]), pose)
    return run


def latent_clips(dataset, cfg: WorldModelConfig, vae, cache_root: Path, canonical_dir: Path | None = None
                 ) -> LatentClips:
    """LatentClips with its cache under ``cache_root/<VAE fingerprint>``; ``canonical_dir`` (e.g.
    ``data/duet``) names the videos that hard-linked copies (the VPT export) share latents with."""
    encoder = VideoEncoder(cfg, vae)
    cache = LatentCache(Path(cache_root) / encoder.fingerprint, encoder.fingerprint, VideoEncoder.tensors)
    return LatentClips(dataset, cache, encoder, canonical_dir)


__all__ = ["LatentClips", "VideoEncoder", "batch_spec", "latent_clips", "make_prepare_latents", "snap_start", "vae_fingerprint"]
