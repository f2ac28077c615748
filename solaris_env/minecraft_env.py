"""``MinecraftParallelEnv``: the real env on real Minecraft 1.20.1, stepped in real time (the ``"minecraft"``
backend of ``real_backends.make_real_env``).

The players are mineflayer bots on a local flying-squid server; their first-person views are rendered by
prismarine-viewer in the bridge process (``engine/minecraft/env_bridge.js``), which Python drives over a
line-JSON TCP protocol on 127.0.0.1 (``engine/minecraft/bridge.py``). Same agents, spaces, observation
shape, ``ticks_per_step`` rule and task plumbing as the voxel env (``real_env.py``); the game runs on its
own 20 Hz clock, so timing is part of the contract (see :class:`MinecraftParallelEnv`).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from solaris_env.engine.blocks import BY_NAME
from solaris_env.engine.minecraft.collect import frames_from_rgba, render_size
from solaris_env.engine.minecraft.install import setup_problem
from solaris_env.engine.minecraft.records import (
    CONTROL_KEYS,
    EYE_HEIGHT,
    PLAYER_HALF_WIDTH,
    PLAYER_HEIGHT,
    action_record,
    project_box,
)
from solaris_env.env_common import check_options, check_seed, episode_rng
from solaris_env.real_env import RealParallelEnv
from solaris_env.spaces import minerl_camera_to_mineflayer

FOV_DEG = 70.0
DISPLAY_ASPECT = 16 / 9
SNEAK_EYE_HEIGHT = 1.27  # env_bridge.js renders a sneaking player's view from here
SURFACE_Y = 5  # feet height on the server's superflat world
SPAWN_CENTRE_HALF_EXTENT = 8  # blocks around the origin: chunks there are loaded and meshed at start
CHUNK = 16
TRUTH_SOURCE = "projected hitbox of the other player at the position this player's client knows (no occlusion)"


def _spawn_spots(rng: np.random.Generator, n: int, dmin: float, dmax: float) -> list[tuple[int, int]]:
    """``n`` block columns around the origin, the first two U(dmin, dmax) apart (the voxel env's layout:
    evenly on a circle of that diameter)."""
    for _ in range(200):
        cx, cz = rng.uniform(-SPAWN_CENTRE_HALF_EXTENT, SPAWN_CENTRE_HALF_EXTENT, 2)
        ang, dist = rng.uniform(0, 2 * math.pi), rng.uniform(dmin, dmax)
        spots = [(math.floor(cx + dist / 2 * math.cos(ang + 2 * math.pi * k / n)),
                  math.floor(cz + dist / 2 * math.sin(ang + 2 * math.pi * k / n))) for k in range(n)]
        if len(set(spots)) == n:
            return spots
    raise RuntimeError(f"no distinct spawn columns for {n} players {dmin}-{dmax} apart")


def _facing(src: tuple[int, int], dst: tuple[int, int]) -> float:
    """Mineflayer yaw from block column ``src`` towards ``dst`` (yaw 0 = -Z, + = left)."""
    return math.atan2(-(dst[0] - src[0]), -(dst[1] - src[1]))


def block_event(cell: list) -> tuple[int, int, int, int | str]:
    """A bridge block event ``[x, y, z, minecraft name]`` -> the voxel env's ``(x, y, z, block id)``
    (``engine.blocks.Block``); a block the voxel engine does not have keeps its Minecraft name."""
    x, y, z, name = cell
    block = BY_NAME.get(name)
    return int(x), int(y), int(z), int(block) if block is not None else name


def screen_of(pose: dict, other_feet: list[float] | None, height: int, width: int) -> dict:
    """Where another player shows on a frame rendered from ``pose``: ``{"pixels", "u"}`` like the voxel env's
    ``screen`` entry, from its hitbox projected with the 16:9 camera (rectangle area; no occlusion)."""
    if other_feet is None:  # the client does not know the other player (yet)
        return {"pixels": 0, "u": None}
    eye = np.array([pose["x"], pose["y"] + (SNEAK_EYE_HEIGHT if pose["sneak"] else EYE_HEIGHT), pose["z"]])
    feet = np.asarray(other_feet, float)
    half = np.array([PLAYER_HALF_WIDTH, 0.0, PLAYER_HALF_WIDTH])
    rect = project_box(eye, pose["yaw"], pose["pitch"], feet - half, feet + half + [0.0, PLAYER_HEIGHT, 0.0],
                       FOV_DEG, DISPLAY_ASPECT)
    if rect is None:
        return {"pixels": 0, "u": None}
    u0, v0, u1, v1 = rect
    pixels = int(round((u1 - u0) * (v1 - v0) * height * width))
    return {"pixels": pixels, "u": (u0 + u1) / 2 if pixels > 0 else None}


class MinecraftParallelEnv(RealParallelEnv):
    """Real Minecraft (1.20.1) with every player an agent; also built by ``make_real_env(backend="minecraft")``.

    Needs the backend installed (``solaris-engine setup-minecraft``); the first ``reset`` starts Xvfb, a
    flying-squid server on 127.0.0.1 and the bridge (one bot and one rendered view per player), ~10-15 s
    including the chunk-meshing warm-up. ``close()`` stops them all (no orphan processes).

    Real time. The game runs on its own 20 Hz clock whether or not ``step`` is called. ``step`` applies the
    first tick's action as soon as it reaches the bridge, then each next tick's action right after the
    previous tick's frame, and returns once every player has a frame for each of its ``ticks_per_step``
    ticks; every frame is rendered right after its tick's physics, so frames and actions align by
    construction. Between steps (while the policy thinks) the players keep the last step's movement keys
    held, with no camera change and no once-keys, as a person holding keys would: these ticks are counted
    in ``infos[agent]["timing"]["idle_ticks"]``. A tick run late because the bridge process was busy (> 25 ms
    after its due time, then run back to back with the next: mineflayer's catch-up) is counted in
    ``catchup_ticks``; ticks skipped when more than 4 were due at once in ``dropped_ticks`` (the game ran
    slower than real time). ``timing["realtime"]`` is True when the step had none of the three. A policy
    that answers within a tick (50 ms, minus the step's own overhead) sees ``idle_ticks == 0``. A paused
    policy (a training update) leaves the players walking: step with no-ops before pausing, or reset after
    (a reset that brings a player back from > 24 blocks away waits ~3 s for its view to mesh again).

    Frames: each view is rendered as the 16:9 game window with a 70 degree vertical FOV at (H, 16/9 H) and
    resampled to (H, W), as the voxel env's frames and the recorder's; no HUD. Other players are drawn where
    the viewer's client last heard they were (relayed by the server: about a tick behind their own pose).

    Args: as :class:`RealParallelEnv`, with these differences:
        world: only ``"flat"``: the server's superflat world (the same world at every reset; ``reset(seed)``
            draws where the players spawn, ``spawn_distance`` apart near the origin, each facing the next).
        view_distance: blocks, rounded up to whole chunks (at least 2) for the server and the viewer.
        hud: must be False: prismarine-viewer draws no hotbar, crosshair or hand.
        server_seed: the flying-squid world seed.

    Actions: ``forward back left right jump sneak sprint`` are held (mineflayer control states),
    ``camera`` turns the view (pitch clamped to +-90 degrees; mineflayer quantises turns to 0.15 degree
    mouse steps, ``action_record["camera"]`` is what was applied), ``hotbar.k`` selects slot k,
    ``attack`` hits a player under the crosshair within 3 blocks: knockback, no damage (``server.js`` keeps
    health full, like the reference's resistance effect); else it digs the block under the crosshair within
    4.5 blocks, as the recorder does (mineflayer's dig: the time follows the block's hardness and the held
    tool, e.g. grass 18 ticks by hand, 3 with the shovel; bedrock never breaks; 5 ticks' pause after a
    break). The dig goes on while ``attack`` stays pressed on the same block and stops on a step without it
    (as the voxel engine: with ``ticks_per_step`` > 1 only the first tick presses it), on another target or a
    hotbar change; it runs on mineflayer's timer, so the clock never waits for it, and the idle ticks between
    steps do not stop it. ``use`` places the held block against the face under the crosshair (within 4.5
    blocks, at most every 4 ticks, never into a player). Every player starts each episode with the
    recorder's kit (``episodes.js`` ``COMMON_ITEMS``, given with ``/give``): 64 stone in slot 1, diamond
    pickaxe, shovel and axe in slots 2-4, slot 5 (an empty hand) selected; ``reset`` refills it and puts
    back every block dug or placed in the episode (``/setblock``). Not available (accepted, no effect):
    ``drop inventory ESC swapHands pickItem``.

    Infos (per agent), the voxel env's keys where the server knows them: ``pos`` (feet), ``yaw`` (radians,
    [0, 2pi)), ``pitch`` of the frame's state (the bot's own pose, which the server accepts), ``step``,
    ``screen`` / ``sees`` (every other player's ``{"pixels", "u"}`` from its hitbox projected with the
    camera at the position this player's client knows, i.e. as rendered; a rectangle's area, no occlusion:
    ``truth_source`` says so), after a step ``action_record`` (the last tick's Mineflayer record),
    ``placed`` / ``mined`` (the voxel env's ``(x, y, z, block id)`` tuples over the step's ticks, ids of
    ``engine.blocks.Block``, a block it lacks by its Minecraft name: ``placed`` when the server's block update
    for the clicked cell arrives, ``mined`` when the player's own dig finishes, which flying-squid always
    accepts; events that land between steps go to the next step), ``timing`` (``tick`` of the bridge clock,
    ``idle_ticks``, ``idle_catchup_ticks``, ``catchup_ticks``, ``dropped_ticks``, ``late_ms`` per tick,
    ``realtime``).

    Not available: ``engine_state()`` snapshots and ``reset(options={"engine_state": ...})`` (the server's
    state cannot be captured or restored: NotImplementedError), seeded reproducibility of trajectories
    (real time, network timing), worlds other than flat.
    """

    metadata: ClassVar[dict] = {**RealParallelEnv.metadata, "name": "solaris_real_minecraft_v0"}
    backend: ClassVar[str] = "minecraft"

    def __init__(self, num_players: int = 2, world: str = "flat", resolution: int | tuple[int, int] = 64,
                 max_steps: int = 1000, render_mode: str | None = None,
                 spawn_distance: tuple[float, float] = (6.0, 10.0), view_distance: float = 48.0,
                 hud: bool = False, task=None, ticks_per_step: int = 1, server_seed: int = 42):
        if world != "flat":
            raise ValueError(f"world: the minecraft backend has only the server's superflat world ('flat'), "
                             f"got {world!r}")
        if hud:
            raise ValueError("hud: the minecraft backend draws no HUD (prismarine-viewer has none); use hud=False")
        super().__init__(num_players=num_players, world=world, resolution=resolution, max_steps=max_steps,
                         render_mode=render_mode, spawn_distance=spawn_distance, view_distance=view_distance,
                         hud=False, task=task, ticks_per_step=ticks_per_step)
        problem = setup_problem()
        if problem:
            raise RuntimeError(f"the Minecraft backend is not set up: {problem}")
        self.server_seed = server_seed
        self.view_chunks = max(2, math.ceil(view_distance / CHUNK))
        self.bridge = None  # started by the first reset
        self._poses: list[dict] | None = None  # every player's pose of the current frame
        self._step_poses: list[list[dict]] = []  # every player's poses of the last step's ticks

    # -- reset / step -----------------------------------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """(Re)spawn the players (see the class docstring); starts the game on the first call."""
        seed = check_seed(seed)
        options = check_options(options, ("world", "engine_state"))
        if "engine_state" in options:
            raise NotImplementedError("reset(options={'engine_state': ...}) is not available on the minecraft "
                                      "backend: a real server's state cannot be restored; use backend='voxel'")
        if options.get("world", "flat") != "flat":
            raise ValueError(f"options['world']: the minecraft backend has only 'flat', got {options['world']!r}")
        self.np_random = episode_rng(self.np_random, seed)
        if self.bridge is None:
            from solaris_env.engine.minecraft.bridge import MinecraftBridge

            self.bridge = MinecraftBridge(self.possible_agents, render_size(self.height, self.width),
                                          view_distance=self.view_chunks, fov_deg=FOV_DEG, seed=self.server_seed)
        spots = _spawn_spots(self.np_random, max(2, self.num_players), *self.spawn_distance)[: self.num_players]
        n = len(spots)
        reply = self.bridge.reset([{"x": x, "y": SURFACE_Y, "z": z, "yaw": _facing((x, z), spots[(k + 1) % n]) if n > 1
                                    else float(self.np_random.uniform(0, 2 * math.pi)), "pitch": 0.0}
                                   for k, (x, z) in enumerate(spots)])
        self.agents = list(self.possible_agents)
        self._camera_pending_P2 = np.zeros((self.num_players, 2))
        self._steps = 0
        self._frames = self._resample(reply.rgba_PTHW4)[:, -1]
        self._step_frames = self._frames[:, None]
        self._poses = [poses[-1] for poses in reply.poses_PT]
        infos = [self._info(i) for i in range(self.num_players)]
        self.task.reset(self._frames, truth=infos)
        return self._observations(), dict(zip(self.possible_agents, infos))

    def step(self, actions: dict[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        if self.bridge is None or self._poses is None or not self.agents:
            raise RuntimeError("step() called before reset() or after the episode ended; call reset()")
        per_player, ticks_P = self._tick_actions(actions)  # P env actions, P lists of k ticks (carried camera turns)
        from solaris_env.engine.minecraft.bridge import tick_message

        reply = self.bridge.step([[tick_message(ticks[t], minerl_camera_to_mineflayer(ticks[t]["camera"]))
                                   for ticks in ticks_P] for t in range(self.ticks_per_step)])
        self._steps += 1
        self._step_frames = self._resample(reply.rgba_PTHW4)  # (P, k, H, W, 3)
        self._frames = self._step_frames[:, -1]
        last_tick = [ticks[-1] for ticks in ticks_P]
        self._poses = [poses[-1] for poses in reply.poses_PT]
        self._step_poses = reply.poses_PT
        infos = [self._info(i, reply.header, last_tick[i]) for i in range(self.num_players)]
        outcome = self.task.step(self._step_frames, per_player, truth=infos)
        return self._step_outputs(outcome.rewards_P, outcome.terminations_P, self._steps >= self.max_steps, infos)

    def engine_state(self):
        raise NotImplementedError("engine_state() is not available on the minecraft backend: a real server's "
                                  "state cannot be snapshotted; use backend='voxel' for EngineState snapshots")

    def close(self) -> None:
        """Stop the bridge, the server and Xvfb (no orphan processes); reset() would start them again."""
        if self.bridge is not None:
            self.bridge.close()
            self.bridge = None
        self._poses = None
        self.agents = []
        super().close()

    # -- internals --------------------------------------------------------------------------------
    def _resample(self, rgba_PTHW4: np.ndarray) -> np.ndarray:
        """(P, T, rh, rw, 4) bottom-up RGBA of the 16:9 window -> (P, T, H, W, 3) uint8 RGB at the env's size."""
        rh, rw = rgba_PTHW4.shape[2:4]
        return np.stack([frames_from_rgba(f, rh, rw, self.height, self.width) for f in rgba_PTHW4])

    def _info(self, i: int, header: dict | None = None, last_action: dict | None = None) -> dict:
        """Player i's info for the current frame; ``header``/``last_action``: the step's reply and the action
        of its last tick (None at reset)."""
        pose = self._poses[i]
        screen = {name: screen_of(pose, pose["others"].get(name), self.height, self.width)
                  for name in self.possible_agents if name != self.possible_agents[i]}
        info = {"pos": np.array([pose["x"], pose["y"], pose["z"]]), "yaw": float(pose["yaw"]) % (2 * math.pi),
                "pitch": float(pose["pitch"]), "step": self._steps,
                "sees": {name: s["pixels"] > 0 for name, s in screen.items()}, "screen": screen,
                "truth_source": TRUTH_SOURCE, "camera_pending": self._camera_pending_P2[i].astype(np.float32)}
        if header is not None:
            info["action_record"] = self._action_record(pose, last_action)
            info["placed"] = [block_event(c) for pose in self._step_poses[i] for c in pose["placed"]]
            info["mined"] = [block_event(c) for pose in self._step_poses[i] for c in pose["mined"]]
            info["timing"] = {"tick": header["tick"], "idle_ticks": header["idleTicks"],
                              "idle_catchup_ticks": header["idleCatchup"], "catchup_ticks": header["catchup"],
                              "dropped_ticks": header["dropped"] + header["idleDropped"],
                              "late_ms": header["lateMs"],
                              "realtime": header["idleTicks"] == 0 and header["catchup"] == 0
                              and header["dropped"] == 0 and header["idleDropped"] == 0}
        return info

    @staticmethod
    def _action_record(pose: dict, action: dict) -> dict:
        """The 24-key Mineflayer record of a step's last tick (what was applied: held keys, camera, hits,
        placements, digging)."""
        dyaw, dpitch = pose["camera"]
        pressed = [k for k in range(1, 10) if action[f"hotbar.{k}"]]
        row = {"t": 0, "yaw": 0.0, "pitch": 0.0, "yaw_next": dyaw, "pitch_next": dpitch,
               "controls": {k: bool(action[k]) for k in CONTROL_KEYS},
               "events": {"attack": int(pose["hit"]), "place_block": int(bool(pose["placed"])),
                          "mine": bool(pose["mine"]), "hotbar": pressed[0] if pressed else None}}
        return action_record(row)
