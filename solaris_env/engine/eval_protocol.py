"""The VLM judge's frame bookkeeping over recorded eval episodes (docs/engine.md §7.1-§7.4).

Everything here reads only the per-tick record dicts the recorder writes (docs/data-format.md §3.2; only
``record["action"]`` is used): ``camera`` = [dyaw, dpitch] radians in Mineflayer's convention
(+yaw = turned LEFT, +pitch = looked UP) and the boolean keys. It reproduces which frames the judge
shows to the VLM and what answer it expects, so that our engine's eval recordings can be checked
against the judge before any video is rendered, and so that eval segment rows (``eval_ids``) start
exactly at the judge's ``frame1``.

Conventions (docs/engine.md §7.1):

* ``sneak_end(records)`` is already ``frame1``: the last index of the FIRST contiguous sneak run plus
  ``SNEAK_FRAME_START_DELAY`` (25). In our engine that is the last idle record before the scripted
  action (the bot's ``start_tick - 1``).
* A record "rotates" when ``|dyaw|`` or ``|dpitch|`` exceeds ``CAMERA_EPS`` (1e-4 rad); it is a no-op
  when additionally no boolean key is true.

Pure Python on purpose: no jax, no numpy, no engine import.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

SNEAK_FRAME_START_DELAY = 25
CAMERA_EPS = 1e-4  # rad; smaller camera deltas count as "not rotating"
EVAL_NUM_FRAMES = 257  # inference segment length (config/inference.yaml num_frames_eval)
STRUCTURE_MAX_OFFSET = 240  # structure's query frame is capped at frame1 + 240
TRANSLATION_FRAME2_OFFSET = 40  # translation's second frame = first movement record + 40
MOVE_KEYS = ("forward", "back", "left", "right")

# Eval type -> the result-directory key of docs/engine.md §7.2 (also the PROMPTS key).
EVAL_KEYS = {
    "translationEval": "translation",
    "rotationEval": "rotation",
    "oneLooksAwayEval": "one_looks_away",
    "bothLookAwayEval": "both_look_away",
    "structureEval": "structure",
    "turnToLookEval": "turn_to_look",
    "turnToLookOppositeEval": "turn_to_look_opposite",
}

_LOOK_AWAY_PROMPT = 'Here is a Minecraft screenshot. Is there another player visible on-screen? Answer with a single word: "yes", "no".'
_TURN_TO_LOOK_PROMPT = (
    "You will be shown two Minecraft screenshots. Do these two screenshots show the same scenery? Be careful and "
    "answer based on the content of the screenshots, not just the camera angles."  # no space before "Answer": as in the judge
    'Answer with a single word: "yes", "no".'
)
# The exact prompt strings of docs/engine.md §7.2, keyed like EVAL_KEYS' values.
PROMPTS = {
    "translation": (
        "Here are Minecraft screenshots showing another player on the screen. Between the first frame and the second "
        "frame, did the player being shown move closer, farther, to the left, or to the right on-screen? Answer with a "
        'single word from "closer", "farther", "left", "right", or "no motion".'
    ),
    "rotation": (
        "Here is a Minecraft screenshot potentially showing another player on the screen. Where is the player located "
        'on the screen? Answer with a single word from "left", "right", "center". If there is no player on the '
        'screen, answer "no player".'
    ),
    "one_looks_away": _LOOK_AWAY_PROMPT,
    "both_look_away": _LOOK_AWAY_PROMPT,
    "structure": (
        "Here is a Minecraft screenshot. Can you tell me whether there is a visible structure built about 6 blocks "
        'away from the player? Answer with a single word from "yes", "no".'
    ),
    "turn_to_look": _TURN_TO_LOOK_PROMPT,
    "turn_to_look_opposite": _TURN_TO_LOOK_PROMPT,
}

# Translation: the mover's held key -> how the OTHER player moves on the mover's screen (and, the
# judge assumes, on the observer's screen too).
TRANSLATION_ANSWERS = {"left": "right", "right": "left", "forward": "closer", "back": "farther"}
STRUCTURE_ANSWERS = {"wall_2x2": "yes", "wall_4x1": "yes", "tower_2x1": "yes"}

# ---------------------------------------------------------------------------------------------
# Per-record predicates
# ---------------------------------------------------------------------------------------------


def _action(record: Mapping) -> Mapping:
    return record.get("action", {})


def is_rotating(action: Mapping, eps: float = CAMERA_EPS) -> bool:
    """Whether an action record turns the camera by more than ``eps`` radians on either axis."""
    dyaw, dpitch = action.get("camera", (0.0, 0.0))
    return abs(dyaw) > eps or abs(dpitch) > eps


def is_noop(action: Mapping, eps: float = CAMERA_EPS) -> bool:
    """No boolean key true and no rotation (the judge's ``_is_noop``)."""
    if is_rotating(action, eps):
        return False
    return not any(v is True for k, v in action.items() if k != "camera")


# ---------------------------------------------------------------------------------------------
# Frame bookkeeping (docs/engine.md §7.1)
# ---------------------------------------------------------------------------------------------


def sneak_end(records: Sequence[Mapping], delay: int = SNEAK_FRAME_START_DELAY) -> int | None:
    """``frame1``: last index of the first contiguous ``sneak`` run + ``delay``; None if the bot never sneaks.

    The result may lie past the end of ``records`` (a sneak at the very end); callers check bounds.
    """
    last = None
    for i, rec in enumerate(records):
        if _action(rec).get("sneak", False):
            last = i
        elif last is not None:
            break
    return None if last is None else last + delay


def rot_end(records: Sequence[Mapping], start: int, buf: int, eps: float = CAMERA_EPS) -> int | None:
    """Last index of the first run of rotating records at or after ``start``, + ``buf``; None if none."""
    last = None
    for i in range(max(0, start), len(records)):
        if is_rotating(_action(records[i]), eps):
            last = i
        elif last is not None:
            break
    return None if last is None else last + buf


def last_action(records: Sequence[Mapping], start: int, buf: int, eps: float = CAMERA_EPS) -> int | None:
    """Last index >= ``start`` whose action is not a no-op, + ``buf``; None if all are no-ops."""
    for i in range(len(records) - 1, max(0, start) - 1, -1):
        if not is_noop(_action(records[i]), eps):
            return i + buf
    return None


def yaw_change_deg(records: Sequence[Mapping], f1: int, f2: int) -> float:
    """Net yaw turn from frame ``f1`` to ``f2``: sum of camera[0] over records (f1, f2], degrees in [-180, 180).

    Positive = turned left (Mineflayer). ``f1 > f2`` gives the negated sum over (f2, f1].
    """
    lo, hi, sign = (f1, f2, 1.0) if f1 <= f2 else (f2, f1, -1.0)
    total = sum(_action(r).get("camera", (0.0, 0.0))[0] for r in records[lo + 1 : hi + 1])
    wrapped = (sign * total + math.pi) % (2 * math.pi) - math.pi
    return math.degrees(wrapped)


def expected_rotation_answer(records: Sequence[Mapping], f1: int, f2: int) -> str | None:
    """The judge's position answer for a turn between ``f1`` and ``f2`` (None = the judge skips the episode).

    |turn| in [35, 45] deg: a left turn (positive yaw) leaves the other player on the RIGHT of the
    screen -> "right", a right turn -> "left"; |turn| in [60, 120] or [175, 185] -> "no player".
    """
    deg = yaw_change_deg(records, f1, f2)
    if 35.0 <= abs(deg) <= 45.0:
        return "left" if deg < 0 else "right"
    if 60.0 <= abs(deg) <= 120.0 or 175.0 <= abs(deg) <= 185.0:
        return "no player"
    return None


def first_movement(records: Sequence[Mapping], start: int) -> tuple[int, str] | None:
    """(index, key) of the first record at or after ``start`` holding a WASD key (forward checked first)."""
    for i in range(max(0, start), len(records)):
        action = _action(records[i])
        for key in MOVE_KEYS:
            if action.get(key, False):
                return i, key
    return None


# ---------------------------------------------------------------------------------------------
# Per-task queries (docs/engine.md §7.2)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Query:
    """One VLM question about GT frames.

    Attributes:
        bots: the bot(s) whose video the frames come from; one entry per image except translation,
            whose two frames both come from ``bots[0]``'s video.
        frames: GT frame indices, in the order the images are shown.
        expected: the answer counted correct (already mapped: structure "yes", not "wall_2x2").
        prompt_key: key into ``PROMPTS``.
        frame1: the judge's reference frame (the generated video's frame g - frame1 - 1 shows GT frame g).
        query_type: the judge's breakdown label (``player_invisible_looked_away``,
            ``player_position_turned_back`` or ``default``).
    """

    bots: tuple[str, ...]
    frames: tuple[int, ...]
    expected: str
    prompt_key: str
    frame1: int
    query_type: str = "default"


def _sneakers(records_by_bot: Mapping[str, Sequence[Mapping]]) -> dict[str, int]:
    """Bot name -> frame1, for the bots that sneak, in sorted-name order (the judge checks Alpha first)."""
    ends = {name: sneak_end(records_by_bot[name]) for name in sorted(records_by_bot)}
    return {name: f for name, f in ends.items() if f is not None}


def _first_actor(records_by_bot: Mapping[str, Sequence[Mapping]], eval_type: str) -> tuple[str, int]:
    sneakers = _sneakers(records_by_bot)
    if not sneakers:
        raise ValueError(f"{eval_type}: no bot sneaks, cannot find frame1")
    name = next(iter(sneakers))
    return name, sneakers[name]


def _require(value: int | None, what: str) -> int:
    if value is None:
        raise ValueError(f"no {what} found after frame1")
    return value


def _translation(records_by_bot, key) -> list[Query]:
    mover, f1 = _first_actor(records_by_bot, "translationEval")
    move = first_movement(records_by_bot[mover], f1)
    if move is None:
        return []  # the judge skips an episode without movement
    mv, held = move
    f2 = mv + TRANSLATION_FRAME2_OFFSET
    return [Query((name,), (f1, f2), TRANSLATION_ANSWERS[held], key, f1) for name in sorted(records_by_bot)]


def _rotation(records_by_bot, key) -> list[Query]:
    rotator, f1 = _first_actor(records_by_bot, "rotationEval")
    f2 = _require(rot_end(records_by_bot[rotator], f1, 20), "rotation")
    answer = expected_rotation_answer(records_by_bot[rotator], f1, f2)
    return [] if answer is None else [Query((rotator,), (f2,), answer, key, f1)]


def _look_away_pair(name: str, records: Sequence[Mapping], f1: int, key: str) -> list[Query]:
    qa = _require(rot_end(records, f1, 10), f"rotation of {name}")
    qb = _require(last_action(records, f1, 20), f"action of {name}")
    return [Query((name,), (qa,), "no", key, f1, "player_invisible_looked_away"),
            Query((name,), (qb,), "yes", key, f1, "player_position_turned_back")]


def _one_looks_away(records_by_bot, key) -> list[Query]:
    actor, f1 = _first_actor(records_by_bot, "oneLooksAwayEval")
    return _look_away_pair(actor, records_by_bot[actor], f1, key)


def _both_look_away(records_by_bot, key) -> list[Query]:
    sneakers = _sneakers(records_by_bot)
    if len(sneakers) != len(records_by_bot):
        raise ValueError(f"bothLookAwayEval: every bot must sneak, got frame1s {sneakers}")
    f1 = max(sneakers.values())
    return [q for name in sorted(records_by_bot) for q in _look_away_pair(name, records_by_bot[name], f1, key)]


def _structure(records_by_bot, key, summary: Mapping | None) -> list[Query]:
    names = sorted(records_by_bot)
    if summary is not None:
        matches = [n for n in names if n.lower() == summary["builder"].lower()]
        if not matches:
            raise ValueError(f"structureEval: summary builder {summary['builder']!r} is none of {names}")
        builder = matches[0]
        expected = STRUCTURE_ANSWERS.get(summary["structure"].strip().lower(), "no")
    else:  # our recordings: the builder is the only bot that sneaks
        builder, expected = _first_actor(records_by_bot, "structureEval")[0], "yes"
    observer = next(n for n in names if n != builder)
    f1 = sneak_end(records_by_bot[builder])
    if f1 is None:
        raise ValueError(f"structureEval: builder {builder} never sneaks")
    f2 = min(_require(last_action(records_by_bot[builder], f1, 20), "builder action"), f1 + STRUCTURE_MAX_OFFSET)
    if f2 >= len(records_by_bot[observer]):
        raise ValueError(f"structureEval: query frame {f2} past the observer's {len(records_by_bot[observer])} records")
    return [Query((observer,), (f2,), expected, key, f1)]


def _turn_to_look(records_by_bot, key, expected: str) -> list[Query]:
    sneakers = _sneakers(records_by_bot)
    if not sneakers:
        raise ValueError("turnToLook: no bot sneaks")
    f1 = max(sneakers.values())
    ends = [rot_end(records_by_bot[n], f1, 20) for n in sorted(records_by_bot)]
    ends = [e for e in ends if e is not None]
    if not ends:
        raise ValueError("turnToLook: no rotation found after frame1")
    f2 = max(ends)  # both bots have finished turning
    if any(f2 >= len(r) for r in records_by_bot.values()):
        raise ValueError(f"turnToLook: query frame {f2} past the end of a recording")
    names = tuple(sorted(records_by_bot))
    return [Query(names, (f2,) * len(names), expected, key, f1)]


def query_frames(eval_type: str, records_by_bot: Mapping[str, Sequence[Mapping]],
                 structure_summary: Mapping | None = None) -> list[Query]:
    """The judge's queries for one episode (docs/engine.md §7.2 table).

    Args:
        eval_type: one of ``EVAL_KEYS`` (e.g. ``"rotationEval"``).
        records_by_bot: bot name (``"Alpha"``, ``"Bravo"``) -> that bot's per-tick records.
        structure_summary: structureEval only: this episode's entry of the §7.3 summary
            (``{"builder": "alpha"|"bravo", "structure": ...}``). Without it the builder is the bot
            that sneaks and the expected answer is "yes".
    Returns:
        The queries in the judge's order; empty where the judge skips the episode (translation
        without movement, rotation outside the answer bands). Raises ValueError where the judge raises
        (no sneak, no rotation, query frame past the end).
    """
    if eval_type not in EVAL_KEYS:
        raise ValueError(f"unknown eval type {eval_type!r}; known: {sorted(EVAL_KEYS)}")
    if len(records_by_bot) != 2:
        raise ValueError(f"eval episodes have two bots, got {sorted(records_by_bot)}")
    key = EVAL_KEYS[eval_type]
    if eval_type == "translationEval":
        return _translation(records_by_bot, key)
    if eval_type == "rotationEval":
        return _rotation(records_by_bot, key)
    if eval_type == "oneLooksAwayEval":
        return _one_looks_away(records_by_bot, key)
    if eval_type == "bothLookAwayEval":
        return _both_look_away(records_by_bot, key)
    if eval_type == "structureEval":
        return _structure(records_by_bot, key, structure_summary)
    return _turn_to_look(records_by_bot, key, "yes" if eval_type == "turnToLookEval" else "no")


# ---------------------------------------------------------------------------------------------
# Eval segment rows (docs/engine.md §7.4, docs/data-format.md §5.2) and the structure summary (§7.3)
# ---------------------------------------------------------------------------------------------


def eval_ids_row(episode_id: int, records_alpha: Sequence[Mapping], records_bravo: Sequence[Mapping],
                 num_frames: int = EVAL_NUM_FRAMES) -> list[int]:
    """One ``eval_ids_<dataset>.json`` row: ``[episode_id, s1, s1 + num_frames, s2, s2 + num_frames]``.

    The start of each bot's segment is the judge's ``frame1`` = ``sneak_end`` (last sneak record + 25),
    so generated frame ``g - frame1 - 1`` shows GT frame g (§7.4). Our reading of the spec: a bot that
    sneaks starts at its own frame1; a bot that never sneaks (the observer of rotation, translation,
    one-looks-away, structure) starts at the actor's frame1, so both segments cover the same ticks.
    In both-sneak types (both-look-away, turn-to-look*) our bots sneak on the same tick, so their own
    frame1s equal the judge's ``max`` over both.
    """
    own = [sneak_end(records_alpha), sneak_end(records_bravo)]
    actors = [f for f in own if f is not None]
    if not actors:
        raise ValueError(f"episode {episode_id}: neither bot sneaks, no eval start")
    s1, s2 = (f if f is not None else actors[0] for f in own)
    return [int(episode_id), s1, s1 + num_frames, s2, s2 + num_frames]


def structure_summary(episodes: Iterable[Mapping]) -> dict:
    """The judge's ``structure_building_summary.json`` (§7.3) from structureEval episode_info dicts.

    Args:
        episodes: ``*_episode_info.json`` dicts (either or both bots of each episode; duplicates merge),
            each with ``instance_id``, ``episode_number`` and ``eval_metadata`` holding ``builder_bot``,
            ``observer_bot`` and ``structure_type``. Other episode types and empty metadata are skipped.
    Returns:
        ``{"instance_<i>": {"episode_<n>": {builder, structure, alpha_structure, alpha_builds,
        bravo_structure, bravo_builds}}}`` with lower-case bot names, sorted by instance then episode.
    """
    rows: dict[tuple[int, int], dict] = {}
    for info in episodes:
        meta = info.get("eval_metadata") or {}
        if info.get("episode_type", "structureEval") != "structureEval" or "builder_bot" not in meta:
            continue
        builder, structure = meta["builder_bot"].lower(), meta["structure_type"]
        rows[(int(info["instance_id"]), int(info["episode_number"]))] = {
            "builder": builder, "structure": structure,
            "alpha_structure": structure, "alpha_builds": builder == "alpha",
            "bravo_structure": structure, "bravo_builds": builder == "bravo",
        }
    out: dict[str, dict] = {}
    for (inst, ep), row in sorted(rows.items()):
        out.setdefault(f"instance_{inst}", {})[f"episode_{ep}"] = row
    return out
