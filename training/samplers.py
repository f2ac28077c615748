"""Segments and batches of the training data (docs/data-format.md §7.4-§7.7): the seeded, resumable segment
samplers of the Duet and VPT datasets, the fixed eval segments, and batching.

Determinism and resume: the samplers draw segment ``i`` of a run with
``np.random.default_rng([seed, rank, i])``, so the stream depends only on (seed, rank, step);
``state_dict()`` / ``load_state_dict()`` save and restore the step, and a resumed run draws exactly
the segments the uninterrupted run would have drawn. (The reference's multiplayer sampler ignores the
configured seed and replays its stream on resume, docs/data-format.md §7.5; ours does neither.)

Shapes: a segment is ``obs_TPHW3`` uint8 and ``act_TP25`` float32 (P=2 for Duet, P=1 for VPT);
:func:`make_batch` stacks and right-pads them to ``obs_BTPHW3`` / ``act_BTP25`` plus ``real_lengths_B``.
"""

from __future__ import annotations

import json
import logging
import os
from collections import Counter
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from solaris_env.spaces import MODEL_ACTION_DIM
from training.duet import DuetDataset
from training.episodes import TOO_SHORT, EpisodeError, SegmentMP, SegmentSP
from training.vpt import VPTDataset

logger = logging.getLogger(__name__)

# Segments of a batch load on this many threads (``next_batch``): decoding and resizing release the GIL, and a
# GPU step is faster than one thread decodes its batch (docs/data-format.md §7.7).
LOAD_THREADS = max(1, min(8, os.cpu_count() or 1))
_load_pool: ThreadPoolExecutor | None = None


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

    @property
    def candidates(self) -> tuple[int, ...]:
        """The episode ids this sampler draws from."""
        return tuple(self._candidates)

    def next(self, among: Sequence[int] | None = None):
        """The next segment; draws whose episode has since been marked invalid are passed over. ``among``
        (non-empty, a subset of ``candidates``): draw the episode from these instead, e.g. the episodes whose
        latents are ready (``training.latents.LatentClips.next_batch``); the same random stream per step."""
        pool = self._candidates if among is None else among
        while True:
            rng = np.random.default_rng([self.seed, self.rank, self.step])
            self.step += 1
            episode_id = pool[int(rng.integers(len(pool)))]
            if self.dataset.is_valid(episode_id):
                return self._draw(rng, episode_id)
            if not any(self.dataset.is_valid(i) for i in pool):
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
    global _load_pool
    num_frames = num_frames or sampler.num_frames
    if _load_pool is None and LOAD_THREADS > 1:
        _load_pool = ThreadPoolExecutor(LOAD_THREADS, thread_name_prefix="segment-loader")
    return make_batch(draw_loaded(sampler, lambda seg: dataset.load(seg, num_frames), batch_size, _load_pool),
                      num_frames)


def draw_loaded(sampler, load, batch_size: int, pool: ThreadPoolExecutor | None = None,
                among: Sequence[int] | None = None) -> list:
    """``batch_size`` results of ``load(sampler.next(among))``, drawing again when an episode fails (EpisodeError).

    With ``pool``, the loads of a batch run on its threads; the segments are still drawn one after another
    and kept in draw order. The result is deterministic given the sampler's state either way, and while no
    episode fails it is the one-thread loop's (after a failure, draws already made may still pick the episode
    that failed: they are replaced in turn)."""

    def attempt(segment):
        try:
            return True, load(segment)
        except EpisodeError:
            return False, None

    out = []
    while len(out) < batch_size:
        segments = [sampler.next(among) for _ in range(batch_size - len(out))]
        results = pool.map(attempt, segments) if pool is not None else map(attempt, segments)
        out += [result for ok, result in results if ok]
    return out

