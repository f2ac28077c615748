"""Policies for the partner tasks, all with one interface: ``reset(env, agent, seed)`` then ``act(obs) -> action``.

A policy is an :class:`~solaris_env.wrappers.opponents.Opponent` (so any of them can also drive the partner in
the single-agent and SB3 wrappers): ``reset`` is called at each episode start with the (unwrapped) env and the
agent it plays, ``act`` takes that agent's observation, uint8 (H, W, 3), and returns an env action (the
MineRL dict of ``solaris_env.spaces``).

* ``random``: :class:`RandomPolicy`, uniform keys, camera uniform in +-``camera_max_deg``.
* ``noop``: stands still.
* ``spin:DEG``: :class:`SpinPolicy`, open loop: turns DEG degrees right every step.
* ``seeker:NOISE`` / ``seeker-walk:NOISE``: :class:`JudgeSeekerPolicy`, scripted from the frames: the
  ``visible`` and ``position`` judges say where the partner is, the policy turns toward it (scanning when no
  player is seen; ``-walk`` also walks forward when the partner is centred); with probability NOISE a step
  is random.
  Runs in the dream and the real env.
* ``bot:NOISE`` / ``bot-walk:NOISE``: :class:`EngineSeekerBot`, the same behaviour from the engine's ground
  truth (real env only): an upper reference that reads no pixels.
* ``ppo:PATH``: :class:`PPOPolicy`, an SB3 PPO checkpoint written by ``agents/ppo_dream.py`` or
  ``agents/ppo_real.py`` (its ``.json`` sidecar gives the action encoding and the observation size).

``make_policy(spec)`` builds one from those strings (``POLICIES`` lists the kinds). Camera turns stay within
+-20 degrees per step (``spaces.CAMERA_CLIP_DEG``), which a dream step of k = 4 frames and the real env at
``ticks_per_step=4`` turn in full (up to 4 x 8.59 deg, ``spaces.CAMERA_TICK_LIMIT_DEG``; more would be carried
over to the next steps, the same in both envs).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from solaris_env.spaces import (
    CAMERA_CLIP_DEG,
    CAMERA_KEY,
    FlatActionCodec,
    make_action_space,
    noop,
)
from solaris_env.tasks import shared_judge
from solaris_env.wrappers.opponents import Opponent

TURN_DEG = 10.0  # scripted turn per step: a quarter of the middle third of the 125-degree-wide view
SCAN_DEG = 15.0  # scripted turn per step while no partner is seen


def _turn(dyaw_deg: float, **keys: int) -> dict[str, Any]:
    """An env action turning ``dyaw_deg`` degrees (+ = right) with the given keys held."""
    action = noop()
    action[CAMERA_KEY] = np.array([0.0, dyaw_deg], np.float32)
    action.update(keys)
    return action


def _check_noise(noise: float) -> float:
    if not 0.0 <= noise <= 1.0:
        raise ValueError(f"noise must be in [0, 1], got {noise}")
    return float(noise)


def _check_turn(deg: float, name: str) -> float:
    if not 0.0 <= abs(deg) <= CAMERA_CLIP_DEG:
        raise ValueError(f"{name} must be within +-{CAMERA_CLIP_DEG} degrees per step, got {deg}")
    return float(deg)


# ---------------------------------------------------------------------------------------------
# Baselines
# ---------------------------------------------------------------------------------------------


class Policy(Opponent):
    """Base: stands still. ``name`` is the spec it was built from (``make_policy``); ``needs_engine`` is True
    for policies that read the engine's game state (real env only)."""

    name = "noop"
    needs_engine = False


class RandomPolicy(Policy):
    """Uniformly random keys; camera [dpitch, dyaw] uniform in +-``camera_max_deg`` (seeded by ``reset``).

    Args:
        camera_max_deg: largest camera turn per step, degrees (at most the model's per-tick clip).
    """

    name = "random"

    def __init__(self, camera_max_deg: float = TURN_DEG):
        self.camera_max_deg = _check_turn(camera_max_deg, "camera_max_deg")
        self._space = make_action_space()

    def reset(self, env: Any, agent: str, seed: int | None) -> None:
        self._space.seed(seed)

    def act(self, observation: np.ndarray) -> dict[str, Any]:
        action = self._space.sample()
        action[CAMERA_KEY] = (action[CAMERA_KEY] / 180.0 * self.camera_max_deg).astype(np.float32)
        return action


