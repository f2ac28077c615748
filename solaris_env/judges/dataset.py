"""Training examples of the probes: engine frames with their ground-truth labels.

Every ``frame_stride``-th frame of each bot's video goes into one shared :class:`FrameBank`
(uint8, ``image_size`` square). Each question gets an :class:`Examples` table: for every example the
bank indices of its frames (in the order the probe sees them) and the label index. Labels come from
:mod:`labels`; ambiguous ones (None) are left out.

Which frames feed which question:
- ``visible``, ``position``, ``structure``: every kept frame of every bot.
- ``motion``: a kept frame and one ``pair_gap`` frames later of the same bot; with ``still_pair_prob`` also the
  frame with itself (labelled like any pair: "no motion" when the partner shows), because an agent that stands
  still, or a frozen dream, shows the probe two identical frames.
- ``same_scenery``: normal-world episodes only (on a superflat world every view shows the same
  sky and grass, so the question has no visual answer): a kept frame of one bot with the other bot's
  frame at the same tick (half of the pairs, as the eval query) or ``pair_gap`` away, or with the
  same bot's frame ``pair_gap`` away; the two views in random order. Plus ``cross_episode_pairs``
  "no" pairs of two frames from two different normal-world episodes (different world seeds: never the
  same scenery).

Plus, for every question, ``featureless_fraction`` extra examples whose frames carry nothing to see
(:func:`featureless`: one flat colour, horizontal or vertical stripes of the row or column means, a blur of
sigma 4-8 pixels), the way a world model's frames fail. Their answer is the one a frame without content
earns (:data:`FEATURELESS_ANSWER`): no player, no structure, no motion, not the same scenery. Without them a
probe's answer on such frames is whatever its training data never told it (the structure probe said "yes"
on all 40 flat frames tested). They are marked ``episode_N == -1`` and scored apart (``train.frame_accuracy``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from solaris_env.judges import labels as L
from solaris_env.judges import questions
from solaris_env.judges.config import JudgeConfig
from solaris_env.judges.episodes import Episode, read_video


@dataclass
class FrameBank:
    """frames_NHW3: uint8 (N, S, S, 3); ``where[i]`` = (episode index, bot, frame) of bank row i, or
    (-1, "featureless", -1) for a made-up featureless frame."""

    frames_NHW3: np.ndarray
    where: list[tuple[int, str, int]]


@dataclass
class Examples:
    """One question's examples: index_NF (N, F) bank rows, label_N (N,) answer index, episode_N (N,) (-1 for a
    featureless example)."""

    question: str
    index_NF: np.ndarray
    label_N: np.ndarray
    episode_N: np.ndarray

    def __len__(self) -> int:
        return len(self.label_N)

    def class_counts(self) -> dict[str, int]:
        q = questions.get(self.question)
        return {a: int((self.label_N == i).sum()) for i, a in enumerate(q.answers)}


FEATURELESS_KINDS = ("flat", "rows", "columns", "blur")
FEATURELESS_BLUR_SIGMA = (4.0, 8.0)  # pixels at 64 x 64 (scaled with the frame size)
# The answer of a query whose frames are all featureless; same_scenery also when only one of the two is.
FEATURELESS_ANSWER = {"visible": "no", "position": "no player", "structure": "no", "motion": "no motion",
                      "same_scenery": "no"}


def featureless(frame_HW3: np.ndarray, kind: str, rng: np.random.Generator) -> np.ndarray:
    """``frame_HW3`` (uint8) with its content removed: ``flat`` (the mean colour), ``rows`` / ``columns``
    (each row / column its mean: horizontal / vertical stripes), ``blur`` (Gaussian, sigma drawn from
    ``FEATURELESS_BLUR_SIGMA`` per 64 pixels). The colours stay the frame's, so colour alone tells nothing."""
    x = frame_HW3.astype(np.float32)
    if kind == "flat":
        y = np.broadcast_to(x.mean((0, 1)), x.shape)
    elif kind == "rows":
        y = np.broadcast_to(x.mean(1, keepdims=True), x.shape)
    elif kind == "columns":
        y = np.broadcast_to(x.mean(0, keepdims=True), x.shape)
    elif kind == "blur":
        sigma = rng.uniform(*FEATURELESS_BLUR_SIGMA) * x.shape[0] / 64
        y = cv2.GaussianBlur(x, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    else:
        raise ValueError(f"kind must be one of {FEATURELESS_KINDS}, got {kind!r}")
    return np.clip(np.rint(y), 0, 255).astype(np.uint8)


def _featureless_rows(question: str, rows: list[tuple[list[int], int, int]], frames_NHW3: np.ndarray,
                      bank_size: int, fraction: float, rng: np.random.Generator) -> tuple[list, list]:
    """``round(fraction * len(rows))`` featureless examples of one question built from random real examples:
    (new example rows (bank rows, label, -1), the new frames, appended after bank row ``bank_size - 1``)."""
    q = questions.get(question)
    n = round(fraction * len(rows))
    if n == 0:
        return [], []
    label = q.index(FEATURELESS_ANSWER[question])
    new_rows, new_frames = [], []
    for k in rng.choice(len(rows), n):
        views = list(rows[int(k)][0])
        # same_scenery: one view (either) or both made featureless; every other question: all views
        which = range(len(views))
        if question == "same_scenery" and rng.random() < 2 / 3:
            which = [int(rng.integers(len(views)))]
        for i in which:
            kind = FEATURELESS_KINDS[int(rng.integers(len(FEATURELESS_KINDS)))]
            new_frames.append(featureless(frames_NHW3[views[i]], kind, rng))
            views[i] = bank_size + len(new_frames) - 1
        new_rows.append((views, label, -1))
    return new_rows, new_frames


def _pair_frame(rng: np.random.Generator, f: int, T: int, stride: int, gap: tuple[int, int]) -> int | None:
    """A kept frame ``gap`` (rounded down to the stride) after ``f``; None past the end."""
    g = int(rng.integers(gap[0], gap[1] + 1)) // stride * stride
    f2 = f + max(g, stride)
    return f2 if f2 < T else None


def episode_examples(ep: Episode, num_frames: int, cfg: JudgeConfig, rng: np.random.Generator,
                     wanted: Sequence[str]) -> dict[str, list[tuple[tuple[tuple[str, int], ...], str]]]:
    """Labelled examples of one episode: question -> [(((bot, frame), ...), answer)], frames on the
    stride grid ``range(0, num_frames, frame_stride)``. Pure given ``rng``; reads only ``ep.gt``."""
    gt, tc, lc = ep.gt, cfg.train, cfg.labels
    kept = range(0, num_frames, tc.frame_stride)
    bots = ep.players
    out: dict[str, list] = {q: [] for q in wanted}

    def add(q, views, label):
        if label is not None:
            out[q].append((tuple(views), label))

    for bot in bots:
        for f in kept:
            if "visible" in out:
                add("visible", [(bot, f)], L.visible_label(gt, bot, f, lc))
            if "position" in out:
                add("position", [(bot, f)], L.position_label(gt, bot, f, lc))
            if "structure" in out:
                add("structure", [(bot, f)], L.structure_label(gt, bot, f, lc))
            for _ in range(tc.pairs_per_frame if "motion" in out else 0):
                f2 = _pair_frame(rng, f, num_frames, tc.frame_stride, tc.pair_gap)
                if f2 is not None:
                    add("motion", [(bot, f), (bot, f2)], L.motion_label(gt, bot, f, f2, lc))
            if "motion" in out and rng.random() < tc.still_pair_prob:
                add("motion", [(bot, f), (bot, f)], L.motion_label(gt, bot, f, f, lc))
    if "same_scenery" in out and gt.get("world_type") == "normal" and len(bots) >= 2:
        for f in kept:
            for _ in range(tc.pairs_per_frame):
                a = bots[int(rng.integers(len(bots)))]
                kind = rng.random()
                if kind < 0.5:  # the eval query: both bots at the same tick
                    b, f2 = next(x for x in bots if x != a), f
                else:
                    b = a if kind < 0.75 else next(x for x in bots if x != a)
                    f2 = _pair_frame(rng, f, num_frames, tc.frame_stride, tc.pair_gap)
                    if f2 is None:
                        continue
                views = [(a, f), (b, f2)]
                if rng.random() < 0.5:
                    views.reverse()
                add("same_scenery", views, L.same_scenery_label(gt, views[0], views[1], lc))
    return out


def build(episodes: Sequence[Episode], cfg: JudgeConfig, seed: int,
          wanted: Sequence[str] | None = None) -> tuple[FrameBank, dict[str, Examples]]:
    """Read the videos and label the frames of ``episodes`` for the ``wanted`` questions (default all)."""
    wanted = list(questions.QUESTIONS) if wanted is None else [questions.get(q).name for q in wanted]
    rng = np.random.default_rng(seed)
    size, stride = cfg.probe.image_size, cfg.train.frame_stride
    chunks, where = [], []
    rows: dict[str, list] = {q: [] for q in wanted}
    for e, ep in enumerate(episodes):
        videos = {bot: read_video(ep.video_path(bot), size) for bot in ep.players}
        T = min(len(v) for v in videos.values())
        if T != ep.gt["num_frames"]:
            raise ValueError(f"{ep.key}: videos have {T} frames, the sidecar {ep.gt['num_frames']}")
        row_of = {}
        for bot, frames in videos.items():
            for f in range(0, T, stride):
                row_of[(bot, f)] = len(where)
                where.append((e, bot, f))
            chunks.append(frames[::stride])
        for q, items in episode_examples(ep, T, cfg, rng, wanted).items():
            q_idx = questions.get(q)
            rows[q] += [([row_of[v] for v in views], q_idx.index(label), e) for views, label in items]
    if "same_scenery" in rows:
        rows["same_scenery"] += _cross_episode_pairs(episodes, where, len(rows["same_scenery"]), cfg, rng)
    frames = np.concatenate(chunks) if chunks else np.zeros((0, size, size, 3), np.uint8)
    extra = []
    for q in wanted:
        new_rows, new_frames = _featureless_rows(q, rows[q], frames, len(frames) + len(extra),
                                                 cfg.train.featureless_fraction, rng)
        rows[q] += new_rows
        extra += new_frames
        where += [(-1, "featureless", -1)] * len(new_frames)
    if extra:
        frames = np.concatenate([frames, np.stack(extra)])
    bank = FrameBank(frames, where)
    examples = {}
    for q in wanted:
        F = questions.get(q).num_frames
        r = rows[q]
        examples[q] = Examples(q, np.array([x[0] for x in r], np.int64).reshape(len(r), F),
                               np.array([x[1] for x in r], np.int64), np.array([x[2] for x in r], np.int64))
    return bank, examples


def _cross_episode_pairs(episodes: Sequence[Episode], where: list[tuple[int, str, int]], num_within: int,
                         cfg: JudgeConfig, rng: np.random.Generator) -> list[tuple[list[int], int, int]]:
    """``cross_episode_pairs * num_within`` "no" examples: bank rows of two different normal-world episodes."""
    normal = {e for e, ep in enumerate(episodes) if ep.gt.get("world_type") == "normal"}
    rows_by_ep: dict[int, list[int]] = {}
    for row, (e, _, _) in enumerate(where):
        if e in normal:
            rows_by_ep.setdefault(e, []).append(row)
    eps = sorted(rows_by_ep)
    if len(eps) < 2:
        return []
    no = questions.get("same_scenery").index("no")
    out = []
    for _ in range(int(cfg.train.cross_episode_pairs * num_within)):
        a, b = rng.choice(len(eps), 2, replace=False)
        ra, rb = rows_by_ep[eps[a]], rows_by_ep[eps[b]]
        out.append(([ra[int(rng.integers(len(ra)))], rb[int(rng.integers(len(rb)))]], no, int(eps[a])))
    return out


def balanced_probabilities(label_N: np.ndarray, num_classes: int) -> np.ndarray:
    """Sampling probabilities giving every present class the same total mass."""
    counts = np.bincount(label_N, minlength=num_classes).astype(np.float64)
    present = counts > 0
    if not present.any():
        raise ValueError("no examples to sample from")
    p = np.where(present[label_N], 1.0 / np.maximum(counts[label_N], 1.0), 0.0)
    return p / p.sum()
