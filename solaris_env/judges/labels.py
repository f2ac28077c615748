"""Ground-truth labels of the five judge questions, from an episode's sidecar (``capture.ground_truth``).

One pure function per question. Each takes the sidecar dict ``gt`` (the ``*_groundtruth.json``
content: ``sight``, ``pose``, ``blocks``, ``frame_size``), the viewer(s) and frame index(es), and a
:class:`LabelConfig`; it returns the answer word of :mod:`questions` or None where the truth is
ambiguous (a player covering a single pixel, a centroid on a third boundary, a motion that is neither
clearly still nor clearly one direction, a structure half off screen). Nothing here reads videos.

Frame t of a viewer shows state s_t: ``sight[viewer][other][...][t]`` and ``pose[viewer][...][t]``.
A block edit recorded at tick t is first visible in frame t + 1.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from solaris_env.judges.config import LabelConfig

_DEFAULT = LabelConfig()


# ---------------------------------------------------------------------------------------------
# Sidecar accessors
# ---------------------------------------------------------------------------------------------


def _check_frame(gt: Mapping, frame: int) -> None:
    n = int(gt["num_frames"])
    if not 0 <= frame < n:
        raise ValueError(f"frame must be in [0, {n}), got {frame}")


def _others(gt: Mapping, viewer: str) -> list[str]:
    if viewer not in gt["sight"]:
        raise ValueError(f"viewer {viewer!r} is not one of {sorted(gt['sight'])}")
    return sorted(gt["sight"][viewer])


def _the_other(gt: Mapping, viewer: str) -> str:
    others = _others(gt, viewer)
    if len(others) != 1:
        raise ValueError(f"this question is about exactly one other player; {viewer} sees {others}")
    return others[0]


def pixel_count(gt: Mapping, viewer: str, other: str, frame: int) -> int:
    """Avatar pixels of ``other`` in ``viewer``'s frame (from the stored pixel fraction)."""
    h, w = gt["frame_size"]
    return round(gt["sight"][viewer][other]["pixel_fraction"][frame] * h * w)


def visibility_of(pixels: int, cfg: LabelConfig = _DEFAULT) -> bool | None:
    """A player covering ``pixels`` avatar pixels: True / False when clear, None when 1 .. min_visible_pixels-1
    pixels show."""
    if pixels == 0:
        return False
    return True if pixels >= cfg.min_visible_pixels else None


def _clearly_visible(gt: Mapping, viewer: str, other: str, frame: int, cfg: LabelConfig) -> bool | None:
    return visibility_of(pixel_count(gt, viewer, other, frame), cfg)


# ---------------------------------------------------------------------------------------------
# Camera model (the renderer's: Mineflayer yaw/pitch, vertical FOV, 16:9 window)
# ---------------------------------------------------------------------------------------------


