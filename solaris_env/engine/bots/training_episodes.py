"""The 14 training episode types (docs/engine.md §5.3), as per-bot choreographies.

Each type is a generator ``behaviour(bot)`` run by both bots, plus an optional ``setup(bot)`` that hands
out items (and, for placeAndMine, re-teleports) before recording starts. Decisions both bots must agree
on are drawn from ``bot.shared_rng`` at the same points on both; private choices use ``bot.rng``.

Adaptations to our engine (it has no Mineflayer pathfinder and no mobs):

* Pathfinder goals become :meth:`Bot.goto` (steering, step jumps, ``dig=True`` for ``canDig``),
  :meth:`Bot.tunnel_to` (digging goals), :meth:`Bot.bridge` (scaffolding) and :meth:`Bot.place_below`
  (1x1 towers). Timeouts are the spec's.
* Goals far away (chase's 100 blocks) are clipped to the world's playable square.
* pve sparring: with no hostile mobs, each "mob" is a sparring bout against the partner: both leave
  their guard posts, meet, fight with swords for a shared bout length, walk back to their posts and look
  at the other post.
* buildHouse: bots raise the walls from inside the house and the roof from a 3-block stone pillar
  inside it (scaffolding, left in place like the pathfinder's), finishing on the roof; the roof's
  last block is placed under their feet. Then they drop off the roof towards the door.
"""

from __future__ import annotations

import math

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.blocks import Block, Item
from solaris_env.engine.bots.controller import MAX_TURN_RAD, MOVE_KEYS, REVERSE, Actions, Bot, EpisodeAbort, act
from solaris_env.engine.bots.registry import EpisodeSpec, register
from solaris_env.engine.bots.runner import face
from solaris_env.engine.physics import Player, pitch_to, yaw_to
from solaris_env.engine.world import World
from solaris_env.engine.worldgen import WorldConfig

# Common constants (docs/engine.md §5.2).
JUMP_PROB = 0.25
CAMERA_DPS = 60.0  # lookAtSmooth speed
BOT_LOOK_DPS = 90.0  # lookAtBot speed
FAST_LOOK_DPS = 180.0  # the reference's 180 deg/s looks; randomized, hence clipped to <= 171 deg/s
WALK_MIN, WALK_MAX = 3.0, 4.0  # random-walk distance (blocks)
WALK_TIMEOUT_S = 5.0
RETURN_TOLERANCE = 1.0  # blocks: a walk back ends this close to its start
ACTION_SLEEP_MIN_S, ACTION_SLEEP_MAX_S = 0.2, 0.5
EYE_CONTACT_S = 1.5
PLAYABLE_MARGIN = WorldConfig().margin  # keep goals this far inside the world box (fog hides the edge)
EDGE_MARGIN = 2.0  # and this much further in, so a goal is never on the playable border itself
SWORDS = (Item.WOODEN_SWORD, Item.STONE_SWORD, Item.IRON_SWORD, Item.GOLDEN_SWORD, Item.DIAMOND_SWORD,
          Item.NETHERITE_SWORD)


def _ticks(seconds: float) -> int:
    return round(seconds * C.TICKS_PER_SECOND)


# ---------------------------------------------------------------------------------------------
# Shared helpers
# ---------------------------------------------------------------------------------------------


def _yaw_pitch_to(bot: Bot, feet) -> tuple[float, float]:
    return yaw_to(bot.me.pos, feet), pitch_to(bot.me.pos, feet)


def _eye_contact(bot: Bot, seconds: float = EYE_CONTACT_S) -> Actions:
    """``lookAt`` the partner's head, then hold the gaze for ``seconds``."""
    yield from bot.look_at_player(bot.other)
    yield from bot.sleep(seconds)


def _feet_cell(bot: Bot) -> tuple[int, int, int]:
    p = bot.me.pos
    return math.floor(p[0]), math.floor(p[1] + 0.01), math.floor(p[2])


