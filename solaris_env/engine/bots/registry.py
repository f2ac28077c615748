"""Episode types: every type of the episode modules by name (docs/engine.md §5.2 table, §6.2) and the
weighted sampler. An episode type is a :class:`~solaris_env.engine.bots.spec.EpisodeSpec`; ``training_episodes``
and ``eval_episodes`` list theirs in ``EPISODE_TYPES``.
"""

from __future__ import annotations

import math

import numpy as np

from solaris_env.engine.bots import eval_episodes, training_episodes
from solaris_env.engine.bots.spec import EpisodeSpec


def _by_name(specs: tuple[EpisodeSpec, ...]) -> dict[str, EpisodeSpec]:
    out: dict[str, EpisodeSpec] = {}
    for spec in specs:
        if spec.name in out:
            raise ValueError(f"episode type {spec.name!r} defined twice")
        out[spec.name] = spec
    return out


EPISODES: dict[str, EpisodeSpec] = _by_name(training_episodes.EPISODE_TYPES + eval_episodes.EPISODE_TYPES)


def training_types() -> list[str]:
    """The reference's training types: the default mix of a collect."""
    return sorted(n for n, s in EPISODES.items() if not s.is_eval and s.in_default_mix)


def opt_in_training_types() -> list[str]:
    """Our extra training types, collected only when named (``collect --types``)."""
    return sorted(n for n, s in EPISODES.items() if not s.is_eval and not s.in_default_mix)


def eval_types() -> list[str]:
    return sorted(n for n, s in EPISODES.items() if s.is_eval)


def get(name: str) -> EpisodeSpec:
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
