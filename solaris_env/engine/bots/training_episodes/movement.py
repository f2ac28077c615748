"""Movement training types (docs/engine.md §5.3): walkLook, walkLookAway, straightLineWalk, chase, orbit, and
our opt-in lookAround, approach and roam. Goals far away (chase's 100 blocks) are clipped to the world's playable
square."""

from __future__ import annotations

import math

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.bots.controller import MAX_TURN_RAD, MOVE_KEYS, REVERSE, Actions, Bot, act
from solaris_env.engine.bots.spec import EpisodeSpec
from solaris_env.engine.bots.training_episodes.common import (
    ACTION_SLEEP_MAX_S,
    ACTION_SLEEP_MIN_S,
    BOT_LOOK_DPS,
    CAMERA_DPS,
    FAST_LOOK_DPS,
    JUMP_PROB,
    RETURN_TOLERANCE,
    WALK_MAX,
    WALK_MIN,
    WALK_TIMEOUT_S,
    clamp_xz,
    playable_centre,
    ray_length_in_box,
    seconds_to_ticks,
    yaw_pitch_to,
)
from solaris_env.engine.physics import Player


def _random_walk(bot: Bot, distance: float) -> Actions:
    """The reference ``walk``: pick a WASD key, go ``distance`` blocks (<= 5 s), come back with the reverse key."""
    yield from bot.sleep(bot.rng.uniform(ACTION_SLEEP_MIN_S, ACTION_SLEEP_MAX_S))
    key = MOVE_KEYS[int(bot.rng.integers(4))]
    start = bot.me.pos.copy()
    yield from bot.walk(key, distance, timeout_s=WALK_TIMEOUT_S, jump_prob=JUMP_PROB)
    yield from bot.walk_back(REVERSE[key], start, tolerance=RETURN_TOLERANCE, timeout_s=WALK_TIMEOUT_S,
                             jump_prob=JUMP_PROB)


def walk_look(bot: Bot) -> Actions:
    """3 iterations: agree on a mode, look at each other, walker(s) do 2-4 random walks (pure WASD)."""
    for it in range(3):
        yield from bot.barrier(f"walkLook_{it}", pos=bot.me.pos.copy())
        action_count = 2 + int(bot.shared_rng.random() * 3)
        mode = ("both_bots_walk", "lower_name_walks", "bigger_name_walks")[int(bot.shared_rng.random() * 3)]
        other_pos = bot.peer_payloads[f"walkLook_{it}"][bot.other.name]["pos"]
        yield from bot.look(*yaw_pitch_to(bot, other_pos), CAMERA_DPS, easing=True, randomized=True)
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


# ---------------------------------------------------------------------------------------------
# roam (ours, opt-in): the envs' step actions, each held for many steps
# ---------------------------------------------------------------------------------------------

ROAM_TICKS = 800  # ~40 s per bot
ROAM_STEP_TICKS = 4  # the envs' default ticks per step: segments are whole steps, each step's turn on its first ticks
ROAM_SEGMENT_STEPS = (4, 24)  # each segment holds one key set and one per-step turn this many steps
ROAM_KEYS = ((), ("forward",), ("forward",), ("forward", "sprint"), ("back",), ("left",), ("right",),
             ("forward", "left"), ("forward", "right"), ("jump",), ("forward", "jump"))
ROAM_STILL_PROB = 0.5  # segments whose camera holds still
ROAM_TURN_DEG = (1.0, 15.0)  # |yaw turn per step| of the others, either sign
ROAM_PITCH_PROB = 0.25  # a turning segment that also pitches (|pitch per step| up to half the yaw range)
ROAM_FACE_PROB = 0.15  # a segment that first looks at the partner (the partner in view while it moves)
ROAM_SPEED_BPS = 1.4  # blocks per step at most (sprinting): a walk that would leave the box turns inward first


