"""``RecordVideo``: an mp4 of every episode of a ParallelEnv, all players side by side.

Every frame of every step is written (the dream env's k frames per step; one per tick in the real env), so
the video plays in real time at the engine's 20 fps. Each episode's file appears atomically when the
episode ends (or the env is closed): ``<folder>/<name_prefix>-episode-<n>.mp4``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from pettingzoo.utils.wrappers import BaseParallelWrapper

from solaris_env.env_common import side_by_side

VIDEO_FPS = 20  # engine ticks per second: every recorded frame is one tick
VIDEO_FOURCC = "mp4v"


class Mp4Writer:
    """Streams RGB frames to ``path`` through a temporary file; ``close`` renames it into place."""

    def __init__(self, path: str | Path, fps: float = VIDEO_FPS):
        self.path, self.fps = Path(path), fps
        self._tmp = self.path.with_name(f".{self.path.stem}.tmp{self.path.suffix}")
        self._writer = None
        self.frames = 0

    def write(self, frame_HW3: np.ndarray) -> None:
        import cv2

        if self._writer is None:
            h, w = frame_HW3.shape[:2]
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*VIDEO_FOURCC), self.fps, (w, h))
            if not self._writer.isOpened():
                raise RuntimeError(f"OpenCV could not open an {VIDEO_FOURCC} writer for {self._tmp} ({w}x{h})")
        self._writer.write(np.ascontiguousarray(frame_HW3[..., ::-1]))  # RGB -> BGR
        self.frames += 1

    def close(self) -> Path | None:
        """Finish the file; returns its path (None if nothing was written)."""
        if self._writer is None:
            return None
        self._writer.release()
        self._writer = None
        os.replace(self._tmp, self.path)
        return self.path


class RecordVideo(BaseParallelWrapper):
    """Args:
        env: a ParallelEnv of ours (it must have ``step_frames()``; wrappers above it are fine).
        folder: where the videos go.
        name_prefix: file name prefix.
        episodes: which episodes to record (0-based indices); None records every one.
    """

    def __init__(self, env: Any, folder: str | Path, name_prefix: str = "rollout", episodes: Any = None):
        super().__init__(env)
        self.folder, self.name_prefix = Path(folder), name_prefix
        self.episodes = None if episodes is None else {int(e) for e in episodes}
        self.episode = -1
        self.paths: list[Path] = []
        self._writer: Mp4Writer | None = None

    def reset(self, seed: int | None = None, options: dict | None = None):
        out = self.env.reset(seed=seed, options=options)  # a reset that raises leaves the episode (and its video) on
        self._finish()
        self.episode += 1
        if self.episodes is None or self.episode in self.episodes:
            self._writer = Mp4Writer(self.folder / f"{self.name_prefix}-episode-{self.episode}.mp4")
            self._write_step()
        return out

    def step(self, actions: dict):
        out = self.env.step(actions)
        self._write_step()
        if not self.env.agents:
            self._finish()
        return out

    def close(self) -> None:
        self._finish()
        self.env.close()

    def _write_step(self) -> None:
        if self._writer is None:
            return
        frames_PkHW3 = self.env.unwrapped.step_frames()
        for t in range(frames_PkHW3.shape[1]):
            self._writer.write(side_by_side(frames_PkHW3[:, t]))

    def _finish(self) -> None:
        if self._writer is not None:
            path = self._writer.close()
            if path is not None:
                self.paths.append(path)
            self._writer = None