def _playable_box(world: World) -> tuple[np.ndarray, float]:
    """Centre (x, z) and half side of the square that goals must stay inside."""
    ox, _, oz = world.origin
    sx, _, sz = world.shape
    centre = np.array([ox + sx / 2, oz + sz / 2])
    return centre, min(sx, sz) / 2 - PLAYABLE_MARGIN - EDGE_MARGIN


def _clamp_xz(world: World, point: np.ndarray) -> np.ndarray:
    centre, half = _playable_box(world)
    out = np.array(point, float)
    out[[0, 2]] = np.clip(out[[0, 2]], centre - half, centre + half)
    return out


def _ray_length_in_box(world: World, start: np.ndarray, direction: np.ndarray, limit: float) -> float:
    """How far (<= ``limit``) one can go from ``start`` along the unit xz ``direction`` inside the playable box."""
    centre, half = _playable_box(world)
    t = limit
    for k, a in enumerate((0, 2)):
        d = direction[a]
        if abs(d) > 1e-9:
            bound = centre[k] + math.copysign(half, d)
            t = min(t, (bound - start[a]) / d)
    return max(0.0, t)


def _give_stacks(p: Player, item: int, count: int) -> None:
    """Put ``count`` items into empty hotbar slots, a full stack per slot (e.g. 128 torches = 2 slots)."""
    while count > 0:
        slot = next((s for s in p.hotbar if s[0] == 0), None)
        if slot is None:
            return
        n = min(C.STACK_SIZE, count)
        slot[0], slot[1] = int(item), n
        count -= n


def _empty_hand(p: Player) -> None:
    """Select an empty hotbar slot (the reference empties the hand after giving the items)."""
    for s, (item, _) in enumerate(p.hotbar):
        if item == 0:
            p.selected_slot = s
            return


def _give_items(bot: Bot, items: list[tuple[int, int]]) -> None:
    for item, count in items:
        _give_stacks(bot.me, item, count)
    _empty_hand(bot.me)


def _sword(bot: Bot) -> int:
    return next(it for it, _ in bot.me.hotbar if it in SWORDS)


def _give_sword(bot: Bot) -> None:
    """pvp/pve setup: one random sword (private choice, ``Math.random``), empty hand."""
    _give_items(bot, [(SWORDS[int(bot.rng.integers(len(SWORDS)))], 1)])


def _random_walk(bot: Bot, distance: float) -> Actions:
    """The reference ``walk``: pick a WASD key, go ``distance`` blocks (<= 5 s), come back with the reverse key."""
    yield from bot.sleep(bot.rng.uniform(ACTION_SLEEP_MIN_S, ACTION_SLEEP_MAX_S))
    key = MOVE_KEYS[int(bot.rng.integers(4))]
    start = bot.me.pos.copy()
    yield from bot.walk(key, distance, timeout_s=WALK_TIMEOUT_S, jump_prob=JUMP_PROB)
    yield from bot.walk_back(REVERSE[key], start, tolerance=RETURN_TOLERANCE, timeout_s=WALK_TIMEOUT_S,
                             jump_prob=JUMP_PROB)


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


def _floor_midpoint(a: np.ndarray, b: np.ndarray) -> tuple[int, int, int]:
    """Floor-averaged x/z of two positions and the higher feet y."""
    return (math.floor((a[0] + b[0]) / 2), math.floor(max(a[1], b[1]) + 0.01), math.floor((a[2] + b[2]) / 2))


# ---------------------------------------------------------------------------------------------
# Movement: walkLook, walkLookAway, straightLineWalk, chase, orbit
# ---------------------------------------------------------------------------------------------


