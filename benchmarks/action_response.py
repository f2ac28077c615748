"""Does the dream move when the player acts? The frame change an action causes, dream env vs real engine.

    .venv/bin/python -m benchmarks.action_response                       # the shipped model, ~2 min
    .venv/bin/python -m benchmarks.action_response --checkpoint runs/x/self-forcing/model

From the same engine start states (``agents.common.make_start_states``: the players a few blocks apart), each
env plays ``--steps`` steps twice: once with the learner holding a probe action (a yaw turn of ``--yaw-deg``
per step; holding ``forward``), once doing nothing. The response at step s is the mean absolute difference
(0-255 grey levels) between the learner's two observations: how much the action changed what the player sees.
In the real engine a 10-degree turn shifts a 64-pixel view by ~4.5 pixels at its centre (~102° across); a world
model that ignores the camera answers ~0. For the turn it also estimates how far the view's content moves from
step to step (pixels, + = right; the probe turns right, so the engine's content moves left): a dream that changes
a lot but turns the wrong way, or just churns, shows in that number. This is what RL in the dream and policy
evaluation need (``agents/``: a face-the-partner policy is a camera policy). Writes
``benchmarks/results/action_response.json``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from solaris_env.paths import portable_path

RESULTS = Path(__file__).parent / "results" / "action_response.json"
PROBES = ("yaw", "forward")


def probe_action(probe: str, yaw_deg: float) -> dict:
    from solaris_env.spaces import CAMERA_KEY, noop

    action = noop()
    if probe == "yaw":
        action[CAMERA_KEY] = np.array([0.0, yaw_deg], np.float32)  # [dpitch, dyaw] degrees
    elif probe == "forward":
        action["forward"] = 1
    else:
        raise ValueError(f"probe must be one of {PROBES}, got {probe!r}")
    return action


def learner_frames(env, start, action: dict, steps: int, seed: int) -> np.ndarray:
    """(steps + 1, H, W, 3) float32 observations of the learner holding ``action`` (the partner idle)."""
    from solaris_env.spaces import noop

    learner, partner = env.possible_agents
    obs, _ = env.reset(seed=seed, options={"engine_state": start})
    frames = [obs[learner]]
    for _ in range(steps):
        obs, *_ = env.step({learner: action, partner: noop()})
        frames.append(obs[learner])
    return np.stack(frames).astype(np.float32)


def rollouts(env, starts, probe: str, yaw_deg: float, steps: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(starts, steps + 1, H, W, 3) observations holding the probe action, and doing nothing."""
    from solaris_env.spaces import noop

    acting = np.stack([learner_frames(env, s, probe_action(probe, yaw_deg), steps, seed) for s in starts])
    still = np.stack([learner_frames(env, s, noop(), steps, seed) for s in starts])
    return acting, still


def response(acting: np.ndarray, still: np.ndarray) -> np.ndarray:
    """(steps,) mean |obs(action) - obs(noop)| per step, averaged over the start states."""
    return np.abs(acting - still)[:, 1:].mean(axis=(0, 2, 3, 4))


def _blur(grey_HW: np.ndarray) -> np.ndarray:
    """Two passes of the separable [1, 2, 1] / 4 filter (wrap-around), textures out, shapes kept."""
    for _ in range(2):
        for axis in (0, 1):
            grey_HW = (np.roll(grey_HW, 1, axis) + 2 * grey_HW + np.roll(grey_HW, -1, axis)) / 4
    return grey_HW


def horizontal_shift(before_HW3: np.ndarray, after_HW3: np.ndarray, max_px: int = 10) -> int:
    """The whole-pixel shift d (+ = content moved right) that best maps ``before`` onto ``after`` (blurred grey,
    columns compared away from the wrapped edges)."""
    b, a = _blur(before_HW3.mean(axis=-1)), _blur(after_HW3.mean(axis=-1))
    cols = slice(max_px + 2, b.shape[1] - max_px - 2)
    errors = [np.mean((np.roll(b, d, axis=1)[:, cols] - a[:, cols]) ** 2) for d in range(-max_px, max_px + 1)]
    return int(np.argmin(errors)) - max_px


