"""Export a Duet dataset as single-player episodes in OpenAI VPT's layout: the stage-1 stand-in for VPT.

    solaris-engine export-vpt data --out data        # data/duet/{train,test} -> data/vpt/{train,test}

Every bot recording ``duet/<split>/<stem>.mp4`` + ``<stem>.json`` becomes one VPT episode
``vpt/<split>/engine/<stem>.mp4`` (hard link, or a copy across file systems / with ``link=False``) +
``engine/<stem>.jsonl`` (one JSON object per tick), listed in ``vpt/<split>/episodes_info.json`` =
``{"num_episodes", "episodes": [{"video_path", "actions_path", "length", "episode_id"}]}`` (paths
relative to the split dir, ids = positions in the sorted list; docs/data-format.md §6).

Alignment: the Duet mp4 already has VPT's alignment (frame t shows the state before tick t's action,
so frame t + 1 is its effect and a loader reads frames start+1 .. stop for ticks start .. stop-1);
the video is reused unchanged and ``length`` = ticks = frames.

A tick (:func:`records_to_vpt_ticks`) carries VPT's fields, from the Mineflayer record:

* ``keyboard.keys``: forward/back/left/right -> w/s/a/d, jump -> space, sneak and dismount ->
  left.shift, sprint -> left.control, a ``hotbar.k`` event -> ``k`` on that tick; ``newKeys`` = keys
  not held on the previous tick; ``chars`` = "".
* ``mouse.buttons``: 0 (attack) for attack/mine, 1 (use) for use/mount/place_block/place_entity;
  ``newButtons`` likewise. ``dx, dy`` in pixels = degrees / (360/2400) with VPT's signs (+dx turns
  right, +dy looks down): dx = -deg(dyaw), dy = -deg(dpitch) over 0.15. ``x, y`` integrate dx, dy from
  the centre of a 1280x720 window, ``scaledX, scaledY`` are the same relative to the centre, ``dwheel`` 0.
* ``hotbar``: the selected slot (0-based) after the tick's action (the record's
  ``inventory.quickBarSlot``); ``yaw``/``pitch`` the record's pose in Minecraft's degrees
  (yaw 0 = south, + turns right; pitch + = down); ``xpos/ypos/zpos`` the feet position; ``tick``,
  ``milli`` (= renderTime), ``serverTick`` (= world age), ``serverTickDurationMs``; ``inventory`` a list
  of ``{type, quantity}``; ``isGuiOpen``/``isGuiInventory`` false; ``stats`` {}.

Round trip (tested): ``vpt_jsonl_to_vectors`` of the export, with the camera sign flipped back
(``training.vpt.vpt_camera_to_mineflayer``), equals ``mineflayer_records_to_vectors`` of the
records on all 25 dims (camera to float rounding). mount/dismount/place_entity/place_block/mine have no
VPT key of their own, but the Mineflayer conversion collapses them into use/sneak/attack exactly as the
export does, so nothing is lost for the model. Two VPT-converter quirks can differ at tick 0 only:
a selected slot != 0 at tick 0 pulses ``hotbar.(slot+1)`` (VPT's previous hotbar starts at 0; the
engine starts bots on slot 4 or 5), and attack held alone at tick 0 is dropped until re-pressed ("attack
stuck"; never happens here, tick 0 is in the idle pre-roll).
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from solaris_env.spaces import HOTBAR_KEYS, VPT_CAMERA_DEG_PER_PIXEL

logger = logging.getLogger(__name__)

VPT_DIR = "vpt"
EPISODE_SUBDIR = "engine"  # like the reference's "v10/" contractor subdirectories
SPLITS = ("train", "test")
SCREEN_CENTER = (640.0, 360.0)  # VPT recorded a 1280x720 window
SERVER_TICK_MS = 50.0

# Recorded (Mineflayer) key -> VPT keyboard key; several record keys may share one VPT key.
RECORDED_TO_VPT_KEY = {
    "forward": "key.keyboard.w", "back": "key.keyboard.s", "left": "key.keyboard.a", "right": "key.keyboard.d",
    "jump": "key.keyboard.space", "sneak": "key.keyboard.left.shift", "dismount": "key.keyboard.left.shift",
    "sprint": "key.keyboard.left.control",
    **{key: f"key.keyboard.{key.split('.')[1]}" for key in HOTBAR_KEYS},
}
VPT_ATTACK, VPT_USE = 0, 1
RECORDED_TO_VPT_BUTTON = {"attack": VPT_ATTACK, "mine": VPT_ATTACK, "use": VPT_USE, "mount": VPT_USE,
                          "place_block": VPT_USE, "place_entity": VPT_USE}


# ---------------------------------------------------------------------------------------------
# Records -> VPT ticks
# ---------------------------------------------------------------------------------------------


def _pixels(delta_rad: float) -> float:
    """A Mineflayer per-tick angle delta (radians, + = left/up) -> VPT mouse pixels (+ = right/down)."""
    return 0.0 - math.degrees(delta_rad) / VPT_CAMERA_DEG_PER_PIXEL


def _pressed(action: Mapping[str, Any], table: Mapping[str, Any]) -> list:
    """Distinct VPT keys/buttons switched on by an action, in table order."""
    out = []
    for key, vpt in table.items():
        if action.get(key) and vpt not in out:
            out.append(vpt)
    return out


def _vpt_inventory(record: Mapping[str, Any]) -> list[dict]:
    hotbar = (record.get("inventory") or {}).get("hotbar") or []
    return [{"type": item["name"], "quantity": item["count"]} for item in hotbar if item]


def records_to_vpt_ticks(records: Sequence[Mapping[str, Any]]) -> list[dict]:
    """One episode's Mineflayer records (docs/data-format.md §3.2) -> VPT JSONL tick objects (see module doc)."""
    ticks = []
    mouse_x, mouse_y = SCREEN_CENTER
    prev_keys: list[str] = []
    prev_buttons: list[int] = []
    slot = 0  # fallback when records carry no inventory: follow the hotbar events
    for t, record in enumerate(records):
        action = record["action"]
        keys, buttons = _pressed(action, RECORDED_TO_VPT_KEY), sorted(_pressed(action, RECORDED_TO_VPT_BUTTON))
        dx, dy = _pixels(action["camera"][0]), _pixels(action["camera"][1])
        mouse_x, mouse_y = mouse_x + dx, mouse_y + dy
        events = [k for k in range(1, 10) if action.get(f"hotbar.{k}")]
        slot = events[-1] - 1 if events else slot
        slot = int((record.get("inventory") or {}).get("quickBarSlot", slot))
        ticks.append({
            "mouse": {"x": mouse_x, "y": mouse_y, "dx": dx, "dy": dy,
                      "scaledX": mouse_x - SCREEN_CENTER[0], "scaledY": mouse_y - SCREEN_CENTER[1], "dwheel": 0.0,
                      "buttons": buttons, "newButtons": [b for b in buttons if b not in prev_buttons]},
            "keyboard": {"keys": keys, "newKeys": [k for k in keys if k not in prev_keys], "chars": ""},
            "isGuiOpen": False,
            "isGuiInventory": False,
            "hotbar": slot,
            "yaw": (180.0 - math.degrees(record["yaw"])) % 360.0,
            "pitch": 0.0 - math.degrees(record["pitch"]),
            "xpos": record["x"], "ypos": record["y"], "zpos": record["z"],
            "tick": t,
            "milli": record.get("renderTime", t * SERVER_TICK_MS),
            "inventory": _vpt_inventory(record),
            "serverTick": record.get("worldAgeTicks", t),
            "serverTickDurationMs": SERVER_TICK_MS,
            "stats": {},
        })
        prev_keys, prev_buttons = keys, buttons
    return ticks


