"""``DreamVectorEnv``: N dream worlds of P players each, stepped in ONE batched world-model call.

A Gymnasium 1.x ``VectorEnv`` whose sub-environment is one world with all of its players:

* ``single_observation_space`` = ``Box(0, 255, (P, H, W, 3), uint8)``: every player's view (agent order);
  the batched observation is (N, P, H, W, 3).
* ``single_action_space`` = ``Dict({agent: MineRL action Dict})``. ``step`` takes the batched form
  (``action_space.sample()``: agent -> key -> (N, ...) arrays) or a list of N per-world ``{agent: action}``
  dicts. Every action is checked before the model runs (ValueError naming the world, agent and key).
* rewards are (N, P) float32, one per player (the task's); terminations and truncations are (N,) bool:
  a world ends when the task terminates any of its players or at ``max_steps``.
* infos: ``"frames"`` (N, P, k, H, W, 3) uint8, all k frames of the step; ``"step"`` (N,) int, the step
  count of the episode each observation belongs to (0 for a world that restarted).

Autoreset (``metadata["autoreset_mode"]``, chosen with ``autoreset_mode=``): ``SAME_STEP`` (default) resets
an ended world inside the same ``step`` (the returned observation is the new episode's first one, the last
one is in ``infos["final_obs"]`` with ``infos["final_info"]``; what SB3 expects); ``NEXT_STEP`` resets it on
the following ``step`` (its action is ignored, reward 0); ``DISABLED``: call
``reset(options={"reset_mask": mask})``. Ended worlds are re-initialised with ``WorldModel.reset_worlds``,
which compiles once for any world index.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces as gym_spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from solaris_env.dream_env import (
    ENGINE_TICKS_PER_SECOND,
    build_model,
    check_model_players,
    world_actions,
)
from solaris_env.engine.bots.runner import PLAYER_NAMES
from solaris_env.env_common import (
    check_agent_actions,
    check_int,
    check_options,
    check_seed,
    episode_rng,
    side_by_side,
)
from solaris_env.spaces import make_action_space
from solaris_env.start_scenes import POSES_NEEDED, StartFrames
from solaris_env.tasks import make_task


def _autoreset_mode(mode: Any) -> AutoresetMode:
    try:
        return AutoresetMode(mode) if not isinstance(mode, AutoresetMode) else mode
    except ValueError:
        names = [m.value for m in AutoresetMode]
        raise ValueError(f"autoreset_mode must be an AutoresetMode or one of {names}, got {mode!r}") from None


class DreamVectorEnv(VectorEnv):
    """N worlds x P players of the world model, batched (see the module docstring).

    Args:
        num_worlds: N, the number of worlds (``num_envs``).
        checkpoint, preset, num_players, max_steps, task, start_states, seed_model, model: as
            ``DreamParallelEnv`` (one Task per world: an instance is copied).
        autoreset_mode: ``AutoresetMode.SAME_STEP`` (default), ``NEXT_STEP`` or ``DISABLED``.
        render_mode: None or ``"rgb_array"`` (the worlds stacked vertically, players side by side).
    """

    def __init__(self, num_worlds: int, checkpoint=None, preset: str | None = None, num_players: int | None = None,
                 max_steps: int = 200, task=None, start_states: Any = "bundled",
                 autoreset_mode: Any = AutoresetMode.SAME_STEP, render_mode: str | None = None, seed_model: int = 0,
                 model=None):
        num_worlds = check_int(num_worlds, "num_worlds")
        max_steps = check_int(max_steps, "max_steps")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.tasks = [make_task(task) for _ in range(num_worlds)]
        if self.tasks[0].requires_truth:
            raise ValueError(f"task {self.tasks[0].name!r} needs the engine's ground truth; dream worlds have none")
        self.model = model if model is not None else build_model(checkpoint, preset, num_players, seed_model)
        self.num_players = check_model_players(self.model, num_players)
        self.num_envs = self.num_worlds = int(num_worlds)
        self.max_steps, self.render_mode = max_steps, render_mode
        self.height, self.width, _ = self.model.frame_shape
        self.frames_per_step = self.model.frames_per_step
        self.possible_agents = list(PLAYER_NAMES[: self.num_players])
        self.metadata = {"autoreset_mode": self.autoreset_mode, "render_modes": ["rgb_array"],
                         "render_fps": ENGINE_TICKS_PER_SECOND / self.frames_per_step, "name": "solaris_dream_vector_v0"}
        self.single_observation_space = gym_spaces.Box(0, 255, (self.num_players, self.height, self.width, 3),
                                                       np.uint8)
        self.single_action_space = gym_spaces.Dict({a: make_action_space() for a in self.possible_agents})
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.start_frames = StartFrames(start_states, self.possible_agents, self.height, self.width)
        self._state = None  # the model's WorldState (B = N); donated on every step
        self._obs_NPHW3: np.ndarray | None = None
        self._steps_N = np.zeros(self.num_envs, np.int64)
        self._ended_N = np.zeros(self.num_envs, bool)  # ended at the last step (NEXT_STEP / DISABLED)
        # [dpitch, dyaw] deg each player still has to turn (``spaces.step_ticks``, as DreamParallelEnv)
        self._camera_pending_NP2 = np.zeros((self.num_envs, self.num_players, 2))

    # -- reset ------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Start every world, or only those in ``options["reset_mask"]`` ((N,) bool; needs a previous reset).

        Start frames: ``options["frames"]`` (N, P, H, W, 3) uint8, ``options["engine_state"]`` (one EngineState
        for every world, or a list of N), else ``start_states`` sampled with ``seed``. Any other key raises
        ValueError. ``seed``: None or an int >= 0 (numpy integers too; not a bool). Everything is checked before
        anything is drawn: a reset that raises changes nothing (not the seed stream, not the worlds).
        """
        seed = check_seed(seed)
        options = check_options(options, ("frames", "engine_state", "reset_mask"), ignored=())
        mask_N = self._reset_mask(options.get("reset_mask"))
        given = self._given_starts(options, mask_N)
        fresh = seed is not None or self._np_random is None  # else continue the stream (on a copy, kept at the end)
        rng, rng_seed = seeding.np_random(seed) if fresh else (episode_rng(self._np_random, None), None)
        first_NPHW3, starts, poses_NP5 = self._start_frames(given, mask_N, rng)
        model_seed = int(rng.integers(2**31 - 1))
        if mask_N.all():
            self._state = self.model.init(first_NPHW3, model_seed, poses=poses_NP5)
        else:
            self._state = self.model.reset_worlds(self._state, mask_N, first_NPHW3, model_seed, poses=poses_NP5)
        if fresh:
            self._np_random_seed = rng_seed
        self._np_random = rng
        obs = self._restart(mask_N)
        infos = {"step": self._steps_N.copy(), "_step": np.ones(self.num_envs, bool)}
        infos["start"] = np.array(starts, dtype=object)
        return obs, infos

    def _reset_mask(self, mask: Any) -> np.ndarray:
        if mask is None:
            return np.ones(self.num_envs, bool)
        mask = np.asarray(mask)
        if mask.shape != (self.num_envs,) or mask.dtype != np.bool_:
            raise ValueError(f"options['reset_mask'] must be a ({self.num_envs},) bool array, "
                             f"got {mask.dtype} {mask.shape}")
        if self._state is None and not mask.all():
            raise RuntimeError("a partial reset needs a full reset() first")
        return mask

    def _given_starts(self, options: dict, mask_N: np.ndarray) -> list | np.ndarray | None:
        """The start frames ``options`` give, checked (nothing drawn): (N, P, H, W, 3) uint8 for ``"frames"``, a
        list of N (frames, start info) or None (sample that world) for ``"engine_state"``, None for neither."""
        shape = (self.num_envs, self.num_players, self.height, self.width, 3)
        if "frames" in options and "engine_state" in options:
            raise ValueError("options may give 'frames' or 'engine_state', not both")
        if "frames" in options:
            frames = options["frames"]
            if getattr(frames, "dtype", None) != np.uint8 or tuple(getattr(frames, "shape", ())) != shape:
                raise ValueError(f"options['frames'] must be a uint8 array of shape {shape}, got dtype "
                                 f"{getattr(frames, 'dtype', None)} shape {getattr(frames, 'shape', None)}")
            return np.asarray(frames)
        states = options.get("engine_state")
        if states is None:
            return None
        if not isinstance(states, (list, tuple)):
            states = [states] * self.num_envs
        if len(states) != self.num_envs:
            raise ValueError(f"options['engine_state'] must be one EngineState or a list of {self.num_envs}, "
                             f"got a list of {len(states)}")
        return [(*self.start_frames.from_options({"engine_state": states[i]}), self.start_frames.poses) if m else None
                for i, m in enumerate(mask_N)]

    def _start_frames(self, given: list | np.ndarray | None, mask_N: np.ndarray,
                      rng: np.random.Generator) -> tuple[np.ndarray, list, np.ndarray | None]:
        """(N, P, H, W, 3) start frames (rows outside ``mask_N`` are filler), per-world start infos and, for a
        model with the partner map (docs/model.md §8.6), the start poses (N, P, 5) (else None): the ``given`` ones
        (``_given_starts``), the others sampled from ``start_states`` with ``rng``."""
        needs_poses = bool(self.model.config.dit.partner_map)
        if isinstance(given, np.ndarray):
            if needs_poses:
                raise ValueError(POSES_NEEDED)
            return given, [{"start": "frames"} if m else None for m in mask_N], None
        shape = (self.num_envs, self.num_players, self.height, self.width, 3)
        out, starts = np.zeros(shape, np.uint8), [None] * self.num_envs
        poses = np.zeros((self.num_envs, self.num_players, 5), np.float32)
        for i in np.flatnonzero(mask_N):
            start = None if given is None else given[i]
            if start is None:
                start = (*self.start_frames.sample(rng), self.start_frames.poses)
            out[i], starts[i], pose = start
            if needs_poses and pose is None:
                raise ValueError(POSES_NEEDED)
            if pose is not None:
                poses[i] = pose
        return out, starts, poses if needs_poses else None

    def _restart(self, mask_N: np.ndarray) -> np.ndarray:
        """Bookkeeping after worlds were (re)initialised: observations, step counters, tasks."""
        frame0_NPHW3 = np.array(self._state.frame0_BPHW3)  # a copy: the state is donated later
        if self._obs_NPHW3 is None:
            self._obs_NPHW3 = np.zeros_like(frame0_NPHW3)
        self._obs_NPHW3[mask_N] = frame0_NPHW3[mask_N]
        self._steps_N[mask_N] = 0
        self._ended_N[mask_N] = False
        self._camera_pending_NP2[mask_N] = 0.0
        for i in np.flatnonzero(mask_N):
            self.tasks[i].reset(self._obs_NPHW3[i])
        return self._obs_NPHW3.copy()

    # -- step -------------------------------------------------------------------------------------
    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        if self._state is None:
            raise RuntimeError("step() called before reset(); call reset()")
        if self.autoreset_mode == AutoresetMode.DISABLED and self._ended_N.any():
            raise RuntimeError(f"worlds {np.flatnonzero(self._ended_N).tolist()} ended and autoreset is disabled; "
                               "reset them with reset(options={'reset_mask': mask})")
        ticks_NPk25, per_world, pending_NP2 = self._world_actions(actions)
        frames_NPkHW3, self._state = self.model.step(self._state, ticks_NPk25)
        self._camera_pending_NP2 = pending_NP2
        frames_NPkHW3 = np.array(frames_NPkHW3)
        obs = frames_NPkHW3[:, :, -1].copy()
        rewards_NP = np.zeros((self.num_envs, self.num_players), np.float32)
        terminations_N = np.zeros(self.num_envs, bool)
        restarting_N = self._ended_N.copy() if self.autoreset_mode == AutoresetMode.NEXT_STEP \
            else np.zeros(self.num_envs, bool)
        for i in np.flatnonzero(~restarting_N):
            outcome = self.tasks[i].step(frames_NPkHW3[i], per_world[i])
            rewards_NP[i], terminations_N[i] = outcome.rewards_P, outcome.terminations_P.any()
        self._steps_N[~restarting_N] += 1
        truncations_N = (self._steps_N >= self.max_steps) & ~terminations_N & ~restarting_N
        infos = {"frames": frames_NPkHW3, "camera_pending": pending_NP2.astype(np.float32)}
        self._obs_NPHW3 = obs.copy()  # kept for autoresets and render; callers get their own arrays
        ended_N = terminations_N | truncations_N
        if self.autoreset_mode == AutoresetMode.SAME_STEP and ended_N.any():
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(ended_N):
                final_obs[i] = obs[i].copy()
            infos["final_obs"] = final_obs
            infos["_final_obs"] = ended_N.copy()
            infos["final_info"] = {"step": self._steps_N.copy(), "_step": ended_N.copy()}
            infos["_final_info"] = ended_N.copy()
            obs = self._autoreset(ended_N)
        elif restarting_N.any():
            obs = self._autoreset(restarting_N)
        self._ended_N = ended_N
        infos["step"] = self._steps_N.copy()  # 0 for worlds that restarted in this call
        return obs, rewards_NP, terminations_N, truncations_N, infos

    def _autoreset(self, mask_N: np.ndarray) -> np.ndarray:
        first_NPHW3, _, poses_NP5 = self._start_frames(None, mask_N, self._np_random)
        self._state = self.model.reset_worlds(self._state, mask_N, first_NPHW3, int(self._np_random.integers(2**31 - 1)),
                                              poses=poses_NP5)
        return self._restart(mask_N)

    def _world_actions(self, actions: Any) -> tuple[np.ndarray, list[list[dict]], np.ndarray]:
        """Batched or per-world actions -> (N, P, k, 25) model ticks, per world the P env actions, and the
        (N, P, 2) camera turns carried to the next step (``dream_env.world_actions``)."""
        per_world = self._split_actions(actions)
        ticks, env_actions, pending = [], [], []
        for i, world in enumerate(per_world):
            try:
                t, a, p = world_actions(world, self.possible_agents, self.possible_agents, self.frames_per_step,
                                        self._camera_pending_NP2[i])
            except (ValueError, TypeError) as err:
                raise type(err)(f"world {i}: {err}") from err
            ticks.append(t)
            env_actions.append(a)
            pending.append(p)
        return np.stack(ticks), env_actions, np.stack(pending)

    def _split_actions(self, actions: Any) -> list:
        n = self.num_envs
        if isinstance(actions, Sequence) and not isinstance(actions, (str, bytes)):
            if len(actions) != n:
                raise ValueError(f"actions as a list must hold one {{agent: action}} dict per world ({n}), "
                                 f"got {len(actions)}")
            return list(actions)
        if not isinstance(actions, Mapping):
            raise TypeError(f"actions must be the batched dict of action_space (agent -> key -> ({n}, ...) arrays) "
                            f"or a list of {n} per-world dicts; got {type(actions).__name__}")
        check_agent_actions(actions, self.possible_agents)
        per_world: list[dict] = [{} for _ in range(n)]
        for agent, keyed in actions.items():
            if not isinstance(keyed, Mapping):
                raise TypeError(f"actions[{agent!r}] must be a dict of batched keys, got {type(keyed).__name__}")
            for i in range(n):
                per_world[i][agent] = {}
            for key, value in keyed.items():
                arr = np.asarray(value)
                if arr.ndim < 1 or arr.shape[0] != n:
                    raise ValueError(f"actions[{agent!r}][{key!r}] must have a leading world axis of {n}, "
                                     f"got shape {arr.shape}")
                for i in range(n):
                    per_world[i][agent][key] = arr[i]
        return per_world

    # -- rendering --------------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """``"rgb_array"``: (N*H, P*W, 3), one row of players per world."""
        if self.render_mode is None or self._obs_NPHW3 is None:
            return None
        return np.concatenate([side_by_side(world) for world in self._obs_NPHW3], axis=0)

    def close_extras(self, **kwargs) -> None:
        self._state = None
