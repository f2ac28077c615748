"""What the training episode types share (docs/engine.md §5.2 "Common constants"): look speeds, eye contact,
the playable square goals stay inside, item hand-outs and tick counts."""

from __future__ import annotations

import math

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.bots.controller import Actions, Bot
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


def seconds_to_ticks(seconds: float) -> int:
    return round(seconds * C.TICKS_PER_SECOND)


def yaw_pitch_to(bot: Bot, feet) -> tuple[float, float]:
    return yaw_to(bot.me.pos, feet), pitch_to(bot.me.pos, feet)


def eye_contact(bot: Bot, seconds: float = EYE_CONTACT_S) -> Actions:
    """``lookAt`` the partner's head, then hold the gaze for ``seconds``."""
    yield from bot.look_at_player(bot.other)
    yield from bot.sleep(seconds)


def _playable_box(world: World) -> tuple[np.ndarray, float]:
    """Centre (x, z) and half side of the square that goals must stay inside."""
    ox, _, oz = world.origin
    sx, _, sz = world.shape
    centre = np.array([ox + sx / 2, oz + sz / 2])
    return centre, min(sx, sz) / 2 - PLAYABLE_MARGIN - EDGE_MARGIN


def playable_centre(world: World) -> np.ndarray:
    """The centre (x, 0, z) of the square that goals must stay inside."""
    centre, _ = _playable_box(world)
    return np.array([centre[0], 0.0, centre[1]])


def clamp_xz(world: World, point: np.ndarray) -> np.ndarray:
    centre, half = _playable_box(world)
    out = np.array(point, float)
    out[[0, 2]] = np.clip(out[[0, 2]], centre - half, centre + half)
    return out


def ray_length_in_box(world: World, start: np.ndarray, direction: np.ndarray, limit: float) -> float:
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


def give_items(bot: Bot, items: list[tuple[int, int]]) -> None:
    for item, count in items:
        _give_stacks(bot.me, item, count)
    _empty_hand(bot.me)


def floor_midpoint(a: np.ndarray, b: np.ndarray) -> tuple[int, int, int]:
    """Floor-averaged x/z of two positions and the higher feet y."""
    return (math.floor((a[0] + b[0]) / 2), math.floor(max(a[1], b[1]) + 0.01), math.floor((a[2] + b[2]) / 2))
