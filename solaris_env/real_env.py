"""``RealParallelEnv``: the voxel engine as a PettingZoo ``ParallelEnv``.

Same agents, spaces and step contract as the dream env: each agent's action is the MineRL-style dict of
``solaris_env.spaces`` and each observation is that player's first-person frame, ``uint8`` (H, W, 3). The
env only translates; game logic lives in ``solaris_env.engine``.

An :class:`EngineState` is a snapshot of the game (the voxel world and every player's full state: pose,
velocity, inventory, digging progress, tick). ``RealParallelEnv.engine_state()`` takes one and
``reset(options={"engine_state": s})`` on the real or the dream env starts there, so both can be run from
the same state (the dream env renders the state's views with the engine and starts the model from them).
"""

from __future__ import annotations

import copy
import functools
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces as gym_spaces
from pettingzoo import ParallelEnv

from solaris_env.engine.bots.runner import PLAYER_NAMES, make_players, spawn_positions
from solaris_env.engine.game import Game
from solaris_env.engine.trace import Trace
from solaris_env.engine.worldgen import FLAT_VARIANTS, WorldConfig, generate
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
from solaris_env.spaces import make_action_space, noop, step_ticks, validate_action
from solaris_env.tasks import make_task

WORLD_CHOICES = ("flat", "normal", "mixed")
DEFAULT_VIEW_DISTANCE = 48.0  # blocks, as the recorded training data


# ---------------------------------------------------------------------------------------------
# Engine state and rendering
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class EngineState:
    """A snapshot of an engine game: the world and all players, independent of any frame size.

    Holds a private deep copy; ``game()`` returns a fresh copy each call, so one snapshot can start any
    number of episodes (real or dream) and is never changed by them.
    """

    _game: Game

    @classmethod
    def of(cls, game: Game) -> EngineState:
        return cls(copy.deepcopy(game))

    def game(self) -> Game:
        return copy.deepcopy(self._game)

    @property
    def player_names(self) -> list[str]:
        return [p.name for p in self._game.players]

    @property
    def num_players(self) -> int:
        return len(self._game.players)

    @property
    def tick(self) -> int:
        return self._game.tick

    @property
    def poses(self) -> np.ndarray:
        """(P, 5) float32 every player's [x, y, z, yaw, pitch]: feet in blocks, camera in Mineflayer radians (the
        start a partner-map model dead reckons from, ``WorldModel.init(..., poses=)``)."""
        return np.array([[*p.pos, p.yaw, p.pitch] for p in self._game.players], np.float32)


def check_engine_state(state: Any, agents: list[str]) -> EngineState:
    """``options["engine_state"]`` must be an EngineState whose players are exactly ``agents``."""
    if not isinstance(state, EngineState):
        raise TypeError(f"options['engine_state'] must be an EngineState (RealParallelEnv.engine_state()), "
                         f"got {type(state).__name__}")
    if state.player_names != list(agents):
        raise ValueError(f"options['engine_state'] has players {state.player_names}; this env has {list(agents)}")
    return state


@functools.lru_cache(maxsize=8)
def _renderer(height: int, width: int, view_distance: float, hud: bool):
    """One jitted renderer per configuration, shared by every env in the process."""
    from solaris_env.engine.render import RenderConfig, Renderer

    return Renderer(RenderConfig(height=height, width=width, view_distance=view_distance, hud=hud))


