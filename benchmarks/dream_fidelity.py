"""Dream fidelity: does the dream simulate? Paired rollouts, real engine vs dream, same start, same actions.

    .venv/bin/python -m benchmarks.dream_fidelity                                  # shipped model, ~10 min
    .venv/bin/python -m benchmarks.dream_fidelity --model default --model runs/x/self-forcing/model
    .venv/bin/python -m benchmarks.dream_fidelity --quick --programs forward yaw_right_15 random
    .venv/bin/python -m benchmarks.dream_fidelity --model runs/x/self-forcing/model --out runs/x/fidelity.json

From each engine start state (``make_states``: fresh seeds from 700000, every flat surface and normal
worlds, the partner in view or the learner turned away) the real engine (``RealParallelEnv`` with
``ticks_per_step`` = the model's ``frames_per_step``) plays an action program for both players; the actions
are recorded and the dream (``DreamParallelEnv``, started from the same ``EngineState``) is fed exactly the
same ones. The learner's (Alpha's) two frame sequences are then compared step by step (``PROGRAMS``: walks,
turns, pitch, jump, sprint, the partner walking, mining, placing, random play, a scripted bot episode of
the training mix, standing still). Metrics (pure numpy / OpenCV functions below, no model), per program and step window
(``WINDOWS``) and per start-world surface (grass, snow, sand, red_sand, normal):

* ``view_change_ratio``: mean |frame_t - frame_t-1| (grey levels) of the dream over the engine's.
* ``within_step_change_ratio``: the same inside each env step (its k frames, 20 fps), dream over engine: a
  dream that shows one picture per step and jumps between steps scores 0 here whatever its ``view_change_ratio``.
* ``direction_agreement``: does the dream's view move the way the engine's does (``direction_score``):
  a global camera motion (turn, tilt, zoom) is fitted to every engine frame pair; each pair, engine or
  dream, is scored by how much better that motion explains its change than the reversed motion,
  ``d = (E(-m) - E(m)) / (E(-m) + E(m))`` in [-1, 1]; agreement = mean d(dream) / mean d(engine) over the
  steps whose engine motion is visible (engine d >= ``VALID_SCORE``). Engine against itself = 1, a frozen
  dream = 0 exactly, a time-reversed dream = -1 exactly, a mirrored turn < 0.
* ``frozen_fraction``: of the steps where the engine's view changes > 2 grey levels, the share where the
  dream's changes < 0.5.
* ``drift_fraction``: the mirror image: of the steps where the engine's view changes < 0.5 grey levels (nothing
  moves), the share where the dream's changes > 2 (``stand_still``, the partner programs once the partner
  stands, mining and placing between clicks).
* ``sharpness_ratio``: mean |Laplacian| of the dream's frames over the engine's.
* ``psnr_db``: dream frame vs engine frame.
* ``colour_error``: mean |dream - engine| (grey levels, over RGB) of the frames' ``COLOUR_CELLS`` x
  ``COLOUR_CELLS`` block means: whether the sky stays sky-coloured and the ground ground-coloured (a sky that
  darkens or grass that turns yellow), not where the detail is. A frozen dream on a flat world scores low here;
  the direction and view-change columns judge motion.
* partner agreement: the shipped ``visible`` / ``position`` judges on dream frames (and on engine frames,
  as a sanity check) against the engine's ground truth (avatar pixels and centroid), on partner programs
  and wherever the engine shows the partner.
* ``frechet``: Fréchet distance between dream and engine frame sets in judge features
  (``solaris_env.judges.features``, 192-d; an in-domain distance, comparable between rows only).

Writes ``benchmarks/results/dream_fidelity.json`` (setup, per program x window, per surface, estimator
validation, timings, machine), a contact sheet ``dream_fidelity.png`` (engine rows over dream rows) and a
side-by-side video ``dream_fidelity.mp4`` next to it, and prints a compact table.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import os
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from solaris_env.paths import portable_path

REPO = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).parent / "results" / "dream_fidelity.json"
START_WORLD_XZ = 320  # blocks: the start worlds' width (``make_states``)
DAY_END_TICKS = 12_000  # Minecraft time of day (ticks): 0 sunrise, 6000 noon, 12000 sunset
START_SEED = 700_000  # far from the training (0..) and evaluation (100_000..) start seeds of agents.common
WINDOWS = ((1, 8), (9, 32), (33, 64), (65, 256))  # env steps, inclusive
LEARNER, PARTNER = "Alpha", "Bravo"

# The engine's camera (``engine.constants.FOV_DEG``, ``RenderConfig.display_aspect``): a 16:9 view resampled to
# the frame, so a frame shows ~102 degrees across whatever its pixel size.
FOV_DEG = 70.0
DISPLAY_ASPECT = 16 / 9

# Start worlds: the five flat variants (``worldgen.FLAT_VARIANTS``) and normal terrain, by surface.
WORLD_CLASSES = ("plains", "windswept_hills", "snowy_plains", "desert", "desert_red", "normal")
SURFACE = {"plains": "grass", "windswept_hills": "grass", "snowy_plains": "snow", "desert": "sand",
           "desert_red": "red_sand", "normal": "normal"}
SURFACES = ("grass", "snow", "sand", "red_sand", "normal")

# Thresholds of the metrics (grey levels 0..255 unless said otherwise).
FROZEN_DREAM_MAX = 0.5  # a dream step changing less than this ...
FROZEN_ENGINE_MIN = 2.0  # ... while the engine's changes more than this is "frozen"
DRIFT_ENGINE_MAX = 0.5  # an engine step changing less than this (a still view) ...
DRIFT_DREAM_MIN = 2.0  # ... while the dream's changes more than this is "drifting"
VALID_SCORE = 0.25  # engine direction score from which a step's motion counts as visible
MIN_MOTION = (0.5, 0.5, 0.005)  # |yaw| deg, |pitch| deg, |log zoom|: below all three, no motion to agree with
MAX_MOTION = (24.0, 24.0, 0.15)  # beyond the searched range on any axis: the fit ran off (no trust)
MIN_VISIBLE_PIXELS = 2  # judges.config.LabelConfig.min_visible_pixels
COLOUR_CELLS = 4  # the colour error compares 4 x 4 block means (16 x 16 pixels at 64 x 64)
REGION_MARGIN = 0.03  # LabelConfig.region_margin around the thirds of the screen (capture.REGION_*)


# =============================================================================================
# Pure metrics (numpy / OpenCV; no model, no engine)
# =============================================================================================


def grey_THW(frames_THW3: np.ndarray) -> np.ndarray:
    """float32 grey levels (T, H, W): the mean of the three channels."""
    frames_THW3 = np.asarray(frames_THW3)
    if frames_THW3.ndim != 4 or frames_THW3.shape[-1] != 3:
        raise ValueError(f"frames must be (T, H, W, 3), got {frames_THW3.shape}")
    return frames_THW3.astype(np.float32).mean(axis=-1)


def view_change_T(frames_THW3: np.ndarray) -> np.ndarray:
    """(T - 1,) mean |grey_t - grey_t-1| of consecutive frames; entry t - 1 is the change into frame t."""
    g = grey_THW(frames_THW3)
    return np.abs(np.diff(g, axis=0)).mean(axis=(1, 2)) if len(g) > 1 else np.zeros(0, np.float32)


def within_step_change(frames_kHW3: np.ndarray) -> float:
    """Mean |grey_j - grey_j-1| over the consecutive frames of one env step (its k ticks); 0 for k = 1."""
    change = view_change_T(frames_kHW3)
    return float(change.mean()) if len(change) else 0.0


def sharpness_T(frames_THW3: np.ndarray) -> np.ndarray:
    """(T,) mean |4-neighbour Laplacian| of each grey frame over its interior pixels; any leading axes
    (..., H, W, 3) -> (...)."""
    frames = np.asarray(frames_THW3)
    g = grey_THW(frames.reshape((-1,) + frames.shape[-3:]))
    lap = 4 * g[:, 1:-1, 1:-1] - g[:, :-2, 1:-1] - g[:, 2:, 1:-1] - g[:, 1:-1, :-2] - g[:, 1:-1, 2:]
    return np.abs(lap).mean(axis=(1, 2)).reshape(frames.shape[:-3])


def sharpness_ratio(frames: np.ndarray, reference: np.ndarray) -> float:
    """Mean sharpness of ``frames`` over ``reference``'s (any leading axes, frames last as (H, W, 3))."""
    return round(float(sharpness_T(frames).mean() / max(sharpness_T(reference).mean(), 1e-12)), 3)


def psnr_T(a_THW3: np.ndarray, b_THW3: np.ndarray) -> np.ndarray:
    """(T,) PSNR (dB, peak 255) of each frame pair over RGB; identical frames give +inf."""
    a, b = np.asarray(a_THW3, np.float64), np.asarray(b_THW3, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"frame sets differ in shape: {a.shape} vs {b.shape}")
    mse = ((a - b) ** 2).mean(axis=(1, 2, 3))
    with np.errstate(divide="ignore"):
        return 10 * np.log10(255.0**2 / mse)


