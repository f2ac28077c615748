"""The 7 eval episode types (docs/engine.md §6) with the sneak-signal protocol (§6.1, §7.1).

Every eval recording looks like: 1 s idle (the runner's pre-roll) -> phase barrier -> both bots look
at each other (constant rate, no easing) -> barrier -> the acting bot(s) sneak 5 ticks and idle 25
(``start_tick``) -> the scripted action -> padding until ``EPISODE_MIN_TICKS`` after start_tick.
Observers never sneak and never act during the signal; the runner keeps recording them (no-op
records) until every bot has finished. The VLM judge (``solaris_env/engine/eval_protocol.py``) finds
its frames from the first sneak run, so no bot may sneak before the signal.

Shared draws (``bot.shared_rng``) are consumed in the same order by both bots, as in the reference;
roles that depend on the episode number use ``bot.episode``.
"""

from __future__ import annotations

import math
import zlib

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.blocks import Block
from solaris_env.engine.bots.controller import MOVE_KEYS, REVERSE, Actions, Bot, act
from solaris_env.engine.bots.spec import EpisodeSpec
from solaris_env.engine.physics import horizontal_axes, pitch_to, yaw_to
from solaris_env.engine.world import World
from solaris_env.engine.worldgen import WorldConfig

EPISODE_MIN_TICKS = 300
EVAL_CAMERA_DPS = C.DEFAULT_LOOK_SPEED_DEG  # 171.8873 deg/s = 3 rad/s, constant rate, no easing


def _names(bot: Bot) -> list[str]:
    return sorted(p.name for p in bot.game.players)


def _look_at_each_other(bot: Bot, phase: str, dps: float = EVAL_CAMERA_DPS) -> Actions:
    """Phase barrier, constant-rate feet-to-feet look at the partner, then a barrier so signals start together."""
    yield from bot.barrier(f"{phase}_phase", pos=bot.me.pos.copy())
    yield from bot.look_at_smooth(bot.other, dps, easing=False, randomized=False)
    yield from bot.barrier(f"{phase}_signal")


def _turn_to(bot: Bot, yaw: float, pitch: float) -> Actions:
    """The eval ``lookSmooth``: shortest arc at 171.9 deg/s, no easing, no randomisation."""
    yield from bot.look(yaw, pitch, EVAL_CAMERA_DPS, easing=False, randomized=False)


# ---------------------------------------------------------------------------------------------
# rotationEval (docs/engine.md §6.2)
# ---------------------------------------------------------------------------------------------

ROTATION_CASES = (40.0, -40.0, 180.0)  # degrees, Mineflayer sign (+ = left)


def rotation_eval(bot: Bot) -> Actions:
    """case = N mod 6: 0/1/2 the lower name turns +40/-40/180 deg, 3/4/5 the bigger name does; the other stays still."""
    yield from _look_at_each_other(bot, "rotationEval")
    case = bot.episode % 6
    rotator = _names(bot)[0 if case < 3 else 1]
    degrees = ROTATION_CASES[case % 3]
    bot.eval_metadata = {"bots_chosen": [rotator], "rotation_degrees": degrees,
                         "camera_speed_degrees_per_sec": EVAL_CAMERA_DPS, "case_num": case}
    if bot.name != rotator:
        return  # the observer keeps recording (no-ops) until the rotator has padded
    yield from bot.sneak_signal()
    yield from bot.turn(math.radians(degrees), EVAL_CAMERA_DPS)  # keeps the pitch
    yield from bot.pad_to(EPISODE_MIN_TICKS)


# ---------------------------------------------------------------------------------------------
# translationEval (docs/engine.md §6.2)
# ---------------------------------------------------------------------------------------------

WALK_DISTANCE = (6.0, 9.0)  # blocks, U(min, max)
ALIGN_TIMEOUT_S = 10.0
ALIGN_RADIUS = 0.5  # GoalXZ: end inside the target column


