"""What the training data's two layouts share (``training.duet``, ``training.vpt``; docs/data-format.md §7):
the episode error and its skip reasons, the segment tuples, the episode table and a segment's length.

Robustness (docs/data-format.md §7.2): every episode is validated when its dataset is built. A corrupt or
missing episode is skipped, logged through :mod:`logging` and counted in ``dataset.skipped`` (reason ->
count); it never raises. Complete-but-corrupt Duet episodes keep their id (marked invalid) so the ids of the
others, which eval id files refer to, do not shift. A decode failure found later (a video that opens but is
cut short) marks the episode invalid the same way; ``training.samplers.next_batch`` then draws another
segment.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Sequence
from typing import NamedTuple

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
NOT_READY = "not_ready"  # training.latents: the video's latents are still being encoded (drawn again, not a skip)


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


def segment_length(num_frames: int, starts: Sequence[int], num_records: Sequence[int]) -> int:
    """Frames a segment can hold: min(num_frames, n - 1 - start) over players (frames end at start+T)."""
    if num_frames < 1:
        raise ValueError(f"num_frames must be >= 1, got {num_frames}")
    for start, n in zip(starts, num_records):
        if not 0 <= start < n - 1:
            raise ValueError(f"segment start {start} outside [0, {n - 1}) for a recording of {n} records")
    return min(num_frames, *(n - 1 - s for s, n in zip(starts, num_records)))


class EpisodeTable:
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

    def _entry(self, episode_id: int, name: Callable[[], str]):
        """The table's entry of ``episode_id``: IndexError outside the table, EpisodeError for an invalid episode
        (``name()`` names it in the message)."""
        if not 0 <= episode_id < self.num_episodes:
            raise IndexError(f"episode id {episode_id} outside [0, {self.num_episodes})")
        episode = self._episodes[episode_id]
        if episode is None:
            raise EpisodeError(INVALID_EPISODE, f"{name()} was skipped")
        return episode

    def _init_skips(self) -> None:
        self.skipped: Counter[str] = Counter()

    def _skip(self, what: str, err: EpisodeError) -> None:
        self.skipped[err.reason] += 1
        logger.warning("skipping %s: %s", what, err)

