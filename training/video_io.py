"""Reading the training videos (docs/data-format.md §7): a video's frame count, frame ranges as RGB uint8
resized with ``cv2.INTER_AREA``, and ``FrameReader``, the datasets' store of decoded videos (an LRU).
Failures raise ``training.episodes.EpisodeError`` (``unreadable_video``, ``decode_error``)."""

from __future__ import annotations

import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np

from training.episodes import DECODE_ERROR, UNREADABLE_VIDEO, EpisodeError

DEFAULT_FRAME_CACHE_MB = 256  # decoded-episode LRU per dataset; 0 decodes only the frames asked for


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
    """Reads frame ranges of videos at one output size, with an LRU of fully decoded videos. Thread-safe: the
    loaders of ``training.samplers.next_batch`` read from several threads (decoding runs outside the lock).

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
        self._lock = threading.Lock()

    def read(self, path: Path, start: int, stop: int) -> np.ndarray:
        """Frames ``[start, stop)`` as (stop - start, H, W, 3) uint8 RGB (read-only when cached)."""
        if self.max_bytes <= 0 or path in self._too_big:
            return read_frames(path, start, stop, self.size)
        with self._lock:
            frames_THW3 = self._cache.get(path)
            if frames_THW3 is not None:
                self._cache.move_to_end(path)
        if frames_THW3 is None:
            frames_THW3 = read_frames(path, 0, None, self.size)
            with self._lock:
                self._put(path, frames_THW3)
        if stop > len(frames_THW3):
            raise EpisodeError(DECODE_ERROR, f"{path.name}: only {len(frames_THW3)} frames decode, need {stop}")
        return frames_THW3[start:stop]

    def _put(self, path: Path, frames_THW3: np.ndarray) -> None:  # under the lock
        if path in self._cache:  # another thread decoded it meanwhile
            return
        if frames_THW3.nbytes > self.max_bytes:
            self._too_big.add(path)  # later reads of it decode just their range
            return
        frames_THW3.flags.writeable = False  # shared by every segment sliced from it
        self._cache[path] = frames_THW3
        self._bytes += frames_THW3.nbytes
        while self._bytes > self.max_bytes:
            _, old = self._cache.popitem(last=False)
            self._bytes -= old.nbytes