def walk_look(bot: Bot) -> Actions:
    """3 iterations: agree on a mode, look at each other, walker(s) do 2-4 random walks (pure WASD)."""
    for it in range(3):
        yield from bot.barrier(f"walkLook_{it}", pos=bot.me.pos.copy())
        action_count = 2 + int(bot.shared_rng.random() * 3)
        mode = ("both_bots_walk", "lower_name_walks", "bigger_name_walks")[int(bot.shared_rng.random() * 3)]
        other_pos = bot.peer_payloads[f"walkLook_{it}"][bot.other.name]["pos"]
        yield from bot.look(*_yaw_pitch_to(bot, other_pos), CAMERA_DPS, easing=True, randomized=True)
        walks = mode == "both_bots_walk" or (mode == "lower_name_walks") == bot.is_lower
        if walks:
            for _ in range(action_count):
                yield from _random_walk(bot, bot.rng.uniform(WALK_MIN, WALK_MAX))


# ---------------------------------------------------------------------------------------------
# lookAround (ours, opt-in): action coverage for the world model
# ---------------------------------------------------------------------------------------------

LOOK_AROUND_TICKS = 600  # ~30 s per bot
LOOK_AROUND_SEGMENT_TICKS = (2, 16)  # each segment holds one camera rate and one key set this long
LOOK_AROUND_PITCH_MAX_DEG = 30.0  # pitch stays within +-this: the horizon remains in view
LOOK_AROUND_FACE_PROB = 0.15  # a segment that looks back at the partner instead (keeps it on screen often)
LOOK_AROUND_KEYS = ((), ("forward",), ("forward",), ("back",), ("left",), ("right",), ("forward", "jump"))


def _look_around_segment(bot: Bot) -> Actions:
    """One segment: a camera mode (still / constant turn / a single-tick turn every 4 ticks, the dream env's
    per-step turn) drawn at random, keys drawn at random, for 2-16 ticks."""
    rng = bot.rng
    ticks = int(rng.integers(LOOK_AROUND_SEGMENT_TICKS[0], LOOK_AROUND_SEGMENT_TICKS[1] + 1))
    keys = {k: 1 for k in LOOK_AROUND_KEYS[int(rng.integers(len(LOOK_AROUND_KEYS)))]}
    mode = rng.choice(("still", "turn", "turn", "impulse"))
    q = math.radians(C.LOOK_STEP_DEG)
    cap = round(MAX_TURN_RAD / q)  # in 0.15-degree steps
    yaw_rate = int(rng.integers(-cap, cap + 1)) * q
    pitch_rate = int(rng.integers(-cap // 2, cap // 2 + 1)) * q if rng.random() < 0.3 else 0.0
    limit = math.radians(LOOK_AROUND_PITCH_MAX_DEG)
    for t in range(ticks):
        moving = mode == "turn" or (mode == "impulse" and t % 4 == 0)
        dyaw = yaw_rate if moving else 0.0
        dpitch = pitch_rate if moving and abs(bot.me.pitch + pitch_rate) <= limit else 0.0
        yield act((dyaw, dpitch), **keys)


def look_around(bot: Bot) -> Actions:
    """Both bots turn and walk at random for ~30 s: camera turns that start, stop and change rate at random
    (the history of a clip does not predict them), now and then a look back at the partner. Not a reference
    type: world-model data whose camera actions are the only explanation of the view's motion."""
    yield from bot.barrier("lookAround")
    yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)
    start = bot.game.tick
    while bot.game.tick - start < LOOK_AROUND_TICKS:
        if bot.rng.random() < LOOK_AROUND_FACE_PROB:
            yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)
        else:
            yield from _look_around_segment(bot)


LOOK_AWAY_SPREAD_DEG = 90.0  # walkLookAway turns to yaw + 180 deg + U(-90, 90) deg


