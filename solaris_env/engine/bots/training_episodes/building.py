"""Building training types (docs/engine.md §5.3): buildStructure, buildTower, towerBridge, buildHouse.

buildHouse: bots raise the walls from inside the house and the roof from a 3-block stone pillar inside it
(scaffolding, left in place like the pathfinder's), finishing on the roof; the roof's last block is placed
under their feet. Then they drop off the roof towards the door.
"""

from __future__ import annotations

import math

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.blocks import Block
from solaris_env.engine.bots.controller import Actions, Bot, EpisodeAbort
from solaris_env.engine.bots.spec import EpisodeSpec
from solaris_env.engine.bots.training_episodes.common import (
    CAMERA_DPS,
    EYE_CONTACT_S,
    clamp_xz,
    eye_contact,
    floor_midpoint,
    give_items,
    seconds_to_ticks,
)
from solaris_env.engine.world import World

BUILD_FAIL_FRACTION = 0.5  # more failed placements than this aborts the episode


def _build_cells(bot: Bot, cells: list[tuple[int, int, int]], block: int, pause_s: float, approach: bool = True,
                 passes: int = 3, scaffold: int | None = None) -> Actions:
    """Place ``block`` in ``cells`` in order, ``pause_s`` apart; cells that fail (no support yet, a player
    in the way) are retried in later passes. Cells already filled by terrain are skipped.

    Returns (number attempted, number failed).
    """
    world = bot.game.world
    pending = [c for c in cells if not world.is_solid(*c) or world.get(*c) == block]
    attempted = len(pending)
    for _ in range(passes):
        left = []
        for cell in pending:
            if (yield from bot.place_at(cell, block, attempts=2, approach=approach, scaffold=scaffold)):
                yield from bot.sleep(pause_s)
            else:
                left.append(cell)
        if len(left) == len(pending):
            break
        pending = left
    return attempted, len([c for c in pending if world.get(*c) != block])


def _check_build(name: str, attempted: int, failed: int) -> None:
    """The reference build phases throw (episode abort) when more than half of the blocks failed."""
    if attempted and failed / attempted > BUILD_FAIL_FRACTION:
        raise EpisodeAbort(f"{name}: {failed}/{attempted} placements failed")


def _spiral(width: int, depth: int) -> list[tuple[int, int]]:
    """Local (x, z) cells of a ``width`` x ``depth`` rectangle, ring by ring from the edge to the centre."""
    order, x0, z0, x1, z1 = [], 0, 0, width - 1, depth - 1
    while x0 <= x1 and z0 <= z1:
        ring = [(x, z0) for x in range(x0, x1 + 1)] + [(x1, z) for z in range(z0 + 1, z1 + 1)]
        if z1 > z0:
            ring += [(x, z1) for x in range(x1 - 1, x0 - 1, -1)]
        if x1 > x0:
            ring += [(x0, z) for z in range(z1 - 1, z0, -1)]
        order += ring
        x0, z0, x1, z1 = x0 + 1, z0 + 1, x1 - 1, z1 - 1
    return order


def _is_west(bot: Bot, mine: np.ndarray, other: np.ndarray) -> bool:
    """Which bot builds the west (low-x) half: the one spawned further west; a tie goes to the lower name."""
    if math.floor(mine[0]) != math.floor(other[0]):
        return mine[0] < other[0]
    return bot.is_lower


GROUND_SEARCH = 3  # blocks above/below a reference height searched for the local ground
FOUNDATION_DEPTH = 3  # floating floor cells get support columns at most this deep


def _ground_near(world: World, x: int, z: int, y_ref: int) -> int:
    """Feet-level y of the ground in column (x, z) nearest to ``y_ref`` (solid below, free at y), else ``y_ref``.

    Unlike ``World.surface_y`` this ignores tree tops and overhangs far above the reference height.
    """
    for dy in sorted(range(-GROUND_SEARCH, GROUND_SEARCH + 1), key=abs):
        y = y_ref + dy
        if world.is_solid(x, y - 1, z) and not world.is_solid(x, y, z):
            return y
    return y_ref


