"""``SingleAgentEnv``: one learning player of a multiplayer env as a Gymnasium ``Env``.

The other players are driven by opponents (``solaris_env.wrappers.opponents``): a scripted engine bot (real
env), random or no-op actions, or a frozen policy. Registered as ``solaris_env/Dream-v0`` and
``solaris_env/Real-v0`` (``gymnasium.make``, after ``import solaris_env``)::

    env = gymnasium.make("solaris_env/Real-v0", resolution=64, opponent="bot", flatten="multidiscrete")
    env = gymnasium.make("solaris_env/Dream-v0", preset="tiny", opponent="random", flatten="box")

``make_dream`` / ``make_real`` build the stack: the parallel env, then optional ``resize`` and
``frame_stack`` (``observations``), this wrapper, then optional action flattening (``actions``) for SB3.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from solaris_env.env_common import available_render_modes, check_seed
from solaris_env.spaces import validate_action
from solaris_env.wrappers.opponents import Opponent, make_opponent


class SingleAgentEnv(gym.Env):
    """One agent of a PettingZoo ParallelEnv learns; the others follow ``opponent``.

    Args:
        env: a ParallelEnv of ours (dream or real, possibly wrapped).
        agent: the learning agent (default: the first, ``"Alpha"``).
        opponent: for every other player: a name (``"random"``, ``"noop"``, ``"bot"``), an Opponent class or
            factory, or a callable ``observation -> env action`` (a frozen policy). One Opponent per player.

    The episode ends when the learning agent terminates or is truncated. ``info`` is the learning agent's
    info plus ``"others"``: the other agents' rewards of the step. A ``step`` or ``reset`` that raises (a bad
    action, seed or option) changes nothing: the learner's action is checked before the opponents act.
    """

    def __init__(self, env: Any, agent: str | None = None, opponent: Any = "random"):
        self.env = env
        self.agent = agent if agent is not None else env.possible_agents[0]
        if self.agent not in env.possible_agents:
            raise ValueError(f"agent {self.agent!r} is not one of {env.possible_agents}")
        self.others = [a for a in env.possible_agents if a != self.agent]
        if isinstance(opponent, Opponent) and len(self.others) > 1:
            raise ValueError("one Opponent instance cannot drive several players; pass a name or a factory")
        self.opponents = {a: make_opponent(opponent) for a in self.others}
        self.observation_space = env.observation_space(self.agent)
        self.action_space = env.action_space(self.agent)
        self.render_mode = getattr(env, "render_mode", None)
        self.metadata = {**getattr(env, "metadata", {}), "render_modes": available_render_modes()}
        self._obs: dict | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        # the env checks seed and options before anything is drawn; the wrapper's own generator (the opponents'
        # seeds) is seeded only once that reset has succeeded, so a failed reset changes nothing
        obs, infos = self.env.reset(seed=seed, options=options)
        super().reset(seed=check_seed(seed))  # numpy integer seeds are fine
        seeds = self.np_random.integers(2**31 - 1, size=len(self.others))
        for a, s in zip(self.others, seeds):
            self.opponents[a].reset(self.env.unwrapped, a, int(s))
        self._obs = obs
        return obs[self.agent], infos[self.agent]

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._obs is None or self.agent not in self.env.agents:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        # check the learner's action before any opponent acts (draws randomness, advances a script): a rejected
        # action must change nothing
        actions = {self.agent: validate_action(action, agent=self.agent)}
        for a in self.others:
            if a in self.env.agents:
                actions[a] = self.opponents[a].act(self._obs[a])
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        self._obs = obs
        info = {**infos[self.agent], "others": {a: rewards[a] for a in rewards if a != self.agent}}
        return obs[self.agent], float(rewards[self.agent]), bool(terminations[self.agent]), \
            bool(truncations[self.agent]), info

    def render(self):
        return self.env.render()

    def close(self) -> None:
        self.env.close()


# ---------------------------------------------------------------------------------------------
# Factories (gymnasium entry points)
# ---------------------------------------------------------------------------------------------


def _wrap(parallel: Any, agent: str | None, opponent: Any, resize: Any, frame_stack: int | None,
          flatten: str | None, camera_bins: int, camera_max_deg: float, flatten_keys: Any,
          flatten_camera_axes: Any) -> gym.Env:
    from solaris_env.wrappers.observations import ResizeFrames, StackFrames

    if resize is not None:
        parallel = ResizeFrames(parallel, resize)
    if frame_stack is not None:
        parallel = StackFrames(parallel, frame_stack)
    env: gym.Env = SingleAgentEnv(parallel, agent=agent, opponent=opponent)
    if flatten is not None:
        from solaris_env.wrappers.actions import FlatActions

        env = FlatActions(env, kind=flatten, camera_bins=camera_bins, camera_max_deg=camera_max_deg, keys=flatten_keys,
                          camera_axes=flatten_camera_axes)
    return env


def make_dream(agent: str | None = None, opponent: Any = "random", resize: Any = None, frame_stack: int | None = None,
               flatten: str | None = None, camera_bins: int = 11, camera_max_deg: float = 10.0,
               flatten_keys: Any = None, flatten_camera_axes: Any = ("pitch", "yaw"), **dream_kwargs) -> gym.Env:
    """``solaris_env/Dream-v0``: ``DreamParallelEnv(**dream_kwargs)`` seen by one agent (see ``_wrap``'s args:
    ``resize`` (h, w) or int, ``frame_stack`` n, ``flatten`` None / "multidiscrete" / "box", ``flatten_keys`` /
    ``flatten_camera_axes`` the binary keys (None = all) and camera axes the flat action exposes)."""
    from solaris_env.dream_env import DreamParallelEnv

    return _wrap(DreamParallelEnv(**dream_kwargs), agent, opponent, resize, frame_stack, flatten, camera_bins,
                 camera_max_deg, flatten_keys, flatten_camera_axes)


def make_real(agent: str | None = None, opponent: Any = "bot", resize: Any = None, frame_stack: int | None = None,
              flatten: str | None = None, camera_bins: int = 11, camera_max_deg: float = 10.0,
              flatten_keys: Any = None, flatten_camera_axes: Any = ("pitch", "yaw"), **real_kwargs) -> gym.Env:
    """``solaris_env/Real-v0``: ``make_real_env(**real_kwargs)`` (``real_backends``: the voxel engine, or with
    ``backend="minecraft"`` real Minecraft) seen by one agent; the others are scripted engine bots by default."""
    from solaris_env.real_backends import make_real_env

    return _wrap(make_real_env(**real_kwargs), agent, opponent, resize, frame_stack, flatten, camera_bins,
                 camera_max_deg, flatten_keys, flatten_camera_axes)


from solaris_env.registration import ENV_IDS, register_envs  # noqa: F401 - re-exported
