"""PPO (Stable-Baselines3, CnnPolicy) trained ONLY in the dream: the world model generates every frame and the
judges score the task from those frames. ``agents/transfer.py`` then measures it in the real engine.

    .venv/bin/python -m agents.ppo_dream --task face_partner --total-timesteps 200000 --seed 1 \\
        --out runs/agents/ppo_dream-face_partner-s1

The learner is Alpha in ``--num-worlds`` two-player dream worlds stepped in ONE batched model call
(``DreamVectorEnv`` -> ``SB3VecEnv``), the partner stands still (``--partner``). Worlds start from
``--start-states`` engine states where Alpha was turned away by a random yaw (``agents.common.make_start_states``;
the engine renders them, the model continues). The reward is the judge variant of the task (``source="judge"``).
Checkpoints: ``<out>/checkpoints/step_<timesteps>.zip`` + ``.json`` every ``--checkpoint-every`` steps;
SB3's logs (episode return ``rollout/ep_rew_mean``, losses, fps) go to stdout and ``<out>/progress.csv``.
The same command again resumes from the newest checkpoint up to ``--total-timesteps`` (``--no-resume`` starts
over). Actions: the flat MultiDiscrete of the task's keys and camera axes only (``ppo_common.TASK_KEYS`` /
``TASK_CAMERA_AXES``; ``--keys``, ``--camera``): face_partner turns in yaw and presses nothing.
``--preset test --obs-size 36`` runs the random-init test model (the smoke test).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from agents.common import (
    LEARNER,
    TRAIN_START_SEED,
    arg,
    make_start_states,
    parse_args,
    write_json_atomic,
)
from agents.ppo_common import (
    CheckpointEvery,
    PPOArgs,
    VecResize,
    args_record,
    checkpoint_meta,
    learn,
    make_ppo,
    run_dir,
)


@dataclass
class Args(PPOArgs):
    checkpoint: str | None = arg(None, "world-model checkpoint (default: the shipped solaris_env/assets/default)")
    preset: str | None = arg(None, "a RANDOM-INIT world-model preset instead (tiny | test): smoke tests only")
    num_worlds: int = arg(8, "dream worlds batched in one model call")
    obs_size: int | None = arg(None, "resize the learner's frames to this square size (default: the model's)")

    def __post_init__(self):
        super().__post_init__()
        if self.num_worlds < 1:
            raise ValueError(f"num_worlds must be >= 1, got {self.num_worlds}")
        if self.obs_size is not None and self.obs_size < 36:
            raise ValueError(f"obs_size must be >= 36 for SB3's CnnPolicy, got {self.obs_size}")


def make_env(args: Args, model, start_states: list):
    """The dream worlds of ``model`` as one SB3 VecEnv of the learner's views (flat MultiDiscrete actions)."""
    from stable_baselines3.common.vec_env import VecMonitor

    from solaris_env.tasks import JUDGED_TASKS
    from solaris_env.vector_env import DreamVectorEnv
    from solaris_env.wrappers.sb3 import SB3VecEnv

    worlds = DreamVectorEnv(
        args.num_worlds, model=model, num_players=2,
        max_steps=args.max_steps, task=JUDGED_TASKS[args.task](source="judge"), start_states=start_states,
    )
    envs = SB3VecEnv(worlds, learners=[LEARNER], codec=args.codec(), opponent=args.partner)
    if args.obs_size is not None and args.obs_size != worlds.height:
        envs = VecResize(envs, args.obs_size)
    envs = VecMonitor(envs)  # episode returns for rollout/ep_rew_mean
    return envs


def main(argv: list[str] | None = None) -> None:
    args = parse_args(Args, argv, description=__doc__.split("\n\n")[0])

    # ---- setup -----------------------------------------------------------------------------
    import torch

    from solaris_env.dream_env import build_model

    torch.set_num_threads(args.torch_threads)
    out = run_dir(args, "ppo_dream")
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "args.json", args_record(args))

    # ---- world model and envs --------------------------------------------------------------
    t0 = time.perf_counter()
    world_model = build_model(args.checkpoint, args.preset, num_players=2, seed_model=args.seed)
    height, width, _ = world_model.frame_shape
    start_states = make_start_states(args.start_states, TRAIN_START_SEED, args.world, (height, width))
    envs = make_env(args, world_model, start_states)
    print(f"ppo_dream: world model {height}x{width}, k={world_model.frames_per_step} frames per step, "
          f"{len(start_states)} start states, built in {time.perf_counter() - t0:.0f} s", flush=True)

    # ---- agent -----------------------------------------------------------------------------
    model = make_ppo(args, envs, out)  # new, or resumed from <out>/checkpoints
    batch = args.n_steps * envs.num_envs  # derived: learner steps per PPO update
    print(f"ppo_dream: task={args.task} worlds={args.num_worlds} obs={envs.observation_space.shape} "
          f"steps/update={batch} updates={-(-args.total_timesteps // batch)} out={out}", flush=True)

    # ---- train -----------------------------------------------------------------------------
    checkpoints = CheckpointEvery(args.checkpoint_every, out / "checkpoints",
                                  checkpoint_meta(args, "dream", envs.observation_space.shape,
                                                  world_model.frames_per_step))
    t0 = time.perf_counter()
    start = model.num_timesteps
    learn(model, args, checkpoints)
    wall = time.perf_counter() - t0
    print(f"done: {model.num_timesteps} steps ({model.num_timesteps - start} this run) in {wall:.0f} s "
          f"({(model.num_timesteps - start) / max(wall, 1e-9):.1f} SPS); "
          f"{len(checkpoints.saved)} checkpoints in {out / 'checkpoints'}", flush=True)
    envs.close()


if __name__ == "__main__":
    main()
