"""Combat training types (docs/engine.md §5.3): pvp, pve. Our engine has no mobs, so pve's "mobs" are sparring
bouts against the partner: both leave their guard posts, meet, fight with swords for a shared bout length,
walk back to their posts and look at the other post."""

from __future__ import annotations

import numpy as np

from solaris_env.engine.blocks import Item
from solaris_env.engine.bots.controller import Actions, Bot
from solaris_env.engine.bots.spec import EpisodeSpec
from solaris_env.engine.bots.training_episodes.common import (
    CAMERA_DPS,
    FAST_LOOK_DPS,
    give_items,
    seconds_to_ticks,
    yaw_pitch_to,
)

SWORDS = (Item.WOODEN_SWORD, Item.STONE_SWORD, Item.IRON_SWORD, Item.GOLDEN_SWORD, Item.DIAMOND_SWORD,
          Item.NETHERITE_SWORD)


def _sword(bot: Bot) -> int:
    return next(it for it, _ in bot.me.hotbar if it in SWORDS)


def _give_sword(bot: Bot) -> None:
    """pvp/pve setup: one random sword (private choice, ``Math.random``), empty hand."""
    give_items(bot, [(SWORDS[int(bot.rng.integers(len(SWORDS)))], 1)])


PVP_MIN_MS, PVP_SPAN_MS = 10000, 5001  # fight length = 10000 + floor(rng * 5001) ms
PVP_PAUSE_S = 0.5


def pvp(bot: Bot) -> Actions:
    """Look at each other, equip the sword, fight for 10-15 s (hits are ``attack`` once-flags)."""
    yield from bot.barrier("pvp")
    ticks = seconds_to_ticks((PVP_MIN_MS + int(bot.shared_rng.random() * PVP_SPAN_MS)) / 1000)
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
    yield from bot.look(*yaw_pitch_to(bot, other_guard), CAMERA_DPS, easing=True, randomized=True)
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
        fight_ticks = seconds_to_ticks(bot.shared_rng.uniform(PVE_FIGHT_MIN_S, PVE_FIGHT_MAX_S))
        yield from bot.select(_sword(bot))
        yield from bot.follow(bot.other, PVE_ENGAGE_DIST / 2, seconds_to_ticks(PVE_ENGAGE_S), until=near)
        yield from bot.barrier(f"pve_engage_{k}")
        yield from bot.fight(bot.other, fight_ticks)
        yield from _return_to_guard(bot, guard, other_guard)


# ---------------------------------------------------------------------------------------------
# Episode types (docs/engine.md §5.2: typical length, spawn distance min/max)
# ---------------------------------------------------------------------------------------------

EPISODE_TYPES = (
    EpisodeSpec("pve", "Combat", 60, 15, 25, pve, _give_sword),
    EpisodeSpec("pvp", "Combat", 15, 8, 15, pvp, _give_sword),
)
