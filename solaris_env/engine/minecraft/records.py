"""Raw tick rows of ``record.js`` -> Mineflayer action records (docs/data-format.md §3.2) and the sidecar.

A raw row is what the recorder saw on one physics tick of one bot: the pose of the state it rendered
(``x y z yaw pitch``, Mineflayer convention, radians), the yaw/pitch right after this tick's look
(``yaw_next pitch_next``), the held ``controls``, the tick's ``events`` (counts of one-tick events,
``mine`` sustained, ``hotbar`` = the new 1-based slot or null), clocks and ``dtMs`` since the bot's
previous tick. Everything here is pure and tested without Minecraft.

Ground truth (no depth buffer from the real renderer): the other player's hitbox (0.6 x 1.8 x 0.6) is
projected with the recorded camera (feet + eye height, yaw, pitch, vertical FOV, display aspect). Its
clipped screen rectangle gives ``visible`` / ``u`` / ``v`` / ``pixel_fraction`` (rectangle area);
blocks do not occlude (the recorded worlds are flat and empty).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from solaris_env.engine.capture import (
    GROUNDTRUTH_FORMAT,
    REGION_LEFT_MAX_U,
    REGION_RIGHT_MIN_U,
    screen_region,
)
from solaris_env.engine.game import RECORD_BOOL_KEYS

CONTROL_KEYS = ("forward", "back", "left", "right", "jump", "sprint", "sneak")
ONCE_KEYS = ("attack", "use", "mount", "dismount", "place_block", "place_entity")  # read-and-reset flags
PLAYER_HALF_WIDTH = 0.3
PLAYER_HEIGHT = 1.8
EYE_HEIGHT = 1.62
NEAR = 0.05
BURST_DT_MS = 25.0  # a tick this soon after the previous one is a physics catch-up tick
MAX_BURST_FRACTION = 0.05  # more catch-up ticks than this fraction of an episode flags it as aborted


def wrap_pi(a: float) -> float:
    """Angle in (-pi, pi]."""
    a = math.fmod(a + math.pi, 2 * math.pi)
    if a <= 0:
        a += 2 * math.pi
    return a - math.pi


def camera_delta(row: Mapping) -> list[float]:
    """[dyaw, dpitch] applied on this tick (shortest arc yaw, Mineflayer sign: + = left / up)."""
    return [round(wrap_pi(row["yaw_next"] - row["yaw"]), 6), round(row["pitch_next"] - row["pitch"], 6)]


def action_record(row: Mapping) -> dict:
    """The 24-key ``action`` object of one raw row (docs/actions.md §6.1): sustained keys from the held controls,
    once flags true when the event happened on this tick, ``mine`` sustained, ``hotbar.k`` on a change."""
    controls, events = row["controls"], row.get("events", {})
    for k in CONTROL_KEYS:
        if k not in controls:
            raise ValueError(f"raw row {row.get('t')}: controls lacks {k!r} (expected all of {CONTROL_KEYS})")
    rec = {k: False for k in RECORD_BOOL_KEYS}
    for k in CONTROL_KEYS:
        rec[k] = bool(controls[k])
    for k in ONCE_KEYS:
        rec[k] = bool(events.get(k, 0))
    rec["mine"] = bool(events.get("mine", False))
    slot = events.get("hotbar")
    if slot is not None:
        if not 1 <= int(slot) <= 9:
            raise ValueError(f"raw row {row.get('t')}: events.hotbar must be 1..9 or null, got {slot}")
        rec[f"hotbar.{int(slot)}"] = True
    rec["camera"] = camera_delta(row)
    return rec


def build_records(rows: Sequence[Mapping], episode: int) -> list[dict]:
    """Per-tick records in the act_recorder layout (docs/data-format.md §3.2) from one bot's raw rows, in tick
    order."""
    out = []
    t0 = None
    last_rt = None
    for i, row in enumerate(rows):
        if row["t"] != i:
            raise ValueError(f"raw rows must be consecutive ticks 0..T-1; row {i} has t={row['t']}")
        rt = int(row["renderTime"])
        if last_rt is not None and rt <= last_rt:  # renderTime must be strictly increasing
            rt = last_rt + 1
        last_rt = rt
        t0 = rt if t0 is None else t0
        slot = int(row.get("quickBarSlot") or 0)
        out.append({
            "x": round(row["x"], 3), "y": round(row["y"], 3), "z": round(row["z"], 3),
            "yaw": round(row["yaw"] % (2 * math.pi), 3), "pitch": round(row["pitch"], 3),
            "action": action_record(row),
            "inventory": {"quickBarSlot": slot, "mainInventory": [], "hotbar": [], "heldItem": None,
                          "offHandItem": None},
            "renderTime": rt,
            "physicsTime": float(row["physicsTime"]),
            "worldAgeTicks": row.get("worldAgeTicks"),
            "isInWater": bool(row.get("isInWater", False)),
            "frame_count": i,
            "episode_id": episode,
            "relativeTimeMs": float(rt - t0),
            "epochTime": rt / 1000.0,
            "extra_info": {"seed": 42},
        })
    return out


def catchup_ticks(rows: Sequence[Mapping], burst_dt_ms: float = BURST_DT_MS) -> int:
    """How many ticks came less than ``burst_dt_ms`` after the previous one (mineflayer catch-up bursts)."""
    return sum(1 for r in rows if r.get("dtMs") is not None and r["dtMs"] < burst_dt_ms)


def edit_events(rows_by_bot: Mapping[str, Sequence[Mapping]], num_ticks: int) -> tuple[dict, dict]:
    """The sidecar's ``blocks`` and ``hits`` column tables (the voxel engine's layout) from the raw rows'
    ``events.placed`` / ``events.mined`` (``[x, y, z, block name]`` lists) and ``events.hits`` (victim
    names), in tick order then bot order, over the first ``num_ticks`` ticks."""
    blocks = {k: [] for k in ("tick", "player", "action", "x", "y", "z", "block")}
    hits = {k: [] for k in ("tick", "attacker", "victim")}
    names = list(rows_by_bot)
    for t in range(num_ticks):
        for name in names:
            events = rows_by_bot[name][t].get("events", {})
            for action, key in (("place", "placed"), ("mine", "mined")):
                for x, y, z, block in events.get(key, []):
                    for k, v in zip(blocks, (t, name, action, int(x), int(y), int(z), str(block))):
                        blocks[k].append(v)
            for victim in events.get("hits", []):
                hits["tick"].append(t)
                hits["attacker"].append(name)
                hits["victim"].append(victim)
    return blocks, hits


# ---------------------------------------------------------------------------------------------
# Ground truth from poses + camera
# ---------------------------------------------------------------------------------------------


def camera_axes(yaw: float, pitch: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward) unit vectors for a Mineflayer yaw/pitch (yaw 0 = -Z, + = turn left; + pitch = up)."""
    fwd = np.array([-math.sin(yaw) * math.cos(pitch), math.sin(pitch), -math.cos(yaw) * math.cos(pitch)])
    right = np.array([math.cos(yaw), 0.0, -math.sin(yaw)])
    return right, np.cross(right, fwd), fwd


