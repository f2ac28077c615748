"""Mining training types (docs/engine.md §5.3): mine, collector, placeAndMine (whose setup re-teleports both
bots to a site it finds)."""

from __future__ import annotations

import math

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.blocks import Block, Item
from solaris_env.engine.bots.controller import Actions, Bot, EpisodeAbort
from solaris_env.engine.bots.spec import EpisodeSpec
from solaris_env.engine.bots.training_episodes.common import (
    BOT_LOOK_DPS,
    clamp_xz,
    eye_contact,
    floor_midpoint,
    give_items,
    seconds_to_ticks,
)
from solaris_env.engine.physics import face
from solaris_env.engine.world import World


def _feet_cell(bot: Bot) -> tuple[int, int, int]:
    p = bot.me.pos
    return math.floor(p[0]), math.floor(p[1] + 0.01), math.floor(p[2])


TORCHES = 64  # mine gets 64 torches, collector twice as many
MINE_DOWN_PAUSE_S, MINE_FALL_S = 0.5, 0.8
MINE_RADIUS = 1.6  # GoalNear(1.6)
MINE_TIMEOUT_S = 60.0


def _mine_setup(bot: Bot) -> None:
    give_items(bot, [(Block.TORCH, TORCHES)])


def mine(bot: Bot) -> Actions:
    """Dig one block down, then tunnel to one block below the midpoint of both holes, and make eye contact."""
    yield from bot.barrier("mine")
    yield from eye_contact(bot)
    yield from bot.select(Item.DIAMOND_PICKAXE)
    yield from bot.look(bot.me.yaw, -C.PITCH_LIMIT)
    yield from bot.sleep(MINE_DOWN_PAUSE_S)
    x, y, z = _feet_cell(bot)
    dug = yield from bot.dig((x, y - 1, z))
    yield from bot.sleep(MINE_FALL_S)
    if not dug or bot.me.pos[1] > y - 0.5:
        raise EpisodeAbort("mine: digging down failed")
    yield from bot.barrier("mine_underground", pos=bot.me.pos.copy())
    other = bot.peer_payloads["mine_underground"][bot.other.name]["pos"]
    mine_pos = bot.me.pos
    goal = np.array([math.floor((mine_pos[0] + other[0]) / 2) + 0.5,
                     math.floor((mine_pos[1] + other[1]) / 2 + 0.01) - 1.0,
                     math.floor((mine_pos[2] + other[2]) / 2) + 0.5])
    yield from bot.tunnel_to(goal, MINE_RADIUS, MINE_TIMEOUT_S)
    yield from eye_contact(bot)


COLLECTOR_CYCLES = 10
COLLECTOR_BUDGET_S = 140.0  # no new task starts after this (keeps the episode under max_s)
COLLECTOR_MIN_CYCLE_S = 5.0  # a cycle needs at least this much budget left to start
COLLECTOR_GRACE_S = 12.0  # the follower waits this long past the budget for the leader's last task
COLLECTOR_TASKS = 2  # a new random task, then the same task again
COLLECTOR_MIN_TICKS = 40
COLLECTOR_FOLLOW_S = 74.0
COLLECTOR_FOLLOW_RADIUS = 2.0
COLLECTOR_TORCH_EVERY_S = 5.0
COLLECTOR_TORCH_S = 2.4
COLLECTOR_TORCH_REACH = 2  # torches go at most this many blocks away
COLLECTOR_DIRECTIONAL_PROB = 0.6
COLLECTOR_MOVE_MIN, COLLECTOR_MOVE_MAX = 5, 8  # blocks (both the directional and staircase legs)
COLLECTOR_MOVE_S = 10.0
COLLECTOR_STAIRS_FLOOR = 5  # staircases stop this many blocks above the world's bottom
ORE_SCAN_RADIUS = math.ceil(C.REACH)  # "visible" ores: an exposed face within reach
ORE_MAX = 8
ORE_DIG_S = 8.0
VALUABLE_ORES = (Block.COAL_ORE, Block.IRON_ORE, Block.DIAMOND_ORE)
CARDINALS = ((1, 0), (-1, 0), (0, 1), (0, -1))


def _collector_setup(bot: Bot) -> None:
    give_items(bot, [(Block.TORCH, 2 * TORCHES)])