def _with_foundation(world: World, cells: list[tuple[int, int, int]]) -> list[tuple[int, int, int]]:
    """Precede floating cells with support columns down to the ground (if it is at most ``FOUNDATION_DEPTH`` below)."""
    support = []
    for x, y, z in cells:
        depth = 0
        while depth < FOUNDATION_DEPTH and not world.is_solid(x, y - depth - 1, z):
            depth += 1
        if depth and world.is_solid(x, y - depth - 1, z):
            support += [(x, y - k, z) for k in range(depth, 0, -1)]
    return support + list(cells)


STRUCTURES = ("wall", "tower", "platform")
STRUCTURE_BLOCKS = (Block.STONE, Block.COBBLESTONE, Block.OAK_PLANKS, Block.BRICKS)
STRUCTURE_BLOCK_S = 0.3
WALL_WIDTH, WALL_HEIGHT = 5, 2
COLUMN_HEIGHT = 2
PLATFORM_SIZE = 4
PLATFORM_WEST_MAX_X = 2  # the west builder takes local x <= 2 (12 blocks), the east one x = 3 (4)
BUILD_OFFSET = 2  # walls and columns stand this many blocks in front of their builder


def _structure_setup(bot: Bot) -> None:
    give_items(bot, [(b, C.STACK_SIZE) for b in STRUCTURE_BLOCKS if b != Block.STONE])


def _toward_partner(mine: np.ndarray, other: np.ndarray) -> tuple[int, int]:
    """The cardinal (dx, dz) step from ``mine`` that points most towards ``other``."""
    d = other - mine
    if abs(d[0]) >= abs(d[2]):
        return (1 if d[0] >= 0 else -1), 0
    return 0, (1 if d[2] >= 0 else -1)


def _structure_cells(bot: Bot, kind: str, mine: np.ndarray, other: np.ndarray) -> list[tuple[int, int, int]]:
    x0, y0, z0 = (math.floor(mine[0]), math.floor(mine[1] + 0.01), math.floor(mine[2]))
    sx, sz = _toward_partner(mine, other)
    bx, bz = x0 + BUILD_OFFSET * sx, z0 + BUILD_OFFSET * sz
    world = bot.game.world
    if kind == "wall":  # 5 x 2 across the line to the partner, bottom-up then left to right, on the ground
        ax, az = abs(sz), abs(sx)  # along the wall
        half = WALL_WIDTH // 2
        columns = [(bx + i * ax, bz + i * az) for i in range(-half, half + 1)]
        base = {c: _ground_near(world, c[0], c[1], y0) for c in columns}
        return [(x, base[(x, z)] + j, z) for j in range(WALL_HEIGHT) for x, z in columns]
    if kind == "tower":
        base = _ground_near(world, bx, bz, y0)
        return [(bx, base + j, bz) for j in range(COLUMN_HEIGHT)]
    ox, oy, oz = floor_midpoint(mine, other)
    ox, oz = ox - PLATFORM_SIZE // 2, oz - PLATFORM_SIZE // 2
    oy = max([oy] + [_ground_near(world, ox + lx, oz + lz, oy) for lx, lz in _spiral(PLATFORM_SIZE, PLATFORM_SIZE)])
    west = _is_west(bot, mine, other)
    cells = [(ox + lx, oy, oz + lz) for lx, lz in _spiral(PLATFORM_SIZE, PLATFORM_SIZE)
             if (lx <= PLATFORM_WEST_MAX_X) == west]
    return _with_foundation(world, cells)


