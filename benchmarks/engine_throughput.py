"""Engine throughput: renderer frames/s (one view per call vs batched) and collect speed vs real time.

    .venv/bin/python benchmarks/engine_throughput.py            # ~2-3 min on 2 CPU cores
    .venv/bin/python benchmarks/engine_throughput.py --quick    # fewer timed calls / episodes

Writes ``benchmarks/results/engine_throughput.json``:

* ``frames_per_s.{single,batched}_{64,128}``: views rendered per second for a realistic two-player
  scene: the first 512 views (256 ticks x 2 players, each seeing the other) of a recorded walkLook
  episode, after a warm-up call that compiles the shape; median over repeated passes. ``single`` = 1 view per call,
  ``batched`` = the views per call that ``collect`` uses at that resolution (``cli.auto_chunk_ticks`` x
  2 players). The headline figure is the equal-split (flat / normal world, like the paper's data)
  harmonic mean; ``by_world`` has each world and ``sweep_64`` the batch-size curve.
* ``collect_realtime_factor_64``: seconds of recorded gameplay (ticks / 20, per episode, both players
  at once) per wall-clock second of ``solaris-engine collect --world mixed --resolution 64 --workers 1``
  (simulation, rendering, ground truth, mp4 encoding, JSON writing), after a 1-episode warm-up collect
  in the same process (so jit compilation of the main shape is excluded; ``collect_cold_*`` includes it).

Targets: >= 500 frames/s batched at 64x64; collection >= 10x real time.

    .venv/bin/python benchmarks/engine_throughput.py --backend minecraft [--quick]   # ~4 min (quick ~1 min)

writes ``benchmarks/results/engine_throughput_minecraft.json`` instead (needs ``solaris-engine
setup-minecraft``; one bot pair at a time): ``env`` = ``MinecraftParallelEnv`` at 64 and
128, and at 64 with ticks_per_step=4 (env steps/s, frames/s, CPU cores per pair = CPU seconds of Node +
server + Xvfb over wall time, Python's CPU, and how many steps kept real time) and ``recorder`` =
``record.js`` rotationEval episodes at 128x128.
Real time caps both at 20 ticks/s = 40 frames/s per pair.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.machine import machine_info, write_result

from solaris_env.engine import cli
from solaris_env.engine.bots.runner import EpisodeConfig, run_episode
from solaris_env.engine.capture import views_at_ticks

RESULTS = Path(__file__).parent / "results" / "engine_throughput.json"
SCENE = dict(seed=0, instance=0, episode=0, episode_type="walkLook")
WORLDS = ("flat", "normal")
SWEEP_VIEWS = (1, 16, 64, 256)
TOTAL_VIEWS = 512  # the same views (256 ticks x 2 players) are rendered for every batch size


def scene(world: str):
    out = run_episode(EpisodeConfig(world_kind=world, **SCENE))
    voxels_KXYZ, world_idx_T = out.trace.snapshots(0, out.trace.num_ticks)
    return out.trace, voxels_KXYZ, world_idx_T


def time_views(renderer, trace, voxels_KXYZ, world_idx_T, views_per_call: int, total_views: int,
               repeats: int) -> float:
    """Frames/s rendering the same ``total_views`` views (ticks 0.., both players) ``views_per_call`` at a
    time; the median over ``repeats`` passes, after a warm-up call that compiles the shape."""
    P = len(trace.player_names)
    ticks_N = np.arange(total_views // P) % trace.num_ticks
    views = views_at_ticks(trace, ticks_N, world_idx_T[ticks_N])
    calls = [type(views)(**{k: v[i : i + views_per_call] for k, v in vars(views).items()})
             for i in range(0, total_views, views_per_call)]
    renderer.render(voxels_KXYZ, trace.origin, calls[0])  # compile this shape
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for v in calls:
            renderer.render(voxels_KXYZ, trace.origin, v)
        rates.append(total_views / (time.perf_counter() - t0))
    return statistics.median(rates)


def render_rates(resolution: int, total_views: int, repeats: int, sweep: bool) -> dict:
    renderer = cli.get_renderer(resolution, resolution)
    batch = cli.auto_chunk_ticks(resolution, resolution) * 2
    by_world = {}
    for world in WORLDS:
        trace, vox, idx = scene(world)
        rate = {n: time_views(renderer, trace, vox, idx, n, total_views, repeats)
                for n in sorted({1, batch, *(SWEEP_VIEWS if sweep else ())})}
        by_world[world] = {"single": rate[1], "batched": rate[batch]}
        if sweep:
            by_world[world]["sweep"] = {str(n): r for n, r in rate.items()}
    harmonic = {k: len(WORLDS) / sum(1.0 / by_world[w][k] for w in WORLDS) for k in ("single", "batched")}
    return {"batch_views": batch, "by_world": by_world, **harmonic}


def collect_rate(episodes: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        args = ["--resolution", "64", "--world", "mixed", "--workers", "1"]
        t0 = time.perf_counter()
        cli.main(["collect", "--out", f"{tmp}/warm", "--episodes", "1", "--seed", "1000", *args])
        cold_s = time.perf_counter() - t0
        cold_ticks = sum(len(json.loads(p.read_text())) for p in Path(tmp, "warm").rglob("*_Alpha_*.json")
                         if not p.name.endswith("_episode_info.json"))
        t0 = time.perf_counter()
        status = cli.main(["collect", "--out", f"{tmp}/timed", "--episodes", str(episodes), "--seed", "0", *args])
        wall = time.perf_counter() - t0
        ticks = [len(json.loads(p.read_text())) for p in Path(tmp, "timed").rglob("*_Alpha_*.json")
                 if not p.name.endswith("_episode_info.json")]
        mp4_bytes = sum(p.stat().st_size for p in Path(tmp, "timed").rglob("*.mp4"))
    if status != 0 or len(ticks) != episodes:
        raise RuntimeError(f"collect failed (status {status}, {len(ticks)}/{episodes} episodes)")
    return {"realtime_factor": sum(ticks) / 20 / wall, "cold_realtime_factor": cold_ticks / 20 / cold_s,
            "episodes": episodes, "ticks": ticks, "wall_s": wall, "mp4_bytes": mp4_bytes}


def _proc_cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


MC_ENV_TICKS = 600  # 30 s of real time per configuration (--quick: 200)
MC_ENV_CONFIGS = ((64, 1), (128, 1), (64, 4))  # (resolution, ticks_per_step); --quick: the first only


def minecraft_env_rate(resolution: int, ticks_per_step: int, ticks: int) -> dict:
    """``MinecraftParallelEnv`` (one bot pair) stepped for ``ticks`` game ticks by a random
    policy answering at once: env steps/s, frames/s (both players), the step-timing counters, and CPU
    cores used (process CPU time over wall time) by the bridge (Node: both bots + views), the server and
    Xvfb together, and by this Python process (frame resampling, ground truth, the protocol)."""
    import resource

    from solaris_env.minecraft_env import MinecraftParallelEnv

    steps = ticks // ticks_per_step
    env = MinecraftParallelEnv(resolution=resolution, max_steps=steps + 1, ticks_per_step=ticks_per_step)
    try:
        t0 = time.perf_counter()
        env.reset(seed=0)
        start_s = time.perf_counter() - t0
        env.step({a: env.action_space(a).sample() for a in env.agents})  # the first step after reset idles
        cpu0, py0 = env.bridge.cpu_seconds(), resource.getrusage(resource.RUSAGE_SELF)
        t0 = time.perf_counter()
        timings = []
        for _ in range(steps):
            _, _, _, _, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
            timings.append(infos["Alpha"]["timing"])
        wall = time.perf_counter() - t0
        cpu1, py1 = env.bridge.cpu_seconds(), resource.getrusage(resource.RUSAGE_SELF)
        P = env.num_players
    finally:
        env.close()
    by_proc = {name: round((cpu1[name] - cpu0[name]) / wall, 3) for name in cpu1}
    py_cpu = (py1.ru_utime + py1.ru_stime) - (py0.ru_utime + py0.ru_stime)
    return {"resolution": resolution, "ticks_per_step": ticks_per_step, "players": P, "steps": steps,
            "wall_s": round(wall, 2),
            "start_and_first_reset_s": round(start_s, 1),
            "env_steps_per_s": round(steps / wall, 2), "frames_per_s": round(P * steps * ticks_per_step / wall, 1),
            "cpu_cores_pair": round(sum(by_proc.values()), 3), "cpu_cores_by_process": by_proc,
            "cpu_cores_python": round(py_cpu / wall, 3),
            "realtime_steps_fraction": round(sum(t["realtime"] for t in timings) / steps, 3),
            "idle_ticks": sum(t["idle_ticks"] for t in timings),
            "catchup_ticks": sum(t["catchup_ticks"] + t["idle_catchup_ticks"] for t in timings),
            "dropped_ticks": sum(t["dropped_ticks"] for t in timings),
            "late_ms_max": max(max(t["late_ms"]) for t in timings)}


def minecraft_recorder_rate(tmp: str, quick: bool) -> list[dict]:
    """rotationEval episodes (~350 ticks) recorded at 128x128 by ``record.js``: frames/s over both bots,
    and CPU cores used by the recorder (both bots + views), the server and Xvfb."""
    import resource

    from solaris_env.engine.minecraft.collect import MinecraftSession
    from solaris_env.engine.recorder import EpisodeKey

    rows = []
    with MinecraftSession() as session:
        for ep in range(1 if quick else 2):
            cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            server0 = session.server
            srv0, xvfb0, t0 = _proc_cpu_s(server0.pid), _proc_cpu_s(session.xvfb.pid), time.perf_counter()
            res = session.record(tmp, EpisodeKey(ep, 0, eval_type="rotationEval"), "rotationEval", 0, 128, 128)
            wall = time.perf_counter() - t0
            cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            # reaped children: record.js, and the previous server when record() restarted it (fresh world)
            rec_cpu = (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime)
            srv_cpu = _proc_cpu_s(session.server.pid) - (srv0 if session.server is server0 else 0.0)
            cores = {"recorder": rec_cpu / wall, "server": srv_cpu / wall,
                     "Xvfb": (_proc_cpu_s(session.xvfb.pid) - xvfb0) / wall}
            rows.append({"ticks": res["ticks"], "wall_s": round(wall, 2), "catchup_ticks": res["catchup_ticks"],
                         "frames_per_s": round(2 * res["ticks"] / wall, 1),
                         "cpu_cores_pair": round(sum(cores.values()), 3),
                         "cpu_cores_by_process": {k: round(v, 3) for k, v in cores.items()}})
    return rows


def minecraft_rate(out: Path, quick: bool) -> None:
    """The real-Minecraft backend, one bot pair at a time: the env (real-time steps) and the recorder."""
    load_before = os.getloadavg()
    env_rows = [minecraft_env_rate(r, k, 200 if quick else MC_ENV_TICKS)
                for r, k in (MC_ENV_CONFIGS[:1] if quick else MC_ENV_CONFIGS)]
    from solaris_env.engine.minecraft.supervisor import ProcessError

    with tempfile.TemporaryDirectory() as tmp:
        try:
            rec_rows = minecraft_recorder_rate(tmp, quick)
        except (ProcessError, RuntimeError) as e:  # the env numbers still count; say why these are missing
            rec_rows = {"error": str(e)[-2000:]}
    result = {
        "backend": "minecraft",
        "env": env_rows,
        "recorder": rec_rows,
        "notes": {
            "env": "MinecraftParallelEnv, random actions; wall time of the timed steps only "
                   "(after start-up, the first reset and one step); real time caps it at 20 / ticks_per_step "
                   "steps/s and 40 frames/s per pair; cpu_cores_pair = CPU seconds of env_bridge (Node) + server "
                   "+ Xvfb / wall",
            "recorder": "wall_s includes bot login, teleport and ~3 s of chunk-meshing warm-up per episode; "
                        "cpu_cores_pair = CPU seconds of record.js + server(s) + Xvfb / wall",
        },
        "machine": machine_info(load_before),
    }
    write_result(out, result)
    print(json.dumps({"env": env_rows, "recorder": rec_rows}, indent=2))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer timed calls and episodes")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--backend", choices=("voxel", "minecraft"), default="voxel",
                        help="minecraft: env steps/s, frames/s and CPU per bot pair of the real-Minecraft env and "
                             "recorder (benchmarks/results/engine_throughput_minecraft.json)")
    args = parser.parse_args()
    if args.backend == "minecraft":
        return minecraft_rate(args.out or RESULTS.with_name("engine_throughput_minecraft.json"), args.quick)
    args.out = args.out or RESULTS
    repeats, episodes = (1, 2) if args.quick else (3, 4)


    from solaris_env.engine.bots import registry

    load_before = os.getloadavg()
    r64 = render_rates(64, TOTAL_VIEWS, repeats, sweep=True)
    r128 = render_rates(128, TOTAL_VIEWS, repeats, sweep=False)
    col = collect_rate(episodes)
    result = {
        "frames_per_s": {"single_64": round(r64["single"], 1), "batched_64": round(r64["batched"], 1),
                         "single_128": round(r128["single"], 1), "batched_128": round(r128["batched"], 1)},
        "collect_realtime_factor_64": round(col["realtime_factor"], 2),
        "collect_cold_realtime_factor_64": round(col["cold_realtime_factor"], 2),
        "by_world": {"64": r64["by_world"], "128": r128["by_world"]},
        "collect": col,
        "machine": machine_info(load_before),
        "config": {"scene": SCENE, "worlds": list(WORLDS), "batch_views_64": r64["batch_views"],
                   "batch_views_128": r128["batch_views"], "views_timed": TOTAL_VIEWS, "repeats": repeats, "statistic": "median over repeats",
                   "headline": "harmonic mean over worlds (equal flat/normal split)",
                   "collect_args": "--world mixed --resolution 64 --workers 1", "collect_episodes": episodes,
                   "training_types": registry.training_types()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: result[k] for k in ("frames_per_s", "collect_realtime_factor_64",
                                             "collect_cold_realtime_factor_64")}, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