def _walk_looking_away(bot: Bot) -> Actions:
    """``walk(lookAway=true)``: turn away, walk 3-4 blocks, come back (turn around or reverse key), turn back."""
    yaw0, pitch0 = bot.me.yaw, bot.me.pitch
    away = yaw0 + math.pi + math.radians(bot.rng.uniform(-LOOK_AWAY_SPREAD_DEG, LOOK_AWAY_SPREAD_DEG))
    yield from bot.look(away, pitch0, CAMERA_DPS, easing=True, randomized=True)
    yield from bot.sleep(bot.rng.uniform(ACTION_SLEEP_MIN_S, ACTION_SLEEP_MAX_S))
    key = MOVE_KEYS[int(bot.rng.integers(4))]
    start = bot.me.pos.copy()
    yield from bot.walk(key, bot.rng.uniform(WALK_MIN, WALK_MAX), timeout_s=WALK_TIMEOUT_S, jump_prob=JUMP_PROB)
    if bot.rng.random() < 0.5:  # (a) turn around and walk back with the same key
        yield from bot.turn(math.pi, CAMERA_DPS, easing=True)
        back_key = key
    else:  # (b) walk back with the reverse key
        back_key = REVERSE[key]
    yield from bot.walk_back(back_key, start, tolerance=RETURN_TOLERANCE, timeout_s=WALK_TIMEOUT_S,
                             jump_prob=JUMP_PROB)
    yield from bot.look(yaw0, pitch0, CAMERA_DPS, easing=True, randomized=True)


def walk_look_away(bot: Bot) -> Actions:
    """3 iterations: agree on the walker (lower or bigger name), look at each other, the walker walks looking away."""
    for it in range(3):
        name = f"walkLookAway_{it}"
        yield from bot.barrier(name, pos=bot.me.pos.copy())
        lower_walks = int(bot.shared_rng.random() * 2) == 0
        yield from bot.look(*_yaw_pitch_to(bot, bot.peer_payloads[name][bot.other.name]["pos"]), CAMERA_DPS,
                            easing=True, randomized=True)
        if lower_walks == bot.is_lower:
            yield from _walk_looking_away(bot)


STRAIGHT_BEYOND_MIN, STRAIGHT_BEYOND_MAX = 4, 8  # blocks past the other bot (integers)
STRAIGHT_TIMEOUT_S = 20.0
STRAIGHT_SPRINT_PROB = 0.5


def _walk_past(bot: Bot) -> Actions:
    """Walk in a straight line to 4-8 blocks beyond the other bot, then look at it."""
    me, other = bot.me.pos, bot.other.pos
    d = (other - me) * np.array([1.0, 0.0, 1.0])
    d /= max(1e-9, float(np.linalg.norm(d)))
    beyond = float(bot.rng.integers(STRAIGHT_BEYOND_MIN, STRAIGHT_BEYOND_MAX + 1))
    goal = _clamp_xz(bot.game.world, other + d * beyond)
    sprint = bot.rng.random() < STRAIGHT_SPRINT_PROB
    yield from bot.goto(goal, radius=1.0, timeout_s=STRAIGHT_TIMEOUT_S, sprint=sprint, dig=True)
    bot.post("straightLineWalk_arrived")
    yield from bot.look_at(bot.other.eye, FAST_LOOK_DPS, randomized=True)


def straight_line_walk(bot: Bot) -> Actions:
    """One phase: the walker (lower or bigger name, shared draw) walks past the other; the other watches it."""
    yield from bot.barrier("straightLineWalk")
    lower_walks = int(bot.shared_rng.random() * 2) == 0
    if lower_walks == bot.is_lower:
        yield from _walk_past(bot)
    else:
        arrived = lambda: bot.received("straightLineWalk_arrived") is not None  # noqa: E731
        yield from bot.track(bot.other, _ticks(STRAIGHT_TIMEOUT_S), BOT_LOOK_DPS, until=arrived)


CHASE_MIN_MS, CHASE_SPAN_MS = 5000, 10001  # duration = 5000 + floor(rng * 10001) ms
CHASE_RUN_DIST = 100.0  # the runner's goal distance (clipped to the playable square)
CHASE_MIN_RUN = 8.0  # a clipped run shorter than this picks a side direction instead
CHASE_RADIUS = 3.0  # chaser: GoalNear(runner, 3)
CHASE_REFRESH_S = 1.0  # chaser: re-targets the runner every second


