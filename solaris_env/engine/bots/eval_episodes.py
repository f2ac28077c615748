"""The 7 eval episode types (engine-spec §6) with the sneak-signal protocol (§6, §7.1).

Every eval recording looks like: 1 s idle -> phase barrier -> sneak 5 ticks (actors only) -> 25 idle
ticks (``start_tick``) -> the scripted action -> padding to ``EPISODE_MIN_TICKS`` after start_tick.
"""

from __future__ import annotations

import math

from solaris_env.engine import constants as C
from solaris_env.engine.bots.controller import Actions, Bot
from solaris_env.engine.bots.registry import EpisodeSpec, register

EPISODE_MIN_TICKS = 300
EVAL_CAMERA_DPS = C.DEFAULT_LOOK_SPEED_DEG  # 171.8873 deg/s = 3 rad/s, constant rate, no easing


def rotation_eval(bot: Bot) -> Actions:
    """case = N mod 6: 0/1/2 Alpha turns +40/-40/180 deg, 3/4/5 Bravo does; the other stays still."""
    yield from bot.barrier("rotation_start")
    yield from bot.look_at_smooth(bot.other, 60.0, easing=False, randomized=False)
    yield from bot.barrier("rotation_look")
    case = bot.episode % 6
    rotator = "Alpha" if case < 3 else "Bravo"
    degrees = (40.0, -40.0, 180.0)[case % 3]
    bot.eval_metadata = {"bots_chosen": [rotator], "rotation_degrees": degrees,
                         "camera_speed_degrees_per_sec": EVAL_CAMERA_DPS, "case_num": case}
    if bot.name != rotator:
        yield from bot.idle(5 + 25 + EPISODE_MIN_TICKS)  # the observer keeps recording meanwhile
        return
    yield from bot.sneak_signal()
    yield from bot.turn(math.radians(degrees), EVAL_CAMERA_DPS)
    yield from bot.pad_to(EPISODE_MIN_TICKS)


register(EpisodeSpec("rotationEval", "Movement", 60, 10, 12, rotation_eval, is_eval=True, world="flat"))