def project_box(eye: np.ndarray, yaw: float, pitch: float, bmin: np.ndarray, bmax: np.ndarray,
                fov_deg: float, aspect: float) -> tuple[float, float, float, float] | None:
    """Screen rectangle (u0, v0, u1, v1) in [0, 1] (u: 0 = left, v: 0 = top) covered by an AABB, or None.

    Corners behind the near plane are ignored (boxes partly behind the camera are approximated)."""
    right, up, fwd = camera_axes(yaw, pitch)
    corners = np.array([[x, y, z] for x in (bmin[0], bmax[0]) for y in (bmin[1], bmax[1])
                        for z in (bmin[2], bmax[2])]) - eye
    zf = corners @ fwd
    front = zf > NEAR
    if not front.any():
        return None
    ty = math.tan(math.radians(fov_deg) / 2)
    tx = ty * aspect
    ndc_x = (corners[front] @ right) / (zf[front] * tx)
    ndc_y = (corners[front] @ up) / (zf[front] * ty)
    u0, u1 = (ndc_x.min() + 1) / 2, (ndc_x.max() + 1) / 2
    v0, v1 = (1 - ndc_y.max()) / 2, (1 - ndc_y.min()) / 2
    u0, u1, v0, v1 = max(u0, 0.0), min(u1, 1.0), max(v0, 0.0), min(v1, 1.0)
    if u1 <= u0 or v1 <= v0:
        return None
    return float(u0), float(v0), float(u1), float(v1)