def _flee_goal(bot: Bot, chaser: Player) -> np.ndarray | None:
    """A goal away from the chaser inside the playable square (straight away, else to a side, else back)."""
    away = (bot.me.pos - chaser.pos) * np.array([1.0, 0.0, 1.0])
    n = float(np.linalg.norm(away))
    away = away / n if n > 1e-6 else np.array([1.0, 0.0, 0.0])
    side = 1.0 if bot.rng.random() < 0.5 else -1.0
    for turn in (0.0, side * math.pi / 2, -side * math.pi / 2, math.pi):
        c, s = math.cos(turn), math.sin(turn)
        d = np.array([c * away[0] - s * away[2], 0.0, s * away[0] + c * away[2]])
        run = _ray_length_in_box(bot.game.world, bot.me.pos, d, CHASE_RUN_DIST)
        if run >= CHASE_MIN_RUN:
            return bot.me.pos + d * run
    return None


def _run_away(bot: Bot, ticks: int) -> Actions:
    end = bot.tick + ticks
    while bot.tick < end:
        goal = _flee_goal(bot, bot.other)
        if goal is None:
            yield from bot.idle(1)
            continue
        yield from bot.goto(goal, radius=2.0, timeout_s=(end - bot.tick) / C.TICKS_PER_SECOND, sprint=True)


def chase(bot: Bot) -> Actions:
    """The primary bot chases (GoalNear 3, re-aimed every 1 s); the other sprints away for 5-15 s."""
    yield from bot.barrier("chase")
    chaser = bot.decide_primary()
    ticks = _ticks((CHASE_MIN_MS + int(bot.shared_rng.random() * CHASE_SPAN_MS)) / 1000)
    if chaser:
        yield from bot.follow(bot.other, CHASE_RADIUS, ticks, sprint=True, refresh_ticks=_ticks(CHASE_REFRESH_S))
    else:
        yield from _run_away(bot, ticks)


ORBIT_CHECKPOINTS = 8
ORBIT_RADIUS = 1.5  # GoalNear radius of a checkpoint
ORBIT_CHECKPOINT_S = 5.0
ORBIT_HOLD_S = 1.0


def orbit(bot: Bot) -> Actions:
    """Both circle their midpoint through 8 checkpoints 45 deg apart, looking at each other at each."""
    yield from bot.barrier("orbit", pos=bot.me.pos.copy())
    other = bot.peer_payloads["orbit"][bot.other.name]["pos"]
    mine = bot.me.pos.copy()
    centre = (mine + other) / 2
    radius = float(np.hypot(*(mine - other)[[0, 2]])) / 2
    angle0 = math.atan2(mine[2] - centre[2], mine[0] - centre[0])
    for k in range(1, ORBIT_CHECKPOINTS + 1):
        a = angle0 + k * 2 * math.pi / ORBIT_CHECKPOINTS
        checkpoint = centre + radius * np.array([math.cos(a), 0.0, math.sin(a)])
        yield from bot.goto(checkpoint, ORBIT_RADIUS, ORBIT_CHECKPOINT_S, sprint=True)
        yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)
        yield from bot.sleep(ORBIT_HOLD_S)


# ---------------------------------------------------------------------------------------------
# Combat: pvp, pve
# ---------------------------------------------------------------------------------------------

PVP_MIN_MS, PVP_SPAN_MS = 10000, 5001  # fight length = 10000 + floor(rng * 5001) ms
PVP_PAUSE_S = 0.5


