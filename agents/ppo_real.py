"""PPO (Stable-Baselines3, CnnPolicy) trained in the REAL engine with ground-truth rewards: the reference that the
dream-trained policy (``agents/ppo_dream.py``) is compared with in ``agents/transfer.py``.

    .venv/bin/python -m agents.ppo_real --task face_partner --total-timesteps 200000 --seed 1 \\
        --out runs/agents/ppo_real-face_partner-s1

The learner is Alpha in a two-player ``RealParallelEnv`` (64 x 64 frames, ``ticks_per_step`` = the world model's
k = 4 frames per step, so a step means the same in both envs), the partner stands still (``--partner``). Episodes
start from ``--start-states`` engine states where Alpha was turned away by a random yaw
(``agents.common.make_start_states``). The task's reward comes from the engine (``<task>_truth``).
Checkpoints: ``<out>/checkpoints/step_<timesteps>.zip`` + ``.json`` every ``--checkpoint-every`` steps;
SB3's logs (episode return ``rollout/ep_rew_mean``, losses, fps) go to stdout and ``<out>/progress.csv``.
The same command again resumes from the newest checkpoint up to ``--total-timesteps`` (``--no-resume`` starts
over). Actions: the flat MultiDiscrete of the task's keys and camera axes only (``ppo_common.TASK_KEYS`` /
``TASK_CAMERA_AXES``; ``--keys``, ``--camera``): face_partner turns in yaw and presses nothing.
Measured speed is in the docstring of ``agents/evaluate.py`` once the lead has run it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from agents.common import (
    TRAIN_START_SEED,
    StartFromStates,
    arg,
    make_start_states,
    parse_args,
    write_json_atomic,
)
from agents.ppo_common import (
    CheckpointEvery,
    PPOArgs,
    args_record,
    checkpoint_meta,
    learn,
    make_ppo,
    run_dir,
)


@dataclass
class Args(PPOArgs):
    num_envs: int = arg(8, "real envs stepped in turn (DummyVecEnv)")
    resolution: int = arg(64, "frame size (square; >= 36 for SB3's CNN); the dream model's is 64")
    ticks_per_step: int = arg(4, "engine ticks per env step: the world model's frames_per_step")
    view_distance: float = arg(48.0, "render distance in blocks (as the world model's training data)")

    def __post_init__(self):
        super().__post_init__()
        if self.resolution < 36:
            raise ValueError(f"resolution must be >= 36 for SB3's CnnPolicy, got {self.resolution}")
        if self.num_envs < 1 or self.ticks_per_step < 1:
            raise ValueError(f"num_envs and ticks_per_step must be >= 1, got {self.num_envs}, {self.ticks_per_step}")


def make_env(args: Args, start_states: list):
    """A thunk building one single-agent real env (the learner's view, flat MultiDiscrete actions)."""

    def thunk():
        from stable_baselines3.common.monitor import Monitor

        from solaris_env.tasks import JUDGED_TASKS
        from solaris_env.wrappers.single_agent import make_real

        env = make_real(
            opponent=args.partner,
            flatten="multidiscrete", camera_bins=args.camera_bins, camera_max_deg=args.camera_max_deg,
            flatten_keys=args.policy_keys(), flatten_camera_axes=args.camera_axes(),
            num_players=2, world=args.world, resolution=args.resolution, view_distance=args.view_distance,
            max_steps=args.max_steps, ticks_per_step=args.ticks_per_step,
            task=JUDGED_TASKS[args.task](source="truth"),
        )
        env = StartFromStates(env, start_states)
        env = Monitor(env)  # episode returns for rollout/ep_rew_mean
        return env

    return thunk


def main(argv: list[str] | None = None) -> None:
    args = parse_args(Args, argv, description=__doc__.split("\n\n")[0])

    # ---- setup -----------------------------------------------------------------------------
    import torch
    from stable_baselines3.common.vec_env import DummyVecEnv

    torch.set_num_threads(args.torch_threads)
    out = run_dir(args, "ppo_real")
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "args.json", args_record(args))

    # ---- envs ------------------------------------------------------------------------------
    start_states = make_start_states(args.start_states, TRAIN_START_SEED, args.world, args.resolution)
    envs = DummyVecEnv([make_env(args, start_states) for _ in range(args.num_envs)])

    # ---- agent -----------------------------------------------------------------------------
    model = make_ppo(args, envs, out)  # new, or resumed from <out>/checkpoints
    batch = args.n_steps * args.num_envs  # derived: learner steps per PPO update
    print(f"ppo_real: task={args.task} envs={args.num_envs} obs={envs.observation_space.shape} "
          f"steps/update={batch} updates={-(-args.total_timesteps // batch)} out={out}", flush=True)

    # ---- train -----------------------------------------------------------------------------
    checkpoints = CheckpointEvery(args.checkpoint_every, out / "checkpoints",
                                  checkpoint_meta(args, "real", envs.observation_space.shape, args.ticks_per_step))
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