def colour_error_T(a_THW3: np.ndarray, b_THW3: np.ndarray, cells: int = COLOUR_CELLS) -> np.ndarray:
    """(T,) mean |a - b| (grey levels, over RGB) of each frame pair's ``cells`` x ``cells`` block means (the
    frame cut into equal blocks; H and W must divide by ``cells``)."""
    a, b = np.asarray(a_THW3, np.float64), np.asarray(b_THW3, np.float64)
    if a.shape != b.shape or a.ndim != 4 or a.shape[-1] != 3:
        raise ValueError(f"frame sets must be equal (T, H, W, 3); got {a.shape} vs {b.shape}")
    t, h, w, _ = a.shape
    if h % cells or w % cells:
        raise ValueError(f"frames of {h} x {w} do not cut into {cells} x {cells} equal blocks")
    block = lambda x: x.reshape(t, cells, h // cells, cells, w // cells, 3).mean(axis=(2, 4))
    return np.abs(block(a) - block(b)).mean(axis=(1, 2, 3))


def frozen_T(dream_change_T: np.ndarray, engine_change_T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(frozen, counted): per step, whether the dream froze (< ``FROZEN_DREAM_MAX``) and whether the engine
    moved (> ``FROZEN_ENGINE_MIN``), the steps the frozen fraction counts."""
    counted = np.asarray(engine_change_T) > FROZEN_ENGINE_MIN
    return counted & (np.asarray(dream_change_T) < FROZEN_DREAM_MAX), counted


def drift_T(dream_change_T: np.ndarray, engine_change_T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(drifting, counted): per step, whether the dream changed (> ``DRIFT_DREAM_MIN``) and whether the engine's
    view stood still (< ``DRIFT_ENGINE_MAX``), the steps the drift fraction counts (``frozen_T`` mirrored)."""
    counted = np.asarray(engine_change_T) < DRIFT_ENGINE_MAX
    return counted & (np.asarray(dream_change_T) > DRIFT_DREAM_MIN), counted


def ratio(num: float, den: float) -> float | None:
    """num / den, None when the denominator is not positive (nothing to compare with)."""
    return float(num) / float(den) if den > 0 else None


# ---------------------------------------------------------------------------------------------
# Direction of motion
# ---------------------------------------------------------------------------------------------
# A view's change from one step to the next is modelled as a global camera motion m = (yaw, pitch, log
# zoom): the camera turns right by ``yaw`` degrees and down by ``pitch`` degrees (MineRL signs, as the env's
# camera action) and the content expands by exp(log zoom) about the centre (a forward walk; strafing and
# jumping show as small turns). ``warp_HW`` renders what a frame would show after such a motion (an exact
# rotation homography of the engine's camera, edges repeated). A pair (a, b) is compared half way:
# E(m) = mean (warp(a, m / 2) - warp(b, -m / 2))^2 over the frame minus its HUD and margins, on blurred grey
# frames (the block textures are finer than the pixels at 64 x 64; only coarse structure moves coherently).
# This makes the score exactly antisymmetric: swapping a and b swaps E(m) and E(-m), and a pair of equal
# frames has E(m) = E(-m).


def camera_tangents() -> tuple[float, float]:
    """(tan of half the horizontal field of view, tan of half the vertical one)."""
    tan_v = math.tan(math.radians(FOV_DEG) / 2)
    return tan_v * DISPLAY_ASPECT, tan_v


@functools.lru_cache(maxsize=4096)
def warp_maps(height: int, width: int, yaw_deg: float, pitch_deg: float, log_zoom: float) -> tuple:
    """(map_x, map_y) float32 (H, W) for ``cv2.remap``: the pixel of the original frame that each pixel of the
    view after the motion (yaw right, pitch down, zoom in) shows."""
    tan_h, tan_v = camera_tangents()
    x = ((np.arange(width) + 0.5) / width * 2 - 1)[None, :] / math.exp(log_zoom)
    y = (1 - (np.arange(height) + 0.5) / height * 2)[:, None] / math.exp(log_zoom)
    rx, ry, rz = np.broadcast_to(x * tan_h, (height, width)), np.broadcast_to(y * tan_v, (height, width)), 1.0
    p, q = math.radians(pitch_deg), math.radians(yaw_deg)
    # the ray in the turned camera -> the original camera: tilt down by p about the right axis, then turn right by q
    ry2, rz2 = ry * math.cos(p) - rz * math.sin(p), ry * math.sin(p) + rz * math.cos(p)
    ox, oz = rx * math.cos(q) + rz2 * math.sin(q), -rx * math.sin(q) + rz2 * math.cos(q)
    ahead = oz > 1e-3
    oz = np.where(ahead, oz, 1.0)
    u = np.where(ahead, ox / (oz * tan_h), 1e3)
    v = np.where(ahead, ry2 / (oz * tan_v), 1e3)
    map_x = ((u + 1) / 2 * width - 0.5).astype(np.float32)
    map_y = ((1 - v) / 2 * height - 0.5).astype(np.float32)
    return map_x, map_y


def warp_HW(grey_HW: np.ndarray, motion: Sequence[float]) -> np.ndarray:
    """The frame as seen after the camera motion (yaw deg, pitch deg, log zoom); bilinear, edges repeated."""
    h, w = grey_HW.shape
    yaw, pitch, zoom = (round(float(v), 4) for v in motion)
    if yaw == 0 and pitch == 0 and zoom == 0:
        return grey_HW
    map_x, map_y = warp_maps(h, w, yaw, pitch, zoom)
    return cv2.remap(grey_HW, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


@functools.lru_cache(maxsize=16)
def compare_mask(height: int, width: int) -> np.ndarray:
    """bool (H, W): the pixels the motion estimate compares: without the side margins (new content enters
    there), the top rows (sky), the hotbar band at the bottom and the crosshair (static HUD, ``engine.hud``)."""
    m = np.zeros((height, width), bool)
    mx, top = max(1, round(width / 8)), max(1, round(height / 16))
    hud_top = int(height * 0.875)  # the hotbar is 22 of 240 GUI units high, plus its selection frame
    m[top:hud_top, mx:width - mx] = True
    c, r = (height // 2, width // 2), max(2, round(height / 24))
    m[c[0] - r:c[0] + r + 1, c[1] - r:c[1] + r + 1] = False
    return m


def prepare_THW(frames_THW3: np.ndarray) -> np.ndarray:
    """Blurred grey frames (T, H, W) float32 for the motion estimate (Gaussian, sigma = 1.5 px at 64 px)."""
    g = grey_THW(frames_THW3)
    sigma = 1.5 * g.shape[2] / 64
    return np.stack([cv2.GaussianBlur(f, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE) for f in g]) \
        if len(g) else g


def pair_error(a_HW: np.ndarray, b_HW: np.ndarray, motion: Sequence[float]) -> float:
    """E(m): mean squared difference of ``a`` moved by m / 2 and ``b`` moved back by m / 2 (compared pixels)."""
    half = np.asarray(motion, np.float64) / 2
    d = warp_HW(a_HW, half) - warp_HW(b_HW, -half)
    return float(np.mean(d[compare_mask(*a_HW.shape)] ** 2))


def direction_score(a_HW: np.ndarray, b_HW: np.ndarray, motion: Sequence[float]) -> float:
    """(E(-m) - E(m)) / (E(-m) + E(m)) in [-1, 1]: + when the change a -> b looks like the motion m, - when it
    looks like its reverse, 0 for no change at all (prepared frames, ``prepare_THW``)."""
    m = np.asarray(motion, np.float64)
    forward, backward = pair_error(a_HW, b_HW, m), pair_error(a_HW, b_HW, -m)
    total = forward + backward
    return (backward - forward) / total if total > 1e-12 else 0.0


_COARSE = np.arange(-24.0, 24.1, 3.0)  # degrees: the grid of turns tried first (the model clips at 20 per step)
_ZOOMS = np.arange(-0.15, 0.151, 0.03)


def fit_motion(a_HW: np.ndarray, b_HW: np.ndarray) -> np.ndarray:
    """The camera motion (yaw, pitch, log zoom) that best explains a -> b (min E) on prepared frames: on a
    half-size copy (frames wider than 48 px), line searches over the turn grid (yaw, then pitch, twice) and
    over zoom; then a coordinate search with halving steps at full size."""
    h, w = a_HW.shape
    if w > 48:
        small = (w // 2, h // 2)
        a_s, b_s = (cv2.resize(x, small, interpolation=cv2.INTER_AREA) for x in (a_HW, b_HW))
    else:
        a_s, b_s = a_HW, b_HW
    best, best_e = np.zeros(3), pair_error(a_s, b_s, (0.0, 0.0, 0.0))
    lines = [(0, _COARSE), (1, _COARSE), (0, _COARSE), (1, _COARSE), (2, _ZOOMS)]
    for axis, grid in lines:
        for value in grid:
            cand = best.copy()
            cand[axis] = value
            e = pair_error(a_s, b_s, cand)
            if e < best_e:
                best, best_e = cand, e
    best_e = pair_error(a_HW, b_HW, best)
    steps = np.array([1.5, 1.5, 0.015])
    for _ in range(4):
        for axis in range(3):
            for sign in (-1.0, 1.0):
                cand = best.copy()
                cand[axis] += sign * steps[axis]
                e = pair_error(a_HW, b_HW, cand)
                if e < best_e:
                    best, best_e = cand, e
        steps = steps / 2
    return best


def has_motion(motion_N3: np.ndarray) -> np.ndarray:
    """(N,) bool: a fitted motion at least ``MIN_MOTION`` on some axis and inside the searched range
    (``MAX_MOTION``; a fit that ran off its grid found no motion that explains the change)."""
    size = np.abs(np.asarray(motion_N3, np.float64).reshape(-1, 3))
    return (size >= np.asarray(MIN_MOTION)).any(axis=-1) & (size <= np.asarray(MAX_MOTION)).all(axis=-1)


def direction_scores(engine_THW3: np.ndarray, dream_THW3: np.ndarray | None = None,
                     motion_T3: np.ndarray | None = None) -> dict:
    """Per step t = 1..T-1 of a paired rollout: the engine's fitted motion (T - 1, 3) (or the given
    ``motion_T3``), the engine's direction score and, with ``dream_THW3``, the dream's under the engine's motion.

    Returns ``{"motion": (T-1, 3), "engine": (T-1,), "dream": (T-1,) or None, "valid": (T-1,) bool}``; valid =
    the engine moved (``has_motion``) and its motion shows (engine score >= ``VALID_SCORE``)."""
    e = prepare_THW(engine_THW3)
    motion = np.array([fit_motion(e[t - 1], e[t]) for t in range(1, len(e))]).reshape(-1, 3) \
        if motion_T3 is None else np.asarray(motion_T3, np.float64).reshape(-1, 3)
    s_e = np.array([direction_score(e[t - 1], e[t], motion[t - 1]) for t in range(1, len(e))])
    valid = has_motion(motion) & (s_e >= VALID_SCORE)
    s_d = None
    if dream_THW3 is not None:
        d = prepare_THW(dream_THW3)
        if d.shape != e.shape:
            raise ValueError(f"engine and dream frames differ in shape: {e.shape} vs {d.shape}")
        s_d = np.array([direction_score(d[t - 1], d[t], motion[t - 1]) for t in range(1, len(d))])
    return {"motion": motion, "engine": s_e, "dream": s_d, "valid": valid}


def direction_agreement(engine_scores: np.ndarray, dream_scores: np.ndarray, valid: np.ndarray) -> float | None:
    """mean dream score / mean engine score over the valid steps: 1 = moves as the engine does, 0 = no motion
    (frozen) or unrelated motion, < 0 = the reverse; None without valid steps."""
    valid = np.asarray(valid, bool)
    if not valid.any():
        return None
    return ratio(np.mean(np.asarray(dream_scores)[valid]), np.mean(np.asarray(engine_scores)[valid]))


# ---------------------------------------------------------------------------------------------
# Partner ground truth (the judges' labels, ``judges.labels``, from the env's per-step infos)
# ---------------------------------------------------------------------------------------------


def visible_truth(pixels: int) -> str | None:
    """"yes" (>= ``MIN_VISIBLE_PIXELS`` avatar pixels), "no" (none) or None (a single pixel: ambiguous)."""
    return "no" if pixels == 0 else ("yes" if pixels >= MIN_VISIBLE_PIXELS else None)


def position_truth(pixels: int, u: float | None) -> str | None:
    """"left" / "center" / "right" by thirds of the avatar centroid, "no player", or None when ambiguous."""
    seen = visible_truth(pixels)
    if seen is None:
        return None
    if seen == "no":
        return "no player"
    lo, hi = 1 / 3, 2 / 3
    if min(abs(u - lo), abs(u - hi)) < REGION_MARGIN:
        return None
    return "left" if u < lo else ("right" if u >= hi else "center")


def agreement(answers: Sequence[str], truth: Sequence[str | None], scope: np.ndarray) -> tuple[int, int]:
    """(matches, counted) of judge answers against truths inside ``scope``, skipping ambiguous truths (None)."""
    return pooled(class_agreement(answers, truth, scope))


def pooled(per_class: dict[str, list[int]]) -> tuple[int, int]:
    """(matches, counted) summed over the truth classes of ``class_agreement``."""
    return sum(h for h, _ in per_class.values()), sum(n for _, n in per_class.values())


def class_agreement(answers: Sequence[str], truth: Sequence[str | None], scope: np.ndarray) -> dict[str, list[int]]:
    """Per truth class, [matches, counted] of judge answers inside ``scope`` (ambiguous truths skipped)."""
    out: dict[str, list[int]] = {}
    for a, t, s in zip(answers, truth, scope):
        if s and t is not None:
            counts = out.setdefault(t, [0, 0])
            counts[0] += a == t
            counts[1] += 1
    return out


def balanced_agreement(per_class: dict[str, list[int]]) -> float:
    """The mean over the truth classes present of each class's agreement: a judge that gives one answer to every
    frame scores 1 / (number of classes), whatever the classes' shares (the judges answer "yes, centre" to noise;
    docs/evaluation.md). NaN when nothing was counted."""
    rates = [h / n for h, n in per_class.values() if n]
    return float(np.mean(rates)) if rates else float("nan")


# =============================================================================================
# Action programs
# =============================================================================================


@dataclass(frozen=True)
class Program:
    """One action program: ``steps`` env steps; ``kind`` says who acts: ``"learner"`` (the partner idles),
    ``"partner"`` (the learner stands; started with the partner in view), ``"both"`` (random play, the bot
    episode)."""

    name: str
    steps: int
    kind: str
    doc: str


PITCH_CYCLE = (6, 5.0, 2, 15.0)  # pitch programs: 6 steps of 5 deg the program's way, then 2 of 15 deg back


PROGRAMS: dict[str, Program] = {p.name: p for p in (
    Program("forward", 64, "learner", "hold forward"),
    Program("back", 64, "learner", "hold back"),
    Program("strafe_left", 64, "learner", "hold left"),
    Program("strafe_right", 64, "learner", "hold right"),
    Program("yaw_right_5", 64, "learner", "turn right 5 deg per step"),
    Program("yaw_left_5", 64, "learner", "turn left 5 deg per step"),
    Program("yaw_right_15", 64, "learner", "turn right 15 deg per step"),
    Program("yaw_left_15", 64, "learner", "turn left 15 deg per step"),
    Program("pitch_up", 64, "learner", "look up 5 deg per step for 6 steps, then down 15 deg per step for 2 "
                                       "(bounded: the view swings 30 deg above the start, never pins at 90)"),
    Program("pitch_down", 64, "learner", "look down 5 deg per step for 6 steps, then up 15 deg for 2 (bounded)"),
    Program("jump", 64, "learner", "hold jump"),
    Program("sprint_forward", 64, "learner", "hold forward + sprint"),
    Program("partner_toward", 64, "partner", "the partner walks towards the learner until 2 blocks away, then "
                                             "stands"),
    Program("partner_away", 64, "partner", "the partner walks backwards, away from the learner, until 20 "
                                           "blocks away, then stands"),
    Program("partner_across", 64, "partner", "the partner strafes across the learner's view: left 8 steps, "
                                             "right 16, left 16, right 16, left 8"),
    Program("mine", 64, "learner", "select the diamond pickaxe, look down 45 deg (3 steps), then hold attack "
                                   "(attack is a once-key: only the first tick of each step digs)"),
    Program("place", 64, "learner", "select stone, look down 45 deg (3 steps), then use every 8th step"),
    Program("random", 256, "both", "random play of both players: held keys re-drawn every 4 steps, smooth "
                                   "random turns of at most 15 deg, pitch pulled back towards level"),
    Program("bot", 256, "both", "one scripted bot episode of the training mix (both players), every k ticks of "
                                "the bots' actions merged into one env step"),
    # last, so that adding it (session 47) left every earlier program's start states as they were
    # (``assign_states``' cursors carry over from program to program)
    Program("stand_still", 64, "learner", "no-op: both players stand still (the engine's view does not change)"),
)}


def make_action(camera: tuple[float, float] = (0.0, 0.0), **keys: int) -> dict:
    """An env action: ``camera`` = (dpitch, dyaw) degrees (MineRL: + = down, + = right); keys by name
    (``hotbar_2=1`` for ``hotbar.2``)."""
    from solaris_env.spaces import CAMERA_KEY, noop

    action = noop()
    for key, value in keys.items():
        action[key.replace("hotbar_", "hotbar.")] = int(value)
    action[CAMERA_KEY] = np.array(camera, np.float32)
    return action


def _distance(infos: dict) -> float:
    return float(np.linalg.norm(np.asarray(infos[LEARNER]["pos"]) - np.asarray(infos[PARTNER]["pos"])))


def learner_action(name: str, t: int) -> dict:
    """Step t's action of the learner in a ``"learner"`` program."""
    fixed = {"stand_still": {}, "forward": {"forward": 1}, "back": {"back": 1}, "strafe_left": {"left": 1},
             "strafe_right": {"right": 1}, "jump": {"jump": 1}, "sprint_forward": {"forward": 1, "sprint": 1},
             "yaw_right_5": {"camera": (0.0, 5.0)}, "yaw_left_5": {"camera": (0.0, -5.0)},
             "yaw_right_15": {"camera": (0.0, 15.0)}, "yaw_left_15": {"camera": (0.0, -15.0)}}
    if name in fixed:
        return make_action(**fixed[name])
    if name in ("pitch_up", "pitch_down"):
        sign = -1.0 if name == "pitch_up" else 1.0  # MineRL: + pitch looks down
        n_way, deg_way, n_back, deg_back = PITCH_CYCLE
        way = t % (n_way + n_back) < n_way
        return make_action(camera=(sign * deg_way if way else -sign * deg_back, 0.0))
    if name in ("mine", "place"):
        if t < 3:  # select the tool / block, look down 3 x 15 deg
            return make_action(camera=(15.0, 0.0), **({"hotbar_2" if name == "mine" else "hotbar_1": 1}
                                                     if t == 0 else {}))
        if name == "mine":
            return make_action(attack=1)
        return make_action(use=int((t - 3) % 8 == 0))
    raise ValueError(f"{name!r} is not a learner program; learner programs: "
                     f"{[p.name for p in PROGRAMS.values() if p.kind == 'learner']}")


def partner_action(name: str, t: int, infos: dict) -> dict:
    """Step t's action of the partner in a ``"partner"`` program (closed loop on the engine's infos)."""
    if name == "partner_toward":
        return make_action(forward=int(_distance(infos) > 2.0))
    if name == "partner_away":
        return make_action(back=int(_distance(infos) < 20.0))
    if name == "partner_across":
        phase = t % 64
        return make_action(left=1) if phase < 8 or 24 <= phase < 40 or phase >= 56 else make_action(right=1)
    raise ValueError(f"{name!r} is not a partner program")


class RandomPlay:
    """Random play of both players (seeded): held movement keys re-drawn every 4 steps, a smoothly varying
    yaw turn (at most 15 deg per step) and a pitch turn pulled back towards level (closed loop on the
    engine's pitch), rare attack and use clicks."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)
        self.keys = {LEARNER: {}, PARTNER: {}}
        self.yaw = {LEARNER: 0.0, PARTNER: 0.0}

    def __call__(self, t: int, infos: dict) -> dict:
        out = {}
        for agent in (LEARNER, PARTNER):
            rng = self.rng
            if t % 4 == 0:
                forward = rng.random() < 0.5
                keys = {"forward": int(forward), "back": int(not forward and rng.random() < 0.25),
                        "jump": int(rng.random() < 0.15), "sprint": int(forward and rng.random() < 0.3)}
                side = rng.choice(["", "left", "right"], p=[0.6, 0.2, 0.2])
                if side:
                    keys[side] = 1
                self.keys[agent] = keys
            self.yaw[agent] = float(np.clip(0.7 * self.yaw[agent] + rng.normal(0.0, 5.0), -15.0, 15.0))
            pitch_up_deg = math.degrees(float(infos[agent]["pitch"]))  # the engine's pitch: + = up
            dpitch = float(np.clip(rng.normal(0.0, 3.0) + 0.15 * pitch_up_deg, -10.0, 10.0))  # + = down
            out[agent] = make_action(camera=(dpitch, self.yaw[agent]), attack=int(rng.random() < 0.05),
                                     use=int(rng.random() < 0.03), **self.keys[agent])
        return out


def merge_ticks(ticks: Sequence[dict]) -> dict:
    """k per-tick env actions -> one env step's action, for the envs' step rule (``spaces.step_ticks``): held
    keys pressed on at least half of the ticks, once-keys pressed on any, the camera turns summed and clipped to
    what k ticks turn (k x ``CAMERA_TICK_LIMIT_DEG`` per axis; the bots never turn faster, so nothing is carried
    over into the next step)."""
    from solaris_env.spaces import (
        BINARY_KEYS,
        CAMERA_KEY,
        CAMERA_TICK_LIMIT_DEG,
        ONCE_KEYS,
        noop,
    )

    action = noop()
    for key in BINARY_KEYS:
        n = sum(int(t[key]) for t in ticks)
        action[key] = int(n > 0) if key in ONCE_KEYS else int(2 * n >= len(ticks))
    camera = np.sum([np.asarray(t[CAMERA_KEY], np.float64) for t in ticks], axis=0)
    limit = float(np.float32(len(ticks) * CAMERA_TICK_LIMIT_DEG)) * (1 - 1e-6)
    action[CAMERA_KEY] = np.clip(camera, -limit, limit).astype(np.float32)
    return action


@dataclass
class BotEpisode:
    start: object  # EngineState after setup and the 1 s pre-roll
    actions: list  # per env step {agent: action}
    episode_type: str
    world: str
    world_age: int
    active_steps: int  # steps before both bots finished (the rest are no-ops)
    config: dict


def bot_episode(steps: int, k: int, seed: int = START_SEED, world_kind: str = "normal",
                max_tries: int = 40) -> BotEpisode:
    """A scripted training episode (type drawn by the training mix's sampler, ``registry.sample_type``) in
    daylight whose bots act for ``steps`` x ``k`` ticks: the first such episode of ``EpisodeConfig(seed, 0,
    episode)``, episode = 0, 1, ... (else the longest of ``max_tries``). Training episodes start at a random
    time of day; night ones are skipped (dark frames say little about the dream). The bots are driven tick by
    tick as ``runner.run_episode`` drives them (``setup_episode``, ``next_actions``, ``release_barrier``); every k
    ticks of their actions become one env step (``merge_ticks``)."""
    from solaris_env.engine.bots import registry, runner
    from solaris_env.engine.bots.controller import EpisodeAbort
    from solaris_env.real_env import EngineState
    from solaris_env.spaces import noop

    best = None
    for episode in range(max_tries):
        cfg = runner.EpisodeConfig(seed=seed, instance=0, episode=episode, world_kind=world_kind)
        shared, world_seed = runner.episode_seeds(cfg)
        etype = registry.sample_type(np.random.default_rng(shared))
        spec = registry.get(etype)
        if spec.world is not None and spec.world != world_kind:
            continue
        game, bots = runner.setup_episode(cfg, spec, world_seed, shared)
        if game.world_age0 % 24000 >= DAY_END_TICKS:
            continue
        for _ in range(runner.PRE_ROLL_TICKS):
            game.step([noop() for _ in bots])
        start, age = EngineState.of(game), int(game.world_age0 + game.tick)
        gens = [spec.behaviour(b) for b in bots]
        n = len(bots)
        done, waiting, ticks = [False] * n, [None] * n, []
        try:
            while len(ticks) < steps * k:
                actions, _ = runner.next_actions(gens, waiting, done)
                if all(done):
                    break
                runner.release_barrier(bots, waiting, done)
                game.step(actions)
                ticks.append(actions)
        except EpisodeAbort:
            pass
        if best is None or len(ticks) > len(best[1]):
            best = (start, ticks, etype, world_seed, age, cfg)
        if len(ticks) >= steps * k:
            break
    if best is None:
        raise RuntimeError(f"no daylight {world_kind} training episode among {max_tries} tries of seed {seed}")
    start, ticks, etype, world_seed, age, cfg = best
    active = len(ticks) // k
    ticks = ticks + [[noop(), noop()]] * (steps * k - len(ticks))
    actions = [{agent: merge_ticks([ticks[s * k + j][i] for j in range(k)]) for i, agent in enumerate((LEARNER, PARTNER))}
               for s in range(steps)]
    return BotEpisode(start, actions, etype, world_kind, age, active,
                      {"seed": cfg.seed, "instance": cfg.instance, "episode": cfg.episode, "world_seed": world_seed})


# =============================================================================================
# Start states
# =============================================================================================


@dataclass
class StartState:
    state: object  # EngineState
    seed: int
    world: str  # one of WORLD_CLASSES
    in_view: bool  # the partner shows on the learner's screen (>= MIN_VISIBLE_PIXELS pixels)
    partner_pixels: int
    turn_deg: float  # the learner's yaw turn after spawning (0: facing the partner)
    distance: float

    @property
    def surface(self) -> str:
        return SURFACE[self.world]

    def describe(self) -> dict:
        return {"seed": self.seed, "world": self.world, "surface": self.surface, "partner_in_view": self.in_view,
                "partner_pixels": self.partner_pixels, "learner_turn_deg": round(self.turn_deg, 1),
                "distance_blocks": round(self.distance, 2)}


def make_states(per_world: int, start_seed: int = START_SEED, resolution: int | tuple[int, int] = 64,
                normal: int | None = None) -> list[StartState]:
    """``per_world`` engine states of each flat variant and ``normal`` (default 2 x per_world) of normal worlds,
    half with the partner in view (as spawned: the players face each other, 6-10 blocks apart), half with the
    learner turned away by a random yaw of 70-180 deg until no partner pixel shows (one engine tick with the
    whole turn, on the game itself, as ``agents.common.make_start_states``: the env would spread it over
    several steps). Reset seeds start at ``start_seed``; the flat variant is the reset seed's draw, so
    seeds are tried in order and each one goes to the first world class still short of states (in-view
    states whose partner is hidden, e.g. behind a hill, are skipped).

    The worlds are ``START_WORLD`` boxes: twice the env's default width with the same spawn square around the
    centre, so no program reaches the edge of the world (a 64-step sprint covers ~72 blocks; in the default
    160-block box the players spawn as little as 34 blocks from the edge, beyond which the view shows void)."""
    from solaris_env.engine.worldgen import WorldConfig
    from solaris_env.real_env import RealParallelEnv, render_game_views, screen_position

    want = {w: per_world for w in WORLD_CLASSES}
    want["normal"] = 2 * per_world if normal is None else normal
    have: dict[str, list[StartState]] = {w: [] for w in WORLD_CLASSES}
    env = RealParallelEnv(num_players=2, world="flat", resolution=resolution)
    default = WorldConfig()
    env.world_config = WorldConfig(size_xz=START_WORLD_XZ, margin=START_WORLD_XZ // 2 - round(
        default.playable_half_extent))  # the default spawn square (+-56 blocks), 104 blocks from the edge
    seed = start_seed
    while any(len(have[w]) < want[w] for w in WORLD_CLASSES):
        kind = "flat" if any(len(have[w]) < want[w] for w in WORLD_CLASSES if w != "normal") else "normal"
        _, infos = env.reset(seed=seed, options={"world": kind})
        world = env.game.world.variant if kind == "flat" else "normal"
        if len(have[world]) < want[world]:
            in_view = len(have[world]) % 2 == 0
            pixels = infos[LEARNER]["screen"][PARTNER]["pixels"]
            turn = 0.0
            if not in_view:
                rng = np.random.default_rng(seed)
                for _ in range(8):
                    env.reset(seed=seed, options={"world": kind})
                    turn = float(rng.choice([-1.0, 1.0]) * rng.uniform(70.0, 180.0))
                    env.game.step([make_action(camera=(0.0, turn)), make_action()])
                    _, avatar_id_PHW = render_game_views(env.game, env.height, env.width, env.view_distance, env.hud)
                    pixels = screen_position(avatar_id_PHW[0], 1)["pixels"]
                    if pixels == 0:
                        break
            if (pixels >= MIN_VISIBLE_PIXELS) == in_view and (in_view or pixels == 0):
                distance = float(np.linalg.norm(env.game.players[0].pos - env.game.players[1].pos))
                have[world].append(StartState(env.engine_state(), seed, world, in_view, int(pixels), turn, distance))
        seed += 1
    return [s for w in WORLD_CLASSES for s in have[w]]


def assign_states(states: Sequence[StartState], programs: Sequence[Program], per_program: int,
                  per_long_program: int) -> dict[str, list[int]]:
    """Which start states (indices) each program runs from: one normal world first (where the motion shows
    most), then flat worlds rotating through the variants; in view and turned away alternate (partner
    programs: in view only). Cursors carry over between programs, so the states are used about equally."""
    def interleave(idx):  # round-robin over the world classes
        by_class = [[i for i in idx if states[i].world == w] for w in WORLD_CLASSES]
        out = []
        for r in range(max((len(c) for c in by_class), default=0)):
            out += [c[r] for c in by_class if r < len(c)]
        return out

    pools = {(normal, view): interleave([i for i, s in enumerate(states) if (s.world == "normal") == normal
                                         and s.in_view == view]) for normal in (True, False) for view in (True, False)}
    cursor = {key: 0 for key in pools}

    def take(normal: bool, view: bool) -> int | None:
        for v in (view, not view):  # fall back to the other side if a pool is empty
            pool = pools[(normal, v)]
            if pool:
                i = pool[cursor[(normal, v)] % len(pool)]
                cursor[(normal, v)] += 1
                return i
        return None

    out = {}
    for k, prog in enumerate(programs):
        if prog.kind == "bot" or prog.name == "bot":
            out[prog.name] = []
            continue
        n = per_long_program if prog.steps > 64 else per_program
        chosen = []
        for j in range(n):
            view = True if prog.kind == "partner" else (k + j) % 2 == 0
            i = take(j == 0, view)
            if i is None:
                i = take(j != 0, view)
            if i is not None and i not in chosen:
                chosen.append(i)
        out[prog.name] = chosen
    return out


# =============================================================================================
# Rollouts
# =============================================================================================


@dataclass
class Rollout:
    """One program from one start state in the engine, and what is needed to replay it in the dream."""

    program: str
    kind: str
    state_index: int  # into the run's start states; -1 for the bot episode (its own start)
    start: object  # EngineState
    surface: str
    in_view: bool
    seed: int  # the dream's reset seed (the same for every model)
    actions: list  # per step {agent: action}
    engine_THW3: np.ndarray  # (T + 1, H, W, 3) uint8: the learner's observations, reset included
    pixels_T: np.ndarray  # (T + 1,) the partner's avatar pixels on the learner's screen
    u_T: list  # (T + 1,) their centroid's horizontal position, None when no pixel shows
    yaw_pitch_T2: np.ndarray  # (T + 1, 2) the learner's view direction, degrees (MineRL: + = right, + = down)
    within_T: np.ndarray | None = None  # (T,) the engine's ``within_step_change`` of the learner per step


def rollout_seed(program: str, state_index: int) -> int:
    return zlib.crc32(f"dream_fidelity/{program}/{state_index}".encode()) & 0x7FFFFFFF


def engine_rollout(env, program: Program, start, state_index: int, surface: str, in_view: bool,
                   actions: list | None = None) -> Rollout:
    """Play ``program`` in the engine from ``start`` (closed loop where the program reads the engine), or the
    given per-step ``actions``; record everything the dream replay and the metrics need."""
    obs, infos = env.reset(seed=0, options={"engine_state": start})
    frames, pixels, us, views, played, within = [obs[LEARNER]], [], [], [], [], []
    learner = env.possible_agents.index(LEARNER)
    random_play = RandomPlay(rollout_seed(program.name, state_index)) if program.name == "random" else None

    def record(infos):
        s = infos[LEARNER]["screen"][PARTNER]
        pixels.append(s["pixels"])
        us.append(s["u"])
        # engine pose: Mineflayer yaw (+ = left), pitch (+ = up), radians
        views.append((-math.degrees(infos[LEARNER]["yaw"]), -math.degrees(infos[LEARNER]["pitch"])))

    record(infos)
    for t in range(program.steps):
        if actions is not None:
            step = actions[t]
        elif random_play is not None:
            step = random_play(t, infos)
        elif program.kind == "partner":
            step = {LEARNER: make_action(), PARTNER: partner_action(program.name, t, infos)}
        else:
            step = {LEARNER: learner_action(program.name, t), PARTNER: make_action()}
        played.append(step)
        obs, _, _, _, infos = env.step(step)
        frames.append(obs[LEARNER])
        within.append(within_step_change(env.step_frames()[learner]))
        record(infos)
    return Rollout(program.name, program.kind, state_index, start, surface, in_view,
                   rollout_seed(program.name, state_index), played, np.stack(frames), np.asarray(pixels),
                   us, np.asarray(views, np.float64), np.asarray(within, np.float32))


def dream_rollout(env, rollout: Rollout, dream_seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(frames (T + 1, H, W, 3) uint8, within (T,)): the learner's dream observations from the same start with the
    same actions, and each step's ``within_step_change``; ``dream_seed`` moves the dream's sampling noise only
    (``--dream-seed``: the metrics' noise floor)."""
    obs, _ = env.reset(seed=rollout.seed + dream_seed, options={"engine_state": rollout.start})
    learner = env.possible_agents.index(LEARNER)
    frames, within = [obs[LEARNER]], []
    for step in rollout.actions:
        obs, *_ = env.step(step)
        frames.append(obs[LEARNER])
        within.append(within_step_change(env.step_frames()[learner]))
    return np.stack(frames), np.asarray(within, np.float32)


DREAM_BATCH = 16  # worlds per batched dream call (``dream_rollouts``)


def dream_batches(rollouts: Sequence[Rollout], batch: int = DREAM_BATCH) -> list[list[int]]:
    """Indices of ``rollouts`` in batches that step together: rollouts of one length, in their order, split into
    the fewest batches of at most ``batch``, as even as possible (so a length compiles one or two shapes)."""
    if batch < 1:
        raise ValueError(f"batch must be >= 1, got {batch}")
    by_length: dict[int, list[int]] = {}
    for i, r in enumerate(rollouts):
        by_length.setdefault(len(r.actions), []).append(i)
    out = []
    for idx in by_length.values():
        n = math.ceil(len(idx) / batch)
        size = math.ceil(len(idx) / n)
        out.extend(idx[j:j + size] for j in range(0, len(idx), size))
    return out


def dream_rollouts(env, rollouts: Sequence[Rollout], dream_seed: int = 0,
                   batch: int = DREAM_BATCH) -> list[tuple[np.ndarray, np.ndarray]]:
    """``dream_rollout`` of every rollout, stepped ``batch`` worlds at a time through ``env.model`` (a
    ``DreamParallelEnv``): each world starts exactly as ``env.reset(seed=rollout.seed + dream_seed,
    options={"engine_state": rollout.start})`` starts it (the same start frames and model seed, so the same
    sampling noise) and gets the same per-tick actions (``dream_env.world_actions``); the worlds' states are
    joined on the batch axis. Batched matmuls may round differently from B = 1, so frames can differ from
    ``dream_rollout``'s by a grey level here and there (tests/benchmarks/test_dream_fidelity.py)."""
    import jax
    import jax.numpy as jnp

    from solaris_env.dream_env import world_actions
    from solaris_env.env_common import episode_rng

    model, agents = env.model, env.possible_agents
    learner, k = agents.index(LEARNER), model.frames_per_step
    out: list = [None] * len(rollouts)
    for idx in dream_batches(rollouts, batch):
        states = []
        for i in idx:  # DreamParallelEnv.reset, world by world
            rng = episode_rng(None, rollouts[i].seed + dream_seed)
            first_PHW3, _ = env.start_frames.from_options({"engine_state": rollouts[i].start})
            poses = rollouts[i].start.poses[None] if model.config.dit.partner_map else None  # docs/model.md §8.6
            states.append(model.init(first_PHW3[None], int(rng.integers(2**31 - 1)), poses=poses))
        state = jax.tree.map(lambda *leaves: jnp.concatenate(leaves, axis=0), *states)
        frames = [[np.array(state.frame0_BPHW3[j, learner])] for j in range(len(idx))]
        withins: list[list[float]] = [[] for _ in idx]
        pending = [np.zeros((len(agents), 2)) for _ in idx]
        for t in range(len(rollouts[idx[0]].actions)):
            ticks = []
            for j, i in enumerate(idx):
                ticks_Pk25, _, pending[j] = world_actions(rollouts[i].actions[t], agents, agents, k, pending[j])
                ticks.append(ticks_Pk25)
            step_BPkHW3, state = model.step(state, np.stack(ticks))
            step_BPkHW3 = np.asarray(step_BPkHW3)
            for j in range(len(idx)):
                frames[j].append(step_BPkHW3[j, learner, -1])
                withins[j].append(within_step_change(step_BPkHW3[j, learner]))
        for j, i in enumerate(idx):
            out[i] = (np.stack(frames[j]), np.asarray(withins[j], np.float32))
    return out


# =============================================================================================
# Models
# =============================================================================================


FORMULA = "formula:warp"  # the reference row of the warps' formulas alone (``WarpFormula``)


class WarpFormula:
    """A reference row, not a world model: each frame is the previous one moved by the formulas the shipped
    model feeds its DiT (``DiTConfig.walk_warp`` and ``jump_warp``, then ``camera_warp``, with its
    ``warp_interp``), applied to pixels from the engine's true first frame. It shows what the geometry alone
    gives on each program and metric (a turn's new view is the edge repeated, the partner never moves, the HUD
    moves with the view), so the model's rows can be read against it (docs/evaluation.md). Spec ``formula:warp``."""

    def __init__(self, cfg):
        if not cfg.dit.camera_warp_enabled:
            raise ValueError(f"{FORMULA}: the shipped model's config has no camera warp to replay")
        self.cfg = cfg
        self.frame_shape = (cfg.frame_height, cfg.frame_width, 3)
        self.frames_per_step = cfg.frames_per_step
        scale = (cfg.frame_height / cfg.latent_height, cfg.frame_width / cfg.latent_width)
        self.pixels_per_degree = (cfg.dit.camera_warp[0] * scale[0], cfg.dit.camera_warp[1] * scale[1])

    @functools.cached_property
    def _step(self):
        """One step as one jitted call: (frame (H, W, 3), ticks (1, k, 25), jump state (1, 1, JUMP_STATE)) ->
        (the next frame, the jump state carried on, as a rollout's cache carries it)."""
        import jax

        from solaris_env.world_model import camera

        k, kb, dit = self.frames_per_step, self.cfg.action.keyboard_dim, self.cfg.dit

        def step(frame_HW3, ticks_1kA, jump_113):
            lift = None
            if dit.jump_warp:
                lift, after = camera.frame_lifts(ticks_1kA[None, ..., :kb], 1, k, jump_113)
                lift, jump_113 = lift[0, 0], after[:, :, 0]
            x = camera.warp_previous(frame_HW3[None], ticks_1kA[..., kb:], ticks_1kA[..., :kb], k,
                                     self.pixels_per_degree, dit.walk_warp, dit.warp_interp, lift, dit.jump_warp,
                                     dit.warp_geometry)
            return x[0], jump_113

        return jax.jit(step)

    def rollout(self, rollout: Rollout) -> np.ndarray:
        """(T + 1, H, W, 3) uint8: the engine's first frame, then each step's frame warped from the last."""
        import jax.numpy as jnp

        from solaris_env.dream_env import expand_action
        from solaris_env.world_model import camera

        frames, pending = [rollout.engine_THW3[0]], None
        jump = jnp.zeros((1, 1, camera.JUMP_STATE), jnp.float32)  # on the floor
        for step in rollout.actions:
            ticks_kA, pending = expand_action(step[LEARNER], self.frames_per_step, pending, LEARNER)
            x, jump = self._step(jnp.asarray(frames[-1], jnp.float32), jnp.asarray(ticks_kA)[None], jump)
            frames.append(np.clip(np.rint(np.asarray(x)), 0, 255).astype(np.uint8))
        return np.stack(frames)


SAMPLER_OVERRIDE = "@"  # "SPEC@noise_warp=0" / "SPEC@noise_warp=0.5,shift=3": SPEC under another rollout setting


def split_spec(spec: str) -> tuple[str, dict[str, int | float]]:
    """``"SPEC@name=value,name=value"`` -> (SPEC, {name: value}): ``SamplerConfig`` fields (numbers, parsed as
    each field's type) to change for the rollouts, the weights unchanged, so that a setting is measured with and
    without in one run."""
    base, sep, rest = spec.partition(SAMPLER_OVERRIDE)
    if not sep:
        return spec, {}
    from solaris_env.world_model.config import SamplerConfig

    fields = {f.name for f in dataclasses.fields(SamplerConfig)}
    defaults = SamplerConfig()
    overrides = {}
    for item in rest.split(","):
        name, eq, value = item.partition("=")
        if not eq or name not in fields:
            raise ValueError(f"--model {spec!r}: after '@' give SamplerConfig fields as name=value "
                             f"(one of {sorted(fields)})")
        try:
            kind = int if isinstance(getattr(defaults, name), int) else float  # the field's own type
            overrides[name] = kind(value)
        except ValueError:
            what = "an integer" if kind is int else "a number"
            raise ValueError(f"--model {spec!r}: {name} must be {what}, got {value!r}") from None
    return base, overrides


def model_label(spec: str) -> str:
    """The name in the results of a model spec (``"default"``, ``"PATH"``, ``"preset:NAME"``: random init,
    smoke runs, or ``formula:warp``, ``WarpFormula``; any of them but the formula with ``@name=value``
    sampler overrides, ``split_spec``): ``shipped default``, a repository-relative path, never absolute."""
    spec, overrides = split_spec(spec)
    suffix = "".join(f", sampler {k} {v:g}" for k, v in overrides.items())
    if spec == "default":
        return "shipped default" + suffix
    if spec == FORMULA:
        return "formula: the default's warps alone, no model"
    if spec.startswith("preset:"):
        return f"preset {spec.split(':', 1)[1]} (random init)" + suffix
    return portable_path(spec, parts=3) + suffix  # outside the repository: its last three components only


def load_model(spec: str):
    """The world model of a spec (``model_label``)."""
    from solaris_env.dream_env import build_model

    spec, overrides = split_spec(spec)
    if spec == FORMULA:
        if overrides:
            raise ValueError(f"{FORMULA} has no sampler to override")
        return WarpFormula(build_model(None, None, num_players=2).config)
    if spec == "default":
        model = build_model(None, None, num_players=2)
    elif spec.startswith("preset:"):
        model = build_model(None, spec.split(":", 1)[1], num_players=2)
    else:
        model = build_model(spec, None, num_players=2)
    if overrides:  # SamplerConfig and WorldModelConfig check the values (a clear error naming the field)
        model = model.with_sampler(dataclasses.replace(model.config.sampler, **overrides))
    return model


# =============================================================================================
# Scoring
# =============================================================================================


@dataclass
class Scored:
    """Per-step values (steps 1..T) of one rollout and one model; engine-only values are shared."""

    rollout: Rollout
    change_e: np.ndarray
    change_d: np.ndarray
    sharp_e: np.ndarray
    sharp_d: np.ndarray
    psnr: np.ndarray
    colour: np.ndarray  # per-step ``colour_error_T``
    dir_e: np.ndarray
    dir_d: np.ndarray
    valid: np.ndarray
    motion_e: np.ndarray  # (T, 3) fitted engine motion
    motion_d: np.ndarray  # (T, 3) fitted dream motion on valid steps (nan elsewhere)
    vis_truth: list
    pos_truth: list
    vis_e: list
    pos_e: list
    vis_d: list
    pos_d: list
    feat_e: np.ndarray | None
    feat_d: np.ndarray | None
    within_e: np.ndarray | None = None  # per-step ``within_step_change``; None where a row has one frame per step
    within_d: np.ndarray | None = None

    @property
    def steps(self) -> np.ndarray:
        return np.arange(1, len(self.change_e) + 1)

    @property
    def partner_scope(self) -> np.ndarray:
        """Steps the partner agreement counts: all of a partner program, else where the engine shows the partner."""
        if self.rollout.kind == "partner":
            return np.ones(len(self.vis_truth), bool)
        return np.array([t == "yes" for t in self.vis_truth])


class EngineCache:
    """Engine-side values of a rollout computed once and shared by every model: frame stats, the fitted motion
    and its scores, judge answers and features."""

    def __init__(self, rollout: Rollout, judge, features):
        f = rollout.engine_THW3
        self.change = view_change_T(f)
        self.sharp = sharpness_T(f)[1:]
        s = direction_scores(f)
        self.motion, self.dir, self.valid = s["motion"], s["engine"], s["valid"]
        self.vis_truth = [visible_truth(int(p)) for p in rollout.pixels_T[1:]]
        self.pos_truth = [position_truth(int(p), u) for p, u in zip(rollout.pixels_T[1:], rollout.u_T[1:])]
        self.vis = judge.answer("visible", f[1:]) if judge is not None else [None] * len(self.change)
        self.pos = judge.answer("position", f[1:]) if judge is not None else [None] * len(self.change)
        self.feat = features(f[1:]) if features is not None else None


def score(rollout: Rollout, engine: EngineCache, dream_THW3: np.ndarray, judge, features,
          within_d: np.ndarray | None = None) -> Scored:
    e, d = rollout.engine_THW3, dream_THW3
    dirs = direction_scores(e, d, motion_T3=engine.motion)
    pd = prepare_THW(d)
    motion_d = np.full_like(engine.motion, np.nan)
    for t in np.flatnonzero(engine.valid):  # the dream's own apparent motion where the engine's shows
        motion_d[t] = fit_motion(pd[t], pd[t + 1])
    n = len(engine.change)
    return Scored(rollout, engine.change, view_change_T(d), engine.sharp, sharpness_T(d)[1:], psnr_T(e, d)[1:],
                  colour_error_T(e, d)[1:], engine.dir, dirs["dream"], engine.valid, engine.motion, motion_d,
                  engine.vis_truth, engine.pos_truth, engine.vis, engine.pos,
                  judge.answer("visible", d[1:]) if judge is not None else [None] * n,
                  judge.answer("position", d[1:]) if judge is not None else [None] * n,
                  engine.feat, features(d[1:]) if features is not None else None, rollout.within_T, within_d)


def _r(x, nd: int = 3):
    return None if x is None or not np.isfinite(x) else round(float(x), nd)


def summarize(parts: Sequence[tuple[Scored, np.ndarray]]) -> dict:
    """The metrics of a group of (scored rollout, step mask) parts: ratios of sums, means over steps."""
    from solaris_env.judges.features import frechet_distance

    cat = lambda f: np.concatenate([np.asarray(f(s))[m] for s, m in parts]) if parts else np.zeros(0)
    steps = sum(int(m.sum()) for _, m in parts)
    if steps == 0:
        return {"steps": 0}
    ce, cd = cat(lambda s: s.change_e), cat(lambda s: s.change_d)
    se, sd = cat(lambda s: s.sharp_e), cat(lambda s: s.sharp_d)
    valid = cat(lambda s: s.valid).astype(bool)
    de, dd = cat(lambda s: s.dir_e), cat(lambda s: s.dir_d)
    frozen, counted = frozen_T(cd, ce)
    drifting, still = drift_T(cd, ce)
    psnr = np.minimum(cat(lambda s: s.psnr), 99.0)
    me, md = cat(lambda s: s.motion_e).reshape(-1, 3), cat(lambda s: s.motion_d).reshape(-1, 3)
    out = {
        "steps": steps,
        "view_change_ratio": _r(ratio(cd.sum(), ce.sum())),
        "view_change_engine": _r(ce.mean(), 2), "view_change_dream": _r(cd.mean(), 2),
        "within_step_change_ratio": None,
        "direction_agreement": _r(direction_agreement(de, dd, valid)),
        "direction_valid_steps": int(valid.sum()),
        "direction_score_engine": _r(de[valid].mean()) if valid.any() else None,
        "direction_score_dream": _r(dd[valid].mean()) if valid.any() else None,
        "frozen_fraction": _r(ratio(frozen.sum(), counted.sum())),
        "frozen_counted_steps": int(counted.sum()),
        "drift_fraction": _r(ratio(drifting.sum(), still.sum())),
        "drift_counted_steps": int(still.sum()),
        "sharpness_ratio": _r(ratio(sd.sum(), se.sum())),
        "sharpness_engine": _r(se.mean(), 2), "sharpness_dream": _r(sd.mean(), 2),
        "psnr_db": _r(psnr.mean(), 2),
        "colour_error": _r(cat(lambda s: s.colour).mean(), 2),
    }
    if all(s.within_e is not None and s.within_d is not None for s, _ in parts):
        we, wd = cat(lambda s: s.within_e), cat(lambda s: s.within_d)
        out["within_step_change_ratio"] = _r(ratio(wd.sum(), we.sum()))
        out["within_step_change_engine"], out["within_step_change_dream"] = _r(we.mean(), 2), _r(wd.mean(), 2)
    if valid.any():
        out["motion_engine"] = {k: _r(v, 3) for k, v in zip(("yaw_deg", "pitch_deg", "log_zoom"), me[valid].mean(0))}
        out["motion_dream"] = {k: _r(v, 3) for k, v in zip(("yaw_deg", "pitch_deg", "log_zoom"),
                                                           np.nanmean(md[valid], axis=0))}
    for q, truth, attr in (("visible", "vis_truth", "vis"), ("position", "pos_truth", "pos")):
        classes: dict[str, dict[str, list[int]]] = {"dream": {}, "engine": {}}
        for s, m in parts:
            scope = s.partner_scope & m
            for src in ("dream", "engine"):
                answers = getattr(s, f"{attr}_{src[0]}")
                if answers and answers[0] is not None:
                    for c, (ch, cn) in class_agreement(answers, getattr(s, truth), scope).items():
                        counts = classes[src].setdefault(c, [0, 0])
                        counts[0] += ch
                        counts[1] += cn
        engine_hits, counted = pooled(classes["engine"])
        out[f"{q}_agreement_dream"] = _r(ratio(*pooled(classes["dream"])))
        out[f"{q}_agreement_engine"] = _r(ratio(engine_hits, counted))
        out[f"{q}_balanced_dream"] = _r(balanced_agreement(classes["dream"]))
        out[f"{q}_balanced_engine"] = _r(balanced_agreement(classes["engine"]))
        out[f"{q}_counted_steps"] = counted
        out[f"{q}_truth_classes"] = {c: n for c, (_, n) in sorted(classes["engine"].items())}
    if parts and parts[0][0].feat_e is not None:
        fe, fd = cat(lambda s: s.feat_e), cat(lambda s: s.feat_d)
        out["frechet"] = _r(frechet_distance(fd, fe), 2) if len(fe) >= 16 else None
    return out


def window_mask(steps: np.ndarray, window: tuple[int, int]) -> np.ndarray:
    return (steps >= window[0]) & (steps <= window[1])


def tables(scored: Sequence[Scored], programs: Sequence[Program]) -> dict:
    """Per program (windows and all steps), per start-world surface, by whether the partner was in view at the
    start, and overall."""
    by_program = {}
    for prog in programs:
        group = [s for s in scored if s.rollout.program == prog.name]
        if not group:
            continue
        windows = {f"{lo}-{hi}": summarize([(s, window_mask(s.steps, (lo, hi))) for s in group])
                   for lo, hi in WINDOWS if lo <= prog.steps}
        by_program[prog.name] = {"windows": windows, "all": summarize([(s, np.ones(len(s.steps), bool))
                                                                        for s in group])}
    by_surface = {}
    for surface in SURFACES:
        group = [s for s in scored if s.rollout.surface == surface]
        if group:
            by_surface[surface] = summarize([(s, np.ones(len(s.steps), bool)) for s in group])
    by_start = {}
    for key, view in (("partner_in_view", True), ("partner_away", False)):
        group = [s for s in scored if s.rollout.in_view == view]
        if group:
            by_start[key] = summarize([(s, np.ones(len(s.steps), bool)) for s in group])
    overall = summarize([(s, np.ones(len(s.steps), bool)) for s in scored])
    return {"programs": by_program, "surfaces": by_surface, "partner_at_start": by_start, "overall": overall}


# ---------------------------------------------------------------------------------------------
# Uncertainty: a paired bootstrap over rollouts
# ---------------------------------------------------------------------------------------------

# The headline metrics whose uncertainty is reported, each a ratio of sums over rollouts (so a resample of the
# rollouts recomputes them exactly as ``summarize`` does): overall direction agreement and view-change ratio, the
# late sharpness of random play (steps ``LATE_STEPS``; the bot episode, one rollout, has no spread to resample),
# and the partner's balanced position agreement. Draws resample the rollouts of each program with replacement,
# the same draws for every model, so the difference between two models is paired: how hard each start is, shared
# by both, cancels, and what is left is how consistently one model differs from the other across starts.
HEADLINE = ("direction_agreement", "view_change_ratio", "late_sharpness_ratio", "position_balanced_dream")
LATE_PROGRAMS, LATE_STEPS = ("random",), (33, 256)
POSITION_CLASSES = ("left", "center", "right", "no player")
BOOTSTRAP_DRAWS, BOOTSTRAP_LEVEL, BOOTSTRAP_SEED = 2000, 0.9, 0


def rollout_sums(s: Scored) -> np.ndarray:
    """The sums one rollout adds to the ``HEADLINE`` metrics: (dream, engine) direction scores over the valid
    steps, (dream, engine) view change, (dream, engine) sharpness over the late steps of ``LATE_PROGRAMS``, then
    per ``POSITION_CLASSES`` truth class the dream judge's (matches, counted) inside the partner scope."""
    valid = s.valid.astype(bool)
    late = window_mask(s.steps, LATE_STEPS) if s.rollout.program in LATE_PROGRAMS else np.zeros(len(s.steps), bool)
    out = [np.sum(np.asarray(s.dir_d)[valid]), np.sum(np.asarray(s.dir_e)[valid]), np.sum(s.change_d),
           np.sum(s.change_e), np.sum(s.sharp_d[late]), np.sum(s.sharp_e[late])]
    per_class = class_agreement(s.pos_d, s.pos_truth, s.partner_scope) if s.pos_d and s.pos_d[0] is not None else {}
    for c in POSITION_CLASSES:
        out += per_class.get(c, [0, 0])
    return np.asarray(out, np.float64)


def headline(sums_NK: np.ndarray) -> np.ndarray:
    """(N, len(HEADLINE)) metrics from (N, K) summed ``rollout_sums``; NaN where a denominator is 0."""
    sums_NK = np.atleast_2d(sums_NK)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = [np.where(sums_NK[:, i + 1] != 0, sums_NK[:, i] / sums_NK[:, i + 1], np.nan) for i in (0, 2, 4)]
    hits, counted = sums_NK[:, 6::2], sums_NK[:, 7::2]
    classes = (counted > 0).sum(1)  # the truth classes present: ``balanced_agreement`` averages over them
    rates = np.where(counted > 0, hits / np.maximum(counted, 1), 0.0).sum(1)
    balanced = np.where(classes > 0, rates / np.maximum(classes, 1), np.nan)
    return np.stack(ratios + [balanced], axis=1)


def bootstrap(sums_by_model: dict[str, np.ndarray], strata: Sequence[str], draws: int = BOOTSTRAP_DRAWS,
              level: float = BOOTSTRAP_LEVEL, seed: int = BOOTSTRAP_SEED) -> dict:
    """Percentile intervals of the ``HEADLINE`` metrics per model and of each model's difference from the first,
    from ``draws`` resamples of the rollouts (with replacement inside each stratum, e.g. each program; the same
    resamples for every model). ``sums_by_model``: label -> (R, K) ``rollout_sums`` in the same rollout order.

    Returns {"models": {label: {metric: {"value", "interval"}}}, "differences": {label: {metric: {"value",
    "interval", "share_above_zero"}}} (vs the first model; absent for one model)}."""
    labels = list(sums_by_model)
    strata = np.asarray(strata)
    n = len(strata)
    if any(v.shape[0] != n for v in sums_by_model.values()):
        raise ValueError(f"every model needs one row of sums per rollout ({n})")
    rng = np.random.default_rng(seed)
    idx = np.empty((draws, n), np.int64)
    for name in dict.fromkeys(strata.tolist()):  # resample inside each stratum, in a fixed order
        members = np.flatnonzero(strata == name)
        idx[:, members] = members[rng.integers(0, len(members), (draws, len(members)))]
    lo_q, hi_q = 100 * (1 - level) / 2, 100 * (1 + level) / 2

    def interval(x):
        x = x[np.isfinite(x)]
        return [_r(np.percentile(x, lo_q)), _r(np.percentile(x, hi_q))] if len(x) else [None, None]

    points = {k: headline(v.sum(0))[0] for k, v in sums_by_model.items()}
    samples = {k: headline(v[idx].sum(1)) for k, v in sums_by_model.items()}  # (draws, metrics)
    out = {"models": {k: {m: {"value": _r(points[k][j]), "interval": interval(samples[k][:, j])}
                          for j, m in enumerate(HEADLINE)} for k in labels}, "differences": {}}
    for k in labels[1:]:
        row = {}
        for j, m in enumerate(HEADLINE):
            d = samples[k][:, j] - samples[labels[0]][:, j]
            d = d[np.isfinite(d)]
            row[m] = {"value": _r(points[k][j] - points[labels[0]][j]), "interval": interval(d),
                      "share_above_zero": _r(np.mean(d > 0)) if len(d) else None}
        out["differences"][k] = row
    return out


def estimator_validation(caches: dict, rollouts: Sequence[Rollout]) -> dict:
    """The direction estimator on engine frames only: engine against itself, a frozen copy (every frame = the
    first), the time-reversed sequence, the mirrored one (turn programs) and, on the turn programs, the
    fitted turn per step against the engine's own pose change."""
    rows = {}
    groups = {"all": [r for r in rollouts if caches[id(r)].valid.any()],
              "turns": [r for r in rollouts if r.program.startswith("yaw_") and caches[id(r)].valid.any()]}
    for name, group in groups.items():
        acc = {"self": [], "frozen": [], "reversed": [], "mirrored": [], "engine": []}
        fitted, pose, valid_steps, total = [], [], 0, 0
        for r in group:
            c = caches[id(r)]
            e = prepare_THW(r.engine_THW3)
            total += len(c.dir)
            for t in np.flatnonzero(c.valid):
                a, b, m = e[t], e[t + 1], c.motion[t]
                acc["engine"].append(c.dir[t])
                acc["self"].append(direction_score(a, b, m))
                acc["frozen"].append(direction_score(e[0], e[0], m))
                acc["reversed"].append(direction_score(b, a, m))
                if name == "turns":
                    acc["mirrored"].append(direction_score(a[:, ::-1].copy(), b[:, ::-1].copy(), m))
                    fitted.append(m[0])
                    d = r.yaw_pitch_T2[t + 1, 0] - r.yaw_pitch_T2[t, 0]
                    pose.append((d + 180.0) % 360.0 - 180.0)
                valid_steps += 1
        eng = np.mean(acc["engine"]) if acc["engine"] else float("nan")
        row = {"rollouts": len(group), "steps": total, "valid_steps": valid_steps,
               "engine_score_mean": _r(eng)}
        for key in ("self", "frozen", "reversed", "mirrored"):
            if acc[key]:
                row[f"agreement_{key}"] = _r(np.mean(acc[key]) / eng)
        if fitted:
            row["fitted_yaw_deg_per_step"] = _r(np.mean(np.abs(fitted)), 2)
            row["pose_yaw_deg_per_step"] = _r(np.mean(np.abs(pose)), 2)
            row["fitted_sign_matches_pose"] = _r(np.mean(np.sign(fitted) == np.sign(pose)))
        rows[name] = row
    return rows


# =============================================================================================
# Pictures
# =============================================================================================

SHOWCASE = ("forward", "yaw_right_15", "partner_toward", "random")  # the contact sheet's and video's programs


def showcase(rollouts: Sequence[Rollout]) -> list[Rollout]:
    """Per ``SHOWCASE`` program of the run, its rollout whose engine view changes most (a walk that is not
    blocked by a hill at once, a partner that comes close); the first programs of the run if none of them ran."""
    best: dict[str, tuple[float, Rollout]] = {}
    for r in rollouts:
        change = float(view_change_T(r.engine_THW3).sum())
        if r.program not in best or change > best[r.program][0]:
            best[r.program] = (change, r)
    chosen = [best[p][1] for p in SHOWCASE if p in best]
    return chosen or [r for _, r in list(best.values())[:4]]


def _label(img: np.ndarray, text: str, width: int) -> np.ndarray:
    """A ``width``-pixel label strip in front of a row of frames (RGB uint8)."""
    strip = np.full((img.shape[0], width, 3), 255, np.uint8)
    for k, line in enumerate(text.split("\n")):
        cv2.putText(strip, line, (3, 12 + 12 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.33, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([strip, img], axis=1)


def contact_sheet(rows: Sequence[tuple[Rollout, dict]], names: Sequence[str], scale: int = 2) -> np.ndarray:
    """RGB uint8 sheet: per program, the engine's row over each model's row; every (steps / 8)th step (every 8th
    of a 64-step program), frame 0 first."""
    def pad(f):  # scaled up, with a 1-pixel white frame
        return np.pad(cv2.resize(f, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST),
                      ((1, 1), (1, 1), (0, 0)), constant_values=255)

    blocks = []
    for rollout, dreams in rows:
        T = len(rollout.actions)
        every = max(1, T // 8)
        cols = list(range(0, T + 1, every))
        lines = [(f"{rollout.program} ({rollout.surface})\nengine", rollout.engine_THW3)]
        lines += [("dream:\n" + n.replace(", ", ",\n"), dreams[n]) for n in names]  # one clause per line
        for text, frames in lines:
            blocks.append(_label(np.concatenate([pad(frames[t]) for t in cols], axis=1), text, 150))
        header = np.full((14, blocks[-1].shape[1], 3), 255, np.uint8)
        tile = rollout.engine_THW3.shape[2] * scale + 2
        for j, c in enumerate(cols):
            cv2.putText(header, f"step {c}" if j == 0 else str(c), (150 + j * tile + 3, 11),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.33, (80, 80, 80), 1, cv2.LINE_AA)
        blocks.insert(len(blocks) - len(lines), header)
        blocks.append(np.full((6, blocks[-1].shape[1], 3), 255, np.uint8))
    width = max(b.shape[1] for b in blocks)
    return np.concatenate([np.pad(b, ((0, 0), (0, width - b.shape[1]), (0, 0)), constant_values=255) for b in blocks])


def write_video(path: Path, rows: Sequence[tuple[Rollout, dict]], names: Sequence[str], fps: float,
                scale: int = 2, max_steps: int = 64) -> None:
    """mp4 (mp4v): the showcase rollouts one after the other (at most ``max_steps`` steps each, to keep the file
    small), engine beside each model's dream."""
    frames = []
    for rollout, dreams in rows:
        for t in range(min(len(rollout.actions), max_steps) + 1):
            tiles = [rollout.engine_THW3[t]] + [dreams[n][t] for n in names]
            row = np.concatenate([cv2.resize(f, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
                                  for f in tiles], axis=1)
            head = np.full((14, row.shape[1], 3), 255, np.uint8)
            cv2.putText(head, f"{rollout.program} t={t}  engine | " + " | ".join(names), (2, 10),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.3, (0, 0, 0), 1, cv2.LINE_AA)
            frames.append(np.concatenate([head, row]))
    if not frames:
        return
    h, w = frames[0].shape[:2]
    h2, w2 = h + h % 2, w + w % 2
    tmp = path.with_name(f".{path.stem}.tmp.mp4")
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w2, h2))
    for f in frames:
        writer.write(np.pad(f, ((0, h2 - h), (0, w2 - w), (0, 0)))[..., ::-1])
    writer.release()
    os.replace(tmp, path)


# =============================================================================================
# The benchmark
# =============================================================================================


@dataclass(frozen=True)
class Setup:
    per_world: int = 4  # start states per flat variant (normal worlds: twice as many)
    per_program: int = 3  # start states per 64-step program
    per_long_program: int = 2  # start states of random play
    steps: int | None = None  # cap every program at this many steps (smoke runs)
    start_seed: int = START_SEED
    dream_seed: int = 0  # added to every dream rollout's reset seed: other sampling noise, the same engine rollouts

    def __post_init__(self):
        if self.dream_seed < 0:
            raise ValueError(f"dream_seed (--dream-seed) must be >= 0, got {self.dream_seed}")


QUICK = Setup(per_world=1, per_program=2, per_long_program=1, steps=None)
QUICK_STEPS = (16, 32)  # --quick: 64-step programs play 16 steps, the long ones 32


def run(model_specs: Sequence[str], program_names: Sequence[str], setup: Setup, quick: bool = False,
        with_judges: bool = True, log: Callable[[str], None] = print) -> tuple[dict, dict]:
    """Engine rollouts once, then each model's dream rollouts and scores. Returns (result, pictures)."""
    import dataclasses

    from solaris_env.dream_env import DreamParallelEnv
    from solaris_env.real_env import RealParallelEnv

    unknown = [p for p in program_names if p not in PROGRAMS]
    if unknown:
        raise ValueError(f"unknown programs {unknown}; known: {list(PROGRAMS)}")
    if not model_specs:
        raise ValueError("give at least one model")
    programs = []
    for name in program_names:
        prog = PROGRAMS[name]
        steps = prog.steps
        if quick:
            steps = QUICK_STEPS[0] if prog.steps <= 64 else QUICK_STEPS[1]
        if setup.steps is not None:
            steps = min(steps, setup.steps)
        programs.append(dataclasses.replace(prog, steps=steps))
    cv2.setNumThreads(1)  # the frames are tiny: OpenCV's thread pool only costs here (2x faster fits)
    timing = {}
    t0 = time.perf_counter()
    models = {}
    for spec in model_specs:
        label = model_label(spec)
        if label in models:
            raise ValueError(f"model {spec!r} given twice")
        models[label] = load_model(spec)
    first = next(iter(models.values()))
    shapes = {(m.frame_shape, m.frames_per_step) for m in models.values()}
    if len(shapes) != 1:
        raise ValueError(f"the models differ in frame shape / frames per step: {shapes}; compare like with like")
    (height, width, _), k = first.frame_shape, first.frames_per_step
    timing["load_models_s"] = round(time.perf_counter() - t0, 1)

    t0 = time.perf_counter()
    states = make_states(setup.per_world, setup.start_seed, (height, width))
    assignment = assign_states(states, programs, setup.per_program, setup.per_long_program)
    timing["start_states_s"] = round(time.perf_counter() - t0, 1)
    log(f"{len(states)} start states ({timing['start_states_s']} s)")

    t0 = time.perf_counter()
    env = RealParallelEnv(num_players=2, world="flat", resolution=(height, width), max_steps=10**6,
                          ticks_per_step=k)
    rollouts, bot = [], None
    for prog in programs:
        if prog.name == "bot":
            bot = bot_episode(prog.steps, k, setup.start_seed)
            surface = SURFACE.get(bot.world, "normal")
            rollouts.append(engine_rollout(env, prog, bot.start, -1, surface, False, actions=bot.actions))
            rollouts[-1].in_view = bool(rollouts[-1].pixels_T[0] >= MIN_VISIBLE_PIXELS)
            continue
        for i in assignment[prog.name]:
            s = states[i]
            rollouts.append(engine_rollout(env, prog, s.state, i, s.surface, s.in_view))
    timing["engine_rollouts_s"] = round(time.perf_counter() - t0, 1)
    log(f"{len(rollouts)} engine rollouts, {sum(len(r.actions) for r in rollouts)} steps "
        f"({timing['engine_rollouts_s']} s)")

    judge = features = None
    if with_judges:
        from solaris_env.judges import Judge
        from solaris_env.judges.features import FrameFeatures

        judge, features = Judge.load(names=["visible", "position"]), FrameFeatures.load()
    t0 = time.perf_counter()
    caches = {id(r): EngineCache(r, judge, features) for r in rollouts}
    timing["engine_scoring_s"] = round(time.perf_counter() - t0, 1)
    validation = estimator_validation(caches, rollouts)
    log(f"engine motion fitted and judged ({timing['engine_scoring_s']} s); estimator: {validation.get('all')}")

    results, shown, sums = {}, {id(r): {} for r in showcase(rollouts)}, {}
    for label, model in models.items():
        t0 = time.perf_counter()
        if isinstance(model, WarpFormula):
            dreams, withins = [model.rollout(r) for r in rollouts], [None] * len(rollouts)
        else:
            denv = DreamParallelEnv(model=model, max_steps=10**6)
            dreams, withins = map(list, zip(*dream_rollouts(denv, rollouts, setup.dream_seed)))
        for r, frames in zip(rollouts, dreams):
            if id(r) in shown:
                shown[id(r)][label] = frames
        dream_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        scored = [score(r, caches[id(r)], d, judge, features, w) for r, d, w in zip(rollouts, dreams, withins)]
        results[label] = tables(scored, programs)
        sums[label] = np.stack([rollout_sums(x) for x in scored])
        timing[f"dream_rollouts_s[{label}]"] = round(dream_s, 1)
        timing[f"dream_scoring_s[{label}]"] = round(time.perf_counter() - t0, 1)
        log(f"dream {label}: {timing[f'dream_rollouts_s[{label}]']} s rollouts, "
            f"{timing[f'dream_scoring_s[{label}]']} s scoring")

    result = {
        "benchmark": "dream_fidelity",
        "setup": {
            "models": [{"spec": spec, "name": model_label(spec)} for spec in model_specs],
            "frame_size": [height, width], "frames_per_step": k, "quick": quick,
            "start_seed": setup.start_seed, "dream_seed": setup.dream_seed, "per_world": setup.per_world,
            "per_program": setup.per_program, "per_long_program": setup.per_long_program,
            "start_states": [s.describe() for s in states],
            "programs": {p.name: {"steps": p.steps, "kind": p.kind, "doc": p.doc, "start_states": assignment[p.name]}
                         for p in programs},
            "bot_episode": None if bot is None else {"type": bot.episode_type, "world": bot.world,
                                                     "world_age_ticks": bot.world_age,
                                                     "bots_active_steps": bot.active_steps, **bot.config},
            "windows": [f"{lo}-{hi}" for lo, hi in WINDOWS],
            "dream_reset_seed": "crc32('dream_fidelity/<program>/<state index>'), the same for every model",
            "judges": "shipped probes (solaris_env/assets/judges): visible, position; features for the Fréchet "
                      "distance: visible/position/structure penultimate activations (192-d)" if with_judges else None,
            "metrics": {
                "view_change_ratio": "sum over steps of the dream's mean |grey_t - grey_t-1| / the engine's",
                "within_step_change_ratio": "the same over the consecutive frames inside each env step (its k "
                                            "ticks), dream / engine; None for a row with one frame per step",
                "direction_agreement": "mean direction score of the dream / of the engine over the steps whose "
                                       f"engine motion shows (score >= {VALID_SCORE}); 1 = as the engine, 0 = frozen "
                                       "or unrelated, < 0 = reversed",
                "frozen_fraction": f"of the steps where the engine changes > {FROZEN_ENGINE_MIN} grey levels, the "
                                   f"share where the dream changes < {FROZEN_DREAM_MAX}",
                "drift_fraction": f"of the steps where the engine changes < {DRIFT_ENGINE_MAX} grey levels, the "
                                  f"share where the dream changes > {DRIFT_DREAM_MIN}",
                "sharpness_ratio": "mean |4-neighbour Laplacian| of the dream's frames / the engine's",
                "psnr_db": "dream vs engine frame, RGB, mean over steps (capped at 99)",
                "colour_error": f"mean |dream - engine| of the frames' {COLOUR_CELLS} x {COLOUR_CELLS} block means "
                                "(grey levels, over RGB): the sky and ground colours, not the detail",
                "visible_/position_agreement": "judge answer == engine ground truth, on partner programs and "
                                               "wherever the engine shows the partner (ambiguous truths skipped)",
                "visible_/position_balanced": "the same per truth class, averaged over the classes: one answer "
                                              "to every frame scores 1 / classes (the judges answer 'yes, center' "
                                              "to noise)",
                "frechet": "Fréchet distance, dream vs engine frames, judge features (>= 16 frames)",
            },
            "direction_estimator": {
                "motion": "global camera motion (yaw, pitch deg; log zoom) fitted to each engine frame pair: "
                          "3-deg grid of turns on half-size frames, zoom line search, coordinate search",
                "frames": "grey, Gaussian blur sigma 1.5 px at 64 px; HUD, margins and top rows masked",
                "score": "d = (E(-m) - E(m)) / (E(-m) + E(m)), E(m) = mean (warp(a, m/2) - warp(b, -m/2))^2",
                "valid_score": VALID_SCORE, "min_motion": MIN_MOTION, "max_motion": MAX_MOTION,
            },
        },
        "estimator_validation": validation,
        "results": results,
        "uncertainty": {"method": f"paired bootstrap over rollouts, resampled inside each program; {BOOTSTRAP_DRAWS} "
                                  f"draws, {int(100 * BOOTSTRAP_LEVEL)} % percentile intervals; differences are "
                                  "each model minus the first on the same draws",
                        "late_sharpness": f"steps {LATE_STEPS[0]}-{LATE_STEPS[1]} of {' and '.join(LATE_PROGRAMS)}",
                        **bootstrap(sums, [r.program for r in rollouts])},
        "timing": timing,
    }
    pictures = {"rows": [(r, shown[id(r)]) for r in rollouts if id(r) in shown], "names": list(models),
                "fps": 20.0 / k}
    return result, pictures


def _fmt(v, nd=2, width=6) -> str:
    if v is None:
        return f"{'-':>{width}s}"
    return f"{'>99':>{width}s}" if v > 99 and nd == 2 else f"{v:{width}.{nd}f}"


def print_tables(result: dict) -> None:
    """Per model: program x (view-change ratio and direction agreement per window, frozen and drift fractions,
    sharpness ratio, PSNR, partner agreement, FD), then per surface."""
    windows = result["setup"]["windows"]
    for name, res in result["results"].items():
        print(f"\n== {name} ==")
        wh = " ".join(f"{w:>6s}" for w in windows)
        print(f"{'':16s} {'view-change ratio':^{7 * len(windows)}s}| {'direction agreement':^{7 * len(windows)}s}| "
              f"{'all steps':^57s}")
        print(f"{'program':16s} {wh} | {wh} | frozen  drift  sharp   PSNR colour  vis_d  vis_e  pos_d  pos_e     FD")
        for prog, row in res["programs"].items():
            vc = " ".join(_fmt(row["windows"].get(w, {}).get("view_change_ratio")) for w in windows)
            da = " ".join(_fmt(row["windows"].get(w, {}).get("direction_agreement")) for w in windows)
            a = row["all"]
            print(f"{prog:16s} {vc} | {da} | {_fmt(a['frozen_fraction'])} {_fmt(a['drift_fraction'])} "
                  f"{_fmt(a['sharpness_ratio'])} "
                  f"{_fmt(a['psnr_db'], 1)} {_fmt(a.get('colour_error'), 1)} "
                  f"{_fmt(a.get('visible_agreement_dream'))} "
                  f"{_fmt(a.get('visible_agreement_engine'))} {_fmt(a.get('position_agreement_dream'))} "
                  f"{_fmt(a.get('position_agreement_engine'))} {_fmt(a.get('frechet'), 1)}")
        print(f"{'surface':16s} {'vc':>6s} {'within':>6s} {'dir':>6s} frozen  drift  sharp   PSNR colour  vis_d  "
              "vis_e  pos_d  pos_e     FD  steps  visB_d  posB_d  (B: balanced over truth classes)")
        rows = list(res["surfaces"].items()) + list(res["partner_at_start"].items()) + [("overall", res["overall"])]
        for surf, a in rows:
            print(f"{surf:16s} {_fmt(a['view_change_ratio'])} {_fmt(a.get('within_step_change_ratio'))} "
                  f"{_fmt(a['direction_agreement'])} "
                  f"{_fmt(a['frozen_fraction'])} {_fmt(a['drift_fraction'])} {_fmt(a['sharpness_ratio'])} "
                  f"{_fmt(a['psnr_db'], 1)} {_fmt(a.get('colour_error'), 1)} "
                  f"{_fmt(a.get('visible_agreement_dream'))} {_fmt(a.get('visible_agreement_engine'))} "
                  f"{_fmt(a.get('position_agreement_dream'))} {_fmt(a.get('position_agreement_engine'))} "
                  f"{_fmt(a.get('frechet'), 1)} {a['steps']:6d}  {_fmt(a.get('visible_balanced_dream'))}  "
                  f"{_fmt(a.get('position_balanced_dream'))}")
    u = result.get("uncertainty")
    if u:
        print(f"\nheadline metrics, {u['method']}:")
        iv = lambda c: f"{_fmt(c['value'], 3, 6)} [{_fmt(c['interval'][0], 3, 6)}, {_fmt(c['interval'][1], 3, 6)}]"
        print(f"{'model':40s} " + " ".join(f"{m:>24s}" for m in HEADLINE))
        for name, row in u["models"].items():
            print(f"{name[-40:]:40s} " + " ".join(f"{iv(row[m]):>24s}" for m in HEADLINE))
        for name, row in u["differences"].items():
            print(f"{'minus first: ' + name[-27:]:40s} " + " ".join(f"{iv(row[m]):>24s}" for m in HEADLINE))
    v = result["estimator_validation"]
    for key, row in v.items():
        print(f"direction estimator ({key}, engine frames): " + ", ".join(f"{k} {x}" for k, x in row.items()))


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(prog="python -m benchmarks.dream_fidelity", description=__doc__.split("\n\n")[0])
    p.add_argument("--model", action="append", default=None,
                   help="a model: 'default' (the shipped one), a checkpoint directory, 'preset:NAME' (random "
                        "init, smoke runs) or 'formula:warp' (the default's warps alone, a reference row); append "
                        "'@name=value' to sample under another SamplerConfig value (e.g. default@noise_warp=0). "
                        "Repeat to compare models on the same engine rollouts (default: default)")
    p.add_argument("--programs", nargs="+", default=list(PROGRAMS), metavar="NAME",
                   help=f"action programs (default: all): {' '.join(PROGRAMS)}")
    p.add_argument("--quick", action="store_true",
                   help=f"a small run: 1 state per flat variant, 2 per program, {QUICK_STEPS[0]} steps "
                        f"({QUICK_STEPS[1]} for random / bot)")
    p.add_argument("--steps", type=int, default=None, help="cap every program at this many steps")
    p.add_argument("--per-program", type=int, default=None, help="start states per 64-step program (default 3)")
    p.add_argument("--start-seed", type=int, default=START_SEED, help="first reset seed of the start states")
    p.add_argument("--dream-seed", type=int, default=0,
                   help="added to each dream rollout's reset seed: the same engine rollouts under other sampling "
                        "noise, to measure how far the metrics move by chance (default 0)")
    p.add_argument("--out", default=str(RESULTS), help="the JSON; the .png and .mp4 go next to it")
    args = p.parse_args(argv)
    specs = args.model or ["default"]
    setup = QUICK if args.quick else Setup()
    setup = Setup(setup.per_world, args.per_program or setup.per_program, setup.per_long_program, args.steps,
                  args.start_seed, args.dream_seed)
    from benchmarks.machine import machine_info, write_result

    load = os.getloadavg()
    t0 = time.perf_counter()
    result, pictures = run(specs, args.programs, setup, quick=args.quick)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet = contact_sheet(pictures["rows"], pictures["names"])
    png, mp4 = out.with_suffix(".png"), out.with_suffix(".mp4")
    cv2.imwrite(str(png), sheet[..., ::-1])
    write_video(mp4, pictures["rows"], pictures["names"], pictures["fps"])
    result["wall_s"] = round(time.perf_counter() - t0, 1)
    result["machine"] = machine_info(load)
    result["outputs"] = {"contact_sheet": png.name, "video": mp4.name,
                         "showcase": [f"{r.program} (start state {r.state_index}, {r.surface})"
                                      for r, _ in pictures["rows"]]}
    print_tables(result)
    print(f"wall time {result['wall_s']} s")
    write_result(out, result)
    return result


if __name__ == "__main__":
    main()
