"""``DreamParallelEnv``: the streaming world model as a PettingZoo ``ParallelEnv``.

Same agents (Alpha, Bravo, ...), spaces and step contract as ``RealParallelEnv``, so a policy runs in
both: each agent's action is the MineRL-style dict of ``solaris_env.spaces`` and each observation is that
player's generated first-person frame, ``uint8`` (H, W, 3). One env step is one latent frame of the model,
i.e. k = ``model.frames_per_step`` video frames (engine ticks at 20 Hz); the observation is the last of
them and ``infos[agent]["frames"]`` holds all k.

First increment of issue 5: one world (B = 1), the default task (zero reward, never terminates), start
frames from the engine or from ``options``. Tasks, bundled start scenes, engine-state starts and vector
envs come later.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces as gym_spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from solaris_env.env_common import PlayerViewsEnv
from solaris_env.engine.bots.runner import PLAYER_NAMES
from solaris_env.spaces import BINARY_KEYS, MODEL_INDEX, KEYBOARD_DIM, env_action_to_model_vector, make_action_space

ENGINE_TICKS_PER_SECOND = 20

# Keys that act once per key press in Minecraft: in a step of k ticks they are sent on the first tick only.
# Movement keys (forward, back, left, right, jump, sneak, sprint) are held for all k ticks.
ONCE_KEYS = ("attack", "use", "drop", "inventory", "ESC", "swapHands", "pickItem") + tuple(
    k for k in BINARY_KEYS if k.startswith("hotbar."))
_ONCE_INDICES = np.array([MODEL_INDEX[k] for k in ONCE_KEYS])


def expand_action(vec_25: np.ndarray, k: int) -> np.ndarray:
    """One env step's model vector (25,) -> the k per-tick vectors (k, 25) the model consumes.

    Tick 0 carries the whole action. Ticks 1..k-1 keep the held movement keys but zero the once-keys
    (``ONCE_KEYS``) and the camera: the camera delta is a per-step turn applied on the first tick, not
    repeated k times (each tick's turn is clipped to +-20 degrees by ``camera_linear``).
    """
    ticks_k25 = np.repeat(vec_25[None].astype(np.float32), k, axis=0)
    ticks_k25[1:, _ONCE_INDICES] = 0.0
    ticks_k25[1:, KEYBOARD_DIM:] = 0.0  # camera
    return ticks_k25


class DreamParallelEnv(PlayerViewsEnv, ParallelEnv):
    """The world model with every player an agent.

    No shipped default checkpoint exists yet: without ``checkpoint`` the env uses a preset with
    RANDOM-INIT weights (``WorldModel.from_preset``), which generates noise-like frames. That keeps the
    API usable and testable until the training issue ships a default model.

    Args:
        checkpoint: path to a checkpoint (ours or an official orbax directory) for ``WorldModel.load``.
        preset: preset name when no checkpoint is given (``"tiny"`` by default; ``"test"`` for unit tests).
        num_players: number of players; None takes the model's. With a preset it overrides the preset's
            ``num_players``; with a checkpoint it must equal the checkpoint's.
        max_steps: episode length in env steps; ``truncations`` become True at this step and the agents leave.
        render_mode: None, ``"rgb_array"`` (all views side by side) or ``"human"`` (an OpenCV window).
        seed_model: seed of the random initialisation of a preset (ignored with a checkpoint).
        model: an already built ``WorldModel`` to use instead of ``checkpoint``/``preset`` (shares its
            compiled programs between envs, e.g. in tests).

    Rendering: ``render()`` returns one sheet per env step, i.e. k engine ticks, so
    ``metadata["render_fps"]`` = 20 / k plays it in real time (``infos[agent]["frames"]`` run at 20 fps).
    """

    metadata = {"name": "solaris_dream_v0", "render_modes": ["rgb_array", "human"],
                "render_fps": ENGINE_TICKS_PER_SECOND, "is_parallelizable": True}

    def __init__(self, checkpoint=None, preset: str | None = None, num_players: int | None = None,
                 max_steps: int = 200, render_mode: str | None = None, seed_model: int = 0, model=None):
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        if num_players is not None and not 1 <= num_players <= len(PLAYER_NAMES):
            raise ValueError(f"num_players must be in [1, {len(PLAYER_NAMES)}], got {num_players}")
        if checkpoint is not None and preset is not None:
            raise ValueError(f"give either checkpoint or preset, not both (got {checkpoint!r} and {preset!r})")
        self.model = model if model is not None else _build_model(checkpoint, preset, num_players, seed_model)
        if num_players is not None and self.model.num_players != num_players:
            raise ValueError(f"num_players={num_players} but the model has num_players={self.model.num_players}")
        if self.model.num_players > len(PLAYER_NAMES):
            raise ValueError(f"the model has {self.model.num_players} players; at most {len(PLAYER_NAMES)} are named")
        self.num_players, self.max_steps, self.render_mode = self.model.num_players, max_steps, render_mode
        self.height, self.width, _ = self.model.frame_shape
        self.frames_per_step = self.model.frames_per_step
        self.metadata = {**type(self).metadata, "render_fps": ENGINE_TICKS_PER_SECOND / self.frames_per_step}
        self.possible_agents = list(PLAYER_NAMES[: self.num_players])
        self.agents: list[str] = []
        self._observation_spaces = {a: gym_spaces.Box(0, 255, (self.height, self.width, 3), np.uint8)
                                    for a in self.possible_agents}
        self._action_spaces = {a: make_action_space() for a in self.possible_agents}
        self._state = None  # the model's WorldState (B = 1); donated on every step
        self._frames: np.ndarray | None = None  # (P, H, W, 3): the last frame of each player
        self._start_env = None  # RealParallelEnv that renders default start frames, built on first use
        self._steps = 0

    # -- reset / step -----------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start the model from one frame per player; the observation is the model's frame 0.

        Start frames: ``options={"frames": {agent: (H, W, 3) uint8}}`` (every agent), or by default a
        scene rendered by the engine (``RealParallelEnv(num_players=P, resolution=(H, W))`` reset with a
        seed drawn from ``seed``): players spawned facing each other in a fresh flat world. A bundled
        set of start scenes shipped with the package is future work. Frame 0 is generated by the model
        conditioned on the start frame (not copied), so it equals the start frame only for a trained model.
        Other ``options`` keys are ignored (PettingZoo's API test passes arbitrary ones).
        """
        self.np_random, _ = seeding.np_random(seed)
        options = options or {}
        engine_seed = int(self.np_random.integers(2**31 - 1))
        model_seed = int(self.np_random.integers(2**31 - 1))
        if "frames" in options:
            first_PHW3 = self._check_start_frames(options["frames"])
        else:
            first_PHW3 = self._engine_start_frames(engine_seed)
        self._state = self.model.init(first_PHW3[None], model_seed)
        self._frames = np.array(self._state.frame0_BPHW3[0])
        self.agents = list(self.possible_agents)
        self._steps = 0
        return self._observations(), {a: {"step": 0} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if self._state is None or not self.agents:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        if not isinstance(actions, Mapping):
            raise ValueError(f"actions must be a dict keyed by agent {self.agents}, got {type(actions).__name__}")
        missing = [a for a in self.agents if a not in actions]
        unknown = [a for a in actions if a not in self.agents]
        if missing or unknown:
            raise ValueError(f"actions must have exactly one entry per live agent {self.agents}; "
                             f"missing {missing}, unknown {unknown}")
        # validate every action before the (donating) model call, so a bad action leaves the env intact
        actions_Pk25 = np.stack([expand_action(env_action_to_model_vector(actions[a], agent=a), self.frames_per_step)
                                 for a in self.agents])
        frames_BPkHW3, self._state = self.model.step(self._state, actions_Pk25[None])
        frames_PkHW3 = np.array(frames_BPkHW3[0])
        self._frames = frames_PkHW3[:, -1]
        self._steps += 1
        truncated = self._steps >= self.max_steps
        obs = self._observations()
        rewards = {a: 0.0 for a in self.agents}
        terminations = {a: False for a in self.agents}
        truncations = {a: truncated for a in self.agents}
        infos = {a: {"step": self._steps, "frames": frames_PkHW3[i]} for i, a in enumerate(self.agents)}
        if truncated:
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    # -- start frames -----------------------------------------------------------------------------
    def _check_start_frames(self, frames: Any) -> np.ndarray:
        """``options["frames"]`` -> (P, H, W, 3) uint8 in agent order; ValueError naming the agent."""
        if not isinstance(frames, Mapping):
            raise ValueError(f"options['frames'] must be a dict {{agent: (H, W, 3) uint8}}, "
                             f"got {type(frames).__name__}")
        missing = [a for a in self.possible_agents if a not in frames]
        unknown = [a for a in frames if a not in self.possible_agents]
        if missing or unknown:
            raise ValueError(f"options['frames'] must have one frame per agent {self.possible_agents}; "
                             f"missing {missing}, unknown {unknown}")
        shape = (self.height, self.width, 3)
        for a in self.possible_agents:
            frame = frames[a]
            dtype, got = getattr(frame, "dtype", None), getattr(frame, "shape", None)
            if dtype is None or np.dtype(dtype) != np.uint8 or tuple(got) != shape:
                raise ValueError(f"options['frames'][{a!r}]: expected uint8 array of shape {shape}, "
                                 f"got dtype {dtype} shape {got}")
        return np.stack([np.asarray(frames[a]) for a in self.possible_agents])

    def _engine_start_frames(self, engine_seed: int) -> np.ndarray:
        """(P, H, W, 3) uint8: the engine's first views of a freshly seeded world."""
        if self._start_env is None:
            from solaris_env.real_env import RealParallelEnv

            self._start_env = RealParallelEnv(num_players=self.num_players, resolution=(self.height, self.width))
        obs, _ = self._start_env.reset(seed=engine_seed)
        return np.stack([obs[a] for a in self.possible_agents])

    # -- rendering --------------------------------------------------------------------------------
    def _observations(self) -> dict[str, np.ndarray]:
        return {a: self._frames[i] for i, a in enumerate(self.agents)}


def _build_model(checkpoint, preset: str | None, num_players: int | None, seed_model: int):
    """``WorldModel.load(checkpoint)``, else a random-init preset (``num_players`` overrides the preset's)."""
    from solaris_env.world_model.world_model import WorldModel

    if checkpoint is not None:
        return WorldModel.load(checkpoint)
    override = {} if num_players is None else {"num_players": num_players}
    return WorldModel.from_preset(preset or "tiny", seed=seed_model, **override)


def parallel_env(kind: str = "dream", **kwargs) -> ParallelEnv:
    """Build an env by kind: ``"dream"`` -> ``DreamParallelEnv(**kwargs)``,
    ``"real"`` -> ``RealParallelEnv(**kwargs)``."""
    if kind == "dream":
        return DreamParallelEnv(**kwargs)
    if kind == "real":
        from solaris_env.real_env import RealParallelEnv

        return RealParallelEnv(**kwargs)
    raise ValueError(f"kind must be 'dream' or 'real', got {kind!r}")
