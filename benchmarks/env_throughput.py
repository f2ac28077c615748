"""Env throughput: steps/s, player-frames/s, step latency and peak memory of the dream and the real envs.

    .venv/bin/python benchmarks/env_throughput.py                  # the shipped model, ~10-20 min on 2 CPU cores
    .venv/bin/python benchmarks/env_throughput.py --model test --quick     # smoke run

Writes ``benchmarks/results/env_throughput.json`` with one row per configuration, each measured in its own
process (so ``peak_rss_mb`` is that configuration's own peak resident memory, model and compiled programs
included):

* ``dream`` (``DreamParallelEnv``, B = 1) and ``vector`` (``DreamVectorEnv``, N worlds in one batched model
  call, SAME_STEP autoreset) on ``--model``: ``default`` (the shipped model, what the env loads when none
  is named), a checkpoint directory, or a preset name (random-init weights; speed does not depend on the
  weight values), and ``real`` (``RealParallelEnv``, the
  voxel engine at ``--real-resolution``).
* ``env_steps_per_s``: world-steps per second (a vector ``step`` call advances N worlds, so N x calls/s).
  One dream step is k = 4 engine ticks; one real step is one tick, so ``ticks_per_s`` compares them.
* ``player_frames_per_s``: frames generated or rendered per second over all players.
* ``step_latency_ms`` p50 / p99 of one ``step`` call (random actions, validation and host copies included;
  the vector env also converts batched actions per world).
* ``first_reset_s`` / ``first_step_s``: the first calls, JIT compilation included.

The machine is shared: the 1-minute load average before and after each row is recorded; above the core
count the numbers are noisy.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from solaris_env.paths import portable_text

RESULTS = Path(__file__).parent / "results" / "env_throughput.json"
WORLDS = (4, 16, 64)


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


def run_steps(step, steps: int) -> list[float]:
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        step()
        times.append(time.perf_counter() - t0)
    return times


def bench_parallel(env, steps: int, ticks_per_step: int) -> dict:
    """A ParallelEnv: first reset/step, then ``steps`` timed steps with random actions (resets excluded)."""
    t0 = time.perf_counter()
    env.reset(seed=0)
    first_reset = time.perf_counter() - t0
    for i, a in enumerate(env.possible_agents):
        env.action_space(a).seed(i)

    def step():
        if not env.agents:
            env.reset()
        env.step({a: env.action_space(a).sample() for a in env.agents})

    t0 = time.perf_counter()
    step()
    first_step = time.perf_counter() - t0
    run_steps(step, 3)  # warm-up
    times = run_steps(step, steps)
    mean = statistics.fmean(times)
    p = len(env.possible_agents)
    return {"first_reset_s": first_reset, "first_step_s": first_step, "timed_steps": steps,
            "env_steps_per_s": 1 / mean, "ticks_per_s": ticks_per_step / mean,
            "player_frames_per_s": p * ticks_per_step / mean,
            "step_latency_ms": {"p50": 1e3 * percentile(times, 50), "p99": 1e3 * percentile(times, 99)}}


def bench_vector(env, steps: int) -> dict:
    t0 = time.perf_counter()
    env.reset(seed=0)
    first_reset = time.perf_counter() - t0
    env.action_space.seed(0)
    t0 = time.perf_counter()
    env.step(env.action_space.sample())
    first_step = time.perf_counter() - t0
    run_steps(lambda: env.step(env.action_space.sample()), 2)  # warm-up
    times = run_steps(lambda: env.step(env.action_space.sample()), steps)
    mean = statistics.fmean(times)
    n, p, k = env.num_envs, env.num_players, env.frames_per_step
    return {"first_reset_s": first_reset, "first_step_s": first_step, "timed_steps": steps,
            "vector_steps_per_s": 1 / mean, "env_steps_per_s": n / mean, "ticks_per_s": n * k / mean,
            "player_frames_per_s": n * p * k / mean,
            "step_latency_ms": {"p50": 1e3 * percentile(times, 50), "p99": 1e3 * percentile(times, 99)}}


def load_model(name: str):
    """``default`` -> the shipped model; an existing directory -> that checkpoint; else a preset (random init)."""
    from solaris_env.dream_env import DEFAULT_CHECKPOINT
    from solaris_env.world_model.world_model import WorldModel

    if name == "default":
        return WorldModel.load(DEFAULT_CHECKPOINT), f"default ({DEFAULT_CHECKPOINT.name}, trained)"
    if Path(name).is_dir():
        return WorldModel.load(name), f"checkpoint {name}"
    return WorldModel.from_preset(name, seed=0), f"{name} (random-init weights)"


def measure(kind: str, worlds: int, model_name: str, steps: int, resolution: int) -> dict:
    """One configuration, in this process."""
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    if kind == "real":
        from solaris_env.real_env import RealParallelEnv

        env = RealParallelEnv(num_players=2, resolution=resolution, max_steps=1_000_000)
        build = time.perf_counter() - t0
        row = bench_parallel(env, steps, ticks_per_step=1)
        row["frame_size"] = [resolution, resolution]
    else:
        model, described = load_model(model_name)
        build = time.perf_counter() - t0
        if kind == "dream":
            from solaris_env.dream_env import DreamParallelEnv

            env = DreamParallelEnv(model=model, max_steps=1_000_000)
            row = bench_parallel(env, steps, ticks_per_step=model.frames_per_step)
        else:
            from solaris_env.vector_env import DreamVectorEnv

            env = DreamVectorEnv(worlds, model=model, max_steps=1_000_000)
            row = bench_vector(env, steps)
        row["frame_size"] = list(model.frame_shape[:2])
        row["model"] = described
    peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {"env": kind, "worlds": worlds, "build_s": build, **row, "peak_rss_mb": peak_kb / 1024,
            "load_avg_1m_before_after": [round(load_before, 2), round(os.getloadavg()[0], 2)]}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="default",
                        help="'default' (the shipped model), a checkpoint directory, or a preset name (random init)")
    parser.add_argument("--steps", type=int, default=60, help="timed steps at B = 1 (fewer for larger N)")
    parser.add_argument("--real-resolution", type=int, default=64)
    parser.add_argument("--worlds", type=int, nargs="+", default=list(WORLDS))
    parser.add_argument("--quick", action="store_true", help="few steps, N = 4 only (smoke run)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--one", help=argparse.SUPPRESS)  # internal: "kind:worlds", run in a child process
    args = parser.parse_args(argv)
    if args.one:
        kind, worlds = args.one.split(":")
        worlds = int(worlds)
        steps = max(5, args.steps // max(1, worlds // 4)) if kind == "vector" else args.steps
        print(json.dumps(measure(kind, worlds, args.model, steps, args.real_resolution)))
        return
    if args.quick:
        args.steps, args.worlds = 10, [4]
    configs = [("dream", 1), *(("vector", n) for n in args.worlds), ("real", 1)]
    load_before = os.getloadavg()
    rows = []
    for kind, worlds in configs:
        cmd = [sys.executable, "-m", "benchmarks.env_throughput", "--one", f"{kind}:{worlds}",
               "--model", args.model, "--steps", str(args.steps), "--real-resolution", str(args.real_resolution)]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True, cwd=Path(__file__).parent.parent)
        row = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(row)
        print(f"{kind:6s} N={worlds:3d}: {row['env_steps_per_s']:8.2f} env steps/s, "
              f"{row['player_frames_per_s']:8.1f} player-frames/s, p50 {row['step_latency_ms']['p50']:.1f} ms, "
              f"p99 {row['step_latency_ms']['p99']:.1f} ms, peak RSS {row['peak_rss_mb']:.0f} MB", flush=True)
    from benchmarks.machine import machine_info

    result = {"model": portable_text(args.model, parts=3), "note": "2-core CPU shared with other jobs: see the load averages",
              "rows": rows, "machine": machine_info(load_before)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n")
    os.replace(tmp, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
