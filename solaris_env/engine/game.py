"""The game: a world and its players, advanced one 20 Hz tick at a time from per-player actions.

Players act only through the env action space (MineRL keys, ``solaris_env/spaces.py``). Each tick
also yields what a Mineflayer recorder would have written for that player (docs/engine.md §3.3): the
held movement keys, the camera rotation actually applied (radians, Mineflayer convention), and the
one-tick event flags (``attack`` on an entity hit, ``place_block`` after a placement, ``hotbar.k`` on
a slot change) plus the sustained ``mine`` while a dig is in progress.

Order inside a tick, per player in list order: hotbar, camera, attack/dig, use/place, movement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.blocks import BREAK_TICKS, PLACEABLE, Block
from solaris_env.engine.physics import Player, look_vector, move_player
from solaris_env.engine.world import World
from solaris_env.spaces import minerl_camera_to_mineflayer, validate_action

RECORD_BOOL_KEYS = ("forward", "back", "left", "right", "jump", "sprint", "sneak", "attack", "use", "mount",
                    "dismount", "place_block", "place_entity", "mine") + tuple(f"hotbar.{k}" for k in range(1, 10))
USE_REPEAT_TICKS = 4  # vanilla repeats a held right click every 4 ticks
BREAK_DELAY_TICKS = 5  # vanilla pause between two broken blocks while attack is held


@dataclass
class Hit:
    """What the crosshair points at within reach: a block (with the face normal) or a player."""

    distance: float
    block: tuple[int, int, int] | None = None
    normal: tuple[int, int, int] | None = None
    player: int | None = None


@dataclass
class TickEvents:
    """What happened to one player during one tick."""

    record: dict  # the 24-key Mineflayer action record of docs/actions.md §6.1
    placed: list[tuple[int, int, int, int]] = field(default_factory=list)  # (x, y, z, block)
    mined: list[tuple[int, int, int, int]] = field(default_factory=list)  # (x, y, z, block that was there)
    hit_player: int | None = None


def empty_record() -> dict:
    rec = {k: False for k in RECORD_BOOL_KEYS}
    rec["camera"] = [0.0, 0.0]
    return rec


# ---------------------------------------------------------------------------------------------
# Ray casting (crosshair target)
# ---------------------------------------------------------------------------------------------


def _ray_box(origin: np.ndarray, d: np.ndarray, bmin: np.ndarray, bmax: np.ndarray) -> float | None:
    """Entry distance of a ray into an AABB (slab test), or None."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1, t2 = (bmin - origin) * inv, (bmax - origin) * inv
    tmin = np.nanmax(np.minimum(t1, t2))
    tmax = np.nanmin(np.maximum(t1, t2))
    if tmax < max(tmin, 0.0):
        return None
    return float(max(tmin, 0.0))


def raycast_block(world: World, origin: np.ndarray, d: np.ndarray, reach: float) -> Hit | None:
    """First targetable block (anything but air and water) along the ray within ``reach`` (voxel DDA)."""
    cell = [math.floor(c) for c in origin]
    step = [1 if v > 0 else -1 for v in d]
    t_max, t_delta = [], []
    for a in range(3):
        if d[a] == 0:
            t_max.append(math.inf)
            t_delta.append(math.inf)
        else:
            edge = cell[a] + (1 if d[a] > 0 else 0)
            t_max.append((edge - origin[a]) / d[a])
            t_delta.append(abs(1.0 / d[a]))
    normal = (0, 0, 0)
    t = 0.0
    while t <= reach:
        b = world.get(*cell)
        if b not in (Block.AIR, Block.WATER):
            return Hit(distance=t, block=tuple(cell), normal=normal)
        a = int(np.argmin(t_max))
        t = t_max[a]
        cell[a] += step[a]
        t_max[a] += t_delta[a]
        normal = tuple(-step[a] if i == a else 0 for i in range(3))
    return None


# ---------------------------------------------------------------------------------------------
# The game
# ---------------------------------------------------------------------------------------------