def _align(bot: Bot) -> Actions:
    """Walk to share the partner's x (if |dx| < |dz|) or z, then wait 5 ticks (recorded, before the signal)."""
    me, other = bot.me.pos, bot.other.pos
    dx, dz = abs(other[0] - me[0]), abs(other[2] - me[2])
    goal = np.array([other[0], me[1], me[2]]) if dx < dz else np.array([me[0], me[1], other[2]])
    yield from bot.goto(goal, radius=ALIGN_RADIUS, timeout_s=ALIGN_TIMEOUT_S, sprint=True)  # pathfinder sprints
    yield from bot.idle(5)


def translation_eval(bot: Bot) -> Actions:
    """One bot aligns on an axis with the other; the walker (lower name if N even) walks 6-9 blocks with a
    random WASD key and back with the reverse key."""
    lower = _names(bot)[0]
    aligner = lower if bot.shared_rng.random() < 0.5 else _names(bot)[1]
    bot.shared_rng.random()  # the reference draws its run-action count (always 1) here
    if bot.name == aligner:
        yield from _align(bot)
    yield from _look_at_each_other(bot, "translationEval")
    mode = ("lower_name_walks", "bigger_name_walks")[bot.episode % 2]
    walker = _names(bot)[bot.episode % 2]
    bot.eval_metadata = {"bots_chosen": [walker], "mode": mode, "camera_speed_degrees_per_sec": EVAL_CAMERA_DPS,
                         "min_run_actions": 1, "max_run_actions": 1}
    if bot.name != walker:
        return
    yield from bot.sneak_signal()
    yield from bot.sleep(bot.rng.uniform(0.2, 0.5))
    key = MOVE_KEYS[int(bot.rng.integers(len(MOVE_KEYS)))]
    start = bot.me.pos.copy()
    yield from bot.walk(key, bot.rng.uniform(*WALK_DISTANCE), timeout_s=5.0)
    yield from bot.walk_back(REVERSE[key], start, tolerance=1.0, timeout_s=5.0)
    yield from bot.pad_to(EPISODE_MIN_TICKS)


# ---------------------------------------------------------------------------------------------
# oneLooksAwayEval / bothLookAwayEval (docs/engine.md §6.2)
# ---------------------------------------------------------------------------------------------

LOOK_AWAY_FREEZE_TICKS = 60


def _look_away(bot: Bot, mode: str, actors: list[str]) -> Actions:
    """Shared draws dir and offset; each actor turns by the net shortest arc pi + offset (90 +- 22.5 deg), freezes
    60 ticks, turns back and pads."""
    direction = -1 if bot.shared_rng.random() < 0.5 else 1
    offset_deg = 90.0 * direction + bot.shared_rng.random() * 45.0 - 22.5
    bot.eval_metadata = {"bots_chosen": actors, "mode": mode, "camera_speed_degrees_per_sec": EVAL_CAMERA_DPS,
                         "look_away_offset_deg": offset_deg, "look_away_direction": direction,
                         "freeze_ticks": LOOK_AWAY_FREEZE_TICKS}
    if bot.name not in actors:
        return
    yield from bot.sneak_signal()
    yaw0, pitch0 = bot.me.yaw, bot.me.pitch
    yield from _turn_to(bot, yaw0 + math.pi + math.radians(offset_deg), pitch0)
    yield from bot.idle(LOOK_AWAY_FREEZE_TICKS)
    yield from _turn_to(bot, yaw0, pitch0)
    yield from bot.pad_to(EPISODE_MIN_TICKS)


def one_looks_away_eval(bot: Bot) -> Actions:
    """The lower name looks away if N is even, the bigger name if odd; the other keeps looking."""
    yield from _look_at_each_other(bot, "oneLooksAwayEval")
    mode = ("lower_name_looks_away", "bigger_name_looks_away")[bot.episode % 2]
    yield from _look_away(bot, mode, [_names(bot)[bot.episode % 2]])


def both_look_away_eval(bot: Bot) -> Actions:
    """Both bots apply the same signed look-away turn simultaneously."""
    yield from _look_at_each_other(bot, "bothLookAwayEval")
    yield from _look_away(bot, "both_look_away", _names(bot))


# ---------------------------------------------------------------------------------------------
# structureEval (docs/engine.md §6.2)
# ---------------------------------------------------------------------------------------------

