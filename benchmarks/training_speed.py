"""Training speed per stage (steps/s, tokens/s) of the real pipeline, measured on this machine.

    .venv/bin/python -m benchmarks.training_speed                              # tiny preset, ~10 min
    .venv/bin/python -m benchmarks.training_speed --run runs/tiny              # summarise a finished run instead
    .venv/bin/python -m benchmarks.training_speed --preset test --steps 10 --episodes 4   # smoke run
    .venv/bin/python -m benchmarks.training_speed --remat-ab default          # one DiT train step, remat on/off

Default mode: records a small dataset with the engine, then runs ``solaris-train all`` with every
stage's config from ``training/configs/<preset>.json`` (batch size, clip length, learning rate as
shipped) but only ``--steps`` updates per stage (Self Forcing: iterations), in a scratch directory.
``--run DIR`` summarises the ``metrics.jsonl`` of an existing run directory instead (e.g. the run that
made the shipped model; its numbers are as noisy as the machine was then).

Per stage: the median of the logged ``steps_per_s`` / ``tokens_per_s`` intervals, leaving out the first
interval (it holds the compilation). Tokens are what the stage's model sees per update: pixels of the
clips for the VAE, latent tokens (batch x players x latent frames x tokens per frame) for the DiT stages.
The measured mode also projects the wall-clock of the whole ``solaris-train all`` with the configured
budgets (``project_all``). Writes ``benchmarks/results/training_speed.json``.

``--remat-ab MODEL`` (``default`` or a model directory) times the DiT stage-3 train step of that model alone
(``training.step.make_train_step``, the batch and clip length of the preset's ``mp-causal`` block, random frames:
the time does not depend on them) with and without ``remat`` (docs/training.md, "Stage configs"), in alternating
rounds in one process so that both see the same machine; it checks that both give the same losses, and reports
each arm's median seconds per step, their ratio and the f32 matmul peak measured in the same run. Writes
``benchmarks/results/training_step_remat.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from solaris_env.paths import portable_path, portable_text

RESULTS = Path(__file__).parent / "results" / "training_speed.json"
REMAT_RESULTS = Path(__file__).parent / "results" / "training_step_remat.json"
STAGES = ("vae", "vae-decoder", "sp", "mp-bidirectional", "mp-causal", "self-forcing")  # stage_config.STAGES[:-1]


def summarise_stage(metrics_path: Path) -> dict | None:
    """Median steps/s and tokens/s over the logged intervals of one stage, the first left out."""
    if not metrics_path.is_file():
        return None
    rows = [json.loads(line) for line in metrics_path.read_text().splitlines() if line.strip()]
    rows = [r for r in rows if "steps_per_s" in r]
    if not rows:
        return None
    timed = rows[1:] if len(rows) > 1 else rows
    return {"steps": rows[-1]["step"], "intervals": len(timed),
            "steps_per_s": statistics.median(r["steps_per_s"] for r in timed),
            "tokens_per_s": statistics.median(r["tokens_per_s"] for r in timed),
            "wall_s": rows[-1]["time"] - rows[0]["time"] if len(rows) > 1 else None}


def summarise_run(run: Path, stage_cfg: dict | None) -> dict:
    stages = {}
    for stage in STAGES:
        s = summarise_stage(run / stage / "metrics.jsonl")
        if s is None:
            continue
        if stage_cfg and stage in stage_cfg:
            sc = stage_cfg[stage]
            s["batch_size"], s["num_frames"] = sc["batch_size"], sc["num_frames"]
        stages[stage] = s
    return stages


def measure(preset: str, steps: int, episodes: int, workdir: Path) -> tuple[dict, dict]:
    """Collect ``episodes`` with the engine and run every stage for ``steps`` updates in ``workdir``; each
    stage's wall time is kept (its updates plus its fixed costs: compilation, latent cache, evaluations)."""
    from training import cli
    from training.collect import collect_if_missing
    from training.stage_config import TrainingConfig, load_stage_config

    cfg = load_stage_config(preset).to_dict()
    shipped = json.loads(json.dumps(cfg))  # the budgets the projection is for
    cfg["collect"].update(episodes=episodes, test_fraction=0.25, seed=7)
    for stage in STAGES:
        n = max(steps // 3, 3) if stage == "self-forcing" else steps
        log_every = max(n // 6, 1)
        cfg[stage].update(steps=n, log_every=log_every, ckpt_every=n, sample_every=n)
        if stage == "vae":
            cfg[stage].update(eval_clips=4, stats_clips=8)
    measured = TrainingConfig.from_dict(cfg, f"{preset} for the measurement")
    data, out = workdir / "data", workdir / "run"
    t0 = time.perf_counter()
    collect_if_missing(data, preset, measured.collect)
    walls = {"collect": time.perf_counter() - t0}
    args = argparse.Namespace(preset=preset, config=None, data=str(data), out=str(out), seed=None, no_resume=False,
                               fsdp=False, steps=None)
    for stage in STAGES:
        t = time.perf_counter()
        cli.run_stage(stage, args, measured)
        walls[stage] = time.perf_counter() - t
    stages = summarise_run(out, cfg)
    for stage, s in stages.items():
        s["stage_wall_s"] = walls[stage]
    return stages, {"total_wall_s": time.perf_counter() - t0, "walls": walls, "config": cfg, "shipped": shipped}


def project_all(stages: dict, walls: dict, episodes: int, shipped: dict) -> dict:
    """Wall-clock of ``solaris-train all`` with the shipped budgets, from a short measured run: collection
    scaled by episodes; each stage's configured updates at its measured rate, plus its measured fixed cost
    (stage wall minus its updates: compilation, samples, evaluations). The first DiT stage (``sp``) also
    builds the latent cache of every video: its fixed cost beyond the next stage's (which finds the cache
    built) is the cache, scaled by episodes. A projection, not a run."""
    scale = shipped["collect"]["episodes"] / episodes
    fixed = {stage: max(s["stage_wall_s"] - s["steps"] / s["steps_per_s"], 0.0) for stage, s in stages.items()}
    parts = {"collect_s": walls["collect"] * scale}
    for stage, s in stages.items():
        cost = fixed[stage]
        if stage == "sp" and "mp-bidirectional" in fixed:
            cache = max(cost - fixed["mp-bidirectional"], 0.0)
            cost = cost - cache + cache * scale
            parts["latent_cache_s"] = cache * scale
        parts[f"{stage}_s"] = shipped[stage]["steps"] / s["steps_per_s"] + cost
    total = sum(v for k, v in parts.items() if k != "latent_cache_s")  # the cache is inside sp_s
    return {"episodes": shipped["collect"]["episodes"], "parts_s": parts, "total_min": total / 60, "budget_min": 150}


def remat_ab(model_spec: str, rounds: int, steps_per_round: int) -> dict:
    """Seconds per stage-3 train step of ``model_spec`` with ``remat`` off and on, in alternating rounds."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from benchmarks.model_step import matmul_peak_gflops
    from solaris_env.dream_env import DEFAULT_CHECKPOINT
    from solaris_env.world_model.world_model import WorldModel
    from training.stage_config import load_stage_config
    from training.step import TrainState, make_optimizer, make_train_step, prepare_batch

    model = WorldModel.load(DEFAULT_CHECKPOINT if model_spec == "default" else model_spec)
    cfg = model.config
    sc = load_stage_config(cfg.name).stages["mp-causal"]
    dit, vae, encoder = model.modules()
    rng = np.random.default_rng(0)
    shape = (sc.batch_size, sc.num_frames, cfg.num_players, cfg.frame_height, cfg.frame_width)
    obs = jnp.asarray(rng.integers(0, 256, shape + (3,), dtype=np.uint8))
    act = jnp.asarray(rng.normal(size=shape[:3] + (cfg.action.action_dim,)).astype(np.float32))
    batch = jax.jit(lambda o, a: prepare_batch(vae, encoder, o, a, cfg))(obs, act)
    arms = {}
    for remat in (False, True):
        tx = make_optimizer(sc.lr)
        graphdef, state = TrainState.create(dit, tx, rng=0)
        step = make_train_step(graphdef, "forward_causal", "diffusion_forcing", tx, sc.ema_decay, remat=remat)
        state, metrics = step(state, batch)  # compiles
        arms[remat] = {"step": step, "state": state, "losses": [float(metrics["loss"])], "s_per_step": []}
    peak = [matmul_peak_gflops()]
    for _ in range(rounds):
        for arm in arms.values():
            t = time.perf_counter()
            for _ in range(steps_per_round):
                arm["state"], metrics = arm["step"](arm["state"], batch)
                arm["losses"].append(float(metrics["loss"]))
            arm["s_per_step"].append((time.perf_counter() - t) / steps_per_round)
    peak.append(matmul_peak_gflops())
    off, on = arms[False], arms[True]
    if not np.allclose(off["losses"], on["losses"], rtol=1e-4):
        raise SystemExit(f"remat changed the losses: {off['losses']} against {on['losses']}")
    median = {k: statistics.median(a["s_per_step"]) for k, a in (("off", off), ("on", on))}
    return {"benchmark": "training_step_remat", "model": portable_text(model_spec), "preset": cfg.name,
            "batch_size": sc.batch_size, "num_frames": sc.num_frames, "rounds": rounds,
            "steps_per_round": steps_per_round, "s_per_step": {"off": off["s_per_step"], "on": on["s_per_step"]},
            "median_s_per_step": median, "speedup": median["off"] / median["on"],
            "losses_equal": True,
            "max_loss_difference": float(np.max(np.abs(np.subtract(off["losses"], on["losses"])))),
            "matmul_peak_gflops": peak}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.training_speed", description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="tiny")
    p.add_argument("--steps", type=int, default=30, help="updates per stage (Self Forcing: a third, >= 3)")
    p.add_argument("--episodes", type=int, default=8, help="engine episodes recorded for the measurement")
    p.add_argument("--run", default=None, help="summarise this existing run directory instead of measuring")
    p.add_argument("--workdir", default=None, help="scratch directory (default: a temporary one)")
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--note", default=None, help="recorded as is (e.g. how loaded the machine was during --run)")
    p.add_argument("--remat-ab", metavar="MODEL", default=None,
                   help="time MODEL's stage-3 train step with remat off and on instead (default or a directory)")
    p.add_argument("--rounds", type=int, default=5, help="--remat-ab: alternating rounds per arm")
    p.add_argument("--steps-per-round", type=int, default=3, help="--remat-ab: train steps per round")
    args = p.parse_args(argv)

    load_before = os.getloadavg()
    if args.remat_ab:
        from benchmarks.machine import machine_info
        from training.samples import write_json

        result = remat_ab(args.remat_ab, args.rounds, args.steps_per_round)
        result["machine"] = machine_info(load_before)
        med = result["median_s_per_step"]
        print(f"{result['preset']} stage-3 train step, batch {result['batch_size']} x {result['num_frames']} frames: "
              f"remat off {med['off']:.3f} s, on {med['on']:.3f} s -> {result['speedup']:.2f}x "
              f"(f32 matmul peak {result['matmul_peak_gflops'][0]:.0f} GFLOP/s); the same losses")
        out = REMAT_RESULTS if args.out == str(RESULTS) else Path(args.out)
        write_json(out, result)
        print(f"wrote {out}")
        return 0
    if args.run:
        run = Path(args.run)
        cfg_path = run / "train_config.json"
        stage_cfg = json.loads(cfg_path.read_text()) if cfg_path.is_file() else None
        stages, extra = summarise_run(run, stage_cfg), {"mode": "summarised run", "run": portable_path(run)}
    else:
        with tempfile.TemporaryDirectory(dir=args.workdir) as tmp:
            stages, extra = measure(args.preset, args.steps, args.episodes, Path(tmp))
        projection = project_all(stages, extra["walls"], args.episodes, extra["shipped"])
        extra = {"mode": "measured", "steps_per_stage": args.steps, "episodes": args.episodes,
                 "total_wall_s": extra["total_wall_s"], "projected_all": projection}
    if not stages:
        raise SystemExit("no stage metrics found")

    from benchmarks.machine import machine_info
    from training.samples import write_json

    result = {"benchmark": "training_speed", "preset": args.preset, **extra,
              "note": args.note and portable_text(args.note), "stages": stages, "machine": machine_info(load_before)}
    print(f"{'stage':<18}{'steps/s':>10}{'tokens/s':>12}{'batch':>7}{'frames':>8}")
    for stage, s in stages.items():
        print(f"{stage:<18}{s['steps_per_s']:>10.3f}{s['tokens_per_s']:>12.0f}{s.get('batch_size', '-'):>7}"
              f"{s.get('num_frames', '-'):>8}")
    if "projected_all" in extra:
        proj = extra["projected_all"]
        print(f"projected `solaris-train all --preset {args.preset}` ({proj['episodes']} episodes, the configured "
              f"steps): {proj['total_min']:.0f} min (budget {proj['budget_min']} min)")
    write_json(Path(args.out), result)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