def build_structure(bot: Bot) -> Actions:
    """Agree on a structure (wall / tower / platform) and a block; each bot builds its own part, 300 ms a block."""
    yield from bot.barrier("buildStructure", pos=bot.me.pos.copy())
    kind = STRUCTURES[int(bot.shared_rng.random() * len(STRUCTURES))]
    block = STRUCTURE_BLOCKS[int(bot.shared_rng.random() * len(STRUCTURE_BLOCKS))]
    other = bot.peer_payloads["buildStructure"][bot.other.name]["pos"]
    yield from eye_contact(bot)
    cells = _structure_cells(bot, kind, bot.me.pos.copy(), other)
    attempted, failed = yield from _build_cells(bot, cells, block, STRUCTURE_BLOCK_S)
    _check_build("buildStructure", attempted, failed)
    yield from eye_contact(bot)


TOWER_MIN_HEIGHT, TOWER_HEIGHT_CHOICES = 8, 5  # height = 8 + floor(rng * 5)
TOWER_PITCH = -1.45  # buildTower looks down this far (rad) once
TOWER_SETTLE_S = 0.2
TOWER_BLOCK = Block.OAK_PLANKS


def _tower_setup(bot: Bot) -> None:
    give_items(bot, [(TOWER_BLOCK, C.STACK_SIZE)])


def build_tower(bot: Bot) -> Actions:
    """Pillar up 8-12 blocks of oak planks by jump-placing; stop at the first failed level."""
    yield from bot.barrier("buildTower")
    height = TOWER_MIN_HEIGHT + int(bot.shared_rng.random() * TOWER_HEIGHT_CHOICES)
    yield from eye_contact(bot)
    for _ in range(height):
        if not (yield from bot.place_below(TOWER_BLOCK, pitch=TOWER_PITCH)):
            break
        yield from bot.sleep(TOWER_SETTLE_S)
    yield from eye_contact(bot)


BRIDGE_TOWER_HEIGHT = 8
BRIDGE_MAX_TOWER_FAILS = 2  # more failed tower blocks than this aborts
BRIDGE_WAIT_S = 1.5
BRIDGE_RADIUS = 1.0
BRIDGE_TIMEOUT_S = 60.0
BRIDGE_CORNER_OVERSHOOT = 0.25  # blocks past the corner cell's centre where the first leg ends


def tower_bridge(bot: Bot) -> Actions:
    """Pillar 8 blocks, then sneak-bridge towards the midpoint along the axis of larger separation."""
    yield from bot.barrier("towerBridge", pos=bot.me.pos.copy())
    other = bot.peer_payloads["towerBridge"][bot.other.name]["pos"]
    built = fails = 0
    while built < BRIDGE_TOWER_HEIGHT:
        if (yield from bot.place_below(TOWER_BLOCK)):
            built += 1
            continue
        fails += 1
        if fails > BRIDGE_MAX_TOWER_FAILS:
            raise EpisodeAbort(f"towerBridge: {fails} tower blocks failed")
        yield from bot.sleep(TOWER_SETTLE_S)
    yield from bot.sleep(BRIDGE_WAIT_S)
    yield from bot.look_at_player(bot.other, sneak=1)
    yield from bot.hold(seconds_to_ticks(EYE_CONTACT_S), sneak=1)
    yield from _bridge_to_midpoint(bot, other)
    yield from bot.idle(1)  # sneak off
    yield from eye_contact(bot)


def _bridge_to_midpoint(bot: Bot, other: np.ndarray) -> Actions:
    """Bridge to the shared target: the midpoint snapped onto the line of the larger separation. The
    bridge runs as two straight legs (onto that line, then along it), as our scaffolding is axis-aligned;
    both bots then meet head-on on the shared line."""
    me = bot.me.pos.copy()
    major = 0 if abs(other[0] - me[0]) >= abs(other[2] - me[2]) else 2
    minor = 2 - major
    target = me.copy()
    for a in (major, minor):
        target[a] = math.floor((math.floor(me[a]) + math.floor(other[a])) / 2) + 0.5
    end = bot.tick + seconds_to_ticks(BRIDGE_TIMEOUT_S)
    if abs(target[minor] - me[minor]) > BRIDGE_RADIUS:
        leg = me.copy()  # stop over the target cell's far half, so the block under it is the corner
        leg[minor] = target[minor] + math.copysign(BRIDGE_CORNER_OVERSHOOT, target[minor] - me[minor])
        yield from bot.bridge(leg, TOWER_BLOCK, 0.0, (end - bot.tick) / C.TICKS_PER_SECOND)
        yield from _centre_on_support(bot)
    yield from bot.bridge(target, TOWER_BLOCK, BRIDGE_RADIUS, (end - bot.tick) / C.TICKS_PER_SECOND)


