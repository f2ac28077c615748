"""Does a model's autoencoder meet the target? PSNR per world surface, and the judges on its reconstructions.

    .venv/bin/solaris-engine collect --out data/heldout64 --episodes 24 --world mixed --resolution 64 \\
        --seed 99 --instances 10 --test-fraction 1 --workers 2
    .venv/bin/solaris-engine collect --out data/eval_7031 --eval --episodes 8 --resolution 64 --seed 7031
    .venv/bin/python -m benchmarks.autoencoder_target --heldout data/heldout64 --eval data/eval_7031 \\
        --model default --model runs/x/vae/model                      # ~7 min per model, 2 CPU cores

A dream can only show what its VAE reconstructs (docs/evaluation.md, "Autoencoder target"). Per model
(``--model``, repeatable: ``default``, a model directory or ``preset:NAME``), through the VAE's posterior mean
(encode, then decode: what a DiT that predicted every latent exactly would show):

1. **PSNR per world surface.** Held-out engine videos (``duet/test`` of a ``--world mixed`` collect with 10
   instances: the five flat surfaces and ``normal`` worlds) are cut into windows of ``--window`` frames
   (1 + k n: a first frame, then whole latent chunks, as the env decodes them), at most ``--windows`` per video,
   and reconstructed. PSNR over all pixels of a surface's frames (the MSE pooled, as the VAE stage reports it).
   Target: >= 28 dB on every surface. Next to it, per surface, the sharpness ratio (mean |Laplacian| of the
   reconstructions over the truth's, ``dream_fidelity``'s sharpness): the ceiling of any dream of this VAE on
   the fidelity benchmark's sharpness target (>= 0.75). No target of its own.
2. **The judges on reconstructed eval episodes.** The eval sets' 257-frame windows (the five-task benchmark's,
   ``benchmarks.eval_tasks``) are reconstructed, and every judge query is asked about the reconstructed frame
   instead of the recorded one. Reported per task and eval type: the episode accuracy on the originals and on
   the reconstructions, and their difference in points; per question, the fraction of queries answered the
   same on both. Target: every task within 3 points of the originals.

Writes ``benchmarks/results/autoencoder_target.json`` and a PNG: per surface two held-out frames, truth over
each model's reconstruction.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results" / "autoencoder_target.json"
TARGET_PSNR_DB = 28.0
TARGET_JUDGE_POINTS = 3.0

# A reconstruction: uint8 (B, T, P, H, W, 3) -> the same shape (``training.samples.vae_reconstructor``).
Reconstruct = Callable[[np.ndarray], np.ndarray]


# ---------------------------------------------------------------------------------------------
# 1. PSNR per surface on held-out videos
# ---------------------------------------------------------------------------------------------


def heldout_windows(data_dir: str | Path, window: int, windows: int, k: int) -> dict[str, np.ndarray]:
    """surface -> uint8 (N, window, 2, H, W, 3): both players' frames of up to ``windows`` consecutive,
    non-overlapping windows of every ``duet/test`` episode (the same every run)."""
    from benchmarks.autoencoder_capacity import test_videos
    from training.video_io import probe_video, read_frames

    if window < 1 or (window - 1) % k:
        raise ValueError(f"window must be 1 + {k} * n frames (a first frame, then whole latent chunks), got {window}")
    test = Path(data_dir) / "duet" / "test"
    out: dict[str, list[np.ndarray]] = defaultdict(list)
    for surface, videos in test_videos(data_dir):
        length = min(min(probe_video(v) for v in videos), window * windows)
        n = length // window
        if n == 0:
            continue
        frames = [read_frames(v, 0, n * window) for v in videos]
        for i in range(n):
            out[surface].append(np.stack([f[i * window:(i + 1) * window] for f in frames], axis=1))
    if not out:
        raise ValueError(f"{test}: no held-out episode with >= {window} frames "
                         "(collect with --test-fraction 1 into this folder)")
    return {s: np.stack(w) for s, w in sorted(out.items())}


def _psnr(sq: float | np.ndarray, count: int | np.ndarray):
    return np.round(10.0 * np.log10(255.0 ** 2 / np.maximum(np.asarray(sq) / count, 1e-12)), 2)


def psnr_by_surface(reconstruct: Reconstruct, windows: dict[str, np.ndarray], k: int, batch: int = 4
                    ) -> tuple[dict[str, float], list[float], dict[str, np.ndarray], dict[str, float]]:
    """PSNR (dB, the MSE pooled over the pixels) per surface; per latent of the window (the first frame,
    then each chunk of ``k`` frames) over all surfaces, which shows a decoder that degrades along a stream;
    per surface the reconstruction of the first window's middle frame (both players) for the contact
    sheet; and per surface the sharpness ratio, mean |Laplacian| of the reconstructions over the truth's
    (``dream_fidelity``'s sharpness: no dream can be sharper than its decoder makes the truth)."""
    from benchmarks.dream_fidelity import sharpness_T

    psnr, sample, sharpness = {}, {}, {}
    sq_by_frame, n_by_frame = 0.0, 0
    for surface, w in windows.items():
        sq, count, sharp_rec, sharp_truth = 0.0, 0, 0.0, 0.0
        for i in range(0, len(w), batch):
            chunk = w[i:i + batch]
            rec = reconstruct(chunk)
            if i == 0:
                sample[surface] = rec[0, rec.shape[1] // 2]
            diff = rec.astype(np.float64) - chunk.astype(np.float64)
            per_frame = np.sum(diff * diff, axis=(0, 2, 3, 4, 5))  # (T,)
            sq += float(per_frame.sum())
            count += diff.size
            sq_by_frame = sq_by_frame + per_frame
            n_by_frame += diff.size // diff.shape[1]
            sharp_rec += float(sharpness_T(rec).sum())
            sharp_truth += float(sharpness_T(chunk).sum())
        psnr[surface] = float(_psnr(sq, count))
        sharpness[surface] = round(sharp_rec / max(sharp_truth, 1e-12), 3)
    by_latent = [sq_by_frame[:1]] + [sq_by_frame[1 + k * j:1 + k * (j + 1)] for j in range((len(sq_by_frame) - 1) // k)]
    return psnr, [float(_psnr(s.sum(), n_by_frame * len(s))) for s in by_latent], sample, sharpness


# ---------------------------------------------------------------------------------------------
# 2. The judges on reconstructed eval episodes
# ---------------------------------------------------------------------------------------------


def reconstructed_query_frames(reconstruct: Reconstruct, segments) -> dict[tuple[str, str, int], np.ndarray]:
    """(episode key, bot, window index) -> the reconstructed frame of every judge query's view."""
    from benchmarks.eval_tasks import query_frames

    kept = {}
    for seg in segments:
        kept.update(query_frames(seg, reconstruct(seg.ground_truth()[None])[0]))
    return kept


def answer_agreement(original, reconstructed) -> dict[str, dict]:
    """Per question: queries asked, and the fraction answered the same on the reconstructions."""
    given = {(r.episode, r.index): r.answer for r in original}
    by_question: dict[str, list[bool]] = defaultdict(list)
    for r in reconstructed:
        by_question[r.question].append(given[(r.episode, r.index)] == r.answer)
    return {q: {"queries": len(v), "same_answer": round(float(np.mean(v)), 4)} for q, v in sorted(by_question.items())}


def judge_reconstructions(reconstruct: Reconstruct, segments, judge, original=None) -> dict:
    """Episode accuracy per task / type on the reconstructions against the originals (``original``: the
    originals' ``judge_episodes`` results, computed once per run), with the differences in points."""
    from benchmarks.eval_tasks import GeneratedVideos
    from solaris_env.judges.scoring import (
        episode_accuracy,
        judge_episodes,
        task_accuracy,
    )

    episodes = [s.episode for s in segments]
    original = original if original is not None else judge_episodes(judge, episodes)
    t0 = time.perf_counter()
    frames = GeneratedVideos(reconstructed_query_frames(reconstruct, segments), {}, 0.0).source(segments)
    recon = judge_episodes(judge, episodes, frames)
    seconds = time.perf_counter() - t0
    per_type = {"original": episode_accuracy(original), "reconstructed": episode_accuracy(recon)}
    tasks = {name: task_accuracy(pt) for name, pt in per_type.items()}
    points = {t: round(100.0 * (tasks["reconstructed"][t] - tasks["original"][t]), 2) for t in tasks["original"]}
    return {
        "tasks_pct": {name: {t: round(100.0 * a, 2) for t, a in acc.items()} for name, acc in tasks.items()},
        "per_type_pct": {name: {t: round(100.0 * s["accuracy"], 2) for t, s in pt.items()}
                         for name, pt in per_type.items()},
        "difference_points": points,
        "max_abs_difference_points": max(abs(v) for v in points.values()),
        "answer_agreement": answer_agreement(original, recon),
        "seconds": round(seconds, 1),
    }


# ---------------------------------------------------------------------------------------------
# The run
# ---------------------------------------------------------------------------------------------


def score_model(reconstruct: Reconstruct, windows: dict[str, np.ndarray], k: int, segments, judge, original
                ) -> dict:
    """Both parts for one reconstruction, with the verdicts against the targets."""
    t0 = time.perf_counter()
    psnr, by_latent, sample, sharpness = psnr_by_surface(reconstruct, windows, k)
    psnr_s = time.perf_counter() - t0
    judged = judge_reconstructions(reconstruct, segments, judge, original)
    return {
        "psnr_db_by_surface": psnr, "psnr_db_min_surface": min(psnr.values()), "psnr_seconds": round(psnr_s, 1),
        "psnr_db_by_latent": by_latent,
        "sharpness_ratio_by_surface": sharpness, "sharpness_ratio_min_surface": min(sharpness.values()),
        "judges": judged,
        "meets": {"psnr": min(psnr.values()) >= TARGET_PSNR_DB,
                  "judges": judged["max_abs_difference_points"] <= TARGET_JUDGE_POINTS},
        "_sample": sample,
    }


def contact_sheet(windows: dict[str, np.ndarray], samples: dict[str, dict[str, np.ndarray]]) -> np.ndarray:
    """Columns: per surface, both players' middle frame of the first window; rows: truth, then each model."""
    surfaces = list(windows)

    def row(frames_by_surface):
        return np.concatenate([np.concatenate(list(frames_by_surface[s]), axis=1) for s in surfaces], axis=1)

    truth = {s: windows[s][0, windows[s].shape[1] // 2] for s in surfaces}
    return np.concatenate([row(truth)] + [row(samples[m]) for m in samples], axis=0)


def run(models: dict[str, Reconstruct], heldout: str | Path, eval_data: str | Path, window: int, windows: int,
        k: int, frame_shape: tuple[int, int, int], judge=None) -> tuple[dict, np.ndarray]:
    """Score every model (frames of ``frame_shape``, ``k`` frames per latent); -> (result without machine facts,
    contact sheet)."""
    from benchmarks.eval_tasks import EVAL_NUM_FRAMES, make_segments
    from solaris_env.judges.episodes import find_episodes
    from solaris_env.judges.judge import Judge
    from solaris_env.judges.scoring import judge_episodes

    judge = judge or Judge.load()
    held = heldout_windows(heldout, window, windows, k)
    shape = next(iter(held.values())).shape[-3:]
    if tuple(shape) != tuple(frame_shape):
        raise ValueError(f"--heldout {heldout}: frames are {shape[0]}x{shape[1]}, the models make "
                         f"{frame_shape[0]}x{frame_shape[1]}: collect with --resolution {frame_shape[0]}")
    episodes = [e for e in find_episodes(eval_data) if e.is_eval]
    if not episodes:
        raise ValueError(f"--eval {eval_data}: no eval episodes (collect with --eval)")
    segments, skipped = make_segments(episodes, EVAL_NUM_FRAMES)
    if not segments:
        raise ValueError(f"--eval {eval_data}: no eval episode holds a {EVAL_NUM_FRAMES}-frame window: {skipped}")
    eval_shape = segments[0].ground_truth().shape[-3:]
    if tuple(eval_shape) != tuple(frame_shape):
        raise ValueError(f"--eval {eval_data}: frames are {eval_shape[0]}x{eval_shape[1]}, the models make "
                         f"{frame_shape[0]}x{frame_shape[1]}: collect with --resolution {frame_shape[0]}")
    original = judge_episodes(judge, [s.episode for s in segments])
    rows, samples = {}, {}
    for name, reconstruct in models.items():
        print(f"{name}: {sum(len(w) for w in held.values())} held-out windows, {len(segments)} eval episodes",
              file=sys.stderr, flush=True)
        row = score_model(reconstruct, held, k, segments, judge, original)
        samples[name] = row.pop("_sample")
        rows[name] = row
    result = {
        "targets": {"psnr_db_every_surface": TARGET_PSNR_DB, "judges_max_abs_difference_points": TARGET_JUDGE_POINTS},
        "heldout_windows": {"by_surface": {s: len(w) for s, w in held.items()}, "frames": window},
        "eval_episodes": {"per_type": dict(sorted(Counter(s.episode.episode_type for s in segments).items())),
                          "skipped": skipped, "frames": EVAL_NUM_FRAMES},
        "models": rows,
    }
    return result, contact_sheet(held, samples)


def table(result: dict) -> str:
    """Markdown: per model the PSNR per surface and the task differences."""
    models = result["models"]
    surfaces = list(next(iter(models.values()))["psnr_db_by_surface"])
    tasks = list(next(iter(models.values()))["judges"]["difference_points"])
    head = ["model", *[f"{s} dB" for s in surfaces], "sharpness (min surface)", *[f"{t} Δ" for t in tasks], "meets"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, row in models.items():
        meets = "yes" if all(row["meets"].values()) else "no (" + ", ".join(k for k, v in row["meets"].items() if not v) + ")"
        cells = [name, *[f"{row['psnr_db_by_surface'][s]:.2f}" for s in surfaces],
                 f"{row['sharpness_ratio_min_surface']:.2f}",
                 *[f"{row['judges']['difference_points'][t]:+.1f}" for t in tasks], meets]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m benchmarks.autoencoder_target", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", action="append", default=None,
                   help="default, a model directory or preset:NAME (repeatable; default: default)")
    p.add_argument("--heldout", required=True, help="a --world mixed collect with --test-fraction 1 (duet/test)")
    p.add_argument("--eval", required=True, dest="eval_data", help="a collect --eval output at the models' resolution")
    p.add_argument("--window", type=int, default=65, help="frames per held-out window (1 + k n)")
    p.add_argument("--windows", type=int, default=4, help="held-out windows per video at most")
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    from benchmarks.dream_fidelity import load_model, model_label
    from benchmarks.machine import machine_info, write_result
    from solaris_env.paths import portable_path
    from training.samples import vae_reconstructor, write_png

    load = os.getloadavg()
    specs = args.model or ["default"]
    loaded = {model_label(s): load_model(s) for s in specs}
    ks = {m.frames_per_step for m in loaded.values()}
    shapes = {m.frame_shape for m in loaded.values()}
    if len(ks) != 1 or len(shapes) != 1:
        raise SystemExit(f"--model: every model must share frames per step and frame size to be compared on the "
                         f"same windows, got k {sorted(ks)} and frames {sorted(shapes)}")
    t0 = time.perf_counter()
    result, sheet = run({name: vae_reconstructor(m) for name, m in loaded.items()}, args.heldout, args.eval_data,
                        args.window, args.windows, ks.pop(), shapes.pop())
    result = {"benchmark": "autoencoder_target", "heldout": portable_path(args.heldout),
              "eval_data": portable_path(args.eval_data), **result, "table": None,
              "seconds": round(time.perf_counter() - t0, 1), "machine": machine_info(load)}
    result["table"] = table(result)
    print(result["table"])
    write_result(args.out, result)
    png = Path(args.out).with_suffix(".png")
    write_png(png, sheet, scale=2)
    print(f"wrote {png} (rows: truth, then {', '.join(loaded)}; columns: per surface both players)")
    return result


if __name__ == "__main__":
    main()