def _place_torch_near(bot: Bot, seconds: float = COLLECTOR_TORCH_S) -> Actions:
    """Put a torch on the ground within 2 blocks (nearest free spot first), trying for at most ``seconds``."""
    world = bot.game.world
    x0, y0, z0 = _feet_cell(bot)
    spots = [(x0 + dx, y0 + dy, z0 + dz) for dx in range(-COLLECTOR_TORCH_REACH, COLLECTOR_TORCH_REACH + 1)
             for dz in range(-COLLECTOR_TORCH_REACH, COLLECTOR_TORCH_REACH + 1) for dy in (0, -1, 1)
             if (dx, dz) != (0, 0)]
    spots.sort(key=lambda c: abs(c[0] - x0) + abs(c[2] - z0) + abs(c[1] - y0))
    end = bot.tick + seconds_to_ticks(seconds)
    for cell in spots:
        if bot.tick >= end:
            return False
        if world.get(*cell) != Block.AIR or not world.is_solid(cell[0], cell[1] - 1, cell[2]):
            continue
        if (yield from bot.place_at(cell, Block.TORCH, attempts=1, approach=False)):
            return True
    return False


def _visible_ores(bot: Bot) -> list[tuple[int, int, int]]:
    """Valuable ores with a face the bot can see within reach, nearest first (at most 8)."""
    world = bot.game.world
    ox, oy, oz = world.origin
    x, y, z = _feet_cell(bot)
    lo = np.maximum(np.array([x - ox, y - oy, z - oz]) - ORE_SCAN_RADIUS, 0)
    hi = np.minimum(np.array([x - ox, y - oy, z - oz]) + ORE_SCAN_RADIUS + 1, world.shape)
    box = world.blocks_XYZ[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    found = np.argwhere(np.isin(box, np.array(VALUABLE_ORES, np.uint8))) + lo + np.array([ox, oy, oz])
    cells = sorted((tuple(int(v) for v in c) for c in found),
                   key=lambda c: (c[0] - x) ** 2 + (c[1] - y) ** 2 + (c[2] - z) ** 2)
    visible = []
    for cell in cells:
        if len(visible) == ORE_MAX:
            break
        if bot.visible_point(cell) is not None:
            visible.append(cell)
    return visible


def _collector_move(bot: Bot, kind: str) -> Actions:
    """60 %: walk 5-8 blocks in a random cardinal direction (digging through); 40 %: dig a staircase
    5-8 down and 5-8 across."""
    dx, dz = CARDINALS[int(bot.rng.integers(len(CARDINALS)))]
    across = float(bot.rng.integers(COLLECTOR_MOVE_MIN, COLLECTOR_MOVE_MAX + 1))
    here = bot.me.pos
    goal = clamp_xz(bot.game.world, here + across * np.array([dx, 0.0, dz]))
    if kind == "directional":
        yield from bot.goto(goal, radius=1.0, timeout_s=COLLECTOR_MOVE_S, dig=True)
        return
    down = float(bot.rng.integers(COLLECTOR_MOVE_MIN, COLLECTOR_MOVE_MAX + 1))
    goal[1] = max(math.floor(here[1] + 0.01) - down, bot.game.world.origin[1] + COLLECTOR_STAIRS_FLOOR)
    yield from bot.tunnel_to(goal, radius=1.0, timeout_s=COLLECTOR_MOVE_S)


def _collector_lead(bot: Bot, cycle: int, end: int) -> Actions:
    """Two tasks (torch, visible ores, then a move of one random kind), at least 40 ticks, then ``done``.
    Nothing new is started after tick ``end`` (the episode's time budget)."""
    start = bot.tick
    kind = "directional" if bot.rng.random() < COLLECTOR_DIRECTIONAL_PROB else "staircase"
    for _ in range(COLLECTOR_TASKS):
        if bot.tick >= end:
            break
        yield from _place_torch_near(bot)
        for ore in _visible_ores(bot):
            if bot.tick >= end:
                break
            yield from bot.dig(ore, timeout_s=ORE_DIG_S)
        if bot.tick < end:
            yield from _collector_move(bot, kind)
    yield from bot.idle(start + COLLECTOR_MIN_TICKS - bot.tick)
    bot.post(f"collector_done_{cycle}")


def _collector_follow(bot: Bot, cycle: int, end: int) -> Actions:
    """Follow the leader (GoalFollow 2); every 5 s stop, place a torch and look at it; stop at its
    ``done`` (or after 74 s, or once the episode's budget ``end`` has passed)."""
    done = lambda: bot.received(f"collector_done_{cycle}") is not None  # noqa: E731
    stop = min(bot.tick + seconds_to_ticks(COLLECTOR_FOLLOW_S), end + seconds_to_ticks(COLLECTOR_GRACE_S))
    while bot.tick < stop and not done():
        leg = min(seconds_to_ticks(COLLECTOR_TORCH_EVERY_S), stop - bot.tick)
        if (yield from bot.follow(bot.other, COLLECTOR_FOLLOW_RADIUS, leg, until=done, dig=True)):
            break
        yield from _place_torch_near(bot)
        yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)