def render_game_views(game: Game, height: int, width: int, view_distance: float = DEFAULT_VIEW_DISTANCE,
                      hud: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Every player's first-person view of the game now.

    Returns:
        rgb_PHW3: uint8 (P, H, W, 3); avatar_id_PHW: per pixel, the index of the player drawn there (-1: none).
    """
    from solaris_env.engine.capture import views_from_trace

    snap = Trace([p.name for p in game.players], [p.skin for p in game.players], game.world.blocks_XYZ,
                 game.world.origin, records=[])
    snap.append_state(game)
    snap.finish()
    views = views_from_trace(snap, 0, 1, np.zeros(1, np.int32))
    rgb, avatar_id = _renderer(height, width, view_distance, hud).render(game.world.blocks_XYZ[None],
                                                                         game.world.origin, views)
    return np.asarray(rgb), np.asarray(avatar_id)


def screen_position(avatar_id_HW: np.ndarray, player: int) -> dict:
    """Where ``player`` shows on one screen: ``{"pixels": n, "u": centroid column in [0, 1] (pixel centres,
    0 = left edge) or None when n == 0}``; the same ``u`` as the ground-truth sidecar's (``capture``)."""
    mask_HW = avatar_id_HW == player
    n = int(mask_HW.sum())
    if n == 0:
        return {"pixels": 0, "u": None}
    w = mask_HW.shape[1]
    u = float(mask_HW.sum(0) @ ((np.arange(w) + 0.5) / w)) / n
    return {"pixels": n, "u": u}


# ---------------------------------------------------------------------------------------------
# The env
# ---------------------------------------------------------------------------------------------


class RealParallelEnv(PlayerViewsEnv, ParallelEnv):
    """The voxel engine with every player an agent. One env step is ``ticks_per_step`` 20 Hz engine ticks
    (default 1). The real env's other backend, real Minecraft stepped in real time, is
    ``solaris_env.minecraft_env.MinecraftParallelEnv``; ``solaris_env.real_backends.make_real_env(backend=...)``
    builds either by name.

    Args:
        num_players: number of players (1..8); agents are named Alpha, Bravo, Charlie, ...
        world: ``"flat"``, ``"normal"`` or ``"mixed"`` (flat or normal drawn at each reset).
        resolution: frame size, an int (square) or (height, width); at least 36 for SB3 CNN policies.
        max_steps: episode length; ``truncations`` become True at this step and the agents leave.
        task: rewards and terminations (``solaris_env.tasks``): None (zero reward), a task name, a Task
            class or instance. Tasks here also get the engine's ground truth (the per-player infos).
        render_mode: None, ``"rgb_array"`` (all views side by side) or ``"human"`` (an OpenCV window; needs
            a display and OpenCV with GUI support, else a RuntimeError at construction).
        spawn_distance: (min, max) blocks between the first two players at reset.
        view_distance: render distance in blocks (fog ends there).
        hud: draw the hotbar and crosshair.
        ticks_per_step: engine ticks per env step (k). With k > 1 a step plays like a dream env step of k
            frames: the first tick gets the whole action, ticks 2..k keep the movement keys held but release
            the once-keys, and the camera turn is spread over the ticks (below; ``spaces.step_ticks``); every tick is rendered
            (``step_frames()`` is (P, k, H, W, 3)), the task scores the step once with all k frames, and the
            infos are the last tick's, with ``placed``/``mined`` gathered over the k ticks. Use the world
            model's ``frames_per_step`` to compare a policy in both envs.

    Infos (per agent): ``pos``, ``yaw``, ``pitch`` (the player's pose), ``step``, ``sees`` (other player ->
    visible on this screen), ``screen`` (other player -> ``{"pixels": avatar pixels on this screen, "u":
    their centroid's horizontal position in [0, 1], None when no pixel shows}``, from the renderer's
    per-pixel player ids), and after a step ``action_record``, ``placed``, ``mined``.

    Camera: a player turns at most ``spaces.CAMERA_TICK_LIMIT_DEG`` = 8.59 deg per tick and axis (the look speed
    of the recorded data and the world model's per-tick range), so one step turns up to k * 8.59 deg per axis
    from its first tick on; the rest of a larger turn (a yaw of 90 deg at k = 4: 34.4 + 34.4 + 21.2) is carried
    over and turned in the next steps, before their own turns -- the dream env's rule, so an action means the
    same in both envs. Nothing is clipped. What is still to turn is part of the env's state
    (``infos[agent]["camera_pending"]``, [dpitch, dyaw] degrees; kept while the agent has ended, cleared by
    ``reset``). Pitch stops at +-90 deg as in the game (what is pending beyond it is still turned against it).

    ``reset(seed, options)`` options: ``{"world": "flat" | "normal"}`` overrides the world kind for the
    episode; ``{"engine_state": EngineState}`` starts from a snapshot instead of a fresh world. Any other key
    raises ValueError (except ``"options"``, PettingZoo's API-test probe, ignored). ``seed``: None or an int
    >= 0 (numpy integers too; not a bool). ``reset()`` without a seed continues the generator of the last
    seeded reset (Gymnasium's rule), so a seeded run of episodes is reproducible. A reset that raises changes
    nothing (everything is checked before anything is drawn). Observations are copies the caller owns.
    """

    metadata: ClassVar[dict] = {"name": "solaris_real_v0", "render_modes": ["rgb_array", "human"], "render_fps": 20,
                "is_parallelizable": True}
    backend: ClassVar[str] = "voxel"  # its name in ``real_backends.BACKENDS``

    def __init__(self, num_players: int = 2, world: str = "flat", resolution: int | tuple[int, int] = 64,
                 max_steps: int = 1000, render_mode: str | None = None,
                 spawn_distance: tuple[float, float] = (6.0, 10.0), view_distance: float = DEFAULT_VIEW_DISTANCE,
                 hud: bool = True, task=None, ticks_per_step: int = 1):
        if not 1 <= num_players <= len(PLAYER_NAMES):
            raise ValueError(f"num_players must be in [1, {len(PLAYER_NAMES)}], got {num_players}")
        if world not in WORLD_CHOICES:
            raise ValueError(f"world must be one of {WORLD_CHOICES}, got {world!r}")
        h, w = (resolution, resolution) if isinstance(resolution, int) else tuple(resolution)
        if h < 8 or w < 8:
            raise ValueError(f"resolution must be at least 8x8, got {(h, w)}")
        max_steps = check_int(max_steps, "max_steps")
        ticks_per_step = check_int(ticks_per_step, "ticks_per_step")
        check_render_mode(render_mode)
        if not 0 < spawn_distance[0] <= spawn_distance[1]:
            raise ValueError(f"spawn_distance must be (min, max) with 0 < min <= max, got {spawn_distance}")
        self.num_players, self.world_kind, self.max_steps = num_players, world, max_steps
        self.ticks_per_step = int(ticks_per_step)
        self.render_mode = render_mode
        self.metadata = {**type(self).metadata, "render_fps": 20 / self.ticks_per_step,
                         "render_modes": available_render_modes()}
        self.height, self.width = h, w
        self.spawn_distance, self.view_distance, self.hud = spawn_distance, view_distance, hud
        self.task = make_task(task)
        self.world_config = WorldConfig()
        self.possible_agents = list(PLAYER_NAMES[:num_players])
        self.agents: list[str] = []
        self._observation_spaces = {a: gym_spaces.Box(0, 255, (h, w, 3), np.uint8) for a in self.possible_agents}
        self._action_spaces = {a: make_action_space() for a in self.possible_agents}
        self.game: Game | None = None
        self._frames: np.ndarray | None = None  # (P, H, W, 3) of the current state
        self._step_frames: np.ndarray | None = None  # (P, k, H, W, 3): every tick of the last step
        self._steps = 0
        self._camera_pending_P2 = np.zeros((num_players, 2))  # [dpitch, dyaw] deg still to turn (step_ticks)
        self.np_random: np.random.Generator | None = None  # seeded by reset(seed)

    # -- reset / step -----------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Build a fresh seeded world and spawn the players facing each other, or start from
        ``options["engine_state"]``."""
        seed = check_seed(seed)
        options = check_options(options, self.RESET_OPTIONS)
        state = check_engine_state(options["engine_state"], self.possible_agents) if "engine_state" in options \
            else None
        kind = options.get("world", self.world_kind)
        if kind not in WORLD_CHOICES:
            raise ValueError(f"options['world'] must be 'flat' or 'normal' (or 'mixed'), got {kind!r}")
        rng = episode_rng(self.np_random, seed)  # no seed: continue the episode stream (Gymnasium rule)
        self.game = state.game() if state is not None else self._new_game(kind, rng)
        self.np_random = rng
        self.agents = list(self.possible_agents)
        self._camera_pending_P2 = np.zeros((self.num_players, 2))
        self._steps = 0
        self._frames = self._render_views()
        self._step_frames = self._frames[:, None]
        infos = [self._info(i) for i in range(self.num_players)]
        self.task.reset(self._frames, truth=infos)
        return self._observations(), dict(zip(self.possible_agents, infos))

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if self.game is None or not self.agents:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        per_player, ticks_P = self._tick_actions(actions)  # P env actions, P lists of k tick actions
        frames, events = [], []
        for t in range(self.ticks_per_step):
            events.append(self.game.step([ticks[t] for ticks in ticks_P]))
            frames.append(self._render_views())
        self._steps += 1
        self._frames = frames[-1]
        self._step_frames = np.stack(frames, axis=1)  # (P, k, H, W, 3)
        infos = [self._info(i, [tick[i] for tick in events]) for i in range(self.num_players)]
        outcome = self.task.step(self._step_frames, per_player, truth=infos)
        return self._step_outputs(outcome.rewards_P, outcome.terminations_P, self._steps >= self.max_steps, infos)

    def engine_state(self) -> EngineState:
        """A snapshot of the current game (see ``EngineState``); raises before the first reset."""
        if self.game is None:
            raise RuntimeError("engine_state() called before reset(); call reset() first")
        return EngineState.of(self.game)

    # -- internals --------------------------------------------------------------------------------
    RESET_OPTIONS = ("world", "engine_state")

    def _tick_actions(self, actions: Any) -> tuple[list[dict], list[list[dict]]]:
        """Check every action (ValueError naming the agent and key) and split each into its k ticks with the
        carried camera turn (``spaces.step_ticks``); the new pending turns are kept only when all are valid.
        Players whose agent has ended get a no-op (and keep turning what they had pending)."""
        check_agent_actions(actions, self.agents)
        per_player = [validate_action(actions[a], agent=a) if a in self.agents else noop()
                      for a in self.possible_agents]
        split = [step_ticks(act, self.ticks_per_step, self._camera_pending_P2[i], agent=a)
                 for i, (a, act) in enumerate(zip(self.possible_agents, per_player))]
        self._camera_pending_P2 = np.stack([pending for _, pending in split])
        return per_player, [ticks for ticks, _ in split]

    def _new_game(self, kind: str, rng: np.random.Generator) -> Game:
        if kind == "mixed":
            kind = ("flat", "normal")[int(rng.integers(2))]
        world_seed = int(rng.integers(2**31 - 1))
        world = generate(kind, world_seed, variant=int(rng.integers(len(FLAT_VARIANTS))),
                         cfg=self.world_config)
        n = max(2, self.num_players)
        feet = spawn_positions(world, rng, n, *self.spawn_distance, self.world_config)[: self.num_players]
        return Game(world, make_players(feet), world_age=6000)

    def _render_views(self) -> np.ndarray:
        rgb, self._avatar_id = render_game_views(self.game, self.height, self.width, self.view_distance, self.hud)
        return rgb

    def _info(self, i: int, events=None) -> dict:
        """Player i's info now; ``events``: its TickEvents of each tick of the step (None at reset)."""
        p = self.game.players[i]
        screen = {q.name: screen_position(self._avatar_id[i], j) for j, q in enumerate(self.game.players) if j != i}
        info = {"pos": p.pos.copy(), "yaw": p.yaw, "pitch": p.pitch, "step": self._steps,
                "sees": {name: s["pixels"] > 0 for name, s in screen.items()}, "screen": screen,
                "camera_pending": self._camera_pending_P2[i].astype(np.float32)}
        if events is not None:
            info["action_record"] = events[-1].record
            info["placed"] = [cell for e in events for cell in e.placed]
            info["mined"] = [cell for e in events for cell in e.mined]
        return info
