"""``RealParallelEnv``: the voxel engine as a PettingZoo ``ParallelEnv``.

Same agents, spaces and step contract as the dream env: each agent's action is the MineRL-style dict of
``solaris_env.spaces`` and each observation is that player's first-person frame, ``uint8`` (H, W, 3). The
env only translates; game logic lives in ``solaris_env.engine``.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import spaces as gym_spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from solaris_env.env_common import PlayerViewsEnv
from solaris_env.engine.bots.runner import PLAYER_NAMES, make_players, spawn_positions
from solaris_env.engine.game import Game
from solaris_env.engine.trace import Trace
from solaris_env.engine.worldgen import FLAT_VARIANTS, WorldConfig, generate
from solaris_env.spaces import make_action_space

WORLD_CHOICES = ("flat", "normal", "mixed")


@functools.lru_cache(maxsize=8)
def _renderer(height: int, width: int, view_distance: float, hud: bool):
    """One jitted renderer per configuration, shared by every env in the process."""
    from solaris_env.engine.render import RenderConfig, Renderer

    return Renderer(RenderConfig(height=height, width=width, view_distance=view_distance, hud=hud))


class RealParallelEnv(PlayerViewsEnv, ParallelEnv):
    """The voxel engine with every player an agent.

    Args:
        num_players: number of players (2..8); agents are named Alpha, Bravo, Charlie, ...
        world: ``"flat"``, ``"normal"`` or ``"mixed"`` (flat or normal drawn at each reset).
        resolution: frame size, an int (square) or (height, width); at least 36 for SB3 CNN policies.
        max_steps: episode length; ``truncations`` become True at this step and the agents leave.
        render_mode: None, ``"rgb_array"`` (all views side by side) or ``"human"`` (an OpenCV window).
        spawn_distance: (min, max) blocks between the first two players at reset.
        view_distance: render distance in blocks (fog ends there).
        hud: draw the hotbar and crosshair.
    """

    metadata = {"name": "solaris_real_v0", "render_modes": ["rgb_array", "human"], "render_fps": 20,
                "is_parallelizable": True}

    def __init__(self, num_players: int = 2, world: str = "flat", resolution: int | tuple[int, int] = 64,
                 max_steps: int = 1000, render_mode: str | None = None,
                 spawn_distance: tuple[float, float] = (6.0, 10.0), view_distance: float = 48.0, hud: bool = True):
        if not 1 <= num_players <= len(PLAYER_NAMES):
            raise ValueError(f"num_players must be in [1, {len(PLAYER_NAMES)}], got {num_players}")
        if world not in WORLD_CHOICES:
            raise ValueError(f"world must be one of {WORLD_CHOICES}, got {world!r}")
        h, w = (resolution, resolution) if isinstance(resolution, int) else tuple(resolution)
        if h < 8 or w < 8:
            raise ValueError(f"resolution must be at least 8x8, got {(h, w)}")
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        if not 0 < spawn_distance[0] <= spawn_distance[1]:
            raise ValueError(f"spawn_distance must be (min, max) with 0 < min <= max, got {spawn_distance}")
        self.num_players, self.world_kind, self.max_steps = num_players, world, max_steps
        self.render_mode = render_mode
        self.height, self.width = h, w
        self.spawn_distance, self.view_distance, self.hud = spawn_distance, view_distance, hud
        self.world_config = WorldConfig()
        self.possible_agents = list(PLAYER_NAMES[:num_players])
        self.agents: list[str] = []
        self._observation_spaces = {a: gym_spaces.Box(0, 255, (h, w, 3), np.uint8) for a in self.possible_agents}
        self._action_spaces = {a: make_action_space() for a in self.possible_agents}
        self.game: Game | None = None
        self._frames: np.ndarray | None = None  # (P, H, W, 3) of the current state
        self._steps = 0

    # -- reset / step -----------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Build a fresh seeded world and spawn the players facing each other.

        ``options``: ``{"world": "flat" | "normal"}`` overrides the world kind for this episode.
        """
        self.np_random, _ = seeding.np_random(seed)
        options = options or {}
        kind = options.get("world", self.world_kind)
        if kind == "mixed":
            kind = ("flat", "normal")[int(self.np_random.integers(2))]
        if kind not in ("flat", "normal"):
            raise ValueError(f"options['world'] must be 'flat' or 'normal', got {kind!r}")
        world_seed = int(self.np_random.integers(2**31 - 1))
        world = generate(kind, world_seed, variant=int(self.np_random.integers(len(FLAT_VARIANTS))),
                         cfg=self.world_config)
        n = max(2, self.num_players)
        feet = spawn_positions(world, self.np_random, n, *self.spawn_distance, self.world_config)[: self.num_players]
        self.game = Game(world, make_players(feet), world_age=6000)
        self.agents = list(self.possible_agents)
        self._steps = 0
        self._frames = self._render_views()
        return self._observations(), {a: self._info(i) for i, a in enumerate(self.agents)}

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if self.game is None or not self.agents:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        missing = [a for a in self.agents if a not in actions]
        unknown = [a for a in actions if a not in self.agents]
        if missing or unknown:
            raise ValueError(f"actions must have exactly one entry per live agent {self.agents}; "
                             f"missing {missing}, unknown {unknown}")
        events = self.game.step([actions[a] for a in self.agents])
        self._steps += 1
        self._frames = self._render_views()
        truncated = self._steps >= self.max_steps
        obs = self._observations()
        rewards = {a: 0.0 for a in self.agents}
        terminations = {a: False for a in self.agents}
        truncations = {a: truncated for a in self.agents}
        infos = {a: self._info(i, events[i]) for i, a in enumerate(self.agents)}
        if truncated:
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    # -- rendering --------------------------------------------------------------------------------
    def _render_views(self) -> np.ndarray:
        from solaris_env.engine.capture import views_from_trace

        g = self.game
        snap = Trace([p.name for p in g.players], [p.skin for p in g.players],
                     g.world.blocks_XYZ, g.world.origin, records=[])
        snap.append_state(g)
        snap.finish()
        views = views_from_trace(snap, 0, 1, np.zeros(1, np.int32))
        rgb, avatar_id = _renderer(self.height, self.width, self.view_distance, self.hud).render(
            g.world.blocks_XYZ[None], g.world.origin, views)
        self._avatar_id = avatar_id
        return rgb

    def _observations(self) -> dict[str, np.ndarray]:
        return {a: self._frames[i] for i, a in enumerate(self.agents)}

    def _info(self, i: int, event=None) -> dict:
        p = self.game.players[i]
        seen = self._avatar_id[i]
        others = {q.name: bool((seen == j).any()) for j, q in enumerate(self.game.players) if j != i}
        info = {"pos": p.pos.copy(), "yaw": p.yaw, "pitch": p.pitch, "step": self._steps, "sees": others}
        if event is not None:
            info["action_record"] = event.record
            info["placed"], info["mined"] = event.placed, event.mined
        return info
