"""Capture: turn an episode's trace into first-person frames, plus a ground-truth sidecar for judges.

Rendering is done after simulation, in large batches: the ticks of an episode are cut into chunks of
``chunk_ticks``; each chunk gets its world snapshots (``Trace.snapshots``) and the views of all P
players at all its ticks, rendered in one ``Renderer.render`` call (the renderer pads view and
snapshot counts to powers of two, so only a handful of shapes are ever compiled).

View order inside a batch: view ``b = (t - t0) * P + p`` (time-major, then player). Avatars: axis A
holds all P players in trace order, with the viewer itself masked out, so an ``avatar_id`` pixel value
is a player index.

The ground truth (:func:`ground_truth`) says, per frame and viewer, where every other player is on
screen (from the renderer's avatar-id buffer, so occlusion by blocks is exact), plus the poses and the
block edits. Frame t shows state s_t (docs/engine.md §4.3), the same state as record t's pose.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from solaris_env.engine.blocks import item_name
from solaris_env.engine.trace import Trace

if TYPE_CHECKING:
    from solaris_env.engine.game import TickEvents
    from solaris_env.engine.render import Renderer, Views

# Screen regions by the centroid's horizontal coordinate u in [0, 1] (0 = left edge): thirds, the
# split the rotation judge's "left" / "center" / "right" answers refer to (docs/engine.md §7.2).
REGION_LEFT_MAX_U = 1.0 / 3.0  # u < this -> "left"
REGION_RIGHT_MIN_U = 2.0 / 3.0  # u >= this -> "right"; otherwise "center"
REGION_NONE = "none"  # the other player covers no pixel
VISIBLE_MIN_PIXELS = 1  # visible = at least this many avatar pixels
GROUNDTRUTH_FORMAT = "solaris_env.groundtruth/v1"


# ---------------------------------------------------------------------------------------------
# Views
# ---------------------------------------------------------------------------------------------


def views_from_trace(trace: Trace, t0: int, t1: int, world_idx_T: np.ndarray) -> "Views":
    """Views of all P players at ticks ``t0..t1-1``, flattened to B = (t1 - t0) * P (time-major).

    Args:
        trace: a finished trace (arrays, not lists).
        t0, t1: tick range.
        world_idx_T: (t1 - t0,) index of each tick's world snapshot (from ``trace.snapshots``).
    """
    return views_at_ticks(trace, np.arange(t0, t1), world_idx_T)


def views_at_ticks(trace: Trace, ticks_N: np.ndarray, world_idx_N: np.ndarray) -> "Views":
    """Views of all P players at arbitrary ticks (repeats allowed), B = N * P, view b = n * P + p."""
    from solaris_env.engine.render import Views  # jax is imported lazily (CLI start-up time)

    ticks_N = np.asarray(ticks_N, np.int64)
    N, P = len(ticks_N), len(trace.player_names)
    if len(world_idx_N) != N:
        raise ValueError(f"world_idx has {len(world_idx_N)} entries for {N} ticks")

    def per_view(x_TP, dtype):  # (T, P, ...) -> (B, ...)
        x = np.asarray(x_TP, dtype)[ticks_N]
        return x.reshape(N * P, *x.shape[2:])

    def per_avatar(x_TP, dtype):  # (T, P, ...) -> (B, A=P, ...): every viewer sees every player
        x = np.asarray(x_TP, dtype)[ticks_N]
        return np.repeat(x[:, None], P, axis=1).reshape(N * P, P, *x.shape[2:])

    return Views(
        world_idx_B=np.repeat(np.asarray(world_idx_N, np.int32), P),
        eye_B3=per_view(trace.eye_TP3, np.float32),
        yaw_B=per_view(trace.yaw_TP, np.float32),
        pitch_B=per_view(trace.pitch_TP, np.float32),
        avatar_feet_BA3=per_avatar(trace.feet_TP3, np.float32),
        avatar_yaw_BA=per_avatar(trace.yaw_TP, np.float32),
        avatar_pitch_BA=per_avatar(trace.pitch_TP, np.float32),
        avatar_skin_BA=np.broadcast_to(np.asarray(trace.skins, np.int32), (N * P, P)).copy(),
        avatar_swing_BA=per_avatar(trace.swing_TP, np.float32),
        avatar_sneak_BA=per_avatar(trace.sneak_TP, bool),
        avatar_mask_BA=np.tile(~np.eye(P, dtype=bool), (N, 1)),  # a viewer never sees itself
        selected_slot_B=per_view(trace.selected_slot_TP, np.int32),
        hotbar_items_B9=per_view(trace.hotbar_TP9, np.int32),
        daylight_B=np.repeat(np.asarray(trace.daylight_T, np.float32)[ticks_N], P),
    )


def render_episode(trace: Trace, renderer: "Renderer", chunk_ticks: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Render every player's view of every tick, ``chunk_ticks`` ticks (x P views) per renderer call.

    The last chunk is padded to the full chunk length by repeating its last tick, so every call has
    the same number of views and a jitted renderer compiles once per snapshot-count bucket, not once
    per episode-length remainder (~4 s per compile on CPU).

    Returns:
        frames_PTHW3: (P, T, H, W, 3) uint8, frame t of player p = render(s_t).
        avatar_id_PTHW: (P, T, H, W) int8, index of the player seen at each pixel, -1 for none.
    """
    if chunk_ticks < 1:
        raise ValueError(f"chunk_ticks must be >= 1, got {chunk_ticks}")
    T, P = trace.num_ticks, len(trace.player_names)
    H, W = renderer.cfg.height, renderer.cfg.width
    frames_PTHW3 = np.zeros((P, T, H, W, 3), np.uint8)
    avatar_id_PTHW = np.full((P, T, H, W), -1, np.int8)
    for t0 in range(0, T, chunk_ticks):
        t1 = min(T, t0 + chunk_ticks)
        n = t1 - t0
        voxels_KXYZ, world_idx_T = trace.snapshots(t0, t1)
        pad = chunk_ticks - n
        ticks_N = np.concatenate([np.arange(t0, t1), np.full(pad, t1 - 1)])
        world_idx_N = np.concatenate([world_idx_T, np.full(pad, world_idx_T[-1])])
        rgb_BHW3, avatar_id_BHW = renderer.render(voxels_KXYZ, trace.origin, views_at_ticks(trace, ticks_N, world_idx_N))
        frames_PTHW3[:, t0:t1] = rgb_BHW3[: n * P].reshape(n, P, H, W, 3).transpose(1, 0, 2, 3, 4)
        avatar_id_PTHW[:, t0:t1] = avatar_id_BHW[: n * P].reshape(n, P, H, W).transpose(1, 0, 2, 3)
    return frames_PTHW3, avatar_id_PTHW


