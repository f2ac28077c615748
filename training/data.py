"""Training data: Duet (multiplayer) and VPT-layout (single-player) loaders, seeded resumable segment
samplers, batching, and an optional per-episode latent cache.

Reference semantics (docs/data-format.md §2, §5, §7):

* **Duet layout** ``{data_dir}/{name}/{split}/`` with ``name="duet"`` (training) or e.g.
  ``name="eval/rotationEval"``, ``split="test"`` (eval sets). Every ``*_Alpha_*.mp4`` (sorted by file
  name) whose Bravo twin (first ``_Alpha_`` -> ``_Bravo_``) and both action JSONs (same stem, a trailing
  ``_camera`` stripped) exist gets the next episode id 0, 1, 2, ...; eval ids refer to these ids.
  Player 0 is ``bot1`` (Alpha), player 1 is ``bot2`` (Bravo).
* **Alignment**: a segment starting at record ``s`` holds actions ``[s, s+T)`` and frames
  ``[s+1, s+T+1)``: model frame k is the observation *after* action k (frame t of a recording shows the
  state before action t). The two bots are aligned by ``renderTime``, not by index.
* **Actions**: Duet records -> ``mineflayer_records_to_vectors``; VPT JSONL -> ``vpt_jsonl_to_vectors``
  (stateful, so whole episodes are converted once and sliced); then ``camera_linear`` on dims 23/24.
* **VPT camera sign** (a decision, docs/data-format.md §7.3): VPT's +dx is a turn to the right and +dy a look
  down, Mineflayer's +yaw turns left and +pitch looks up. The reference feeds both into the model
  unreconciled. :class:`VPTDataset` flips dims 23/24 of VPT actions by default so that one action
  vector means one motion in both datasets (the stage-1 weights then agree with stages 2-4);
  ``reference_camera_sign=True`` keeps the reference's unflipped VPT camera.

Robustness: every episode is validated when the dataset is built (readable mp4, JSON list of records
with ``action`` dicts, frame count == record count, strictly increasing ``renderTime``). A corrupt or
missing episode is skipped, logged through :mod:`logging` and counted in ``dataset.skipped``
(reason -> count); it never raises. Complete-but-corrupt Duet episodes keep their id (marked invalid)
so the ids of the others, which eval id files refer to, do not shift. A decode failure found later
(a video that opens but is cut short) marks the episode invalid the same way; :func:`next_batch`
then draws another segment.

Determinism and resume: the samplers draw segment ``i`` of a run with
``np.random.default_rng([seed, rank, i])``, so the stream depends only on (seed, rank, step);
``state_dict()`` / ``load_state_dict()`` save and restore the step, and a resumed run draws exactly
the segments the uninterrupted run would have drawn. (The reference's multiplayer sampler ignores the
configured seed and replays its stream on resume, docs/data-format.md §7.5; ours does neither.)

Shapes: a segment is ``obs_TPHW3`` uint8 and ``act_TP25`` float32 (P=2 for Duet, P=1 for VPT: single
player is multiplayer with one player); :func:`make_batch` stacks and right-pads them to
``obs_BTPHW3`` / ``act_BTP25`` plus ``real_lengths_B``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import secrets
import threading
from collections import Counter, OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from solaris_env.spaces import (
    CAMERA_X_INDEX,
    CAMERA_Y_INDEX,
    MODEL_ACTION_DIM,
    camera_linear,
    mineflayer_records_to_vectors,
    vpt_jsonl_to_vectors,
)

logger = logging.getLogger(__name__)

# Skip reasons (keys of ``dataset.skipped`` / ``sampler.skipped``).
MISSING_FILE = "missing_file"  # a bot's mp4 or action JSON is absent
UNREADABLE_VIDEO = "unreadable_video"  # OpenCV cannot open the mp4 or read its first frame
BAD_JSON = "bad_json"  # not JSON, not a list of records with valid "action" dicts / numeric renderTime
COUNT_MISMATCH = "count_mismatch"  # video frames != action records (VPT: != episodes_info length too)
BAD_RENDER_TIME = "bad_render_time"  # renderTime not strictly increasing
DECODE_ERROR = "decode_error"  # the video opened but a frame a segment needs could not be decoded
INVALID_EPISODE = "invalid_episode"  # a segment was asked of an episode already skipped (not counted again)
TOO_SHORT = "too_short"  # sampler: no segment of num_frames (+1 frame) fits the (common) window

DEFAULT_FRAME_CACHE_MB = 256  # decoded-episode LRU per dataset; 0 decodes only the frames asked for


class EpisodeError(ValueError):
    """A corrupt or missing episode file; ``reason`` is one of the skip reasons above."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(f"{reason}: {message}")
        self.reason = reason


class SegmentMP(NamedTuple):
    """A multiplayer segment: episode id and each bot's first action record (eval-id row order)."""

    episode_id: int
    start1: int
    start2: int


