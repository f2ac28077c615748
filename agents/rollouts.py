"""Episodes of one policy in a two-player env of ours (dream or real), from a given engine start state.

The learner (Alpha) follows the policy, the partner (Bravo) its own policy (default: stands still). The same
``EngineState`` starts the real env directly and the dream env through its engine-rendered views, so both
see the same first frame; the ``seed`` draws the model's sampling noise and the policies' randomness.

``side_tasks`` score the same episode with other Task objects through the Task API (e.g. the judge variant
of a task on real frames, next to the env's ground-truth reward): they get every step's frames, actions and,
in the real env, the ground truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from agents.common import LEARNER, PARTNER
from agents.policies import Policy
from solaris_env.spaces import noop


@dataclass(frozen=True)
class EpisodeResult:
    """One episode: the learner's return from the env's task, from each side task, and its length."""

    env_return: float
    side_returns: tuple[float, ...]
    steps: int


def _truth(env: Any, infos: dict) -> list[dict] | None:
    """The real env's per-player infos in agent order (ground truth); None in the dream env."""
    if not all("pos" in infos.get(a, {}) for a in env.possible_agents):
        return None
    return [infos[a] for a in env.possible_agents]


def run_episode(env: Any, policy: Policy, start_state: Any, seed: int, partner: Policy | None = None,
                side_tasks: Sequence[Any] = (), frames: list | None = None) -> EpisodeResult:
    """Play one episode (until the learner terminates or is truncated) and sum the learner's rewards.

    Args:
        env: a two-player ``DreamParallelEnv`` or ``RealParallelEnv`` (agents Alpha, Bravo), unwrapped.
        policy: drives the learner; ``reset(env, "Alpha", seed)`` is called first.
        start_state: the ``EngineState`` the episode starts from.
        seed: the reset seed (model noise in the dream) and the policies' seeds.
        partner: drives Bravo (default: stands still).
        side_tasks: extra Tasks scoring the learner in the same episode (their own state is reset here).
        frames: when a list is given, the learner's observations are appended to it (the reset frame, then one
            per step: (H, W, 3) uint8 copies), so the two envs' episodes can be looked at side by side.
    """
    if list(env.possible_agents) != [LEARNER, PARTNER]:
        raise ValueError(f"the env must have the agents {[LEARNER, PARTNER]}, got {env.possible_agents}")
    if policy.needs_engine and not hasattr(env, "game"):
        raise ValueError(f"policy {policy.name!r} reads the engine's game state; it cannot run in "
                         f"{type(env).__name__}")
    partner = partner if partner is not None else Policy()
    obs, infos = env.reset(seed=seed, options={"engine_state": start_state})
    policy.reset(env, LEARNER, seed)
    partner.reset(env, PARTNER, seed + 1)
    if frames is not None:
        frames.append(np.array(obs[LEARNER], np.uint8))
    for task in side_tasks:
        task.reset(env.step_frames()[:, 0], truth=_truth(env, infos))
    env_return, side_returns, steps = 0.0, np.zeros(len(side_tasks)), 0
    while LEARNER in env.agents:
        actions = {LEARNER: policy.act(obs[LEARNER])}
        if PARTNER in env.agents:
            actions[PARTNER] = partner.act(obs[PARTNER])
        obs, rewards, _, _, infos = env.step(actions)
        env_return += rewards[LEARNER]
        steps += 1
        if frames is not None and LEARNER in obs:
            frames.append(np.array(obs[LEARNER], np.uint8))
        per_player = [actions.get(a, noop()) for a in env.possible_agents]  # the Task API's P actions
        for j, task in enumerate(side_tasks):
            side_returns[j] += task.step(env.step_frames(), per_player, truth=_truth(env, infos)).rewards_P[0]
    return EpisodeResult(float(env_return), tuple(float(r) for r in side_returns), steps)
