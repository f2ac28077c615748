"""Opponents: policies for the players that are not learning (single-agent and SB3 wrappers).

An :class:`Opponent` drives one player: ``reset(env, agent, seed)`` at each episode start, then
``act(observation)`` once per env step, returning an env action (the MineRL dict).

* ``"noop"`` (:class:`NoopOpponent`): stands still.
* ``"random"`` (:class:`RandomOpponent`): samples the action space (seeded by the reset seed). By default
  the camera is drawn from +-``camera_max_deg`` instead of the whole +-180 deg box, so it jitters around.
* :class:`PolicyOpponent`: a frozen policy, any callable ``observation -> action`` (an env action dict, or a
  flat action decoded by a ``FlatActionCodec``); ``PolicyOpponent.from_sb3(model, codec)`` wraps a trained
  SB3 model.
* ``"bot"`` (:class:`ScriptedBotOpponent`, real env only): an engine bot reading the game state (as the
  data-collection bots do) that keeps looking at the nearest other player, walks short random legs and
  follows it when it gets far. One real env step is one engine tick, so it yields one tick per step.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from solaris_env.spaces import (
    CAMERA_KEY,
    FlatActionCodec,
    make_action_space,
    noop,
    validate_action,
)


class Opponent:
    """Drives one non-learning player; the base class stands still."""

    def reset(self, env: Any, agent: str, seed: int | None) -> None:
        """Called when an episode starts. ``env``: the (unwrapped) env the player lives in."""

    def act(self, observation: np.ndarray) -> dict[str, Any]:
        return noop()


class NoopOpponent(Opponent):
    """Stands still."""


class RandomOpponent(Opponent):
    """Uniformly random keys; camera uniform in +-``camera_max_deg`` (None: the whole action space)."""

    def __init__(self, camera_max_deg: float | None = 10.0):
        self.camera_max_deg = camera_max_deg
        self._space = make_action_space()

    def reset(self, env: Any, agent: str, seed: int | None) -> None:
        self._space.seed(seed)

    def act(self, observation: np.ndarray) -> dict[str, Any]:
        action = self._space.sample()
        if self.camera_max_deg is not None:
            action[CAMERA_KEY] = (action[CAMERA_KEY] / 180.0 * self.camera_max_deg).astype(np.float32)
        return action


class PolicyOpponent(Opponent):
    """A frozen policy: ``policy(observation) -> action``; with ``codec``, the action is flat and decoded."""

    def __init__(self, policy: Callable[[np.ndarray], Any], codec: FlatActionCodec | None = None):
        if not callable(policy):
            raise TypeError(f"policy must be callable (observation -> action), got {type(policy).__name__}")
        self.policy, self.codec = policy, codec

    @classmethod
    def from_sb3(cls, model: Any, codec: FlatActionCodec, deterministic: bool = True) -> PolicyOpponent:
        """A trained SB3 model acting on flat actions of ``codec``."""
        return cls(lambda obs: model.predict(obs, deterministic=deterministic)[0], codec)

    def act(self, observation: np.ndarray) -> dict[str, Any]:
        action = self.policy(observation)
        return self.codec.decode(action) if self.codec is not None else validate_action(action)


class ScriptedBotOpponent(Opponent):
    """An engine bot (real env only): look at the nearest other player, wander, follow when far.

    Args:
        follow_beyond: blocks; farther than this from the nearest other player, it follows.
        walk_range: (min, max) blocks of a random walking leg.
    """

    def __init__(self, follow_beyond: float = 8.0, walk_range: tuple[float, float] = (1.0, 3.0)):
        self.follow_beyond, self.walk_range = follow_beyond, walk_range
        self._script = None

    def reset(self, env: Any, agent: str, seed: int | None) -> None:
        from solaris_env.engine.bots.controller import Bot

        game = getattr(env, "game", None)
        if game is None:
            raise ValueError("the 'bot' opponent reads the voxel engine's game state: it needs the real env "
                             "(RealParallelEnv, backend='voxel'), not the dream env or the minecraft backend; "
                             "use 'random', 'noop' or a PolicyOpponent")
        index = [p.name for p in game.players].index(agent)
        rng = np.random.default_rng(seed)
        self._bot = Bot(game, index, np.random.default_rng(rng.integers(2**31)), rng)
        self._script = self._behaviour(self._bot)

    def act(self, observation: np.ndarray) -> dict[str, Any]:
        if self._script is None:
            raise RuntimeError("ScriptedBotOpponent.act() before reset()")
        from solaris_env.engine.bots.controller import Barrier

        item = next(self._script)
        return noop() if isinstance(item, Barrier) else item

    def _behaviour(self, bot):
        """Forever: face the nearest other player, then follow it (if far) or walk a short random leg."""
        from solaris_env.engine.bots.controller import MOVE_KEYS

        while True:
            others = bot.others
            if not others:
                yield from bot.idle(20)
                continue
            target = min(others, key=lambda q: float(np.linalg.norm(q.pos - bot.me.pos)))
            yield from bot.look_at_player(target)
            if float(np.linalg.norm(target.pos - bot.me.pos)) > self.follow_beyond:
                yield from bot.follow(target, radius=self.follow_beyond / 2, ticks=60)
            else:
                key = MOVE_KEYS[int(bot.rng.integers(len(MOVE_KEYS)))]
                yield from bot.walk(key, float(bot.rng.uniform(*self.walk_range)), timeout_s=2.0)
                yield from bot.idle(int(bot.rng.integers(5, 20)))


OPPONENTS: dict[str, type[Opponent]] = {"noop": NoopOpponent, "random": RandomOpponent, "bot": ScriptedBotOpponent}


def make_opponent(opponent: Any = "random") -> Opponent:
    """A fresh Opponent from a name in ``OPPONENTS``, an Opponent class or a zero-argument factory, a plain
    callable ``observation -> env action`` (wrapped as a frozen policy), or an Opponent instance (used as is)."""
    if isinstance(opponent, str):
        if opponent not in OPPONENTS:
            raise ValueError(f"unknown opponent {opponent!r}; choose from {sorted(OPPONENTS)} or pass an Opponent")
        return OPPONENTS[opponent]()
    if isinstance(opponent, Opponent):
        return opponent
    if isinstance(opponent, type) and issubclass(opponent, Opponent):
        return opponent()
    if callable(opponent):
        return PolicyOpponent(opponent)
    raise TypeError(f"opponent must be a name in {sorted(OPPONENTS)}, an Opponent or a callable; "
                    f"got {type(opponent).__name__}")


def make_opponents(env: Any, opponent: Any, seed: int) -> dict[str, Opponent]:
    """One fresh ``make_opponent(opponent)`` per agent of ``env`` (unwrapped), each reset for a new episode with
    its own seed drawn from ``seed``."""
    out = {a: make_opponent(opponent) for a in env.possible_agents}
    for a, s in zip(env.possible_agents, np.random.default_rng(seed).integers(2**31 - 1, size=len(out))):
        out[a].reset(env, a, int(s))
    return out
