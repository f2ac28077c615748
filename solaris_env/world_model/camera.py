"""Camera geometry of the player's view, for the two camera conditionings of ours (both off in the official
model): the per-latent-frame turn read from the mouse windows, and the previous latent shifted by it.

Mouse convention (``spaces.env_action_to_model_vector``, Mineflayer signs): the model's mouse vector is
[cameraX, cameraY] in units of ``CAMERA_SCALE_DEG`` degrees, + = turn left / look up. Turning left moves the
view's content right, looking up moves it down.

``frame_turns`` gives each latent frame's turn (the last ``k`` ticks of its action window are the ticks between
latent frames i - 1 and i; docs/model.md §4.3), ``content_shift`` how far it moves the view's content.
``shift_latents`` moves a latent frame's content by a fractional number of latent pixels (linear or Catmull-Rom
cubic interpolation, ``DiTConfig.warp_interp``, of the frame extended by repeating its edges):
``DiTConfig.camera_warp`` feeds the previous latent frame shifted by the frame's turn to the patch embedding, so
following the camera is a copy of an input channel instead of a sub-token interpolation the DiT has to learn.
With ``DiTConfig.warp_geometry = "rotation"`` the turn resamples the latent through the camera's rotation instead
(``turn_source``, ``turn_latents``: the view's sides move faster than its centre; docs/model.md §8.1).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from solaris_env.spaces import CAMERA_SCALE_DEG, MODEL_INDEX
from solaris_env.world_model.config import WARP_GEOMETRIES, WARP_INTERPOLATIONS


def frame_turns(mouse_BPFWA: jax.Array, frames_per_step: int) -> jax.Array:
    """(B, P, F, 2) [yaw (+ left), pitch (+ up)] degrees turned between latent frames i - 1 and i."""
    if mouse_BPFWA.shape[-1] != 2:
        raise ValueError(f"the camera reads [cameraX, cameraY]; the mouse windows have {mouse_BPFWA.shape[-1]} dims")
    return mouse_BPFWA[..., -frames_per_step:, :].astype(jnp.float32).sum(axis=-2) * CAMERA_SCALE_DEG


def holds_still(mouse_BPFWA: jax.Array, keyboard_BPFWK: jax.Array, frames_per_step: int,
                lift_BPF2: jax.Array | None = None) -> jax.Array:
    """(B, P, F) bool: the frame's view holds still, so its warp is the identity: in the last ``frames_per_step``
    ticks of its action windows no mouse movement and no key down, and (with the jump warp's ``lift_BPF2``, the
    [previous, own] heights of ``frame_lifts``) no change of height."""
    k = frames_per_step
    still = (mouse_BPFWA[..., -k:, :] == 0).all(axis=(-2, -1)) & (keyboard_BPFWK[..., -k:, :] == 0).all(axis=(-2, -1))
    if lift_BPF2 is not None:
        still = still & (lift_BPF2[..., 0] == lift_BPF2[..., 1])
    return still


def content_shift(turns_BPF2: jax.Array, pixels_per_degree: tuple[float, float]) -> jax.Array:
    """(B, P, F, 2) (down, right) latent pixels the view's content moves for the turns: a left turn (+ yaw)
    moves it right, looking up (+ pitch) moves it down. ``pixels_per_degree`` is (height, width)."""
    return jnp.stack([turns_BPF2[..., 1] * pixels_per_degree[0], turns_BPF2[..., 0] * pixels_per_degree[1]], axis=-1)


def _cubic_weights(t: jax.Array) -> tuple:
    """Catmull-Rom (Keys, a = -0.5) weights of the 4 taps at -1, 0, 1, 2 for a point t in [0, 1) past tap 0.
    They sum to 1 and reproduce linear ramps; a repeated shift blurs far less than linear interpolation."""
    t2, t3 = t * t, t * t * t
    return (-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0, -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2)


def _shift_axis(x: jax.Array, shift: jax.Array, axis: int, interp: str = "linear") -> jax.Array:
    """out[i] = x[i - shift] along ``axis``, interpolated (``interp``) on the signal extended by repeating its
    edges: each tap's index is clamped, so a point in the uncovered border is exactly the edge value.
    ``x`` (N, h, w, C), ``shift`` (N,)."""
    n = x.shape[axis]
    src = jnp.arange(n, dtype=jnp.float32)[None] - shift[:, None]  # (N, n)
    lo = jnp.floor(src)
    frac = src - lo
    lo = lo.astype(jnp.int32)  # not clamped here: clamping before the taps would mix the edge with inner pixels
    shape = [x.shape[0], 1, 1, 1]
    shape[axis] = n
    take = lambda idx: jnp.take_along_axis(x, jnp.clip(idx, 0, n - 1).reshape(shape), axis=axis)
    frac = frac.reshape(shape).astype(x.dtype)
    if interp == "linear":
        return (1 - frac) * take(lo) + frac * take(lo + 1)
    if interp == "cubic":
        w = _cubic_weights(frac)
        return w[0] * take(lo - 1) + w[1] * take(lo) + w[2] * take(lo + 1) + w[3] * take(lo + 2)
    raise ValueError(f"interp must be one of {WARP_INTERPOLATIONS}, got {interp!r}")


def shift_latents(x_NhwC: jax.Array, shift_N2: jax.Array, interp: str = "linear") -> jax.Array:
    """Move each latent frame's content by (down, right) latent pixels (fractional: linear or Catmull-Rom cubic
    interpolation, ``interp``; the uncovered border repeats the edge). Integer shifts inside the frame are exact."""
    if x_NhwC.ndim != 4 or shift_N2.shape != (x_NhwC.shape[0], 2):
        raise ValueError(f"shift_latents takes x (N, h, w, C) and shift (N, 2); got {x_NhwC.shape}, {shift_N2.shape}")
    shift = shift_N2.astype(jnp.float32)
    return _shift_axis(_shift_axis(x_NhwC, shift[:, 0], 1, interp), shift[:, 1], 2, interp)


# ---------------------------------------------------------------------------------------------
# Walking (``DiTConfig.walk_warp``, docs/model.md §8.1)
# ---------------------------------------------------------------------------------------------

# The view of the frames (docs/engine.md; Minecraft's default): a 16:9 window with a 70 deg vertical field of
# view, resampled to the square frame. (height, width) tangents of the half-angles at the frame's edges.
VIEW_HALF_TAN = (math.tan(math.radians(35.0)), math.tan(math.radians(35.0)) * 16.0 / 9.0)
_KEY = {name: MODEL_INDEX[name] for name in ("forward", "back", "left", "right", "sneak", "sprint")}
SPRINT_FACTOR = 5.612 / 4.317  # Minecraft's sprint / walk speed
SNEAK_FACTOR = 1.295 / 4.317  # sneak / walk
_MIN_DEPTH = 0.2  # the source depth factor is kept above this (a step back on the nearest rows)


def frame_moves(keyboard_BPFWK: jax.Array, frames_per_step: int) -> jax.Array:
    """(B, P, F, 2) [forward, right] how far the player walked between latent frames i - 1 and i, in ticks of
    walking at full speed: the last ``k`` ticks of the frame's keyboard window, forward - back and right - left,
    a diagonal normalised to length 1 (as the engine and Minecraft do), sprint (forward only) and sneak scaling
    the speed. Momentum is left out (a fitted ``walk_warp`` absorbs the average)."""
    if keyboard_BPFWK.shape[-1] <= max(_KEY.values()):
        raise ValueError(f"the walk reads the movement keys of the model's keyboard vector "
                         f"(spaces.MODEL_ACTION_KEYS); the keyboard windows have {keyboard_BPFWK.shape[-1]} dims")
    keys = keyboard_BPFWK[..., -frames_per_step:, :].astype(jnp.float32)
    forward = keys[..., _KEY["forward"]] - keys[..., _KEY["back"]]
    right = keys[..., _KEY["right"]] - keys[..., _KEY["left"]]
    norm = jnp.maximum(jnp.sqrt(forward ** 2 + right ** 2), 1.0)
    speed = jnp.where((keys[..., _KEY["sprint"]] > 0) & (forward > 0), SPRINT_FACTOR, 1.0)
    speed = jnp.where(keys[..., _KEY["sneak"]] > 0, SNEAK_FACTOR, speed)
    step = jnp.stack([forward, right], axis=-1) * (speed / norm)[..., None]
    return step.sum(axis=-2)


def walk_source(h: int, w: int, move_N2: jax.Array, eyes_N2: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """Where each latent pixel of the next view was in the previous one after walking ``move_N2`` [forward,
    right] eye heights and, with ``eyes_N2``, rising from H0 to H1 eye heights above the floor (default 1, 1):
    (N, h, w) source rows and columns (fractional latent pixels).

    The scene is a floor below the eye and a ceiling above it, each one eye height away (the "tunnel"; the sky
    is uniform, so moving it costs nothing, and a flat world's ground is exactly the floor). A view ray at
    tangents (x, v) from the view's centre (v down) meets the floor at depth H1/v; walking f forward and s right
    from eye height H0 to H1 it was at depth H1/v + f, s further right and H0 below the eye before, so it came
    from v_src = H0 v / (H1 + v f), x_src = (x H1 + v s) / (H1 + v f). The ceiling rows (v < 0) walk as at
    H0 = H1 = 1 (a jump moves the ground, not the far or the sky). Rows at the horizon do not move."""
    ty, tx = VIEW_HALF_TAN
    v = ((jnp.arange(h, dtype=jnp.float32) + 0.5) / h * 2.0 - 1.0) * ty  # (h,) down
    x = ((jnp.arange(w, dtype=jnp.float32) + 0.5) / w * 2.0 - 1.0) * tx  # (w,) right
    av = jnp.abs(v)[None, :, None]
    f, s = move_N2[:, 0, None, None], move_N2[:, 1, None, None]
    if eyes_N2 is None:
        h0 = h1 = jnp.ones_like(f)
    else:
        floor = (v > 0)[None, :, None]
        h0 = jnp.where(floor, eyes_N2[:, 0, None, None], 1.0)
        h1 = jnp.where(floor, eyes_N2[:, 1, None, None], 1.0)
    depth = jnp.maximum(1.0 + av * f / h1, _MIN_DEPTH)  # (N, h, 1)
    v_src = v[None, :, None] * (h0 / h1) / depth
    x_src = (x[None, None, :] + av * s / h1) / depth
    rows = (v_src / ty + 1.0) / 2.0 * h - 0.5
    cols = (x_src / tx + 1.0) / 2.0 * w - 0.5
    return jnp.broadcast_to(rows, (move_N2.shape[0], h, w)), jnp.broadcast_to(cols, (move_N2.shape[0], h, w))


def walk_latents(x_NhwC: jax.Array, move_N2: jax.Array, eyes_N2: jax.Array | None = None) -> jax.Array:
    """Each latent frame's content as seen after walking ``move_N2`` [forward, right] eye heights and, with
    ``eyes_N2``, rising from H0 to H1 eye heights above the floor (``walk_source``; bilinear, indices clamped so
    the border repeats the edge). A zero move at a constant height returns the frame unchanged."""
    if x_NhwC.ndim != 4 or move_N2.shape != (x_NhwC.shape[0], 2):
        raise ValueError(f"walk_latents takes x (N, h, w, C) and move (N, 2); got {x_NhwC.shape}, {move_N2.shape}")
    if eyes_N2 is not None and eyes_N2.shape != move_N2.shape:
        raise ValueError(f"walk_latents takes eyes (N, 2) [H0, H1] like move; got {eyes_N2.shape}")
    n, h, w, c = x_NhwC.shape
    rows, cols = walk_source(h, w, move_N2.astype(jnp.float32), None if eyes_N2 is None
                             else eyes_N2.astype(jnp.float32))
    r0, c0 = jnp.floor(rows), jnp.floor(cols)
    fr, fc = (rows - r0)[..., None].astype(x_NhwC.dtype), (cols - c0)[..., None].astype(x_NhwC.dtype)
    flat = x_NhwC.reshape(n, h * w, c)

    def take(r, col):
        idx = jnp.clip(r, 0, h - 1).astype(jnp.int32) * w + jnp.clip(col, 0, w - 1).astype(jnp.int32)
        return jnp.take_along_axis(flat, idx.reshape(n, h * w, 1), axis=1).reshape(n, h, w, c)

    top = (1 - fc) * take(r0, c0) + fc * take(r0, c0 + 1)
    bottom = (1 - fc) * take(r0 + 1, c0) + fc * take(r0 + 1, c0 + 1)
    still = jnp.all(move_N2 == 0, axis=-1)  # standing still at one height returns x itself, bit for bit
    if eyes_N2 is not None:
        still = still & (eyes_N2[:, 0] == eyes_N2[:, 1])
    return jnp.where(still[:, None, None, None], x_NhwC, (1 - fr) * top + fr * bottom)


# ---------------------------------------------------------------------------------------------
# Jumping (``DiTConfig.jump_warp``, docs/model.md §8.1)
# ---------------------------------------------------------------------------------------------

# Minecraft's vertical motion per tick (blocks, ticks; ``engine/constants.py`` has the same values): a jump from
# the ground sets the vertical velocity, then every tick moves by it and it becomes (vy - gravity) * drag.
JUMP_VELOCITY, GRAVITY, VERTICAL_DRAG = 0.42, 0.08, 0.98
_JUMP = MODEL_INDEX["jump"]
JUMP_STATE = 3  # (height above the floor, vertical velocity, the previous latent frame's mean height), blocks


def jump_ticks(jump_BPT: jax.Array, state_BP2: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Heights above a flat floor tick by tick from the jump key alone: (heights after each tick (B, P, T),
    (height, vertical velocity) after each tick (B, P, T, 2)), from ``state_BP2``. On the floor (height 0, not
    rising) a held jump key jumps; a landing stops on the floor. Nothing else (blocks underfoot, water) is known,
    so a jump onto a block lands back on the floor."""
    def tick(state, jump):
        y, vy = state[..., 0], state[..., 1]
        vy = jnp.where((y <= 0.0) & (vy <= 0.0) & (jump > 0.5), JUMP_VELOCITY, vy)
        y = y + vy
        landed = y <= 0.0
        y, vy = jnp.where(landed, 0.0, y), jnp.where(landed, 0.0, vy)
        new = jnp.stack([y, (vy - GRAVITY) * VERTICAL_DRAG], axis=-1)
        return new, new

    _, states = jax.lax.scan(tick, state_BP2.astype(jnp.float32), jnp.moveaxis(jump_BPT.astype(jnp.float32), -1, 0))
    states = jnp.moveaxis(states, 0, -2)  # (B, P, T, 2)
    return states[..., 0], states


def frame_lifts(keyboard_BPTK: jax.Array, num_frames: int, frames_per_step: int,
                state_BP3: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """Each latent frame's height change from its jump key: (lift (B, P, F, 2) = [the previous frame's mean
    height, this frame's] in blocks, the jump state after each frame (B, P, F, ``JUMP_STATE``)).

    The frames' ticks are the last k * F entries of the (padded) keyboard sequence (frame f's are the last k of
    its window; docs/model.md §4.3); a frame's height is the mean over its k ticks, as its latent sums k video
    frames. ``state_BP3`` is the state before the first frame (``JUMP_STATE``; default: standing on the floor,
    the previous mean height 0): a whole clip starts there, a rollout's cache carries it on."""
    b, p = keyboard_BPTK.shape[:2]
    k = frames_per_step
    if keyboard_BPTK.shape[-1] <= _JUMP or keyboard_BPTK.shape[2] < k * num_frames:
        raise ValueError(f"frame_lifts reads the jump key of the last k * F = {k * num_frames} ticks; the keyboard "
                         f"sequence has shape {keyboard_BPTK.shape}")
    state = jnp.zeros((b, p, JUMP_STATE), jnp.float32) if state_BP3 is None else state_BP3.astype(jnp.float32)
    heights, states = jump_ticks(keyboard_BPTK[:, :, keyboard_BPTK.shape[2] - k * num_frames:, _JUMP], state[..., :2])
    mean_BPF = heights.reshape(b, p, num_frames, k).mean(axis=-1)
    prev_BPF = jnp.concatenate([state[..., 2:], mean_BPF[..., :-1]], axis=-1)
    after = jnp.concatenate([states.reshape(b, p, num_frames, k, 2)[..., -1, :], mean_BPF[..., None]], axis=-1)
    return jnp.stack([prev_BPF, mean_BPF], axis=-1), after


# ---------------------------------------------------------------------------------------------
# Both warps together (the DiT's warp input; ``benchmarks.dream_fidelity.WarpFormula`` on pixels)
# ---------------------------------------------------------------------------------------------


def warp_previous(prev_NhwC: jax.Array, mouse_NWA: jax.Array, keyboard_NWK: jax.Array, frames_per_step: int,
                  pixels_per_degree: tuple[float, float], walk_warp: float, interp: str,
                  lift_N2: jax.Array | None = None, jump_warp: float = 0.0, geometry: str = "shift") -> jax.Array:
    """Each frame moved by its action window: by its walk (``walk_latents``, ``walk_warp`` eye heights per tick;
    0 = no walk) and its jump (``lift_N2`` [previous, this] heights in blocks from ``frame_lifts``, times
    ``jump_warp`` eye heights per block; 0 = no jump), then by its camera turn (``geometry``: "shift",
    ``shift_latents``, or "rotation", ``turn_latents``). ``prev_NhwC`` float, one action window per frame."""
    x = prev_NhwC.astype(jnp.float32)
    eyes = None if not jump_warp or lift_N2 is None else 1.0 + jump_warp * lift_N2.astype(jnp.float32)
    if walk_warp or eyes is not None:
        x = walk_latents(x, frame_moves(keyboard_NWK, frames_per_step) * walk_warp, eyes)
    turns = frame_turns(mouse_NWA, frames_per_step)
    if geometry == "rotation":
        return turn_latents(x, turns, pixels_per_degree, interp)
    if geometry != "shift":
        raise ValueError(f"geometry must be one of {WARP_GEOMETRIES}, got {geometry!r}")
    return shift_latents(x, content_shift(turns, pixels_per_degree), interp)


# ---------------------------------------------------------------------------------------------
# Turning as a rotation (``DiTConfig.warp_geometry = "rotation"``, docs/model.md §8.1)
# ---------------------------------------------------------------------------------------------


def view_tangents(h: int, w: int, pixels_per_degree: tuple[float, float]) -> tuple[float, float]:
    """(tan of half the vertical field of view, tan of half the horizontal one) of the pinhole camera whose
    content moves ``pixels_per_degree`` (height, width) pixels per degree of turn at the centre of an h x w view:
    a ray at screen position u in [-1, 1] has tangent u * tan_half, so d(pixels)/d(radians) at u = 0 is
    (size / 2) / tan_half. The tiny16 warp (0.1996, 0.1122) on 16 x 16 latents gives 0.700 and 1.244: the
    engine's 70-degree vertical field of view shown 16:9 (tan 35 deg = 0.700, x 16 / 9 = 1.245)."""
    per_radian = [float(p) * 180.0 / math.pi for p in pixels_per_degree]
    return (h / 2) / per_radian[0], (w / 2) / per_radian[1]


def turn_source(h: int, w: int, turns_N2: jax.Array, pixels_per_degree: tuple[float, float]) -> tuple[jax.Array, jax.Array]:
    """(row, col), each (N, h, w) float32: where in the previous frame each pixel of the turned view looks, for
    turns_N2 [left, up] degrees (the mouse convention; ``frame_turns``): the camera's ray through the pixel
    centre, rotated back by the pitch (about the camera's right axis) and then the yaw (about the vertical),
    projected onto the previous view (``view_tangents``). Pixel centres are at index + 0.5; no turn gives each
    pixel its own index. Rays that end up behind the camera are sent far outside the frame (edge values)."""
    tan_v, tan_h = view_tangents(h, w, pixels_per_degree)
    turns = turns_N2.astype(jnp.float32)
    n = turns.shape[0]
    rx = jnp.broadcast_to(((jnp.arange(w, dtype=jnp.float32) + 0.5) / w * 2 - 1)[None, None, :] * tan_h, (n, h, w))
    ry = jnp.broadcast_to((1 - (jnp.arange(h, dtype=jnp.float32) + 0.5) / h * 2)[None, :, None] * tan_v, (n, h, w))
    yaw_right = jnp.radians(-turns[:, 0])[:, None, None]
    pitch_down = jnp.radians(-turns[:, 1])[:, None, None]
    ry2 = ry * jnp.cos(pitch_down) - jnp.sin(pitch_down)
    rz2 = ry * jnp.sin(pitch_down) + jnp.cos(pitch_down)
    ox = rx * jnp.cos(yaw_right) + rz2 * jnp.sin(yaw_right)
    oz = -rx * jnp.sin(yaw_right) + rz2 * jnp.cos(yaw_right)
    ahead = oz > 1e-3
    oz = jnp.where(ahead, oz, 1.0)
    u = jnp.where(ahead, ox / (oz * tan_h), 1e3)
    v = jnp.where(ahead, ry2 / (oz * tan_v), 1e3)
    return (1 - v) / 2 * h - 0.5, (u + 1) / 2 * w - 0.5


def turn_latents(x_NhwC: jax.Array, turns_N2: jax.Array, pixels_per_degree: tuple[float, float],
                 interp: str = "linear") -> jax.Array:
    """Each latent frame as the turned camera sees it: sampled at ``turn_source`` (bilinear, or bicubic with the
    Catmull-Rom weights of ``interp = "cubic"``) on the frame extended by repeating its edges, as
    ``shift_latents`` does. No turn returns the frame; at the view's centre it moves as ``shift_latents`` with
    the same pixels per degree."""
    if x_NhwC.ndim != 4 or turns_N2.shape != (x_NhwC.shape[0], 2):
        raise ValueError(f"turn_latents takes x (N, h, w, C) and turns (N, 2); got {x_NhwC.shape}, {turns_N2.shape}")
    if interp not in WARP_INTERPOLATIONS:
        raise ValueError(f"interp must be one of {WARP_INTERPOLATIONS}, got {interp!r}")
    _, h, w, _ = x_NhwC.shape
    row, col = turn_source(h, w, turns_N2, pixels_per_degree)
    r0, c0 = jnp.floor(row), jnp.floor(col)
    fr, fc = row - r0, col - c0
    if interp == "cubic":
        taps, wr, wc = (-1, 0, 1, 2), _cubic_weights(fr), _cubic_weights(fc)
    else:
        taps, wr, wc = (0, 1), (1 - fr, fr), (1 - fc, fc)
    r0, c0 = r0.astype(jnp.int32), c0.astype(jnp.int32)

    def one(x_hwC, r0_hw, c0_hw, wr_Thw, wc_Thw):
        out = jnp.zeros(x_hwC.shape, jnp.float32)
        for a, da in enumerate(taps):
            rows = jnp.clip(r0_hw + da, 0, h - 1)
            for b, db in enumerate(taps):
                cols = jnp.clip(c0_hw + db, 0, w - 1)
                out = out + (wr_Thw[a] * wc_Thw[b])[..., None] * x_hwC[rows, cols]
        return out

    return jax.vmap(one)(x_NhwC.astype(jnp.float32), r0, c0, jnp.stack(wr, 1), jnp.stack(wc, 1))
