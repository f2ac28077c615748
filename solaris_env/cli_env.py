"""``solaris-env``: look at and drive the envs from the command line.

    solaris-env info                                   # envs, models, start scenes, tasks
    solaris-env rollout --kind real --steps 200 --policy bot --out rollout.mp4
    solaris-env rollout --kind dream --preset tiny --steps 50 --out dream.mp4 --rrd dream.rrd
    solaris-env play --kind real                       # a local web page: drive Alpha with keyboard and mouse
    solaris-env play --kind dream --agent Bravo --window  # the same in an OpenCV window (needs a display)

Heavy frameworks (jax, torch) are imported only inside the commands, so ``--help`` is instant. Errors print one
line (``--debug`` shows the traceback); ``rollout`` checks ``--out`` / ``--rrd`` before it builds anything; Ctrl-C
ends ``info`` and ``rollout`` with one line and status 130 and stops ``play`` (status 0).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from solaris_env.cli_support import (
    add_debug_flag,
    check_output_file,
    non_negative_int,
    positive_int,
    run_command,
)

# ---------------------------------------------------------------------------------------------
# Building envs from arguments
# ---------------------------------------------------------------------------------------------


def _add_env_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--kind", choices=("dream", "real"), default="real", help="world model or engine")
    p.add_argument("--checkpoint", type=Path, help="dream: a world-model checkpoint (default: the shipped one)")
    p.add_argument("--preset", choices=("tiny", "test", "solaris"), help="dream: a RANDOM-INIT preset instead")
    p.add_argument("--players", type=positive_int, default=2, help="number of players")
    p.add_argument("--resolution", type=positive_int, default=64, help="real: frame size (square)")
    p.add_argument("--world", choices=("flat", "normal", "mixed"), default=None,
                   help="real: world kind (default: mixed; the minecraft backend has only flat)")
    p.add_argument("--backend", choices=("voxel", "minecraft"), default="voxel",
                   help="real: the voxel engine or real Minecraft in real time (`solaris-engine setup-minecraft`)")
    p.add_argument("--task", default=None, help="task name (solaris_env.tasks.TASKS); default: zero reward")
    p.add_argument("--seed", type=non_negative_int, default=0, help="reset seed")
    add_debug_flag(p)


def _make_env(args, max_steps: int, render_mode: str | None = None):
    if args.kind == "dream":
        from solaris_env.dream_env import DreamParallelEnv

        return DreamParallelEnv(checkpoint=args.checkpoint, preset=args.preset, num_players=args.players,
                                max_steps=max_steps, task=args.task, render_mode=render_mode)
    from solaris_env.real_backends import make_real_env

    world = args.world or ("flat" if args.backend == "minecraft" else "mixed")
    return make_real_env(backend=args.backend, num_players=args.players, world=world, resolution=args.resolution,
                         max_steps=max_steps, task=args.task, render_mode=render_mode)


# ---------------------------------------------------------------------------------------------
# Commands
# ---------------------------------------------------------------------------------------------


def cmd_info(args) -> int:
    import solaris_env
    from solaris_env.dream_env import DEFAULT_CHECKPOINT
    from solaris_env.start_scenes import SCENES_PATH, load_bundle
    from solaris_env.tasks import TASKS
    from solaris_env.world_model.config import PRESETS
    from solaris_env.wrappers.opponents import OPPONENTS
    from solaris_env.wrappers.single_agent import ENV_IDS

    print(f"solaris_env {solaris_env.__version__}")
    print("parallel envs : solaris_env.parallel_env('dream' | 'real'), DreamVectorEnv (N worlds, one model call)")
    print(f"gymnasium ids : {', '.join(ENV_IDS)}")
    shipped = "present" if DEFAULT_CHECKPOINT.exists() else "NOT shipped yet (use --preset for random-init weights)"
    print(f"default model : {DEFAULT_CHECKPOINT} ({shipped})")
    print(f"presets       : {', '.join(sorted(PRESETS))} (random-init)")
    if SCENES_PATH.exists():
        b = load_bundle(str(SCENES_PATH))
        print(f"start scenes  : {len(b['seeds'])} per player count {b['player_counts'].tolist()} at "
              f"{b['resolutions'].tolist()} px ({SCENES_PATH.stat().st_size / 1e6:.2f} MB)")
    else:
        print(f"start scenes  : missing ({SCENES_PATH}); build with python -m solaris_env.start_scenes")
    print(f"tasks         : {', '.join(TASKS)}")
    print(f"policies      : {', '.join(OPPONENTS)}")
    return 0


def cmd_rollout(args) -> int:
    """Run one episode of ``--steps`` steps with every player on ``--policy``; write all views to an mp4."""
    import numpy as np

    from solaris_env.env_common import side_by_side
    from solaris_env.wrappers.opponents import make_opponents
    from solaris_env.wrappers.video import Mp4Writer

    check_output_file(args.out, ".mp4", "--out")  # before the (slow) env: a bad path is a one-line error at once
    if args.rrd is not None:
        check_output_file(args.rrd, ".rrd", "--rrd")
    env = _make_env(args, max_steps=args.steps)
    if args.rrd is not None:
        from solaris_env.wrappers.rerun_log import RerunRecorder

        env = RerunRecorder(env, path=args.rrd)
    writer = Mp4Writer(args.out)
    start = time.perf_counter()
    obs, _ = env.reset(seed=args.seed)
    policies = make_opponents(env.unwrapped, args.policy, args.seed)
    returns = dict.fromkeys(env.possible_agents, 0.0)

    def write():
        frames_PkHW3 = env.unwrapped.step_frames()
        for t in range(frames_PkHW3.shape[1]):
            writer.write(side_by_side(frames_PkHW3[:, t]))

    write()
    steps = 0
    while env.agents:
        obs, rewards, *_ = env.step({a: policies[a].act(obs[a]) for a in env.agents})
        for a, r in rewards.items():
            returns[a] += r
        steps += 1
        write()
    seconds = time.perf_counter() - start
    env.close()
    path = writer.close()
    print(f"{args.kind}: {steps} steps in {seconds:.1f} s ({steps / seconds:.1f} steps/s incl. compile), "
          f"{writer.frames} frames -> {path}")
    print("returns: " + ", ".join(f"{a} {r:.3f}" for a, r in returns.items()))
    if args.rrd is not None:
        print(f"rerun: {args.rrd} (open with `rerun {args.rrd}`)")
    return 0 if np.isfinite(list(returns.values())).all() else 1


def cmd_play(args) -> int:
    """Drive ``--agent`` with keyboard and mouse (a local web page, or ``--window``); the others follow ``--policy``."""
    from solaris_env.play import PlaySession, run_window, serve_play, window_problem

    if args.window and (problem := window_problem()) is not None:
        raise SystemExit(f"solaris-env play --window: {problem}; drop --window to play in a web page instead")
    env = _make_env(args, max_steps=args.max_steps)
    session = PlaySession(env, args.agent, args.policy, args.seed)
    fps = args.fps if args.fps is not None else env.metadata["render_fps"]  # default: real time
    if args.window:
        run_window(session, fps)
    else:
        serve_play(session, args.host, args.port, fps)
    return 0


# ---------------------------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="solaris-env", description=__doc__.split("\n\n")[0].strip("` "),
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    add_debug_flag(parser, top=True)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("info", help="what is installed: envs, models, start scenes, tasks")
    add_debug_flag(p)
    p.set_defaults(run=cmd_info)
    p = sub.add_parser("rollout", help="run an episode with a scripted/random policy and write an mp4")
    _add_env_args(p)
    p.add_argument("--steps", type=positive_int, default=100, help="episode length in env steps")
    p.add_argument("--policy", choices=("random", "noop", "bot"), default="random",
                   help="what drives every player ('bot': real only)")
    p.add_argument("--out", type=Path, default=Path("rollout.mp4"), help="the mp4 (all players side by side)")
    p.add_argument("--rrd", type=Path, default=None, help="also write a Rerun recording here")
    p.set_defaults(run=cmd_rollout)
    p = sub.add_parser("play", help="drive one player with keyboard and mouse (local web page or OpenCV window)")
    _add_env_args(p)
    p.add_argument("--agent", default="Alpha", help="the player you drive (Alpha, Bravo, ...)")
    p.add_argument("--policy", choices=("random", "noop", "bot"), default="noop", help="what drives the others")
    p.add_argument("--max-steps", type=positive_int, default=100_000, help="episode length")
    p.add_argument("--fps", type=float, default=None, help="env steps per second (default: real time, the env's "
                   "render_fps: 20 for real, 5 for dream; the env may be slower)")
    p.add_argument("--window", action="store_true", help="an OpenCV window instead of the web page "
                   "(needs a display and a GUI build of OpenCV)")
    p.add_argument("--host", default="127.0.0.1", help="web page: the address to listen on (keep it local)")
    p.add_argument("--port", type=int, default=8765, help="web page: the port (0: any free one)")
    p.set_defaults(run=cmd_play)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Errors print one line (``--debug``: the traceback); Ctrl-C prints one line and exits with status 130
    (``solaris_env.cli_support``; ``play`` stops on Ctrl-C by design and exits 0)."""
    args = build_parser().parse_args(argv)
    return run_command("solaris-env", args.run, args, debug=args.debug)


if __name__ == "__main__":
    sys.exit(main())
