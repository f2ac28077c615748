"""Where the partner stands in each player's view: the partner map (``DiTConfig.partner_map``, docs/model.md §8.6).

An option of ours, off in the official layout. The DiT reads, as one more conditioning channel, the share of
each latent cell that the other player's body covers in this player's view. In training the poses come from the
recording (``*_Alpha_*.json`` records: feet position, yaw, pitch of every frame); in a rollout they are dead
reckoned from the start poses and the actions alone (``track``: the turn from the mouse, the walk from the keys
with Minecraft's ground friction, no collisions and no jumps). Nothing of the world is read: a wall between the
players does not hide the box, and a partner stopped by a block keeps walking in the map.

Conventions (docs/engine.md §1.2, Mineflayer's): a pose is [x, y, z, yaw, pitch], the feet in blocks, yaw 0 =
north (-Z), + = turned left, pitch + = up, radians. The view: eye 1.62 blocks above the feet, 70 deg vertical
field of view on a 16:9 window resampled to the square frame (``camera.VIEW_HALF_TAN``). The body: an upright box
0.6 wide and 1.8 tall standing on the feet (the engine's ``constants.py``; repeated here, the model does not
import the engine).

Shapes: poses (..., 5); a tracker state (..., ``TRACK_STATE``) = the pose and the horizontal velocity [vx, vz].
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from solaris_env.spaces import CAMERA_SCALE_DEG, MODEL_INDEX
from solaris_env.world_model.camera import VIEW_HALF_TAN

POSE = 5  # [x, y, z, yaw, pitch]
TRACK_STATE = 7  # the pose, then the horizontal velocity [vx, vz] (blocks per tick)
EYE_HEIGHT = 1.62
BODY_WIDTH, BODY_HEIGHT = 0.6, 1.8
NEAR = 0.05  # blocks: a box with a corner closer than this in front of the eye is left out of the map
# Minecraft's walking (per tick): v <- (v + accel * input) * friction on the ground, accel = speed * (1 - friction)
GROUND_FRICTION = 0.6 * 0.91
WALK_SPEED, SPRINT_SPEED, SNEAK_SPEED = 4.317 / 20, 5.612 / 20, 1.295 / 20
PITCH_LIMIT = math.pi / 2
_KEY = {name: MODEL_INDEX[name] for name in ("forward", "back", "left", "right", "sneak", "sprint")}


def track_state(pose_N5: jax.Array) -> jax.Array:
    """A tracker state at rest at ``pose`` (..., 5) -> (..., ``TRACK_STATE``)."""
    pose = jnp.asarray(pose_N5, jnp.float32)
    if pose.shape[-1] != POSE:
        raise ValueError(f"a pose is [x, y, z, yaw, pitch] ({POSE} numbers); got shape {pose.shape}")
    return jnp.concatenate([pose, jnp.zeros(pose.shape[:-1] + (2,), jnp.float32)], axis=-1)


def track_tick(state: jax.Array, mouse_2: jax.Array, keyboard_K: jax.Array) -> jax.Array:
    """One tick of dead reckoning, in the engine's order: the camera turns (the model's mouse vector, units of
    ``CAMERA_SCALE_DEG``, + = left / up), then the walk (forward - back, left - right, a diagonal normalised,
    sneak slows, sprint speeds up forward), then the ground friction. Shapes (..., 7), (..., 2), (..., K)."""
    keys = keyboard_K.astype(jnp.float32)
    turn = jnp.radians(mouse_2.astype(jnp.float32) * CAMERA_SCALE_DEG)
    yaw = state[..., 3] + turn[..., 0]
    pitch = jnp.clip(state[..., 4] + turn[..., 1], -PITCH_LIMIT, PITCH_LIMIT)
    forward = keys[..., _KEY["forward"]] - keys[..., _KEY["back"]]
    left = keys[..., _KEY["left"]] - keys[..., _KEY["right"]]
    norm = jnp.maximum(jnp.sqrt(forward ** 2 + left ** 2), 1.0)
    sneak = keys[..., _KEY["sneak"]] > 0
    scale = jnp.where(sneak, SNEAK_SPEED / WALK_SPEED, 1.0) / norm
    forward, left = forward * scale, left * scale
    speed = jnp.where((keys[..., _KEY["sprint"]] > 0) & (forward > 0) & ~sneak, SPRINT_SPEED, WALK_SPEED)
    accel = speed * (1.0 - GROUND_FRICTION)
    sy, cy = jnp.sin(yaw), jnp.cos(yaw)
    # forward = (-sin yaw, -cos yaw), left = (-cos yaw, sin yaw) on (x, z)
    vx = state[..., 5] + accel * (-forward * sy - left * cy)
    vz = state[..., 6] + accel * (-forward * cy + left * sy)
    x, z = state[..., 0] + vx, state[..., 2] + vz
    return jnp.stack([x, state[..., 1], z, yaw, pitch, vx * GROUND_FRICTION, vz * GROUND_FRICTION], axis=-1)


def track(state_N7: jax.Array, mouse_NT2: jax.Array, keyboard_NTK: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Dead reckoning over T ticks: (the poses after each tick (N, T, 5), the state after the last (N, 7)).
    Leading dims N may be any (the same for all three)."""
    if state_N7.shape[-1] != TRACK_STATE:
        raise ValueError(f"a tracker state has {TRACK_STATE} numbers (track_state); got shape {state_N7.shape}")

    def tick(state, ticks):
        new = track_tick(state, *ticks)
        return new, new[..., :POSE]

    mouse, keys = (jnp.moveaxis(a, -2, 0) for a in (mouse_NT2, keyboard_NTK))
    last, poses = jax.lax.scan(tick, state_N7.astype(jnp.float32), (mouse, keys))
    return jnp.moveaxis(poses, 0, -2), last