def _move_direction(bot: Bot, keys: tuple[str, ...]) -> np.ndarray | None:
    """The unit xz direction the held WASD keys walk in (Mineflayer yaw: facing = (-sin, 0, -cos))."""
    f = np.array([-math.sin(bot.me.yaw), 0.0, -math.cos(bot.me.yaw)])
    r = np.array([-f[2], 0.0, f[0]])  # facing turned 90 deg to the right
    d = f * (("forward" in keys) - ("back" in keys)) + r * (("right" in keys) - ("left" in keys))
    n = float(np.linalg.norm(d))
    return d / n if n > 0 else None


def _step_turns(turn_rad: float) -> list[float]:
    """One step's turn as the envs split it over the step's ticks (``spaces.step_ticks``): up to the per-tick cap
    from the first tick on, on the 0.15-degree mouse grid."""
    q = math.radians(C.LOOK_STEP_DEG)
    n, cap = round(turn_rad / q), math.floor(MAX_TURN_RAD / q + 1e-9)
    out = []
    for _ in range(ROAM_STEP_TICKS):
        m = int(np.clip(n, -cap, cap))
        out.append(m * q)
        n -= m
    return out


def _roam_segment(bot: Bot) -> Actions:
    """One segment: a key set and a per-step yaw (and sometimes pitch) turn, held for 4-24 steps of 4 ticks."""
    rng = bot.rng
    steps = int(rng.integers(ROAM_SEGMENT_STEPS[0], ROAM_SEGMENT_STEPS[1] + 1))
    keys = ROAM_KEYS[int(rng.integers(len(ROAM_KEYS)))]
    direction = _move_direction(bot, keys)
    if direction is not None:
        room = ray_length_in_box(bot.game.world, bot.me.pos, direction, steps * ROAM_SPEED_BPS)
        if room < ROAM_SEGMENT_STEPS[0] * ROAM_SPEED_BPS:  # the box edge is near: face its centre, walk on
            yield from bot.look(yaw_pitch_to(bot, playable_centre(bot.game.world))[0], 0.0, BOT_LOOK_DPS)
            keys = ("forward",) + tuple(k for k in keys if k in ("sprint", "jump"))
        else:
            steps = min(steps, max(ROAM_SEGMENT_STEPS[0], int(room / ROAM_SPEED_BPS)))
    dyaw = dpitch = 0.0
    if rng.random() >= ROAM_STILL_PROB:
        dyaw = math.radians(rng.uniform(*ROAM_TURN_DEG)) * (1 if rng.random() < 0.5 else -1)
        if rng.random() < ROAM_PITCH_PROB:
            dpitch = math.radians(rng.uniform(0.0, ROAM_TURN_DEG[1] / 2)) * (1 if rng.random() < 0.5 else -1)
    held = {k: 1 for k in keys}
    limit = math.radians(LOOK_AROUND_PITCH_MAX_DEG)
    for _ in range(steps):
        for ty, tp in zip(_step_turns(dyaw), _step_turns(dpitch)):
            tp = tp if abs(bot.me.pitch + tp) <= limit else 0.0
            yield act((ty, tp), **held)


