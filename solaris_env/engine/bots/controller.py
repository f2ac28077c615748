"""Scripted bot controllers: per-tick policies written as generators of env actions.

A choreography is a generator function ``behaviour(bot)`` that ``yield``s one env action per tick (or
a :class:`Barrier`). Primitives (look, walk, go to, place, dig, sneak signal) are generators too and
compose with ``yield from``; those that can fail *return* a bool. This mirrors the reference
engine's async Mineflayer episode handlers one-to-one while staying a pure per-tick policy: the bot
reads the game state (privileged, like a Mineflayer bot) but acts only through the action space.

Shared randomness (docs/engine.md §5.1): every bot holds its own copy of ``shared_rng`` seeded
identically, so decisions both bots must agree on are drawn in the same order on both; ``rng`` is
the bot's private randomness (``Math.random()`` in the reference).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field
from typing import Callable, Generator

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.blocks import Block, Item
from solaris_env.engine.game import Game, raycast_block
from solaris_env.engine.physics import Player, horizontal_axes, look_vector, pitch_to, wrap_angle, yaw_to
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

MAX_SCAFFOLD_PILLARS = 4  # goto(scaffold=...): at most this many one-block pillars per call
MAX_CLIMB = 3  # goto(scaffold=...) climbs steps up to this high
STUCK_TICKS = 10  # goto: ticks without horizontal motion before it jumps (or digs, with ``dig=True``)
FACE_INSET = 0.3  # aim points on a block face sit this far from its centre towards the edges
REACH_MARGIN = 0.3  # aim only at points this much closer than the reach
PILLAR_PITCH = -C.PITCH_LIMIT  # place_below looks straight down by default
BRIDGE_STUCK_TICKS = 40  # bridge gives up after this long without moving
BRIDGE_PITCH = -math.radians(80.0)  # bridging: the crosshair meets the support's side face at the edge
NUDGE_TOLERANCE = 0.15  # blocks: nudge_to stops this close to its point
STEP_OUT_DIST = 1.0  # blocks: place_at steps this far from a cell (or player) its body is in
STEP_OUT_TOLERANCE = 0.2  # blocks: ... to within this
STEP_OUT_S = 1.5  # ... trying for at most this long
NUDGE_STUCK_TICKS = 3  # nudge_to (not sneaking) jumps after this many ticks without moving
MOVING_SPEED = 0.02  # blocks/tick: slower than this counts as standing still
MAX_TURN_RAD = math.radians(C.DEFAULT_LOOK_SPEED_DEG) / C.TICKS_PER_SECOND  # 0.15 rad: the per-tick camera cap
FOLLOW_TURN_RAD = math.radians(90.0) / C.TICKS_PER_SECOND  # follow: keep the target in view at 90 deg/s
FIGHT_CLOSE = 2.0  # blocks: fight stops walking forward this close to its target
FIGHT_RANGE = 3.0  # blocks from the eye: mineflayer-pvp's attackRange
BODY_AIM_HEIGHT = 1.2  # fight aims this high above the target's feet (upper body)
# Neighbour directions (from the support block to the placed cell), the block below first.
FACE_NORMALS = ((0, 1, 0), (1, 0, 0), (-1, 0, 0), (0, 0, 1), (0, 0, -1), (0, -1, 0))
_MAILBOXES: "weakref.WeakKeyDictionary[Game, dict]" = weakref.WeakKeyDictionary()


def _jump_apex() -> float:
    """Height (blocks) a standing jump rises, from the physics constants."""
    v, h = C.JUMP_VELOCITY, 0.0
    while v > 0:
        h += v
        v = (v - C.GRAVITY) * C.VERTICAL_DRAG
    return h


JUMP_APEX = _jump_apex()  # ~1.25 blocks
JUMP_AIR_TICKS = 12  # a jump lands after about this many ticks


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


def _face_points(cell: tuple[int, int, int], normal: tuple[int, int, int]) -> list[np.ndarray]:
    """Aim points on the face of ``cell`` that looks against ``normal`` (the face shared with the support):
    the face centre first, then points ``FACE_INSET`` towards its edges and corners."""
    axis = next(a for a in range(3) if normal[a] != 0)
    t1, t2 = [a for a in range(3) if a != axis]
    centre = np.array(cell, float) + 0.5 - 0.5 * np.array(normal, float)
    points = []
    for a, b in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)):
        q = centre.copy()
        q[t1] += a * FACE_INSET
        q[t2] += b * FACE_INSET
        points.append(q)
    return points


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

    def goto(self, goal: np.ndarray, radius: float = 1.0, timeout_s: float = 10.0, sprint: bool = False,
             dig: bool = False, scaffold: int | None = None) -> Actions:
        """Walk toward ``goal`` (x, z used; y ignored) until within ``radius``: steer at 3 rad/s, jump
        over one-block steps, swim up in water, give up after ``timeout_s``. With ``dig``, a wall it
        keeps running into is dug through (the pathfinder's ``canDig``); with a ``scaffold`` block, a
        two-block step is climbed by pillaring up one block first (``canPlace``). Returns whether the
        goal was reached."""
        deadline = self.tick + round(timeout_s * C.TICKS_PER_SECOND)
        stuck = pillars = 0
        while self.tick < deadline:
            p = self.me
            dist = math.hypot(goal[0] - p.pos[0], goal[2] - p.pos[2])
            if dist <= radius:
                return True
            stuck = 0 if math.hypot(p.vel[0], p.vel[2]) > MOVING_SPEED else stuck + 1
            facing = abs(wrap_angle(yaw_to(p.pos, goal) - p.yaw)) < math.radians(45)
            blocked = facing and p.on_ground and stuck > STUCK_TICKS
            if blocked and scaffold is not None and pillars < MAX_SCAFFOLD_PILLARS and self._high_step_ahead():
                stuck, pillars = 0, pillars + 1
                x, y, z = math.floor(p.pos[0]), math.floor(p.pos[1] + 0.01), math.floor(p.pos[2])
                if self.game.world.is_solid(x, y + 2, z):  # e.g. leaves overhead: dig for head room
                    yield from self.dig((x, y + 2, z))
                yield from self.place_below(scaffold)
                continue
            if blocked and dig and self._wall_ahead():
                stuck = 0
                yield from self._dig_ahead()
                continue
            yield self._steer(goal, dist, sprint, stuck > STUCK_TICKS)
        return False

    def _high_step_ahead(self) -> bool:
        """A step of 2 to ``MAX_CLIMB`` blocks in front (too high to jump, room to stand on top of it)."""
        world = self.game.world
        (hx, hy, hz), (fx, fy, fz) = self._cells_ahead()
        if not (world.is_solid(fx, fy, fz) and world.is_solid(hx, hy, hz)):
            return False
        return any(not world.is_solid(fx, fy + k, fz) and not world.is_solid(fx, fy + k + 1, fz)
                   for k in range(2, MAX_CLIMB + 1))

    def _steer(self, goal: np.ndarray, dist: float, sprint: bool, force_jump: bool) -> dict:
        """One tick of walking toward ``goal``: turn (<= 0.15 rad), forward when roughly facing it, jump steps."""
        p = self.me
        target_yaw = yaw_to(p.pos, goal)
        fwd = abs(wrap_angle(target_yaw - p.yaw)) < math.radians(45)
        jump = (fwd and p.on_ground and self._blocked_ahead()) or (force_jump and p.on_ground) or p.in_water
        return act(self.turn_step(target_yaw, 0.0), forward=int(fwd), jump=int(jump),
                   sprint=int(sprint and fwd and dist > 3))

    def turn_step(self, yaw: float, pitch: float, max_step: float = MAX_TURN_RAD) -> tuple[float, float]:
        """One tick's camera delta (dyaw, dpitch) toward (yaw, pitch): at most ``max_step`` rad per axis,
        on the 0.15 deg mouse grid."""
        q = math.radians(C.LOOK_STEP_DEG)
        n_max = math.floor(max_step / q + 1e-9)
        pitch = float(np.clip(pitch, -C.PITCH_LIMIT, C.PITCH_LIMIT))
        n_yaw = int(np.clip(round(wrap_angle(yaw - self.me.yaw) / q), -n_max, n_max))
        n_pitch = int(np.clip(round((pitch - self.me.pitch) / q), -n_max, n_max))
        return n_yaw * q, n_pitch * q

    def _blocked_ahead(self) -> bool:
        p = self.me
        fwd = look_vector(p.yaw, 0.0)
        ahead = p.pos + fwd * 0.8
        x, y, z = math.floor(ahead[0]), math.floor(p.pos[1] + 0.01), math.floor(ahead[2])
        return self.game.world.is_solid(x, y, z) and not self.game.world.is_solid(x, y + 1, z) \
            and not self.game.world.is_solid(x, y + 2, z)

    def _cells_ahead(self) -> list[tuple[int, int, int]]:
        """The head and feet cells just in front of the player (the ones a 1x2 tunnel clears)."""
        p = self.me
        ahead = p.pos + look_vector(p.yaw, 0.0) * 0.8
        x, y, z = math.floor(ahead[0]), math.floor(p.pos[1] + 0.01), math.floor(ahead[2])
        return [(x, y + 1, z), (x, y, z)]

    def _wall_ahead(self) -> bool:
        return any(self.game.world.is_solid(*c) for c in self._cells_ahead())

    def _dig_ahead(self) -> Actions:
        for cell in self._cells_ahead():
            if self.game.world.is_solid(*cell):
                yield from self.dig(cell)

    def follow(self, player: Player, radius: float, ticks: int, sprint: bool = False, refresh_ticks: int = 1,
               until: Callable[[], bool] | None = None, dig: bool = False) -> Actions:
        """Follow a moving player (``GoalFollow``) for ``ticks`` ticks: re-aim at its position every
        ``refresh_ticks``; inside ``radius`` stand and keep it in view. Returns True if ``until()`` ended it."""
        goal, stuck = player.pos.copy(), 0
        for t in range(max(0, int(ticks))):
            if until is not None and until():
                return True
            if t % refresh_ticks == 0:
                goal = player.pos.copy()
            p = self.me
            dist = math.hypot(goal[0] - p.pos[0], goal[2] - p.pos[2])
            if dist <= radius:
                yield act(self.turn_step(yaw_to(p.eye, player.eye), pitch_to(p.eye, player.eye), FOLLOW_TURN_RAD))
                continue
            stuck = 0 if math.hypot(p.vel[0], p.vel[2]) > MOVING_SPEED else stuck + 1
            if dig and p.on_ground and stuck > STUCK_TICKS and self._wall_ahead():
                stuck = 0
                yield from self._dig_ahead()
                continue
            yield self._steer(goal, dist, sprint, stuck > STUCK_TICKS)
        return False

    def track(self, player: Player, ticks: int, speed_dps: float = C.DEFAULT_LOOK_SPEED_DEG,
              until: Callable[[], bool] | None = None, **keys: int) -> Actions:
        """Keep the crosshair on ``player``'s head for ``ticks`` ticks (or until ``until()``), turning at
        most ``speed_dps``."""
        step = min(MAX_TURN_RAD, math.radians(speed_dps) / C.TICKS_PER_SECOND)
        for _ in range(max(0, int(ticks))):
            if until is not None and until():
                return True
            eye = self.me.eye
            yield act(self.turn_step(yaw_to(eye, player.eye), pitch_to(eye, player.eye), step), **keys)
        return False

    def nudge_to(self, point: np.ndarray, tolerance: float = NUDGE_TOLERANCE, timeout_s: float = 2.0,
                 sneak: bool = True) -> Actions:
        """Step to ``point`` (x, z) with WASD and no camera motion (sneaking by default: slow, never off an
        edge; without sneaking it jumps up a step it is stuck against)."""
        stuck = 0
        for _ in range(round(timeout_s * C.TICKS_PER_SECOND)):
            p = self.me
            d = np.asarray(point, float) - p.pos
            d[1] = 0.0
            if math.hypot(d[0], d[2]) <= tolerance:
                return True
            stuck = 0 if math.hypot(p.vel[0], p.vel[2]) > MOVING_SPEED else stuck + 1
            fwd, left = horizontal_axes(p.yaw)
            f, s = float(d @ fwd), float(d @ left)
            half = tolerance / 2
            keys = {"forward": int(f > half), "back": int(f < -half), "left": int(s > half), "right": int(s < -half)}
            jump = not sneak and p.on_ground and stuck > NUDGE_STUCK_TICKS
            yield act(sneak=int(sneak), jump=int(jump), **keys)
        return False

    # -- building and digging --------------------------------------------------------------------
    def place_at(self, cell: tuple[int, int, int], block: int, attempts: int = 3, sneak: bool = False,
                 approach: bool = True, scaffold: int | None = None) -> Actions:
        """Place ``block`` at ``cell`` against a solid neighbour's face; True when it stands there.

        Aims at a point of a neighbour's face that the crosshair reaches unobstructed (the block below
        first). With ``approach`` it first walks within reach and steps out of the cell. If no face is
        visible from where it stands, it tries once more at the apex of a jump. ``scaffold`` lets the
        approach climb two-block steps (see :meth:`goto`).
        """
        world = self.game.world
        for _ in range(attempts):
            if world.get(*cell) == block:
                return True
            if self._support_face(cell) is None:
                return False
            yield from self.select(block)
            if approach:
                yield from self._approach(cell, scaffold)
            face = self._visible_face(cell, self._eye(sneak))
            if face is None:
                yield from self._jump_place(cell, sneak)
                continue
            support, normal, point = face
            yield from self.look_at(point, sneak=int(sneak))
            while self.me.use_cooldown > 1:
                yield act(sneak=int(sneak))
            if self._aims_at(support, normal):
                yield act(use=1, sneak=int(sneak))
        return world.get(*cell) == block

    def place_below(self, block: int, pitch: float = PILLAR_PITCH, timeout_s: float = 2.0) -> Actions:
        """Pillar up one block: jump and place ``block`` in the cell the feet just left (the jump-place)."""
        world = self.game.world
        p = self.me
        x, y, z = math.floor(p.pos[0]), math.floor(p.pos[1] + 0.01), math.floor(p.pos[2])
        support = (x, y - 1, z)
        if not world.is_solid(*support) or world.is_solid(x, y + 2, z) or world.is_solid(x, y, z):
            return False
        yield from self.select(block)
        yield from self.look(p.yaw, pitch)
        for _ in range(round(timeout_s * C.TICKS_PER_SECOND)):
            if world.get(x, y, z) == block:
                break
            clear = self.me.pos[1] > y + 1 + 1e-6  # the feet left the cell
            yield act(jump=int(self.me.on_ground), use=int(clear and self._aims_at(support, (0, 1, 0))))
        for _ in range(JUMP_AIR_TICKS):
            if self.me.on_ground:
                break
            yield act()
        return world.get(x, y, z) == block

    def _eye(self, sneak: bool) -> np.ndarray:
        return self.me.pos + np.array([0.0, C.SNEAK_EYE_HEIGHT if sneak else C.EYE_HEIGHT, 0.0])

    def _aims_at(self, block: tuple[int, int, int], normal: tuple[int, int, int] | None = None) -> bool:
        """Whether the crosshair targets ``block`` (on the face with ``normal``, if given)."""
        hit = self.game.target(self.index)
        if hit is None or hit.block != tuple(block):
            return False
        return normal is None or hit.normal == tuple(normal)

    def _approach(self, cell: tuple[int, int, int], scaffold: int | None = None) -> Actions:
        """Walk within reach of ``cell`` and out of it (a block cannot be placed inside its placer)."""
        center = np.array(cell, float) + 0.5
        if np.linalg.norm(center - self.me.eye) > C.REACH - REACH_MARGIN - 0.5:
            yield from self.goto(center, radius=2.5, timeout_s=5.0, scaffold=scaffold)
        if self._overlaps(cell):
            yield from self._step_away(center)
        crowding = [q for q in self.others if math.hypot(*(q.pos - self.me.pos)[[0, 2]]) < C.PLAYER_WIDTH]
        if crowding:  # the crosshair would start inside the other player's body
            yield from self._step_away(crowding[0].pos)

    def _step_away(self, point: np.ndarray) -> Actions:
        """Step ``STEP_OUT_DIST`` blocks horizontally away from ``point`` (jumping a step if needed)."""
        away = self.me.pos - point
        away[1] = 0.0
        n = float(np.linalg.norm(away))
        away = away / n if n > 1e-3 else look_vector(self.me.yaw + math.pi, 0.0)
        yield from self.nudge_to(np.asarray(point, float) + away * STEP_OUT_DIST, tolerance=STEP_OUT_TOLERANCE,
                                 timeout_s=STEP_OUT_S, sneak=False)

    def _overlaps(self, cell: tuple[int, int, int]) -> bool:
        lo, hi = self.me.aabb()
        c = np.array(cell, float)
        return bool(np.all(lo < c + 1) and np.all(hi > c))

    def _support_face(self, cell: tuple[int, int, int]) -> tuple[tuple[int, int, int], tuple[int, int, int]] | None:
        x, y, z = cell
        for n in FACE_NORMALS:
            support = (x - n[0], y - n[1], z - n[2])
            if self.game.world.is_solid(*support):
                return support, n
        return None

    def _visible_face(self, cell: tuple[int, int, int], eye: np.ndarray):
        """(support, normal, aim point) of the first neighbour face the crosshair can reach from ``eye``, or None."""
        x, y, z = cell
        for n in FACE_NORMALS:
            support = (x - n[0], y - n[1], z - n[2])
            if not self.game.world.is_solid(*support):
                continue
            for point in _face_points(cell, n):
                if self._ray_hits(eye, point, support, n):
                    return support, n, point
        return None

    def visible_point(self, cell: tuple[int, int, int], eye: np.ndarray | None = None) -> np.ndarray | None:
        """A point on an exposed face of the block at ``cell`` that a ray from ``eye`` (default: the
        player's eye) reaches first within reach, or None (the block is hidden or too far)."""
        eye = self.me.eye if eye is None else eye
        x, y, z = cell
        for n in FACE_NORMALS:
            if self.game.world.is_solid(x + n[0], y + n[1], z + n[2]):
                continue  # a covered face
            outward = (x + n[0], y + n[1], z + n[2])
            for point in _face_points(outward, n):
                if self._ray_hits(eye, point, cell, None):
                    return point
        return None

    def _ray_hits(self, eye: np.ndarray, point: np.ndarray, block, normal) -> bool:
        d = point - eye
        dist = float(np.linalg.norm(d))
        if dist > C.REACH - REACH_MARGIN or dist < 1e-6:
            return False
        hit = raycast_block(self.game.world, eye, d / dist, C.REACH)
        return hit is not None and hit.block == tuple(block) and (normal is None or hit.normal == tuple(normal))

    def _jump_place(self, cell: tuple[int, int, int], sneak: bool) -> Actions:
        """Place at the apex of a jump, for a face hidden from standing eye height (e.g. the top of a wall)."""
        apex_eye = self._eye(False) + np.array([0.0, JUMP_APEX, 0.0])
        face = self._visible_face(cell, apex_eye)
        if face is None or not self.me.on_ground:
            return False
        support, normal, point = face
        yield from self.look_at(point)
        placed = False
        for t in range(JUMP_AIR_TICKS + 2):
            eye = self.me.eye
            use = not placed and self.me.use_cooldown <= 1 and self._aims_at(support, normal)
            # The game turns the camera before it uses the item: hold still on the tick of the click.
            cam = (0.0, 0.0) if use else self.turn_step(yaw_to(eye, point), pitch_to(eye, point))
            placed = placed or use
            yield act(cam, jump=int(t == 0), use=int(use))
        return True

    def dig(self, cell: tuple[int, int, int], timeout_s: float = 5.0) -> Actions:
        """Look at a visible face of a block and hold attack until it is gone. True on success.

        Attack is only held while the crosshair is on that block, so nothing else gets mined.
        """
        world = self.game.world
        center = np.array(cell, float) + 0.5
        if np.linalg.norm(center - self.me.eye) > C.REACH - REACH_MARGIN:
            yield from self.goto(center, radius=2.5, timeout_s=5.0)
        if self.slot_of(Item.DIAMOND_PICKAXE) is not None:
            yield from self.select(Item.DIAMOND_PICKAXE)
        point = self.visible_point(cell, self.me.eye)
        point = center if point is None else point
        yield from self.look_at(point)
        for _ in range(round(timeout_s * C.TICKS_PER_SECOND)):
            if world.get(*cell) in (Block.AIR, Block.WATER):
                return True
            if self._aims_at(cell):
                yield act(attack=1)
                continue
            eye = self.me.eye
            fresh = self.visible_point(cell, eye)
            point = point if fresh is None else fresh
            yield act(self.turn_step(yaw_to(eye, point), pitch_to(eye, point)))
        return world.get(*cell) in (Block.AIR, Block.WATER)

    def fight(self, player: Player, ticks: int, close: float = FIGHT_CLOSE) -> Actions:
        """mineflayer-pvp ``attack`` for ``ticks`` ticks: close in on ``player``, keep the crosshair on its
        body and swing whenever it is targeted within ``FIGHT_RANGE`` and the attack cooldown is over
        (each swing is a hit)."""
        for _ in range(max(0, int(ticks))):
            p = self.me
            aim = player.pos + np.array([0.0, BODY_AIM_HEIGHT, 0.0])
            cam = self.turn_step(yaw_to(p.eye, aim), pitch_to(p.eye, aim))
            dist = math.hypot(player.pos[0] - p.pos[0], player.pos[2] - p.pos[2])
            facing = abs(wrap_angle(yaw_to(p.pos, player.pos) - p.yaw)) < math.radians(45)
            fwd = dist > close and facing
            jump = (fwd and p.on_ground and self._blocked_ahead()) or p.in_water
            hit = self.game.target(self.index)
            on_target = hit is not None and hit.player is not None and self.game.players[hit.player] is player
            swing = on_target and hit.distance <= FIGHT_RANGE and p.attack_cooldown <= 1
            cam = (0.0, 0.0) if swing else cam  # the game turns before it attacks: hold still to hit
            yield act(cam, forward=int(fwd), jump=int(jump), attack=int(swing))

    # -- scaffolding movement --------------------------------------------------------------------
    def bridge(self, goal: np.ndarray, block: int, radius: float = 1.0, timeout_s: float = 60.0) -> Actions:
        """Bridge toward ``goal`` along its dominant horizontal axis: face away, sneak backwards and place
        ``block`` against the side of the block underfoot whenever the next cell is open (pathfinder scaffolding)."""
        world = self.game.world
        delta = np.asarray(goal, float) - self.me.pos
        axis = 0 if abs(delta[0]) >= abs(delta[2]) else 2
        sign = 1 if delta[axis] >= 0 else -1
        step = np.zeros(3, int)
        step[axis] = sign
        yield from self.select(block)
        yield from self.look(yaw_to(self.me.pos, self.me.pos - step), BRIDGE_PITCH, sneak=1)
        stuck = 0
        for _ in range(round(timeout_s * C.TICKS_PER_SECOND)):
            p = self.me
            if sign * (goal[axis] - p.pos[axis]) <= radius:
                return True
            stuck = 0 if math.hypot(p.vel[0], p.vel[2]) > MOVING_SPEED / 4 else stuck + 1
            if stuck > BRIDGE_STUCK_TICKS:
                return False  # a wall (terrain, another bridge) blocks the way
            under = np.array([math.floor(p.pos[0]), math.floor(p.pos[1] + 0.01) - 1, math.floor(p.pos[2])])
            if not world.is_solid(*under):
                under = under - step  # hanging over the edge: the support is the cell behind
            support, normal = tuple(int(v) for v in under), tuple(int(v) for v in step)
            nxt = tuple(int(v) for v in under + step)
            aimed = not world.is_solid(*nxt) and self._aims_at(support, normal)
            yield act(back=1, sneak=1, use=int(aimed and p.use_cooldown <= 1))
        return False

    def tunnel_to(self, goal: np.ndarray, radius: float = 1.6, timeout_s: float = 60.0) -> Actions:
        """Dig a 1x2 tunnel toward ``goal`` (feet position), one cardinal step at a time, stepping one
        block down per step while the goal is lower (a staircase). True when within ``radius`` (3-D)."""
        goal = np.asarray(goal, float)
        deadline = self.tick + round(timeout_s * C.TICKS_PER_SECOND)
        while self.tick < deadline:
            p = self.me
            if np.linalg.norm(goal - p.pos) <= radius:
                return True
            cx, cy, cz = math.floor(p.pos[0]), math.floor(p.pos[1] + 0.01), math.floor(p.pos[2])
            dx, dz = goal[0] - (cx + 0.5), goal[2] - (cz + 0.5)
            down = goal[1] < cy - 0.5
            if max(abs(dx), abs(dz)) < 0.5:
                if not down or not (yield from self.dig((cx, cy - 1, cz))):
                    return False
                yield from self.idle(JUMP_AIR_TICKS)  # fall into the hole
                continue
            sx, sz = (int(np.sign(dx)), 0) if abs(dx) >= abs(dz) else (0, int(np.sign(dz)))
            nx, nz = cx + sx, cz + sz
            for y in range(cy + 1, cy - 1 - int(down), -1):
                if self.game.world.is_solid(nx, y, nz) and not (yield from self.dig((nx, y, nz))):
                    return False
            yield from self.nudge_to(np.array([nx + 0.5, 0.0, nz + 0.5]), timeout_s=1.5, sneak=False)
        return False

    # -- messages ----------------------------------------------------------------------------------
    @property
    def mailbox(self) -> dict[str, dict]:
        """Messages shared by the bots of one game (the reference's peer events that need no barrier)."""
        return _MAILBOXES.setdefault(self.game, {})

    def post(self, name: str, **payload) -> None:
        """Send a one-way message (e.g. ``done_<cycle>``) that the peers can poll with :meth:`received`."""
        self.mailbox[name] = {**payload, "sender": self.name, "tick": self.tick}

    def received(self, name: str) -> dict | None:
        """A message of this name posted by another bot, or None."""
        msg = self.mailbox.get(name)
        return msg if msg is not None and msg["sender"] != self.name else None

    def sneak_signal(self) -> Actions:
        """The eval signal (docs/engine.md §6.1): sneak 5 ticks, release, idle 25 ticks; sets ``start_tick``."""
        yield from self.hold(5, sneak=1)
        yield from self.idle(25)
        self.start_tick = self.tick

    def pad_to(self, ticks_since_start: int) -> Actions:
        """Idle until ``ticks_since_start`` ticks have passed since ``start_tick`` (eval padding)."""
        if self.start_tick is None:
            raise EpisodeAbort("pad_to before the sneak signal")
        yield from self.idle(self.start_tick + ticks_since_start - self.tick)