# ---------------------------------------------------------------------------------------------
# Ground truth
# ---------------------------------------------------------------------------------------------


def screen_region(u: float | None) -> str:
    """'left' / 'center' / 'right' by thirds of the centroid's u, 'none' when not visible."""
    if u is None:
        return REGION_NONE
    if u < REGION_LEFT_MAX_U:
        return "left"
    if u >= REGION_RIGHT_MIN_U:
        return "right"
    return "center"


def _sight(avatar_id_THW: np.ndarray, other: int, feet_T3: np.ndarray, other_feet_T3: np.ndarray) -> dict:
    """Per-frame visibility of player ``other`` in one viewer's frames (arrays per field)."""
    T, H, W = avatar_id_THW.shape
    mask_THW = avatar_id_THW == other
    count_T = mask_THW.sum((1, 2))
    visible_T = count_T >= VISIBLE_MIN_PIXELS
    safe_T = np.maximum(count_T, 1)
    u_T = (mask_THW.sum(1) @ ((np.arange(W) + 0.5) / W)) / safe_T  # column histogram . pixel centres
    v_T = (mask_THW.sum(2) @ ((np.arange(H) + 0.5) / H)) / safe_T
    u = [round(float(x), 4) if vis else None for x, vis in zip(u_T, visible_T)]
    v = [round(float(x), 4) if vis else None for x, vis in zip(v_T, visible_T)]
    dist_T = np.linalg.norm(np.asarray(other_feet_T3, np.float64) - np.asarray(feet_T3, np.float64), axis=-1)
    return {
        "visible": visible_T.tolist(),
        "pixel_fraction": np.round(count_T / (H * W), 5).tolist(),
        "u": u,
        "v": v,
        "region": [screen_region(x) for x in u],
        "distance": np.round(dist_T, 3).tolist(),
    }