class Game:
    """A world plus players. Pure game logic: no Gymnasium, no rendering.

    Args:
        world: the voxel world (mutated in place by digging and placing).
        players: the players, in a fixed order (index = player id).
        world_age: world age in ticks at tick 0 (sets the time of day).
    """

    def __init__(self, world: World, players: list[Player], world_age: int = 6000):
        if len(players) < 1:
            raise ValueError("a game needs at least one player")
        self.world = world
        self.players = players
        self.tick = 0
        self.world_age0 = world_age

    @property
    def world_age(self) -> int:
        return self.world_age0 + self.tick

    def daylight(self) -> float:
        """1.0 at noon, 0.25 at midnight (vanilla: tick 6000 = noon, 18000 = midnight)."""
        phase = ((self.world_age % 24000) - 6000) / 24000 * 2 * math.pi
        return float(0.25 + 0.75 * np.clip(0.5 + 0.7 * math.cos(phase), 0.0, 1.0))

    # -- targeting ------------------------------------------------------------------------------
    def target(self, i: int) -> Hit | None:
        """What player ``i``'s crosshair points at within reach (the nearer of a block and a player)."""
        p = self.players[i]
        origin, d = p.eye, look_vector(p.yaw, p.pitch)
        best = raycast_block(self.world, origin, d, C.REACH)
        for j, q in enumerate(self.players):
            if j == i:
                continue
            t = _ray_box(origin, d, *q.aabb())
            if t is not None and t <= C.REACH and (best is None or t < best.distance):
                best = Hit(distance=t, player=j)
        return best

    # -- one tick -------------------------------------------------------------------------------
    def step(self, actions: list[dict]) -> list[TickEvents]:
        """Apply one action per player (validated env actions) and advance the world by one tick."""
        if len(actions) != len(self.players):
            raise ValueError(f"expected {len(self.players)} actions (one per player), got {len(actions)}")
        actions = [validate_action(a, agent=p.name) for a, p in zip(actions, self.players)]
        events = [TickEvents(record=empty_record()) for _ in self.players]
        for i, (p, a, ev) in enumerate(zip(self.players, actions, events)):
            self._select_hotbar(p, a, ev)
            self._turn(p, a, ev)
            self._attack(i, a, ev)
            self._use(i, a, ev)
        for i, (p, a, ev) in enumerate(zip(self.players, actions, events)):
            others = [q for j, q in enumerate(self.players) if j != i]
            move_player(self.world, p, a["forward"] - a["back"], a["left"] - a["right"], bool(a["jump"]),
                        bool(a["sneak"]), bool(a["sprint"]), others)
            for k in ("forward", "back", "left", "right", "jump", "sneak"):
                ev.record[k] = bool(a[k])
            ev.record["sprint"] = bool(a["sprint"])
        self.tick += 1
        return events

    def _select_hotbar(self, p: Player, a: dict, ev: TickEvents) -> None:
        pressed = [k for k in range(1, 10) if a[f"hotbar.{k}"]]
        if pressed:  # several keys in one tick: the lowest wins (documented, deterministic)
            slot = pressed[0] - 1
            if slot != p.selected_slot:
                p.selected_slot = slot
                ev.record[f"hotbar.{slot + 1}"] = True
                p.dig_pos, p.dig_progress = None, 0

    def _turn(self, p: Player, a: dict, ev: TickEvents) -> None:
        dyaw, dpitch = minerl_camera_to_mineflayer(a["camera"])
        new_pitch = min(C.PITCH_LIMIT, max(-C.PITCH_LIMIT, p.pitch + dpitch))
        applied_dpitch = new_pitch - p.pitch if dpitch != 0.0 else 0.0
        p.pitch = new_pitch
        p.yaw = math.fmod(p.yaw + dyaw, 2 * math.pi)
        if p.yaw < 0:
            p.yaw += 2 * math.pi
        ev.record["camera"] = [float(dyaw), float(applied_dpitch)]

    def _attack(self, i: int, a: dict, ev: TickEvents) -> None:
        p = self.players[i]
        p.attack_cooldown = max(0, p.attack_cooldown - 1)
        p.dig_cooldown = max(0, p.dig_cooldown - 1)
        hit = self.target(i) if a["attack"] else None
        if hit is None or hit.block is None:
            p.dig_pos, p.dig_progress = None, 0
        if hit is None:
            return
        if hit.player is not None:
            if p.attack_cooldown == 0:
                self._hit_player(p, self.players[hit.player])
                p.attack_cooldown = C.ATTACK_COOLDOWN_TICKS
                ev.record["attack"] = True
                ev.hit_player = hit.player
            return
        if p.dig_cooldown > 0:
            return
        block = self.world.get(*hit.block)
        if hit.block != p.dig_pos:
            p.dig_pos, p.dig_progress = hit.block, 0
        ev.record["mine"] = True  # sustained while a dig is in progress (docs/engine.md §3.3)
        needed = int(BREAK_TICKS[block])
        if needed < 0:
            return  # unbreakable: keeps digging forever, as in vanilla
        p.dig_progress += 1
        if p.dig_progress >= max(1, needed):
            self.world.set(*hit.block, Block.AIR)
            ev.mined.append((*hit.block, block))
            p.dig_pos, p.dig_progress = None, 0
            p.dig_cooldown = BREAK_DELAY_TICKS
            above = (hit.block[0], hit.block[1] + 1, hit.block[2])
            if self.world.get(*above) == Block.TORCH:  # a torch loses its support
                self.world.set(*above, Block.AIR)
                ev.mined.append((*above, int(Block.TORCH)))

    @staticmethod
    def _hit_player(attacker: Player, victim: Player) -> None:
        d = victim.pos - attacker.pos
        d[1] = 0.0
        n = float(np.linalg.norm(d)) or 1.0
        victim.vel += d / n * C.KNOCKBACK
        if victim.on_ground:
            victim.vel[1] = 0.36
        victim.hits_taken += 1

    def _use(self, i: int, a: dict, ev: TickEvents) -> None:
        p = self.players[i]
        p.use_cooldown = max(0, p.use_cooldown - 1)
        if not a["use"] or p.use_cooldown > 0:
            return
        p.use_cooldown = USE_REPEAT_TICKS
        item, count = p.hotbar[p.selected_slot]
        hit = self.target(i)
        if hit is None or hit.block is None or count <= 0 or item not in PLACEABLE:
            return
        x, y, z = (hit.block[k] + hit.normal[k] for k in range(3))
        if not self.world.in_bounds(x, y, z) or self.world.get(x, y, z) not in (Block.AIR, Block.WATER):
            return
        if item == Block.TORCH and not self.world.is_solid(*hit.block):
            return
        cell_min, cell_max = np.array([x, y, z], float), np.array([x + 1, y + 1, z + 1], float)
        for q in self.players:  # never place a solid block inside a player
            qmin, qmax = q.aabb()
            if item != Block.TORCH and np.all(qmin < cell_max) and np.all(qmax > cell_min):
                return
        self.world.set(x, y, z, item)
        p.hotbar[p.selected_slot][1] = count - 1
        if count - 1 == 0:
            p.hotbar[p.selected_slot][0] = 0
        ev.record["place_block"] = True
        ev.placed.append((x, y, z, int(item)))
