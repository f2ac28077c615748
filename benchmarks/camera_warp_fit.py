"""Do the camera and walk warps move a model's latents the way the engine's turns and walks move them?

    .venv/bin/solaris-engine collect --out data/heldout64 --episodes 24 --world mixed --resolution 64 \\
        --seed 99 --instances 10 --test-fraction 1 --workers 2
    .venv/bin/python -m benchmarks.camera_warp_fit --data data/heldout64 --model default   # ~1 min

The camera warp (``DiTConfig.camera_warp``, docs/model.md §8.1) gives the DiT each frame's previous latent,
its content moved by the frame's camera turn at a fixed number of latent pixels per degree. That helps only
if the model's latents of a turning view really are the previous latents moved by that much. This benchmark
measures it on held-out engine clips (``duet/test``): the true latents (the VAE's normalised posterior means,
as the DiT is trained on them) and each latent frame's turn (``camera.frame_turns`` of the recorded mouse).

On the frames that turn about one axis only (yaw frames: |pitch| < 2 deg; pitch frames the other way round),
binned by the size of the turn (2-8, 8-20, 20-90 deg per latent frame), it reports the mean squared difference of the
next latent and the previous one moved by ``s * turn`` for a scan of ``s`` (latent pixels per degree): at
``s = 0`` (no warp), at the model's configured ``s``, and at the best ``s`` of the scan. The border ring of
latents is left out (new content enters there). Next to it, the same scan on the frames themselves (the
last frame of each latent chunk, grey, a border of one latent pixel's width left out, which also drops the
hotbar; pixels per degree divided by the VAE's spatial compression): the camera geometry the warp assumes,
and a check that the mouse is read at the right ticks.

The walk warp (``DiTConfig.walk_warp``) gets the same treatment on frames that walk without turning (forward
at walking and at sprinting speed, back, strafe; ``camera.frame_moves``), scanning eye heights per tick, and on
the engine's own frames from controlled walks (``engine_walk_fit``: one key held from five starts), which
checks the geometry itself.

A warp whose configured ``s`` scores above ``s = 0`` feeds the DiT a previous frame further from the truth than
no warp at all. Writes ``benchmarks/results/camera_warp_fit.json``.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results" / "camera_warp_fit.json"
BINS_DEG = ((2.0, 8.0), (8.0, 20.0), (20.0, 90.0))  # |turn| per latent frame
OTHER_AXIS_MAX_DEG = 2.0
# The scan in frame pixels per degree (-0.48 to 0.96 in steps of 0.08): at 8x spatial compression, -0.06 to 0.12
# latent pixels per degree in steps of 0.01. ``latent_scan`` divides it by the model's compression, so a 16x16
# latent (4x) scans -0.12 to 0.24 and its configured warp lies inside the scan.
FRAME_SCAN = tuple(np.round(np.arange(-6, 13) * 0.08, 2))


def latent_scan(compression: int) -> tuple[float, ...]:
    """The scan in latent pixels per degree for a VAE of this spatial compression."""
    return tuple(round(s / compression, 4) for s in FRAME_SCAN)


def shift_frames(x_NhwC: np.ndarray, shift_N2: np.ndarray) -> np.ndarray:
    """Move each frame's content by (down, right) pixels (``camera.shift_latents``: linear interpolation,
    edges repeated)."""
    import jax.numpy as jnp

    from solaris_env.world_model import camera

    return np.asarray(camera.shift_latents(jnp.asarray(x_NhwC, jnp.float32), jnp.asarray(shift_N2, jnp.float32)))


def scan_errors(prev_NhwC: np.ndarray, next_NhwC: np.ndarray, turns_N: np.ndarray, axis: int,
                scales: Sequence[float], border: int = 1) -> np.ndarray:
    """(len(scales),) mean squared difference of ``next`` and ``prev`` moved by ``scale * turn`` along ``axis``
    (0 = down, for pitch; 1 = right, for yaw), a ring of ``border`` pixels excluded."""
    out = []
    for s in scales:
        shift = np.zeros((len(turns_N), 2), np.float32)
        shift[:, axis] = s * turns_N
        d = shift_frames(prev_NhwC, shift) - next_NhwC
        out.append(float(np.mean(d[:, border:-border, border:-border] ** 2)))
    return np.asarray(out)


def select(turns_N2: np.ndarray, axis: str, lo: float, hi: float) -> np.ndarray:
    """(N,) bool: frames turning ``lo <= |turn| < hi`` degrees about ``axis`` ('yaw' or 'pitch') only."""
    i = 0 if axis == "yaw" else 1
    this, other = np.abs(turns_N2[:, i]), np.abs(turns_N2[:, 1 - i])
    return (this >= lo) & (this < hi) & (other < OTHER_AXIS_MAX_DEG)


def fit(prev_NhwC: np.ndarray, next_NhwC: np.ndarray, turns_N2: np.ndarray, configured: tuple[float, float],
        scales: Sequence[float], bins: Sequence[tuple[float, float]] = BINS_DEG, border: int = 1) -> dict:
    """Per axis and bin of turn size: frames, and the mean error at no warp, the configured warp and the best
    scale of the scan. ``turns_N2`` is [yaw (+ left), pitch (+ up)] degrees; a left turn moves content right
    and looking up moves it down (``camera.content_shift``), so both scales are positive when right.
    ``configured`` is (pitch, yaw) pixels per degree, as ``DiTConfig.camera_warp``."""
    scales = list(scales)
    out = {}
    for axis, shift_axis, conf in (("yaw", 1, configured[1]), ("pitch", 0, configured[0])):
        rows = []
        for lo, hi in bins:
            sel = select(turns_N2, axis, lo, hi)
            row = {"turn_deg": [lo, hi], "frames": int(sel.sum())}
            if sel.any():
                turn = turns_N2[sel, 0 if axis == "yaw" else 1]
                errs = scan_errors(prev_NhwC[sel], next_NhwC[sel], turn, shift_axis, scales + [0.0, conf], border)
                best = int(np.argmin(errs[:len(scales)]))
                row.update({"mse_no_warp": round(float(errs[-2]), 4), "mse_configured": round(float(errs[-1]), 4),
                            "best_per_degree": float(scales[best]), "mse_best": round(float(errs[best]), 4),
                            "configured_helps": bool(errs[-1] < errs[-2])})
            rows.append(row)
        out[axis] = {"configured_per_degree": conf, "bins": rows}
    return out


WALK_SCAN = (0.0, 0.033, 0.067, 0.1, 0.133, 0.167, 0.2, 0.267)  # eye heights per tick (DiTConfig.walk_warp)
WALK_BINS = (("forward", 0, 2.0, 4.5), ("forward", 0, 4.5, 9.0), ("back", 0, -9.0, -2.0),
             ("strafe", 1, 2.0, 9.0))  # name, axis of camera.frame_moves, range of ticks walked
STILL_MAX = 0.5  # ticks walked on the other axis of a walking frame


def walk_frames(prev_NhwC: np.ndarray, next_NhwC: np.ndarray, moves_N2: np.ndarray, turns_N2: np.ndarray,
                configured: float, scales: Sequence[float] = WALK_SCAN, border: int = 1) -> list[dict]:
    """Per kind of walk (``WALK_BINS``; frames that turn less than ``OTHER_AXIS_MAX_DEG`` about both axes, a
    strafe counted either way): frames, and the mean squared difference of ``next`` and ``prev`` walked by
    ``s * moves`` (``camera.walk_latents``) at no walk, at ``configured`` and at the best ``s`` of the scan."""
    import jax.numpy as jnp

    from solaris_env.world_model import camera

    still = np.all(np.abs(turns_N2) < OTHER_AXIS_MAX_DEG, axis=1)
    rows = []
    for name, axis, lo, hi in WALK_BINS:
        amount = np.abs(moves_N2[:, axis]) if name == "strafe" else moves_N2[:, axis]
        sel = still & (amount >= lo) & (amount < hi) & (np.abs(moves_N2[:, 1 - axis]) < STILL_MAX)
        row = {"walk": name, "ticks": [lo, hi], "frames": int(sel.sum())}
        if sel.any():
            errs = []
            for s in list(scales) + [configured]:
                moved = camera.walk_latents(jnp.asarray(prev_NhwC[sel], jnp.float32),
                                            jnp.asarray(s * moves_N2[sel], jnp.float32))
                d = np.asarray(moved) - next_NhwC[sel]
                errs.append(float(np.mean(d[:, border:-border, border:-border] ** 2)))
            best = int(np.argmin(errs[:-1]))
            row.update({"mse_no_walk": round(errs[0], 4), "mse_configured": round(errs[-1], 4),
                        "best_per_tick": float(scales[best]), "mse_best": round(errs[best], 4),
                        "configured_helps": bool(errs[-1] < errs[0])})
        rows.append(row)
    return rows


ENGINE_WALKS = (("forward", 0, 1.0), ("back", 0, -1.0), ("right", 1, 1.0))  # key, move axis, sign
ENGINE_STARTS = ((11, "flat"), (13, "flat"), (15, "flat"), (12, "normal"), (14, "normal"))  # reset seed, world


def engine_walk_fit(steps: int = 10, warmup: int = 3, scales: Sequence[float] = WALK_SCAN,
                    starts: Sequence[tuple[int, str]] = ENGINE_STARTS) -> list[dict]:
    """The walk geometry on the engine's own frames: player 0 holds one movement key from each start
    (``ENGINE_STARTS``, k = 4 ticks per step, the partner standing), and from step ``warmup`` on (top speed)
    each step's grey frame is compared with the previous one walked by ``s * 4`` ticks (``camera.walk_latents``,
    a border of 4 pixels left out). The scale that fits best is what ``walk_warp`` should be if the latents
    followed the frames."""
    import jax.numpy as jnp

    from solaris_env.real_env import RealParallelEnv
    from solaris_env.spaces import noop
    from solaris_env.world_model import camera

    rows = []
    for key, axis, sign in ENGINE_WALKS:
        prev, nxt = [], []
        for seed, world in starts:
            env = RealParallelEnv(world=world, ticks_per_step=4)
            obs, _ = env.reset(seed=seed)
            me = env.possible_agents[0]
            grey = [obs[me].astype(np.float32).mean(-1)]
            for _ in range(steps):
                act = {a: noop() for a in env.possible_agents}
                act[me][key] = 1
                obs, *_ = env.step(act)
                grey.append(obs[me].astype(np.float32).mean(-1))
            prev += grey[warmup:-1]
            nxt += grey[warmup + 1:]
        p_, q = np.stack(prev)[..., None], np.stack(nxt)
        errs = []
        for s in scales:
            move = np.zeros((len(p_), 2), np.float32)
            move[:, axis] = sign * 4 * s
            walked = np.asarray(camera.walk_latents(jnp.asarray(p_), jnp.asarray(move)))[..., 0]
            errs.append(float(np.mean((walked - q)[:, 4:-4, 4:-4] ** 2)))
        best = int(np.argmin(errs))
        rows.append({"key": key, "frames": len(q), "mse_no_walk": round(errs[0], 1),
                     "best_per_tick": float(scales[best]), "mse_best": round(errs[best], 1),
                     "mse_per_scale": dict(zip(map(str, scales), (round(e, 1) for e in errs)))})
    return rows


def clips(data_dir: str | Path, model, segments: int, steps: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Held-out clips through the model's VAE: per latent frame f >= 1 of every clip and player, the previous
    and next latent (N, h, w, C), the last frame of each latent chunk in grey (N, H, W) before and after, and
    the turn (N, 2)."""
    import jax.numpy as jnp

    from solaris_env.world_model import camera
    from solaris_env.world_model.action_module import action_windows
    from training.duet import DuetDataset
    from training.evaluate import _segments
    from training.step import prepare_batch

    cfg = model.config
    k = model.frames_per_step
    dataset = DuetDataset(data_dir, "test", obs_size=(cfg.frame_height, cfg.frame_width))
    seg = _segments(dataset, 1 + k * steps, segments, seed)
    if seg is None:
        raise SystemExit(f"--data: no held-out episode in {data_dir}/duet/test holds {1 + k * steps} frames")
    _, vae, image_encoder = model.modules()[:3]
    batch = prepare_batch(vae, image_encoder, jnp.asarray(seg["obs"]), jnp.asarray(seg["act"]), cfg)
    x0 = np.asarray(batch["x0"], np.float32)  # (B, P, F, h, w, C)
    turns = np.asarray(camera.frame_turns(action_windows(batch["mouse"], cfg, x0.shape[2]), k))  # (B, P, F, 2)
    moves = np.asarray(camera.frame_moves(action_windows(batch["keyboard"], cfg, x0.shape[2]), k))
    grey = seg["obs"][:, ::k].astype(np.float32).mean(axis=-1).swapaxes(1, 2)  # (B, P, F, H, W)
    flat = lambda a: a[:, :, 1:].reshape((-1,) + a.shape[3:])
    before = lambda a: a[:, :, :-1].reshape((-1,) + a.shape[3:])
    return {"prev": before(x0), "next": flat(x0), "grey_prev": before(grey), "grey_next": flat(grey),
            "turns": flat(turns), "moves": flat(moves), "compression": cfg.frame_height // x0.shape[3]}


def run(model, data_dir: str | Path, segments: int, steps: int) -> dict:
    c = clips(data_dir, model, segments, steps)
    configured = tuple(model.config.dit.camera_warp)
    latent = fit(c["prev"], c["next"], c["turns"], configured, latent_scan(c["compression"]))
    pixel_scales = list(FRAME_SCAN)  # the same scan in frame pixels per degree
    pixel = fit(c["grey_prev"][..., None], c["grey_next"][..., None], c["turns"],
                tuple(v * c["compression"] for v in configured), pixel_scales, border=c["compression"])
    for axis in pixel.values():  # report in latent pixels per degree, as the warp is configured
        axis["configured_per_degree"] = round(axis["configured_per_degree"] / c["compression"], 4)
        for row in axis["bins"]:
            if "best_per_degree" in row:
                row["best_per_degree"] = round(row["best_per_degree"] / c["compression"], 4)
    walk = float(model.config.dit.walk_warp)
    cmp = c["compression"]
    walking = {"latents": walk_frames(c["prev"], c["next"], c["moves"], c["turns"], walk),
               "frames": walk_frames(c["grey_prev"][..., None], c["grey_next"][..., None], c["moves"], c["turns"],
                                     walk, border=cmp),
               "engine": engine_walk_fit()}
    return {"latent_frames": len(c["turns"]), "spatial_compression": int(cmp),
            "camera_warp": list(configured), "latents": latent, "frames": pixel,
            "walk_warp": walk, "walking": walking}


def _line(name: str, space: str, span: str, row: dict, no_key: str, best_key: str) -> str:
    return (f"{name:8s} {space:7s} {span:10s} {row['frames']:6d} {row[no_key]:12.4f} {row['mse_configured']:15.4f} "
            f"{row[best_key]:7.3f} {row['mse_best']:10.4f}  {row['configured_helps']}")


def table(result: dict) -> str:
    lines = ["axis     space    turn deg   frames  mse no warp  mse configured  best s   mse best  configured helps"]
    for name, space in (("latents", "latent"), ("frames", "frame")):
        for axis, a in result[name].items():
            lines += [_line(axis, space, "{:.0f}-{:.0f}".format(*row["turn_deg"]), row, "mse_no_warp", "best_per_degree")
                      for row in a["bins"] if row["frames"]]
    lines.append("walk     space    ticks      frames  mse no walk  mse configured  best s   mse best  configured helps")
    for space in ("latents", "frames"):
        lines += [_line(row["walk"], space[:-1], "{:.1f}-{:.1f}".format(*row["ticks"]), row, "mse_no_walk",
                        "best_per_tick") for row in result["walking"][space] if row["frames"]]
    lines.append("engine walks (grey frames, top speed): " + ", ".join(
        f"{r['key']} best {r['best_per_tick']} (mse {r['mse_no_walk']} -> {r['mse_best']}, {r['frames']} frames)"
        for r in result["walking"]["engine"]))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m benchmarks.camera_warp_fit", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="default", help="default, a model directory or preset:NAME")
    p.add_argument("--data", required=True, help="a collect with held-out episodes (duet/test)")
    p.add_argument("--segments", type=int, default=16, help="held-out clips (both players each)")
    p.add_argument("--steps", type=int, default=32, help="env steps (latent frames after the first) per clip")
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    from benchmarks.dream_fidelity import load_model, model_label
    from benchmarks.machine import machine_info, write_result
    from solaris_env.paths import portable_path

    load = os.getloadavg()
    t0 = time.perf_counter()
    model = load_model(args.model)
    if not model.config.dit.camera_warp_enabled:
        print("the model has no camera warp: its configured scale reads as 0 (the best scale is still fitted)")
    result = {"benchmark": "camera_warp_fit", "model": model_label(args.model), "data": portable_path(args.data),
              "segments": args.segments, "steps": args.steps, **run(model, args.data, args.segments, args.steps)}
    result["table"] = table(result)
    result["seconds"] = round(time.perf_counter() - t0, 1)
    result["machine"] = machine_info(load)
    print(result["table"])
    write_result(args.out, result)
    return result


if __name__ == "__main__":
    main()