def _centre_on_support(bot: Bot) -> Actions:
    """Sneak back onto the middle of the block underfoot (a bridge leg ends hanging over its edge)."""
    world = bot.game.world
    p = bot.me.pos
    y = math.floor(p[1] + 0.01) - 1
    cells = [(math.floor(p[0] + dx), y, math.floor(p[2] + dz)) for dx in (0.0, -0.3, 0.3) for dz in (0.0, -0.3, 0.3)]
    support = next((c for c in cells if world.is_solid(*c)), None)
    if support is not None:
        yield from bot.nudge_to(np.array([support[0] + 0.5, 0.0, support[2] + 0.5]), timeout_s=2.0, sneak=True)


HOUSE_SIZE = 5
HOUSE_WALL_LAYERS = (1, 2, 3)
HOUSE_ROOF_LAYER = 4
HOUSE_DOOR = (2, 0)  # local (x, z) of the 1 x 2 door gap in layers 1-2
HOUSE_DOOR_LAYERS = (1, 2)
HOUSE_WEST_MAX_X = 2  # local x <= 2 is the west half
HOUSE_STANDS = {True: (2, 2), False: (3, 2)}  # local (x, z) where the west / east builder works inside
HOUSE_FLOOR, HOUSE_WALL, HOUSE_ROOF = Block.COBBLESTONE, Block.OAK_PLANKS, Block.OAK_LOG
HOUSE_SCAFFOLD = Block.STONE
HOUSE_BLOCK_S = 0.2
HOUSE_SITE_RADIUS = 10  # on uneven ground the house may move this far from the midpoint
HOUSE_SITE_STEP = 1  # ... to a spot whose ground heights differ by at most this
HOUSE_TREE_CLEARANCE = 2  # ... and with no tree this close
TREE_BLOCKS = (Block.OAK_LOG, Block.LEAVES)
HOUSE_WALK_S = 10.0
HOUSE_SETTLE_TICKS = 6  # time to drop into a floor hole before filling it
HOUSE_PHASE_PAUSE_S = 1.0
HOUSE_DROP_S, HOUSE_DOOR_S = 5.0, 3.0
HOUSE_SPOT_MIN, HOUSE_SPOT_SPAN = 12.0, 8.0  # admiring spot 12-20 blocks from the house centre
HOUSE_SPOT_SIDE = 1.5  # the two bots stand this far either side of the spot
HOUSE_SPOT_S = 20.0
HOUSE_ADMIRE_S = 2.0
HOUSE_LOOK_UP = 2.0  # look at the house centre this high above the floor
HOUSE_CLEARANCE = 1.5  # detour corners sit this far outside the walls
SPOT_ANGLE_HASH = (12.9898, 78.233, 43758.5453)  # sin-hash coefficients (x, z, scale) of the spot's angle
SPOT_DIST_HASH = (39.3468, 11.135, 24634.6345)  # ... and of its distance


def _house_floor() -> list[tuple[int, int, int]]:
    return [(x, 0, z) for x, z in _spiral(HOUSE_SIZE, HOUSE_SIZE)]


def _house_walls() -> list[tuple[int, int, int]]:
    ring = [c for c in _spiral(HOUSE_SIZE, HOUSE_SIZE) if c[0] in (0, HOUSE_SIZE - 1) or c[1] in (0, HOUSE_SIZE - 1)]
    return [(x, y, z) for y in HOUSE_WALL_LAYERS for x, z in ring
            if not ((x, z) == HOUSE_DOOR and y in HOUSE_DOOR_LAYERS)]