STRUCTURE_TYPES = ("wall_2x2", "wall_4x1", "tower_2x1")
STRUCTURE_BLOCKS = {"stone": Block.STONE}
# Offsets (dx, dy, dz) from the base B = floor(builder spawn) + (1, 0, 0); walls grow along +x.
STRUCTURE_OFFSETS = {
    "wall_2x2": tuple((dx, dy, 0) for dy in range(2) for dx in range(2)),
    "wall_4x1": tuple((dx, 0, 0) for dx in range(4)),
    "tower_2x1": tuple((0, dy, 0) for dy in range(2)),
}
PRE_SIGNAL_TICKS = 15  # builder: after equipping stone; observer: stands still
POST_SIGNAL_TICKS = 10
EYE_CONTACT_TICKS = 4
LOOK_SETTLE_TICKS = 18  # reference: wait after looking at the face to click
BLOCK_DELAY_TICKS = 4  # reference getBlockPlaceDelayTicks; the observer waits blocks x this
PLACE_TRIES = 5
STANDOFF_BLOCKS = 1.0  # feet this far in front (-z) of the cell being placed: clear of it, within reach
FRONT_DISTANCE = 6
FRONT_TIMEOUT_S = 10.0
ADMIRE_TICKS = 4


def structure_base(builder_spawn: np.ndarray) -> tuple[int, int, int]:
    """B = floor(builder spawn) + (1, 0, 0)."""
    x, y, z = (math.floor(c) for c in builder_spawn)
    return x + 1, y, z


def structure_cells(structure: str, base: tuple[int, int, int]) -> list[tuple[int, int, int]]:
    """The world cells of a structure built at ``base``."""
    return [(base[0] + dx, base[1] + dy, base[2] + dz) for dx, dy, dz in STRUCTURE_OFFSETS[structure]]


def structure_length(structure: str) -> int:
    """Width seen from the front (along x)."""
    return max(dx for dx, _, _ in STRUCTURE_OFFSETS[structure]) + 1


def _build_order(cells: list[tuple[int, int, int]], pos: np.ndarray) -> list[tuple[int, int, int]]:
    """Bottom-up, then far-to-near from ``pos`` (so a ray never crosses a placed block), then west to east."""
    def dist(c):
        return float(np.linalg.norm(np.array(c, float) + 0.5 - pos))

    return sorted(cells, key=lambda c: (c[1], -round(dist(c) * 2) / 2, c[0]))


def _side_step(bot: Bot, target: np.ndarray, tol: float = 0.15, timeout_ticks: int = 60) -> Actions:
    """Walk to ``target`` (xz) with WASD in the body frame, camera still, releasing the keys early enough that
    the ground slide (``v / (1 - friction)``) ends there; returns once stopped within ``tol``."""
    slide = 1.0 / (1.0 - C.GROUND_FRICTION)
    for _ in range(timeout_ticks):
        p = bot.me
        rest = (target - p.pos)[[0, 2]] - p.vel[[0, 2]] * slide  # where we still need to go after the slide
        if np.hypot(*rest) <= tol:
            if np.hypot(*p.vel[[0, 2]]) < 1e-3:
                return True
            yield act()
            continue
        fwd, left = (v[[0, 2]] for v in horizontal_axes(p.yaw))
        f, l = float(rest @ fwd), float(rest @ left)
        n = math.hypot(f, l)
        keys = {}
        if abs(f) > 0.38 * n:
            keys["forward" if f > 0 else "back"] = 1
        if abs(l) > 0.38 * n:
            keys["left" if l > 0 else "right"] = 1
        yield act(**keys)
    return False


