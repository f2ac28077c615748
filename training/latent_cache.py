"""The latent cache's file format (docs/data-format.md §7.7): one safetensors file per video and frozen
encoder, written atomically; ``training.latents`` builds the DiT stages' clips from it."""

from __future__ import annotations

import hashlib
import logging
import os
import secrets
import threading
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from training.video_io import read_frames

logger = logging.getLogger(__name__)


class LatentCache:
    """Per-video tensors on disk (the latents, and what else the clips need), computed once by a frozen encoder.

    One safetensors file per video and encoder, ``{stem}.{sha1(fingerprint)[:12]}.safetensors``, whose
    metadata records the source's size and mtime (ns), the fingerprint, the frame size and the names of the
    tensors. A lookup is a hit only if all of them match; otherwise the video is decoded,
    ``encode_fn(frames_THW3 uint8)`` is called (it returns a dict with exactly those names) and the result
    replaces the file (written to a temporary name, then ``os.replace``d, so readers never see a partial file).

    Args:
        cache_dir: directory for the cache files (created).
        fingerprint: identifies the encoder (e.g. preset name + a hash of its weights); a new
            fingerprint never reuses another's latents.
        tensors: the names ``encode_fn`` returns; a file holding others (an older layout) is stale.

    Attributes:
        stats: counts of "hits", "misses" (no file) and "stale" (file for another source version).
    """

    def __init__(self, cache_dir: str | Path, fingerprint: str, tensors: tuple[str, ...] = ("latents",)) -> None:
        self.dir = Path(cache_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.tensors = tuple(tensors)
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
                "fingerprint": self.fingerprint, "frame_size": "native" if size is None else f"{size[0]}x{size[1]}",
                "tensors": ",".join(self.tensors)}

    def get(self, video: str | Path, obs_size: tuple[int, int] | None = None) -> dict[str, np.ndarray] | None:
        """The cached tensors of ``video`` at ``obs_size`` by name, or None (miss or stale)."""
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
                tensors = {name: f.get_tensor(name) for name in self.tensors}
        except Exception as err:  # noqa: BLE001 - an unreadable cache file is a miss, never a crash
            logger.warning("latent cache: unreadable %s (%s); re-encoding", path.name, err)
            self._count("stale")
            return None
        self._count("hits")
        return tensors

    def get_or_encode(self, video: str | Path, encode_fn: Callable[[np.ndarray], dict[str, Any]],
                      obs_size: tuple[int, int] | None = None) -> dict[str, np.ndarray]:
        """The cached tensors, or decode every frame (resized to obs_size), encode, store and return them."""
        tensors = self.get(video, obs_size)
        if tensors is not None:
            return tensors
        video = Path(video)
        key = self._key(video, obs_size)  # before decoding: a file changed meanwhile reads as stale next time
        encoded = encode_fn(read_frames(video, 0, None, obs_size))
        if sorted(encoded) != sorted(self.tensors):
            raise ValueError(f"latent cache: encode_fn returned tensors {sorted(encoded)}, expected {sorted(self.tensors)}")
        tensors = {name: np.ascontiguousarray(np.asarray(encoded[name])) for name in self.tensors}
        self._write(self.path_for(video), tensors, key)
        return tensors

    def _write(self, path: Path, tensors: dict[str, np.ndarray], key: dict[str, str]) -> None:
        from safetensors.numpy import save

        tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
        try:
            tmp.write_bytes(save(tensors, metadata=key))
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