def _house_roof() -> list[tuple[int, int, int]]:
    return [(x, HOUSE_ROOF_LAYER, z) for x, z in _spiral(HOUSE_SIZE, HOUSE_SIZE)]


def _house_setup(bot: Bot) -> None:
    """Materials: twice the block counts (the reference gives 2x)."""
    give_items(bot, [(HOUSE_FLOOR, 2 * len(_house_floor())), (HOUSE_WALL, 2 * len(_house_walls())),
                      (HOUSE_ROOF, 2 * len(_house_roof()))])


def _house_origin(world: World, mine: np.ndarray, other: np.ndarray) -> tuple[int, int, int]:
    """Low corner of the house, centred on the floor-averaged midpoint at the higher bot's feet y.

    On uneven ground (normal worlds) the house moves to the nearest spot, ring by ring up to
    ``HOUSE_SITE_RADIUS`` away, whose ground varies by at most one block and has free air above; the
    floor then sits on the highest ground there (floating cells get a one-block foundation).
    """
    mx, my, mz = floor_midpoint(mine, other)
    r = HOUSE_SITE_RADIUS + HOUSE_SIZE
    xs, zs = range(mx - r, mx + r + 1), range(mz - r, mz + r + 1)
    ground = np.array([[_ground_near(world, x, z, my) for z in zs] for x in xs])  # (X, Z) feet-level y
    for ring in range(HOUSE_SITE_RADIUS + 1):
        for dx, dz in sorted(((dx, dz) for dx in range(-ring, ring + 1) for dz in range(-ring, ring + 1)
                              if max(abs(dx), abs(dz)) == ring), key=lambda d: (abs(d[0]) + abs(d[1]), d)):
            ox, oz = mx + dx - HOUSE_SIZE // 2, mz + dz - HOUSE_SIZE // 2
            i, k = ox - xs[0], oz - zs[0]
            patch = ground[i:i + HOUSE_SIZE, k:k + HOUSE_SIZE]
            y = max(int(patch.max()), my) if ring == 0 else int(patch.max())
            if patch.max() - patch.min() <= HOUSE_SITE_STEP and _house_space_free(world, ox, y, oz):
                return ox, y, oz
    ox, oz = mx - HOUSE_SIZE // 2, mz - HOUSE_SIZE // 2
    return ox, max([my] + [_ground_near(world, ox + x, oz + z, my) for x in range(HOUSE_SIZE)
                           for z in range(HOUSE_SIZE)]), oz


def _house_space_free(world: World, ox: int, y: int, oz: int) -> bool:
    """Nothing but air in the house's volume (floor to above the roof) and no tree within
    ``HOUSE_TREE_CLEARANCE`` blocks of it (its leaves would block the builders' jumps)."""
    m = HOUSE_TREE_CLEARANCE
    for x in range(ox - m, ox + HOUSE_SIZE + m):
        for z in range(oz - m, oz + HOUSE_SIZE + m):
            inside = ox <= x < ox + HOUSE_SIZE and oz <= z < oz + HOUSE_SIZE
            for dy in range(HOUSE_ROOF_LAYER + 2):
                b = world.get(x, y + dy, z)
                if (inside and b != Block.AIR) or b in TREE_BLOCKS:
                    return False
    return True


def _house_half(cells, origin, west: bool) -> list[tuple[int, int, int]]:
    ox, oy, oz = origin
    return [(ox + x, oy + y, oz + z) for x, y, z in cells if (x <= HOUSE_WEST_MAX_X) == west]


def _sin_hash(x: float, z: float, coeffs: tuple[float, float, float]) -> float:
    """Deterministic pseudo-random number in [0, 1) from a position (the classic ``fract(sin(dot) * k)``)."""
    a, b, k = coeffs
    return (math.sin(x * a + z * b) * k) % 1.0


