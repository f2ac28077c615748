"""What an episode type is (docs/engine.md §5.2, §6.2): :class:`EpisodeSpec`. The episode modules
(``training_episodes``, ``eval_episodes``) list theirs in ``EPISODE_TYPES``; ``registry`` collects them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from solaris_env.engine.bots.controller import Actions, Bot


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode type.

    Attributes:
        name: the reference's type name (``walkLook``, ``rotationEval``, ...).
        category: Movement / Building / Mining / Combat / eval task name.
        typical_s: typical length in seconds (sets the sampling weight 1/sqrt(typical_s)).
        spawn_min, spawn_max: distance between the two bots at spawn (blocks).
        behaviour: ``behaviour(bot) -> Actions``, run by every bot.
        setup: ``setup(bot)`` before recording (give items, re-teleport); may be None.
        is_eval: eval types are never sampled for training data.
        world: forced world kind for eval types (``"flat"`` or ``"normal"``), None = any.
        max_s: hard cap on the recorded length; reaching it aborts the episode.
        in_default_mix: False for our opt-in types (not in the reference's table): never sampled unless
            named (``collect --types``).
    """

    name: str
    category: str
    typical_s: float
    spawn_min: float
    spawn_max: float
    behaviour: Callable[[Bot], Actions]
    setup: Callable[[Bot], None] | None = None
    is_eval: bool = False
    world: str | None = None
    max_s: float = 180.0
    in_default_mix: bool = True
