"""World-model streaming step: seconds per env step (denoise incl. the fused commit / VAE decode), frames/s, FLOPs.

    .venv/bin/python -m benchmarks.model_step --preset tiny            # ~5-10 min on 2 shared CPU cores
    .venv/bin/python -m benchmarks.model_step --preset test --quick    # smoke run

Writes ``benchmarks/results/model_step.json`` with, for every batch size B (worlds; P players each):

* ``step_s``: wall seconds of one ``WorldModel.step`` (the jitted, donated program the env uses; one
  latent frame = k video frames per player, both players), median over the timed rounds, frames ready
  (``block_until_ready``). ``env_steps_per_s`` = 1 / step_s (one env step advances all B worlds) and
  ``player_frames_per_s`` = B * P * k / step_s.
* ``parts_s``: the parts of a step jitted and timed on their own, in the same rounds as the step (each
  round times one step then each part once, so all see the same background load): ``denoise`` (every
  DiT pass: the few-step sampler's len(ar_timesteps) passes, the first of them fused with the commit of
  the previous latent frame -- ``WorldDiT.decode(..., commit=1)``: one pass of two frames, the
  clean one at t = 0 written to the KV cache), ``decode`` (the streaming VAE decode of the new latent
  frame), and ``first_pass`` (the fused commit + first denoising pass alone; included in ``denoise``).
  The commit has no time of its own: it is the first of the two frames of that pass.
* ``flops``: XLA's cost analysis (``jitted.lower(...).compile().cost_analysis()["flops"]``) of the
  compiled parts. XLA counts a loop body once, so the DiT parts are compiled for counting with their
  loops traced as straight-line code (``Programs(..., unroll=True)``: the same computation, every
  sampler step and DiT layer present). The decode runs one world at a time (``lax.map``), so its count is
  B x the cost analysis of the decode of one world (a loop-free program). ``step`` = the sum.
  ``flops_xla_looped_step`` is the cost analysis of the production (looped) step, for reference.
* ``achieved_gflops`` = flops / seconds for the step and each part, and ``fraction_of_matmul_peak`` =
  achieved / the f32 matmul rate measured in the same run (best of several 2048^3 matmuls, measured
  before and after the batches; the max is used).

The model has random weights (``from_preset``): speed does not depend on the values. The worlds are
initialised once at B=1 (``init_s``: that call, compilation included and excluded) and tiled to the
larger batches. Targets (tiny preset, 2 cores): >= 20 env steps/s at B=1, >= 200 player-frames/s at
B=16, >= 40 % of the matmul peak at B=16. The CPU is shared with other jobs: ``machine`` records the
load average before/after; a load above the core count means slower, noisier numbers.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np

from benchmarks.machine import machine_info, write_result

RESULTS = Path(__file__).parent / "results" / "model_step.json"
BATCHES = (1, 4, 16)


def xla_flops(jitted, *args) -> float:
    """XLA's cost-analysis FLOP count of ``jitted`` compiled for ``args``."""
    analysis = jitted.lower(*args).compile().cost_analysis()
    if isinstance(analysis, (list, tuple)):  # older jax returns one dict per program
        analysis = analysis[0]
    return float(analysis.get("flops", float("nan")))