class SpinPolicy(Policy):
    """Open loop: turn ``deg`` degrees right every step (finds the partner once per turn, never stops on it)."""

    def __init__(self, deg: float = SCAN_DEG):
        self.deg = _check_turn(deg, "deg")
        self.name = f"spin:{deg:g}"

    def act(self, observation: np.ndarray) -> dict[str, Any]:
        return _turn(self.deg)


# ---------------------------------------------------------------------------------------------
# Scripted seekers: from the frames (judge) or from the engine (ground truth)
# ---------------------------------------------------------------------------------------------


class _Seeker(Policy):
    """Shared behaviour: partner on the left -> turn left, right -> turn right, centred -> hold (and walk
    forward with ``walk``), not seen -> scan right. With probability ``noise`` a step is random instead."""

    kind = "seeker"

    def __init__(self, noise: float = 0.0, walk: bool = False, turn_deg: float = TURN_DEG,
                 scan_deg: float = SCAN_DEG):
        self.noise, self.walk = _check_noise(noise), bool(walk)
        self.turn_deg, self.scan_deg = _check_turn(turn_deg, "turn_deg"), _check_turn(scan_deg, "scan_deg")
        self.name = f"{self.kind}{'-walk' if walk else ''}:{noise:g}"
        self._random = RandomPolicy()
        self._rng = np.random.default_rng()

    def reset(self, env: Any, agent: str, seed: int | None) -> None:
        self._rng = np.random.default_rng(seed)
        self._random.reset(env, agent, int(self._rng.integers(2**31 - 1)))

    def act(self, observation: np.ndarray) -> dict[str, Any]:
        if self.noise > 0.0 and self._rng.random() < self.noise:
            return self._random.act(observation)
        return self._act_on(self.where(observation))

    def where(self, observation: np.ndarray) -> str:
        """"left" / "center" / "right" / "no player": where the partner is on this player's screen."""
        raise NotImplementedError

    def _act_on(self, where: str) -> dict[str, Any]:
        if where == "left":
            return _turn(-self.turn_deg)
        if where == "right":
            return _turn(self.turn_deg)
        if where == "center":
            return _turn(0.0, forward=int(self.walk))
        return _turn(self.scan_deg)


class JudgeSeekerPolicy(_Seeker):
    """The seeker reading its own frame with the ``position`` judge (dream and real env).

    Args:
        noise: probability of a random step instead of the scripted one.
        walk: walk forward while the partner is centred (the approach task's behaviour).
        turn_deg, scan_deg: turn per step toward a seen partner / while scanning.
        judge_dir: probe weights (None: the shipped judges).
    """

    kind = "seeker"

    def __init__(self, noise: float = 0.0, walk: bool = False, turn_deg: float = TURN_DEG,
                 scan_deg: float = SCAN_DEG, judge_dir: str | None = None):
        super().__init__(noise, walk, turn_deg, scan_deg)
        self.judge_dir = judge_dir

    def where(self, observation: np.ndarray) -> str:
        judge = shared_judge(self.judge_dir)
        if judge.answer("visible", observation)[0] != "yes":  # the face task's gate against false sightings
            return "no player"
        return judge.answer("position", observation)[0]


class EngineSeekerBot(_Seeker):
    """The seeker reading the engine's game state (real env only): turns toward the partner's yaw and
    counts it centred within ``centre_deg`` degrees. Same noise and walking as :class:`JudgeSeekerPolicy`.

    Args:
        centre_deg: half-width of "centred" in degrees of yaw (20: the middle third of the ~125-degree view).
    """

    kind = "bot"
    needs_engine = True

    def __init__(self, noise: float = 0.0, walk: bool = False, turn_deg: float = TURN_DEG,
                 scan_deg: float = SCAN_DEG, centre_deg: float = 20.0):
        super().__init__(noise, walk, turn_deg, scan_deg)
        self.centre_deg = centre_deg
        self._game, self._index = None, 0

    def reset(self, env: Any, agent: str, seed: int | None) -> None:
        super().reset(env, agent, seed)
        self._game = getattr(env, "game", None)
        if self._game is None:
            raise ValueError(f"{self.name!r} reads the engine's game state: it needs RealParallelEnv, got "
                             f"{type(env).__name__}; use 'seeker:NOISE' (the judge) in the dream env")
        self._index = [p.name for p in self._game.players].index(agent)

    def where(self, observation: np.ndarray) -> str:
        from solaris_env.engine.physics import wrap_angle, yaw_to

        me = self._game.players[self._index]
        partner = self._game.players[1 - self._index]
        # Mineflayer yaw: + = turned left, so a positive error means the partner is to the left
        error_deg = math.degrees(wrap_angle(yaw_to(me.pos, partner.pos) - me.yaw))
        if abs(error_deg) <= self.centre_deg:
            return "center"
        return "left" if error_deg > 0 else "right"