def collector(bot: Bot) -> Actions:
    """Up to 10 cycles; each cycle a shared draw picks the leader, who collects while the other follows.

    Adaptation: cycles stop at a time budget so the episode stays under ``max_s``.
    """
    yield from bot.barrier("collector")
    end = bot.tick + seconds_to_ticks(COLLECTOR_BUDGET_S)
    for cycle in range(COLLECTOR_CYCLES):
        yield from bot.barrier(f"collector_{cycle}")
        if bot.tick + seconds_to_ticks(COLLECTOR_MIN_CYCLE_S) > end:  # same tick on both bots: they agree
            break
        lower_leads = bot.shared_rng.random() < 0.5
        if lower_leads == bot.is_lower:
            yield from _collector_lead(bot, cycle, end)
        else:
            yield from _collector_follow(bot, cycle, end)


PAM_LAYOUT = "placeAndMine_layout"
PAM_SEARCH_RADIUS = 15
PAM_SEARCH_DY = 5
PAM_HALF_STRIP = 2  # strips are 5 long: centre +- 2
PAM_STAND = 2  # builder and miner stand centre +- 2 along the observation axis
PAM_BLOCKS = (Block.STONE, Block.OAK_PLANKS, Block.BRICKS, Block.DIRT, Block.SMOOTH_SANDSTONE)
PAM_MIN_ROUNDS, PAM_ROUND_CHOICES = 7, 4  # rounds = 7 + floor(rng * 4)
PAM_MAX_BLOCKS = 5
PAM_GAP_MIN_S, PAM_GAP_MAX_S = 0.4, 0.8
PAM_PAUSE_S = 0.5
PAM_EXTRA_MIN_S, PAM_EXTRA_MAX_S = 0.5, 1.0
PAM_LOOK_S = 1.0


def _standable(world: World, x: int, y: int, z: int) -> bool:
    return world.is_solid(x, y - 1, z) and world.get(x, y, z) == Block.AIR and world.get(x, y + 1, z) == Block.AIR


def _strip_clear(world: World, x: int, y: int, z: int, axis: int) -> bool:
    """A 5-long strip through (x, z) along ``axis`` of solid ground with two air blocks above."""
    ax, az = (1, 0) if axis == 0 else (0, 1)
    return all(_standable(world, x + k * ax, y, z + k * az) for k in range(-PAM_HALF_STRIP, PAM_HALF_STRIP + 1))


def _stands_ok(world: World, x: int, y: int, z: int, axis: int) -> bool:
    ax, az = (1, 0) if axis == 0 else (0, 1)
    return all(_standable(world, x + s * PAM_STAND * ax, y, z + s * PAM_STAND * az) for s in (-1, 1))


def _find_site(world: World, cx: int, cz: int, y_ref: int):
    """Ring-by-ring search for a cross of clear strips (priority 0), else one clear strip whose
    perpendicular has standable ends (priority 2: the miner clears it). Returns (x, y, z, priority, forced axis)."""
    fallback = None
    for r in range(PAM_SEARCH_RADIUS + 1):
        ring = [(cx + dx, cz + dz) for dx in range(-r, r + 1) for dz in range(-r, r + 1) if max(abs(dx), abs(dz)) == r]
        for x, z in ring:
            y = world.surface_y(x, z)
            if abs(y - y_ref) > PAM_SEARCH_DY:
                continue
            clear = [_strip_clear(world, x, y, z, axis) for axis in (0, 2)]
            if all(clear):
                return x, y, z, 0, None
            if fallback is None and any(clear):
                obs = 2 if clear[0] else 0  # observe along the axis that is not clear
                if _stands_ok(world, x, y, z, obs):
                    fallback = (x, y, z, 2, obs)
    return fallback


def _place_and_mine_setup(bot: Bot) -> None:
    """Give the blocks; the first bot finds the site and teleports both (Alpha's role in the reference).

    Both bots draw the same three shared numbers (axis, side, builder) so their RNGs stay in step.
    """
    give_items(bot, [(b, C.STACK_SIZE) for b in PAM_BLOCKS if b != Block.STONE])
    u_axis, u_side, u_builder = bot.shared_rng.random(3)
    if bot.mailbox.get(PAM_LAYOUT) is not None:
        return
    a, b = bot.game.players[0], bot.game.players[1]
    mx, my, mz = floor_midpoint(a.pos, b.pos)
    site = _find_site(bot.game.world, mx, mz, my)
    if site is None:
        bot.post(PAM_LAYOUT, ok=False)
        return
    x, y, z, priority, forced = site
    obs = forced if priority else (0 if u_axis < 0.5 else 2)
    side = 1 if u_side < 0.5 else -1
    names = sorted(p.name for p in bot.game.players)
    builder = names[int(u_builder * len(names))]
    o = np.array([1.0, 0.0, 0.0]) if obs == 0 else np.array([0.0, 0.0, 1.0])
    centre = np.array([x + 0.5, float(y), z + 0.5])
    for p in (a, b):
        p.pos = centre + o * (PAM_STAND * side if p.name == builder else -PAM_STAND * side)
        p.vel = np.zeros(3)
        p.on_ground = True
    face(a, b)
    face(b, a)
    bot.post(PAM_LAYOUT, ok=True, centre=(x, y, z), obs=obs, priority=priority, builder=builder)


