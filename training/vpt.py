"""The VPT (single-player) dataset layout (docs/data-format.md §6, §7.3): the VPT export of the Duet data
(``solaris_env.engine.vpt_export``) or the reference's VPT index, segments with a player axis of 1 (single
player is multiplayer with one player).

* **Actions**: VPT JSONL -> ``vpt_jsonl_to_vectors`` (stateful, so whole episodes are converted once and
  sliced), then ``camera_linear`` on dims 23/24.
* **Camera sign** (a decision, docs/data-format.md §7.3): VPT's +dx is a turn to the right and +dy a look
  down, Mineflayer's +yaw turns left and +pitch looks up. The reference feeds both into the model
  unreconciled. :class:`VPTDataset` flips dims 23/24 of VPT actions by default so that one action vector
  means one motion in both datasets (the stage-1 weights then agree with stages 2-4);
  ``reference_camera_sign=True`` keeps the reference's unflipped VPT camera.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solaris_env.spaces import (
    CAMERA_X_INDEX,
    CAMERA_Y_INDEX,
    camera_linear,
    vpt_jsonl_to_vectors,
)
from training.episodes import (
    BAD_JSON,
    COUNT_MISMATCH,
    MISSING_FILE,
    EpisodeError,
    EpisodeTable,
    SegmentSP,
    segment_length,
)
from training.video_io import DEFAULT_FRAME_CACHE_MB, FrameReader, probe_video

logger = logging.getLogger(__name__)


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


class VPTDataset(EpisodeTable):
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
        return self._entry(episode_id, lambda: f"vpt episode {episode_id}")

    def segment(self, episode_id: int, start: int, num_frames: int) -> tuple[np.ndarray, np.ndarray]:
        """``obs_T1HW3`` = frames ``[start+1, start+T+1)``, ``act_T125`` = ticks ``[start, start+T)``.

        T = num_frames, or fewer at the end of the episode. Errors as ``training.duet.DuetDataset.segment``.
        """
        episode = self.episode(episode_id)
        T = segment_length(num_frames, (start,), (episode.length,))
        try:
            obs_THW3 = self.frames.read(episode.video, start + 1, start + T + 1)
        except EpisodeError as err:
            self._episodes[episode_id] = None
            self._skip(f"vpt episode {episode_id}", err)
            raise
        return obs_THW3[:, None].copy(), episode.act_T25[start : start + T, None].copy()

    def load(self, segment: SegmentSP, num_frames: int) -> tuple[np.ndarray, np.ndarray]:
        return self.segment(segment.episode_id, segment.start, num_frames)

