"""Action spaces and action conversions shared by the env, the engine and the data pipeline.

Three action representations meet here:

* The **env action** (what agents send to ``step``): a dict with MineRL keys. 23 binary keys
  (``BINARY_KEYS``, each ``Discrete(2)``) plus ``camera`` = [dpitch, dyaw] in DEGREES, MineRL
  convention: positive pitch looks DOWN, positive yaw turns RIGHT.
* The **Mineflayer** convention used by the engine and the recorded data (docs/actions.md §2):
  radians, +yaw = turn LEFT (counter-clockwise seen from above), +pitch = look UP.
* The **model vector** (docs/actions.md §4): float32 (25,) in ``MODEL_ACTION_KEYS`` order; dims 0..22
  are binary keyboard/mouse-button flags, dims 23/24 are cameraX (yaw) / cameraY (pitch) in
  the Mineflayer sign convention, in degrees before ``camera_linear`` and scaled after it.

Converters from recorded data (Mineflayer records, VPT JSONL) reproduce the reference
``convert_act_slice_mineflayer`` / ``read_act_slice_vpt`` and return raw degrees (no
``camera_linear``). ``FlatActionCodec`` gives a flat encoding for SB3 policies.

Pure numpy + gymnasium: no jax or torch import.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Literal

import numpy as np
from gymnasium import spaces

# ---------------------------------------------------------------------------------------------
# Env action contract (MineRL keys)
# ---------------------------------------------------------------------------------------------

HOTBAR_KEYS = tuple(f"hotbar.{k}" for k in range(1, 10))
BINARY_KEYS = (
    "forward", "back", "left", "right", "jump", "sneak", "sprint",
    "attack", "use", "drop", "inventory", "ESC", "swapHands", "pickItem",
) + HOTBAR_KEYS
CAMERA_KEY = "camera"
CAMERA_AXES = ("pitch", "yaw")  # the camera action is [dpitch, dyaw] degrees (MineRL)
ACTION_KEYS = BINARY_KEYS + (CAMERA_KEY,)
CAMERA_LIMIT_DEG = 180.0  # env camera bound per step, both axes, inclusive
# The largest camera turn per 20 Hz engine tick and axis, degrees: the per-tick range of the Duet training data
# (Mineflayer's look speed, 3 rad/s = 0.15 rad = 8.594 deg per tick; ``engine.bots.controller.MAX_TURN_RAD``; every
# recorded tick lies within it). An env step of k ticks turns at most k times this per axis; the rest of a larger
# turn is carried over to the next steps (``step_ticks``), in the engine and in the dream alike.
CAMERA_TICK_LIMIT_DEG = math.degrees(3.0 / 20)
_TICK_LIMIT_F32 = float(np.float32(CAMERA_TICK_LIMIT_DEG))  # a full tick's turn as the float32 a tick action holds

# ---------------------------------------------------------------------------------------------
# Model action vector (docs/actions.md §4)
# ---------------------------------------------------------------------------------------------

MODEL_ACTION_KEYS = (
    "inventory", "ESC",
) + HOTBAR_KEYS + (
    "forward", "back", "left", "right", "jump", "sneak", "sprint",
    "swapHands", "attack", "use", "pickItem", "drop",
    "cameraX", "cameraY",
)
MODEL_INDEX = {name: i for i, name in enumerate(MODEL_ACTION_KEYS)}
MODEL_ACTION_DIM = len(MODEL_ACTION_KEYS)  # 25
MOUSE_DIM = 2  # cameraX, cameraY
KEYBOARD_DIM = MODEL_ACTION_DIM - MOUSE_DIM  # 23
CAMERA_X_INDEX = MODEL_INDEX["cameraX"]  # 23, yaw
CAMERA_Y_INDEX = MODEL_INDEX["cameraY"]  # 24, pitch

# CameraLinearConverterMatrixGame2: degrees clipped to ±CAMERA_CLIP_DEG, then divided by
# CAMERA_SCALE_DEG, so the model's mouse input lies in ±20/15 = ±1.3333.
CAMERA_CLIP_DEG = 20.0
CAMERA_SCALE_DEG = 15.0

# ---------------------------------------------------------------------------------------------
# Recorded data formats
# ---------------------------------------------------------------------------------------------

# docs/actions.md §6.1: the 24 keys of a Mineflayer record's "action" object, in emitted order.
RECORDED_ACTION_KEYS = (
    "forward", "back", "left", "right", "jump", "sprint", "sneak", "camera",
    "attack", "use", "mount", "dismount", "place_block", "place_entity", "mine",
) + HOTBAR_KEYS

# docs/actions.md §6.2: recorded boolean key -> model key it switches on (OR-combined).
RECORDED_TO_MODEL = {
    "forward": "forward", "back": "back", "left": "left", "right": "right",
    "jump": "jump", "sprint": "sprint", "sneak": "sneak",
    "attack": "attack", "mine": "attack",
    "use": "use", "mount": "use", "place_block": "use", "place_entity": "use",
    "dismount": "sneak",
    **{k: k for k in HOTBAR_KEYS},
}

# docs/actions.md §7.1: VPT keyboard key -> model key. Keys not listed are ignored.
VPT_KEY_TO_MODEL = {
    "key.keyboard.escape": "ESC", "key.keyboard.s": "back", "key.keyboard.q": "drop",
    "key.keyboard.w": "forward", "key.keyboard.e": "inventory", "key.keyboard.space": "jump",
    "key.keyboard.a": "left", "key.keyboard.d": "right", "key.keyboard.left.shift": "sneak",
    "key.keyboard.left.control": "sprint", "key.keyboard.f": "swapHands",
    **{f"key.keyboard.{k}": f"hotbar.{k}" for k in range(1, 10)},
}
VPT_BUTTON_TO_MODEL = {0: "attack", 1: "use", 2: "pickItem"}
VPT_ATTACK_BUTTON = 0
VPT_CAMERA_DEG_PER_PIXEL = 360.0 / 2400.0  # mouse dx/dy pixels -> degrees


# ---------------------------------------------------------------------------------------------
# Env action space, no-op and validation
# ---------------------------------------------------------------------------------------------


def make_action_space(seed: int | None = None) -> spaces.Dict:
    """The per-agent env action space: ``Dict`` in ``ACTION_KEYS`` order.

    Binary keys are ``Discrete(2)``; ``camera`` is ``Box(-180, 180, (2,), float32)`` holding
    [dpitch, dyaw] in degrees (MineRL convention: +pitch looks down, +yaw turns right).
    """
    items = [(key, spaces.Discrete(2)) for key in BINARY_KEYS]
    camera = spaces.Box(-CAMERA_LIMIT_DEG, CAMERA_LIMIT_DEG, shape=(2,), dtype=np.float32)
    items.append((CAMERA_KEY, camera))
    return spaces.Dict(items, seed=seed)


def noop() -> dict[str, Any]:
    """The do-nothing env action: every binary key 0, camera float32 zeros (2,)."""
    action: dict[str, Any] = {key: 0 for key in BINARY_KEYS}
    action[CAMERA_KEY] = np.zeros(2, dtype=np.float32)
    return action


# Keys that act once per key press in Minecraft: in an env step of k engine ticks (the dream env's
# k = frames_per_step, the real env's ``ticks_per_step``) they are sent on the first tick only. The movement
# keys (forward, back, left, right, jump, sneak, sprint) and ``attack`` are held for all k ticks: digging needs
# attack on every tick (a tick without it resets the block's progress, as in the game and the recorded bots),
# and a held attack on a player swings whenever the attack cooldown allows (docs/actions.md §5).
ONCE_KEYS = ("use", "drop", "inventory", "ESC", "swapHands", "pickItem") + HOTBAR_KEYS


def step_ticks(action: Mapping[str, Any], k: int, pending_deg: Any = None,
               agent: str | None = None) -> tuple[list[dict[str, Any]], np.ndarray]:
    """One env step's action -> the k per-tick env actions of the step, and the camera turn left for later steps.

    Keys: tick 0 carries the whole action; ticks 1..k-1 keep the held movement keys but release the ``ONCE_KEYS``.
    Camera: the step's turn [dpitch, dyaw] plus ``pending_deg`` (what earlier steps left over) is turned at up to
    ``CAMERA_TICK_LIMIT_DEG`` per tick and axis, from tick 0 on (a 20 deg yaw at k = 4: 8.59, 8.59, 2.81, 0), so
    a step turns up to k * 8.59 deg per axis; the rest is returned, to be passed as ``pending_deg`` with the next
    step's action (nothing is clipped or dropped). The real env (``ticks_per_step`` = k) and the dream env (k =
    the model's ``frames_per_step``; ``dream_env.expand_action``) both use this rule, so an action means the same
    turn in both.

    Returns:
        ticks: k validated env actions (camera float32 degrees per tick).
        pending: float64 (2,) [dpitch, dyaw] degrees still to turn (exact zeros once the turn is done).
    Raises ValueError (naming ``agent`` and the key) on a bad action, a bad ``k`` or a bad ``pending_deg``.
    """
    if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"k (ticks per step) must be an int >= 1, got {k!r}")
    first = validate_action(action, agent)
    pending = first[CAMERA_KEY].astype(np.float64)
    if pending_deg is not None:
        pending = pending + _as_finite_pair(pending_deg, "pending_deg", _where(agent))
    rest = [float(pending[0]), float(pending[1])]
    turns = np.zeros((int(k), 2), np.float32)
    for t in range(int(k)):
        for axis in (0, 1):
            if abs(rest[axis]) <= CAMERA_TICK_LIMIT_DEG:  # what is left fits in this tick: done
                turns[t, axis], rest[axis] = rest[axis], 0.0
            else:
                turns[t, axis] = math.copysign(_TICK_LIMIT_F32, rest[axis])
                rest[axis] -= float(turns[t, axis])
    held = dict(first, **{key: 0 for key in ONCE_KEYS})
    ticks = [dict(first if t == 0 else held) for t in range(int(k))]
    for t, tick in enumerate(ticks):
        tick[CAMERA_KEY] = turns[t]
    return ticks, np.array(rest)


def _where(agent: str | None) -> str:
    """Message prefix naming the agent, if any."""
    return f"agent {agent!r}: " if agent is not None else ""


def _as_binary(value: Any, key: str, where: str) -> int:
    """Return ``value`` as python int 0/1; accepts bool, int, numpy integer/bool scalars or 0-d arrays."""
    if isinstance(value, np.ndarray):
        if value.shape != ():
            raise ValueError(f"{where}action key {key!r}: expected a scalar 0 or 1, got array of shape {value.shape}")
        value = value[()]
    if not isinstance(value, (bool, int, np.bool_, np.integer)):
        raise ValueError(
            f"{where}action key {key!r}: expected an int or bool 0/1, got {type(value).__name__} {value!r}"
        )
    if value not in (0, 1):
        raise ValueError(f"{where}action key {key!r}: expected 0 or 1, got {value!r}")
    return int(value)


def _as_finite_pair(value: Any, key: str, where: str) -> np.ndarray:
    """Return ``value`` as float64 (2,), raising on ragged/non-numeric input, wrong shape or NaN/inf."""
    try:
        arr = np.asarray(value)
    except (ValueError, TypeError) as err:
        raise ValueError(f"{where}action key {key!r}: expected 2 numbers, got {value!r}") from err
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{where}action key {key!r}: expected a numeric array, got dtype {arr.dtype}")
    if arr.shape != (2,):
        raise ValueError(f"{where}action key {key!r}: expected shape (2,), got {arr.shape}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}action key {key!r}: expected finite values, got {arr.tolist()}")
    return arr


def _as_camera(value: Any, where: str) -> np.ndarray:
    """Return the env camera as float32 (2,) in degrees; raises outside [-180, 180] (never clips)."""
    arr = _as_finite_pair(value, CAMERA_KEY, where)
    if np.any(np.abs(arr) > CAMERA_LIMIT_DEG):
        raise ValueError(
            f"{where}action key {CAMERA_KEY!r}: expected degrees in [-{CAMERA_LIMIT_DEG}, {CAMERA_LIMIT_DEG}], "
            f"got {arr.tolist()}"
        )
    return arr.astype(np.float32)


def _check_keys(keys: Iterable[str], expected: Sequence[str], where: str, what: str) -> None:
    """Raise ValueError naming the first unknown or missing key."""
    keys = set(keys)
    unknown = [k for k in keys if k not in expected]
    if unknown:
        raise ValueError(f"{where}unknown {what} key {sorted(map(str, unknown))[0]!r}; expected keys {list(expected)}")
    missing = [k for k in expected if k not in keys]
    if missing:
        raise ValueError(f"{where}missing {what} key {missing[0]!r}")


def validate_action(action: Mapping[str, Any], agent: str | None = None) -> dict[str, Any]:
    """Check one env action and return a normalised copy.

    Returns a dict in ``ACTION_KEYS`` order: binary keys as python int 0/1, camera as float32 (2,).
    Raises ValueError (naming ``agent`` when given, and the key) on unknown or missing keys,
    binary values outside {0, 1}, and a camera that is non-numeric, not shape (2,), NaN/inf or
    outside [-180, 180] degrees. Nothing is clipped.
    """
    where = _where(agent)
    if not isinstance(action, Mapping):
        raise ValueError(
            f"{where}expected the action to be a dict with keys {list(ACTION_KEYS)}, got {type(action).__name__}"
        )
    _check_keys(action.keys(), ACTION_KEYS, where, "action")
    out: dict[str, Any] = {key: _as_binary(action[key], key, where) for key in BINARY_KEYS}
    out[CAMERA_KEY] = _as_camera(action[CAMERA_KEY], where)
    return out


# ---------------------------------------------------------------------------------------------
# Camera conventions
# ---------------------------------------------------------------------------------------------


def minerl_camera_to_mineflayer(camera_deg: Any) -> tuple[float, float]:
    """MineRL camera [dpitch, dyaw] degrees (+down, +right) -> Mineflayer (dyaw, dpitch) radians (+left, +up).

    dyaw = -radians(camera[1]), dpitch = -radians(camera[0]). Exact zero maps to +0.0.
    """
    dpitch_deg, dyaw_deg = _as_finite_pair(camera_deg, CAMERA_KEY, "")
    return 0.0 - math.radians(dyaw_deg), 0.0 - math.radians(dpitch_deg)


def mineflayer_to_minerl_camera(dyaw_rad: float, dpitch_rad: float) -> np.ndarray:
    """Mineflayer (dyaw, dpitch) radians (+left, +up) -> MineRL camera float32 (2,) [dpitch, dyaw] degrees."""
    dyaw, dpitch = _as_finite_pair([dyaw_rad, dpitch_rad], CAMERA_KEY, "")
    return np.array([0.0 - math.degrees(dpitch), 0.0 - math.degrees(dyaw)], dtype=np.float32)


# ---------------------------------------------------------------------------------------------
# Model action vector
# ---------------------------------------------------------------------------------------------


def camera_linear(vec_T25: Any) -> np.ndarray:
    """``CameraLinearConverterMatrixGame2``: model input transform of the two camera dims.

    Args:
        vec_T25: (..., 25) action vectors with dims 23/24 in degrees.
    Returns:
        float32 copy (..., 25) with dims 23/24 = clip(deg, -CAMERA_CLIP_DEG, CAMERA_CLIP_DEG) / CAMERA_SCALE_DEG,
        i.e. in [-1.3333, 1.3333]. The clip is part of the definition (the model never sees larger
        per-frame turns), not error handling. Keyboard dims are passed through unchanged.
    """
    out = np.array(vec_T25, dtype=np.float32)  # copy
    if out.ndim == 0 or out.shape[-1] != MODEL_ACTION_DIM:
        raise ValueError(f"camera_linear: expected shape (..., {MODEL_ACTION_DIM}), got {out.shape}")
    mouse = out[..., KEYBOARD_DIM:].astype(np.float64)
    if not np.all(np.isfinite(mouse)):
        raise ValueError("camera_linear: cameraX/cameraY must be finite")
    out[..., KEYBOARD_DIM:] = np.clip(mouse, -CAMERA_CLIP_DEG, CAMERA_CLIP_DEG) / CAMERA_SCALE_DEG
    return out


def env_action_to_model_vector(action: Mapping[str, Any], agent: str | None = None) -> np.ndarray:
    """Env (MineRL) action -> model input vector float32 (25,), ``camera_linear`` applied.

    cameraX = -camera[1] (dyaw, + = left) and cameraY = -camera[0] (dpitch, + = up) in degrees,
    i.e. the Mineflayer convention of the training data, then scaled by ``camera_linear``.
    """
    return _model_vector(validate_action(action, agent))


def _model_vector(action: Mapping[str, Any]) -> np.ndarray:
    """``env_action_to_model_vector`` of an action ``validate_action`` already returned."""
    vec_25 = np.zeros(MODEL_ACTION_DIM, dtype=np.float32)
    for key in BINARY_KEYS:
        vec_25[MODEL_INDEX[key]] = action[key]
    dpitch_deg, dyaw_deg = action[CAMERA_KEY].astype(np.float64)
    vec_25[CAMERA_X_INDEX] = 0.0 - dyaw_deg
    vec_25[CAMERA_Y_INDEX] = 0.0 - dpitch_deg
    return camera_linear(vec_25)


def env_actions_to_model_vectors(actions: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """A sequence of T env actions -> float32 (T, 25) model vectors (``camera_linear`` applied)."""
    rows = [env_action_to_model_vector(a) for a in actions]
    return np.stack(rows) if rows else np.zeros((0, MODEL_ACTION_DIM), dtype=np.float32)


# ---------------------------------------------------------------------------------------------
# Mineflayer records (docs/actions.md §6) -> model vectors
# ---------------------------------------------------------------------------------------------


def _record_to_vector(record: Mapping[str, Any], index: int) -> np.ndarray:
    """One Mineflayer record (with an ``"action"`` dict) -> float32 (25,), camera in raw degrees."""
    where = f"record {index}: "
    action = record.get("action") if isinstance(record, Mapping) else None
    if not isinstance(action, Mapping):
        raise ValueError(f"{where}expected a dict with an 'action' dict")
    _check_keys(action.keys(), RECORDED_ACTION_KEYS, where, "recorded action")
    vec_25 = np.zeros(MODEL_ACTION_DIM, dtype=np.float32)
    for key, model_key in RECORDED_TO_MODEL.items():
        if _as_binary(action[key], key, where):
            vec_25[MODEL_INDEX[model_key]] = 1.0
    dyaw_rad, dpitch_rad = _as_finite_pair(action[CAMERA_KEY], CAMERA_KEY, where)
    vec_25[CAMERA_X_INDEX] = math.degrees(dyaw_rad)  # no sign change: + = left
    vec_25[CAMERA_Y_INDEX] = math.degrees(dpitch_rad)  # + = up
    return vec_25


def mineflayer_records_to_vectors(records: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """Reference ``convert_act_slice_mineflayer``: T per-tick records -> float32 (T, 25).

    Mapping (docs/actions.md §6.2): attack/mine -> attack (19); use/mount/place_block/place_entity
    -> use (20); dismount -> sneak (16); hotbar.k -> 1+k; camera [dyaw, dpitch] radians ->
    dims 23/24 in degrees with no sign change. No ``camera_linear`` is applied. Each record's
    ``action`` must hold exactly ``RECORDED_ACTION_KEYS``; violations raise ValueError naming
    the record index and key.
    """
    rows = [_record_to_vector(record, i) for i, record in enumerate(records)]
    return np.stack(rows) if rows else np.zeros((0, MODEL_ACTION_DIM), dtype=np.float32)


# ---------------------------------------------------------------------------------------------
# VPT JSONL (docs/actions.md §7) -> model vectors
# ---------------------------------------------------------------------------------------------


def _parse_vpt_ticks(lines_or_objs: Iterable[str | Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """JSON-decode string lines (blank lines skipped); dicts pass through."""
    ticks = []
    for item in lines_or_objs:
        if isinstance(item, (str, bytes)):
            if not item.strip():
                continue
            item = json.loads(item)
        if not isinstance(item, Mapping):
            raise ValueError(f"VPT tick {len(ticks)}: expected a JSON object, got {type(item).__name__}")
        ticks.append(item)
    return ticks


def _vpt_fields(tick: Mapping[str, Any], index: int) -> tuple[list, list, list, float, float, int]:
    """Pull (keys, buttons, newButtons, dx, dy, hotbar) out of one VPT tick, raising on missing fields."""
    try:
        keys = list(tick["keyboard"]["keys"])
        mouse = tick["mouse"]
        buttons, new_buttons = list(mouse["buttons"]), list(mouse["newButtons"])
        dx, dy, hotbar = float(mouse["dx"]), float(mouse["dy"]), int(tick["hotbar"])
    except (KeyError, TypeError) as err:
        raise ValueError(f"VPT tick {index}: missing or malformed field {err}") from err
    return keys, buttons, new_buttons, dx, dy, hotbar


def vpt_jsonl_to_vectors(lines_or_objs: Iterable[str | Mapping[str, Any]]) -> np.ndarray:
    """Reference ``read_act_slice_vpt``: VPT JSONL ticks (lines or parsed dicts) -> float32 (T, 25).

    keyboard.keys via ``VPT_KEY_TO_MODEL``; mouse buttons 0/1/2 -> attack/use/pickItem; camera
    cameraX = dx * 360/2400, cameraY = dy * 360/2400 degrees (VPT signs: + = right/down; not
    reconciled with Mineflayer, as in the reference). No ``camera_linear`` is applied.
    Stateful, so pass the episode from tick 0 and slice afterwards:
      * attack stuck: if tick 0 has ``newButtons == [0]``, button 0 is dropped from every tick
        until a later tick has 0 in ``newButtons`` (that tick keeps it);
      * hotbar: ``hotbar.(h+1)`` pulses to 1 only on ticks whose ``hotbar`` h differs from the
        previous tick's (initial previous = 0).
    """
    ticks = _parse_vpt_ticks(lines_or_objs)
    out_T25 = np.zeros((len(ticks), MODEL_ACTION_DIM), dtype=np.float32)
    attack_stuck, prev_hotbar = False, 0
    for t, tick in enumerate(ticks):
        keys, buttons, new_buttons, dx, dy, hotbar = _vpt_fields(tick, t)
        if t == 0:
            attack_stuck = new_buttons == [VPT_ATTACK_BUTTON]
        elif attack_stuck and VPT_ATTACK_BUTTON in new_buttons:
            attack_stuck = False
        if attack_stuck:
            buttons = [b for b in buttons if b != VPT_ATTACK_BUTTON]
        pressed = [VPT_KEY_TO_MODEL[k] for k in keys if k in VPT_KEY_TO_MODEL]
        pressed += [VPT_BUTTON_TO_MODEL[b] for b in buttons if b in VPT_BUTTON_TO_MODEL]
        if hotbar != prev_hotbar:
            pressed.append(f"hotbar.{hotbar + 1}")
        prev_hotbar = hotbar
        out_T25[t, [MODEL_INDEX[name] for name in pressed]] = 1.0
        out_T25[t, CAMERA_X_INDEX] = dx * VPT_CAMERA_DEG_PER_PIXEL
        out_T25[t, CAMERA_Y_INDEX] = dy * VPT_CAMERA_DEG_PER_PIXEL
    return out_T25


# ---------------------------------------------------------------------------------------------
# Flat encoding for SB3
# ---------------------------------------------------------------------------------------------


class FlatActionCodec:
    """Flat, SB3-friendly encoding of the env action, and back.

    Layout (``len(keys) + len(camera_axes)`` entries): the exposed binary ``keys`` (default: all 23
    ``BINARY_KEYS``, in that order), then the exposed camera axes (default [dpitch, dyaw], MineRL). Keys and
    axes left out stay 0: a policy that only needs to turn (``keys=(), camera_axes=("yaw",)``) does not
    explore by dropping items, opening the inventory or staring at the sky.

    * ``kind="multidiscrete"``: ``MultiDiscrete([2]*len(keys) + [camera_bins]*len(camera_axes))``. Camera bin i is
      ``camera_max_deg * (i - c) / c`` degrees with c = camera_bins // 2: linear, symmetric,
      exact 0 at the centre bin, ends at ±camera_max_deg.
    * ``kind="box"``: ``Box(-1, 1, (len(keys) + len(camera_axes),), float32)``. A binary key is 1 iff its value > 0 (encode
      writes +1/-1); camera degrees = value * camera_max_deg.

    ``encode`` is lossy for the camera (snapped to the nearest bin, or clipped to
    ±camera_max_deg for "box") and raises on a pressed key or a turn about an axis that is not exposed;
    ``decode(encode(decode(x))) == decode(x)`` holds exactly.

    Args:
        camera_bins: odd number >= 3 of camera bins per axis ("multidiscrete" only).
        camera_max_deg: largest camera step in degrees, in (0, 180].
        kind: "multidiscrete" or "box".
        keys: the binary keys the flat action exposes (a subset of ``BINARY_KEYS``, no repeats; any order,
            kept); None = all of them.
        camera_axes: the camera axes the flat action exposes, in MineRL's order: ("pitch", "yaw") (default),
            ("yaw",), ("pitch",) or ().
    """

    def __init__(
        self,
        camera_bins: int = 11,
        camera_max_deg: float = 10.0,
        kind: Literal["multidiscrete", "box"] = "multidiscrete",
        keys: Sequence[str] | None = None,
        camera_axes: Sequence[str] = CAMERA_AXES,
    ) -> None:
        if kind not in ("multidiscrete", "box"):
            raise ValueError(f"kind: expected 'multidiscrete' or 'box', got {kind!r}")
        if not isinstance(camera_bins, (int, np.integer)) or camera_bins < 3 or camera_bins % 2 == 0:
            raise ValueError(f"camera_bins: expected an odd int >= 3 (so 0 deg is a bin), got {camera_bins!r}")
        if not (0.0 < camera_max_deg <= CAMERA_LIMIT_DEG):
            raise ValueError(f"camera_max_deg: expected a value in (0, {CAMERA_LIMIT_DEG}], got {camera_max_deg!r}")
        self.keys = BINARY_KEYS if keys is None else self._check_keys(keys)
        ordered = tuple(a for a in CAMERA_AXES if a in tuple(camera_axes))
        if isinstance(camera_axes, str) or ordered != tuple(camera_axes):
            raise ValueError(f"camera_axes: expected a subsequence of {list(CAMERA_AXES)}, got {camera_axes!r}")
        self.camera_axes = tuple(camera_axes)
        self._axis_index = np.array([CAMERA_AXES.index(a) for a in self.camera_axes], dtype=np.int64)
        self.kind = kind
        self.camera_bins = int(camera_bins)
        self.camera_max_deg = float(camera_max_deg)
        half = self.camera_bins // 2
        self.bin_centers_deg = (self.camera_max_deg * (np.arange(self.camera_bins) - half) / half).astype(np.float32)
        self.space = self._make_space()

    @staticmethod
    def _check_keys(keys: Sequence[str]) -> tuple[str, ...]:
        if isinstance(keys, str):
            raise ValueError(f"keys: expected a sequence of key names, got the string {keys!r}")
        keys = tuple(keys)
        unknown = [k for k in keys if k not in BINARY_KEYS]
        if unknown:
            raise ValueError(f"keys: {unknown[0]!r} is not a binary key; expected names from {list(BINARY_KEYS)}")
        if len(set(keys)) != len(keys):
            raise ValueError(f"keys: expected no repeats, got {list(keys)}")
        return keys

    def config(self) -> dict[str, Any]:
        """The constructor arguments (JSON-able): ``FlatActionCodec(**codec.config())`` rebuilds it."""
        return {"kind": self.kind, "camera_bins": self.camera_bins, "camera_max_deg": self.camera_max_deg,
                "keys": list(self.keys), "camera_axes": list(self.camera_axes)}

    def _entry_name(self, i: int) -> str:
        """Name of flat entry i: an exposed key, or camera[0] (dpitch) / camera[1] (dyaw)."""
        n_binary = len(self.keys)
        return self.keys[i] if i < n_binary else f"{CAMERA_KEY}[{self._axis_index[i - n_binary]}]"

    def _make_space(self) -> spaces.Space:
        n_binary, n_axes = len(self.keys), len(self.camera_axes)
        if n_binary + n_axes == 0:
            raise ValueError("keys and camera_axes: expected at least one key or camera axis, got neither")
        if self.kind == "multidiscrete":
            return spaces.MultiDiscrete([2] * n_binary + [self.camera_bins] * n_axes)
        return spaces.Box(-1.0, 1.0, shape=(n_binary + n_axes,), dtype=np.float32)

    # -- encode -----------------------------------------------------------------------------

    def encode(self, env_action: Mapping[str, Any]) -> np.ndarray:
        """Env action -> flat (len(keys) + len(camera_axes),) (int64 for "multidiscrete", float32 for "box");
        camera is lossy. ValueError if the action presses a key or turns about an axis this codec does not expose."""
        action = validate_action(env_action)
        hidden = [key for key in BINARY_KEYS if action[key] and key not in self.keys]
        if hidden:
            raise ValueError(f"action presses {hidden[0]!r}, which this codec does not expose (keys={list(self.keys)})")
        bits = np.array([action[key] for key in self.keys], dtype=np.int64)
        hidden_axes = [a for i, a in enumerate(CAMERA_AXES) if action[CAMERA_KEY][i] and a not in self.camera_axes]
        if hidden_axes:
            raise ValueError(f"action turns the camera about {hidden_axes[0]!r}, which this codec does not expose "
                             f"(camera_axes={list(self.camera_axes)})")
        camera = action[CAMERA_KEY].astype(np.float64)[self._axis_index]
        if self.kind == "multidiscrete":
            return np.concatenate([bits, self._camera_to_bins(camera)]).astype(np.int64)
        return np.concatenate([2.0 * bits - 1.0, self._camera_to_box(camera)]).astype(np.float32)

    def _camera_to_bins(self, camera_deg: np.ndarray) -> np.ndarray:
        """Nearest bin index per exposed axis; values beyond ±camera_max_deg land in the end bins."""
        half = self.camera_bins // 2
        index = np.rint(camera_deg / self.camera_max_deg * half) + half
        return np.clip(index, 0, self.camera_bins - 1).astype(np.int64)

    def _camera_to_box(self, camera_deg: np.ndarray) -> np.ndarray:
        """float32 (n_axes,) in [-1, 1] whose decode is nearest to camera_deg (exact if camera_deg came from decode)."""
        guess = np.clip(camera_deg / self.camera_max_deg, -1.0, 1.0).astype(np.float32)
        candidates = np.stack([
            np.nextafter(guess, np.float32(-1.0)), guess, np.nextafter(guess, np.float32(1.0)),
        ])  # (3, n_axes); float32 division can land one ulp off the value decode started from
        error = np.abs(self._box_to_camera(candidates) - camera_deg)
        return candidates[np.argmin(error, axis=0), np.arange(len(camera_deg))]

    # -- decode -----------------------------------------------------------------------------

    def decode(self, flat: Any) -> dict[str, Any]:
        """Flat (len(keys) + len(camera_axes),) -> validated env action dict (keys and axes not exposed: 0);
        ValueError on wrong shape, dtype or range."""
        arr = np.asarray(flat)
        n_flat = len(self.keys) + len(self.camera_axes)
        if arr.shape != (n_flat,):
            raise ValueError(f"flat action: expected shape ({n_flat},), got {arr.shape}")
        if self.kind == "multidiscrete":
            bits, camera = self._decode_multidiscrete(arr)
        else:
            bits, camera = self._decode_box(arr)
        action: dict[str, Any] = dict.fromkeys(BINARY_KEYS, 0)
        action.update({key: int(b) for key, b in zip(self.keys, bits)})
        action[CAMERA_KEY] = np.zeros(2, dtype=np.float32)
        action[CAMERA_KEY][self._axis_index] = camera
        return validate_action(action)

    def _decode_multidiscrete(self, arr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Integer (len(keys) + n_axes,) -> (bits (len(keys),), camera float32 (n_axes,) degrees)."""
        if arr.dtype.kind not in "iu":
            raise ValueError(f"flat action: expected an integer array for MultiDiscrete, got dtype {arr.dtype}")
        bad = np.flatnonzero((arr < 0) | (arr >= self.space.nvec))
        if bad.size:
            i = int(bad[0])
            high = self.space.nvec[i] - 1
            raise ValueError(f"flat action: entry {i} ({self._entry_name(i)!r}) = {arr[i]} outside [0, {high}]")
        n_binary = len(self.keys)
        return arr[:n_binary], self.bin_centers_deg[arr[n_binary:]]

    def _decode_box(self, arr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """float (len(keys) + n_axes,) in [-1, 1] -> (bits (len(keys),), camera float32 (n_axes,) degrees)."""
        if arr.dtype.kind not in "iuf":
            raise ValueError(f"flat action: expected a numeric array for Box, got dtype {arr.dtype}")
        arr = arr.astype(np.float64)  # range-check before any float32 rounding
        if not np.all(np.abs(arr) <= 1.0):  # also catches NaN
            i = int(np.flatnonzero(~(np.abs(arr) <= 1.0))[0])
            raise ValueError(f"flat action: entry {i} ({self._entry_name(i)!r}) = {arr[i]} outside [-1, 1]")
        n_binary = len(self.keys)
        return (arr[:n_binary] > 0).astype(np.int64), self._box_to_camera(arr[n_binary:])

    def _box_to_camera(self, value: np.ndarray) -> np.ndarray:
        """Box camera value(s) in [-1, 1] -> float32 degrees, computed in float64 then rounded once."""
        return (value.astype(np.float64) * self.camera_max_deg).astype(np.float32)
