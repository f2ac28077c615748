"""Episode types: their constants (docs/engine.md §5.2 table, §6.2) and the weighted sampler.

An episode type is a :class:`EpisodeSpec`: spawn distances, typical length, an optional ``setup``
hook (items and teleports before recording) and ``behaviour(bot)``, the per-bot choreography.
Modules that define types register them with :func:`register`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

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


EPISODES: dict[str, EpisodeSpec] = {}


def register(spec: EpisodeSpec) -> EpisodeSpec:
    if spec.name in EPISODES:
        raise ValueError(f"episode type {spec.name!r} registered twice")
    EPISODES[spec.name] = spec
    return spec


def _load_all() -> None:
    # Importing the modules registers their types.
    from solaris_env.engine.bots import eval_episodes, training_episodes  # noqa: F401


def training_types() -> list[str]:
    """The reference's training types: the default mix of a collect."""
    _load_all()
    return sorted(n for n, s in EPISODES.items() if not s.is_eval and s.in_default_mix)


def opt_in_training_types() -> list[str]:
    """Our extra training types, collected only when named (``collect --types``)."""
    _load_all()
    return sorted(n for n, s in EPISODES.items() if not s.is_eval and not s.in_default_mix)


def eval_types() -> list[str]:
    _load_all()
    return sorted(n for n, s in EPISODES.items() if s.is_eval)


def get(name: str) -> EpisodeSpec:
    _load_all()
    if name not in EPISODES:
        raise ValueError(f"unknown episode type {name!r}; known: {sorted(EPISODES)}")
    return EPISODES[name]


def sampling_weights(types: list[str] | None = None) -> dict[str, float]:
    """Normalised weights 1/sqrt(typical length) over the (alphabetically sorted) training types."""
    types = sorted(types or training_types())
    w = np.array([1.0 / math.sqrt(get(t).typical_s) for t in types])
    return dict(zip(types, (w / w.sum()).tolist()))


def sample_type(rng: np.random.Generator, types: list[str] | None = None) -> str:
    """Cumulative sampling with one draw of the shared RNG (docs/engine.md §5.2)."""
    weights = sampling_weights(types)
    u, acc = rng.random(), 0.0
    for name, w in weights.items():
        acc += w
        if u < acc:
            return name
    return name
