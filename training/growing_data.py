"""Training data that grows while a stage trains (``solaris-train sprint``, docs/training.md "GPU sprint"): the
Duet episodes the background collect finishes join the samplers as the stage goes. ``train.duet_stream`` /
``vpt_stream`` with the stage-config key ``rescan_s`` read the training split through ``growing_stream``: every
``rescan_s`` seconds the episodes completed since (at most ``RESCAN_MAX_NEW`` at a time) join the sampler; the
single-player stage reads each bot's view of the Duet episodes (``DuetPlayers``) instead of a VPT export.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from training.duet import DuetDataset
from training.samplers import MultiplayerSegmentSampler, SinglePlayerSegmentSampler
from training.vpt import VPTEpisode

logger = logging.getLogger(__name__)

RESCAN_MAX_NEW = 64  # episodes a rescan adds at most (each is validated, then encoded when first drawn)


def _complete(alpha_mp4: Path) -> bool:
    """All of an episode's files moved in: the recorder moves both bots' ``_episode_info.json`` last."""
    bravo_mp4 = alpha_mp4.with_name(alpha_mp4.name.replace("_Alpha_", "_Bravo_", 1))
    return all(p.with_name(p.name.removesuffix(".mp4") + "_episode_info.json").is_file()
               for p in (alpha_mp4, bravo_mp4))


class GrowingDuetDataset(DuetDataset):
    """A ``DuetDataset`` that ``rescan()``s its directory for episodes finished since. New episodes get the
    next ids (ids follow arrival, not file names: fine for training, not for eval-id files). ``history``:
    (epoch seconds, episodes, frames) at the start and after every rescan that added some."""

    def __init__(self, *args, **kw) -> None:
        super().__init__(*args, **kw)
        self.history = [self._stats()]

    def _add_episode(self, alpha_mp4: Path) -> None:
        if _complete(alpha_mp4):  # one still being moved in is picked up by a later rescan
            super()._add_episode(alpha_mp4)

    def rescan(self, max_new: int = RESCAN_MAX_NEW) -> list[int]:
        """Add up to ``max_new`` episodes finished since; returns the new valid ids."""
        known = set(self.stems)
        fresh = [p for p in sorted(self.directory.glob(f"*_{self.bots[0]}_*.mp4"), key=lambda p: p.name)
                 if p.name.removesuffix(".mp4") not in known and _complete(p)][:max_new]
        first = self.num_episodes
        for alpha_mp4 in fresh:
            self._add_episode(alpha_mp4)
        new = [i for i in range(first, self.num_episodes) if self.is_valid(i)]
        if fresh:
            self.history.append(self._stats())
            logger.info("%s/%s: %d new episodes, %d in all", self.name, self.split, len(new), self.num_episodes)
        return new

    def _stats(self) -> tuple[float, int, int]:
        frames = sum(rec.num_records for i in self.valid_ids for rec in self.recordings(i))
        return time.time(), len(self.valid_ids), frames


class DuetPlayers:
    """Each bot's view of a (growing) Duet dataset as single-player episodes, the ``VPTDataset`` interface
    ``SinglePlayerSegmentSampler`` and ``LatentClips`` read: episode ``2 i + p`` is player p of Duet episode
    i, its actions the Duet ones (what the VPT export's round trip gives back, ``engine.vpt_export``)."""

    def __init__(self, duet) -> None:
        self.duet, self.frames, self.name, self.split = duet, duet.frames, "duet-players", duet.split

    @property
    def skipped(self):
        return self.duet.skipped

    @property
    def num_episodes(self) -> int:
        return 2 * self.duet.num_episodes

    @property
    def valid_ids(self) -> list[int]:
        return [2 * i + p for i in self.duet.valid_ids for p in (0, 1)]

    def is_valid(self, episode_id: int) -> bool:
        return self.duet.is_valid(episode_id // 2)

    def episode(self, episode_id: int) -> VPTEpisode:
        rec = self.duet.recordings(episode_id // 2)[episode_id % 2]
        return VPTEpisode(rec.video, rec.actions, rec.act_T25)

    def rescan(self, max_new: int = RESCAN_MAX_NEW) -> list[int]:
        return [2 * i + p for i in self.duet.rescan(max_new) for p in (0, 1)]


class _Rescanning:
    """A sampler whose ``next()`` first rescans its dataset every ``rescan_s`` seconds, the new episodes
    joining the candidates (``add_episode``)."""

    def __init__(self, dataset, num_frames: int, seed: int, rescan_s: float, **ranks) -> None:
        super().__init__(dataset, num_frames, seed=seed, **ranks)
        self.rescan_s = float(rescan_s)
        self._next_scan = time.monotonic() + self.rescan_s

    def next(self, among=None):
        if time.monotonic() >= self._next_scan:
            for episode_id in self.dataset.rescan():
                self.add_episode(episode_id)
            self._next_scan = time.monotonic() + self.rescan_s
        return super().next(among)


class RescanningMultiplayerSampler(_Rescanning, MultiplayerSegmentSampler):
    """``MultiplayerSegmentSampler`` over a ``GrowingDuetDataset``."""


class RescanningSinglePlayerSampler(_Rescanning, SinglePlayerSegmentSampler):
    """``SinglePlayerSegmentSampler`` over ``DuetPlayers``."""


STREAMS: list = []  # the growing streams' (Duet dataset, sampler) in creation order: the sprint's data record


def growing_stream(data_dir: Path, cfg, num_frames: int, seed: int, rescan_s: float, single_player: bool,
                   rank: int = 0, num_ranks: int = 1):
    """(dataset, sampler) over ``data_dir/duet/train`` that picks up new episodes every ``rescan_s`` s:
    Duet segments, or with ``single_player`` each bot's view (``DuetPlayers``). Registered in ``STREAMS``."""
    duet = GrowingDuetDataset(data_dir, "train", obs_size=(cfg.frame_height, cfg.frame_width), frame_cache_mb=4096)
    dataset = DuetPlayers(duet) if single_player else duet
    sampler_cls = RescanningSinglePlayerSampler if single_player else RescanningMultiplayerSampler
    sampler = sampler_cls(dataset, num_frames, seed, rescan_s, rank=rank, num_ranks=num_ranks)
    STREAMS.append((duet, sampler))
    return dataset, sampler


def data_record(streams: list) -> dict:
    """What a stage's training streams saw: episodes and frames when the stage started and at its end,
    the segments drawn and the rescans that added episodes."""
    if not streams:
        return {}
    duet = streams[0][0]
    (_, ep0, fr0), (_, ep1, fr1) = duet.history[0], duet.history[-1]
    return {"episodes_at_start": ep0, "frames_at_start": fr0, "episodes_at_end": ep1, "frames_at_end": fr1,
            "segments_drawn": sum(s.step for _, s in streams), "rescans_with_new_episodes": len(duet.history) - 1}
