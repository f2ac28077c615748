"""What ``ppo_dream.py`` and ``ppo_real.py`` share: the PPO arguments, checkpoints, and a VecEnv resize.

A checkpoint is ``<run>/checkpoints/step_<timesteps>.zip`` (SB3's format) plus ``step_<timesteps>.json``: the
env it was trained in, the task, the flat action encoding, the observation shape and every argument of the
run. ``agents.policies.PPOPolicy`` needs both files. Both are written through temporary files.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces as gym_spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from agents.common import arg, write_json_atomic
from solaris_env.paths import portable_text


@dataclass
class PPOArgs:
    """Arguments shared by the PPO scripts (each script adds its env's)."""

    task: str = arg("face_partner", "judged task (solaris_env.tasks.JUDGED_TASKS): face_partner | approach_partner | build_structure")
    total_timesteps: int = arg(200_000, "learner steps to train for")
    seed: int = arg(1, "seed of PPO, the envs and the start-state draw")
    out: str | None = arg(None, "run directory (default runs/agents/<script>-<task>-s<seed>)")
    checkpoint_every: int = arg(25_000, "save a checkpoint every this many learner steps (and at the end)")
    max_steps: int = arg(50, "episode length in env steps (one step = the world model's k frames)")
    start_states: int = arg(256, "training start states (reset seeds TRAIN_START_SEED + i)")
    world: str = arg("flat", "engine world of the start states: flat | normal | mixed")
    partner: str = arg("noop", "what drives the partner (Bravo): noop | random")
    keys: str = arg("task", "binary keys the policy may press: 'task' (TASK_KEYS[task]), 'all' (all 23), "
                            "'none' (camera only) or a comma list, e.g. forward,jump")
    camera: str = arg("task", "camera axes the policy may turn: 'task' (TASK_CAMERA_AXES[task]), 'both', 'yaw', 'pitch'")
    camera_bins: int = arg(11, "camera bins per axis of the flat action (odd)")
    camera_max_deg: float = arg(10.0, "largest camera turn per step, degrees")
    n_steps: int = arg(128, "PPO rollout length per env before each update")
    batch_size: int = arg(256, "PPO minibatch size")
    n_epochs: int = arg(4, "PPO epochs per update")
    learning_rate: float = arg(2.5e-4, "Adam learning rate")
    gamma: float = arg(0.99, "discount")
    gae_lambda: float = arg(0.95, "GAE lambda")
    clip_range: float = arg(0.1, "PPO clip range")
    ent_coef: float = arg(0.01, "entropy bonus")
    vf_coef: float = arg(0.5, "value-loss weight")
    torch_threads: int = arg(1, "torch CPU threads (small convs are fastest single-threaded on these VMs)")
    resume: bool = arg(True, "continue from the newest checkpoint in <out>/checkpoints (up to --total-timesteps); "
                             "--no-resume starts over")

    def __post_init__(self):
        from solaris_env.tasks import JUDGED_TASKS

        if self.task not in JUDGED_TASKS:
            raise ValueError(f"task must be one of {sorted(JUDGED_TASKS)}, got {self.task!r}")
        if self.partner not in ("noop", "random"):
            raise ValueError(f"partner must be 'noop' or 'random' (both run in the dream), got {self.partner!r}")
        if self.world not in ("flat", "normal", "mixed"):
            raise ValueError(f"world must be 'flat', 'normal' or 'mixed', got {self.world!r}")
        if self.camera not in ("task", "both", "yaw", "pitch"):
            raise ValueError(f"camera must be 'task', 'both', 'yaw' or 'pitch', got {self.camera!r}")
        try:
            self.codec()  # the codec checks keys, camera bins and range: fail before any env is built
        except ValueError as err:
            if not str(err).startswith("keys"):
                raise
            raise ValueError(f"keys must be 'task', 'all', 'none' or a comma list of distinct binary keys, got "
                             f"{self.keys!r} ({err})") from None
        for name in ("total_timesteps", "checkpoint_every", "max_steps", "start_states", "n_steps", "batch_size",
                     "n_epochs", "torch_threads"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")

    def policy_keys(self) -> tuple[str, ...] | None:
        """The binary keys of the flat action (None: all of them), as given; ``codec()`` checks them."""
        if self.keys == "task":
            return TASK_KEYS[self.task]
        if self.keys == "all":
            return None
        if self.keys == "none":
            return ()
        return tuple(k.strip() for k in self.keys.split(",") if k.strip())

    def camera_axes(self) -> tuple[str, ...]:
        """The camera axes of the flat action."""
        if self.camera == "task":
            return TASK_CAMERA_AXES[self.task]
        return ("pitch", "yaw") if self.camera == "both" else (self.camera,)

    def codec(self):
        """The flat MultiDiscrete action encoding the policy acts in."""
        from solaris_env.spaces import FlatActionCodec

        return FlatActionCodec(camera_bins=self.camera_bins, camera_max_deg=self.camera_max_deg,
                               kind="multidiscrete", keys=self.policy_keys(), camera_axes=self.camera_axes())


# The keys each task's policy may press and the camera axes it may turn (action shaping, as MineRL agents do): a
# policy exploring with all 23 keys spends its steps walking off, dropping items and opening the inventory, and a
# random walk in pitch ends up looking at the sky or the ground, where no partner is.
TASK_KEYS: dict[str, tuple[str, ...]] = {
    "face_partner": (),  # turn to the partner: the camera alone
    "approach_partner": ("forward", "jump", "sprint"),
    "build_structure": ("forward", "jump", "sneak", "use"),
}
TASK_CAMERA_AXES: dict[str, tuple[str, ...]] = {
    "face_partner": ("yaw",),  # the partner stands on the same ground: turn, do not look up or down
    "approach_partner": ("yaw",),
    "build_structure": ("pitch", "yaw"),  # placing needs a look at the ground
}


def ppo_kwargs(args: PPOArgs) -> dict:
    """SB3 ``PPO(...)`` keyword arguments from the shared args."""
    return {"n_steps": args.n_steps, "batch_size": args.batch_size, "n_epochs": args.n_epochs,
            "learning_rate": args.learning_rate, "gamma": args.gamma, "gae_lambda": args.gae_lambda,
            "clip_range": args.clip_range, "ent_coef": args.ent_coef, "vf_coef": args.vf_coef}


def run_dir(args: PPOArgs, script: str) -> Path:
    return Path(args.out) if args.out is not None else Path("runs") / "agents" / f"{script}-{args.task}-s{args.seed}"


def args_record(args: Any) -> dict:
    """The run's arguments as written to ``args.json`` and the checkpoint sidecars: every absolute path made
    portable (``solaris_env.paths``), so a record copied into ``benchmarks/results`` names no machine."""
    def portable(v: Any) -> Any:
        return portable_text(v) if isinstance(v, str) else [portable(x) for x in v] if isinstance(v, list) else v

    return {k: portable(v) for k, v in dataclasses.asdict(args).items()}


# ---------------------------------------------------------------------------------------------
# The agent: new or resumed
# ---------------------------------------------------------------------------------------------


def latest_checkpoint(directory: Path) -> Path | None:
    """The ``step_<timesteps>.zip`` of ``directory`` with the most steps (and a sidecar), or None."""
    found = [p for p in Path(directory).glob("step_*.zip") if p.with_suffix(".json").is_file()]
    return max(found, key=lambda p: int(p.stem.split("_")[1]), default=None)


def make_ppo(args: PPOArgs, envs: VecEnv, out: Path) -> Any:
    """SB3 PPO (CnnPolicy) on ``envs``, logging to stdout and ``<out>/progress.csv``; with ``args.resume`` and a
    checkpoint in ``<out>/checkpoints``, the newest one is loaded (weights, optimiser, step count) and the old
    ``progress.csv`` is kept as ``progress-<step>.csv`` (SB3's logger starts the file anew)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure

    last = latest_checkpoint(out / "checkpoints") if args.resume else None
    if last is None:
        model = PPO("CnnPolicy", envs, seed=args.seed, device="cpu", verbose=1, **ppo_kwargs(args))
    else:
        model = PPO.load(last, env=envs, device="cpu", **ppo_kwargs(args))
        model.set_random_seed(args.seed + model.num_timesteps)  # a fresh stream, reproducible per resume point
        log = out / "progress.csv"
        if log.is_file():
            os.replace(log, out / f"progress-{model.num_timesteps:09d}.csv")
        print(f"resumed from {last} at {model.num_timesteps} steps", flush=True)
    model.set_logger(configure(str(out), ["stdout", "csv"]))
    return model


def learn(model: Any, args: PPOArgs, checkpoints: CheckpointEvery) -> None:
    """Train up to ``args.total_timesteps`` learner steps in all (a resumed model counts its past steps)."""
    checkpoints.start_at(model.num_timesteps)
    remaining = args.total_timesteps - model.num_timesteps
    if remaining > 0:
        model.learn(total_timesteps=remaining, callback=checkpoints, reset_num_timesteps=model.num_timesteps == 0)
        checkpoints.save_last()


# ---------------------------------------------------------------------------------------------
# Checkpoints
# ---------------------------------------------------------------------------------------------


def checkpoint_meta(args: PPOArgs, env_kind: str, obs_shape: tuple[int, ...], frames_per_step: int) -> dict:
    """The sidecar of every checkpoint of a run (``step`` is added at save time). ``frames_per_step``: engine
    ticks per env step the policy was trained with (the dream's k; the real env's ticks_per_step)."""
    return {"algo": "ppo", "env": env_kind, "task": args.task, "seed": args.seed, "obs_shape": list(obs_shape),
            "frames_per_step": int(frames_per_step),
            "codec": args.codec().config(),
            "args": args_record(args)}


def save_checkpoint(model: Any, path: Path, meta: dict) -> Path:
    """``model.save`` to ``path`` (a ``.zip``) and its ``.json`` sidecar, each through a temporary file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.zip")
    model.save(tmp)
    os.replace(tmp, path)
    write_json_atomic(path.with_suffix(".json"), {**meta, "step": int(model.num_timesteps)})
    return path


class CheckpointEvery(BaseCallback):
    """Saves ``directory/step_<timesteps>.zip`` (+ sidecar) each time the learner passes a multiple of
    ``every`` steps; ``save_last()`` after ``learn`` saves the final step unless it was just saved.

    Args:
        every: learner steps between checkpoints.
        directory: where the checkpoints go.
        meta: the sidecar content (``checkpoint_meta``).
    """

    def __init__(self, every: int, directory: Path, meta: dict):
        super().__init__()
        if every < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.every, self.directory, self.meta = every, Path(directory), meta
        self.saved: list[Path] = []
        self._last_saved_step = 0

    def _on_step(self) -> bool:
        if self.num_timesteps // self.every > self._last_saved_step // self.every:
            self._save(self.num_timesteps)
        return True

    def start_at(self, step: int) -> None:
        """A resumed run: the checkpoint of ``step`` exists already."""
        self._last_saved_step = int(step)

    def save_last(self) -> None:
        if self.model.num_timesteps != self._last_saved_step:
            self._save(self.model.num_timesteps)

    def _save(self, step: int) -> None:
        path = save_checkpoint(self.model, self.directory / f"step_{step:09d}.zip", self.meta)
        self.saved.append(path)
        self._last_saved_step = step
        print(f"checkpoint {path}", flush=True)


# ---------------------------------------------------------------------------------------------
# Observations
# ---------------------------------------------------------------------------------------------


class VecResize(VecEnvWrapper):
    """Image observations (and ``terminal_observation`` infos) resized to size x size, area averaging down and
    bilinear up: lets a small world model (the 32 x 32 test preset) feed SB3's CNN, which needs >= 36 x 36."""

    def __init__(self, venv: VecEnv, size: int):
        if size < 1:
            raise ValueError(f"size must be >= 1, got {size}")
        self.size = int(size)
        c = venv.observation_space.shape[-1]
        super().__init__(venv, observation_space=gym_spaces.Box(0, 255, (self.size, self.size, c), np.uint8))

    def _resize(self, frame_HW3: np.ndarray) -> np.ndarray:
        import cv2

        s = self.size
        interp = cv2.INTER_AREA if s <= frame_HW3.shape[0] else cv2.INTER_LINEAR
        return cv2.resize(frame_HW3, (s, s), interpolation=interp).reshape(s, s, frame_HW3.shape[-1])

    def reset(self) -> np.ndarray:
        return np.stack([self._resize(o) for o in self.venv.reset()])

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        for info in infos:
            if "terminal_observation" in info:
                info["terminal_observation"] = self._resize(info["terminal_observation"])
        return np.stack([self._resize(o) for o in obs]), rewards, dones, infos
