"""Which latent layout can hold a 64x64 engine frame? VAE candidates trained side by side, scored per world.

    .venv/bin/python -m benchmarks.autoencoder_capacity --data data/ae16 --minutes 8      # ~8 min per candidate
    .venv/bin/python -m benchmarks.autoencoder_capacity --data data/ae16 --candidates s4_z16 s8_z16 --steps 400

The world model can only show what its autoencoder can represent: a partner 2-3 pixels wide, the hotbar,
block edges. Each candidate (a ``VAEConfig`` on the ``tiny`` preset's 64x64 frames: spatial factor, latent
channels, temporal factor) trains from scratch with the VAE stage's objective (``training.vae``) for the same
wall-clock budget (or the same number of updates) on the same clips, then reconstructs held-out clips
(``duet/test``, 1 + 2k frames: the first-frame latent and the chunk latents) through the posterior mean.
Reported per candidate: PSNR over all held-out frames, per world surface (grass / snow / sand / red sand /
normal; a flat world's surface is its instance mod 5, ``engine.worldgen.FLAT_VARIANTS``), the sharpness ratio
(mean |Laplacian| of the reconstructions over the truth's, overall and per surface), the updates done,
latent numbers per frame, and the decoder's cost (GFLOP per env step and player, from XLA's cost analysis).
The issue's target is >= 28 dB on every world (docs/evaluation.md). Short CPU runs rank the candidates;
the GPU sprint (docs/training.md) trains the chosen one to convergence. Writes
``benchmarks/results/autoencoder_capacity.json`` and a PNG (truth over each candidate's reconstruction).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np

from benchmarks.dream_fidelity import sharpness_ratio

RESULTS = Path(__file__).parent / "results" / "autoencoder_capacity.json"
SURFACES = ("grass", "grass", "snow", "sand", "red_sand")  # FLAT_VARIANTS' surfaces by instance mod 5
# name -> VAEConfig fields over the tiny preset's VAE (spatial factor = 2 ** (len(dim_mult) - 1))
CANDIDATES = {
    "s8_z16": {},  # the shipped layout: 8x8x16 latents per 4 frames
    # both stages halve time (k = 4), so the decoder keeps its full-resolution stage (head upscale 1)
    "s4_z16": {"dim_mult": (1, 2, 4), "temporal_downsample": (True, True), "decoder_head_upscale": 1},
    "s4_z32": {"z_dim": 32, "dim_mult": (1, 2, 4), "temporal_downsample": (True, True), "decoder_head_upscale": 1},
    "s4_z16_k2": {"dim_mult": (1, 2, 4), "temporal_downsample": (False, True), "decoder_head_upscale": 2},
    # tiny16's layout with 4x the channels: encoder base 16 -> 32 (it runs once per env reset), decoder 8 -> 32
    "s4_z16_w32": {"dim_mult": (1, 2, 4), "temporal_downsample": (True, True), "decoder_head_upscale": 1,
                   "base_dim": 32, "decoder_base_dim": 32},
}


def candidate_config(name: str):
    """The tiny preset with candidate ``name``'s VAE (no latent statistics yet)."""
    from solaris_env.world_model.config import preset

    if name not in CANDIDATES:
        raise ValueError(f"candidate must be one of {sorted(CANDIDATES)}, got {name!r}")
    cfg = preset("tiny")
    vae = dataclasses.replace(cfg.vae, latent_mean=(), latent_std=(), **CANDIDATES[name])
    return cfg.replace(vae=vae)


def surface_of(groundtruth: dict) -> str:
    """The start world's surface of an episode (its ground-truth sidecar)."""
    if groundtruth["world_type"] != "flat":
        return "normal"
    return SURFACES[int(groundtruth["instance"]) % len(SURFACES)]


def test_videos(data_dir: str | Path) -> list[tuple[str, list[Path]]]:
    """(surface, [Alpha's video, Bravo's video]) of every ``duet/test`` episode, sorted by file name."""
    test = Path(data_dir) / "duet" / "test"
    out = []
    for gt_path in sorted(test.glob("*_groundtruth.json")):
        stem = gt_path.name.removesuffix("_groundtruth.json")  # batch_B_EEEEEE_instance_III
        prefix, instance = stem.rsplit("_instance_", 1)
        out.append((surface_of(json.loads(gt_path.read_text())),
                    [test / f"{prefix}_{player}_instance_{instance}.mp4" for player in ("Alpha", "Bravo")]))
    return out


