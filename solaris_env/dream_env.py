"""``DreamParallelEnv``: the streaming world model as a PettingZoo ``ParallelEnv`` (one world, B = 1).

Same agents (Alpha, Bravo, ...), spaces and step contract as ``RealParallelEnv``, so a policy runs in
both: each agent's action is the MineRL-style dict of ``solaris_env.spaces`` and each observation is that
player's generated first-person frame, ``uint8`` (H, W, 3). One env step is one latent frame of the model,
i.e. k = ``model.frames_per_step`` video frames (engine ticks at 20 Hz); the observation is the last of
them and ``infos[agent]["frames"]`` holds all k. Many worlds in one batched model call:
``solaris_env.vector_env.DreamVectorEnv``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces as gym_spaces
from pettingzoo import ParallelEnv

from solaris_env.engine.bots.runner import PLAYER_NAMES
from solaris_env.env_common import (
    PlayerViewsEnv,
    available_render_modes,
    check_agent_actions,
    check_int,
    check_options,
    check_render_mode,
    check_seed,
    episode_rng,
)
from solaris_env.spaces import (
    ONCE_KEYS as ONCE_KEYS,  # re-exported: keys sent on the first tick of a step only (spaces.step_ticks)
    _model_vector,
    make_action_space,
    noop,
    step_ticks,
)
from solaris_env.start_scenes import POSES_NEEDED, StartFrames
from solaris_env.tasks import make_task

ENGINE_TICKS_PER_SECOND = 20
DEFAULT_CHECKPOINT = Path(__file__).parent / "assets" / "default"


# ---------------------------------------------------------------------------------------------
# Actions and the model
# ---------------------------------------------------------------------------------------------


def expand_action(action: Any, k: int, pending_deg: Any = None,
                  agent: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One env step's action -> the k per-tick model vectors (k, 25) the model consumes, and the camera turn
    carried to the next step.

    The k per-tick env actions are the engine's (``spaces.step_ticks``, also ``RealParallelEnv(ticks_per_step=k)``):
    tick 0 carries the whole action; ticks 1..k-1 keep the held movement keys but release the once-keys
    (``ONCE_KEYS``); the camera turn (plus ``pending_deg``, what earlier steps left) is spread over the ticks at up
    to ``CAMERA_TICK_LIMIT_DEG`` = 8.59 deg per tick and axis, the range of the model's training data, and what
    does not fit in k ticks is returned as the new pending turn. Each tick becomes its model vector
    (``env_action_to_model_vector``), so ``camera_linear``'s +-20 deg clip never acts on an env action.
    """
    ticks, pending = step_ticks(action, k, pending_deg, agent)
    return np.stack([_model_vector(tick) for tick in ticks]), pending  # ticks are validated


def world_actions(actions: Any, agents: list[str], live: list[str], k: int,
                  pending_P2: np.ndarray | None = None) -> tuple[np.ndarray, list[dict], np.ndarray]:
    """One world's actions -> (P, k, 25) model ticks, the P env actions and the (P, 2) camera turns carried to the
    next step, in ``agents`` order (``pending_P2``: the carried turns of the last step; None = none).

    ``actions`` must hold exactly the ``live`` agents; players whose agent has ended get a no-op (and keep turning
    what they had pending). Every action is validated first (ValueError naming the agent and the key), so a bad
    one changes nothing.
    """
    check_agent_actions(actions, live)
    per_player = [actions[a] if a in live else noop() for a in agents]
    pending_P2 = np.zeros((len(agents), 2)) if pending_P2 is None else pending_P2
    expanded = [expand_action(act, k, pending_P2[i], a) for i, (a, act) in enumerate(zip(agents, per_player))]
    return np.stack([t for t, _ in expanded]), per_player, np.stack([p for _, p in expanded])


def build_model(checkpoint=None, preset: str | None = None, num_players: int | None = None, seed_model: int = 0):
    """The world model of a dream env.

    ``checkpoint`` -> ``WorldModel.load``; else ``preset`` -> random-init weights (``num_players`` overrides
    the preset's); with neither, the shipped default checkpoint ``solaris_env/assets/default/``.
    """
    from solaris_env.world_model.world_model import WorldModel

    if checkpoint is not None and preset is not None:
        raise ValueError(f"give either checkpoint or preset, not both (got {checkpoint!r} and {preset!r})")
    if preset is not None:
        override = {} if num_players is None else {"num_players": num_players}
        return WorldModel.from_preset(preset, seed=seed_model, **override)
    if checkpoint is None:
        if not DEFAULT_CHECKPOINT.exists():
            raise FileNotFoundError(
                f"no trained default world model is shipped yet ({DEFAULT_CHECKPOINT} does not exist; it is being "
                "trained). Pass checkpoint=PATH for a trained model, or preset='tiny' (or 'test') for a "
                "random-init model that generates noise-like frames.")
        checkpoint = DEFAULT_CHECKPOINT
    model = WorldModel.load(checkpoint)
    if num_players is not None and model.num_players != num_players:
        raise ValueError(f"num_players={num_players} but the checkpoint {checkpoint} has "
                         f"num_players={model.num_players}")
    return model