def pvp(bot: Bot) -> Actions:
    """Look at each other, equip the sword, fight for 10-15 s (hits are ``attack`` once-flags)."""
    yield from bot.barrier("pvp")
    ticks = _ticks((PVP_MIN_MS + int(bot.shared_rng.random() * PVP_SPAN_MS)) / 1000)
    yield from bot.look_at(bot.other.eye, FAST_LOOK_DPS, randomized=True)
    yield from bot.sleep(PVP_PAUSE_S)
    yield from bot.select(_sword(bot))
    yield from bot.sleep(PVP_PAUSE_S)
    yield from bot.fight(bot.other, ticks)


PVE_MIN_BOUTS, PVE_BOUT_CHOICES = 2, 4  # numMobs = 2 + floor(rng * 4)
PVE_ENGAGE_DIST = 7.0  # "wait for a hostile within 7 blocks"
PVE_ENGAGE_S = 15.0
PVE_FIGHT_MIN_S, PVE_FIGHT_MAX_S = 3.0, 6.0  # a bout lasts this long (shared draw)
PVE_GUARD_RADIUS = 1.0
PVE_GUARD_S = 30.0
PVE_GUARD_TRIES = 2
PVE_HOLD_MIN_S, PVE_HOLD_MAX_S = 1.0, 3.0


def _return_to_guard(bot: Bot, guard: np.ndarray, other_guard: np.ndarray) -> Actions:
    """Walk back to the guard post (GoalNear 1, 30 s, 2 tries), look at the other post, hold 1-3 s."""
    for _ in range(PVE_GUARD_TRIES):
        if (yield from bot.goto(guard, PVE_GUARD_RADIUS, PVE_GUARD_S)):
            break
    yield from bot.look(*_yaw_pitch_to(bot, other_guard), CAMERA_DPS, easing=True, randomized=True)
    yield from bot.sleep(bot.rng.uniform(PVE_HOLD_MIN_S, PVE_HOLD_MAX_S))


def pve(bot: Bot) -> Actions:
    """Guard duty with sparring bouts in place of mobs (no mobs in our engine): per bout both leave their
    guard posts, meet within 7 blocks, fight with swords for a shared 3-6 s, and return to their posts."""
    yield from bot.barrier("pve", guard=bot.me.pos.copy())
    guard = bot.me.pos.copy()
    other_guard = bot.peer_payloads["pve"][bot.other.name]["guard"]
    bouts = PVE_MIN_BOUTS + int(bot.shared_rng.random() * PVE_BOUT_CHOICES)
    near = lambda: np.hypot(*(bot.other.pos - bot.me.pos)[[0, 2]]) <= PVE_ENGAGE_DIST  # noqa: E731
    for k in range(bouts):
        yield from bot.barrier(f"pve_bout_{k}")
        fight_ticks = _ticks(bot.shared_rng.uniform(PVE_FIGHT_MIN_S, PVE_FIGHT_MAX_S))
        yield from bot.select(_sword(bot))
        yield from bot.follow(bot.other, PVE_ENGAGE_DIST / 2, _ticks(PVE_ENGAGE_S), until=near)
        yield from bot.barrier(f"pve_engage_{k}")
        yield from bot.fight(bot.other, fight_ticks)
        yield from _return_to_guard(bot, guard, other_guard)


# ---------------------------------------------------------------------------------------------
# Building: buildStructure, buildTower, towerBridge, buildHouse
# ---------------------------------------------------------------------------------------------

BUILD_FAIL_FRACTION = 0.5  # more failed placements than this aborts the episode
STRUCTURES = ("wall", "tower", "platform")
STRUCTURE_BLOCKS = (Block.STONE, Block.COBBLESTONE, Block.OAK_PLANKS, Block.BRICKS)
STRUCTURE_BLOCK_S = 0.3
WALL_WIDTH, WALL_HEIGHT = 5, 2
COLUMN_HEIGHT = 2
PLATFORM_SIZE = 4
PLATFORM_WEST_MAX_X = 2  # the west builder takes local x <= 2 (12 blocks), the east one x = 3 (4)
BUILD_OFFSET = 2  # walls and columns stand this many blocks in front of their builder


