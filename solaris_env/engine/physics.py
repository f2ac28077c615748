"""Player state and Minecraft-like movement physics (one 20 Hz tick at a time).

Vanilla's model, per tick: jump impulse, ``velocity += accel * input_dir``, move with axis-separated
AABB collision (y, then x, then z), then ``velocity *= friction`` horizontally and
``vy = (vy - gravity) * drag``. With ``accel = speed * (1 - friction)`` the per-tick displacement
converges to ``speed``, which gives the walk/sprint/sneak speeds of ``constants``. Sneaking on the
ground never walks off an edge higher than a step (vanilla's back-off-from-edge).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.blocks import Block
from solaris_env.engine.world import World

_EPS = 1e-7
_STEP_DOWN = 0.6  # drop that sneaking refuses to walk off (vanilla maxUpStep)


@dataclass
class Player:
    """One player's state. Angles use Mineflayer's convention (docs/engine.md §1.2): yaw 0 = north
    (-Z), +yaw = turned left (CCW seen from +Y), pitch + = looking up."""

    name: str
    skin: int
    pos: np.ndarray  # (3,) float64 feet position
    yaw: float = 0.0
    pitch: float = 0.0
    vel: np.ndarray = field(default_factory=lambda: np.zeros(3))
    on_ground: bool = False
    in_water: bool = False
    sneaking: bool = False
    sprinting: bool = False
    selected_slot: int = 0
    hotbar: list[list[int]] = field(default_factory=lambda: [[0, 0] for _ in range(C.HOTBAR_SIZE)])  # [item id, count]
    dig_pos: tuple[int, int, int] | None = None
    dig_progress: int = 0
    dig_cooldown: int = 0
    attack_cooldown: int = 0
    use_cooldown: int = 0
    walk_dist: float = 0.0  # horizontal distance walked, drives the limb swing
    hits_taken: int = 0

    @property
    def height(self) -> float:
        return C.PLAYER_SNEAK_HEIGHT if self.sneaking else C.PLAYER_HEIGHT

    @property
    def eye_height(self) -> float:
        return C.SNEAK_EYE_HEIGHT if self.sneaking else C.EYE_HEIGHT

    @property
    def eye(self) -> np.ndarray:
        return self.pos + np.array([0.0, self.eye_height, 0.0])

    @property
    def held_item(self) -> int:
        return self.hotbar[self.selected_slot][0]

    def aabb(self, pos: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        p = self.pos if pos is None else pos
        half = C.PLAYER_WIDTH / 2
        return p - np.array([half, 0.0, half]), p + np.array([half, self.height, half])

    def swing_angle(self) -> float:
        """Limb swing for the avatar, in radians (vanilla: ~0.6662 rad per block walked, amplitude by speed)."""
        speed = math.hypot(self.vel[0], self.vel[2]) / C.WALK_SPEED
        return float(0.9 * math.sin(self.walk_dist * 0.6662 * 2) * min(1.0, speed))


# ---------------------------------------------------------------------------------------------
# Direction helpers (Mineflayer convention)
# ---------------------------------------------------------------------------------------------


def look_vector(yaw: float, pitch: float) -> np.ndarray:
    """Unit view direction for Mineflayer yaw/pitch: yaw 0 -> -Z, yaw pi/2 -> -X (west), pitch + -> up."""
    cp = math.cos(pitch)
    return np.array([-math.sin(yaw) * cp, math.sin(pitch), -math.cos(yaw) * cp])


def horizontal_axes(yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """(forward, left) unit vectors on the ground plane for a yaw."""
    fwd = np.array([-math.sin(yaw), 0.0, -math.cos(yaw)])
    left = np.array([-math.cos(yaw), 0.0, math.sin(yaw)])
    return fwd, left


def wrap_angle(a: float) -> float:
    """Wrap to (-pi, pi]."""
    a = math.fmod(a + math.pi, 2 * math.pi)
    if a <= 0:
        a += 2 * math.pi
    return a - math.pi


def yaw_to(src: np.ndarray, dst: np.ndarray) -> float:
    """Mineflayer yaw that faces from ``src`` toward ``dst`` (``atan2(-dx, -dz)``)."""
    return math.atan2(-(dst[0] - src[0]), -(dst[2] - src[2]))


def pitch_to(src: np.ndarray, dst: np.ndarray) -> float:
    d = dst - src
    return math.atan2(d[1], math.hypot(d[0], d[2]))


def face(p: Player, target: Player) -> None:
    """Set ``p``'s camera straight onto another player (a setup before recording, not a tick's turn)."""
    p.yaw = yaw_to(p.pos, target.pos) % (2 * math.pi)
    p.pitch = pitch_to(p.pos, target.pos)


# ---------------------------------------------------------------------------------------------
# Collision
# ---------------------------------------------------------------------------------------------


def _cells(lo: float, hi: float) -> tuple[int, int]:
    """Integer cells overlapped by the open interval (lo, hi)."""
    return math.floor(lo + _EPS), math.ceil(hi - _EPS) - 1


def sweep_axis(world: World, bmin: np.ndarray, bmax: np.ndarray, axis: int, d: float) -> float:
    """The part of a move ``d`` along ``axis`` that the box [bmin, bmax] can make before hitting a solid block."""
    if d == 0.0:
        return 0.0
    o1, o2 = [a for a in range(3) if a != axis]
    lo, hi = [0, 0, 0], [0, 0, 0]
    lo[o1], hi[o1] = _cells(bmin[o1], bmax[o1])
    lo[o2], hi[o2] = _cells(bmin[o2], bmax[o2])
    if d > 0:
        first, last = math.ceil(bmax[axis] - _EPS), math.ceil(bmax[axis] + d) - 1
        for c in range(first, last + 1):
            lo[axis] = hi[axis] = c
            if world.any_solid(tuple(lo), tuple(hi)):
                return max(0.0, c - bmax[axis])
        return d
    first, last = math.floor(bmin[axis] + _EPS) - 1, math.floor(bmin[axis] + d)
    for c in range(first, last - 1, -1):
        lo[axis] = hi[axis] = c
        if world.any_solid(tuple(lo), tuple(hi)):
            return min(0.0, c + 1 - bmin[axis])
    return d


def box_collides(world: World, bmin: np.ndarray, bmax: np.ndarray) -> bool:
    lo = [_cells(bmin[a], bmax[a])[0] for a in range(3)]
    hi = [_cells(bmin[a], bmax[a])[1] for a in range(3)]
    return world.any_solid(tuple(lo), tuple(hi))


def _back_off_from_edge(world: World, p: Player, dx: float, dz: float) -> tuple[float, float]:
    """Vanilla sneaking: shrink (dx, dz) in 0.05 steps until the moved box still has ground within a step."""
    bmin, bmax = p.aabb()
    down = np.array([0.0, -_STEP_DOWN, 0.0])

    def unsupported(mx: float, mz: float) -> bool:
        off = np.array([mx, 0.0, mz]) + down
        return not box_collides(world, bmin + off, bmax + off)

    step = C.SNEAK_EDGE_PROBE
    while dx != 0.0 and unsupported(dx, 0.0):
        dx = 0.0 if abs(dx) < step else dx - math.copysign(step, dx)
    while dz != 0.0 and unsupported(0.0, dz):
        dz = 0.0 if abs(dz) < step else dz - math.copysign(step, dz)
    while dx != 0.0 and dz != 0.0 and unsupported(dx, dz):
        dx = 0.0 if abs(dx) < step else dx - math.copysign(step, dx)
        dz = 0.0 if abs(dz) < step else dz - math.copysign(step, dz)
    return dx, dz


def in_water(world: World, p: Player) -> bool:
    x, z = math.floor(p.pos[0]), math.floor(p.pos[2])
    return world.get(x, math.floor(p.pos[1] + 0.4), z) == Block.WATER


# ---------------------------------------------------------------------------------------------
# One tick of movement
# ---------------------------------------------------------------------------------------------


def move_player(world: World, p: Player, forward: int, strafe: int, jump: bool, sneak: bool, sprint: bool,
                others: list[Player] = ()) -> None:
    """Advance ``p`` by one tick of movement.

    Args:
        forward: +1 forward, -1 back, 0 none. strafe: +1 left, -1 right, 0 none (vanilla's signs).
        jump, sneak, sprint: held keys. Sprinting needs forward input and no sneaking.
        others: players whose bodies block the sneak-stand-up check (not collided with otherwise,
            as in vanilla where players push rather than block each other).
    """
    if not sneak and p.sneaking:
        bmin, bmax = p.aabb()
        stand_max = bmax.copy()
        stand_max[1] = bmin[1] + C.PLAYER_HEIGHT
        if box_collides(world, bmin, stand_max):
            sneak = True  # no room to stand up
    p.sneaking = sneak
    p.sprinting = bool(sprint and forward > 0 and not sneak)
    p.in_water = in_water(world, p)

    fwd_dir, left_dir = horizontal_axes(p.yaw)
    inp = np.array([float(strafe), float(forward)])
    norm = float(np.hypot(*inp))
    if norm > 1.0:
        inp /= norm
    if p.sneaking:
        inp *= C.SNEAK_SPEED / C.WALK_SPEED
    wish = inp[1] * fwd_dir + inp[0] * left_dir  # (3,) horizontal, length <= 1

    if p.in_water:
        accel, friction = C.AIR_ACCEL, C.WATER_DRAG
        if jump:
            p.vel[1] += C.WATER_SWIM_UP
    else:
        speed = C.SPRINT_SPEED if p.sprinting else C.WALK_SPEED
        if p.on_ground:
            friction = C.GROUND_FRICTION
            accel = speed * (1.0 - friction)
            if jump:
                p.vel[1] = C.JUMP_VELOCITY
                if p.sprinting:
                    p.vel += fwd_dir * C.SPRINT_JUMP_BOOST
        else:
            friction = C.AIR_FRICTION
            accel = C.AIR_SPRINT_ACCEL if p.sprinting else C.AIR_ACCEL
    p.vel += wish * accel

    dx, dy, dz = float(p.vel[0]), float(p.vel[1]), float(p.vel[2])
    if p.sneaking and p.on_ground and not jump:
        dx, dz = _back_off_from_edge(world, p, dx, dz)
    start = p.pos.copy()
    bmin, bmax = p.aabb()
    my = sweep_axis(world, bmin, bmax, 1, dy)
    p.pos[1] += my
    bmin, bmax = p.aabb()
    mx = sweep_axis(world, bmin, bmax, 0, dx)
    p.pos[0] += mx
    bmin, bmax = p.aabb()
    mz = sweep_axis(world, bmin, bmax, 2, dz)
    p.pos[2] += mz

    p.on_ground = dy < 0 and my > dy + _EPS
    if my != dy:
        p.vel[1] = 0.0
    if mx != dx:
        p.vel[0] = 0.0
        p.sprinting = False
    if mz != dz:
        p.vel[2] = 0.0
    p.vel[0] *= friction
    p.vel[2] *= friction
    if p.in_water:
        p.vel[1] = (p.vel[1] - C.WATER_GRAVITY) * C.WATER_DRAG
    else:
        p.vel[1] = (p.vel[1] - C.GRAVITY) * C.VERTICAL_DRAG
    p.walk_dist += float(np.hypot(p.pos[0] - start[0], p.pos[2] - start[2]))