def sight(viewer: Sequence[Mapping], other: Sequence[Mapping], fov_deg: float, aspect: float,
          eye_height: float = EYE_HEIGHT) -> dict:
    """Per-frame visibility of ``other`` (its records) in ``viewer``'s frames (records), same keys as the
    voxel engine's sidecar; frames beyond the shorter record list are not covered."""
    vis, frac, us, vs, dist = [], [], [], [], []
    for a, b in zip(viewer, other):
        eye = np.array([a["x"], a["y"] + eye_height, a["z"]])
        feet = np.array([b["x"], b["y"], b["z"]])
        bmin = feet - np.array([PLAYER_HALF_WIDTH, 0.0, PLAYER_HALF_WIDTH])
        bmax = feet + np.array([PLAYER_HALF_WIDTH, PLAYER_HEIGHT, PLAYER_HALF_WIDTH])
        rect = project_box(eye, a["yaw"], a["pitch"], bmin, bmax, fov_deg, aspect)
        vis.append(rect is not None)
        if rect is None:
            frac.append(0.0)
            us.append(None)
            vs.append(None)
        else:
            u0, v0, u1, v1 = rect
            frac.append(round((u1 - u0) * (v1 - v0), 5))
            us.append(round((u0 + u1) / 2, 4))
            vs.append(round((v0 + v1) / 2, 4))
        dist.append(round(float(np.linalg.norm(feet - np.array([a["x"], a["y"], a["z"]]))), 3))
    return {"visible": vis, "pixel_fraction": frac, "u": us, "v": vs, "region": [screen_region(u) for u in us],
            "distance": dist}


def ground_truth(records_by_bot: Mapping[str, Sequence[Mapping]], frame_size: tuple[int, int], fov_deg: float,
                 aspect: float) -> dict:
    """The sidecar's ground truth (the voxel engine's keys), from the records' poses and the camera model."""
    names = list(records_by_bot)
    T = min(len(r) for r in records_by_bot.values())
    pose = {n: {k: [r[k] for r in recs[:T]] for k in ("x", "y", "z", "yaw", "pitch")}
            for n, recs in records_by_bot.items()}
    sights = {n: {o: sight(records_by_bot[n][:T], records_by_bot[o][:T], fov_deg, aspect) for o in names if o != n}
              for n in names}
    return {
        "format": GROUNDTRUTH_FORMAT,
        "players": names,
        "num_frames": T,
        "frame_size": list(frame_size),
        "regions": {"left_max_u": REGION_LEFT_MAX_U, "right_min_u": REGION_RIGHT_MIN_U},
        "visibility_source": "projected hitbox from poses + camera (no occlusion)",
        "camera": {"fov_deg": fov_deg, "display_aspect": aspect, "eye_height": EYE_HEIGHT},
        "pose": pose,
        "sight": sights,
        "blocks": {k: [] for k in ("tick", "player", "action", "x", "y", "z", "block")},
        "hits": {k: [] for k in ("tick", "attacker", "victim")},
    }
