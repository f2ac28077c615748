"""``SB3VecEnv``: our vector env as a Stable-Baselines3 ``VecEnv`` with one shared policy.

SB3 env slot j = (world j // L, learning agent j % L) for N worlds and L learning agents: ``num_envs`` =
N x L, every learning player of every world is a sample for the same policy. Observations are the learning
players' frames (num_envs, H, W, 3) uint8; actions are flat (``FlatActionCodec``: MultiDiscrete with a
binned camera, or Box). Players that are not learning are driven by opponents (one per world and player).

When a world ends, all its slots are done; SB3's conventions hold: the returned observation is the new
episode's first, ``infos[j]["terminal_observation"]`` is the last one and ``infos[j]["TimeLimit.truncated"]``
says the end was a truncation (``max_steps``), not a termination. This needs the vector env's
``SAME_STEP`` autoreset.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces as gym_spaces
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from solaris_env.spaces import FlatActionCodec
from solaris_env.wrappers.opponents import make_opponent


class SB3VecEnv(VecEnv):
    """Args:
        vec_env: a ``DreamVectorEnv`` (``SAME_STEP`` autoreset).
        learners: the learning agents (default: every agent).
        codec: the flat action encoding (default ``FlatActionCodec()``: MultiDiscrete, 11 camera bins of
            +-10 deg).
        opponent: what drives the other players (see ``make_opponent``): a name or a factory; one Opponent
            is made per world and player.
    """

    def __init__(self, vec_env: Any, learners: Sequence[str] | None = None, codec: FlatActionCodec | None = None,
                 opponent: Any = "random"):
        if vec_env.metadata.get("autoreset_mode") != AutoresetMode.SAME_STEP:
            raise ValueError(f"SB3VecEnv needs a vector env with SAME_STEP autoreset, got "
                             f"{vec_env.metadata.get('autoreset_mode')}")
        agents = list(vec_env.possible_agents)
        self.learners = list(agents if learners is None else learners)
        unknown = [a for a in self.learners if a not in agents]
        if unknown or not self.learners or len(set(self.learners)) != len(self.learners):
            raise ValueError(f"learners must be distinct agents of {agents}, got {self.learners}")
        self.vec_env, self.codec = vec_env, codec or FlatActionCodec()
        self.others = [a for a in agents if a not in self.learners]
        self._learner_index = [agents.index(a) for a in self.learners]
        self._other_index = [agents.index(a) for a in self.others]
        self.num_worlds = vec_env.num_envs
        self.opponents = [[make_opponent(opponent) for _ in self.others] for _ in range(self.num_worlds)]
        obs_space = gym_spaces.Box(0, 255, (vec_env.height, vec_env.width, 3), np.uint8)
        super().__init__(self.num_worlds * len(self.learners), obs_space, self.codec.space)
        self.render_mode = vec_env.render_mode
        self._world_obs_NPHW3: np.ndarray | None = None
        self._actions: np.ndarray | None = None

    # -- VecEnv API -------------------------------------------------------------------------------
    def reset(self) -> np.ndarray:
        seed = self._seeds[0] if self._seeds else None
        obs_NPHW3, _ = self.vec_env.reset(seed=seed, options=self._options[0] if self._options else None)
        self._reset_seeds()
        self._reset_options()
        rng = np.random.default_rng(seed)
        for w in range(self.num_worlds):
            self._reset_opponents(w, rng)
        self._opp_rng = rng
        self._world_obs_NPHW3 = obs_NPHW3
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return self._learner_obs(obs_NPHW3)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        if self._world_obs_NPHW3 is None or self._actions is None:
            raise RuntimeError("step before reset() / step_async(); call reset() first")
        expected = (self.num_envs, *self.codec.space.shape)
        if self._actions.shape != expected:
            raise ValueError(f"actions must have shape {expected} (num_envs x flat action), got {self._actions.shape}")
        per_world = self._world_actions(self._actions)
        self._actions = None
        obs_NPHW3, rewards_NP, terms_N, truncs_N, infos = self.vec_env.step(per_world)
        self._world_obs_NPHW3 = obs_NPHW3
        ended_N = terms_N | truncs_N
        rewards = rewards_NP[:, self._learner_index].reshape(-1).astype(np.float32)
        dones = np.repeat(ended_N, len(self.learners))
        out_infos: list[dict] = []
        for w in range(self.num_worlds):
            for p in self._learner_index:
                info: dict = {}
                if ended_N[w]:
                    info["terminal_observation"] = infos["final_obs"][w][p]
                    info["TimeLimit.truncated"] = bool(truncs_N[w] and not terms_N[w])
                out_infos.append(info)
            if ended_N[w]:
                self._reset_opponents(w, self._opp_rng)
        return self._learner_obs(obs_NPHW3), rewards, dones, out_infos

    def close(self) -> None:
        self.vec_env.close()

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self.vec_env, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self.vec_env, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: Any = None, **method_kwargs) -> list[Any]:
        result = getattr(self.vec_env, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        if self._world_obs_NPHW3 is None:
            return [None] * self.num_envs
        return list(self._learner_obs(self._world_obs_NPHW3))

    def _get_indices(self, indices: Any) -> Iterable[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, (int, np.integer)) else indices

    # -- internals --------------------------------------------------------------------------------
    def _learner_obs(self, obs_NPHW3: np.ndarray) -> np.ndarray:
        return obs_NPHW3[:, self._learner_index].reshape(self.num_envs, *obs_NPHW3.shape[2:]).copy()

    def _world_actions(self, flat_actions: np.ndarray) -> list[dict]:
        """Every slot's flat action decoded (ValueError naming the slot) before any opponent acts, so a rejected
        batch changes nothing (no opponent draws or advances); then the opponents' actions."""
        per_world = []
        for w in range(self.num_worlds):
            world = {}
            for j, agent in enumerate(self.learners):
                slot = w * len(self.learners) + j
                try:
                    world[agent] = self.codec.decode(flat_actions[slot])
                except ValueError as err:
                    raise ValueError(f"SB3 env slot {slot} (world {w}, agent {agent!r}): {err}") from err
            per_world.append(world)
        for w, world in enumerate(per_world):
            for k, (agent, p) in enumerate(zip(self.others, self._other_index)):
                world[agent] = self.opponents[w][k].act(self._world_obs_NPHW3[w, p])
        return per_world

    def _reset_opponents(self, w: int, rng: np.random.Generator) -> None:
        for opp, agent in zip(self.opponents[w], self.others):
            opp.reset(self.vec_env, agent, int(rng.integers(2**31 - 1)))
