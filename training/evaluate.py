"""Is it a world model? Held-out rollouts of a trained model against the engine's ground truth.

    python -m training.evaluate MODEL_DIR --data data/heldout --out runs/tiny/eval

On held-out Duet episodes (``DATA/duet/test``), from each segment's first frame and the true actions:

(a) rollouts of ``steps`` env steps (default 32 = 128 frames) scored by PSNR against ground truth,
    next to the copy-the-last-observed-frame baseline (the first frame repeated);
(b) action following: the same rollout with all actions zeroed, per player (true actions must be
    closer to the ground truth than zeroed ones);
(c) collapse: a ``long_steps`` rollout (default 200) with PSNR and mean/std of the pixels over time
    (a collapsing model drifts to a flat or saturated image);
next to both, the VAE's reconstruction of the ground truth (its encode then decode, i.e. a DiT that predicted
every latent exactly: the model's ceiling), and the teacher-forced rollout (each step predicted from the true
past latents: its gap to (a) is the drift, its gap to the ceiling the per-step error). PSNR is the mean over
frames of each frame's PSNR (the criterion); next to it, the PSNR of the mean squared error over all frames;
plus a contact sheet (generated over ground truth, both players, 64 steps) and ``eval.json``.

PSNR rewards a blur, so (a) also reports per env step the sharpness ratio (mean |Laplacian| over the truth's,
the fidelity benchmark's measure) and the pixel std of the free rollout, the teacher-forced one and the VAE's
reconstruction, with the truth's std. A rollout that fades loses both along the steps while its teacher-forced
twin keeps them (docs/history.md, session 25). And whether each rollout moves the way the truth does: the
fidelity benchmark's direction agreement on env-step frames, for the free rollout, the teacher-forced one (its
one-step predictions, scored from the frame they were conditioned on) and both with zeroed actions. A model
whose teacher-forced predictions follow the actions but whose free rollout does not is drifting; one whose
teacher-forced predictions do not is not conditioned on the actions.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from solaris_env.paths import portable_path
from training.duet import DuetDataset
from training.samplers import MultiplayerSegmentSampler, draw_loaded, make_batch
from training.samples import (
    contact_sheet,
    psnr_per_frame,
    rollout,
    side_by_side,
    vae_reconstructor,
    write_json,
    write_mp4,
    write_png,
)


def start_poses(dataset: DuetDataset, segment) -> np.ndarray:
    """(P, 5) the players' poses at a segment's first frame (record start + 1, ``DuetDataset.segment``), which a
    partner-map model starts from (``DiTConfig.partner_map``, docs/model.md §8.6)."""
    poses = []
    for rec, start in zip(dataset.recordings(segment.episode_id), (segment.start1, segment.start2)):
        if rec.pose_T5 is None:
            raise ValueError(f"episode {segment.episode_id} of {dataset.directory} records no poses, which this "
                             "partner-map model needs; re-collect it with `solaris-engine collect`")
        poses.append(rec.pose_T5[start + 1])
    return np.stack(poses).astype(np.float32)


def _segments(dataset, num_frames: int, count: int, seed: int, poses: bool = False) -> dict[str, np.ndarray] | None:
    """``count`` held-out segments (``next_batch``'s keys), with ``poses`` (B, P, 5) at their first frames."""
    try:
        sampler = MultiplayerSegmentSampler(dataset, num_frames, seed=seed)
    except ValueError:  # no episode is long enough
        return None
    loaded = draw_loaded(sampler, lambda seg: (dataset.load(seg, num_frames), seg), count)
    batch = make_batch([sample for sample, _ in loaded], num_frames)
    batch["poses"] = np.stack([start_poses(dataset, seg) for _, seg in loaded]) if poses else None
    return batch


def fade_by_step(truth_BTPHW3: np.ndarray, rollouts: dict[str, np.ndarray], steps: int, k: int) -> dict:
    """Per env step (frames 1.., k per step): each rollout's sharpness ratio to the truth and pixel std, and the
    truth's pixel std; plus each rollout's sharpness ratio over all steps."""
    from benchmarks.dream_fidelity import sharpness_T

    def per_frame(x):  # (B, T, P, H, W, 3) -> (sharpness, std), each (B, T - 1, P) without the given frame
        return sharpness_T(x)[:, 1:], x.reshape(x.shape[:3] + (-1,)).astype(np.float32).std(axis=-1)[:, 1:]

    by_step = lambda v: v.mean(axis=(0, 2)).reshape(steps, k).mean(axis=1)
    sharp_truth, std_truth = per_frame(truth_BTPHW3)
    out = {"pixel_std_truth_by_step": [round(float(v), 2) for v in by_step(std_truth)]}
    for name, x in rollouts.items():
        sharp, std = per_frame(x)
        ratio = by_step(sharp) / np.maximum(by_step(sharp_truth), 1e-12)
        out[f"sharpness_ratio_{name}"] = round(float(sharp.mean() / max(sharp_truth.mean(), 1e-12)), 3)
        out[f"sharpness_ratio_{name}_by_step"] = [round(float(v), 3) for v in ratio]
        out[f"pixel_std_{name}_by_step"] = [round(float(v), 2) for v in by_step(std)]
    return out


def direction_by_rollout(truth_BTPHW3: np.ndarray, rollouts: dict[str, tuple[np.ndarray, np.ndarray]],
                         k: int) -> dict:
    """Does each rollout move the way the truth does? The fidelity benchmark's direction estimator
    (``benchmarks.dream_fidelity.direction_scores``) on env-step frames (every k-th frame): the camera motion is
    fitted to each true step, and a rollout's step ``before[t-1] -> after[t]`` is scored under it.

    ``rollouts`` maps a name to ``(before, after)``, both (B, T, P, H, W, 3) uint8: a free rollout is scored
    against itself (``(x, x)``); a teacher-forced one from the frames its step was conditioned on (the VAE's
    reconstruction of the truth), so its score is that of a one-step prediction. Returns per name the direction
    agreement (1 = as the truth, 0 = frozen or unrelated, < 0 = reversed) and the count of scored steps."""
    from benchmarks.dream_fidelity import (
        direction_agreement,
        direction_score,
        direction_scores,
        prepare_THW,
    )

    engine, valid, scores = [], [], {name: [] for name in rollouts}
    b, _, p = truth_BTPHW3.shape[:3]
    for i in range(b):
        for j in range(p):
            ref = direction_scores(truth_BTPHW3[i, ::k, j])
            engine.append(ref["engine"])
            valid.append(ref["valid"])
            for name, (before, after) in rollouts.items():
                x, y = prepare_THW(before[i, ::k, j]), prepare_THW(after[i, ::k, j])
                scores[name].append([direction_score(x[t - 1], y[t], ref["motion"][t - 1]) for t in range(1, len(y))])
    engine, valid = np.concatenate(engine), np.concatenate(valid)
    out = {"direction_valid_steps": int(valid.sum())}
    for name, s in scores.items():
        agreement = direction_agreement(engine, np.concatenate(s), valid)
        out[f"direction_agreement_{name}"] = None if agreement is None else round(float(agreement), 3)
    return out


def evaluate(model_dir: str | Path, data_dir: str | Path, out_dir: str | Path, num_segments: int = 8,
             steps: int = 32, long_steps: int = 200, sheet_steps: int = 64, seed: int = 0) -> dict:
    from solaris_env.world_model.world_model import WorldModel

    model = WorldModel.load(model_dir)
    cfg = model.config
    k = model.frames_per_step
    out_dir = Path(out_dir)
    dataset = DuetDataset(data_dir, "test", obs_size=(cfg.frame_height, cfg.frame_width))
    result: dict = {"model": portable_path(model_dir, parts=3), "data": portable_path(data_dir),  # never absolute
                    "episodes": len(dataset.valid_ids),
                    "frames_per_step": k}

    # (a) + (b): short rollouts
    needs_poses = bool(cfg.dit.partner_map)
    seg = _segments(dataset, 1 + k * steps, num_segments, seed, needs_poses)
    if seg is None:
        raise ValueError(f"no held-out episode in {data_dir}/duet/test holds {1 + k * steps} frames")
    obs, act, poses = seg["obs"], seg["act"], seg["poses"]
    gen = rollout(model, obs, act, seed, poses_BP5=poses)
    gen_zero = rollout(model, obs, np.zeros_like(act), seed, poses_BP5=poses)
    gen_teacher = rollout(model, obs, act, seed, teacher_forced=True, poses_BP5=poses)
    copy = np.repeat(obs[:, :1], obs.shape[1], axis=1)
    ceiling = vae_reconstructor(model)(obs)
    score = lambda x: psnr_per_frame(x, obs)[:, 1:]  # (B, T-1, P): frames after the given one
    mse_db = lambda x: float(10.0 * np.log10(255.0 ** 2 / np.mean((x[:, 1:].astype(np.float64) - obs[:, 1:]) ** 2)))
    per_player = lambda x: [float(v) for v in score(x).mean(axis=(0, 1))]
    by_step = lambda x: [float(v) for v in score(x).mean(axis=(0, 2)).reshape(steps, k).mean(axis=1)]  # env step
    result["rollout"] = {
        "segments": len(obs), "steps": steps, "frames": int(obs.shape[1]),
        "psnr_model_db": float(score(gen).mean()), "psnr_copy_last_frame_db": float(score(copy).mean()),
        "psnr_zero_actions_db": float(score(gen_zero).mean()),
        "psnr_model_per_player_db": per_player(gen), "psnr_zero_actions_per_player_db": per_player(gen_zero),
        "psnr_copy_per_player_db": per_player(copy),
        "psnr_model_by_step_db": by_step(gen),
        "psnr_copy_last_frame_by_step_db": by_step(copy),
        "psnr_vae_reconstruction_db": float(score(ceiling).mean()),
        "psnr_vae_reconstruction_by_step_db": by_step(ceiling),
        "psnr_teacher_forced_db": float(score(gen_teacher).mean()),
        "psnr_teacher_forced_by_step_db": by_step(gen_teacher),
        "psnr_of_mean_mse_model_db": mse_db(gen), "psnr_of_mean_mse_copy_last_frame_db": mse_db(copy),
    }
    fade = fade_by_step(obs, {"model": gen, "teacher_forced": gen_teacher, "vae_reconstruction": ceiling}, steps, k)
    result["rollout"].update(fade)
    gen_teacher_zero = rollout(model, obs, np.zeros_like(act), seed, teacher_forced=True, poses_BP5=poses)
    result["rollout"].update(direction_by_rollout(obs, {
        "model": (gen, gen), "zero_actions": (gen_zero, gen_zero),
        "teacher_forced": (ceiling, gen_teacher), "teacher_forced_zero_actions": (ceiling, gen_teacher_zero),
        "vae_reconstruction": (ceiling, ceiling)}, k))
    r = result["rollout"]
    r["beats_copy_last_frame"] = r["psnr_model_db"] > r["psnr_copy_last_frame_db"]
    r["follows_actions_per_player"] = [a > z for a, z in zip(r["psnr_model_per_player_db"],
                                                              r["psnr_zero_actions_per_player_db"])]
    write_mp4(out_dir / "rollout_0.mp4", side_by_side(gen[0], obs[0]))

    # contact sheet: 64 steps of one segment, every 2nd step
    sheet = _segments(dataset, 1 + k * sheet_steps, 1, seed + 1, needs_poses)
    if sheet is not None:
        g = rollout(model, sheet["obs"], sheet["act"], seed, poses_BP5=sheet["poses"])
        write_png(out_dir / "contact_sheet.png", contact_sheet(g[0], sheet["obs"][0], every=2 * k))
        result["contact_sheet"] = {"steps": sheet_steps, "psnr_db": float(psnr_per_frame(g, sheet["obs"])[:, 1:].mean())}

    # (c) collapse over long rollouts
    long = _segments(dataset, 1 + k * long_steps, min(num_segments, 4), seed + 2, needs_poses)
    if long is not None:
        g = rollout(model, long["obs"], long["act"], seed, poses_BP5=long["poses"])
        p = psnr_per_frame(g, long["obs"])  # (B, T, P)
        idx = np.arange(k, g.shape[1], k * 10)  # every 10 steps
        result["long_rollout"] = {
            "segments": len(g), "steps": long_steps,
            "step": [int(i // k) for i in idx],
            "psnr_db": [float(p[:, i].mean()) for i in idx],
            "pixel_mean_generated": [float(g[:, i].mean()) for i in idx],
            "pixel_std_generated": [float(g[:, i].std()) for i in idx],
            "pixel_mean_ground_truth": [float(long["obs"][:, i].mean()) for i in idx],
            "pixel_std_ground_truth": [float(long["obs"][:, i].std()) for i in idx],
        }
        write_mp4(out_dir / "long_rollout_0.mp4", side_by_side(g[0], long["obs"][0]))
    else:
        result["long_rollout"] = None

    write_json(out_dir / "eval.json", result)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m training.evaluate", description=__doc__.split("\n\n")[0])
    parser.add_argument("model", help="a model directory (ours)")
    parser.add_argument("--data", required=True, help="dataset root with held-out duet/test episodes")
    parser.add_argument("--out", required=True)
    parser.add_argument("--segments", type=int, default=8)
    parser.add_argument("--steps", type=int, default=32)
    parser.add_argument("--long-steps", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    result = evaluate(args.model, args.data, args.out, args.segments, args.steps, args.long_steps, seed=args.seed)
    print(json.dumps({k: v for k, v in result.items() if k != "long_rollout"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
