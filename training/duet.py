"""The Duet (multiplayer) dataset layout (docs/data-format.md §2, §5, §7.1-§7.4).

* **Layout** ``{data_dir}/{name}/{split}/`` with ``name="duet"`` (training) or e.g.
  ``name="eval/rotationEval"``, ``split="test"`` (eval sets). Every ``*_Alpha_*.mp4`` (sorted by file
  name) whose Bravo twin (first ``_Alpha_`` -> ``_Bravo_``) and both action JSONs (same stem, a trailing
  ``_camera`` stripped) exist gets the next episode id 0, 1, 2, ...; eval ids refer to these ids.
  Player 0 is ``bot1`` (Alpha), player 1 is ``bot2`` (Bravo).
* **Validation**: readable mp4, JSON list of records with ``action`` dicts, frame count == record count,
  strictly increasing ``renderTime``; a bad episode is skipped (``training.episodes``).
* **Alignment**: a segment starting at record ``s`` holds actions ``[s, s+T)`` and frames
  ``[s+1, s+T+1)``: model frame k is the observation *after* action k (frame t of a recording shows the
  state before action t). The two bots are aligned by ``renderTime``, not by index
  (``training.samplers.MultiplayerSegmentSampler``).
* **Actions**: ``mineflayer_records_to_vectors``, then ``camera_linear`` on dims 23/24.

Segments are ``obs_TPHW3`` uint8 and ``act_TP25`` float32 with P = 2.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solaris_env.spaces import camera_linear, mineflayer_records_to_vectors
from training.episodes import (
    BAD_JSON,
    BAD_RENDER_TIME,
    COUNT_MISMATCH,
    MISSING_FILE,
    EpisodeError,
    EpisodeTable,
    SegmentMP,
    segment_length,
)
from training.video_io import DEFAULT_FRAME_CACHE_MB, FrameReader, probe_video

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class BotRecording:
    """One bot's validated recording: files, per-record renderTime (ms) and model action vectors."""

    video: Path
    actions: Path
    times_T: np.ndarray  # (T,) float64 renderTime, strictly increasing
    act_T25: np.ndarray  # (T, 25) float32, camera_linear applied
    pose_T5: np.ndarray | None = None  # (T, 5) float32 [x, y, z, yaw, pitch] per record; None if not recorded

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


# A validated recording's arrays, kept beside the data: every stage of a sprint, every rescan of its growing data
# and every later process (a `solaris-train` stage, the second call of a GPU session) indexes the same finished
# episodes again, at ~50 ms each (mostly the JSON). ``<split>/.index/<video name>.npz``, docs/data-format.md §7.2.
INDEX_DIR = ".index"


def load_bot_recording(video: Path, actions: Path) -> BotRecording:
    """Validate one bot's mp4 + action JSON and convert its actions; raises EpisodeError. A pair of files
    validated before, unchanged since (names, sizes and mtimes), is read from its sidecar file, which the first
    validation writes (where the directory is writable)."""
    try:
        key = repr(tuple((p.name, st.st_size, st.st_mtime_ns) for p, st in ((p, p.stat()) for p in (video, actions))))
    except OSError:
        return _validated_recording(video, actions)  # it names the missing file
    sidecar = video.parent / INDEX_DIR / f"{video.name}.npz"
    recording = _from_sidecar(sidecar, key, video, actions)
    if recording is None:
        recording = _validated_recording(video, actions)
        _write_sidecar(sidecar, key, recording)
    return recording


def _from_sidecar(path: Path, key: str, video: Path, actions: Path) -> BotRecording | None:
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) != key:
                return None  # written for another version of the files
            pose = z["pose_T5"] if "pose_T5" in z.files else None
            if "pose_T5" not in z.files and "no_pose" not in z.files:
                return None  # written before the poses were kept
            return BotRecording(video, actions, z["times_T"], z["act_T25"], pose)
    except (OSError, KeyError, ValueError):  # none yet, or unreadable: validate again
        return None


def _write_sidecar(path: Path, key: str, recording: BotRecording) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        path.parent.mkdir(exist_ok=True)
        with open(tmp, "wb") as f:
            poses = {"no_pose": np.zeros(0)} if recording.pose_T5 is None else {"pose_T5": recording.pose_T5}
            np.savez(f, key=np.array(key), times_T=recording.times_T, act_T25=recording.act_T25, **poses)
        os.replace(tmp, path)
    except OSError as err:  # a read-only dataset: validate in every process
        logger.debug("episode index: no sidecar for %s (%s)", recording.video.name, err)
    finally:
        tmp.unlink(missing_ok=True)


def _validated_recording(video: Path, actions: Path) -> BotRecording:
    n_frames = probe_video(video)
    records = _read_records(actions)
    try:
        act_T25 = camera_linear(mineflayer_records_to_vectors(records))
    except ValueError as err:
        raise EpisodeError(BAD_JSON, f"{actions.name}: {err}") from None
    times_T = _render_times(records, actions)
    if n_frames != len(records):
        raise EpisodeError(COUNT_MISMATCH, f"{video.name}: {n_frames} frames for {len(records)} records")
    return BotRecording(video, actions, times_T, act_T25, record_poses(records))


def record_poses(records: list) -> np.ndarray | None:
    """(T, 5) float32 [x, y, z, yaw, pitch] of every record (feet in blocks; Mineflayer radians), or None when the
    records carry no pose (the partner map, ``DiTConfig.partner_map``, then cannot be trained on them)."""
    try:
        pose = np.array([[float(r[k]) for k in ("x", "y", "z", "yaw", "pitch")] for r in records], np.float32)
    except (KeyError, TypeError, ValueError):
        return None
    return pose if np.all(np.isfinite(pose)) else None

class DuetDataset(EpisodeTable):
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
        return self._entry(episode_id, lambda: f"episode {episode_id} ({self.stems[episode_id]})")

    def render_times(self, episode_id: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-record renderTime (ms, float64) of both bots."""
        rec1, rec2 = self.recordings(episode_id)
        return rec1.times_T, rec2.times_T

    # -- segments ---------------------------------------------------------------------------

    def segment(self, episode_id: int, start1: int, start2: int, num_frames: int) -> tuple[np.ndarray, np.ndarray]:
        """Aligned frames and actions of both bots.

        Returns ``obs_TPHW3`` uint8 = frames ``[start_p + 1, start_p + T + 1)`` and ``act_TP25`` float32 =
        records ``[start_p, start_p + T)`` of each bot p, with T = num_frames, or fewer when a recording
        ends first (pad with ``training.samplers.make_batch``). Raises ValueError for a start outside the
        recording and EpisodeError for a skipped episode or a frame that does not decode (the episode is
        then marked invalid and counted as DECODE_ERROR).
        """
        recs = self.recordings(episode_id)
        starts = (start1, start2)
        T = segment_length(num_frames, starts, [r.num_records for r in recs])
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