def held_out_clips(data_dir: Path, num_frames: int, per_episode: int, seed: int = 0) -> dict[str, np.ndarray]:
    """surface -> (N, num_frames, 64, 64, 3) uint8 clips from ``duet/test`` (both players, evenly spaced
    starts per video, the same every run)."""
    from training.video_io import probe_video, read_frames

    clips: dict[str, list] = {}
    test = data_dir / "duet" / "test"
    for surface, videos in test_videos(data_dir):
        for video in videos:
            n = probe_video(video)
            if n < num_frames:
                continue
            for start in np.linspace(0, n - num_frames, per_episode).astype(int):
                clips.setdefault(surface, []).append(read_frames(video, int(start), int(start) + num_frames, (64, 64)))
    if not clips:
        raise ValueError(f"{test}: no test episodes with >= {num_frames} frames (collect with --test-fraction > 0)")
    return {s: np.stack(c) for s, c in sorted(clips.items())}


def decoder_gflop(cfg) -> float:
    """GFLOP of decoding one latent frame (k video frames) for one player, from XLA's cost analysis."""
    import jax
    import jax.numpy as jnp
    from flax import nnx

    from solaris_env.world_model.vae import CausalVideoVAE

    vae = CausalVideoVAE(cfg.vae, rngs=nnx.Rngs(0))
    graphdef, state = nnx.split(vae)
    z = jnp.zeros((1, 2, cfg.latent_height, cfg.latent_width, cfg.latent_channels), jnp.float32)
    cost = jax.jit(lambda s, z: nnx.merge(graphdef, s).decode_raw(z)).lower(state, z).compile().cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    return float(cost.get("flops", 0.0)) / 2 / 1e9  # two latent frames decoded: per latent frame


def train_candidate(name: str, data_dir: Path, test: dict[str, np.ndarray], minutes: float | None,
                    steps: int | None, batch_size: int, num_frames: int, lr: float, seed: int) -> dict:
    """Train candidate ``name`` from scratch; its held-out PSNR per surface and a reconstruction sample."""
    import jax.numpy as jnp
    from flax import nnx

    from solaris_env.world_model.vae import CausalVideoVAE
    from training import vae as V
    from training.samplers import next_batch
    from training.step import TrainState, make_optimizer
    from training.train import duet_stream

    cfg = candidate_config(name)
    vae = CausalVideoVAE(cfg.vae, rngs=nnx.Rngs(seed))
    tx = make_optimizer(lr)
    graphdef, state = TrainState.create(vae, tx, rng=seed)
    step_fn = V.make_vae_train_step(graphdef, tx, V.VAELossWeights())
    dataset, sampler = duet_stream(data_dir, cfg, num_frames, seed)
    t0, done, losses = time.perf_counter(), 0, []
    while True:
        obs = next_batch(dataset, sampler, batch_size)["obs"]
        video = jnp.asarray(np.swapaxes(obs, 1, 2).reshape((-1,) + obs.shape[1:2] + obs.shape[3:]))
        state, metrics = step_fn(state, video)
        done += 1
        losses.append(float(metrics["psnr"]))
        if (steps is not None and done >= steps) or (minutes is not None and time.perf_counter() - t0 > minutes * 60):
            break
    train_s = time.perf_counter() - t0
    reconstruct = V.make_reconstruct(graphdef)
    per_surface, sharp_by_surface, recon_all, truth_all = {}, {}, [], []
    for surface, clips in test.items():
        rec = np.concatenate([np.asarray(reconstruct(state.params, state.rest, clips[i:i + 8]))
                              for i in range(0, len(clips), 8)])
        per_surface[surface] = round(V.psnr_uint8(rec, clips), 2)
        sharp_by_surface[surface] = sharpness_ratio(rec, clips)
        recon_all.append(rec[:2])
        truth_all.append(clips[:2])
    all_rec = np.concatenate([np.asarray(reconstruct(state.params, state.rest, c[i:i + 8]))
                              for c in test.values() for i in range(0, len(c), 8)])
    all_truth = np.concatenate(list(test.values()))
    k = cfg.frames_per_step
    return {"vae": {f: getattr(cfg.vae, f) for f in ("z_dim", "dim_mult", "temporal_downsample",
                                                    "decoder_head_upscale")},
            "latent_shape": [cfg.latent_height, cfg.latent_width, cfg.latent_channels], "frames_per_latent": k,
            "latent_numbers_per_frame": cfg.latent_height * cfg.latent_width * cfg.latent_channels / k,
            "updates": done, "train_s": round(train_s, 1), "train_psnr_last50_db": round(float(np.mean(losses[-50:])), 2),
            "test_psnr_db": round(V.psnr_uint8(all_rec, all_truth), 2),
            "test_psnr_min_surface_db": min(per_surface.values()), "test_psnr_by_surface_db": per_surface,
            "test_sharpness_ratio": sharpness_ratio(all_rec, all_truth),
            "test_sharpness_ratio_by_surface": sharp_by_surface,
            "decoder_gflop_per_latent_frame": round(decoder_gflop(cfg), 3),
            "_sample": (np.concatenate(truth_all), np.concatenate(recon_all))}


