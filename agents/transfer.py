"""Dream -> real transfer (issue 6 §3): the real-engine return of the dream-trained PPO against the real-trained
PPO and random (and the scripted engine bot as an upper reference), from the same held-out start states.

    .venv/bin/python -m agents.transfer --task face_partner \\
        --dream-ppo runs/agents/ppo_dream-face_partner-s1 --real-ppo runs/agents/ppo_real-face_partner-s1

Every policy plays the learner (Alpha) for ``--episodes`` episodes in ``RealParallelEnv`` with the ground-truth
reward (``<task>_truth``) and ``ticks_per_step`` = the policies' frames per step. Reported per policy: mean return
and 95 % bootstrap CI (``agents.stats``); and the transfer ratio (dream PPO - random) / (real PPO - random): 1
means training in the dream was as good as training in the engine (reported only when the real PPO's CI lies
above the random mean; otherwise null, with the reason in ``transfer_ratio_note``). A run directory stands for its last
checkpoint. Writes ``--out`` (default ``benchmarks/results/transfer_<task>.json``) atomically.
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

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
from agents.stats import summarize
from solaris_env.paths import portable_text


@dataclass
class Args:
    dream_ppo: str = arg("", "dream-trained PPO: a step_*.zip checkpoint or its run directory (last checkpoint)")
    real_ppo: str = arg("", "real-trained PPO: a step_*.zip checkpoint or its run directory (last checkpoint)")
    task: str = arg("face_partner", "judged task (solaris_env.tasks.JUDGED_TASKS)")
    references: list[str] = arg(["random", "bot:0"], "other policies to report (agents.policies specs)")  # noqa: RUF009
    episodes: int = arg(32, "episodes per policy (the same start states for all)")
    max_steps: int = arg(50, "episode length in env steps")
    seed: int = arg(0, "episode e uses reset/policy seed seed + e")
    start_seed: int = arg(EVAL_START_SEED, "start state i is engine reset seed start_seed + i (held out)")
    world: str = arg("flat", "engine world of the start states: flat | normal | mixed")
    partner: str = arg("noop", "the partner's policy spec")
    resolution: int = arg(64, "real frame size (PPO policies resize to their own input)")
    resamples: int = arg(10_000, "bootstrap resamples per confidence interval")
    out: str | None = arg(None, "results JSON (default benchmarks/results/transfer_<task>.json)")

    def __post_init__(self):
        from solaris_env.tasks import JUDGED_TASKS

        if self.task not in JUDGED_TASKS:
            raise ValueError(f"task must be one of {sorted(JUDGED_TASKS)}, got {self.task!r}")
        if not self.dream_ppo or not self.real_ppo:
            raise ValueError("give both --dream-ppo and --real-ppo (a checkpoint .zip or a run directory)")


def last_checkpoint(path: str) -> Path:
    """A ``.zip`` as given; a run directory -> its last ``checkpoints/step_*.zip``."""
    p = Path(path)
    if p.is_file():
        return p
    found = sorted(p.glob("step_*.zip")) or sorted((p / "checkpoints").glob("step_*.zip"))
    if not found:
        raise FileNotFoundError(f"{p}: no checkpoint (a .zip, or a run directory with checkpoints/step_*.zip)")
    return found[-1]


def transfer_ratio(rows: dict) -> tuple[float | None, str]:
    """(dream PPO - random) / (real PPO - random) and why it is (not) defined: only when the real-trained
    reference clearly learned something, its 95 % CI above the random mean (else the ratio is noise)."""
    if "random" not in rows:
        return None, "no random baseline"
    random_mean = rows["random"]["mean"]
    if rows["real_ppo"]["ci_low"] <= random_mean:
        return None, "undefined: the real-trained PPO is not better than random (its 95 % CI reaches the random mean)"
    ratio = (rows["dream_ppo"]["mean"] - random_mean) / (rows["real_ppo"]["mean"] - random_mean)
    return ratio, "defined: the real PPO's 95 % CI lies above the random mean"


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(Args, argv, description=__doc__.split("\n\n")[0])
    t_start = time.perf_counter()
    from solaris_env.real_env import RealParallelEnv
    from solaris_env.tasks import JUDGED_TASKS

    # ---- policies and the env --------------------------------------------------------------
    checkpoints = {"dream_ppo": last_checkpoint(args.dream_ppo), "real_ppo": last_checkpoint(args.real_ppo)}
    metas = {role: json.loads(path.with_suffix(".json").read_text()) for role, path in checkpoints.items()}
    ticks = {meta["frames_per_step"] for meta in metas.values()}
    if len(ticks) != 1:
        raise ValueError(f"the two PPO checkpoints were trained with different frames_per_step: "
                         f"{ {role: m['frames_per_step'] for role, m in metas.items()} }")
    for role, meta in metas.items():
        if meta["task"] != args.task:
            raise ValueError(f"--{role.replace('_', '-')} {checkpoints[role]} was trained on task {meta['task']!r}, "
                             f"not --task {args.task!r}")
    (k,) = ticks
    env = RealParallelEnv(num_players=2, world=args.world, resolution=args.resolution, max_steps=args.max_steps,
                          ticks_per_step=k, task=JUDGED_TASKS[args.task](source="truth"))
    starts = make_start_states(args.episodes, args.start_seed, args.world, args.resolution)
    roles = {"dream_ppo": f"ppo:{checkpoints['dream_ppo']}", "real_ppo": f"ppo:{checkpoints['real_ppo']}",
             **{spec: spec for spec in args.references}}
    print(f"transfer: task={args.task} {len(roles)} policies x {args.episodes} real episodes of {args.max_steps} "
          f"steps (k={k})", flush=True)

    # ---- rollouts --------------------------------------------------------------------------
    rows = {}
    for role, spec in roles.items():
        policy, t0 = make_policy(spec), time.perf_counter()
        returns = [run_episode(env, policy, s, args.seed + e, make_policy(args.partner)).env_return
                   for e, s in enumerate(starts)]
        rows[role] = {"policy": portable_text(spec, parts=3), **summarize(returns, resamples=args.resamples),
                      "wall_s": time.perf_counter() - t0}
        if role in metas:
            rows[role]["trained_steps"] = metas[role]["step"]
        print(f"  {role:>10s}: {rows[role]['mean']:6.2f}  [{rows[role]['ci_low']:.2f}, {rows[role]['ci_high']:.2f}]",
              flush=True)

    # ---- report ----------------------------------------------------------------------------
    ratio, note = transfer_ratio(rows)
    results = {
        "task": args.task, "returns": rows, "transfer_ratio": ratio, "transfer_ratio_note": note,
        "setup": {"episodes": args.episodes, "max_steps": args.max_steps, "frames_per_step": k,
                  "resolution": args.resolution, "world": args.world, "partner": args.partner,
                  "start_seed": args.start_seed, "seed": args.seed},
        "machine": {"load_avg_1m_end": os.getloadavg()[0], "cpus": os.cpu_count()},
        "wall_s": time.perf_counter() - t_start,
        "command": " ".join([Path(sys.executable).name, "-m", "agents.transfer",
                             *(portable_text(a, parts=3) for a in (argv if argv is not None else sys.argv[1:]))]),
    }
    out = write_json_atomic(args.out or RESULTS_DIR / f"transfer_{args.task}.json", results)
    print(f"transfer ratio (dream PPO - random) / (real PPO - random) = {ratio} ({note}); wrote {out}", flush=True)
    return results


if __name__ == "__main__":
    main()