class SegmentSP(NamedTuple):
    """A single-player segment: episode id and first action record."""

    episode_id: int
    start: int


# ---------------------------------------------------------------------------------------------
# Video reading
# ---------------------------------------------------------------------------------------------


def _open_video(path: Path):
    import cv2

    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise EpisodeError(UNREADABLE_VIDEO, f"{path.name}: OpenCV cannot open it")
    return cap


def probe_video(path: str | Path) -> int:
    """Frame count of an mp4 from its header, after checking that the first frame decodes."""
    import cv2

    path = Path(path)
    cap = _open_video(path)
    try:
        n_frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        ok, _ = cap.read()
    finally:
        cap.release()
    if n_frames <= 0 or not ok:
        raise EpisodeError(UNREADABLE_VIDEO, f"{path.name}: reports {n_frames} frames, first frame ok={ok}")
    return n_frames


def _to_rgb(bgr_HW3: np.ndarray, size: tuple[int, int] | None) -> np.ndarray:
    """BGR frame -> RGB uint8, resized with INTER_AREA to ``size`` = (H, W) when it differs."""
    import cv2

    rgb_HW3 = bgr_HW3[..., ::-1]
    if size is not None and rgb_HW3.shape[:2] != tuple(size):
        rgb_HW3 = cv2.resize(rgb_HW3, (size[1], size[0]), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(rgb_HW3)


def read_frames(path: str | Path, start: int, stop: int | None, size: tuple[int, int] | None = None) -> np.ndarray:
    """Decode frames ``[start, stop)`` (``stop=None``: to the end) as RGB uint8 (N, H, W, 3).

    Frames before ``start`` are grabbed without conversion (sequential decoding: exact for any codec,
    unlike seeking). Raises EpisodeError(DECODE_ERROR) when a frame in the range cannot be decoded.
    """
    path = Path(path)
    cap = _open_video(path)
    frames = []
    try:
        for i in range(start):
            if not cap.grab():
                raise EpisodeError(DECODE_ERROR, f"{path.name}: frame {i} could not be decoded")
        i = start
        while stop is None or i < stop:
            ok, bgr = cap.read()
            if not ok:
                if stop is None:
                    break
                raise EpisodeError(DECODE_ERROR, f"{path.name}: frame {i} could not be decoded")
            frames.append(_to_rgb(bgr, size))
            i += 1
    finally:
        cap.release()
    if not frames:
        raise EpisodeError(DECODE_ERROR, f"{path.name}: no frame in [{start}, {stop})")
    return np.stack(frames)


class FrameReader:
    """Reads frame ranges of videos at one output size, with an LRU of fully decoded videos.

    Args:
        size: (H, W) to resize to with INTER_AREA, or None to keep the recorded size.
        cache_mb: memory budget of the LRU in MiB; 0 disables it (each read decodes just the range).
    """

    def __init__(self, size: tuple[int, int] | None = None, cache_mb: float = DEFAULT_FRAME_CACHE_MB) -> None:
        if size is not None and (len(size) != 2 or min(size) < 1):
            raise ValueError(f"obs_size must be (H, W) with positive sizes or None, got {size!r}")
        self.size = None if size is None else (int(size[0]), int(size[1]))
        self.max_bytes = int(cache_mb * 2**20)
        self._cache: OrderedDict[Path, np.ndarray] = OrderedDict()
        self._bytes = 0
        self._too_big: set[Path] = set()

    def read(self, path: Path, start: int, stop: int) -> np.ndarray:
        """Frames ``[start, stop)`` as (stop - start, H, W, 3) uint8 RGB (read-only when cached)."""
        if self.max_bytes <= 0 or path in self._too_big:
            return read_frames(path, start, stop, self.size)
        frames_THW3 = self._cache.get(path)
        if frames_THW3 is None:
            frames_THW3 = read_frames(path, 0, None, self.size)
            self._put(path, frames_THW3)
        else:
            self._cache.move_to_end(path)
        if stop > len(frames_THW3):
            raise EpisodeError(DECODE_ERROR, f"{path.name}: only {len(frames_THW3)} frames decode, need {stop}")
        return frames_THW3[start:stop]

    def _put(self, path: Path, frames_THW3: np.ndarray) -> None:
        if frames_THW3.nbytes > self.max_bytes:
            self._too_big.add(path)  # later reads of it decode just their range
            return
        frames_THW3.flags.writeable = False  # shared by every segment sliced from it
        self._cache[path] = frames_THW3
        self._bytes += frames_THW3.nbytes
        while self._bytes > self.max_bytes:
            _, old = self._cache.popitem(last=False)
            self._bytes -= old.nbytes


# ---------------------------------------------------------------------------------------------
# Duet (multiplayer) dataset
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BotRecording:
    """One bot's validated recording: files, per-record renderTime (ms) and model action vectors."""

    video: Path
    actions: Path
    times_T: np.ndarray  # (T,) float64 renderTime, strictly increasing
    act_T25: np.ndarray  # (T, 25) float32, camera_linear applied

    @property
    def num_records(self) -> int:
        return len(self.times_T)


def actions_path_of(video: Path) -> Path:
    """``<stem>[_camera].mp4`` -> ``<stem>.json`` (the eval layout keeps ``_camera`` on videos only)."""
    return video.with_name(video.name.removesuffix(".mp4").removesuffix("_camera") + ".json")


def _read_records(path: Path) -> list:
    try:
        records = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise EpisodeError(BAD_JSON, f"{path.name}: {err}") from None
    if not isinstance(records, list) or not records:
        raise EpisodeError(BAD_JSON, f"{path.name}: expected a non-empty JSON list of records")
    return records


def _render_times(records: list, path: Path) -> np.ndarray:
    try:
        times_T = np.array([float(r["renderTime"]) for r in records], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as err:
        raise EpisodeError(BAD_JSON, f"{path.name}: missing or non-numeric renderTime ({err!r})") from None
    if not np.all(np.isfinite(times_T)):
        raise EpisodeError(BAD_JSON, f"{path.name}: non-finite renderTime")
    if np.any(np.diff(times_T) <= 0):
        i = int(np.flatnonzero(np.diff(times_T) <= 0)[0])
        raise EpisodeError(BAD_RENDER_TIME, f"{path.name}: renderTime[{i + 1}]={times_T[i + 1]} <= [{i}]={times_T[i]}")
    return times_T


def load_bot_recording(video: Path, actions: Path) -> BotRecording:
    """Validate one bot's mp4 + action JSON and convert its actions; raises EpisodeError."""
    n_frames = probe_video(video)
    records = _read_records(actions)
    try:
        act_T25 = camera_linear(mineflayer_records_to_vectors(records))
    except ValueError as err:
        raise EpisodeError(BAD_JSON, f"{actions.name}: {err}") from None
    times_T = _render_times(records, actions)
    if n_frames != len(records):
        raise EpisodeError(COUNT_MISMATCH, f"{video.name}: {n_frames} frames for {len(records)} records")
    return BotRecording(video, actions, times_T, act_T25)


def _segment_length(num_frames: int, starts: Sequence[int], num_records: Sequence[int]) -> int:
    """Frames a segment can hold: min(num_frames, n - 1 - start) over players (frames end at start+T)."""
    if num_frames < 1:
        raise ValueError(f"num_frames must be >= 1, got {num_frames}")
    for start, n in zip(starts, num_records):
        if not 0 <= start < n - 1:
            raise ValueError(f"segment start {start} outside [0, {n - 1}) for a recording of {n} records")
    return min(num_frames, *(n - 1 - s for s, n in zip(starts, num_records)))


class _EpisodeTable:
    """What the datasets share: the ``skipped`` counter with logging, and the episode table
    ``self._episodes`` (one entry per episode id, None for an invalid episode)."""

    _episodes: list

    @property
    def num_episodes(self) -> int:
        return len(self._episodes)

    @property
    def valid_ids(self) -> list[int]:
        return [i for i, ep in enumerate(self._episodes) if ep is not None]

    def is_valid(self, episode_id: int) -> bool:
        return 0 <= episode_id < self.num_episodes and self._episodes[episode_id] is not None

    def _init_skips(self) -> None:
        self.skipped: Counter[str] = Counter()

    def _skip(self, what: str, err: EpisodeError) -> None:
        self.skipped[err.reason] += 1
        logger.warning("skipping %s: %s", what, err)


class DuetDataset(_EpisodeTable):
    """Two-player episodes in the Duet layout (docs/data-format.md §7.1), validated once at construction.

    Args:
        data_dir: dataset root; episodes are read from ``data_dir/name/split``.
        split: "train" or "test" (eval sets only have "test").
        bot1, bot2: bot names of players 0 and 1.
        obs_size: (H, W) frames are resized to (cv2 INTER_AREA) when they differ; None keeps the recorded
            size (the reference uses (360, 640)).
        name: dataset name under ``data_dir``: "duet" or e.g. "eval/rotationEval" (also the eval-ids key).
        frame_cache_mb: LRU budget of decoded videos (:class:`FrameReader`).

    Attributes:
        num_episodes: number of episode ids (complete file quadruples, valid or not).
        valid_ids: ids of the episodes that passed validation.
        skipped: reason -> number of episodes skipped for it.
    """

    def __init__(
        self,
        data_dir: str | Path,
        split: str = "train",
        bot1: str = "Alpha",
        bot2: str = "Bravo",
        obs_size: tuple[int, int] | None = None,
        name: str = "duet",
        frame_cache_mb: float = DEFAULT_FRAME_CACHE_MB,
    ) -> None:
        self.directory = Path(data_dir) / name / split
        if not self.directory.is_dir():
            raise FileNotFoundError(f"Duet dataset directory {self.directory} does not exist")
        self.name, self.split, self.bots = name, split, (bot1, bot2)
        self.frames = FrameReader(obs_size, frame_cache_mb)
        self._init_skips()
        self._episodes: list[tuple[BotRecording, BotRecording] | None] = []
        self.stems: list[str] = []
        for alpha_mp4 in sorted(self.directory.glob(f"*_{bot1}_*.mp4"), key=lambda p: p.name):
            self._add_episode(alpha_mp4)
        logger.info("%s/%s: %d episodes, %d valid, skipped %s", name, split, self.num_episodes,
                    len(self.valid_ids), dict(self.skipped))

    def _add_episode(self, alpha_mp4: Path) -> None:
        bot1, bot2 = self.bots
        bravo_mp4 = alpha_mp4.with_name(alpha_mp4.name.replace(f"_{bot1}_", f"_{bot2}_", 1))
        files = (alpha_mp4, actions_path_of(alpha_mp4), bravo_mp4, actions_path_of(bravo_mp4))
        missing = [p.name for p in files if not p.is_file()]
        if missing:  # no id: the reference only numbers complete quadruples
            self._skip(alpha_mp4.name, EpisodeError(MISSING_FILE, f"missing {missing}"))
            return
        self.stems.append(alpha_mp4.name.removesuffix(".mp4"))
        try:
            self._episodes.append((load_bot_recording(*files[:2]), load_bot_recording(*files[2:])))
        except EpisodeError as err:
            self._skip(f"episode {len(self._episodes)} ({alpha_mp4.name})", err)
            self._episodes.append(None)

    # -- episode access -----------------------------------------------------------------------

    def recordings(self, episode_id: int) -> tuple[BotRecording, BotRecording]:
        """Both bots' recordings; raises EpisodeError for an invalid episode."""
        if not 0 <= episode_id < self.num_episodes:
            raise IndexError(f"episode id {episode_id} outside [0, {self.num_episodes})")
        episode = self._episodes[episode_id]
        if episode is None:
            raise EpisodeError(INVALID_EPISODE, f"episode {episode_id} ({self.stems[episode_id]}) was skipped")
        return episode

    def render_times(self, episode_id: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-record renderTime (ms, float64) of both bots."""
        rec1, rec2 = self.recordings(episode_id)
        return rec1.times_T, rec2.times_T

    # -- segments ---------------------------------------------------------------------------

    def segment(self, episode_id: int, start1: int, start2: int, num_frames: int) -> tuple[np.ndarray, np.ndarray]:
        """Aligned frames and actions of both bots.

        Returns ``obs_TPHW3`` uint8 = frames ``[start_p + 1, start_p + T + 1)`` and ``act_TP25`` float32 =
        records ``[start_p, start_p + T)`` of each bot p, with T = num_frames, or fewer when a recording
        ends first (pad with :func:`make_batch`). Raises ValueError for a start outside the recording
        and EpisodeError for a skipped episode or a frame that does not decode (the episode is then
        marked invalid and counted as DECODE_ERROR).
        """
        recs = self.recordings(episode_id)
        starts = (start1, start2)
        T = _segment_length(num_frames, starts, [r.num_records for r in recs])
        try:
            obs = [self.frames.read(r.video, s + 1, s + T + 1) for r, s in zip(recs, starts)]
        except EpisodeError as err:
            self._episodes[episode_id] = None
            self._skip(f"episode {episode_id} ({self.stems[episode_id]})", err)
            raise
        obs_TPHW3 = np.stack(obs, axis=1)
        act_TP25 = np.stack([r.act_T25[s : s + T] for r, s in zip(recs, starts)], axis=1)
        return obs_TPHW3, act_TP25

    def load(self, segment: SegmentMP, num_frames: int) -> tuple[np.ndarray, np.ndarray]:
        return self.segment(segment.episode_id, segment.start1, segment.start2, num_frames)


# ---------------------------------------------------------------------------------------------
# VPT-layout (single-player) dataset
# ---------------------------------------------------------------------------------------------


def read_jsonl_text(path: Path) -> str:
    """A VPT actions file as text: utf-8, falling back to windows-1252 (as the reference)."""
    raw = path.read_bytes()
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("windows-1252", errors="replace")


def vpt_camera_to_mineflayer(act_T25: np.ndarray) -> np.ndarray:
    """Flip the sign of cameraX/cameraY: VPT (+right, +down) -> Mineflayer (+left, +up). Returns a copy."""
    out_T25 = np.array(act_T25, dtype=np.float32)
    out_T25[..., [CAMERA_X_INDEX, CAMERA_Y_INDEX]] = 0.0 - out_T25[..., [CAMERA_X_INDEX, CAMERA_Y_INDEX]]
    return out_T25


@dataclass(frozen=True)
class VPTEpisode:
    """One validated VPT-layout episode."""

    video: Path
    actions: Path
    act_T25: np.ndarray  # (L, 25) float32, camera_linear applied

    @property
    def length(self) -> int:
        return len(self.act_T25)


class VPTDataset(_EpisodeTable):
    """Single-player episodes in the VPT layout (docs/data-format.md §7.3), segments with a player axis of 1.

    ``{data_dir}/vpt/{split}/episodes_info.json`` = ``{"num_episodes", "episodes": [{"video_path",
    "actions_path", "length", "episode_id"}]}`` (paths relative to the split dir); episode ids are
    positions in that list. An episode is valid when its mp4 opens, its JSONL parses (utf-8, else
    windows-1252) and frames == JSONL ticks == ``length``.

    Args:
        data_dir: dataset root.
        split: "train" or "test".
        obs_size: (H, W) resize target (INTER_AREA), or None to keep the recorded size.
        reference_camera_sign: False (default) converts VPT's camera to the Mineflayer sign convention
            of the Duet data (flip dims 23/24); True keeps the reference's unreconciled VPT signs.
        frame_cache_mb: LRU budget of decoded videos.
    """

    def __init__(
        self,
        data_dir: str | Path,
        split: str = "train",
        obs_size: tuple[int, int] | None = None,
        reference_camera_sign: bool = False,
        frame_cache_mb: float = DEFAULT_FRAME_CACHE_MB,
    ) -> None:
        self.directory = Path(data_dir) / "vpt" / split
        info_path = self.directory / "episodes_info.json"
        if not info_path.is_file():
            raise FileNotFoundError(f"VPT dataset index {info_path} does not exist")
        self.name, self.split = "vpt", split
        self.reference_camera_sign = reference_camera_sign
        self.frames = FrameReader(obs_size, frame_cache_mb)
        self._init_skips()
        entries = json.loads(info_path.read_text())["episodes"]
        self._episodes: list[VPTEpisode | None] = [self._load_entry(i, e) for i, e in enumerate(entries)]
        logger.info("vpt/%s: %d episodes, %d valid, skipped %s", split, self.num_episodes, len(self.valid_ids),
                    dict(self.skipped))

    def _load_entry(self, index: int, entry: dict) -> VPTEpisode | None:
        try:
            video, actions = self.directory / entry["video_path"], self.directory / entry["actions_path"]
            missing = [p.name for p in (video, actions) if not p.is_file()]
            if missing:
                raise EpisodeError(MISSING_FILE, f"missing {missing}")
            return self._load_episode(video, actions, int(entry["length"]))
        except (KeyError, TypeError, ValueError) as err:  # EpisodeError is a ValueError
            if not isinstance(err, EpisodeError):
                err = EpisodeError(BAD_JSON, f"episodes_info entry {index}: {err!r}")
            self._skip(f"vpt episode {index}", err)
            return None

    def _load_episode(self, video: Path, actions: Path, length: int) -> VPTEpisode:
        n_frames = probe_video(video)
        try:
            act_T25 = vpt_jsonl_to_vectors(read_jsonl_text(actions).splitlines())
        except (OSError, ValueError) as err:  # JSONDecodeError is a ValueError
            raise EpisodeError(BAD_JSON, f"{actions.name}: {err}") from None
        if not n_frames == len(act_T25) == length:
            raise EpisodeError(COUNT_MISMATCH, f"{video.name}: {n_frames} frames, {len(act_T25)} ticks, "
                                               f"length {length}")
        if not self.reference_camera_sign:
            act_T25 = vpt_camera_to_mineflayer(act_T25)
        return VPTEpisode(video, actions, camera_linear(act_T25))


    def episode(self, episode_id: int) -> VPTEpisode:
        if not 0 <= episode_id < self.num_episodes:
            raise IndexError(f"episode id {episode_id} outside [0, {self.num_episodes})")
        episode = self._episodes[episode_id]
        if episode is None:
            raise EpisodeError(INVALID_EPISODE, f"vpt episode {episode_id} was skipped")
        return episode

    def segment(self, episode_id: int, start: int, num_frames: int) -> tuple[np.ndarray, np.ndarray]:
        """``obs_T1HW3`` = frames ``[start+1, start+T+1)``, ``act_T125`` = ticks ``[start, start+T)``.

        T = num_frames, or fewer at the end of the episode. Errors as :meth:`DuetDataset.segment`.
        """
        episode = self.episode(episode_id)
        T = _segment_length(num_frames, (start,), (episode.length,))
        try:
            obs_THW3 = self.frames.read(episode.video, start + 1, start + T + 1)
        except EpisodeError as err:
            self._episodes[episode_id] = None
            self._skip(f"vpt episode {episode_id}", err)
            raise
        return obs_THW3[:, None].copy(), episode.act_T25[start : start + T, None].copy()

    def load(self, segment: SegmentSP, num_frames: int) -> tuple[np.ndarray, np.ndarray]:
        return self.segment(segment.episode_id, segment.start, num_frames)


# ---------------------------------------------------------------------------------------------
# Samplers
# ---------------------------------------------------------------------------------------------


class _ResumableSampler:
    """Seeded, resumable segment stream: draw i uses ``default_rng([seed, rank, i])``.

    Subclasses fill ``self._candidates`` (episode ids of this rank that can hold a segment) and
    implement ``_draw(rng, episode_id)``.
    """

    def __init__(self, dataset, num_frames: int, seed: int, rank: int, num_ranks: int) -> None:
        if num_frames < 1:
            raise ValueError(f"num_frames must be >= 1, got {num_frames}")
        if not 0 <= rank < num_ranks:
            raise ValueError(f"rank must be in [0, num_ranks={num_ranks}), got {rank}")
        self.dataset, self.num_frames = dataset, int(num_frames)
        self.seed, self.rank, self.num_ranks = int(seed), int(rank), int(num_ranks)
        self.step = 0
        self.skipped: Counter[str] = Counter()
        self._candidates: list[int] = []

    def _check_candidates(self) -> None:
        if not self._candidates:
            raise ValueError(f"no episode of rank {self.rank}/{self.num_ranks} holds a segment of {self.num_frames} "
                             f"frames (dataset skipped {dict(self.dataset.skipped)}, sampler skipped "
                             f"{dict(self.skipped)})")

    def _draw(self, rng: np.random.Generator, episode_id: int):
        raise NotImplementedError

    def next(self):
        """The next segment; draws whose episode has since been marked invalid are passed over."""
        while True:
            rng = np.random.default_rng([self.seed, self.rank, self.step])
            self.step += 1
            episode_id = self._candidates[int(rng.integers(len(self._candidates)))]
            if self.dataset.is_valid(episode_id):
                return self._draw(rng, episode_id)
            if not any(self.dataset.is_valid(i) for i in self._candidates):
                raise ValueError(f"every episode of rank {self.rank} has been marked invalid "
                                 f"(skipped {dict(self.dataset.skipped)})")

    def sample(self, batch_size: int = 1) -> list:
        return [self.next() for _ in range(batch_size)]

    def __iter__(self):
        while True:
            yield self.next()

    def state_dict(self) -> dict[str, int]:
        return {"step": self.step, "seed": self.seed, "rank": self.rank, "num_ranks": self.num_ranks,
                "num_frames": self.num_frames, "num_candidates": len(self._candidates)}

    def load_state_dict(self, state: dict[str, int]) -> None:
        """Restore the step; the stream's defining settings must match the saved ones."""
        for key in ("seed", "rank", "num_ranks", "num_frames"):
            if int(state[key]) != getattr(self, key):
                raise ValueError(f"sampler state has {key}={state[key]}, this sampler {key}={getattr(self, key)}")
        if int(state.get("num_candidates", len(self._candidates))) != len(self._candidates):
            logger.warning("sampler resumed over %d episodes, saved with %d: the stream will differ",
                           len(self._candidates), state["num_candidates"])
        self.step = int(state["step"])


@dataclass(frozen=True)
class _Window:
    """Per-episode sampling window of both bots (indices inclusive, times in ms)."""

    start_time: float
    end_time: float


class MultiplayerSegmentSampler(_ResumableSampler):
    """``BatchSamplerMultiplayer`` semantics: uniform episode (with replacement) among this rank's
    episodes (``id % num_ranks == rank``), start time ~ U(window), per-bot start = bisect_left.

    Per episode, the common window ``[max first renderTime, min last renderTime]`` becomes per-bot index
    ranges (bisect), and each range's end is pulled in by num_frames so frame ``start + num_frames``
    exists; the window is then ``[min time at the bot starts, min time at the bot ends]``. Episodes
    where a range is empty are skipped (``skipped[TOO_SHORT]``).

    Args:
        dataset: a :class:`DuetDataset`.
        num_frames: segment length T (actions; frames read are start+1 .. start+T).
        seed: stream seed.
        rank, num_ranks: data-parallel partition.
    """

    def __init__(self, dataset: DuetDataset, num_frames: int, seed: int = 0, rank: int = 0,
                 num_ranks: int = 1) -> None:
        super().__init__(dataset, num_frames, seed, rank, num_ranks)
        self._windows: dict[int, _Window] = {}
        for episode_id in dataset.valid_ids:
            self.add_episode(episode_id)
        self._check_candidates()

    def add_episode(self, episode_id: int) -> bool:
        """Make a valid episode of the dataset a candidate if it is this rank's and holds a segment
        (``training.growing_data`` adds the episodes a growing dataset found); returns whether it was added."""
        if episode_id % self.num_ranks != self.rank:
            return False
        window = self._window(*self.dataset.render_times(episode_id))
        if window is None:
            self.skipped[TOO_SHORT] += 1
            logger.warning("sampler: episode %d cannot hold a segment of %d frames", episode_id, self.num_frames)
            return False
        self._windows[episode_id] = window
        self._candidates.append(episode_id)
        return True

    def _window(self, times1_T: np.ndarray, times2_T: np.ndarray) -> _Window | None:
        start_time = max(times1_T[0], times2_T[0])
        end_time = min(times1_T[-1], times2_T[-1])
        starts = [int(np.searchsorted(t, start_time, side="left")) for t in (times1_T, times2_T)]
        ends = [int(np.searchsorted(t, end_time, side="right")) - 1 - self.num_frames for t in (times1_T, times2_T)]
        if any(e < s for s, e in zip(starts, ends)):
            return None
        return _Window(min(times1_T[starts[0]], times2_T[starts[1]]), min(times1_T[ends[0]], times2_T[ends[1]]))

    def _draw(self, rng: np.random.Generator, episode_id: int) -> SegmentMP:
        window = self._windows[episode_id]
        start_time = rng.uniform(window.start_time, window.end_time)
        times1_T, times2_T = self.dataset.render_times(episode_id)
        start1 = int(np.searchsorted(times1_T, start_time, side="left"))  # bisect_left
        start2 = int(np.searchsorted(times2_T, start_time, side="left"))
        return SegmentMP(episode_id, start1, start2)


class SinglePlayerSegmentSampler(_ResumableSampler):
    """Uniform episode among this rank's episodes with length >= num_frames + 1, uniform start in
    ``[0, length - num_frames - 1]`` (so the last frame read, start + num_frames, exists; the reference
    allows one start more and would read past the end, docs/data-format.md §7.3).

    Args: as :class:`MultiplayerSegmentSampler`, with a :class:`VPTDataset`.
    """

    def __init__(self, dataset: VPTDataset, num_frames: int, seed: int = 0, rank: int = 0,
                 num_ranks: int = 1) -> None:
        super().__init__(dataset, num_frames, seed, rank, num_ranks)
        for episode_id in dataset.valid_ids:
            self.add_episode(episode_id)
        self._check_candidates()

    def add_episode(self, episode_id: int) -> bool:
        """As ``MultiplayerSegmentSampler.add_episode``."""
        if episode_id % self.num_ranks != self.rank:
            return False
        if self.dataset.episode(episode_id).length < self.num_frames + 1:
            self.skipped[TOO_SHORT] += 1
            return False
        self._candidates.append(episode_id)
        return True

    def _draw(self, rng: np.random.Generator, episode_id: int) -> SegmentSP:
        length = self.dataset.episode(episode_id).length
        return SegmentSP(episode_id, int(rng.integers(0, length - self.num_frames)))


class EvalSegments:
    """Fixed eval segments from an ``eval_ids_<name>.json`` file (docs/data-format.md §7.6).

    Rows ``[episode_id, start1, stop1, start2, stop2]`` (multiplayer) or ``[episode_id, start, stop]``
    (single player); stops are ignored (the loader uses start + num_frames).
    """

    def __init__(self, eval_ids_json: str | Path) -> None:
        rows = json.loads(Path(eval_ids_json).read_text())
        lengths = {len(r) for r in rows}
        if not rows or lengths - {3, 5} or len(lengths) != 1:
            raise ValueError(f"{eval_ids_json}: expected rows of 5 (multiplayer) or 3 (single player) ints, "
                             f"got lengths {sorted(lengths)}")
        if lengths == {5}:
            self.all: list = [SegmentMP(int(r[0]), int(r[1]), int(r[3])) for r in rows]
        else:
            self.all = [SegmentSP(int(r[0]), int(r[1])) for r in rows]

    def __len__(self) -> int:
        return len(self.all)

    def segments(self, num_samples: int | None = None, rank: int = 0, num_ranks: int = 1) -> list:
        """The first ``num_samples`` segments, then every num_ranks-th from ``rank`` (device-count independent)."""
        return self.all[:num_samples][rank::num_ranks]


# ---------------------------------------------------------------------------------------------
# Batching
# ---------------------------------------------------------------------------------------------


def make_batch(samples: Sequence[tuple[np.ndarray, np.ndarray]], num_frames: int | None = None,
               batch_size: int | None = None) -> dict[str, np.ndarray]:
    """Stack segments, zero-padding each on the right to num_frames (default: the longest).

    Args:
        samples: (obs_TPHW3 uint8, act_TP25 float32) pairs with the same P, H, W.
        num_frames: padded length T.
        batch_size: pad the batch itself to this many rows (real length 0), e.g. a device multiple.
    Returns:
        ``obs_BTPHW3`` uint8, ``act_BTP25`` float32 and ``real_lengths_B`` int32 under the keys
        "obs", "act", "real_lengths".
    """
    if not samples:
        raise ValueError("make_batch: no samples")
    T = num_frames if num_frames is not None else max(len(obs) for obs, _ in samples)
    B = batch_size if batch_size is not None else len(samples)
    if B < len(samples):
        raise ValueError(f"batch_size {B} < {len(samples)} samples")
    _, P, H, W, _ = samples[0][0].shape
    obs_BTPHW3 = np.zeros((B, T, P, H, W, 3), np.uint8)
    act_BTP25 = np.zeros((B, T, P, MODEL_ACTION_DIM), np.float32)
    real_lengths_B = np.zeros((B,), np.int32)
    for b, (obs_TPHW3, act_TP25) in enumerate(samples):
        n = len(obs_TPHW3)
        if n > T or obs_TPHW3.shape[1:] != (P, H, W, 3) or act_TP25.shape != (n, P, MODEL_ACTION_DIM):
            raise ValueError(f"sample {b}: obs {obs_TPHW3.shape} / act {act_TP25.shape} do not fit "
                             f"(T<={T}, P={P}, H={H}, W={W})")
        obs_BTPHW3[b, :n], act_BTP25[b, :n], real_lengths_B[b] = obs_TPHW3, act_TP25, n
    return {"obs": obs_BTPHW3, "act": act_BTP25, "real_lengths": real_lengths_B}


def next_batch(dataset, sampler: _ResumableSampler, batch_size: int, num_frames: int | None = None
               ) -> dict[str, np.ndarray]:
    """Draw and load ``batch_size`` segments; a segment whose episode fails to decode is replaced by the
    next draw (the failure is logged and counted in ``dataset.skipped``). Deterministic given the
    sampler state, so it resumes exactly with the sampler."""
    num_frames = num_frames or sampler.num_frames
    samples = []
    while len(samples) < batch_size:
        segment = sampler.next()
        try:
            samples.append(dataset.load(segment, num_frames))
        except EpisodeError:
            continue
    return make_batch(samples, num_frames)


# ---------------------------------------------------------------------------------------------
# Latent cache
# ---------------------------------------------------------------------------------------------


class LatentCache:
    """Per-video latents on disk, computed once by a frozen encoder.

    One safetensors file per video and encoder, ``{stem}.{sha1(fingerprint)[:12]}.safetensors``, whose
    metadata records the source's size and mtime (ns), the fingerprint and the frame size. A lookup is
    a hit only if all of them match; otherwise the video is decoded, ``encode_fn(frames_THW3 uint8)``
    is called and the result replaces the file (written to a temporary name, then ``os.replace``d, so
    readers never see a partial file).

    Args:
        cache_dir: directory for the cache files (created).
        fingerprint: identifies the encoder (e.g. preset name + a hash of its weights); a new
            fingerprint never reuses another's latents.

    Attributes:
        stats: counts of "hits", "misses" (no file) and "stale" (file for another source version).
    """

    def __init__(self, cache_dir: str | Path, fingerprint: str) -> None:
        self.dir = Path(cache_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.fingerprint = str(fingerprint)
        self._tag = hashlib.sha1(self.fingerprint.encode()).hexdigest()[:12]
        self.stats: Counter[str] = Counter()
        self._stats_lock = threading.Lock()  # LatentClips.build looks videos up from several threads

    def _count(self, outcome: str) -> None:
        with self._stats_lock:
            self.stats[outcome] += 1

    def path_for(self, video: str | Path) -> Path:
        stem = Path(video).name.removesuffix(".mp4")
        return self.dir / f"{stem}.{self._tag}.safetensors"

    def _key(self, video: Path, size: tuple[int, int] | None) -> dict[str, str]:
        st = video.stat()
        return {"source": video.name, "source_size": str(st.st_size), "source_mtime_ns": str(st.st_mtime_ns),
                "fingerprint": self.fingerprint, "frame_size": "native" if size is None else f"{size[0]}x{size[1]}"}

    def get(self, video: str | Path, obs_size: tuple[int, int] | None = None) -> np.ndarray | None:
        """Cached latents of ``video`` at ``obs_size``, or None (miss or stale)."""
        from safetensors import safe_open

        video, path = Path(video), self.path_for(video)
        if not path.is_file():
            self._count("misses")
            return None
        try:
            with safe_open(str(path), framework="numpy") as f:
                if f.metadata() != self._key(video, obs_size):
                    self._count("stale")
                    return None
                latents = f.get_tensor("latents")
        except Exception as err:  # noqa: BLE001 - an unreadable cache file is a miss, never a crash
            logger.warning("latent cache: unreadable %s (%s); re-encoding", path.name, err)
            self._count("stale")
            return None
        self._count("hits")
        return latents

    def get_or_encode(self, video: str | Path, encode_fn: Callable[[np.ndarray], Any],
                      obs_size: tuple[int, int] | None = None) -> np.ndarray:
        """Cached latents, or decode every frame (resized to obs_size), encode, store and return them."""
        latents = self.get(video, obs_size)
        if latents is not None:
            return latents
        video = Path(video)
        key = self._key(video, obs_size)  # before decoding: a file changed meanwhile reads as stale next time
        latents = np.ascontiguousarray(np.asarray(encode_fn(read_frames(video, 0, None, obs_size))))
        self._write(self.path_for(video), latents, key)
        return latents

    def _write(self, path: Path, latents: np.ndarray, key: dict[str, str]) -> None:
        from safetensors.numpy import save

        tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
        try:
            tmp.write_bytes(save({"latents": latents}, metadata=key))
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