def camera_basis(yaw: float, pitch: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(forward, right, up) unit vectors; yaw 0 looks at -Z, +yaw turns left, +pitch looks up."""
    cp = math.cos(pitch)
    fwd = np.array([-math.sin(yaw) * cp, math.sin(pitch), -math.cos(yaw) * cp])
    right = np.array([math.cos(yaw), 0.0, -math.sin(yaw)])
    return fwd, right, np.cross(right, fwd)


def project(points_N3: np.ndarray, eye_3: np.ndarray, yaw: float, pitch: float,
            cfg: LabelConfig = _DEFAULT) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Screen coordinates of world points: (u_N, v_N, depth_N), u/v in [0, 1] on screen (0 = left / top).

    Points behind the camera get depth <= 0 and u = v = nan.
    """
    fwd, right, up = camera_basis(yaw, pitch)
    d_N3 = np.asarray(points_N3, np.float64) - np.asarray(eye_3, np.float64)
    depth = d_N3 @ fwd
    tan_half = math.tan(math.radians(cfg.fov_deg) / 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(depth > 0, (d_N3 @ right) / depth / (tan_half * cfg.display_aspect), np.nan)
        y = np.where(depth > 0, (d_N3 @ up) / depth / tan_half, np.nan)
    return (x + 1.0) / 2.0, (1.0 - y) / 2.0, depth


def _on_screen(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (u >= 0.0) & (u <= 1.0) & (v >= 0.0) & (v <= 1.0)


def _pose(gt: Mapping, viewer: str, frame: int, cfg: LabelConfig) -> tuple[np.ndarray, float, float]:
    p = gt["pose"][viewer]
    eye = np.array([p["x"][frame], p["y"][frame] + cfg.eye_height, p["z"][frame]])
    return eye, float(p["yaw"][frame]), float(p["pitch"][frame])


# ---------------------------------------------------------------------------------------------
# The five questions
# ---------------------------------------------------------------------------------------------


def visible_label(gt: Mapping, viewer: str, frame: int, cfg: LabelConfig = _DEFAULT) -> str | None:
    """Is another player visible on ``viewer``'s screen at ``frame``? "yes" / "no" / None (a single pixel)."""
    _check_frame(gt, frame)
    states = [_clearly_visible(gt, viewer, o, frame, cfg) for o in _others(gt, viewer)]
    if any(s is True for s in states):
        return "yes"
    return "no" if all(s is False for s in states) else None


def position_label(gt: Mapping, viewer: str, frame: int, cfg: LabelConfig = _DEFAULT) -> str | None:
    """Where is the other player on screen: "left" / "center" / "right" by thirds of the avatar
    centroid, "no player" when no pixel shows, None when ambiguous."""
    _check_frame(gt, frame)
    other = _the_other(gt, viewer)
    state = _clearly_visible(gt, viewer, other, frame, cfg)
    if state is None:
        return None
    if not state:
        return "no player"
    u = gt["sight"][viewer][other]["u"][frame]
    lo, hi = gt["regions"]["left_max_u"], gt["regions"]["right_min_u"]
    if min(abs(u - lo), abs(u - hi)) < cfg.region_margin:
        return None
    return "left" if u < lo else ("right" if u >= hi else "center")


def _screen_u(gt: Mapping, viewer: str, other: str, frame: int, cfg: LabelConfig) -> float | None:
    """Horizontal screen position of ``other`` at ``frame``: the avatar centroid when clearly visible;
    for a player too far to resolve (at least ``motion_far_distance`` away, 0-1 pixels, e.g. behind the
    crosshair) the projection of its body centre when that lies on screen; else None."""
    s = gt["sight"][viewer][other]
    state = _clearly_visible(gt, viewer, other, frame, cfg)
    if state:
        return s["u"][frame]
    if s["distance"][frame] < cfg.motion_far_distance:
        return None
    eye, yaw, pitch = _pose(gt, viewer, frame, cfg)
    p = gt["pose"][other]
    return far_screen_u(eye, yaw, pitch, np.array([p["x"][frame], p["y"][frame], p["z"][frame]]), cfg)


def far_screen_u(eye_3: np.ndarray, yaw: float, pitch: float, other_feet_3: np.ndarray,
                 cfg: LabelConfig = _DEFAULT) -> float | None:
    """Horizontal screen position of a player too far to resolve: the projection of its body centre (feet
    + ``avatar_centre_height``) from the camera at ``eye_3`` (yaw / pitch in radians), None when off screen."""
    centre = np.asarray(other_feet_3, np.float64)[None] + np.array([[0.0, cfg.avatar_centre_height, 0.0]])
    u, v, _ = project(centre, eye_3, yaw, pitch, cfg)
    return float(u[0]) if _on_screen(u, v)[0] else None


def motion_scores(gt: Mapping, viewer: str, frame1: int, frame2: int,
                  cfg: LabelConfig = _DEFAULT) -> tuple[float, float] | None:
    """(lateral, radial) motion of the other player between two frames of ``viewer``, in threshold
    units: lateral = du / motion_u_threshold (+ = moved right on screen), radial = ln(d2/d1) /
    motion_log_distance_threshold (+ = farther). None unless the player is clearly visible in one frame
    and visible or too far to resolve (:func:`_screen_u`) in the other."""
    other = _the_other(gt, viewer)
    for f in (frame1, frame2):
        _check_frame(gt, f)
    if not (_clearly_visible(gt, viewer, other, frame1, cfg) or _clearly_visible(gt, viewer, other, frame2, cfg)):
        return None
    u1, u2 = (_screen_u(gt, viewer, other, f, cfg) for f in (frame1, frame2))
    if u1 is None or u2 is None:
        return None
    s = gt["sight"][viewer][other]
    return motion_scores_of(u1, u2, s["distance"][frame1], s["distance"][frame2], cfg)


def motion_scores_of(u1: float, u2: float, d1: float, d2: float,
                     cfg: LabelConfig = _DEFAULT) -> tuple[float, float]:
    """(lateral, radial) in threshold units from the screen positions u and the distances d (blocks) of the
    other player in the two frames (:func:`motion_scores`)."""
    lateral = (u2 - u1) / cfg.motion_u_threshold
    radial = math.log(max(d2, 1e-3) / max(d1, 1e-3)) / cfg.motion_log_distance_threshold
    return lateral, radial


def motion_label(gt: Mapping, viewer: str, frame1: int, frame2: int, cfg: LabelConfig = _DEFAULT) -> str | None:
    """How did the other player move on ``viewer``'s screen from ``frame1`` to ``frame2``:
    "closer" / "farther" / "left" / "right" / "no motion", None when ambiguous or not seen (see
    :func:`motion_scores`)."""
    scores = motion_scores(gt, viewer, frame1, frame2, cfg)
    return None if scores is None else motion_class(*scores, cfg)


def motion_class(lateral: float, radial: float, cfg: LabelConfig = _DEFAULT) -> str | None:
    """The motion answer of (lateral, radial) scores in threshold units (:func:`motion_scores`): "no motion"
    when both are small, else the dominant one's direction, None when neither dominates or both are between
    ``motion_still_max`` and 1."""
    big, small = max(abs(lateral), abs(radial)), min(abs(lateral), abs(radial))
    if big < cfg.motion_still_max:
        return "no motion"
    if big < 1.0 or big < cfg.motion_dominance * small:
        return None
    if abs(lateral) > abs(radial):
        return "right" if lateral > 0 else "left"
    return "farther" if radial > 0 else "closer"


def placed_blocks(gt: Mapping, frame: int) -> list[tuple[int, int, int]]:
    """Cells holding a block placed during the episode, as shown in ``frame`` (edits of ticks < frame)."""
    _check_frame(gt, frame)
    b = gt["blocks"]
    cells: dict[tuple[int, int, int], None] = {}
    for t, action, x, y, z in zip(b["tick"], b["action"], b["x"], b["y"], b["z"]):
        if t >= frame:
            break  # edits are stored in tick order
        cell = (int(x), int(y), int(z))
        if action == "place":
            cells[cell] = None
        else:
            cells.pop(cell, None)
    return list(cells)


_CORNERS_83 = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], np.float64)


def structure_label(gt: Mapping, viewer: str, frame: int, cfg: LabelConfig = _DEFAULT) -> str | None:
    """Is a structure built during the episode visible on ``viewer``'s screen at ``frame``?
    (:func:`structure_on_screen` of the episode's placed blocks from the viewer's pose.)"""
    cells = placed_blocks(gt, frame)
    if not cells:
        return "no"
    return structure_on_screen(np.asarray(cells, np.float64), *_pose(gt, viewer, frame, cfg), cfg)


def structure_on_screen(cells_N3: np.ndarray, eye_3: np.ndarray, yaw: float, pitch: float,
                        cfg: LabelConfig = _DEFAULT) -> str | None:
    """"yes" if a block's centre (cells are integer block corners) projects on screen within
    ``structure_max_distance`` of the eye, "no" if no block has any corner on screen, else None. Occlusion is
    not modelled (the eval worlds are flat, nothing stands between the players and the structure)."""
    cells_N3 = np.asarray(cells_N3, np.float64).reshape(-1, 3)
    if len(cells_N3) == 0:
        return "no"
    u, v, _ = project(cells_N3 + 0.5, eye_3, yaw, pitch, cfg)
    dist = np.linalg.norm(cells_N3 + 0.5 - eye_3, axis=-1)
    if np.any(_on_screen(u, v) & (dist <= cfg.structure_max_distance)):
        return "yes"
    corners = (cells_N3[:, None, :] + _CORNERS_83[None]).reshape(-1, 3)
    cu, cv, _ = project(corners, eye_3, yaw, pitch, cfg)
    return "no" if not np.any(_on_screen(cu, cv)) else None


def view_angle_deg(gt: Mapping, view_a: tuple[str, int], view_b: tuple[str, int]) -> float:
    """Angle between the two views' look directions, degrees in [0, 180]."""
    dirs = []
    for viewer, frame in (view_a, view_b):
        _check_frame(gt, frame)
        p = gt["pose"][viewer]
        dirs.append(camera_basis(float(p["yaw"][frame]), float(p["pitch"][frame]))[0])
    return math.degrees(math.acos(float(np.clip(dirs[0] @ dirs[1], -1.0, 1.0))))


def same_scenery_label(gt: Mapping, view_a: tuple[str, int], view_b: tuple[str, int],
                       cfg: LabelConfig = _DEFAULT) -> str | None:
    """Do two views ``(viewer, frame)`` show the same scenery? "yes" when they look the same way
    (within ``scenery_same_max_deg``) from nearby feet (within ``scenery_max_separation``), "no" when
    the directions differ by at least ``scenery_different_min_deg``, else None."""
    angle = view_angle_deg(gt, view_a, view_b)
    if angle >= cfg.scenery_different_min_deg:
        return "no"
    if angle > cfg.scenery_same_max_deg:
        return None
    feet = [np.array([gt["pose"][v][k][f] for k in ("x", "y", "z")]) for v, f in (view_a, view_b)]
    return "yes" if np.linalg.norm(feet[0] - feet[1]) <= cfg.scenery_max_separation else None
