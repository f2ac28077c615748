"""Can the DiT learn to follow the camera at all? A synthetic action-following task, per action conditioning.

    .venv/bin/python -m benchmarks.action_learnability                     # tiny preset, 3 variants, ~25 min
    .venv/bin/python -m benchmarks.action_learnability --steps 20 --variants official   # smoke run

The shipped model barely reacts to the camera (``benchmarks.action_response``), and fine-tunes on real engine
data take ~30 min per try. This isolates the architecture: stage-3 training (causal DiT, Diffusion Forcing, the
real train step) from a fresh initialisation on synthetic latent videos whose motion only the actions explain.
Each clip starts from a smooth random latent field (periodic Gaussian blur of white noise, unit std); every later
latent frame is the previous one rolled by -1, 0 or +1 latent pixels along the width, drawn independently per
(clip, player, frame), and the yaw of that frame's k ticks says which (``--yaw`` scaled camera units per tick
times the shift; keyboard all zero). The past never predicts the next shift, so a model can only beat the
shift-blind loss by reading the mouse.

Scored on a fixed held-out batch with fixed timesteps and noise: the flow-matching loss with the true mouse,
with it negated (the opposite shift), and zeroed; ``action_gain`` = loss(negated) / loss(true) - 1 (0 = the
model ignores the mouse). Variants: ``official`` (the reference design), ``gain10`` (``ActionConfig.mouse_input_gain``
10), and, with the official action module, ``camera_warp`` (``DiTConfig.camera_warp`` set to the synthetic shift:
one latent pixel per ``k * yaw`` units). Two more variants measured no gain and were deleted with their options
(docs/history.md: the adaLN action path, +0.9 %, and camera RoPE, +0.7 %). Writes
``benchmarks/results/action_learnability.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results" / "action_learnability.json"
# every variant names both settings: the preset's own defaults (tiny: gain 10) must not leak into "official"
VARIANTS = {"official": {"mouse_input_gain": 1.0},
            "gain10": {"mouse_input_gain": 10.0},
            "camera_warp": {"mouse_input_gain": 1.0}}
CAMERA_WARP_VARIANTS = ("camera_warp",)  # the others run with the warp off, named explicitly too


def matched_camera_warp(cfg, yaw: float) -> tuple[float, float]:
    """``DiTConfig.camera_warp`` (latent pixels per degree) that moves the previous latent as the synthetic shift:
    a latent frame of k ticks at ``yaw`` scaled units per tick moves the field one latent pixel."""
    from solaris_env.spaces import CAMERA_SCALE_DEG

    return (0.0, 1.0 / (cfg.frames_per_step * yaw * CAMERA_SCALE_DEG))


def smooth_fields(rng: np.random.Generator, n: int, h: int, w: int, c: int, sigma: float) -> np.ndarray:
    """(n, h, w, c) float32 periodic smooth random fields with unit std per field."""
    noise = rng.normal(size=(n, h, w, c))
    fy, fx = np.fft.fftfreq(h)[:, None], np.fft.fftfreq(w)[None, :]
    gain = np.exp(-2.0 * (np.pi * sigma) ** 2 * (fy ** 2 + fx ** 2))[None, :, :, None]
    field = np.real(np.fft.ifft2(np.fft.fft2(noise, axes=(1, 2)) * gain, axes=(1, 2)))
    return (field / field.std(axis=(1, 2, 3), keepdims=True)).astype(np.float32)


def synthetic_clips(rng: np.random.Generator, cfg, batch: int, latent_frames: int, yaw: float, sigma: float):
    """-> (x0 (B, P, F, h, w, C), act (B, T, P, 25) with T = k (F - 1) + 1, shifts (B, P, F))."""
    p, h, w, c, k = cfg.num_players, cfg.latent_height, cfg.latent_width, cfg.latent_channels, cfg.frames_per_step
    shifts = rng.integers(-1, 2, size=(batch, p, latent_frames))
    shifts[:, :, 0] = 0
    frames = [smooth_fields(rng, batch * p, h, w, c, sigma).reshape(batch, p, h, w, c)]
    for f in range(1, latent_frames):
        rolled = [[np.roll(frames[-1][b, q], shifts[b, q, f], axis=1) for q in range(p)] for b in range(batch)]
        frames.append(np.asarray(rolled, np.float32))
    x0 = np.stack(frames, axis=2)
    act = np.zeros((batch, k * (latent_frames - 1) + 1, p, 25), np.float32)
    for f in range(1, latent_frames):  # latent frame f holds ticks k(f-1)+1 .. kf
        act[:, k * (f - 1) + 1:k * f + 1, :, 23] = yaw * shifts[:, :, f].astype(np.float32)[:, None, :]
    return x0, act, shifts


def dit_batch(cfg, x0, act, context_tokens: int = 4) -> dict:
    """The DiT batch of ``training.step`` (image-layout first-frame conditioning, zero image context)."""
    import jax.numpy as jnp

    from solaris_env.world_model.action_module import left_pad_actions
    from solaris_env.world_model.conditioning import first_frame_mask
    from solaris_env.world_model.dit import to_stream

    b, p, f = x0.shape[:3]
    img = np.concatenate([x0[:, :, :1], np.zeros_like(x0[:, :, 1:])], axis=2)
    mask = np.asarray(first_frame_mask(f, cfg.frames_per_step))
    mask = np.broadcast_to(mask[None, None, :, None, None, :], (b, p, f) + x0.shape[3:5] + mask.shape[-1:])
    actions = left_pad_actions(jnp.asarray(act).transpose(0, 2, 1, 3), cfg.action_left_padding)
    kb = cfg.action.keyboard_dim
    return {"x0": to_stream(cfg, jnp.asarray(x0)), "cond": to_stream(cfg, jnp.concatenate([mask, img], axis=-1)),
            "context": to_stream(cfg, jnp.zeros((b, p, context_tokens, cfg.context_width), jnp.float32)),
            "mouse": to_stream(cfg, actions[..., kb:]), "keyboard": to_stream(cfg, actions[..., :kb])}


def run_variant(name: str, preset: str, steps: int, batch: int, latent_frames: int, lr: float, yaw: float,
                sigma: float, eval_every: int, seed: int = 0) -> dict:
    import jax
    import jax.numpy as jnp
    from flax import nnx

    from solaris_env.world_model.config import preset as make_preset
    from solaris_env.world_model.dit import WorldDiT
    from training.objectives import sample_timesteps
    from training.step import TrainState, make_loss_fn, make_optimizer, make_train_step

    base = make_preset(preset)
    warp = matched_camera_warp(base, yaw) if name in CAMERA_WARP_VARIANTS else (0.0, 0.0)
    cfg = base.replace(action=dataclasses.replace(base.action, **VARIANTS[name]),
                       dit=dataclasses.replace(base.dit, camera_warp=warp, walk_warp=0.0))  # a turning task
    dit = WorldDiT(cfg, rngs=nnx.Rngs(seed))
    tx = make_optimizer(lr)
    graphdef, state = TrainState.create(dit, tx, rng=seed)
    train_step = make_train_step(graphdef, "forward_causal", "diffusion_forcing", tx, ema_decay=0.0)
    loss_fn = jax.jit(make_loss_fn(graphdef, "forward_causal"))

    rng = np.random.default_rng(seed)
    x0_e, act_e, _ = synthetic_clips(np.random.default_rng(10_000 + seed), cfg, 2 * batch, latent_frames, yaw, sigma)
    k_t, k_n = jax.random.split(jax.random.key(20_000 + seed))
    t_e = sample_timesteps(k_t, x0_e.shape[:3], "diffusion_forcing")
    noise_e = jax.random.normal(k_n, x0_e.shape, jnp.float32)
    kb = cfg.action.keyboard_dim

    def evaluate(st) -> dict:
        out = {}
        for label, scale in (("true", 1.0), ("negated", -1.0), ("zeroed", 0.0)):
            act = act_e.copy()
            act[..., kb:] *= scale
            batch_e = dit_batch(cfg, x0_e, act)
            out[f"loss_{label}"] = float(loss_fn(st.params, st.rest, batch_e, t_e, noise_e))
        out["action_gain"] = out["loss_negated"] / out["loss_true"] - 1.0
        return out

    curve, t0 = [], time.perf_counter()
    for step in range(1, steps + 1):
        x0, act, _ = synthetic_clips(rng, cfg, batch, latent_frames, yaw, sigma)
        state, metrics = train_step(state, dit_batch(cfg, x0, act))
        if step % eval_every == 0 or step == steps:
            row = {"step": step, "train_loss": float(metrics["loss"]), **evaluate(state),
                   "wall_s": round(time.perf_counter() - t0, 1)}
            curve.append(row)
            print(f"{name:>8s} step {step:5d}  loss true {row['loss_true']:.4f}  negated {row['loss_negated']:.4f}  "
                  f"zeroed {row['loss_zeroed']:.4f}  action_gain {row['action_gain']:+.3f}", flush=True)
    return {"variant": name, "action_config": VARIANTS[name], "camera_warp": list(warp),
            "curve": curve,
            "final": curve[-1],
            "steps_per_s": steps / (time.perf_counter() - t0)}


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m benchmarks.action_learnability", description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="tiny")
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--latent-frames", type=int, default=7, help="latent frames per clip (7 = 25 video frames)")
    p.add_argument("--lr", type=float, default=3e-4)
    p.add_argument("--yaw", type=float, default=0.5, help="scaled camera units per tick per latent pixel of shift")
    p.add_argument("--sigma", type=float, default=1.0, help="blur of the random fields (latent pixels)")
    p.add_argument("--eval-every", type=int, default=50)
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    if args.steps < 1 or args.batch < 1 or args.latent_frames < 2:
        raise ValueError(f"steps and batch must be >= 1 and latent-frames >= 2, got {args.steps}, {args.batch}, "
                         f"{args.latent_frames}")
    from benchmarks.machine import machine_info, write_result

    load = os.getloadavg()
    t0 = time.perf_counter()
    runs = [run_variant(v, args.preset, args.steps, args.batch, args.latent_frames, args.lr, args.yaw, args.sigma,
                        args.eval_every) for v in args.variants]
    result = {"setup": {k: v for k, v in vars(args).items() if k != "out"}, "runs": runs,
              "wall_s": round(time.perf_counter() - t0, 1), "machine": machine_info(load)}
    for r in runs:
        f = r["final"]
        print(f"{r['variant']:>8s}: after {f['step']} steps loss true {f['loss_true']:.4f} / negated "
              f"{f['loss_negated']:.4f} / zeroed {f['loss_zeroed']:.4f}: action_gain {f['action_gain']:+.3f}")
    write_result(args.out, result)
    return result


if __name__ == "__main__":
    main()
