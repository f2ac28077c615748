"""The paper's five-task world-model benchmark (Table 3): judge accuracy and a Fréchet distance per task.

    .venv/bin/solaris-engine collect --out data/eval_7001 --eval --episodes 16 --resolution 64 --seed 7001
    .venv/bin/python -m benchmarks.eval_tasks --data data/eval_7001          # ~45 min on 2 CPU cores (3 seeds x 112 episodes)

Data: the 7 eval sets of ``solaris-engine collect --eval`` (docs/engine.md §6), collected at the
model's resolution with a seed no training set used (training data: seeds 0.., held-out: 99; we use
7001). Tasks (docs/engine.md §7.5): Movement = translation + rotation, Grounding = oneLooksAway, Memory =
bothLookAway, Building = structure, Consistency = turnToLook (same) + turnToLookOpposite.

Protocol (docs/engine.md §7.4). Per episode the segment starts at ``s`` = the judge's ``frame1``
(``eval_protocol.eval_ids_row``: sneak_end + 25, both players on the same tick). The model gets each
player's GT frame ``s + 1`` and the recorded actions of ticks ``s .. s + T - 1`` (T = 257 = 1 + 64 model
steps of k = 4; action t pairs with frame t + 1, as in training) and generates T frames per player:
generated frame j shows GT frame ``s + 1 + j``. Every judge query (docs/engine.md §7.2) is then asked about
generated frame ``g - s - 1`` instead of GT frame g (translation's first image, GT frame s, uses
generated frame 0). Episodes are batched as B worlds per model call (the last batch padded by repeating
an episode, whose output is dropped, so the model compiles once).

Rows: ``default`` (the shipped model, or ``--model``), ``ground_truth`` (the judge on the recorded
videos: exactly ``python -m solaris_env.judges.evaluate``), ``copy_first_frame`` (every frame = the GT
frame s + 1 the model is given), and ``concat`` (the Multiverse-style baseline; only with
``--concat-checkpoint``, otherwise listed as "no checkpoint"). Generated rows run one trial per sampling
seed (``--seeds``, default 0 1 2); the judge (the shipped probes) is deterministic, so ground truth and
copy-first-frame have one distinct trial and std 0.

Scores. Episode-level judge accuracy per eval type (all queries of an episode right, docs/engine.md §7.5)
and per task (the mean of its types), mean ± population std over trials. Fréchet distance per task
(and per type): ALL T frames of both players of the task's episodes, generated vs the GT frames they
show (s + 1 .. s + T), in judge features (``solaris_env.judges.features``: the penultimate activations
of the visible / position / structure probes, 192-d) -- an in-domain Fréchet distance, NOT FID: it is
comparable between rows of this table only.

FID (``--inception-weights PATH``, the user's copy of pytorch-fid's ``pt_inception-2015-12-05-6726825d.pth``;
nothing is downloaded): the same frames also get a true FID, in the 2048-d pool3 features of the FID
InceptionV3 (``solaris_env.judges.inception``), stored as ``fid`` next to ``frechet`` in every row and
trial and shown as an extra "FID" column per task. The frames (64 x 64 for the shipped model) are
upsampled bilinearly to 299 x 299, so these FIDs compare with other FIDs only at that resolution and
resizing. Cost: ~6 GFLOP per frame (~230k frames for 112 episodes x 3 seeds: hours on 2 CPU cores).

Writes ``benchmarks/results/eval_tasks.json`` (per trial, per type, per task, timings, machine) and
prints the Markdown table in the layout of the paper's Table 3.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from solaris_env.engine.eval_protocol import EVAL_KEYS, EVAL_NUM_FRAMES, eval_ids_row
from solaris_env.judges import questions
from solaris_env.judges.episodes import Episode, find_episodes, read_video
from solaris_env.judges.features import FrameFeatures, frechet_distance
from solaris_env.judges.scoring import (
    episode_accuracy,
    ground_truth_frames,
    judge_episodes,
    query_views,
    task_accuracy,
)
from solaris_env.spaces import camera_linear, mineflayer_records_to_vectors

RESULTS = Path(__file__).parent / "results" / "eval_tasks.json"
DEFAULT_MODEL = Path(__file__).resolve().parent.parent / "solaris_env" / "assets" / "default"
ROWS = ("default", "concat", "ground_truth", "copy_first_frame")
NO_CHECKPOINT = "no checkpoint"

# ---------------------------------------------------------------------------------------------
# Segments (docs/engine.md §7.4)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Segment:
    """The generated window of one eval episode.

    Attributes:
        episode: the recorded episode.
        start: ``s`` = the judge's frame1; the model gets GT frame s + 1 and the actions of ticks s ...
        num_frames: T generated frames per player; generated frame j shows GT frame s + 1 + j.
    """

    episode: Episode
    start: int
    num_frames: int

    @property
    def players(self) -> list[str]:
        return sorted(self.episode.players)  # Alpha = player 0, Bravo = player 1 (as the training data)

    def generated_index(self, gt_index: int) -> int:
        """Generated frame showing GT frame ``gt_index`` (``g - s - 1``; frame1 itself -> generated frame 0)."""
        j = max(gt_index - self.start - 1, 0)
        if gt_index < self.start or j >= self.num_frames:
            raise ValueError(f"{self.episode.key}: GT frame {gt_index} outside the generated window "
                             f"[{self.start}, {self.start + self.num_frames}]")
        return j

    def actions(self) -> np.ndarray:
        """Model action vectors (T, P, 25) of ticks s .. s + T - 1 (``act[j]`` pairs with generated frame j)."""
        per_bot = [camera_linear(mineflayer_records_to_vectors(self.episode.records[b])) for b in self.players]
        return np.stack([a[self.start:self.start + self.num_frames] for a in per_bot], axis=1).astype(np.float32)

    def start_poses(self) -> np.ndarray:
        """(P, 5) float32 every player's [x, y, z, yaw, pitch] at GT frame s + 1 (record s + 1, as in training):
        where a partner-map model (``DiTConfig.partner_map``) starts dead reckoning."""
        from training.duet import record_poses

        poses = [record_poses(self.episode.records[b][self.start + 1:self.start + 2]) for b in self.players]
        if any(p is None for p in poses):
            raise ValueError(f"{self.episode.key}: its records carry no pose (x, y, z, yaw, pitch), which a "
                             "partner-map model needs; record the eval set again with solaris-engine collect --eval")
        return np.concatenate(poses)

    def ground_truth(self) -> np.ndarray:
        """GT frames s + 1 .. s + T of every player, uint8 (T, P, H, W, 3)."""
        videos = [read_video(self.episode.video_path(b)) for b in self.players]
        return np.stack([v[self.start + 1:self.start + 1 + self.num_frames] for v in videos], axis=1)


def make_segment(ep: Episode, num_frames: int) -> Segment:
    """The episode's window; ValueError if the players start on different ticks, the recording is too
    short, or a query frame falls outside the window."""
    names = sorted(ep.players)
    row = eval_ids_row(0, ep.records[names[0]], ep.records[names[1]], num_frames)
    if row[1] != row[3]:
        raise ValueError(f"{ep.key}: players start on different ticks ({row[1]}, {row[3]})")
    seg = Segment(ep, row[1], num_frames)
    shortest = min(len(r) for r in ep.records.values())
    if seg.start + 1 + num_frames > shortest:
        raise ValueError(f"{ep.key}: {shortest} records, the window needs {seg.start + 1 + num_frames}")
    for q in ep.queries():
        for _, g in query_views(q):
            seg.generated_index(g)
    return seg


def make_segments(episodes: Sequence[Episode], num_frames: int) -> tuple[list[Segment], dict[str, str]]:
    """Segments of the eval episodes that fit; skipped episode key -> reason."""
    segments, skipped = [], {}
    for ep in episodes:
        try:
            segments.append(make_segment(ep, num_frames))
        except ValueError as err:
            skipped[ep.key] = str(err)
    return segments, skipped


# ---------------------------------------------------------------------------------------------
# Frame sources for the judge: ``frames(episode, bot, gt_index) -> HxWx3``
# ---------------------------------------------------------------------------------------------


def copy_first_frame_source(segments: Sequence[Segment]) -> Callable[[Episode, str, int], np.ndarray]:
    """Every frame of the window = GT frame s + 1 (the frame the model starts from)."""
    by_key = {seg.episode.key: seg for seg in segments}
    first: dict[tuple[str, str], np.ndarray] = {}
    for seg in segments:
        for bot in seg.players:
            first[(seg.episode.key, bot)] = read_video(seg.episode.video_path(bot))[seg.start + 1]

    def frames(ep: Episode, bot: str, index: int) -> np.ndarray:
        by_key[ep.key].generated_index(index)  # same window check as generated videos
        return first[(ep.key, bot)]

    return frames


@dataclass
class GeneratedVideos:
    """The query frames of generated videos, keyed (episode key, bot, generated index), and the videos'
    judge features (and FID features, if asked for) per eval type (all frames, both players)."""

    frames: dict[tuple[str, str, int], np.ndarray]
    features: dict[str, list[np.ndarray]]
    seconds: float
    fid_features: dict[str, list[np.ndarray]] = field(default_factory=dict)

    def source(self, segments: Sequence[Segment]) -> Callable[[Episode, str, int], np.ndarray]:
        by_key = {seg.episode.key: seg for seg in segments}

        def frames(ep: Episode, bot: str, index: int) -> np.ndarray:
            return self.frames[(ep.key, bot, by_key[ep.key].generated_index(index))]

        return frames


def query_frames(seg: Segment, video_TPHW3: np.ndarray) -> dict[tuple[str, str, int], np.ndarray]:
    """(episode key, bot, window index) -> the frame of ``video_TPHW3`` (the segment's window, generated or
    reconstructed) that each of the episode's judge queries looks at."""
    kept = {}
    for p, bot in enumerate(seg.players):
        for q in seg.episode.queries():
            for qbot, g in query_views(q):
                if qbot == bot:
                    j = seg.generated_index(g)
                    kept[(seg.episode.key, bot, j)] = video_TPHW3[j, p].copy()
    return kept