def _house_spot(bot: Bot, origin) -> np.ndarray:
    """The shared admiring spot: a sin-hash of the house centre gives angle and distance; sides +-1.5."""
    cx, cz = origin[0] + HOUSE_SIZE / 2, origin[2] + HOUSE_SIZE / 2
    angle = 2 * math.pi * _sin_hash(cx, cz, SPOT_ANGLE_HASH)
    dist = HOUSE_SPOT_MIN + HOUSE_SPOT_SPAN * _sin_hash(cx, cz, SPOT_DIST_HASH)
    side = -HOUSE_SPOT_SIDE if bot.is_lower else HOUSE_SPOT_SIDE
    spot = np.array([cx + dist * math.cos(angle) - side * math.sin(angle), float(origin[1]),
                     cz + dist * math.sin(angle) + side * math.cos(angle)])
    return clamp_xz(bot.game.world, spot)


def _segment_hits_square(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether the xz segment a-b crosses the square [lo, hi] (Liang-Barsky clipping)."""
    t0, t1 = 0.0, 1.0
    for k, axis in enumerate((0, 2)):
        d = b[axis] - a[axis]
        for p, q in ((-d, a[axis] - lo[k]), (d, hi[k] - a[axis])):
            if abs(p) < 1e-12:
                if q < 0:
                    return False
                continue
            t = q / p
            if p < 0:
                t0 = max(t0, t)
            else:
                t1 = min(t1, t)
    return t0 <= t1


def _route_around_house(origin, start: np.ndarray, goal: np.ndarray) -> list[np.ndarray]:
    """Waypoints from the door front to ``goal`` that go round the house instead of through it."""
    ox, oy, oz = origin
    lo = np.array([ox - 0.5, oz - 0.5])
    hi = np.array([ox + HOUSE_SIZE + 0.5, oz + HOUSE_SIZE + 0.5])
    west = goal[0] < ox + HOUSE_SIZE / 2
    x = ox - HOUSE_CLEARANCE if west else ox + HOUSE_SIZE + HOUSE_CLEARANCE
    corners = [np.array([x, oy, oz - HOUSE_CLEARANCE]), np.array([x, oy, oz + HOUSE_SIZE + HOUSE_CLEARANCE])]
    route, here = [], start
    for corner in corners:
        if not _segment_hits_square(here, goal, lo, hi):
            break
        route.append(corner)
        here = corner
    return route + [goal]


def _build_house_phase(bot: Bot, name: str, cells, block: int, approach: bool) -> Actions:
    attempted, failed = yield from _build_cells(bot, cells, block, HOUSE_BLOCK_S, approach=approach,
                                                scaffold=HOUSE_SCAFFOLD)
    _check_build(f"buildHouse {name}", attempted, failed)


def _go_inside(bot: Bot, origin, west: bool) -> Actions:
    """Walk onto the house floor to this bot's working cell and centre on it; if its floor block is
    missing (it stood there), jump-place it."""
    sx, sz = HOUSE_STANDS[west]
    floor_cell = (origin[0] + sx, origin[1], origin[2] + sz)
    yield from bot.place_at(floor_cell, HOUSE_FLOOR, scaffold=HOUSE_SCAFFOLD)
    target = np.array([origin[0] + sx + 0.5, origin[1] + 1.0, origin[2] + sz + 0.5])
    yield from bot.goto(target, radius=0.5, timeout_s=HOUSE_WALK_S, scaffold=HOUSE_SCAFFOLD)
    if not bot.game.world.is_solid(*floor_cell):  # still a hole: step into it and fill it from inside
        yield from bot.nudge_to(target, sneak=False)
        yield from bot.idle(HOUSE_SETTLE_TICKS)
        yield from bot.place_below(HOUSE_FLOOR)
    yield from bot.nudge_to(target)


def _raise_roof(bot: Bot, origin, west: bool) -> Actions:
    """Pillar up 3 stone blocks inside, lay this half of the roof from above, then the last roof
    block under the feet: the bot ends standing on the roof."""
    for _ in HOUSE_WALL_LAYERS:
        yield from bot.place_below(HOUSE_SCAFFOLD)
    sx, sz = HOUSE_STANDS[west]
    own = (origin[0] + sx, origin[1] + HOUSE_ROOF_LAYER, origin[2] + sz)
    cells = [c for c in _house_half(_house_roof(), origin, west) if c != own]
    attempted, failed = yield from _build_cells(bot, cells, HOUSE_ROOF, HOUSE_BLOCK_S, approach=False)
    ok = yield from bot.place_below(HOUSE_ROOF)
    _check_build("buildHouse roof", attempted + 1, failed + (not ok))


def _admire_house(bot: Bot, origin) -> Actions:
    """Drop off the roof towards the door, step to the door, walk round to the shared spot and look at the house."""
    ox, oy, oz = origin
    door_front = np.array([ox + HOUSE_DOOR[0] + 0.5, oy, oz - HOUSE_CLEARANCE])
    yield from bot.goto(door_front, radius=1.0, timeout_s=HOUSE_DROP_S)
    yield from bot.goto(np.array([ox + HOUSE_DOOR[0] + 0.5, oy, oz + 0.5]), radius=1.0, timeout_s=HOUSE_DOOR_S)
    spot = _house_spot(bot, origin)
    for waypoint in [door_front] + _route_around_house(origin, door_front, spot):
        yield from bot.goto(waypoint, radius=1.0, timeout_s=HOUSE_SPOT_S)
    centre = np.array([ox + HOUSE_SIZE / 2, oy + HOUSE_LOOK_UP, oz + HOUSE_SIZE / 2])
    yield from bot.look_at(centre, CAMERA_DPS, easing=True, randomized=True)
    yield from bot.sleep(HOUSE_ADMIRE_S)


def build_house(bot: Bot) -> Actions:
    """A 5 x 5 house at the midpoint (or the nearest even site, see :func:`_house_origin`): floor, walls
    (door gap), roof; each bot builds its half (west: local x <= 2). Phases are separated by barriers and
    a 1 s pause; >50 % failures abort. Then both admire it from a shared spot."""
    yield from bot.barrier("buildHouse", pos=bot.me.pos.copy())
    other = bot.peer_payloads["buildHouse"][bot.other.name]["pos"]
    origin = _house_origin(bot.game.world, bot.me.pos, other)
    west = _is_west(bot, bot.me.pos, other)
    floor = _with_foundation(bot.game.world, _house_half(_house_floor(), origin, west))
    yield from _build_house_phase(bot, "floor", floor, HOUSE_FLOOR, True)
    yield from _go_inside(bot, origin, west)  # before the barrier: off the partner's floor cells
    yield from bot.barrier("buildHouse_walls")
    yield from bot.sleep(HOUSE_PHASE_PAUSE_S)
    yield from _build_house_phase(bot, "walls", _house_half(_house_walls(), origin, west), HOUSE_WALL, False)
    yield from bot.barrier("buildHouse_roof")
    yield from bot.sleep(HOUSE_PHASE_PAUSE_S)
    yield from _raise_roof(bot, origin, west)
    yield from bot.barrier("buildHouse_admire")
    yield from _admire_house(bot, origin)


# ---------------------------------------------------------------------------------------------
# Episode types (docs/engine.md §5.2: typical length, spawn distance min/max)
# ---------------------------------------------------------------------------------------------

EPISODE_TYPES = (
    EpisodeSpec("buildHouse", "Building", 120, 10, 20, build_house, _house_setup),
    EpisodeSpec("buildStructure", "Building", 15, 8, 15, build_structure, _structure_setup),
    EpisodeSpec("buildTower", "Building", 12, 8, 15, build_tower, _tower_setup),
    EpisodeSpec("towerBridge", "Building", 22, 12, 20, tower_bridge, _tower_setup),
)