def median_time(fn, repeats: int) -> float:
    """Median wall time of ``fn()`` (which must block on its result)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def matmul_peak_gflops(size: int = 2048, repeats: int = 5) -> float:
    """Best f32 rate of a (size x size) @ (size x size) matmul, GFLOP/s."""
    import jax
    import jax.numpy as jnp

    a = jax.random.normal(jax.random.key(0), (size, size), jnp.float32)
    b = jax.random.normal(jax.random.key(1), (size, size), jnp.float32)
    matmul = jax.jit(lambda x, y: x @ y)
    matmul(a, b).block_until_ready()
    best = min(median_time(lambda: matmul(a, b).block_until_ready(), 1) for _ in range(repeats))
    return 2 * size ** 3 / best / 1e9


def count_flops(model, state, actions, state1, x0_1) -> dict:
    """XLA cost-analysis FLOPs of denoise (loops unrolled; the fused first pass alone too) and decode (B x one world)."""
    import jax

    from solaris_env.world_model.world_model import Programs

    programs = model.programs
    unrolled = Programs(model.config, programs.graphdefs, unroll=True)
    params = model.step_params
    flops = {
        "denoise": xla_flops(jax.jit(unrolled.denoise), params, state, actions),
        "decode": state.num_worlds * xla_flops(jax.jit(programs.decode), params, state1, x0_1),
    }
    flops["step"] = sum(flops.values())
    flops["first_pass"] = xla_flops(jax.jit(programs.first_pass), params, state, actions)  # part of denoise
    return flops


def bench_batch(model, state1, batch: int, rounds: int, seed: int) -> dict:
    import jax
    import jax.numpy as jnp

    cfg, programs = model.config, model.programs
    p, k = model.num_players, model.frames_per_step
    rng = np.random.default_rng(seed)
    state = jax.tree.map(lambda a: jnp.repeat(a, batch, axis=0), state1)
    shape = (batch, p, k, model.action_dim)
    actions = (rng.random(shape) < 0.2).astype(np.float32)
    actions[..., cfg.action.keyboard_dim:] = rng.uniform(-1.3, 1.3, shape[:-1] + (cfg.action.mouse_dim,))
    actions = jnp.asarray(actions)

    # parts, each jitted on its own (no donation: the same state is reused)
    denoise, first_pass, decode = (jax.jit(f) for f in (programs.denoise, programs.first_pass, programs.decode))
    params = model.step_params
    for _ in range(3):  # compile, then let the thread pools and allocator settle
        x0 = jax.block_until_ready(denoise(params, state, actions))[0]
        jax.block_until_ready(first_pass(params, state, actions))
        jax.block_until_ready(decode(params, state, x0))
    one = lambda a: a[:1]
    flops = count_flops(model, state, actions, jax.tree.map(one, state), x0[:1])
    looped = xla_flops(jax.jit(programs.step), params, state, actions)

    # the real thing: WorldModel.step (donated state, so it runs on its own copy), compiled by the first call
    stream = jax.tree.map(jnp.copy, state)
    t0 = time.perf_counter()
    frames, stream = model.step(stream, actions)
    frames.block_until_ready()
    first_call_s = time.perf_counter() - t0
    for _ in range(2):
        frames, stream = model.step(stream, actions)
    frames.block_until_ready()

    # Timed in rounds (each round: one step, then each part once) so that the step and its parts see the
    # same background load; medians over the rounds.
    def timed(fn) -> float:
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0

    def env_step():
        nonlocal stream
        out, stream = model.step(stream, actions)
        out.block_until_ready()

    times, part_times = [], {"denoise": [], "decode": [], "first_pass": []}
    for _ in range(rounds):
        times.append(timed(env_step))
        part_times["denoise"].append(timed(lambda: jax.block_until_ready(denoise(params, state, actions))))
        part_times["decode"].append(timed(lambda: jax.block_until_ready(decode(params, state, x0))))
        part_times["first_pass"].append(timed(lambda: jax.block_until_ready(first_pass(params, state, actions))))
    parts = {name: statistics.median(ts) for name, ts in part_times.items()}
    step_s = statistics.median(times)
    return {
        "B": batch,
        "step_s": step_s,
        "step_s_min": min(times),
        "first_call_s": first_call_s,
        "parts_s": parts,
        "parts_sum_s": parts["denoise"] + parts["decode"],
        "env_steps_per_s": 1.0 / step_s,
        "player_frames_per_s": batch * p * k / step_s,
        "flops": flops,
        "flops_xla_looped_step": looped,
        "achieved_gflops": {"step": flops["step"] / step_s / 1e9,
                            **{name: flops[name] / s / 1e9 for name, s in parts.items()}},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="tiny", choices=["tiny", "test", "solaris"])
    parser.add_argument("--batches", type=int, nargs="+", default=list(BATCHES))
    parser.add_argument("--quick", action="store_true", help="fewer timed steps")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    rounds = 3 if args.quick else 15

    import jax

    from solaris_env.world_model.checkpoint import config_to_dict
    from solaris_env.world_model.world_model import WorldModel, param_count

    load_before = os.getloadavg()
    t0 = time.perf_counter()
    model = WorldModel.from_preset(args.preset, seed=0)
    build_s = time.perf_counter() - t0
    cfg = model.config
    first = np.random.default_rng(0).integers(0, 256, (1, model.num_players, *model.frame_shape), dtype=np.uint8)
    t0 = time.perf_counter()
    state1 = model.init(first, 0)
    jax.block_until_ready(state1)
    init_cold_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(model.init(first, 1))
    init_s = time.perf_counter() - t0

    peak_before = matmul_peak_gflops()
    rows = [bench_batch(model, state1, b, rounds, seed=b) for b in args.batches]
    peak_after = matmul_peak_gflops()
    peak = max(peak_before, peak_after)
    for row in rows:
        row["fraction_of_matmul_peak"] = {name: g / peak for name, g in row["achieved_gflops"].items()}

    by_b = {r["B"]: r for r in rows}
    targets = {}
    if 1 in by_b:
        targets["env_steps_per_s_B1>=20"] = {"value": round(by_b[1]["env_steps_per_s"], 2),
                                             "met": bool(by_b[1]["env_steps_per_s"] >= 20)}
    if 16 in by_b:
        frac = by_b[16]["fraction_of_matmul_peak"]["step"]
        targets["player_frames_per_s_B16>=200"] = {"value": round(by_b[16]["player_frames_per_s"], 1),
                                                   "met": bool(by_b[16]["player_frames_per_s"] >= 200)}
        targets["matmul_peak_fraction_B16>=0.40"] = {"value": round(frac, 3), "met": bool(frac >= 0.40)}
    result = {
        "preset": args.preset,
        "targets": targets if args.preset == "tiny" else "targets apply to the tiny preset",
        "rows": rows,
        "matmul_peak_gflops": peak,
        "matmul_peak_gflops_before_after": [peak_before, peak_after],
        "init_s": {"cold_B1": init_cold_s, "warm_B1": init_s, "cond_frames_encoded": model.cond_frames},
        "model": {"build_s": build_s, "params": param_count(model), "players": model.num_players,
                  "frames_per_step": model.frames_per_step, "frame_shape": list(model.frame_shape),
                  "dit_passes_per_step": len(cfg.sampler.ar_timesteps) + 1},
        "config": config_to_dict(cfg),
        "machine": machine_info(load_before),
        "run": {"timed_rounds": rounds, "statistic": "median over rounds (one step + each part per round)",
                "xla_flags": os.environ.get("XLA_FLAGS", "")},
    }
    write_result(args.out, result)
    for r in rows:
        ps, fl = r["parts_s"], r["flops"]
        print(f"B={r['B']:3d}  step {r['step_s'] * 1e3:8.1f} ms  (denoise {ps['denoise'] * 1e3:.1f}, "
              f"of which fused commit + first pass {ps['first_pass'] * 1e3:.1f}; decode {ps['decode'] * 1e3:.1f})  "
              f"{r['env_steps_per_s']:.2f} env steps/s  {r['player_frames_per_s']:.1f} player-frames/s  "
              f"{fl['step'] / 1e9:.2f} GFLOP/step (denoise {fl['denoise'] / 1e9:.2f}, decode "
              f"{fl['decode'] / 1e9:.2f})  "
              f"{r['fraction_of_matmul_peak']['step'] * 100:.1f} % of {peak:.0f} GFLOP/s")
    print(json.dumps(result["targets"], indent=2))


if __name__ == "__main__":
    main()