def _place_block(bot: Bot, cell: tuple[int, int, int], block: int) -> Actions:
    """Stand one block in front (-z) of the cell, look at the top face of the block below (default speed),
    settle, then click ``use`` while sneaking. Returns whether the block stands there.

    Adaptation: the reference stands diagonally (x-1, z-1), where the ray to the face centre grazes the
    corner of the neighbouring cell; straight in front, the ray only crosses the cell's own column.
    """
    world = bot.game.world
    x, y, z = cell
    yield from _side_step(bot, np.array([x + 0.5, bot.me.pos[1], z - STANDOFF_BLOCKS]))
    face = np.array([x + 0.5, float(y), z + 0.5])  # top face of the support block
    for _ in range(PLACE_TRIES):
        if world.get(*cell) == block:
            return True
        yield from bot.look_at(face)
        yield from bot.idle(LOOK_SETTLE_TICKS)
        yield from bot.select(block)
        yield act(use=1, sneak=1)
        if world.get(*cell) != block:
            yield from bot.idle(BLOCK_DELAY_TICKS)
    return world.get(*cell) == block


def _path_blocked(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether the straight xz segment a -> b passes through the box [lo, hi] (xz only)."""
    for t in np.linspace(0.0, 1.0, 41):
        p = a + t * (b - a)
        if lo[0] <= p[0] <= hi[0] and lo[2] <= p[2] <= hi[2]:
            return True
    return False


def _walk_to_front(bot: Bot, goal: np.ndarray, cells: list[tuple[int, int, int]]) -> Actions:
    """Go to ``goal`` (GoalNear 1, <= 10 s), detouring around the structure's footprint if the line crosses it."""
    lo = np.array(cells, float).min(axis=0) - 0.8
    hi = np.array(cells, float).max(axis=0) + 1.8
    waypoints = [goal]
    if _path_blocked(bot.me.pos, goal, lo, hi):
        wx = lo[0] - 0.5 if bot.me.pos[0] < (lo[0] + hi[0]) / 2 else hi[0] + 0.5
        waypoints = [np.array([wx, goal[1], bot.me.pos[2]]), np.array([wx, goal[1], goal[2]]), goal]
    deadline = bot.tick + round(FRONT_TIMEOUT_S * C.TICKS_PER_SECOND)
    for k, w in enumerate(waypoints):
        radius = 1.0 if k == len(waypoints) - 1 else 0.8
        yield from bot.goto(w, radius=radius, timeout_s=max(0, deadline - bot.tick) / C.TICKS_PER_SECOND)


def structure_eval(bot: Bot) -> Actions:
    """A shared draw picks the builder; it signals, looks at the observer, builds wall_2x2 / wall_4x1 /
    tower_2x1 of stone at B growing +x; both then walk to (B.x + length/2 +- 1, B.z - 6) and look at it."""
    names = _names(bot)
    yield from _look_at_each_other(bot, "structureEval")
    spawn = bot.peer_payloads["structureEval_phase"]
    role_mode = ("alpha_builds", "bravo_builds")[int(bot.shared_rng.random() * 2)]
    builder = names[0] if role_mode == "alpha_builds" else names[1]
    observer = names[1] if builder == names[0] else names[0]
    is_builder = bot.name == builder
    base = structure_base(spawn[builder]["pos"])
    if is_builder:
        yield from bot.select(Block.STONE)
        yield from bot.idle(PRE_SIGNAL_TICKS)
        yield from bot.sneak_signal()
        yield from bot.idle(POST_SIGNAL_TICKS)
        yield from bot.look_at(bot.other.pos + np.array([0.0, bot.other.height, 0.0]))
    else:
        yield from bot.idle(PRE_SIGNAL_TICKS + POST_SIGNAL_TICKS)
    yield from bot.idle(EYE_CONTACT_TICKS)

    structure = STRUCTURE_TYPES[int(bot.shared_rng.random() * len(STRUCTURE_TYPES))]
    block_name = tuple(STRUCTURE_BLOCKS)[int(bot.shared_rng.random() * len(STRUCTURE_BLOCKS))]
    bot.eval_metadata = {"structure_type": structure, "block_type": block_name, "builder_bot": builder,
                         "observer_bot": observer, "role_assignment_mode": role_mode}
    cells = structure_cells(structure, base)
    if is_builder:
        for cell in _build_order(cells, bot.me.pos):
            yield from _place_block(bot, cell, STRUCTURE_BLOCKS[block_name])
            yield from bot.idle(BLOCK_DELAY_TICKS)
    else:
        yield from bot.idle(len(cells) * BLOCK_DELAY_TICKS)  # stays completely still

    center_x = base[0] + structure_length(structure) / 2
    front = np.array([center_x + (1.0 if is_builder else -1.0), bot.me.pos[1], base[2] - FRONT_DISTANCE])
    yield from _walk_to_front(bot, front, cells)
    view = np.array([center_x, float(base[1]), float(base[2])])
    yield from _turn_to(bot, yaw_to(bot.me.pos, view), pitch_to(bot.me.pos, view))  # lookAtSmooth: feet to point
    yield from bot.idle(ADMIRE_TICKS)
    if is_builder:
        yield from bot.pad_to(EPISODE_MIN_TICKS)


# ---------------------------------------------------------------------------------------------
# turnToLookEval / turnToLookOppositeEval (docs/engine.md §6.2)
# ---------------------------------------------------------------------------------------------

TP_POINT_COUNT = 55  # the reference's tp_points list length; the point is tp_points[N mod 55]
TP_OFFSET = 2  # lower name at P - 2 axis, other at P + 2 axis (4 blocks apart)
TP_POINTS_SEED = 55_2025  # fixed seed of the candidate order
TP_MIN_SPACING = 8.0  # blocks between candidate points, so that N mod 55 picks different scenery
TP_GROUND = np.array([Block.GRASS, Block.DIRT, Block.STONE, Block.SAND, Block.SNOW, Block.GRAVEL], np.uint8)
TURN_TO_LOOK_FACE_DPS = 90.0  # the initial look at each other


def turn_to_look_points(world: World, margin: int = WorldConfig().margin) -> list[tuple[int, int, int]]:
    """Up to 55 standable points (x, feet y, z) of ``world``, deterministic for a given world.

    A point qualifies when the 5-block cross P + k*axis (k = -2..2, both axes) is dry, stands on
    natural ground (not leaves) at one height, with two free blocks above: both players and the
    line of sight between them fit on either axis. Qualifying points are shuffled with a fixed seed
    and taken greedily at least ``TP_MIN_SPACING`` apart. Our stand-in for the reference's 55 fixed
    points of its "solaris" world.
    """
    solid = world.solid_XYZ
    X, Y, Z = solid.shape
    top = Y - 1 - np.argmax(solid[:, ::-1, :], axis=1)  # (X, Z) array y of the highest solid block
    ix, iz = np.arange(X)[:, None], np.arange(Z)[None, :]
    ground = world.blocks_XYZ[ix, top, iz]
    feet = world.blocks_XYZ[ix, np.minimum(top + 1, Y - 1), iz]
    ok = np.isin(ground, TP_GROUND) & (feet == Block.AIR) & (top + 2 < Y) & solid[ix, top, iz]
    lo = margin + TP_OFFSET
    good = np.zeros_like(ok)
    inner = (slice(lo, X - lo), slice(lo, Z - lo))
    good[inner] = ok[inner]
    for d in range(-TP_OFFSET, TP_OFFSET + 1):
        for sx, sz in ((d, 0), (0, d)):
            shifted = (slice(lo + sx, X - lo + sx), slice(lo + sz, Z - lo + sz))
            good[inner] &= ok[shifted] & (top[shifted] == top[inner])
    cand = np.argwhere(good)
    cand = cand[np.random.default_rng(TP_POINTS_SEED).permutation(len(cand))]
    chosen: list[np.ndarray] = []
    for c in cand:
        if all(np.hypot(*(c - p)) >= TP_MIN_SPACING for p in chosen):
            chosen.append(c)
            if len(chosen) == TP_POINT_COUNT:
                break
    ox, oy, oz = world.origin
    return [(int(i) + ox, int(top[i, k]) + 1 + oy, int(k) + oz) for i, k in chosen]


def tp_axis_is_x(episode: int) -> bool:
    """The reference's ``seedrandom("<N>_tp")() > 0.5`` (X axis), with our deterministic string-seeded draw."""
    return np.random.default_rng(zlib.crc32(f"{episode}_tp".encode())).random() > 0.5


def turn_to_look_setup(bot: Bot) -> None:
    """Teleport both players (the lower name does it) around P = points[N mod 55]: lower at P - 2 axis,
    other at P + 2 axis, facing each other (setup happens before recording)."""
    if not bot.is_lower:
        return
    points = turn_to_look_points(bot.game.world)
    if not points:
        raise RuntimeError(f"turnToLook: no standable point pair in world seed {bot.game.world.seed}")
    px, py, pz = points[(bot.episode % TP_POINT_COUNT) % len(points)]
    axis = np.array([1.0, 0.0, 0.0]) if tp_axis_is_x(bot.episode) else np.array([0.0, 0.0, 1.0])
    center = np.array([px + 0.5, float(py), pz + 0.5])
    lower, other = bot.me, bot.other
    for p, sign in ((lower, -1.0), (other, 1.0)):
        p.pos = center + sign * TP_OFFSET * axis
        p.vel = np.zeros(3)
        p.on_ground = True
    for p, q in ((lower, other), (other, lower)):
        p.yaw = yaw_to(p.pos, q.pos) % (2 * math.pi)
        p.pitch = pitch_to(p.pos, q.pos)


def _turn_to_look(bot: Bot, same_side: bool, phase: str) -> Actions:
    """Both look at each other (90 deg/s), both sneak, both turn 90 deg to the side vector s = rot90(n) * dir."""
    yield from bot.barrier(f"{phase}_phase", pos=bot.me.pos.copy())
    yield from bot.idle(2)  # the reference clears controls and waits 2 ticks
    yield from bot.look_at_smooth(bot.other, TURN_TO_LOOK_FACE_DPS, easing=False, randomized=False)
    yield from bot.barrier(f"{phase}_signal")
    yield from bot.sneak_signal()
    me, them = bot.me.pos.copy(), bot.other.pos.copy()
    n = (them - me)[[0, 2]]
    n = n / (np.hypot(*n) or 1.0)
    direction = (1 if bot.is_lower else -1) if same_side else 1
    side = np.array([-n[1] * direction, n[0] * direction])
    bot.eval_metadata = {"camera_speed_degrees_per_sec": EVAL_CAMERA_DPS,
                         "side_vector": {"x": float(side[0]) + 0.0, "z": float(side[1]) + 0.0}, "dir": direction}
    face = me + np.array([side[0], 0.0, side[1]])
    yield from _turn_to(bot, yaw_to(me, face), pitch_to(me, face))
    yield from bot.pad_to(EPISODE_MIN_TICKS)


def turn_to_look_eval(bot: Bot) -> Actions:
    """Same side: dir = +1 for the lower name, -1 for the other -> both face the same world direction."""
    yield from _turn_to_look(bot, True, "turnToLookEval")


def turn_to_look_opposite_eval(bot: Bot) -> Actions:
    """dir = +1 for both -> they face opposite world directions."""
    yield from _turn_to_look(bot, False, "turnToLookOppositeEval")


# ---------------------------------------------------------------------------------------------
# Episode types (spawn distances of the reference classes; typical length 60 s)
# ---------------------------------------------------------------------------------------------

EPISODE_TYPES = (
    EpisodeSpec("rotationEval", "Movement", 60, 10, 12, rotation_eval, is_eval=True, world="flat"),
    EpisodeSpec("translationEval", "Movement", 60, 10, 12, translation_eval, is_eval=True, world="flat"),
    EpisodeSpec("oneLooksAwayEval", "Grounding", 60, 10, 12, one_looks_away_eval, is_eval=True, world="flat"),
    EpisodeSpec("bothLookAwayEval", "Memory", 60, 10, 12, both_look_away_eval, is_eval=True, world="flat"),
    EpisodeSpec("structureEval", "Building", 60, 6, 6, structure_eval, is_eval=True, world="flat"),
    EpisodeSpec("turnToLookEval", "Consistency", 60, 4, 4, turn_to_look_eval, setup=turn_to_look_setup,
                is_eval=True, world="normal"),
    EpisodeSpec("turnToLookOppositeEval", "Consistency", 60, 4, 4, turn_to_look_opposite_eval,
                setup=turn_to_look_setup, is_eval=True, world="normal"),
)
