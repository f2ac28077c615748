"""The 14 training episode types (engine-spec §5.2), as per-bot choreographies."""

from __future__ import annotations

import math

from solaris_env.engine.bots.controller import MOVE_KEYS, REVERSE, Actions, Bot
from solaris_env.engine.bots.registry import EpisodeSpec, register

JUMP_PROB = 0.25
CAMERA_DPS = 60.0


def _random_walk(bot: Bot, distance: float) -> Actions:
    """The reference ``walk``: pick a WASD key, go ``distance`` blocks (<= 5 s), come back with the reverse key."""
    yield from bot.sleep(bot.rng.uniform(0.2, 0.5))
    key = MOVE_KEYS[int(bot.rng.integers(4))]
    start = bot.me.pos.copy()
    yield from bot.walk(key, distance, timeout_s=5.0, jump_prob=JUMP_PROB)
    yield from bot.walk_back(REVERSE[key], start, tolerance=1.0, timeout_s=5.0, jump_prob=JUMP_PROB)


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
                yield from _random_walk(bot, bot.rng.uniform(3.0, 4.0))


def _yaw_pitch_to(bot: Bot, feet) -> tuple[float, float]:
    from solaris_env.engine.physics import pitch_to, yaw_to

    return yaw_to(bot.me.pos, feet), pitch_to(bot.me.pos, feet)


register(EpisodeSpec("walkLook", "Movement", 60, 10, 15, walk_look))
