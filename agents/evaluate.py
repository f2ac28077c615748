"""Policy evaluation with imagined rollouts (issue 6 §4): does the dream rank policies as the real engine does?

    .venv/bin/python -m agents.evaluate --task face_partner --episodes 16 \\
        --ppo-checkpoints runs/agents/ppo_dream-face_partner-s1/checkpoints

Every policy (``--policies`` specs of ``agents.policies.make_policy`` plus every PPO checkpoint found under
``--ppo-checkpoints``) plays the learner (Alpha) for ``--episodes`` episodes from the same held-out engine start
states (``agents.common.make_start_states``, seeds ``--start-seed`` + i) in

* the dream (``DreamParallelEnv``, the world model; reward: the judge variant of the task) and
* the real engine (``RealParallelEnv`` at the model's frame size and ``ticks_per_step`` = the model's k; reward:
  the ground truth), where the judge variant is also scored on the real frames (``real_judge``).

Reported per policy: mean return with a 95 % bootstrap CI for dream, real and real_judge, and the gap
dream - real. Across policies: Pearson and Spearman correlation and MMRV (``agents.stats``) of dream vs real;
real_judge vs real isolates the judges' error, dream vs real_judge the world model's. Goal: Spearman >= 0.8.
Writes ``--out`` (default ``benchmarks/results/policy_eval_<task>.json``), a scatter plot next to it
(``.png``) and a contact sheet of the frames behind the numbers (``_frames.png``: per policy, its first episode's
learner frames in the engine over the same episode in the dream), all atomically. Episodes run one after another (a 2-core CPU is busy with one model call).
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agents.common import (
    EVAL_START_SEED,
    RESULTS_DIR,
    arg,
    make_start_states,
    parse_args,
    write_json_atomic,
)
from agents.policies import make_policy
from agents.rollouts import run_episode
from agents.stats import mmrv, pearson, spearman, summarize
from solaris_env.paths import portable_path, portable_text

# The scripted policies of each task, from useless to good (the PPO checkpoints come on top): the face task's
# seekers turn toward the partner, the approach task's also walk to it once it is centred.
DEFAULT_POLICIES = {
    "face_partner": ["noop", "random", "spin:5", "spin:10", "spin:15", "seeker:0", "seeker:0.1", "seeker:0.25",
                     "seeker:0.5", "seeker:0.75", "seeker:0.9", "seeker-walk:0.25"],
    "approach_partner": ["noop", "random", "spin:15", "seeker:0", "seeker-walk:0", "seeker-walk:0.25",
                         "seeker-walk:0.5", "seeker-walk:0.75"],
}
SPEARMAN_GOAL = 0.8


@dataclass
class Args:
    task: str = arg("face_partner", "judged task (solaris_env.tasks.JUDGED_TASKS)")
    policies: list[str] | None = arg(None, "policy specs (agents.policies.make_policy); default: the task's "
                                           "DEFAULT_POLICIES")
    ppo_checkpoints: list[str] = arg([], "PPO checkpoints (.zip) or dirs of step_*.zip")  # noqa: RUF009
    episodes: int = arg(16, "episodes per policy and env (the same start states for all)")
    max_steps: int = arg(50, "episode length in env steps")
    seed: int = arg(0, "episode e uses reset/policy seed seed + e")
    start_seed: int = arg(EVAL_START_SEED, "start state i is engine reset seed start_seed + i (held out)")
    world: str = arg("flat", "engine world of the start states: flat | normal | mixed")
    partner: str = arg("noop", "the partner's policy spec (runs in both envs): noop | random | spin:DEG ...")
    checkpoint: str | None = arg(None, "world-model checkpoint (default: the shipped solaris_env/assets/default)")
    preset: str | None = arg(None, "a RANDOM-INIT world-model preset instead (tiny | test): smoke tests only")
    judge_dir: str | None = arg(None, "judge probe weights (default: the shipped solaris_env/assets/judges)")
    resamples: int = arg(10_000, "bootstrap resamples per confidence interval")
    out: str | None = arg(None, "results JSON (the plot is written next to it as .png); default: "
                                "benchmarks/results/policy_eval_<task>.json")

    def __post_init__(self):
        from solaris_env.tasks import JUDGED_TASKS

        if self.task not in JUDGED_TASKS:
            raise ValueError(f"task must be one of {sorted(JUDGED_TASKS)}, got {self.task!r}")
        if self.policies is None:
            if self.task not in DEFAULT_POLICIES:
                raise ValueError(f"task {self.task!r} has no default policies ({sorted(DEFAULT_POLICIES)} have); "
                                 "give --policies")
            self.policies = list(DEFAULT_POLICIES[self.task])
        if self.out is None:
            self.out = str(RESULTS_DIR / f"policy_eval_{self.task}.json")
        if self.episodes < 1 or self.max_steps < 1:
            raise ValueError(f"episodes and max_steps must be >= 1, got {self.episodes}, {self.max_steps}")


def expand_checkpoints(paths: list[str]) -> list[str]:
    """``.zip`` files as given; a directory -> its ``step_*.zip`` in step order (also under ``checkpoints/``)."""
    out = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(p.glob("step_*.zip")) or sorted((p / "checkpoints").glob("step_*.zip"))
            if not found:
                raise FileNotFoundError(f"no step_*.zip checkpoints in {p} or {p / 'checkpoints'}")
            out += [str(f) for f in found]
        elif p.suffix == ".zip" and p.is_file():
            out.append(str(p))
        else:
            raise FileNotFoundError(f"--ppo-checkpoints: {p} is neither a .zip checkpoint nor a directory")
    return out


def agreement(real: list[float], proxy: list[float]) -> dict:
    """How well ``proxy`` mean returns order the policies as ``real`` ones do."""
    real_a, proxy_a = np.asarray(real), np.asarray(proxy)
    return {"pearson": pearson(real_a, proxy_a), "spearman": spearman(real_a, proxy_a), "mmrv": mmrv(real_a, proxy_a),
            "mean_gap": float((proxy_a - real_a).mean()), "mean_abs_gap": float(np.abs(proxy_a - real_a).mean())}


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(Args, argv, description=__doc__.split("\n\n")[0])
    t_start = time.perf_counter()

    # ---- envs ------------------------------------------------------------------------------
    from solaris_env.dream_env import DreamParallelEnv, build_model
    from solaris_env.real_env import RealParallelEnv
    from solaris_env.tasks import JUDGED_TASKS

    task_cls = JUDGED_TASKS[args.task]
    model = build_model(args.checkpoint, args.preset, num_players=2)
    height, width, _ = model.frame_shape
    k = model.frames_per_step
    dream = DreamParallelEnv(model=model, max_steps=args.max_steps, task=task_cls(source="judge",
                                                                                  judge_dir=args.judge_dir))
    real = RealParallelEnv(num_players=2, world=args.world, resolution=(height, width), max_steps=args.max_steps,
                           ticks_per_step=k, task=task_cls(source="truth"))
    real_judge = task_cls(source="judge", judge_dir=args.judge_dir)  # the judges on real frames, side by side
    starts = make_start_states(args.episodes, args.start_seed, args.world, (height, width))
    specs = list(args.policies) + [f"ppo:{p}" for p in expand_checkpoints(args.ppo_checkpoints)]
    if len(set(specs)) != len(specs):
        raise ValueError(f"policies must be distinct, got {specs}")
    print(f"evaluate: task={args.task} {len(specs)} policies x {args.episodes} episodes x {{dream, real}}, "
          f"{args.max_steps} steps of k={k} frames at {height}x{width}", flush=True)

    # ---- rollouts --------------------------------------------------------------------------
    rows, sheets = [], []
    for spec in specs:
        policy, partner = make_policy(spec), make_policy(args.partner)
        returns = {"dream": [], "real": [], "real_judge": []}
        seen = {"real": [], "dream": []}  # the first episode's learner frames in both envs, for the contact sheet
        t0 = time.perf_counter()
        for e, start in enumerate(starts):
            result = run_episode(real, policy, start, args.seed + e, partner, side_tasks=[real_judge],
                                 frames=seen["real"] if e == 0 else None)
            returns["real"].append(result.env_return)
            returns["real_judge"].append(result.side_returns[0])
            returns["dream"].append(run_episode(dream, policy, start, args.seed + e, partner,
                                                frames=seen["dream"] if e == 0 else None).env_return)
        sheets.append(seen)
        row = {"name": portable_text(spec, parts=3),  # ppo:PATH without the machine's directories
               **{kind: summarize(r, resamples=args.resamples) for kind, r in returns.items()}}
        row["gap"] = row["dream"]["mean"] - row["real"]["mean"]
        row["wall_s"] = time.perf_counter() - t0
        rows.append(row)
        print(f"  {row['name']:>40s}: dream {row['dream']['mean']:6.2f}  real {row['real']['mean']:6.2f}  "
              f"real_judge {row['real_judge']['mean']:6.2f}  ({row['wall_s']:.0f} s)", flush=True)

    # ---- agreement -------------------------------------------------------------------------
    means = {kind: [row[kind]["mean"] for row in rows] for kind in ("dream", "real", "real_judge")}
    results = {
        "task": args.task, "policies": rows,
        "agreement": {"dream_vs_real": agreement(means["real"], means["dream"]),
                      "real_judge_vs_real": agreement(means["real"], means["real_judge"]),
                      "dream_vs_real_judge": agreement(means["real_judge"], means["dream"])},
        "goal": {"spearman_min": SPEARMAN_GOAL},
        "setup": {"episodes": args.episodes, "max_steps": args.max_steps, "frames_per_step": k,
                  "frame_size": [height, width], "world": args.world, "partner": args.partner,
                  "start_seed": args.start_seed, "seed": args.seed,
                  "world_model": portable_path(args.checkpoint, parts=3) if args.checkpoint else (
                      f"preset {args.preset} (random init)" if args.preset else "shipped default"),
                  "judges": portable_path(args.judge_dir) if args.judge_dir else "shipped"},
        "machine": {"load_avg_1m_end": os.getloadavg()[0], "cpus": os.cpu_count()},
        "wall_s": time.perf_counter() - t_start,
        "command": " ".join([Path(sys.executable).name, "-m", "agents.evaluate",
                             *(portable_text(a, parts=3) for a in (argv if argv is not None else sys.argv[1:]))]),
    }
    spearman_dr = results["agreement"]["dream_vs_real"]["spearman"]
    results["goal"]["met"] = bool(np.isfinite(spearman_dr) and spearman_dr >= SPEARMAN_GOAL)

    # ---- outputs ---------------------------------------------------------------------------
    from agents.plots import frames_png, scatter_png

    out = write_json_atomic(args.out, results)
    plot = scatter_png(Path(args.out).with_suffix(".png"), [r["name"] for r in rows], [r["real"] for r in rows],
                       [r["dream"] for r in rows], f"{args.task}: dream vs real return, {args.episodes} episodes, "
                       f"Spearman {spearman_dr:.2f}")
    sheet = frames_png(Path(args.out).with_name(Path(args.out).stem + "_frames.png"), [r["name"] for r in rows],
                       [s["real"] for s in sheets], [s["dream"] for s in sheets])
    a = results["agreement"]["dream_vs_real"]
    print(f"dream vs real: Pearson {a['pearson']:.3f}  Spearman {a['spearman']:.3f}  MMRV {a['mmrv']:.3f}  "
          f"mean gap {a['mean_gap']:+.2f}; wrote {out}, {plot} and {sheet}", flush=True)
    return results


if __name__ == "__main__":
    main()
