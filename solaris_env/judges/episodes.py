"""Collected episodes as the judges see them: the ground-truth sidecar, the action records, the videos.

Finds every ``*_groundtruth.json`` under a ``solaris-engine collect`` output (the eval layout
``eval/<Type>/test/<ep>_instance_<iii>_groundtruth.json`` and the training layout
``duet/<split>/batch_<b>_<ep>_instance_<iii>_groundtruth.json``, docs/data-format.md §2, §5) and pairs it
with each bot's records (``.json``) and video (``_camera.mp4`` for eval, ``.mp4`` for training).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solaris_env.engine.eval_protocol import EVAL_KEYS, Query, query_frames

SIDECAR_SUFFIX = "_groundtruth.json"


@dataclass(frozen=True)
class Episode:
    """One recorded episode.

    Attributes:
        directory: where its files are.
        stem: the sidecar name without ``_groundtruth.json`` (``000003_instance_001`` or
            ``batch_0_000003_instance_001``).
        gt: the sidecar (``capture.ground_truth`` plus episode facts: ``episode_type``, ``world_type``...).
        records: bot name -> per-tick action records.
    """

    directory: Path
    stem: str
    gt: dict
    records: dict[str, list]

    @property
    def episode_type(self) -> str:
        return self.gt["episode_type"]

    @property
    def is_eval(self) -> bool:
        return self.episode_type in EVAL_KEYS

    @property
    def players(self) -> list[str]:
        return list(self.gt["players"])

    @property
    def key(self) -> str:
        """Unique within a collect: ``<episode type>/<stem>``."""
        return f"{self.episode_type}/{self.stem}"

    def bot_stem(self, bot: str) -> str:
        head, tail = self.stem.rsplit("_instance_", 1)
        return f"{head}_{bot}_instance_{tail}"

    def video_path(self, bot: str) -> Path:
        if bot not in self.gt["players"]:
            raise ValueError(f"{self.key}: bot {bot!r} is not one of {self.players}")
        suffix = "_camera.mp4" if self.is_eval else ".mp4"
        return self.directory / f"{self.bot_stem(bot)}{suffix}"

    def queries(self) -> list[Query]:
        """The judge's queries (docs/engine.md §7.2); empty for training episodes."""
        return query_frames(self.episode_type, self.records) if self.is_eval else []


def load_episode(sidecar: str | Path) -> Episode:
    sidecar = Path(sidecar)
    if not sidecar.name.endswith(SIDECAR_SUFFIX):
        raise ValueError(f"{sidecar}: not a ground-truth sidecar (*{SIDECAR_SUFFIX})")
    gt = json.loads(sidecar.read_text())
    stem = sidecar.name.removesuffix(SIDECAR_SUFFIX)
    ep = Episode(sidecar.parent, stem, gt, {})
    for bot in ep.players:
        path = sidecar.parent / f"{ep.bot_stem(bot)}.json"
        if not path.is_file():
            raise ValueError(f"{sidecar}: records of {bot} missing ({path.name})")
        ep.records[bot] = json.loads(path.read_text())
    return ep


def find_episodes(root: str | Path, episode_types: Iterable[str] | None = None,
                  include_aborted: bool = False) -> list[Episode]:
    """Every episode under ``root`` (sorted by path), optionally only some types; aborted ones are skipped."""
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"data directory {root} does not exist")
    wanted = None if episode_types is None else set(episode_types)
    out = []
    for sidecar in sorted(root.rglob(f"*{SIDECAR_SUFFIX}")):
        if ".staging" in sidecar.parts:
            continue
        ep = load_episode(sidecar)
        if (wanted is None or ep.episode_type in wanted) and (include_aborted or not ep.gt.get("aborted", False)):
            out.append(ep)
    return out


def read_video(path: str | Path, size: int | None = None) -> np.ndarray:
    """All frames of a video as RGB uint8 (T, H, W, 3), resized with INTER_AREA to size x size if given."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise ValueError(f"{path}: OpenCV cannot open it")
    frames = []
    try:
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            frames.append(resize_frame(bgr[..., ::-1], size))
    finally:
        cap.release()
    if not frames:
        raise ValueError(f"{path}: no frame decoded")
    return np.stack(frames)


def resize_frame(rgb_HW3: np.ndarray, size: int | None) -> np.ndarray:
    """RGB uint8 frame -> size x size (INTER_AREA; unchanged when already that size or size is None)."""
    import cv2

    if size is not None and rgb_HW3.shape[:2] != (size, size):
        rgb_HW3 = cv2.resize(np.ascontiguousarray(rgb_HW3), (size, size), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(rgb_HW3)