def contact_sheet(samples: dict[str, tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Rows: the held-out truth, then each candidate's reconstruction (the middle frame of each clip)."""
    names = list(samples)
    truth = samples[names[0]][0]
    mid = truth.shape[1] // 2
    rows = [np.concatenate(list(truth[:, mid]), axis=1)] + [np.concatenate(list(samples[n][1][:, mid]), axis=1)
                                                             for n in names]
    return np.concatenate(rows, axis=0)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m benchmarks.autoencoder_capacity", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="a collected dataset root (duet/train and duet/test)")
    p.add_argument("--candidates", nargs="+", default=list(CANDIDATES), choices=sorted(CANDIDATES))
    p.add_argument("--minutes", type=float, default=None, help="wall-clock training budget per candidate")
    p.add_argument("--steps", type=int, default=None, help="updates per candidate (instead of --minutes)")
    p.add_argument("--batch-size", type=int, default=4, help="Duet segments per update (x 2 players)")
    p.add_argument("--num-frames", type=int, default=9, help="frames per training clip (1 + k * n)")
    p.add_argument("--lr", type=float, default=5e-4)
    p.add_argument("--test-per-episode", type=int, default=2, help="held-out clips per test video")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    if (args.minutes is None) == (args.steps is None):
        p.error("give exactly one of --minutes and --steps")
    from benchmarks.machine import machine_info, write_result
    from training.samples import write_png

    load = os.getloadavg()
    data = Path(args.data)
    test = held_out_clips(data, args.num_frames, args.test_per_episode, args.seed)
    result = {"setup": {"data": data.name, "minutes": args.minutes, "steps": args.steps, "batch_size": args.batch_size,
                        "num_frames": args.num_frames, "lr": args.lr, "frame_size": [64, 64],
                        "test_clips_by_surface": {s: len(c) for s, c in test.items()}},
              "target_psnr_db": 28.0, "candidates": {}}
    samples = {}
    for name in args.candidates:
        row = train_candidate(name, data, test, args.minutes, args.steps, args.batch_size, args.num_frames, args.lr,
                              args.seed)
        samples[name] = row.pop("_sample")
        result["candidates"][name] = row
        print(f"{name:>10s}: {row['test_psnr_db']:5.2f} dB held out (min surface {row['test_psnr_min_surface_db']:5.2f}) "
              f"sharpness {row['test_sharpness_ratio']:.2f} after {row['updates']} updates in {row['train_s']:.0f} s; "
              f"latents {row['latent_shape']} per "
              f"{row['frames_per_latent']} frames; decoder {row['decoder_gflop_per_latent_frame']} GFLOP; "
              f"{row['test_psnr_by_surface_db']}", flush=True)
    result["machine"] = machine_info(load)
    write_result(args.out, result)
    png = Path(args.out).with_suffix(".png")
    write_png(png, contact_sheet(samples), scale=2)
    print(f"wrote {png} (rows: truth, then {', '.join(samples)})")
    return result


if __name__ == "__main__":
    main()
