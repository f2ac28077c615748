"""``solaris-train``: the training pipeline as commands.

    solaris-train all --preset tiny --data data/tiny --out runs/tiny       # collect, VAE, stages 1-4
    solaris-train vae --preset tiny --data data/tiny --out runs/tiny
    solaris-train vae-decoder --preset tiny --data data/tiny --out runs/tiny   # decoder on long clips
    solaris-train sp | mp-bidirectional | mp-causal | self-forcing --data ... --out ...
    solaris-train install runs/tiny/self-forcing/model                    # -> solaris_env/assets/default
    solaris-train sprint --preset tiny --init default --out OUT --budget-min 8.5   # training/sprint.py

Each stage reads the previous stage's ``OUT/<stage>/model`` and resumes from its own latest checkpoint
(``--no-resume`` starts over). Per-stage settings live in ``training/configs/<preset>.json``, validated (with
the defaults of the optional keys) by ``training.stage_config``; ``--steps`` overrides the stage's step count.
``all`` keeps within the config's wall-clock budget (``all.time_budget_min``; ``--time-budget-min``) by ending
stage 3 early when it must (``training.budget``). ``install``, ``with-decoder``, ``with-vae``,
``action-conditioning``, ``official-dit`` and ``fresh-dit`` rewrite a trained model (``training.surgery``).
Heavy imports (jax) happen only inside the commands.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from solaris_env.cli_support import add_debug_flag, run_command
from solaris_env.world_model.config import WARP_GEOMETRIES, WARP_INTERPOLATIONS
from training.collect import collect_if_missing
from training.stage_config import (
    STAGES,
    AllConfig,
    TrainingConfig,
    load_stage_config,
)


def run_stage(stage: str, args, stage_cfg: TrainingConfig, deadline: float | None = None) -> Path:
    from training.train import call_stage

    seed = stage_cfg.seed if args.seed is None else args.seed
    kw = {"seed": seed, "steps": args.steps, "resume": not args.no_resume, "fsdp": args.fsdp}
    if deadline is not None:  # the elastic stage (AllConfig.elastic_stage)
        kw["deadline"] = deadline
    return call_stage(stage, args.out, args.data, stage_cfg, **kw)


def cmd_stage(args) -> int:
    stage_cfg = load_stage_config(args.preset, args.config)
    path = run_stage(args.command, args, stage_cfg)
    print(f"{args.command}: model written to {path}")
    return 0


def budget_settings(args, block: AllConfig) -> tuple[float | None, str, float]:
    """(budget in seconds or None, elastic stage, reserve in seconds) from ``--time-budget-min`` and the
    config's ``all`` block (``TrainingConfig.all``); a budget of 0 or none means every stage runs its configured
    steps (``training.budget``)."""
    minutes = block.time_budget_min if args.time_budget_min is None else args.time_budget_min
    if minutes is not None and not float(minutes) >= 0:
        raise ValueError(f"time budget must be >= 0 minutes (0: none), got {minutes}")
    return (float(minutes) * 60 if minutes else None), block.elastic_stage, block.reserve_min * 60


def cmd_all(args) -> int:
    import time

    from training.budget import RunClock, elastic_deadline
    from training.metrics import read_metrics
    from training.train import model_dir, stage_dir

    stage_cfg = load_stage_config(args.preset, args.config)
    if stage_cfg.collect is None:
        raise ValueError(f"solaris-train all records its data with the stage config's collect block; "
                         f"{args.config or args.preset} has none")
    budget_s, elastic, reserve_s = budget_settings(args, stage_cfg.all)
    clock = RunClock(args.out).start()
    try:
        t = time.perf_counter()
        collect_if_missing(Path(args.data), args.preset, stage_cfg.collect)
        clock.record("collect_s", clock.data["stages"].get("collect_s", 0.0) + time.perf_counter() - t)
        for stage in STAGES:
            if (model_dir(args.out, stage) / "config.json").is_file():  # finished earlier (resume = continue)
                print(f"{stage}: finished earlier, skipped")
                continue
            deadline = None
            if budget_s is not None and stage == elastic:
                deadline = elastic_deadline(time.time(), budget_s, clock.spent(), reserve_s)
                print(f"{stage}: time budget {budget_s / 60:.0f} min, {clock.spent() / 60:.1f} spent, "
                      f"{reserve_s / 60:.0f} kept for the later stages -> at most {(deadline - time.time()) / 60:.1f} "
                      f"min for this stage")
            t = time.perf_counter()
            run_stage(stage, args, stage_cfg, deadline)
            clock.record(f"{stage}_s", time.perf_counter() - t)
            if deadline is not None:  # the step it reached: the loop always logs its last step
                clock.record(f"{stage}_steps", read_metrics(stage_dir(args.out, stage) / "metrics.jsonl")[-1]["step"])
            print(f"{stage}: done in {clock.data['stages'][f'{stage}_s'] / 60:.1f} min")
    finally:
        clock.stop()
    print(f"all stages done; {clock.spent() / 60:.1f} min of wall clock in {args.out}: {clock.data['stages']}")
    return 0


def cmd_with_decoder(args) -> int:
    from training.surgery import with_decoder
    print(f"wrote {with_decoder(args.model, args.decoder_from, args.out)}")
    return 0


def cmd_with_vae(args) -> int:
    from training.surgery import with_vae
    print(f"wrote {with_vae(args.model, args.vae_from, args.out)}")
    return 0


def cmd_decoder_context(args) -> int:
    from training.decoder_context import with_decoder_context
    dest, fit = with_decoder_context(args.model, args.out, args.context, args.data, args.clips, seed=args.seed)
    print(f"decoder fitted on {fit['patches']} patches: mean squared error {fit['mse_before']:.5f} -> "
          f"{fit['mse_after']:.5f}")
    print(f"wrote {dest}")
    return 0


def cmd_action_conditioning(args) -> int:
    from training.surgery import with_action_conditioning
    dest = with_action_conditioning(args.model, args.out, args.mouse_gain, camera_warp=args.camera_warp,
                                    walk_warp=args.walk_warp, previous_skip=args.previous_skip or None,
                                    warp_interp=args.warp_interp, jump_warp=args.jump_warp,
                                    warp_geometry=args.warp_geometry, partner_map=args.partner_map)
    print(f"wrote {dest}")
    return 0


def cmd_official_dit(args) -> int:
    from training.surgery import official_dit
    print(f"wrote {official_dit(args.model, args.out, args.seed)}")
    return 0


def cmd_fresh_dit(args) -> int:
    from training.surgery import fresh_dit
    print(f"wrote {fresh_dit(args.model, args.out, args.patch, args.dim, args.layers, args.seed)}")
    return 0


def cmd_sprint(args) -> int:
    from training.sprint import SprintArgs, process_start_time, run_sprint

    paths = (None if v is None else Path(v) for v in (args.data, args.config, args.work))
    started = process_start_time() if args.whole_process else None  # the budget includes the imports
    dest = run_sprint(SprintArgs(args.preset, Path(args.out), args.budget_min, args.init, *paths, started=started,
                                 workers=args.workers))
    print(f"sprint: model written to {dest}; install it with `solaris-train install {dest}`")
    return 0


def cmd_install(args) -> int:
    from training.surgery import install_default
    dest = install_default(args.model, args.dest, tuple(args.files), noise_warp=args.noise_warp,
                           still_memory=args.still_memory)
    print(f"installed {args.model} as the default model at {dest}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="solaris-train", description=__doc__.split("\n\n")[0])
    add_debug_flag(parser, top=True)
    sub = parser.add_subparsers(dest="command", required=True)

    def common(p):
        p.add_argument("--preset", default="tiny", help="world-model preset (and its training/configs/<preset>.json)")
        p.add_argument("--config", default=None, help="a stage-config JSON instead of training/configs/<preset>.json")
        p.add_argument("--data", required=True, help="dataset root (holds duet/{train,test}; vpt/ is made from it)")
        p.add_argument("--out", required=True, help="run directory (one sub-directory per stage)")
        p.add_argument("--seed", type=int, default=None, help="seed (default: the stage config's)")
        p.add_argument("--no-resume", action="store_true", help="start over instead of resuming")
        p.add_argument("--fsdp", action="store_true",
                       help="shard parameters and optimiser state over the devices (default: replicated)")

    for stage in STAGES:
        p = sub.add_parser(stage, help=f"train the {stage} stage")
        common(p)
        p.add_argument("--steps", type=int, default=None, help="number of updates (default: the stage config's)")
        p.set_defaults(func=cmd_stage)
    a = sub.add_parser("all", help="collect data, then the VAE and stages 1-4 in order (finished stages, those with "
                                   "a model/, are skipped; an unfinished one resumes)")
    common(a)
    a.add_argument("--time-budget-min", type=float, default=None,
                   help="wall-clock budget of the whole run (default: the config's all.time_budget_min; 0 = none): "
                        "the elastic stage (stage 3) stops early to keep within it")
    a.set_defaults(func=cmd_all, steps=None)
    s = sub.add_parser("sprint", help="train a complete model within a wall-clock budget on whatever JAX sees, "
                                      "recording engine data meanwhile (training/sprint.py, docs/training.md)")
    s.add_argument("--preset", default="tiny",
                   help="world-model preset (and its training/configs/sprint-<preset>.json)")
    s.add_argument("--config", default=None,
                   help="a sprint-config JSON instead of training/configs/sprint-<preset>.json")
    s.add_argument("--out", required=True, help="output directory: OUT/model/ (shards, config.json, lineage.json)")
    s.add_argument("--budget-min", type=float, required=True,
                   help="wall-clock minutes from the process's start to the final model written")
    s.add_argument("--init", default=None,
                   help="'default' (the shipped model) or a model directory to continue; default: from scratch")
    s.add_argument("--data", default=None, help="dataset root the engine records into and training reads "
                                                "(default: WORK/data; episodes already there are used at once)")
    s.add_argument("--work", default=None, help="stage runs, latent cache (default: a temporary "
                                                "directory, removed at the end)")
    s.add_argument("--workers", type=int, default=None,
                   help="background collect workers (default: the config's devices.<kind>.workers; 0 there = every "
                        "core but two); two sprints side by side split the cores (training/gpu_call.sh)")
    s.set_defaults(func=cmd_sprint)
    w = sub.add_parser("with-decoder", help="a model with the VAE decoder of a vae-decoder stage (same encoder)")
    w.add_argument("model", help="a model/ directory (e.g. self-forcing/model)")
    w.add_argument("--decoder-from", required=True, help="a vae-decoder/model sharing the model's encoder")
    w.add_argument("--out", required=True, help="the new model directory")
    w.set_defaults(func=cmd_with_decoder)
    v = sub.add_parser("with-vae", help="a model's DiT and image encoder with another model's whole VAE (a new latent "
                                        "space of the same shape: then retrain the DiT from it)")
    v.add_argument("model", help="a model/ directory, or 'default' (the shipped model)")
    v.add_argument("--vae-from", required=True, help="a model/ directory whose VAE to take (e.g. RUN/vae/model)")
    v.add_argument("--out", required=True,
                   help="the new model directory; RUN/mp-bidirectional/model lets `solaris-train mp-causal --out RUN` "
                        "start from it")
    v.set_defaults(func=cmd_with_vae)
    c = sub.add_parser("decoder-context", help="a linear patch codec's decoder refitted to read a k x k neighbourhood "
                                               "of latents (the encoder, the latent space and the DiT kept)")
    c.add_argument("model", help="a model/ directory, or 'default' (the shipped model)")
    c.add_argument("--context", type=int, required=True, help="k, odd >= 1 (1: one latent position)")
    c.add_argument("--data", required=True, help="a collect output; the fit reads clips of its training split")
    c.add_argument("--clips", type=int, default=2048, help="single-player clips of 25 frames to fit on")
    c.add_argument("--seed", type=int, default=0, help="which clips")
    c.add_argument("--out", required=True, help="the new model directory")
    c.set_defaults(func=cmd_decoder_context)
    g = sub.add_parser("action-conditioning", help="a model under another action conditioning, computing the "
                                                   "same function (then fine-tune it)")
    g.add_argument("model", help="a model/ directory")
    g.add_argument("--mouse-gain", type=float, default=None,
                   help="the new ActionConfig.mouse_input_gain (> 0): the camera pathway then trains that much faster")
    g.add_argument("--camera-warp", type=float, nargs=2, default=None, metavar=("H", "W"),
                   help="turn on DiTConfig.camera_warp (latent pixels per degree of pitch / yaw); the patch "
                        "embedding's new rows start at zero")
    g.add_argument("--walk-warp", type=float, default=None, metavar="S",
                   help="set DiTConfig.walk_warp (eye heights per tick of a held movement key; 0 = off; needs the "
                        "camera warp): the warped previous latent also follows the walk")
    g.add_argument("--jump-warp", type=float, default=None, metavar="S",
                   help="set DiTConfig.jump_warp (eye heights per block of height simulated from the jump key; "
                        "0 = off; 1/1.62 is the geometry; needs the camera warp): the warped previous latent's "
                        "floor also follows the jump")
    g.add_argument("--previous-skip", action="store_true",
                   help="turn on DiTConfig.previous_skip (needs the camera warp): the velocity gets gated "
                        "x_t and warped previous latent terms, the gates starting at zero")
    g.add_argument("--warp-interp", choices=WARP_INTERPOLATIONS, default=None,
                   help="set DiTConfig.warp_interp, how the camera warp samples between latent pixels (the "
                        "weights are kept; docs/model.md 8.1)")
    g.add_argument("--warp-geometry", choices=WARP_GEOMETRIES, default=None,
                   help="set DiTConfig.warp_geometry, what a camera turn does to the warped previous latent: "
                        "'shift' (uniform) or 'rotation' (the camera's rotation; the weights are kept; docs/model.md "
                        "8.1)")
    g.add_argument("--partner-map", type=float, default=None, metavar="SCALE",
                   help="set DiTConfig.partner_map (two players; the map's input scale, 0 = off): the DiT also reads "
                        "where the other player's body is in each view, its patch embedding row starting at zero "
                        "(docs/model.md 8.6)")
    g.add_argument("--out", required=True, help="the new model directory")
    g.set_defaults(func=cmd_action_conditioning)
    o = sub.add_parser("official-dit", help="a model's VAE and image encoder under a fresh DiT in the official "
                                            "layout (none of our DiT options): the start of a control run")
    o.add_argument("model", help="a model/ directory, or 'default' (the shipped model)")
    o.add_argument("--out", required=True,
                   help="the new model directory; RUN/vae-decoder/model lets `solaris-train sp --out RUN` start from it")
    o.add_argument("--seed", type=int, default=0, help="the DiT's initialisation seed")
    o.set_defaults(func=cmd_official_dit)
    f = sub.add_parser("fresh-dit", help="a model's VAE and image encoder under a fresh DiT of other sizes (token "
                                         "grid, width, depth) with all of the model's options: a new DiT lineage")
    f.add_argument("model", help="a model/ directory, or 'default' (the shipped model)")
    f.add_argument("--out", required=True,
                   help="the new model directory; RUN/mp-bidirectional/model lets `solaris-train mp-causal --out RUN` "
                        "train it")
    f.add_argument("--patch", type=int, default=None, help="the DiT's spatial patch (default: the model's)")
    f.add_argument("--dim", type=int, default=None, help="the DiT's width (default: the model's)")
    f.add_argument("--layers", type=int, default=None, help="the DiT's depth (default: the model's)")
    f.add_argument("--seed", type=int, default=0, help="the DiT's initialisation seed")
    f.set_defaults(func=cmd_fresh_dit)
    i = sub.add_parser("install", help="copy a trained model to the package's default-model directory")
    i.add_argument("model", help="a model/ directory written by a stage or a sprint (OUT/model: shards and "
                                 "lineage.json)")
    i.add_argument("--dest", default=None, help="default: solaris_env/assets/default")
    i.add_argument("--files", nargs="*", default=[], help="copied alongside (training log, eval.json, contact sheet)")
    i.add_argument("--noise-warp", type=float, default=None, metavar="RHO",
                   help="the installed config's SamplerConfig.noise_warp (in [0, 1]; 0 = fresh noise for every frame; "
                        "default: the model's)")
    i.add_argument("--still-memory", type=float, default=None, metavar="M",
                   help="the installed config's SamplerConfig.still_memory (in [0, 1): the share of the camera warp's "
                        "input kept while a player's view holds still; 0 = off; default: the model's)")
    i.set_defaults(func=cmd_install)
    for p in sub.choices.values():
        add_debug_flag(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    logging.getLogger("absl").setLevel(logging.WARNING)  # orbax logs every save step at INFO
    args = build_parser().parse_args(argv)
    args.whole_process = argv is None  # this process runs just the command (a sprint's clock starts with it)
    return run_command("solaris-train", _run, args, debug=args.debug)


def _run(args) -> int:
    if args.command not in ("install", "with-decoder", "with-vae", "action-conditioning", "official-dit", "fresh-dit"):
        from training.distributed import maybe_initialize_distributed
        maybe_initialize_distributed()  # multi-host when JAX_COORDINATOR_ADDRESS / JAX_NUM_PROCESSES are set
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