def roam(bot: Bot) -> Actions:
    """Both bots hold the envs' step actions for ~40 s: segments of 4-24 steps that each keep one key set (walking,
    sprinting, backing, strafing, jumping, or none) and one per-step turn (none half the time, else 1-15 deg per
    step either way), now and then after a look at the partner. Not a reference type: world-model data with the
    long held actions a user or an RL policy sends (the reference mix holds a still-camera forward for ~3 steps)."""
    yield from bot.barrier("roam")
    yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)
    start = bot.game.tick
    while bot.game.tick - start < ROAM_TICKS:
        if bot.rng.random() < ROAM_FACE_PROB:
            yield from bot.look_at_player(bot.other, BOT_LOOK_DPS)
        yield from _roam_segment(bot)


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
        yield from bot.look(*yaw_pitch_to(bot, bot.peer_payloads[name][bot.other.name]["pos"]), CAMERA_DPS,
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
    goal = clamp_xz(bot.game.world, other + d * beyond)
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
        yield from bot.track(bot.other, seconds_to_ticks(STRAIGHT_TIMEOUT_S), BOT_LOOK_DPS, until=arrived)


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
        run = ray_length_in_box(bot.game.world, bot.me.pos, d, CHASE_RUN_DIST)
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
    ticks = seconds_to_ticks((CHASE_MIN_MS + int(bot.shared_rng.random() * CHASE_SPAN_MS)) / 1000)
    if chaser:
        yield from bot.follow(bot.other, CHASE_RADIUS, ticks, sprint=True,
                              refresh_ticks=seconds_to_ticks(CHASE_REFRESH_S))
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
# approach (ours, opt-in): close-range views of the partner for the judges
# ---------------------------------------------------------------------------------------------

APPROACH_ROUNDS = 3
APPROACH_STOP = (0.6, 2.0)  # the walker stops this far (blocks, feet to feet) from the watcher
APPROACH_TIMEOUT_S = 8.0
APPROACH_HOLD_S = (0.5, 2.0)  # face to face this long, the camera on the partner
APPROACH_BACK_S = (1.0, 3.0)  # then backs away this long, still looking at the partner
APPROACH_SPRINT_PROB = 0.3
APPROACH_WATCH_PROB = 0.5  # the watcher faces the walker; otherwise it looks a random way (back and side views)


def approach(bot: Bot) -> Actions:
    """3 rounds: the walker (shared draw) walks up to the watcher until 0.6-2 blocks apart, faces it, then backs
    away looking at it; the watcher stands and either tracks the walker or turns a random way and stays so (the
    walker then sees its back or side). Not a reference type: the avatar seen from every distance and side down
    to filling the view, as an RL seeker of ``approach_partner`` sees a partner that stands still."""
    for it in range(APPROACH_ROUNDS):
        name = f"approach_{it}"
        yield from bot.barrier(name)
        lower_walks = int(bot.shared_rng.random() * 2) == 0
        if lower_walks == bot.is_lower:
            stop = bot.rng.uniform(*APPROACH_STOP)
            yield from bot.goto(bot.other.pos.copy(), radius=stop, timeout_s=APPROACH_TIMEOUT_S,
                                sprint=bot.rng.random() < APPROACH_SPRINT_PROB)
            yield from bot.track(bot.other, seconds_to_ticks(bot.rng.uniform(*APPROACH_HOLD_S)), BOT_LOOK_DPS)
            yield from bot.track(bot.other, seconds_to_ticks(bot.rng.uniform(*APPROACH_BACK_S)), BOT_LOOK_DPS,
                                 back=1)
            bot.post(f"{name}_done")
        else:
            done = lambda n=name: bot.received(f"{n}_done") is not None
            ticks = seconds_to_ticks(APPROACH_TIMEOUT_S + APPROACH_HOLD_S[1] + APPROACH_BACK_S[1])
            if bot.rng.random() < APPROACH_WATCH_PROB:
                yield from bot.track(bot.other, ticks, BOT_LOOK_DPS, until=done)
            else:
                yield from bot.look(bot.me.yaw + bot.rng.uniform(-math.pi, math.pi), 0.0, BOT_LOOK_DPS)
                start = bot.tick
                while not done() and bot.tick - start < ticks:
                    yield from bot.idle(1)


# ---------------------------------------------------------------------------------------------
# Episode types (docs/engine.md §5.2: typical length, spawn distance min/max)
# ---------------------------------------------------------------------------------------------

EPISODE_TYPES = (
    EpisodeSpec("chase", "Movement", 10, 10, 15, chase),
    EpisodeSpec("orbit", "Movement", 60, 10, 15, orbit),
    EpisodeSpec("straightLineWalk", "Movement", 20, 10, 15, straight_line_walk),
    EpisodeSpec("walkLook", "Movement", 60, 10, 15, walk_look),
    EpisodeSpec("walkLookAway", "Movement", 60, 10, 15, walk_look_away),
    EpisodeSpec("lookAround", "Movement", 30, 6, 12, look_around, in_default_mix=False),
    EpisodeSpec("approach", "Movement", 20, 6, 12, approach, in_default_mix=False),
    EpisodeSpec("roam", "Movement", 40, 6, 12, roam, in_default_mix=False),
)