def _block_events(tick_events: list[list["TickEvents"]], names: list[str]) -> tuple[dict, dict]:
    """Column tables of block edits and player hits, in tick order then player order."""
    blocks = {k: [] for k in ("tick", "player", "action", "x", "y", "z", "block")}
    hits = {k: [] for k in ("tick", "attacker", "victim")}
    for t, events in enumerate(tick_events):
        for p, ev in enumerate(events):
            edits = [("place", e) for e in ev.placed] + [("mine", e) for e in ev.mined]
            for action, (x, y, z, b) in edits:
                for key, val in zip(blocks, (t, names[p], action, int(x), int(y), int(z), item_name(int(b)))):
                    blocks[key].append(val)
            if ev.hit_player is not None:
                hits["tick"].append(t)
                hits["attacker"].append(names[p])
                hits["victim"].append(names[ev.hit_player])
    return blocks, hits


def ground_truth(trace: Trace, avatar_id_PTHW: np.ndarray, tick_events: list[list["TickEvents"]]) -> dict:
    """The per-episode ground-truth sidecar (JSON-serialisable; arrays per field, indexed by frame).

    Layout::

        players, num_frames, frame_size [H, W], region thresholds,
        pose[viewer] = {x, y, z, yaw, pitch}: feet position and camera at frame t (= record t's pose),
        sight[viewer][other] = {visible, pixel_fraction, u, v, region, distance}: ``u, v`` the avatar
            pixels' centroid in [0, 1] (u: 0 = left edge, v: 0 = top; null when not visible),
            ``region`` by :data:`REGION_LEFT_MAX_U` / :data:`REGION_RIGHT_MIN_U`, ``distance`` between
            the feet positions in blocks,
        blocks = {tick, player, action ('place' | 'mine'), x, y, z, block name} (edits made during tick
            t, first visible in frame t + 1), hits = {tick, attacker, victim}.
    """
    P, T, H, W = avatar_id_PTHW.shape
    names = list(trace.player_names)
    if P != len(names) or T != trace.num_ticks:
        raise ValueError(f"avatar_id_PTHW {avatar_id_PTHW.shape} does not match {len(names)} players x "
                         f"{trace.num_ticks} ticks")
    feet_TP3 = np.asarray(trace.feet_TP3, np.float64)
    pose, sight = {}, {}
    for p, name in enumerate(names):
        pose[name] = {
            "x": np.round(feet_TP3[:, p, 0], 3).tolist(),
            "y": np.round(feet_TP3[:, p, 1], 3).tolist(),
            "z": np.round(feet_TP3[:, p, 2], 3).tolist(),
            "yaw": np.round(np.mod(np.asarray(trace.yaw_TP[:, p], np.float64), 2 * math.pi), 3).tolist(),
            "pitch": np.round(np.asarray(trace.pitch_TP[:, p], np.float64), 3).tolist(),
        }
        sight[name] = {other: _sight(avatar_id_PTHW[p], q, feet_TP3[:, p], feet_TP3[:, q])
                       for q, other in enumerate(names) if q != p}
    blocks, hits = _block_events(tick_events, names)
    return {
        "format": GROUNDTRUTH_FORMAT,
        "players": names,
        "num_frames": T,
        "frame_size": [H, W],
        "regions": {"left_max_u": REGION_LEFT_MAX_U, "right_min_u": REGION_RIGHT_MIN_U},
        "pose": pose,
        "sight": sight,
        "blocks": blocks,
        "hits": hits,
    }