def _pam_positions(bot: Bot, layout: dict) -> list[tuple[int, int, int]]:
    """Cells on the activity axis for this round's count (1: c; 2: c + a neighbour; 3: c+-1; 4: +-1 and one
    of +-2; 5: c+-2), at feet level."""
    count = int(bot.rng.integers(1, PAM_MAX_BLOCKS + 1))
    pick = 1 if bot.rng.random() < 0.5 else -1
    offsets = {1: [0], 2: [0, pick], 3: [-1, 0, 1], 4: [-1, 0, 1, 2 * pick], 5: [-2, -1, 0, 1, 2]}[count]
    x, y, z = layout["centre"]
    ax, az = (0, 1) if layout["obs"] == 0 else (1, 0)
    return [(x + k * ax, y, z + k * az) for k in offsets]


def _pam_build(bot: Bot, layout: dict) -> Actions:
    block = PAM_BLOCKS[int(bot.rng.integers(len(PAM_BLOCKS)))]
    placed = []
    for cell in _pam_positions(bot, layout):
        if (yield from bot.place_at(cell, block, attempts=3, approach=False)):
            placed.append(cell)
        yield from bot.sleep(bot.rng.uniform(PAM_GAP_MIN_S, PAM_GAP_MAX_S))
    yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)
    yield from bot.sleep(PAM_PAUSE_S + bot.rng.uniform(PAM_EXTRA_MIN_S, PAM_EXTRA_MAX_S))
    return placed


def _pam_mine(bot: Bot, cells) -> Actions:
    yield from bot.select(Item.DIAMOND_PICKAXE)
    yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)
    for cell in cells:
        yield from bot.dig(tuple(cell))
        yield from bot.sleep(bot.rng.uniform(PAM_GAP_MIN_S, PAM_GAP_MAX_S))
    yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)
    yield from bot.sleep(PAM_PAUSE_S + bot.rng.uniform(PAM_EXTRA_MIN_S, PAM_EXTRA_MAX_S))


def _pam_clear_line(bot: Bot, layout: dict) -> Actions:
    """Priority-2 sites: the miner digs the blocks between the two stands (feet and head level)."""
    x, y, z = layout["centre"]
    ax, az = (1, 0) if layout["obs"] == 0 else (0, 1)
    for k in range(-PAM_HALF_STRIP, PAM_HALF_STRIP + 1):
        for dy in (1, 0):
            cell = (x + k * ax, y + dy, z + k * az)
            if bot.game.world.is_solid(*cell):
                yield from bot.dig(cell)


def place_and_mine(bot: Bot) -> Actions:
    """7-10 rounds 4 blocks apart: the builder places 1-5 blocks between them, the miner digs them out."""
    layout = bot.mailbox.get(PAM_LAYOUT)
    if layout is None or not layout["ok"]:
        raise EpisodeAbort("placeAndMine: no location")
    yield from bot.barrier("placeAndMine")
    rounds = PAM_MIN_ROUNDS + int(bot.shared_rng.random() * PAM_ROUND_CHOICES)
    builder = layout["builder"] == bot.name
    yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)
    yield from bot.sleep(PAM_LOOK_S)
    if layout["priority"] and not builder:
        yield from _pam_clear_line(bot, layout)
    for r in range(rounds):
        yield from bot.barrier(f"placeAndMine_build_{r}")
        placed = (yield from _pam_build(bot, layout)) if builder else []
        yield from bot.barrier(f"placeAndMine_mine_{r}", cells=placed)
        if not builder:
            yield from _pam_mine(bot, bot.peer_payloads[f"placeAndMine_mine_{r}"][bot.other.name]["cells"])


# ---------------------------------------------------------------------------------------------
# Episode types (docs/engine.md §5.2: typical length, spawn distance min/max)
# ---------------------------------------------------------------------------------------------

EPISODE_TYPES = (
    EpisodeSpec("collector", "Mining", 150, 0, 15, collector, _collector_setup),
    EpisodeSpec("mine", "Mining", 10, 10, 15, mine, _mine_setup),
    EpisodeSpec("placeAndMine", "Mining", 120, 4, 8, place_and_mine, _place_and_mine_setup),
)
