"""What the agent scripts share: CLI args from dataclasses, start states, env pieces, checkpoints, atomic writes.

* :func:`parse_args`: a dataclass of arguments (``arg(default, help)`` fields) -> argparse -> an instance.
* :func:`make_start_states`: the episodes' start states: an engine world with the two players spawned 6-10
  blocks apart, the learner (Alpha) then turned by a random yaw, so it has to find its partner. Training and
  evaluation draw from disjoint seed ranges (``TRAIN_START_SEED``, ``EVAL_START_SEED``).
* :class:`StartFromStates`: a single-agent gym env starting each episode from one of those states.
* :func:`write_json_atomic`: results files appear whole or not at all.

The PPO pieces (they import Stable-Baselines3 and torch) are in ``agents/ppo_common.py``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import types
import typing
from dataclasses import field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

LEARNER, PARTNER = "Alpha", "Bravo"
TRAIN_START_SEED = 0  # training start states use reset seeds TRAIN_START_SEED + i
EVAL_START_SEED = 100_000  # held-out start states for evaluation and transfer (disjoint from training)
RESULTS_DIR = Path(__file__).resolve().parent.parent / "benchmarks" / "results"


# ---------------------------------------------------------------------------------------------
# Arguments
# ---------------------------------------------------------------------------------------------


def arg(default: Any, help: str) -> Any:
    """A dataclass field carrying its ``--help`` text."""
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata={"help": help})
    return field(default=default, metadata={"help": help})


def _scalar_type(hint: Any) -> tuple[Any, bool]:
    """(the argparse type, optional?) of a field annotation: int, float, str, bool, X | None, list[X]."""
    args = typing.get_args(hint)
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        inner = [a for a in args if a is not type(None)]
        if len(inner) != 1:
            raise TypeError(f"unsupported annotation {hint}")
        return inner[0], True
    return hint, False


def _none_or(convert: Any) -> Any:
    """argparse type of an ``X | None`` field: the word ``none`` (any case) is None, anything else ``convert``."""
    return lambda text: None if text.lower() == "none" else convert(text)


def parse_args(cls: type, argv: list[str] | None = None, description: str | None = None) -> Any:
    """Parse ``argv`` into the dataclass ``cls``: one ``--field-name`` per field, its type from the
    annotation, its help from ``arg(..., help)``; ``X | None`` fields accept the word ``none``."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        flag = "--" + f.name.replace("_", "-")
        help_text = f.metadata.get("help", "")
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        hint, optional = _scalar_type(hints[f.name])
        if hint is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default, help=help_text)
        elif typing.get_origin(hint) is list:
            (item,) = typing.get_args(hint)
            parser.add_argument(flag, nargs="+", type=item, default=default, help=help_text)
        else:
            parser.add_argument(flag, type=_none_or(hint) if optional else hint, default=default, help=help_text)
    return cls(**vars(parser.parse_args(argv)))


# ---------------------------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------------------------


def write_json_atomic(path: str | Path, obj: Any) -> Path:
    """Write ``obj`` as indented, strict JSON (NaN and infinities become null) through a temporary file
    renamed into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(_finite_or_none(obj), indent=1, default=_json_default, allow_nan=False) + "\n")
    os.replace(tmp, path)
    return path


def _finite_or_none(obj: Any) -> Any:
    if isinstance(obj, float | np.floating):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite_or_none(v) for v in obj]
    return obj


def _json_default(obj: Any) -> Any:
    if isinstance(obj, (np.integer, np.floating)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


# ---------------------------------------------------------------------------------------------
# Start states
# ---------------------------------------------------------------------------------------------


def make_start_states(count: int, seed: int, world: str = "flat", resolution: int | tuple[int, int] = 64,
                      max_turn_deg: float = 180.0) -> list:
    """``count`` engine states: ``RealParallelEnv(world=world).reset(seed=seed + i)`` (players 6-10 blocks
    apart, facing each other), then the learner turned by a yaw uniform in +-``max_turn_deg`` (drawn from
    ``seed + i``) in one tick while the partner stands still. ``resolution`` only picks the renderer used
    on the way (reuse the size of the envs in the process: each size compiles once)."""
    from solaris_env.real_env import RealParallelEnv
    from solaris_env.spaces import CAMERA_KEY, noop

    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    env = RealParallelEnv(num_players=2, world=world, resolution=resolution)
    states = []
    for i in range(count):
        env.reset(seed=seed + i)
        turn = noop()
        turn[CAMERA_KEY] = np.array([0.0, np.random.default_rng(seed + i).uniform(-max_turn_deg, max_turn_deg)],
                                    np.float32)
        # one engine tick with the whole turn, on the game itself: the env would spread a turn over 8.59 deg
        # ticks (spaces.step_ticks) and carry the rest, which a snapshot does not hold
        env.game.step([turn if name == LEARNER else noop() for name in env.possible_agents])
        states.append(env.engine_state())
    return states


class StartFromStates(gym.Wrapper):
    """A single-agent gym env that starts each episode from one of ``states`` (drawn by the reset seed).

    Args:
        env: a single-agent env of ours whose reset accepts ``options={"engine_state": ...}``.
        states: a non-empty list of ``EngineState`` (:func:`make_start_states`).
    """

    def __init__(self, env: gym.Env, states: list):
        super().__init__(env)
        if not states:
            raise ValueError("states must be a non-empty list of EngineState")
        self.states = list(states)
        self._rng = np.random.default_rng()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        state = self.states[int(self._rng.integers(len(self.states)))]
        return self.env.reset(seed=seed, options={**(options or {}), "engine_state": state})