def box_on_screen(viewer_N5: jax.Array, other_N5: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The screen rectangle of the other player's body seen from the viewer: ([u0, v0, u1, v1] (N, 4), u right and
    v down in [0, 1] of the frame, possibly beyond it; valid (N,): every corner of the box in front of the eye)."""
    x, y, z, yaw, pitch = (viewer_N5[..., i] for i in range(POSE))
    sy, cy, sp, cp = jnp.sin(yaw), jnp.cos(yaw), jnp.sin(pitch), jnp.cos(pitch)
    fwd = jnp.stack([-sy * cp, sp, -cy * cp], axis=-1)
    right = jnp.stack([cy, jnp.zeros_like(cy), -sy], axis=-1)
    up = jnp.cross(right, fwd)
    eye = jnp.stack([x, y + EYE_HEIGHT, z], axis=-1)
    half = BODY_WIDTH / 2
    corners = jnp.array([[dx, dy, dz] for dx in (-half, half) for dy in (0.0, BODY_HEIGHT) for dz in (-half, half)],
                        jnp.float32)  # (8, 3)
    rel = other_N5[..., None, :3] + corners - eye[..., None, :]  # (N, 8, 3)
    depth = jnp.einsum("...ci,...i->...c", rel, fwd)
    valid = jnp.all(depth > NEAR, axis=-1)
    safe = jnp.maximum(depth, NEAR)
    ty, tx = VIEW_HALF_TAN
    u = 0.5 + 0.5 * jnp.einsum("...ci,...i->...c", rel, right) / (safe * tx)
    v = 0.5 - 0.5 * jnp.einsum("...ci,...i->...c", rel, up) / (safe * ty)
    return jnp.stack([u.min(-1), v.min(-1), u.max(-1), v.max(-1)], axis=-1), valid


def coverage(box_N4: jax.Array, valid_N: jax.Array, h: int, w: int) -> jax.Array:
    """(N, h, w) the share of each cell of an h x w grid over the frame that the rectangle covers (0 where not
    valid)."""
    def overlap(lo, hi, n):  # (N,), (N,) in [0, 1] units -> (N, n) covered share of each of n cells
        edges = jnp.arange(n, dtype=jnp.float32)
        return jnp.clip(jnp.minimum(hi[..., None] * n, edges + 1) - jnp.maximum(lo[..., None] * n, edges), 0.0, 1.0)

    cols = overlap(box_N4[..., 0], box_N4[..., 2], w)
    rows = overlap(box_N4[..., 1], box_N4[..., 3], h)
    return rows[..., :, None] * cols[..., None, :] * valid_N[..., None, None].astype(jnp.float32)


def partner_maps(poses_NP5: jax.Array, h: int, w: int) -> jax.Array:
    """(N, 2, h, w): each of two players' view of the other's body (``box_on_screen``, ``coverage``)."""
    if poses_NP5.shape[-2:] != (2, POSE):
        raise ValueError(f"partner maps take the poses of two players (..., 2, {POSE}); got {poses_NP5.shape}")
    viewers = poses_NP5.astype(jnp.float32)
    others = viewers[..., ::-1, :]
    return coverage(*box_on_screen(viewers, others), h, w)


def latent_frame_maps(maps_NThw: jax.Array, frames_per_step: int) -> jax.Array:
    """Video-frame maps (N, T, h, w), T = 1 + k (F - 1), -> latent-frame maps (N, F, h, w): frame 0's own, then the
    mean over each latent frame's k video frames (as its latent sums them)."""
    k, t = frames_per_step, maps_NThw.shape[-3]
    if (t - 1) % k:
        raise ValueError(f"the maps cover {t} video frames; expected 1 + k * (F - 1) with k = {k}")
    rest = maps_NThw[..., 1:, :, :]
    rest = rest.reshape(rest.shape[:-3] + ((t - 1) // k, k) + rest.shape[-2:]).mean(axis=-3)
    return jnp.concatenate([maps_NThw[..., :1, :, :], rest], axis=-3)


def with_partner(cond: jax.Array, maps: jax.Array, mask_channels: int, scale: float = 1.0) -> jax.Array:
    """The DiT's conditioning with the partner map: [mask, scale * map, first-frame latent] from [mask, first-frame
    latent] (..., C) and the maps (...,) shaped like cond without its channel axis (``DiTConfig.partner_map`` is
    the scale)."""
    if maps.shape != cond.shape[:-1]:
        raise ValueError(f"partner maps {maps.shape} must match the conditioning {cond.shape} without its channels")
    return jnp.concatenate([cond[..., :mask_channels], (scale * maps[..., None]).astype(cond.dtype),
                            cond[..., mask_channels:]], axis=-1)