def _structure_setup(bot: Bot) -> None:
    _give_items(bot, [(b, C.STACK_SIZE) for b in STRUCTURE_BLOCKS if b != Block.STONE])


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
    ox, oy, oz = _floor_midpoint(mine, other)
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
    yield from _eye_contact(bot)
    cells = _structure_cells(bot, kind, bot.me.pos.copy(), other)
    attempted, failed = yield from _build_cells(bot, cells, block, STRUCTURE_BLOCK_S)
    _check_build("buildStructure", attempted, failed)
    yield from _eye_contact(bot)


TOWER_MIN_HEIGHT, TOWER_HEIGHT_CHOICES = 8, 5  # height = 8 + floor(rng * 5)
TOWER_PITCH = -1.45  # buildTower looks down this far (rad) once
TOWER_SETTLE_S = 0.2
TOWER_BLOCK = Block.OAK_PLANKS


def _tower_setup(bot: Bot) -> None:
    _give_items(bot, [(TOWER_BLOCK, C.STACK_SIZE)])


def build_tower(bot: Bot) -> Actions:
    """Pillar up 8-12 blocks of oak planks by jump-placing; stop at the first failed level."""
    yield from bot.barrier("buildTower")
    height = TOWER_MIN_HEIGHT + int(bot.shared_rng.random() * TOWER_HEIGHT_CHOICES)
    yield from _eye_contact(bot)
    for _ in range(height):
        if not (yield from bot.place_below(TOWER_BLOCK, pitch=TOWER_PITCH)):
            break
        yield from bot.sleep(TOWER_SETTLE_S)
    yield from _eye_contact(bot)


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
    yield from bot.hold(_ticks(EYE_CONTACT_S), sneak=1)
    yield from _bridge_to_midpoint(bot, other)
    yield from bot.idle(1)  # sneak off
    yield from _eye_contact(bot)


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
    end = bot.tick + _ticks(BRIDGE_TIMEOUT_S)
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
    _give_items(bot, [(HOUSE_FLOOR, 2 * len(_house_floor())), (HOUSE_WALL, 2 * len(_house_walls())),
                      (HOUSE_ROOF, 2 * len(_house_roof()))])


def _house_origin(world: World, mine: np.ndarray, other: np.ndarray) -> tuple[int, int, int]:
    """Low corner of the house, centred on the floor-averaged midpoint at the higher bot's feet y.

    On uneven ground (normal worlds) the house moves to the nearest spot, ring by ring up to
    ``HOUSE_SITE_RADIUS`` away, whose ground varies by at most one block and has free air above; the
    floor then sits on the highest ground there (floating cells get a one-block foundation).
    """
    mx, my, mz = _floor_midpoint(mine, other)
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
    return _clamp_xz(bot.game.world, spot)


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
# Mining: mine, collector, placeAndMine
# ---------------------------------------------------------------------------------------------

TORCHES = 64  # mine gets 64 torches, collector twice as many
MINE_DOWN_PAUSE_S, MINE_FALL_S = 0.5, 0.8
MINE_RADIUS = 1.6  # GoalNear(1.6)
MINE_TIMEOUT_S = 60.0


def _mine_setup(bot: Bot) -> None:
    _give_items(bot, [(Block.TORCH, TORCHES)])


def mine(bot: Bot) -> Actions:
    """Dig one block down, then tunnel to one block below the midpoint of both holes, and make eye contact."""
    yield from bot.barrier("mine")
    yield from _eye_contact(bot)
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
    yield from _eye_contact(bot)


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
    _give_items(bot, [(Block.TORCH, 2 * TORCHES)])


