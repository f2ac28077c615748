"""Does the dream move when the player acts? The frame change an action causes, dream env vs real engine.

    .venv/bin/python -m benchmarks.action_response                       # the shipped model, ~2 min
    .venv/bin/python -m benchmarks.action_response --checkpoint runs/x/self-forcing/model

From the same engine start states (``agents.common.make_start_states``: the players a few blocks apart), each
env plays ``--steps`` steps twice: once with the learner holding a probe action (a yaw turn of ``--yaw-deg``
per step; holding ``forward``), once doing nothing. The response at step s is the mean absolute difference
(0-255 grey levels) between the learner's two observations: how much the action changed what the player sees.
In the real engine a 10-degree turn shifts a 64-pixel view by ~9 pixels; a world model that ignores the
camera answers ~0. The agreement is the correlation over pixels of the dream's change with the engine's
change: a dream that turns the wrong way changes as much but scores < 0. This is what RL in the dream and policy evaluation need (``agents/``: a face-the-partner
policy is a camera policy). Writes ``benchmarks/results/action_response.json``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

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


def action_effects(env, starts, probe: str, yaw_deg: float, steps: int, seed: int) -> np.ndarray:
    """(starts, steps, H, W, 3) obs(action) - obs(noop): what the probe action changed, per start state."""
    from solaris_env.spaces import noop

    return np.stack([(learner_frames(env, s, probe_action(probe, yaw_deg), steps, seed)
                      - learner_frames(env, s, noop(), steps, seed))[1:] for s in starts])


def response(effects: np.ndarray) -> np.ndarray:
    """(steps,) mean |obs(action) - obs(noop)| per step, averaged over the start states."""
    return np.abs(effects).mean(axis=(0, 2, 3, 4))


def agreement(dream_effects: np.ndarray, real_effects: np.ndarray) -> np.ndarray:
    """(steps,) Pearson correlation over pixels (and start states) of the dream's and the engine's action
    effects: > 0 when the dream changes the view the way the engine does (a turn the wrong way scores < 0,
    however large its ``response``)."""
    d = dream_effects.transpose(1, 0, 2, 3, 4).reshape(dream_effects.shape[1], -1)
    r = real_effects.transpose(1, 0, 2, 3, 4).reshape(real_effects.shape[1], -1)
    d, r = d - d.mean(axis=1, keepdims=True), r - r.mean(axis=1, keepdims=True)
    return (d * r).sum(axis=1) / np.maximum(np.sqrt((d * d).sum(axis=1) * (r * r).sum(axis=1)), 1e-9)


def run(checkpoint: str | None, preset: str | None, episodes: int, steps: int, yaw_deg: float,
        seed: int = 0, start_seed: int = 100000, action_guidance: float | None = None) -> dict:
    from agents.common import make_start_states
    from solaris_env.dream_env import DreamParallelEnv, build_model
    from solaris_env.real_env import RealParallelEnv

    if episodes < 1 or steps < 1:
        raise ValueError(f"episodes and steps must be >= 1, got {episodes}, {steps}")
    model = build_model(checkpoint, preset, num_players=2)
    if action_guidance is not None:  # SamplerConfig.action_guidance
        import dataclasses
        model = model.with_sampler(dataclasses.replace(model.config.sampler, action_guidance=action_guidance))
    height, width, _ = model.frame_shape
    envs = {"real": RealParallelEnv(num_players=2, world="flat", resolution=(height, width), max_steps=steps,
                                    ticks_per_step=model.frames_per_step),
            "dream": DreamParallelEnv(model=model, max_steps=steps)}
    starts = make_start_states(episodes, start_seed, "flat", (height, width))
    result = {"probes": {}}
    for probe in PROBES:
        row, effects = {}, {}
        for name, env in envs.items():
            t0 = time.perf_counter()
            effects[name] = action_effects(env, starts, probe, yaw_deg, steps, seed)
            r = response(effects[name])
            row[name] = {"by_step": [round(float(v), 3) for v in r], "mean": float(r.mean()),
                         "wall_s": round(time.perf_counter() - t0, 1)}
        row["dream_over_real"] = row["dream"]["mean"] / max(row["real"]["mean"], 1e-9)
        a = agreement(effects["dream"], effects["real"])
        row["agreement"] = {"by_step": [round(float(v), 3) for v in a], "mean": float(a.mean())}
        result["probes"][probe] = row
    result["setup"] = {"episodes": episodes, "steps": steps, "yaw_deg_per_step": yaw_deg,
                       "frames_per_step": model.frames_per_step, "frame_size": [height, width], "world": "flat",
                       "start_seed": start_seed, "seed": seed,
                       "action_guidance": model.config.sampler.action_guidance,
                       "world_model": checkpoint or (f"preset {preset} (random init)" if preset else "shipped default")}
    return result


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m benchmarks.action_response", description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", default=None, help="a model directory (default: the shipped model)")
    p.add_argument("--preset", default=None, help="random-init weights of this preset instead (smoke runs)")
    p.add_argument("--episodes", type=int, default=4, help="start states")
    p.add_argument("--steps", type=int, default=12, help="env steps per rollout")
    p.add_argument("--yaw-deg", type=float, default=10.0, help="yaw turn per step of the yaw probe (degrees)")
    p.add_argument("--action-guidance", type=float, default=None,
                   help="sample the dream with this action guidance (SamplerConfig.action_guidance; default: the model's)")
    p.add_argument("--out", default=str(RESULTS))
    args = p.parse_args(argv)
    from benchmarks.machine import machine_info, write_result

    load = os.getloadavg()
    t0 = time.perf_counter()
    result = run(args.checkpoint, args.preset, args.episodes, args.steps, args.yaw_deg,
                 action_guidance=args.action_guidance)
    result["wall_s"] = round(time.perf_counter() - t0, 1)
    result["machine"] = machine_info(load)
    for probe, row in result["probes"].items():
        print(f"{probe:>8s}: real {row['real']['mean']:6.2f}  dream {row['dream']['mean']:6.2f}  "
              f"(dream/real {row['dream_over_real']:.2f}; grey levels of change per step, {args.steps} steps); "
              f"agreement with the engine's change {row['agreement']['mean']:+.2f}")
    write_result(args.out, result)
    return result


if __name__ == "__main__":
    main()