def yaw_shift(acting: np.ndarray) -> np.ndarray:
    """(steps,) mean horizontal shift (pixels, + = right) from each frame to the next of the turning rollouts:
    a left turn moves the view's content right (engine: ~0.45 px per degree at the centre), so a dream that
    turns the wrong way has the opposite sign however large its ``response``; starts that show no edge score 0."""
    return np.asarray([[horizontal_shift(r[t - 1], r[t]) for t in range(1, r.shape[0])] for r in acting]).mean(axis=0)


def run(checkpoint: str | None, preset: str | None, episodes: int, steps: int, yaw_deg: float,
        seed: int = 0, start_seed: int = 100000, world: str = "flat") -> dict:
    from agents.common import make_start_states
    from solaris_env.dream_env import DreamParallelEnv, build_model
    from solaris_env.real_env import RealParallelEnv

    if episodes < 1 or steps < 1:
        raise ValueError(f"episodes and steps must be >= 1, got {episodes}, {steps}")
    model = build_model(checkpoint, preset, num_players=2)
    height, width, _ = model.frame_shape
    envs = {"real": RealParallelEnv(num_players=2, world=world, resolution=(height, width), max_steps=steps,
                                    ticks_per_step=model.frames_per_step),
            "dream": DreamParallelEnv(model=model, max_steps=steps)}
    starts = make_start_states(episodes, start_seed, world, (height, width))
    result = {"probes": {}}
    for probe in PROBES:
        row = {}
        for name, env in envs.items():
            t0 = time.perf_counter()
            acting, still = rollouts(env, starts, probe, yaw_deg, steps, seed)
            r = response(acting, still)
            row[name] = {"by_step": [round(float(v), 3) for v in r], "mean": float(r.mean()),
                         "wall_s": round(time.perf_counter() - t0, 1)}
            if probe == "yaw":
                shift = yaw_shift(acting)
                row[name]["shift_px_by_step"] = [round(float(v), 2) for v in shift]
                row[name]["shift_px"] = float(shift.mean())
        row["dream_over_real"] = row["dream"]["mean"] / max(row["real"]["mean"], 1e-9)
        result["probes"][probe] = row
    result["setup"] = {"episodes": episodes, "steps": steps, "yaw_deg_per_step": yaw_deg,
                       "frames_per_step": model.frames_per_step, "frame_size": [height, width], "world": world,
                       "start_seed": start_seed, "seed": seed,
                       "world_model": portable_path(checkpoint, parts=3) if checkpoint else (
                           f"preset {preset} (random init)" if preset else "shipped default")}
    return result


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m benchmarks.action_response", description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", default=None, help="a model directory (default: the shipped model)")
    p.add_argument("--preset", default=None, help="random-init weights of this preset instead (smoke runs)")
    p.add_argument("--episodes", type=int, default=4, help="start states")
    p.add_argument("--steps", type=int, default=12, help="env steps per rollout")
    p.add_argument("--yaw-deg", type=float, default=10.0, help="yaw turn per step of the yaw probe (degrees)")
    p.add_argument("--world", default="flat", choices=("flat", "mixed"),
                   help="engine world of the start states (mixed has more edges for the shift estimate)")
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    from benchmarks.machine import machine_info, write_result

    load = os.getloadavg()
    t0 = time.perf_counter()
    result = run(args.checkpoint, args.preset, args.episodes, args.steps, args.yaw_deg, world=args.world)
    result["wall_s"] = round(time.perf_counter() - t0, 1)
    result["machine"] = machine_info(load)
    for probe, row in result["probes"].items():
        print(f"{probe:>8s}: real {row['real']['mean']:6.2f}  dream {row['dream']['mean']:6.2f}  "
              f"(dream/real {row['dream_over_real']:.2f}; grey levels of change per step, {args.steps} steps)")
    yaw = result["probes"]["yaw"]
    print(f"     yaw: view content moves {yaw['real']['shift_px']:+.2f} px per step in the engine, "
          f"{yaw['dream']['shift_px']:+.2f} in the dream")
    write_result(args.out, result)
    return result


if __name__ == "__main__":
    main()