# ---------------------------------------------------------------------------------------------
# PPO checkpoints
# ---------------------------------------------------------------------------------------------


class PPOPolicy(Policy):
    """An SB3 PPO checkpoint (``<name>.zip`` with its ``<name>.json`` sidecar from ``agents/common.py``).

    Observations of another size than the policy's are resized (area averaging down, bilinear up), so a
    dream-trained policy acts on real frames of any resolution.

    Args:
        path: the ``.zip`` checkpoint.
        deterministic: take the most likely action (else sample, seeded by ``reset``).
    """

    def __init__(self, path: str | Path, deterministic: bool = True):
        from stable_baselines3 import PPO

        self.path = Path(path)
        meta_path = self.path.with_suffix(".json")
        if not self.path.is_file() or not meta_path.is_file():
            raise FileNotFoundError(f"a PPO checkpoint needs {self.path} and its sidecar {meta_path}; "
                                    "write them with agents/ppo_dream.py or agents/ppo_real.py")
        self.meta = json.loads(meta_path.read_text())
        self.model = PPO.load(self.path, device="cpu")
        self.codec = FlatActionCodec(**self.meta["codec"])
        self.obs_shape = tuple(self.meta["obs_shape"])  # (H, W, 3): SB3 stores its channel-first transpose
        self.deterministic = deterministic
        self.name = f"ppo:{self.path}"

    def reset(self, env: Any, agent: str, seed: int | None) -> None:
        if not self.deterministic and seed is not None:
            self.model.set_random_seed(seed)

    def act(self, observation: np.ndarray) -> dict[str, Any]:
        obs = _resize(observation, self.obs_shape)
        if not obs.flags.writeable:  # env frames can be read-only views; torch warns on those
            obs = obs.copy()
        flat, _ = self.model.predict(obs, deterministic=self.deterministic)
        return self.codec.decode(np.asarray(flat))


def _resize(frame_HW3: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    if frame_HW3.shape == shape:
        return frame_HW3
    import cv2

    h, w = shape[:2]
    interp = cv2.INTER_AREA if h <= frame_HW3.shape[0] else cv2.INTER_LINEAR
    return cv2.resize(frame_HW3, (w, h), interpolation=interp).reshape(shape)


# ---------------------------------------------------------------------------------------------
# Registry
# ---------------------------------------------------------------------------------------------

POLICIES: dict[str, Callable[[str | None], Policy]] = {
    "random": lambda arg: RandomPolicy(),
    "noop": lambda arg: Policy(),
    "spin": lambda arg: SpinPolicy(SCAN_DEG if arg is None else float(arg)),
    "seeker": lambda arg: JudgeSeekerPolicy(noise=float(arg or 0.0)),
    "seeker-walk": lambda arg: JudgeSeekerPolicy(noise=float(arg or 0.0), walk=True),
    "bot": lambda arg: EngineSeekerBot(noise=float(arg or 0.0)),
    "bot-walk": lambda arg: EngineSeekerBot(noise=float(arg or 0.0), walk=True),
    "ppo": lambda arg: PPOPolicy(arg),
}


def make_policy(spec: str) -> Policy:
    """``"kind"`` or ``"kind:arg"`` (see the module docstring) -> a fresh Policy whose ``name`` is ``spec``."""
    kind, _, arg = spec.partition(":")
    if kind not in POLICIES:
        raise ValueError(f"unknown policy {spec!r}; kinds: {sorted(POLICIES)} (as 'kind' or 'kind:arg')")
    if kind == "ppo" and not arg:
        raise ValueError(f"policy {spec!r}: give the checkpoint as 'ppo:PATH'")
    try:
        policy = POLICIES[kind](arg or None)
    except ValueError as err:
        raise ValueError(f"policy {spec!r}: {err}") from err
    policy.name = spec
    return policy