def _batches(segments: Sequence[Segment], worlds: int) -> list[list[Segment]]:
    return [list(segments[i:i + worlds]) for i in range(0, len(segments), worlds)]


def generate(model, segments: Sequence[Segment], seed: int, worlds: int,
             features: FrameFeatures | None = None, verbose: bool = False,
             fid_features: Callable[[np.ndarray], np.ndarray] | None = None) -> GeneratedVideos:
    """Roll the model out over every segment (``worlds`` per call) with sampling seed ``seed``.

    Batch i uses ``model.init(..., rng=seed * 1_000_003 + i)``; a padded last batch repeats its last
    segment. Keeps only the query frames and (with ``features`` / ``fid_features``) the judge / FID
    features of every frame.
    """
    from training.samples import rollout

    t0 = time.perf_counter()
    kept: dict[tuple[str, str, int], np.ndarray] = {}
    feats: dict[str, list[np.ndarray]] = defaultdict(list)
    fid_feats: dict[str, list[np.ndarray]] = defaultdict(list)
    batches = _batches(segments, worlds)
    for i, batch in enumerate(batches):
        if verbose:
            print(f"    batch {i + 1}/{len(batches)} at {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        padded = batch + [batch[-1]] * (worlds - len(batch))
        obs_BTPHW3 = np.stack([seg.ground_truth() for seg in padded])
        act_BTP25 = np.stack([seg.actions() for seg in padded])
        poses_BP5 = np.stack([seg.start_poses() for seg in padded]) if model.config.dit.partner_map else None
        gen_BTPHW3 = rollout(model, obs_BTPHW3, act_BTP25, seed * 1_000_003 + i, poses_BP5=poses_BP5)
        for b, seg in enumerate(batch):
            kept.update(query_frames(seg, gen_BTPHW3[b]))
            gen_NHW3 = gen_BTPHW3[b].reshape(-1, *gen_BTPHW3.shape[-3:])  # all T frames of both players
            if features is not None:
                feats[seg.episode.episode_type].append(features(gen_NHW3))
            if fid_features is not None:
                fid_feats[seg.episode.episode_type].append(fid_features(gen_NHW3))
    return GeneratedVideos(kept, dict(feats), time.perf_counter() - t0, dict(fid_feats))


def check_frame_size(model, segments: Sequence[Segment]) -> None:
    """The eval data must be recorded at the model's resolution (collect with --resolution H)."""
    if not segments:
        return
    seg = segments[0]
    h, w, _ = read_video(seg.episode.video_path(seg.players[0]))[0].shape
    if (h, w, 3) != tuple(model.frame_shape):
        raise ValueError(f"eval frames are {h}x{w}, the model makes {model.frame_shape[0]}x{model.frame_shape[1]}: "
                         f"collect the eval sets with --resolution {model.frame_shape[0]}")


# ---------------------------------------------------------------------------------------------
# Scoring
# ---------------------------------------------------------------------------------------------


def score_trial(judge, segments: Sequence[Segment], frames) -> dict:
    """One trial: episode-level accuracy per eval type and per task."""
    per_type = episode_accuracy(judge_episodes(judge, [s.episode for s in segments], frames))
    return {"per_type": per_type, "tasks": task_accuracy(per_type)}


def _mean_std(values: Sequence[float]) -> dict:
    v = np.asarray(values, np.float64)
    # population std (docs/engine.md §7.5)
    return {"mean": float(v.mean()), "std": float(v.std()), "trials": [float(x) for x in v]}


def summarise_trials(trials: Sequence[dict]) -> dict:
    """Mean ± std over trials of the accuracy per eval type and per task."""
    types = sorted({t for tr in trials for t in tr["per_type"]})
    tasks = [t for t in questions.TASKS if all(t in tr["tasks"] for tr in trials)]
    return {"per_type": {t: {**_mean_std([tr["per_type"][t]["accuracy"] for tr in trials]),
                             "episodes": trials[0]["per_type"][t]["episodes"]} for t in types},
            "tasks": {t: _mean_std([tr["tasks"][t] for tr in trials]) for t in tasks}}


def features_by_type(features: Callable[[np.ndarray], np.ndarray], segments: Sequence[Segment], copy_first: bool = False
                     ) -> dict[str, list[np.ndarray]]:
    """Features (judge or FID: ``features(frames_NHW3) -> (N, D)``) of the GT window (or of the first frame
    repeated T times) per eval type."""
    out: dict[str, list[np.ndarray]] = defaultdict(list)
    for seg in segments:
        gt_TPHW3 = seg.ground_truth()
        if copy_first:
            f = features(gt_TPHW3[0])  # (P, D): the frame the model starts from, per player
            out[seg.episode.episode_type].append(np.repeat(f[None], seg.num_frames, axis=0).reshape(-1, f.shape[-1]))
        else:
            out[seg.episode.episode_type].append(features(gt_TPHW3.reshape(-1, *gt_TPHW3.shape[-3:])))
    return dict(out)


def frechet_by_task(real: dict[str, list[np.ndarray]], fake: dict[str, list[np.ndarray]]) -> dict:
    """Fréchet distance per eval type and per task (the task's types' frames pooled)."""
    per_type = {t: frechet_distance(np.concatenate(real[t]), np.concatenate(fake[t])) for t in sorted(real)}
    tasks = {}
    for task, types in questions.TASKS.items():
        present = [t for t in types if t in real]
        if present:
            tasks[task] = frechet_distance(np.concatenate([f for t in present for f in real[t]]),
                                           np.concatenate([f for t in present for f in fake[t]]))
    return {"per_type": per_type, "tasks": tasks}


# ---------------------------------------------------------------------------------------------
# Table (the paper's Table 3 layout)
# ---------------------------------------------------------------------------------------------


def _distance_cell(row: dict, key: str, task: str) -> str:
    d = row.get(key, {}).get("tasks_mean", {}).get(task)
    return "–" if d is None or math.isnan(d) else f"{d:.2f}"


def markdown_table(rows: dict[str, dict]) -> str:
    """Rows = models, columns = the five tasks x (judge accuracy % mean ± std, Fréchet distance, and FID
    if any row has one)."""
    tasks = list(questions.TASKS)
    with_fid = any("fid" in row for row in rows.values())
    per_task = 3 if with_fid else 2
    head = "| model | " + " | ".join(f"{t} judge ↑ | {t} FD ↓" + (f" | {t} FID ↓" if with_fid else "")
                                     for t in tasks) + " |"
    lines = [head, "|---|" + "---:|" * (per_task * len(tasks))]
    for name, row in rows.items():
        if row.get("status") == NO_CHECKPOINT:
            lines.append(f"| {name} | " + " | ".join(([NO_CHECKPOINT] + ["–"] * (per_task - 1)) * len(tasks)) + " |")
            continue
        cells = []
        for t in tasks:
            acc = row["accuracy"]["tasks"].get(t)
            cells.append("–" if acc is None else f"{100 * acc['mean']:.1f} ± {100 * acc['std']:.1f}")
            cells.append(_distance_cell(row, "frechet", t))
            if with_fid:
                cells.append(_distance_cell(row, "fid", t))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def per_type_table(rows: dict[str, dict]) -> str:
    """Rows = models, columns = eval types; cells "episode acc. % (query acc. %)", means over trials."""
    scored = {n: r for n, r in rows.items() if r.get("status") != NO_CHECKPOINT}
    types = [t for t in EVAL_KEYS if any(t in r["accuracy"]["per_type"] for r in scored.values())]
    lines = ["| model | " + " | ".join(types) + " |", "|---|" + "---:|" * len(types)]
    for name, row in scored.items():
        cells = []
        for t in types:
            if t not in row["accuracy"]["per_type"]:
                cells.append("–")
                continue
            query = np.mean([tr["per_type"][t]["query_accuracy"] for tr in row["trials"]])
            cells.append(f"{100 * row['accuracy']['per_type'][t]['mean']:.1f} ({100 * query:.1f})")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# The benchmark
# ---------------------------------------------------------------------------------------------


def _frechet_means(fds: Sequence[dict]) -> dict:
    """Mean over trials of ``frechet_by_task`` results: ``{"tasks_mean": ..., "per_type_mean": ...}``."""
    return {"tasks_mean": {t: float(np.mean([f["tasks"][t] for f in fds])) for t in fds[0]["tasks"]},
            "per_type_mean": {t: float(np.mean([f["per_type"][t] for f in fds])) for t in fds[0]["per_type"]}}


def run_generated_row(model, judge, features, segments, seeds, worlds, real_feats,
                      fid_features=None, real_fid=None) -> dict:
    """Trials of one world model: accuracy per trial, Fréchet distance (and FID, with ``fid_features`` and
    the GT's ``real_fid``) per trial, timings."""
    trials, fds, fids, timing = [], [], [], []
    for seed in seeds:
        videos = generate(model, segments, seed, worlds, features, verbose=True, fid_features=fid_features)
        t0 = time.perf_counter()
        trial = score_trial(judge, segments, videos.source(segments))
        judge_s = time.perf_counter() - t0
        fd = frechet_by_task(real_feats, videos.features)
        trials.append({"seed": seed, **trial, "frechet": fd})
        fds.append(fd)
        if fid_features is not None:
            trials[-1]["fid"] = frechet_by_task(real_fid, videos.fid_features)
            fids.append(trials[-1]["fid"])
        timing.append({"seed": seed, "generate_s": round(videos.seconds, 2), "judge_s": round(judge_s, 2)})
        print(f"  seed {seed}: generated in {videos.seconds:.1f} s; tasks "
              + ", ".join(f"{k} {100 * v:.1f}" for k, v in trial["tasks"].items()), file=sys.stderr)
    row = {"accuracy": summarise_trials(trials), "frechet": _frechet_means(fds)}
    if fids:
        row["fid"] = _frechet_means(fids)
    return {**row, "trials": trials, "timing": timing}


def _fixed_frechet(real: dict[str, list[np.ndarray]], fake: dict[str, list[np.ndarray]] | None, trial: dict) -> dict:
    """Fréchet distances of a deterministic row; ``fake`` None = the GT frames themselves (distance 0)."""
    if fake is None:
        return {"tasks_mean": {t: 0.0 for t in trial["tasks"]}, "per_type_mean": {t: 0.0 for t in trial["per_type"]}}
    fd = frechet_by_task(real, fake)
    return {"tasks_mean": fd["tasks"], "per_type_mean": fd["per_type"]}


def run_fixed_row(judge, segments, frames, real_feats, fake_feats, real_fid=None, fake_fid=None) -> dict:
    """A deterministic row (ground truth, copy-first-frame): one trial, std 0 by construction. With the
    GT's FID features ``real_fid`` the row also gets a FID (``fake_fid`` None, like ``fake_feats``: 0)."""
    trial = score_trial(judge, segments, frames)
    row = {"accuracy": summarise_trials([trial]), "frechet": _fixed_frechet(real_feats, fake_feats, trial)}
    if real_fid is not None:
        row["fid"] = _fixed_frechet(real_fid, fake_fid, trial)
    return {**row, "trials": [trial], "deterministic": "the judge is deterministic: one trial, std 0"}


def run_benchmark(data_dir: str | Path, models: dict[str, object | None], seeds: Sequence[int] = (0, 1, 2),
                  worlds: int = 16, num_frames: int = EVAL_NUM_FRAMES, judge=None, features=None,
                  eval_types: Sequence[str] | None = None,
                  fid_features: Callable[[np.ndarray], np.ndarray] | None = None) -> dict:
    """Score every row on the eval sets under ``data_dir``.

    Args:
        models: row name -> a ``WorldModel`` (or None: listed as "no checkpoint").
        seeds: sampling seeds of the generated rows (one trial each).
        worlds: episodes per model call (B).
        num_frames: generated frames per player (T = 1 + k * steps; 257 as the paper).
        fid_features: ``frames_NHW3 -> (N, D)`` features for a FID of the same frames as the in-domain
            Fréchet distance (an ``InceptionFeatures``), stored as each row's ``fid``; None: no FID.
    Returns:
        ``{"rows": {...}, "table": markdown, "episodes_per_type", "skipped", "timing_s", ...}``.
    """
    from solaris_env.judges.judge import Judge

    t_start = time.perf_counter()
    judge = judge or Judge.load()
    features = features or FrameFeatures.load()
    episodes = [e for e in find_episodes(data_dir, eval_types) if e.is_eval]
    if not episodes:
        raise ValueError(f"no eval episodes under {data_dir}")
    segments, skipped = make_segments(episodes, num_frames)
    if not segments:
        raise ValueError(f"no eval episode of {data_dir} holds a {num_frames}-frame window: {skipped}")
    episodes_per_type = {t: sum(s.episode.episode_type == t for s in segments) for t in EVAL_KEYS
                         if any(s.episode.episode_type == t for s in segments)}

    t0 = time.perf_counter()
    real_feats = features_by_type(features, segments)
    copy_feats = features_by_type(features, segments, copy_first=True)
    timing = {"ground_truth_features_s": round(time.perf_counter() - t0, 2)}
    real_fid = copy_fid = None
    if fid_features is not None:
        t0 = time.perf_counter()
        real_fid = features_by_type(fid_features, segments)
        copy_fid = features_by_type(fid_features, segments, copy_first=True)
        timing["ground_truth_fid_features_s"] = round(time.perf_counter() - t0, 2)
    rows: dict[str, dict] = {}
    for name, model in models.items():
        if model is None:
            rows[name] = {"status": NO_CHECKPOINT}
            continue
        check_frame_size(model, segments)
        print(f"{name}: {len(segments)} episodes x {len(seeds)} seeds", file=sys.stderr)
        rows[name] = run_generated_row(model, judge, features, segments, seeds, worlds, real_feats,
                                       fid_features, real_fid)
    t0 = time.perf_counter()
    rows["ground_truth"] = run_fixed_row(judge, segments, ground_truth_frames(), real_feats, None, real_fid, None)
    rows["copy_first_frame"] = run_fixed_row(judge, segments, copy_first_frame_source(segments), real_feats,
                                             copy_feats, real_fid, copy_fid)
    timing["fixed_rows_s"] = round(time.perf_counter() - t0, 2)
    timing["total_s"] = round(time.perf_counter() - t_start, 2)
    return {"rows": rows, "table": markdown_table(rows), "table_per_type": per_type_table(rows),
            "episodes_per_type": episodes_per_type,
            "skipped": skipped, "num_frames": num_frames, "seeds": list(seeds), "worlds": worlds,
            "timing_s": timing}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m benchmarks.eval_tasks", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="a solaris-engine collect --eval output at the model's resolution")
    p.add_argument("--model", default=str(DEFAULT_MODEL), help="the 'default' row's checkpoint (default: shipped)")
    p.add_argument("--concat-checkpoint", default=None, help="a concat-baseline checkpoint (row omitted otherwise)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="sampling seeds = trials")
    p.add_argument("--worlds", type=int, default=16, help="episodes per model call (B)")
    p.add_argument("--num-frames", type=int, default=EVAL_NUM_FRAMES, help="generated frames per player")
    p.add_argument("--types", nargs="+", default=None, choices=sorted(EVAL_KEYS), help="only these eval types")
    p.add_argument("--data-seed", type=int, default=None, help="the collect --seed of --data (recorded only)")
    p.add_argument("--inception-weights", default=None,
                   help="also report true FID per task: the path of the standard FID InceptionV3 weights "
                        "(pytorch-fid's pt_inception-2015-12-05-6726825d.pth, supplied by you; never downloaded)")
    p.add_argument("--out", default=str(RESULTS))
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    fid_features = None
    if args.inception_weights is not None:  # before the world models: a bad weights file fails fast
        from solaris_env.judges.inception import InceptionFeatures

        fid_features = InceptionFeatures.load(args.inception_weights)
    from benchmarks.machine import machine_info, write_result
    from solaris_env.paths import portable_path
    from solaris_env.world_model.world_model import WorldModel

    load_before = os.getloadavg()
    models = {"default": WorldModel.load(args.model),
              "concat": WorldModel.load(args.concat_checkpoint) if args.concat_checkpoint else None}
    result = run_benchmark(args.data, models, args.seeds, args.worlds, args.num_frames, eval_types=args.types,
                           fid_features=fid_features)
    fid = {"fid": f"FID in the FID InceptionV3's 2048-d pool3 features ({args.inception_weights}) of the same "
                  "frames as frechet, upsampled bilinearly from the model's resolution to 299x299: comparable "
                  "to other FIDs only at that resolution and resizing"} if fid_features is not None else {}
    result = {
        "benchmark": "eval_tasks", "judge": "shipped probes (solaris_env/assets/judges), deterministic",
        "frechet": "in-domain Fréchet distance on judge features (visible/position/structure probe penultimate "
                   "activations, 192-d) over all generated frames of both players vs the GT frames they show; "
                   "NOT FID", **fid,
        "std": "population std over trials (sampling seeds); 0 for the deterministic rows",
        "model": portable_path(args.model, parts=3),
        "concat_checkpoint": args.concat_checkpoint and portable_path(args.concat_checkpoint, parts=3),
        "data": portable_path(args.data),
        "data_seed": args.data_seed, **result, "machine": machine_info(load_before),
    }
    print(result["table"])
    print()
    print(result["table_per_type"])
    write_result(args.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