# ---------------------------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------------------------


def _place_video(src: Path, dst: Path, link: bool) -> None:
    """Hard-link (falling back to a copy) or copy ``src`` to ``dst``, replacing ``dst``."""
    tmp = dst.with_name(f".{dst.name}.{os.getpid()}.tmp")
    tmp.unlink(missing_ok=True)
    try:
        if link:
            try:
                os.link(src, tmp)
            except OSError:
                shutil.copy2(src, tmp)
        else:
            shutil.copy2(src, tmp)
        os.replace(tmp, dst)
    finally:
        tmp.unlink(missing_ok=True)


def _write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _frame_count(path: Path) -> int:
    import cv2

    cap = cv2.VideoCapture(str(path))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
    cap.release()
    return n


def _export_recording(video: Path, actions: Path, episode_dir: Path, link: bool) -> int:
    """Write one bot recording as a VPT episode; returns its length. Raises ValueError if unusable."""
    try:
        records = json.loads(actions.read_text())
        ticks = records_to_vpt_ticks(records)
    except (OSError, ValueError, KeyError, TypeError, IndexError) as err:
        raise ValueError(f"bad action JSON: {err!r}") from None
    n_frames = _frame_count(video)
    if not ticks or n_frames != len(ticks):
        raise ValueError(f"{n_frames} frames for {len(ticks)} records")
    stem = actions.name.removesuffix(".json")
    _place_video(video, episode_dir / f"{stem}.mp4", link)
    _write_text(episode_dir / f"{stem}.jsonl", "".join(json.dumps(t, separators=(",", ":")) + "\n" for t in ticks))
    return len(ticks)


def export_split(src_split: Path, dst_split: Path, link: bool = True) -> dict[str, int]:
    """Export every bot recording of one Duet split dir; returns counts (exported, skipped reasons)."""
    episode_dir = dst_split / EPISODE_SUBDIR
    episode_dir.mkdir(parents=True, exist_ok=True)
    episodes, counts = [], Counter()
    for video in sorted(src_split.glob("*.mp4"), key=lambda p: p.name):
        actions = video.with_name(video.name.removesuffix(".mp4").removesuffix("_camera") + ".json")
        if not actions.is_file():
            counts["missing_file"] += 1
            logger.warning("export-vpt: %s has no %s; skipped", video.name, actions.name)
            continue
        try:
            length = _export_recording(video, actions, episode_dir, link)
        except ValueError as err:
            counts["skipped"] += 1
            logger.warning("export-vpt: %s skipped: %s", video.name, err)
            continue
        stem = actions.name.removesuffix(".json")
        episodes.append({"video_path": f"{EPISODE_SUBDIR}/{stem}.mp4", "actions_path": f"{EPISODE_SUBDIR}/{stem}.jsonl",
                         "length": length, "episode_id": len(episodes)})
    info = {"num_episodes": len(episodes), "episodes": episodes}
    _write_text(dst_split / "episodes_info.json", json.dumps(info, indent=1))  # the index last
    counts["exported"] = len(episodes)
    return dict(counts)


def export_vpt(src_dir: str | Path, out_dir: str | Path, link: bool = True,
               splits: Sequence[str] = SPLITS) -> dict[str, dict[str, int]]:
    """``src_dir/duet/<split>`` -> ``out_dir/vpt/<split>`` for each split present; returns per-split counts."""
    src_dir, out_dir = Path(src_dir), Path(out_dir)
    result = {}
    for split in splits:
        src_split = src_dir / "duet" / split
        if src_split.is_dir():
            result[split] = export_split(src_split, out_dir / VPT_DIR / split, link)
    if not result:
        raise FileNotFoundError(f"no duet/{{{','.join(splits)}}} directory under {src_dir}")
    return result