def check_model_players(model, num_players: int | None) -> int:
    if num_players is not None and not 1 <= num_players <= len(PLAYER_NAMES):
        raise ValueError(f"num_players must be in [1, {len(PLAYER_NAMES)}], got {num_players}")
    if num_players is not None and model.num_players != num_players:
        raise ValueError(f"num_players={num_players} but the model has num_players={model.num_players}")
    if model.num_players > len(PLAYER_NAMES):
        raise ValueError(f"the model has {model.num_players} players; at most {len(PLAYER_NAMES)} are named")
    return model.num_players


# ---------------------------------------------------------------------------------------------
# The env
# ---------------------------------------------------------------------------------------------


class DreamParallelEnv(PlayerViewsEnv, ParallelEnv):
    """The world model with every player an agent.

    Args:
        checkpoint: path to a checkpoint (ours or an official orbax directory) for ``WorldModel.load``.
            None with no ``preset``: the shipped default ``solaris_env/assets/default/`` (a clear
            FileNotFoundError until the trained default ships).
        preset: a preset name (``"tiny"``, ``"test"``, ``"solaris"``) for a RANDOM-INIT model (noise-like
            frames; for tests and benchmarks).
        num_players: number of players; None takes the model's. With a preset it overrides the preset's
            ``num_players``; with a checkpoint it must equal the checkpoint's.
        max_steps: episode length in env steps; ``truncations`` become True at this step and the agents leave.
        task: rewards and terminations from frames (``solaris_env.tasks``): None (zero reward), a task name,
            a Task class or instance. Tasks that need the engine's ground truth are refused.
        render_mode: None, ``"rgb_array"`` (all views side by side) or ``"human"`` (an OpenCV window; needs
            a display and OpenCV with GUI support, else a RuntimeError at construction).
        start_states: where reset's start frames come from when ``options`` give none: ``"bundled"`` (the
            shipped engine-rendered start scenes), ``"engine"`` (a fresh engine world per reset), a list of
            ``EngineState`` or a uint8 array (S, P, H, W, 3); sampled by the reset seed
            (``solaris_env.start_scenes``).
        seed_model: seed of the random initialisation of a preset (ignored with a checkpoint).
        model: an already built ``WorldModel`` to use instead of ``checkpoint``/``preset`` (shares its
            compiled programs between envs, e.g. in tests).

    Rendering: ``render()`` returns one sheet per env step, i.e. k engine ticks, so
    ``metadata["render_fps"]`` = 20 / k plays it in real time (``infos[agent]["frames"]`` run at 20 fps).

    Camera: a step's turn is spread over its k ticks at up to ``spaces.CAMERA_TICK_LIMIT_DEG`` = 8.59 deg per tick
    and axis (the per-tick range of the model's training data), so one step turns up to k * 8.59 deg (34.4 at
    k = 4) per axis; the rest of a larger turn (a yaw of 90 deg: 34.4 + 34.4 + 21.2) is carried over and turned in
    the next steps, before their own turns, as ``RealParallelEnv(ticks_per_step=k)`` does
    (``spaces.step_ticks``). Nothing is clipped. What is still to turn is part of the env's state:
    ``infos[agent]["camera_pending"]`` ([dpitch, dyaw] degrees), kept while the agent has ended (its player
    is sent no-ops), cleared by ``reset``.

    Determinism: the same seed and actions give identical frames (bit-exact) in one process and across processes on
    one machine and JAX build (measured: the test preset and the shipped model, a fresh compile or the persistent
    compilation cache, 1 or 2 cores, Eigen multi-threading on or off: 0 differing pixels;
    ``tests/solaris_env/test_dream_env.py``). Another CPU or XLA build may round differently.

    Observations, ``infos[agent]["frames"]`` and ``render()`` are arrays the caller owns (copies: ~10 us a step
    at 64x64); ``step_frames()`` is a read-only view of the env's buffer.
    """

    metadata: ClassVar[dict] = {"name": "solaris_dream_v0", "render_modes": ["rgb_array", "human"],
                                "render_fps": ENGINE_TICKS_PER_SECOND, "is_parallelizable": True}

    def __init__(self, checkpoint=None, preset: str | None = None, num_players: int | None = None,
                 max_steps: int = 200, task=None, render_mode: str | None = None, start_states: Any = "bundled",
                 seed_model: int = 0, model=None):
        max_steps = check_int(max_steps, "max_steps")
        check_render_mode(render_mode)
        if num_players is not None and not 1 <= check_int(num_players, "num_players") <= len(PLAYER_NAMES):
            raise ValueError(f"num_players must be in [1, {len(PLAYER_NAMES)}], got {num_players}")
        self.task = make_task(task)
        if self.task.requires_truth:
            raise ValueError(f"task {self.task.name!r} needs the engine's ground truth; the dream env has none "
                             "(use it with RealParallelEnv)")
        self.model = model if model is not None else build_model(checkpoint, preset, num_players, seed_model)
        self.num_players = check_model_players(self.model, num_players)
        self.max_steps, self.render_mode = max_steps, render_mode
        self.height, self.width, _ = self.model.frame_shape
        self.frames_per_step = self.model.frames_per_step
        self.metadata = {**type(self).metadata, "render_modes": available_render_modes(),
                         "render_fps": ENGINE_TICKS_PER_SECOND / self.frames_per_step}
        self.possible_agents = list(PLAYER_NAMES[: self.num_players])
        self.agents: list[str] = []
        self._observation_spaces = {a: gym_spaces.Box(0, 255, (self.height, self.width, 3), np.uint8)
                                    for a in self.possible_agents}
        self._action_spaces = {a: make_action_space() for a in self.possible_agents}
        self.start_frames = StartFrames(start_states, self.possible_agents, self.height, self.width)
        self._state = None  # the model's WorldState (B = 1); donated on every step
        self._frames: np.ndarray | None = None  # (P, H, W, 3): the last frame of each player
        self._step_frames: np.ndarray | None = None  # (P, k, H, W, 3): all frames of the last step
        self._steps = 0
        self._camera_pending_P2 = np.zeros((self.num_players, 2))  # [dpitch, dyaw] deg still to turn (step_ticks)
        self.np_random: np.random.Generator | None = None  # seeded by reset(seed)

    # -- reset / step -----------------------------------------------------------------------------
    RESET_OPTIONS = ("frames", "engine_state")

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start the model from one frame per player; the observation is the model's frame 0.

        Start frames, by priority: ``options={"frames": {agent: (H, W, 3) uint8}}`` (every agent),
        ``options={"engine_state": EngineState}`` (rendered with the engine), else ``start_states`` sampled
        with ``seed``. Frame 0 is generated by the model conditioned on the start frame (not copied), so it
        equals the start frame only for a trained model. Any other ``options`` key raises ValueError (except
        ``"options"``, PettingZoo's API-test probe, which is ignored). ``seed``: None or an int >= 0 (numpy
        integers too; not a bool). ``infos[agent]["start"]`` says which start was used. Everything is checked
        before anything is drawn: a reset that raises changes nothing (not the seed stream, not the episode).
        """
        seed = check_seed(seed)
        options = check_options(options, self.RESET_OPTIONS)
        given = self.start_frames.from_options(options)
        rng = episode_rng(self.np_random, seed)  # no seed: continue the episode stream (Gymnasium rule)
        first_PHW3, start = given if given is not None else self.start_frames.sample(rng)
        model_seed = int(rng.integers(2**31 - 1))
        self._state = self.model.init(first_PHW3[None], model_seed, poses=self._start_poses())
        self.np_random = rng
        self._frames = _read_only(np.array(self._state.frame0_BPHW3)[0])  # a copy: the state is donated later
        self._step_frames = self._frames[:, None]
        self._camera_pending_P2 = np.zeros((self.num_players, 2))
        self.agents = list(self.possible_agents)
        self._steps = 0
        self.task.reset(self._frames)
        return self._observations(), {a: {"step": 0, **start, "camera_pending": np.zeros(2, np.float32)}
                                      for a in self.agents}

    def _start_poses(self) -> np.ndarray | None:
        """(1, P, 5) the start's poses for a model with the partner map (docs/model.md §8.6), else None."""
        if not self.model.config.dit.partner_map:
            return None
        if self.start_frames.poses is None:
            raise ValueError(POSES_NEEDED)
        return self.start_frames.poses[None]

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if self._state is None or not self.agents:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        # validate every action before the (donating) model call, so a bad action leaves the env intact
        ticks_Pk25, per_player, pending_P2 = world_actions(actions, self.possible_agents, self.agents,
                                                           self.frames_per_step, self._camera_pending_P2)
        frames_BPkHW3, self._state = self.model.step(self._state, ticks_Pk25[None])
        frames_PkHW3 = _read_only(np.array(frames_BPkHW3)[0])
        self._frames, self._step_frames = frames_PkHW3[:, -1], frames_PkHW3
        self._camera_pending_P2 = pending_P2
        self._steps += 1
        outcome = self.task.step(frames_PkHW3, per_player)
        infos = [{"step": self._steps, "frames": frames_PkHW3[i].copy(),
                  "camera_pending": pending_P2[i].astype(np.float32)} for i in range(self.num_players)]
        return self._step_outputs(outcome.rewards_P, outcome.terminations_P, self._steps >= self.max_steps, infos)


def _read_only(array: np.ndarray) -> np.ndarray:
    """``array`` marked read-only (the env's frame buffers: callers get copies or read-only views)."""
    array.setflags(write=False)
    return array


def parallel_env(kind: str = "dream", **kwargs) -> ParallelEnv:
    """Build an env by kind: ``"dream"`` -> ``DreamParallelEnv(**kwargs)``,
    ``"real"`` -> ``real_backends.make_real_env(**kwargs)`` (``backend="voxel"`` by default, or ``"minecraft"``)."""
    if kind == "dream":
        return DreamParallelEnv(**kwargs)
    if kind == "real":
        from solaris_env.real_backends import make_real_env

        return make_real_env(**kwargs)
    raise ValueError(f"kind must be 'dream' or 'real', got {kind!r}")