def _place_torch_near(bot: Bot, seconds: float = COLLECTOR_TORCH_S) -> Actions:
    """Put a torch on the ground within 2 blocks (nearest free spot first), trying for at most ``seconds``."""
    world = bot.game.world
    x0, y0, z0 = _feet_cell(bot)
    spots = [(x0 + dx, y0 + dy, z0 + dz) for dx in range(-COLLECTOR_TORCH_REACH, COLLECTOR_TORCH_REACH + 1)
             for dz in range(-COLLECTOR_TORCH_REACH, COLLECTOR_TORCH_REACH + 1) for dy in (0, -1, 1)
             if (dx, dz) != (0, 0)]
    spots.sort(key=lambda c: abs(c[0] - x0) + abs(c[2] - z0) + abs(c[1] - y0))
    end = bot.tick + _ticks(seconds)
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
    goal = _clamp_xz(bot.game.world, here + across * np.array([dx, 0.0, dz]))
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
    stop = min(bot.tick + _ticks(COLLECTOR_FOLLOW_S), end + _ticks(COLLECTOR_GRACE_S))
    while bot.tick < stop and not done():
        leg = min(_ticks(COLLECTOR_TORCH_EVERY_S), stop - bot.tick)
        if (yield from bot.follow(bot.other, COLLECTOR_FOLLOW_RADIUS, leg, until=done, dig=True)):
            break
        yield from _place_torch_near(bot)
        yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)


def collector(bot: Bot) -> Actions:
    """Up to 10 cycles; each cycle a shared draw picks the leader, who collects while the other follows.

    Adaptation: cycles stop at a time budget so the episode stays under ``max_s``.
    """
    yield from bot.barrier("collector")
    end = bot.tick + _ticks(COLLECTOR_BUDGET_S)
    for cycle in range(COLLECTOR_CYCLES):
        yield from bot.barrier(f"collector_{cycle}")
        if bot.tick + _ticks(COLLECTOR_MIN_CYCLE_S) > end:  # same tick on both bots: they agree
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
    _give_items(bot, [(b, C.STACK_SIZE) for b in PAM_BLOCKS if b != Block.STONE])
    u_axis, u_side, u_builder = bot.shared_rng.random(3)
    if bot.mailbox.get(PAM_LAYOUT) is not None:
        return
    a, b = bot.game.players[0], bot.game.players[1]
    mx, my, mz = _floor_midpoint(a.pos, b.pos)
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
# Registry (docs/engine.md §5.2: typical length, spawn distance min/max)
# ---------------------------------------------------------------------------------------------

register(EpisodeSpec("buildHouse", "Building", 120, 10, 20, build_house, _house_setup))
register(EpisodeSpec("buildStructure", "Building", 15, 8, 15, build_structure, _structure_setup))
register(EpisodeSpec("buildTower", "Building", 12, 8, 15, build_tower, _tower_setup))
register(EpisodeSpec("chase", "Movement", 10, 10, 15, chase))
register(EpisodeSpec("collector", "Mining", 150, 0, 15, collector, _collector_setup))
register(EpisodeSpec("mine", "Mining", 10, 10, 15, mine, _mine_setup))
register(EpisodeSpec("orbit", "Movement", 60, 10, 15, orbit))
register(EpisodeSpec("placeAndMine", "Mining", 120, 4, 8, place_and_mine, _place_and_mine_setup))
register(EpisodeSpec("pve", "Combat", 60, 15, 25, pve, _give_sword))
register(EpisodeSpec("pvp", "Combat", 15, 8, 15, pvp, _give_sword))
register(EpisodeSpec("straightLineWalk", "Movement", 20, 10, 15, straight_line_walk))
register(EpisodeSpec("towerBridge", "Building", 22, 12, 20, tower_bridge, _tower_setup))
register(EpisodeSpec("walkLook", "Movement", 60, 10, 15, walk_look))
register(EpisodeSpec("walkLookAway", "Movement", 60, 10, 15, walk_look_away))
register(EpisodeSpec("lookAround", "Movement", 30, 6, 12, look_around, in_default_mix=False))
