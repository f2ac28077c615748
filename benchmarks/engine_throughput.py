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

from benchmarks.machine import machine_info

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


def minecraft_rate(out: Path, quick: bool) -> None:
    """One rotationEval pair (~350 ticks) recorded at 128x128 on real Minecraft: frames/s over both
    bots, ticks/s, and CPU cores used by the recorder (both bots + views) and by the server."""
    import resource

    from solaris_env.engine.minecraft.collect import MinecraftSession
    from solaris_env.engine.recorder import EpisodeKey

    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp, MinecraftSession() as session:
        rows = []
        for ep in range(1 if quick else 2):
            cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            srv0, t0 = _proc_cpu_s(session.server.pid), time.perf_counter()
            res = session.record(tmp, EpisodeKey(ep, 0, eval_type="rotationEval"), "rotationEval", 0, 128, 128)
            wall = time.perf_counter() - t0
            cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            rec_cpu = (cpu1.ru_utime + cpu1.ru_stime) - (cpu0.ru_utime + cpu0.ru_stime)
            rows.append({"ticks": res["ticks"], "wall_s": round(wall, 2), "catchup_ticks": res["catchup_ticks"],
                         "frames_per_s": round(2 * res["ticks"] / wall, 1),
                         "recorder_cpu_cores": round(rec_cpu / wall, 3),
                         "server_cpu_cores": round((_proc_cpu_s(session.server.pid) - srv0) / wall, 3)})
    result = {"backend": "minecraft", "episodes": rows,
              "note": "wall_s includes bot login, teleport and ~3 s of chunk-meshing warm-up per episode",
              "machine": machine_info(load_before)}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(rows, indent=2))
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer timed calls and episodes")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--backend", choices=("voxel", "minecraft"), default="voxel",
                        help="minecraft: frames/s and CPU per bot pair of the real-Minecraft recorder")
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
