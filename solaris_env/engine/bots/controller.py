"""Scripted bot controllers: per-tick policies written as generators of env actions.

A choreography is a generator function ``behaviour(bot)`` that ``yield``s one env action per tick (or
a :class:`Barrier`). Primitives (look, walk, go to, place, dig, sneak signal) are generators too and
compose with ``yield from``; those that can fail *return* a bool. This mirrors the reference
engine's async Mineflayer episode handlers one-to-one while staying a pure per-tick policy: the bot
reads the game state (privileged, like a Mineflayer bot) but acts only through the action space.

Shared randomness (engine-spec §5.1): every bot holds its own copy of ``shared_rng`` seeded
identically, so decisions both bots must agree on are drawn in the same order on both; ``rng`` is
the bot's private randomness (``Math.random()`` in the reference).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Generator

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.blocks import Block, Item
from solaris_env.engine.game import Game
from solaris_env.engine.physics import Player, look_vector, pitch_to, wrap_angle, yaw_to
from solaris_env.spaces import mineflayer_to_minerl_camera, noop


class EpisodeAbort(Exception):
    """Raised by a choreography when it cannot go on (the reference's thrown episode errors)."""


@dataclass
class Barrier:
    """Yielded by a bot to wait until every bot reached the barrier of the same name.

    ``payload`` is shared: after release, ``bot.peer_payloads[name]`` maps bot names to payloads.
    """

    name: str
    payload: dict = field(default_factory=dict)


Actions = Generator[dict | Barrier, None, bool | None]
MOVE_KEYS = ("forward", "back", "left", "right")
REVERSE = {"forward": "back", "back": "forward", "left": "right", "right": "left"}


def act(camera_mf: tuple[float, float] = (0.0, 0.0), **keys: int) -> dict:
    """An env action from held keys (``hotbar_3=1`` for ``hotbar.3``) and a Mineflayer-convention
    camera delta (dyaw, dpitch) in radians."""
    a = noop()
    for k, v in keys.items():
        a[k.replace("hotbar_", "hotbar.")] = int(v)
    if camera_mf != (0.0, 0.0):
        a["camera"] = mineflayer_to_minerl_camera(*camera_mf)
    return a


def lognormal_speed(rng: np.random.Generator, dps: float, volatility: float = 0.35) -> float:
    """The reference's randomized look speed: dps x LogNormal(mean 1), clipped to [0.4 dps, 171]."""
    f = float(rng.lognormal(-volatility**2 / 2, volatility))
    return float(np.clip(dps * f, 0.4 * dps, 171.0))


def rotation_profile(total_deg: float, speed_dps: float, easing: bool) -> list[float]:
    """Per-tick angle steps (degrees) that sum exactly to ``total_deg`` (quantised to 0.15 deg).

    Constant rate: ``speed/20`` per tick, the last step partial (Mineflayer's physics loop). Easing:
    trapezoid velocity (ramp 20 % / flat 60 % / ramp 20 %) over ``ceil(|total| / (0.8 speed) * 20)`` ticks.
    """
    q = round(total_deg / C.LOOK_STEP_DEG) * C.LOOK_STEP_DEG
    if q == 0.0 or speed_dps <= 0.0:
        return []
    if not easing:
        step = speed_dps / C.TICKS_PER_SECOND
        n = math.ceil(abs(q) / step - 1e-9)
        steps = [math.copysign(step, q)] * (n - 1)
        return steps + [q - sum(steps)]
    n = max(1, math.ceil(abs(q) / (speed_dps * 0.8) * C.TICKS_PER_SECOND))
    u = (np.arange(n) + 0.5) / n
    v = np.minimum(1.0, np.minimum(u / 0.2, (1 - u) / 0.2))  # trapezoid velocity
    steps = v / v.sum() * q
    return [float(s) for s in steps]


class Bot:
    """One scripted player. Created by the episode runner, one per player.

    Args:
        game: the running game (read-only for the bot; it acts through yielded actions).
        index: this bot's player index.
        shared_rng: identically seeded generator held by every bot (agree on decisions).
        rng: this bot's private generator.
    """

    def __init__(self, game: Game, index: int, shared_rng: np.random.Generator, rng: np.random.Generator):
        self.game = game
        self.index = index
        self.shared_rng = shared_rng
        self.rng = rng
        self.peer_payloads: dict[str, dict[str, dict]] = {}
        self.eval_metadata: dict = {}
        self.start_tick: int | None = None  # eval: tick after the sneak signal
        self.episode = 0  # the episode number N (set by the runner; eval cases depend on it)

    # -- state -----------------------------------------------------------------------------------
    @property
    def me(self) -> Player:
        return self.game.players[self.index]

    @property
    def name(self) -> str:
        return self.me.name

    @property
    def others(self) -> list[Player]:
        return [p for i, p in enumerate(self.game.players) if i != self.index]

    @property
    def other(self) -> Player:
        """The partner (the first other player; episodes are written for two players)."""
        return self.others[0]

    @property
    def is_lower(self) -> bool:
        """Whether this bot's name sorts first (the reference's asymmetric-role rule)."""
        return self.name < self.other.name

    @property
    def tick(self) -> int:
        return self.game.tick

    def decide_primary(self) -> bool:
        """The reference ``decidePrimaryBot``: sorted names, ``sorted[floor(rng*2)]`` is primary."""
        names = sorted(p.name for p in self.game.players)
        return names[int(self.shared_rng.random() * len(names))] == self.name

    def slot_of(self, item: int) -> int | None:
        for s, (it, n) in enumerate(self.me.hotbar):
            if it == item and (n > 0 or item >= 256):
                return s
        return None

    # -- primitives ------------------------------------------------------------------------------
    def idle(self, ticks: int) -> Actions:
        for _ in range(max(0, int(ticks))):
            yield act()

    def hold(self, ticks: int, **keys: int) -> Actions:
        for _ in range(max(0, int(ticks))):
            yield act(**keys)

    def sleep(self, seconds: float) -> Actions:
        yield from self.idle(round(seconds * C.TICKS_PER_SECOND))

    def barrier(self, name: str, **payload) -> Actions:
        yield Barrier(name, payload)

    def look(self, yaw: float, pitch: float, speed_dps: float = C.DEFAULT_LOOK_SPEED_DEG, easing: bool = False,
             randomized: bool = False, **keys: int) -> Actions:
        """Turn to (yaw, pitch) along the shortest arc at ``speed_dps``, holding ``keys`` meanwhile."""
        if randomized:
            speed_dps = lognormal_speed(self.rng, speed_dps)
        pitch = float(np.clip(pitch, -C.PITCH_LIMIT, C.PITCH_LIMIT))
        dyaw = math.degrees(wrap_angle(yaw - self.me.yaw))
        dpitch = math.degrees(pitch - self.me.pitch)
        ys = rotation_profile(dyaw, speed_dps, easing)
        ps = rotation_profile(dpitch, speed_dps, easing)
        for t in range(max(len(ys), len(ps))):
            dy = math.radians(ys[t]) if t < len(ys) else 0.0
            dp = math.radians(ps[t]) if t < len(ps) else 0.0
            yield act((dy, dp), **keys)

    def turn(self, dyaw: float, speed_dps: float = C.DEFAULT_LOOK_SPEED_DEG, **kw) -> Actions:
        """Turn by ``dyaw`` radians (Mineflayer sign: + = left), keeping the pitch; any size, not only the shortest arc."""
        ys = rotation_profile(math.degrees(dyaw), speed_dps, kw.pop("easing", False))
        for s in ys:
            yield act((math.radians(s), 0.0), **kw)

    def look_at(self, point: np.ndarray, speed_dps: float = C.DEFAULT_LOOK_SPEED_DEG, **kw) -> Actions:
        """Aim the eye at a point (Mineflayer ``bot.lookAt``)."""
        eye = self.me.eye
        yield from self.look(yaw_to(eye, point), pitch_to(eye, point), speed_dps, **kw)

    def look_at_smooth(self, player: Player, speed_dps: float = 60.0, easing: bool = True, randomized: bool = True,
                       **keys: int) -> Actions:
        """The reference ``lookAtSmooth``: aims feet to feet (pitch ~ 0 on flat ground), eased and randomized."""
        yaw = yaw_to(self.me.pos, player.pos)
        pitch = pitch_to(self.me.pos, player.pos)
        yield from self.look(yaw, pitch, speed_dps, easing=easing, randomized=randomized, **keys)

    def look_at_player(self, player: Player, speed_dps: float = C.DEFAULT_LOOK_SPEED_DEG, **kw) -> Actions:
        """Eye contact: aim at the other player's head (``lookAtBot``)."""
        yield from self.look_at(player.eye, speed_dps, **kw)

    def select(self, item: int) -> Actions:
        """Press the hotbar key of the slot holding ``item`` (one tick); raises EpisodeAbort if absent."""
        slot = self.slot_of(item)
        if slot is None:
            raise EpisodeAbort(f"{self.name} has no {item} in the hotbar")
        if slot != self.me.selected_slot:
            yield act(**{f"hotbar_{slot + 1}": 1})

    def walk(self, key: str, distance: float, timeout_s: float = 5.0, jump_prob: float = 0.0, **extra) -> Actions:
        """Hold a WASD key until displaced by ``distance`` blocks or timeout; maybe jump meanwhile."""
        start = self.me.pos.copy()
        jumping = self.rng.random() < jump_prob
        for t in range(round(timeout_s * C.TICKS_PER_SECOND)):
            if np.hypot(*(self.me.pos - start)[[0, 2]]) >= distance:
                return True
            jump = int(jumping and (t // 5) % 2 == 0)  # toggled 250 ms on / off
            yield act(**{key: 1}, jump=jump, **extra)
        return False

    def walk_back(self, key: str, origin: np.ndarray, tolerance: float = 1.0, timeout_s: float = 5.0,
                  jump_prob: float = 0.0) -> Actions:
        """Hold ``key`` until within ``tolerance`` blocks of ``origin`` (horizontally) or timeout."""
        jumping = self.rng.random() < jump_prob
        for t in range(round(timeout_s * C.TICKS_PER_SECOND)):
            if np.hypot(*(self.me.pos - origin)[[0, 2]]) <= tolerance:
                return True
            yield act(**{key: 1}, jump=int(jumping and (t // 5) % 2 == 0))
        return False

    def goto(self, goal: np.ndarray, radius: float = 1.0, timeout_s: float = 10.0, sprint: bool = False) -> Actions:
        """Walk toward ``goal`` (x, z used; y ignored) until within ``radius``: steer at 3 rad/s, jump
        over one-block steps, give up after ``timeout_s``. Returns whether the goal was reached."""
        max_turn = math.radians(C.DEFAULT_LOOK_SPEED_DEG) / C.TICKS_PER_SECOND
        stuck = 0
        for _ in range(round(timeout_s * C.TICKS_PER_SECOND)):
            p = self.me
            d = goal - p.pos
            dist = math.hypot(d[0], d[2])
            if dist <= radius:
                return True
            err = wrap_angle(yaw_to(p.pos, goal) - p.yaw)
            dyaw = float(np.clip(err, -max_turn, max_turn))
            dpitch = float(np.clip(-p.pitch, -max_turn, max_turn))
            q = math.radians(C.LOOK_STEP_DEG)
            dyaw, dpitch = round(dyaw / q) * q, round(dpitch / q) * q
            fwd = abs(err) < math.radians(45)
            jump = fwd and p.on_ground and self._blocked_ahead()
            moving = math.hypot(p.vel[0], p.vel[2]) > 0.02
            stuck = 0 if moving else stuck + 1
            if stuck > 10 and p.on_ground:
                jump = True
            yield act((dyaw, dpitch), forward=int(fwd), jump=int(jump), sprint=int(sprint and fwd and dist > 3))
        return False

    def _blocked_ahead(self) -> bool:
        p = self.me
        fwd = look_vector(p.yaw, 0.0)
        ahead = p.pos + fwd * 0.8
        x, y, z = math.floor(ahead[0]), math.floor(p.pos[1] + 0.01), math.floor(ahead[2])
        return self.game.world.is_solid(x, y, z) and not self.game.world.is_solid(x, y + 1, z) \
            and not self.game.world.is_solid(x, y + 2, z)

    def place_at(self, cell: tuple[int, int, int], block: int, attempts: int = 3, sneak: bool = False) -> Actions:
        """Place ``block`` at ``cell`` against a solid neighbour (below first); True when it stands there."""
        world = self.game.world
        for _ in range(attempts):
            if world.get(*cell) == block:
                return True
            yield from self.select(block)
            face = self._support_face(cell)
            if face is None:
                return False
            support, normal = face
            aim = np.array(cell, float) + 0.5 - 0.5 * np.array(normal, float)
            if np.linalg.norm(aim - self.me.eye) > C.REACH - 0.3:
                yield from self.goto(aim, radius=2.5, timeout_s=5.0)
            yield from self.look_at(aim, sneak=int(sneak))
            yield act(use=1, sneak=int(sneak))
            if world.get(*cell) == block:
                return True
        return world.get(*cell) == block

    def _support_face(self, cell: tuple[int, int, int]) -> tuple[tuple[int, int, int], tuple[int, int, int]] | None:
        x, y, z = cell
        for n in ((0, 1, 0), (1, 0, 0), (-1, 0, 0), (0, 0, 1), (0, 0, -1), (0, -1, 0)):
            support = (x - n[0], y - n[1], z - n[2])
            if self.game.world.is_solid(*support):
                return support, n
        return None

    def dig(self, cell: tuple[int, int, int], timeout_s: float = 5.0) -> Actions:
        """Look at a block and hold attack until it is gone. True on success."""
        world = self.game.world
        center = np.array(cell, float) + 0.5
        if np.linalg.norm(center - self.me.eye) > C.REACH - 0.3:
            yield from self.goto(center, radius=2.5, timeout_s=5.0)
        if self.slot_of(Item.DIAMOND_PICKAXE) is not None:
            yield from self.select(Item.DIAMOND_PICKAXE)
        yield from self.look_at(center)
        for _ in range(round(timeout_s * C.TICKS_PER_SECOND)):
            if world.get(*cell) in (Block.AIR, Block.WATER):
                return True
            yield act(attack=1)
        return world.get(*cell) in (Block.AIR, Block.WATER)

    def sneak_signal(self) -> Actions:
        """The eval signal (engine-spec §6): sneak 5 ticks, release, idle 25 ticks; sets ``start_tick``."""
        yield from self.hold(5, sneak=1)
        yield from self.idle(25)
        self.start_tick = self.tick

    def pad_to(self, ticks_since_start: int) -> Actions:
        """Idle until ``ticks_since_start`` ticks have passed since ``start_tick`` (eval padding)."""
        if self.start_tick is None:
            raise EpisodeAbort("pad_to before the sneak signal")
        yield from self.idle(self.start_tick + ticks_since_start - self.tick)
