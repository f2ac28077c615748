"""JAX voxel renderer: Minecraft-like first-person views of one world, many views per call.

Every pixel casts one ray. Rays march through the voxel array with a DDA that skips empty space
using a max-height pyramid over the (x, z) columns: a ray that stays above every block of a
2^L x 2^L tile of columns jumps over the whole tile (L grows after each jump and shrinks when the
tile is too tall), and only next to geometry does it step voxel by voxel. Blocks are textured from
the procedural atlas with Minecraft's fixed per-face shading; water is a translucent surface that
rays pass through; torches are a thin stick tested analytically; player avatars are six oriented
boxes (the Minecraft player model) intersected analytically and depth-tested against the blocks.
Distance fog blends into the sky colour, and the HUD is drawn on top.

Conventions: +Y up, -Z north, +X east; block (x, y, z) spans [x, x+1) x [y, y+1) x [z, z+1). Yaw is
Mineflayer's (0 = north, +yaw turns left/CCW seen from +Y), pitch + is up. A view looks along
d = (-sin(yaw) cos(pitch), sin(pitch), -cos(yaw) cos(pitch)) with screen-right (cos(yaw), 0, -sin(yaw)).
Inside the renderer all positions are relative to the voxel array's origin (array index units).

Shape letters: B views, K world snapshots, X/Y/Z voxel array axes, A avatars per view, P pixels
(H*W), H/W image height/width, N parts of the player model (6).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from solaris_env.engine import hud as hud_lib
from solaris_env.engine import textures as tx
from solaris_env.engine.blocks import Block
from solaris_env.engine.constants import FOV_DEG, PLAYER_HEIGHT

# ----------------------------------------------------------------------------------------------
# Look constants
# ----------------------------------------------------------------------------------------------

# Minecraft's fixed face shading ("directional" light of the vanilla block renderer).
SHADE_TOP, SHADE_BOTTOM, SHADE_NORTH_SOUTH, SHADE_EAST_WEST = 1.0, 0.5, 0.8, 0.6
SKY_ZENITH_RGB = (0.47, 0.65, 1.0)  # vanilla plains sky at noon
SKY_HORIZON_RGB = (0.75, 0.85, 1.0)  # vanilla fog colour at noon
SKY_GRADIENT_POWER = 0.5  # sky colour vs elevation: mix(horizon, zenith, elevation ** power)
WATER_SURFACE_ALPHA = 0.45  # opacity of a water surface with nothing (zero depth) behind it
WATER_DEPTH_SCALE = 3.0  # blocks of water that multiply the remaining transparency by 1/e
NEAR_CLIP = 0.05  # blocks; avatar surfaces closer than this to the eye are not drawn

# ----------------------------------------------------------------------------------------------
# Ray marching constants
# ----------------------------------------------------------------------------------------------

NUM_LEVELS = 6  # max-height pyramid levels: tiles of 1, 2, 4, ..., 32 columns
# Most rays finish in a few steps, a few need many: rays march in tiers, each tier compacting the
# tiles of still-active rays into a buffer of 1/frac of all tiles and running rounds of `steps`
# steps (while more tiles are active than the next tier holds, at most `max_rounds`).
# (frac, steps, max_rounds). The last tier runs until every ray is done (see _march_tiers).
MARCH_TIERS = ((1, 8, 1), (8, 16, 8), (64, 64, 0))
STEPS_PER_BLOCK = 1.5  # the last tier's rounds: a voxel-by-voxel ray crosses <= sqrt(3) voxels per block
MAX_STEPS_PER_BLOCK = 4  # bound on the steps of any ray: <= sqrt(3) voxel steps per block, each with
# at most one skip and one level change around it
MIN_TIER_TILES = 16  # smallest compacted buffer
TILE_RAYS = 16  # rays are compacted in tiles of this many consecutive pixels (cheap, coherent)
START_EPS = 1e-4  # blocks; rays that start outside the array begin this far inside it
VOXEL_NUDGE = 1e-3  # blocks past a voxel's entry point that surely lie inside the voxel
CELL_NUDGE = 1e-4  # blocks along the ray at which a voxel's non-entry coordinates are taken
AXIS_NONE = 3  # "no entry face": the ray starts inside the array

# ----------------------------------------------------------------------------------------------
# Player model (Minecraft's: 32 model pixels = PLAYER_HEIGHT blocks)
# ----------------------------------------------------------------------------------------------

MODEL_PX = PLAYER_HEIGHT / 32.0  # blocks per model pixel
HIP_Y_PX = 12.0
# Per part (textures.PART_* order): pivot in the model frame and the box around it, in model pixels.
# The model frame has the avatar's feet at the origin and faces -Z; its right side is +X.
PART_PIVOT_PX = np.array([
    [0, 24, 0],  # head: neck
    [0, HIP_Y_PX, 0],  # body: hip
    [6, 22, 0],  # right arm: shoulder
    [-6, 22, 0],  # left arm
    [2, HIP_Y_PX, 0],  # right leg: hip joint
    [-2, HIP_Y_PX, 0],  # left leg
], np.float32)
PART_BOX_LO_PX = np.array([[-4, 0, -4], [-4, 0, -2], [-2, -10, -2], [-2, -10, -2], [-2, -12, -2], [-2, -12, -2]],
                          np.float32)
PART_BOX_HI_PX = np.array([[4, 8, 4], [4, 12, 2], [2, 2, 2], [2, 2, 2], [2, 0, 2], [2, 0, 2]], np.float32)
assert np.allclose(PART_BOX_HI_PX - PART_BOX_LO_PX, np.array(tx.PART_SIZE_PX)), "boxes must match the skin sizes"
# Which parts hang from the upper body (they lean with it when sneaking).
PART_ON_UPPER_BODY = np.array([1, 1, 1, 1, 0, 0], np.float32)
# Limb swing sign per part: legs and arms in opposite phases, right and left opposite.
PART_SWING_SIGN = np.array([0, 0, -1, 1, 1, -1], np.float32)
PART_IS_HEAD = np.array([1, 0, 0, 0, 0, 0], np.float32)
SNEAK_LEAN_RAD = 0.5  # forward lean of the upper body when sneaking (vanilla: 0.5 rad)
SNEAK_DROP_PX = 0.15 / MODEL_PX  # the hips drop this much; with the lean the head drops ~0.3 blocks
AVATAR_CENTRE_Y = PLAYER_HEIGHT / 2  # centre of the bounding sphere, above the feet
AVATAR_BOUND_RADIUS = 1.2  # blocks; holds the model in any pose (head pitch, swing, sneak)
AVATAR_TILE_FRAC = 8  # the avatar pass handles 1/AVATAR_TILE_FRAC of the ray tiles per round
AVATAR_MIN_TILES = 16


# ----------------------------------------------------------------------------------------------
# Config and inputs
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RenderConfig:
    """Renderer settings.

    Args:
        height, width: image size in pixels.
        fov_deg: vertical field of view, like Minecraft's FOV setting.
        display_aspect: width/height of the game window the frame shows. Minecraft (and the paper's
            data) is 16:9, so with the default every frame covers the same horizontal field of view
            (~102 deg at 70 deg vertical) whatever its pixel size: a 64x64 frame is the 16:9 view
            resampled to a square, exactly as resizing a recorded 640x360 frame would give. This keeps
            the eval protocol valid at any resolution (a +-40 deg turn leaves the partner on screen).
            None = square pixels (horizontal extent from width/height).
        view_distance: rays stop here (blocks); fog reaches the sky colour here.
        fog_start_frac: fog begins at this fraction of ``view_distance``.
        hud: draw the hotbar and crosshair.
    """

    height: int = 64
    width: int = 64
    fov_deg: float = FOV_DEG
    display_aspect: float | None = 16 / 9
    view_distance: float = 48.0
    fog_start_frac: float = 0.55
    hud: bool = True

    def __post_init__(self):
        if self.height < 1 or self.width < 1:
            raise ValueError(f"image size must be positive, got height={self.height} width={self.width}")
        if not 1.0 <= self.fov_deg < 180.0:
            raise ValueError(f"fov_deg must be in [1, 180), got {self.fov_deg}")
        if self.display_aspect is not None and not 0.1 <= self.display_aspect <= 10.0:
            raise ValueError(f"display_aspect must be None or in [0.1, 10], got {self.display_aspect}")
        if not self.view_distance > 0.0:
            raise ValueError(f"view_distance must be positive, got {self.view_distance}")
        if not 0.0 <= self.fog_start_frac < 1.0:
            raise ValueError(f"fog_start_frac must be in [0, 1), got {self.fog_start_frac}")


@dataclass
class Views:
    """B views rendered in one call (numpy arrays, B >= 1, A >= 0 avatars per view).

    Attributes:
        world_idx_B: int32 (B,) which voxel snapshot (axis K) each view sees.
        eye_B3: float32 (B, 3) camera position in world coordinates.
        yaw_B, pitch_B: float32 (B,) camera angles, Mineflayer convention (radians).
        avatar_feet_BA3: float32 (B, A, 3) feet position of each avatar drawn in this view.
        avatar_yaw_BA, avatar_pitch_BA: float32 (B, A) body/head yaw and head pitch.
        avatar_skin_BA: int32 (B, A) 0 = Alpha, 1 = Bravo.
        avatar_swing_BA: float32 (B, A) limb swing angle (radians).
        avatar_sneak_BA: bool (B, A) sneaking pose.
        avatar_mask_BA: bool (B, A) draw this avatar.
        selected_slot_B: int32 (B,) 0..8.
        hotbar_items_B9: int32 (B, 9) block id (<256), Item id (>=256) or 0 = empty.
        daylight_B: float32 (B,) 1.0 = noon, ~0.25 = night.
    """

    world_idx_B: np.ndarray
    eye_B3: np.ndarray
    yaw_B: np.ndarray
    pitch_B: np.ndarray
    avatar_feet_BA3: np.ndarray
    avatar_yaw_BA: np.ndarray
    avatar_pitch_BA: np.ndarray
    avatar_skin_BA: np.ndarray
    avatar_swing_BA: np.ndarray
    avatar_sneak_BA: np.ndarray
    avatar_mask_BA: np.ndarray
    selected_slot_B: np.ndarray
    hotbar_items_B9: np.ndarray
    daylight_B: np.ndarray

    @property
    def num_views(self) -> int:
        return int(np.shape(self.yaw_B)[0])

    @property
    def num_avatars(self) -> int:
        return int(np.shape(self.avatar_mask_BA)[1])


# ----------------------------------------------------------------------------------------------
# World preprocessing (inside jit)
# ----------------------------------------------------------------------------------------------


def _height_pyramid(voxels_KXYZ: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Max-height pyramid of the non-air columns.

    Returns:
        pyramid_KLXZ: float32 (K, NUM_LEVELS, X, Z); level L holds, for every column, the top
            (highest non-air y + 1, 0 if empty) over its aligned 2^L x 2^L tile of columns.
        top_K: float32 (K,) the highest top in each snapshot.
    """
    K, X, Y, Z = voxels_KXYZ.shape
    heights_Y = jnp.arange(1, Y + 1, dtype=jnp.int32)
    top_KXZ = jnp.max(jnp.where(voxels_KXYZ != Block.AIR, heights_Y[None, None, :, None], 0), axis=2)
    levels = []
    for level in range(NUM_LEVELS):
        size = 1 << level
        xp, zp = -(-X // size) * size, -(-Z // size) * size
        padded = jnp.pad(top_KXZ, ((0, 0), (0, xp - X), (0, zp - Z)))
        tiles = padded.reshape(K, xp // size, size, zp // size, size).max(axis=(2, 4))
        full = jnp.repeat(jnp.repeat(tiles, size, axis=1), size, axis=2)[:, :X, :Z]
        levels.append(full)
    pyramid_KLXZ = jnp.stack(levels, axis=1).astype(jnp.float32)
    return pyramid_KLXZ, jnp.max(top_KXZ, axis=(1, 2)).astype(jnp.float32)


# ----------------------------------------------------------------------------------------------
# Camera rays
# ----------------------------------------------------------------------------------------------


def _pixel_ndc(cfg: RenderConfig) -> tuple[np.ndarray, np.ndarray]:
    """Image-plane offsets at unit distance of every pixel centre: (right_P, up_P) float32."""
    tan_half = math.tan(math.radians(cfg.fov_deg) / 2.0)
    aspect = cfg.width / cfg.height if cfg.display_aspect is None else cfg.display_aspect
    rows, cols = np.meshgrid(np.arange(cfg.height), np.arange(cfg.width), indexing="ij")
    right = ((cols + 0.5) / cfg.width * 2.0 - 1.0) * tan_half * aspect
    up = (1.0 - (rows + 0.5) / cfg.height * 2.0) * tan_half
    return right.reshape(-1).astype(np.float32), up.reshape(-1).astype(np.float32)


def _ray_dirs(right_P, up_P, yaw_B, pitch_B):
    """Unit ray directions (dx, dy, dz), each (B, P)."""
    cy, sy = jnp.cos(yaw_B)[:, None], jnp.sin(yaw_B)[:, None]
    cp, sp = jnp.cos(pitch_B)[:, None], jnp.sin(pitch_B)[:, None]
    fwd = (-sy * cp, sp, -cy * cp)
    right = (cy, jnp.zeros_like(cy), -sy)
    # up = right x forward
    up = (right[1] * fwd[2] - right[2] * fwd[1], right[2] * fwd[0] - right[0] * fwd[2],
          right[0] * fwd[1] - right[1] * fwd[0])
    r, u = right_P[None, :], up_P[None, :]
    d = [fwd[i] + r * right[i] + u * up[i] for i in range(3)]
    inv_norm = jax.lax.rsqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    return tuple(c * inv_norm for c in d)


def pack_rgb(rgb_N3: np.ndarray) -> np.ndarray:
    """uint8 RGB(A) texels -> uint32 (R | G << 8 | B << 16 | A << 24): one gather fetches a texel."""
    rgb_N3 = rgb_N3.astype(np.uint32)
    return sum(rgb_N3[..., c] << (8 * c) for c in range(rgb_N3.shape[-1])).astype(np.uint32)


def unpack_rgb(packed, channels: int = 3):
    """uint32 packed texels -> (..., channels) float32 in [0, 1]."""
    return jnp.stack([((packed >> (8 * c)) & 255).astype(jnp.float32) for c in range(channels)], axis=-1) / 255.0


def _safe_inv(d):
    """1/d with zero components replaced by a tiny positive value (no inf/NaN in the slab tests)."""
    tiny = jnp.float32(1e-12)
    return 1.0 / jnp.where(jnp.abs(d) < tiny, tiny, d)


# ----------------------------------------------------------------------------------------------
# Avatars: the Minecraft player model as six oriented boxes
# ----------------------------------------------------------------------------------------------


def _part_frames(feet_BA3, yaw_BA, pitch_BA, swing_BA, sneak_BA):
    """Per part: rotation about the model X axis, the body yaw, and the pivot in array coordinates.

    Returns:
        theta_BAN: (B, A, N) part rotation about the model's X axis (+ tilts the part's -Z toward +Y).
        pivot_BAN3: (B, A, N, 3) pivot positions (array units).
    """
    sneak = sneak_BA.astype(jnp.float32)[..., None]
    lean = -SNEAK_LEAN_RAD * sneak  # forward lean = negative rotation about X
    theta = (PART_IS_HEAD * pitch_BA[..., None]
             + (1.0 - PART_IS_HEAD) * PART_ON_UPPER_BODY * lean
             + PART_SWING_SIGN * swing_BA[..., None])
    # Pivots of upper-body parts rotate about the hip with the lean; everything drops when sneaking.
    rel_y = PART_PIVOT_PX[:, 1] - HIP_Y_PX
    rel_z = PART_PIVOT_PX[:, 2]
    cl, sl = jnp.cos(lean), jnp.sin(lean)
    on_upper = PART_ON_UPPER_BODY
    py = HIP_Y_PX + on_upper * (cl * rel_y - sl * rel_z) + (1 - on_upper) * rel_y - SNEAK_DROP_PX * sneak
    pz = on_upper * (sl * rel_y + cl * rel_z) + (1 - on_upper) * rel_z
    px = jnp.broadcast_to(PART_PIVOT_PX[:, 0], py.shape)
    # Rotate the pivot by the body yaw into the world: x' = c x + s z, z' = -s x + c z.
    cyaw, syaw = jnp.cos(yaw_BA)[..., None], jnp.sin(yaw_BA)[..., None]
    wx = (cyaw * px + syaw * pz) * MODEL_PX + feet_BA3[..., 0:1]
    wy = py * MODEL_PX + feet_BA3[..., 1:2]
    wz = (-syaw * px + cyaw * pz) * MODEL_PX + feet_BA3[..., 2:3]
    return theta, jnp.stack([wx, wy, wz], axis=-1)


def _trace_avatars(o_B3, d, feet_BA3, yaw_BA, pitch_BA, swing_BA, sneak_BA, mask_BA):
    """Nearest avatar box along every ray (analytic slab test in each box's own frame).

    Args:
        o_B3: eye per view; d: ray directions, 3 x (B, P); the rest: avatar pose per view, (B, A).

    Returns:
        t_BP: distance to the nearest avatar surface (inf where none).
        box_BP: int32 index a * N + part of the box hit (0 where none).
        theta_BAN, pivot_BAN3: the part frames (for texturing the hit).
    """
    B, A = mask_BA.shape
    N = tx.NUM_PARTS
    theta, pivot = _part_frames(feet_BA3, yaw_BA, pitch_BA, swing_BA, sneak_BA)
    cyaw = jnp.broadcast_to(jnp.cos(yaw_BA)[..., None], theta.shape)  # (B, A, N)
    syaw = jnp.broadcast_to(jnp.sin(yaw_BA)[..., None], theta.shape)
    ct, st = jnp.cos(theta), jnp.sin(theta)
    # Eye in each part's frame (model pixels): R_x(theta)^T R_y(yaw)^T (eye - pivot) / px.
    rel = (o_B3[:, None, None, :] - pivot) / MODEL_PX
    ex = cyaw * rel[..., 0] - syaw * rel[..., 2]
    ez0 = syaw * rel[..., 0] + cyaw * rel[..., 2]
    ey = ct * rel[..., 1] + st * ez0
    ez = -st * rel[..., 1] + ct * ez0
    e_BAN3 = jnp.stack([ex, ey, ez], axis=-1)
    box_params = jnp.concatenate([
        jnp.stack([cyaw, syaw, ct, st, mask_BA[..., None].astype(jnp.float32) * jnp.ones_like(ct)], axis=-1),
        PART_BOX_LO_PX - e_BAN3, PART_BOX_HI_PX - e_BAN3], axis=-1).reshape(B, A * N, -1)  # (B, A*N, 11)
    dx, dy, dz = (c / MODEL_PX for c in d)

    def one_box(k, best):
        t_best, box_best = best
        cy_, sy_, ct_, st_, on, lx, ly, lz, hx, hy, hz = (c[:, None] for c in jnp.moveaxis(box_params[:, k], -1, 0))
        qx = cy_ * dx - sy_ * dz
        qz0 = sy_ * dx + cy_ * dz
        qy = ct_ * dy + st_ * qz0
        qz = -st_ * dy + ct_ * qz0
        t_near, t_far = None, None
        for q, lo, hi in ((qx, lx, hx), (qy, ly, hy), (qz, lz, hz)):
            inv = _safe_inv(q)
            t1, t2 = lo * inv, hi * inv
            near, far = jnp.minimum(t1, t2), jnp.maximum(t1, t2)
            t_near = near if t_near is None else jnp.maximum(t_near, near)
            t_far = far if t_far is None else jnp.minimum(t_far, far)
        better = (t_near <= t_far) & (t_near > NEAR_CLIP) & (on > 0) & (t_near < t_best)
        return jnp.where(better, t_near, t_best), jnp.where(better, k, box_best)

    init = (jnp.full(dx.shape, jnp.inf, jnp.float32), jnp.zeros(dx.shape, jnp.int32))
    t_BP, box_BP = jax.lax.fori_loop(0, A * N, one_box, init)
    return t_BP, box_BP, theta, pivot


def _shade_avatars(o_B3, d, t_BP, box_BP, theta_BAN, pivot_BAN3, yaw_BA, skin_BA, skins_flat):
    """Skin colour (already face-shaded) of the avatar box hit by each ray: (B, P, 3) float in [0, 1]."""
    B, A = yaw_BA.shape
    N = tx.NUM_PARTS
    a_BP, part_BP = box_BP // N, box_BP % N

    def per_box(arr_BAN):
        return jnp.take_along_axis(arr_BAN.reshape(B, A * N), box_BP, axis=1)

    def per_avatar(arr_BA):
        return jnp.take_along_axis(arr_BA, a_BP, axis=1)

    theta = per_box(theta_BAN)
    ct, st = jnp.cos(theta), jnp.sin(theta)
    yaw = per_avatar(yaw_BA)
    cyaw, syaw = jnp.cos(yaw), jnp.sin(yaw)
    t = jnp.where(jnp.isfinite(t_BP), t_BP, 0.0)
    # Hit point relative to the pivot, rotated into the part frame (model pixels).
    rel = [(o_B3[:, i:i + 1] + d[i] * t - per_box(pivot_BAN3[..., i])) / MODEL_PX for i in range(3)]
    lx = cyaw * rel[0] - syaw * rel[2]
    lz0 = syaw * rel[0] + cyaw * rel[2]
    ly = ct * rel[1] + st * lz0
    lz = -st * rel[1] + ct * lz0
    lo = jnp.asarray(PART_BOX_LO_PX)[part_BP]  # (B, P, 3)
    size = jnp.asarray(PART_BOX_HI_PX - PART_BOX_LO_PX)[part_BP]
    qn = [jnp.clip((c - lo[..., i]) / size[..., i], 0.0, 1.0) for i, c in enumerate((lx, ly, lz))]
    # The face hit is the one the point lies closest to (in pixels).
    dist_face = jnp.stack([jnp.minimum(qn[i], 1 - qn[i]) * size[..., i] for i in range(3)], axis=-1)
    axis = jnp.argmin(dist_face, axis=-1)
    upper = jnp.stack([qn[i] > 0.5 for i in range(3)], axis=-1)
    positive = jnp.take_along_axis(upper, axis[..., None], axis=-1)[..., 0]
    face = 2 * axis + positive.astype(jnp.int32)  # FACE_NEG_X, FACE_POS_X, NEG_Y, POS_Y, FRONT(-Z), BACK(+Z)
    col = jnp.select(
        [face == tx.FACE_NEG_X, face == tx.FACE_POS_X, face == tx.FACE_FRONT, face == tx.FACE_BACK],
        [qn[2], 1 - qn[2], 1 - qn[0], qn[0]], qn[0])
    row = jnp.where(axis == 1, qn[2], 1 - qn[1])
    tex = tx.TEX
    ci = jnp.clip((col * tex).astype(jnp.int32), 0, tex - 1)
    ri = jnp.clip((row * tex).astype(jnp.int32), 0, tex - 1)
    skin = per_avatar(skin_BA)
    texel = (((skin * N + part_BP) * tx.NUM_BOX_FACES + face) * tex + ri) * tex + ci
    rgb = unpack_rgb(skins_flat[texel])
    # World-space normal of the face for Minecraft-like directional shading.
    sign = jnp.where(positive, 1.0, -1.0)
    nl = [jnp.where(axis == i, sign, 0.0) for i in range(3)]
    nz0 = -st * nl[1] + ct * nl[2]  # R_x(theta) n
    ny = ct * nl[1] + st * nl[2]
    nx = cyaw * nl[0] + syaw * nz0  # R_y(yaw)
    nz = -syaw * nl[0] + cyaw * nz0
    shade = (nx * nx * SHADE_EAST_WEST + nz * nz * SHADE_NORTH_SOUTH
             + ny * ny * jnp.where(ny > 0, SHADE_TOP, SHADE_BOTTOM))
    return rgb * shade[..., None]


def _avatar_pass(eye_B3, d, av, skins_flat):
    """Trace and shade the avatars, only for tiles of rays that may see one.

    A ray may see an avatar if it points into the avatar's bounding sphere. The tiles holding such
    rays are processed in rounds of a fixed number of tiles (gathered into a dense buffer), so the
    cost follows how much of the screen the avatars cover.

    Returns:
        t_BP (inf where none), avatar index a_BP (-1 where none), rgb_BP3 (face-shaded skin colour).
    """
    B, P = d[0].shape
    G = TILE_RAYS
    tiles_per_view = -(-P // G)
    T = B * tiles_per_view
    centre = av["feet"] + jnp.asarray([0.0, AVATAR_CENTRE_Y, 0.0], jnp.float32)
    rel_BA3 = centre - eye_B3[:, None, :]
    dist2_BA = jnp.sum(rel_BA3 * rel_BA3, axis=-1)
    # The ray points into the sphere iff d . rel >= sqrt(|rel|^2 - r^2) (or the eye is inside it).
    reach_BA = jnp.sqrt(jnp.maximum(dist2_BA - AVATAR_BOUND_RADIUS ** 2, 0.0))
    dots_BPA = sum(d[i][..., None] * rel_BA3[:, None, :, i] for i in range(3))
    cand_BP = jnp.any(av["mask"][:, None, :] & (dots_BPA >= reach_BA[:, None, :]), axis=-1)

    def tiles(a, fill):  # (B, P, ...) -> (T, G, ...)
        pad = [(0, 0), (0, tiles_per_view * G - P)] + [(0, 0)] * (a.ndim - 2)
        return jnp.pad(a, pad, constant_values=fill).reshape((T, G) + a.shape[2:])

    cand_T = jnp.any(tiles(cand_BP, False), axis=1)
    d_TG = tuple(tiles(c, 1.0) for c in d)
    capacity = min(T, max(AVATAR_MIN_TILES, T // AVATAR_TILE_FRAC))

    def body(carry):
        done_T, t_TG, a_TG, rgb_TG3 = carry
        idx = jnp.nonzero(cand_T & ~done_T, size=capacity, fill_value=T)[0]
        idx_c = jnp.minimum(idx, T - 1)
        view = idx_c // tiles_per_view
        sub = {k: a[view] for k, a in av.items()}
        sub["mask"] = sub["mask"] & (idx < T)[:, None]
        eye = eye_B3[view]
        d_CG = tuple(c[idx_c] for c in d_TG)
        t, box, theta, pivot = _trace_avatars(eye, d_CG, sub["feet"], sub["yaw"], sub["pitch"], sub["swing"],
                                              sub["sneak"], sub["mask"])
        rgb = _shade_avatars(eye, d_CG, t, box, theta, pivot, sub["yaw"], sub["skin"], skins_flat)
        a = jnp.where(jnp.isfinite(t), box // tx.NUM_PARTS, -1)
        return (done_T.at[idx].set(True, mode="drop"), t_TG.at[idx].set(t, mode="drop"),
                a_TG.at[idx].set(a, mode="drop"), rgb_TG3.at[idx].set(rgb, mode="drop"))

    def cond(carry):
        return jnp.any(cand_T & ~carry[0])

    init = (jnp.zeros((T,), bool), jnp.full((T, G), jnp.inf, jnp.float32), jnp.full((T, G), -1, jnp.int32),
            jnp.zeros((T, G, 3), jnp.float32))
    _, t_TG, a_TG, rgb_TG3 = jax.lax.while_loop(cond, body, init)

    def per_pixel(a):
        return a.reshape((B, tiles_per_view * G) + a.shape[2:])[:, :P]

    return per_pixel(t_TG), per_pixel(a_TG), per_pixel(rgb_TG3)


# ----------------------------------------------------------------------------------------------
# Voxel march
# ----------------------------------------------------------------------------------------------


# The march state of a ray is one int32: its voxel (each coordinate + 1, so -1..N fits) and its
# pyramid level and done flag. A single state array keeps XLA's step to a single fused loop.
_DONE_BITS, _LEVEL_BITS = 1, 3


@dataclass(frozen=True)
class _Packing:
    """Bit layout of the march state, LSB first: done | level | z + 1 | y + 1 | x + 1."""

    bits_x: int
    bits_y: int
    bits_z: int

    @staticmethod
    def for_shape(X: int, Y: int, Z: int) -> "_Packing":
        pk = _Packing(*(int(n + 2 - 1).bit_length() for n in (X, Y, Z)))
        total = _DONE_BITS + _LEVEL_BITS + pk.bits_x + pk.bits_y + pk.bits_z
        if total > 31:
            raise ValueError(f"voxel array {(X, Y, Z)} too large for the renderer's packed state ({total} > 31 bits)")
        return pk

    @property
    def shift_z(self) -> int:
        return _DONE_BITS + _LEVEL_BITS

    @property
    def shift_y(self) -> int:
        return self.shift_z + self.bits_z

    @property
    def shift_x(self) -> int:
        return self.shift_y + self.bits_y

    def pack(self, cx, cy, cz, level, done):
        return ((cx + 1) << self.shift_x) | ((cy + 1) << self.shift_y) | ((cz + 1) << self.shift_z) \
            | (level << _DONE_BITS) | done.astype(jnp.int32)

    def unpack(self, code):
        def field(shift, bits):
            return ((code >> shift) & ((1 << bits) - 1)) - 1

        level = (code >> _DONE_BITS) & ((1 << _LEVEL_BITS) - 1)
        return (field(self.shift_x, self.bits_x), field(self.shift_y, self.bits_y), field(self.shift_z, self.bits_z),
                level, (code & 1) == 1)


def _start_cells(o, d, t0, axis0):
    """Voxel where a ray starts: at distance ``t0``, entering through a face on ``axis0`` (AXIS_NONE when
    it starts inside). The entry axis snaps to the face plane; the others are taken a hair further on."""
    cells = []
    for i in range(3):
        p = o[i] + d[i] * t0
        on_face = jnp.round(p).astype(jnp.int32) - (d[i] < 0).astype(jnp.int32)
        inside = jnp.floor(p + d[i] * CELL_NUDGE).astype(jnp.int32)
        cells.append(jnp.where(axis0 == i, on_face, inside))
    return cells


def _cell_times(o, inv, cells):
    """Entry and exit distance of each ray's voxel, and the axis of the entry face.

    Returns:
        t_in, t_out, axis_in, axis_out (same shape as the cells).
    """
    near, far = [], []
    for i in range(3):
        lo = (cells[i].astype(jnp.float32) - o[i]) * inv[i]
        hi = lo + inv[i]  # the voxel is one block wide
        pos = inv[i] > 0
        near.append(jnp.where(pos, lo, hi))
        far.append(jnp.where(pos, hi, lo))
    axis_in = jnp.where((near[0] >= near[1]) & (near[0] >= near[2]), 0, jnp.where(near[1] >= near[2], 1, 2))
    axis_out = jnp.where((far[0] <= far[1]) & (far[0] <= far[2]), 0, jnp.where(far[1] <= far[2], 1, 2))
    t_in = jnp.maximum(jnp.maximum(near[0], near[1]), near[2])
    t_out = jnp.minimum(jnp.minimum(far[0], far[1]), far[2])
    return t_in, t_out, axis_in, axis_out


def _march_step(pk: _Packing, shape_XYZ, vox_flat, pyr_flat, g, code, see_through):
    """One step of every ray: skip a free tile of columns, step one voxel, or refine the level.

    ``g`` holds the ray geometry: per-tile (T, 1) origin o* and snapshot offsets vofs/hofs, per-ray
    (T, G) direction d*, its inverse i*, and end distance ``tend``. Water and torch voxels stop a
    ray unless ``see_through`` (a traced bool).
    """
    X, Y, Z = shape_XYZ
    cx, cy, cz, level, done = pk.unpack(code)
    o, d, inv = (g["ox"], g["oy"], g["oz"]), (g["dx"], g["dy"], g["dz"]), (g["ix"], g["iy"], g["iz"])
    pos = tuple(c > 0 for c in d)
    t_in, tn, _, ax_n = _cell_times(o, inv, (cx, cy, cz))
    t_in = jnp.maximum(t_in, 0.0)
    # Column test at the current level: is the ray above every block of its tile until it leaves it?
    size = jnp.left_shift(1, level)
    align = ~(size - 1)
    lox, loz = cx & align, cz & align
    tcx = (jnp.where(pos[0], lox + size, lox).astype(jnp.float32) - o[0]) * inv[0]
    tcz = (jnp.where(pos[2], loz + size, loz).astype(jnp.float32) - o[2]) * inv[2]
    tcol = jnp.minimum(tcx, tcz)
    ylo = jnp.minimum(o[1] + d[1] * t_in, o[1] + d[1] * tcol)
    cxc, cyc, czc = jnp.clip(cx, 0, X - 1), jnp.clip(cy, 0, Y - 1), jnp.clip(cz, 0, Z - 1)
    # The gathers run as their own small loops (XLA does not vectorise a loop that contains one).
    h_idx, v_idx = jax.lax.optimization_barrier((g["hofs"] + level * (X * Z) + cxc * Z + czc,
                                                 g["vofs"] + (cxc * Y + cyc) * Z + czc))
    h, v = jax.lax.optimization_barrier((pyr_flat[h_idx], vox_flat[v_idx]))
    free = ylo >= h
    # Voxel test (only meaningful at level 0). Below the array is bedrock, above it air.
    v = jnp.where(cy < 0, jnp.uint8(Block.BEDROCK), jnp.where(cy >= Y, jnp.uint8(Block.AIR), v))
    blocked0 = (level == 0) & ~free
    stops = (v != Block.AIR) & ~(see_through & ((v == Block.WATER) | (v == Block.TORCH)))
    dda = blocked0 & ~stops
    t_move = jnp.where(free, tcol, tn)
    ends = t_move >= g["tend"]
    move = (free | dda) & ~ends
    # Skip: leave the tile through its x or z face; the other coordinates a hair further on, never
    # behind the current voxel (so every move advances and no ray can cycle at an edge).
    exit_x = tcx <= tcz
    skip = []
    for i, c in enumerate((cx, cy, cz)):
        q = jnp.floor(o[i] + d[i] * (tcol + CELL_NUDGE)).astype(jnp.int32)
        skip.append(jnp.where(pos[i], jnp.maximum(q, c), jnp.minimum(q, c)))
    skip[0] = jnp.where(exit_x, jnp.where(pos[0], lox + size, lox - 1), skip[0])
    skip[2] = jnp.where(exit_x, skip[2], jnp.where(pos[2], loz + size, loz - 1))
    new = []
    for i, c in enumerate((cx, cy, cz)):
        stepped = jnp.where(ax_n == i, c + jnp.where(pos[i], 1, -1), c)
        new.append(jnp.where(move, jnp.where(free, skip[i], stepped), c))
    level = jnp.where(free, jnp.where(ends, level, jnp.minimum(level + 1, NUM_LEVELS - 1)),
                      jnp.where(blocked0, level, level - 1))
    new_done = done | (blocked0 & stops) | ((free | dda) & ends)
    return jnp.where(done, code, pk.pack(*new, level, new_done))


def _active(code):
    return (code & 1) == 0


def _march_rays(pk, shape_XYZ, vox_flat, pyr_flat, g, code, see_through, max_steps: int):
    """Up to ``max_steps`` steps of the rays in ``g``/``code``, stopping early when all are done."""

    def cond(carry):
        it, code = carry
        return (it < max_steps) & jnp.any(_active(code))

    def body(carry):
        it, code = carry
        return it + 1, _march_step(pk, shape_XYZ, vox_flat, pyr_flat, g, code, see_through)

    return jax.lax.while_loop(cond, body, (jnp.int32(0), code))[1]


def _march_compacted(pk, shape_XYZ, vox_flat, pyr_flat, g, code, see_through, capacity: int, steps: int):
    """March the first ``capacity`` tiles that hold active rays (gathered into a dense buffer: a cheap
    compaction, as neighbouring rays finish together) and scatter them back. Arrays are (T, G)."""
    T = code.shape[0]
    idx = jnp.nonzero(jnp.any(_active(code), axis=1), size=capacity, fill_value=T)[0]
    idx_c = jnp.minimum(idx, T - 1)
    sub_g = {k: a[idx_c] for k, a in g.items()}
    sub_code = jnp.where((idx < T)[:, None], code[idx_c], 1)  # padding tiles are born done
    sub_code = _march_rays(pk, shape_XYZ, vox_flat, pyr_flat, sub_g, sub_code, see_through, steps)
    return code.at[idx].set(sub_code, mode="drop")


def _march(pk, shape_XYZ, vox_flat, pyr_flat, g, code, see_through, tiers):
    """March all rays ((T, G) arrays) until they stop or end, tier by tier (see MARCH_TIERS)."""
    T = code.shape[0]
    caps = [min(T, max(MIN_TIER_TILES, T // frac)) for frac, _, _ in tiers]
    # Tiers whose buffer is no smaller than the one before (small batches) merge into it.
    keep = [i for i in range(len(tiers)) if i == 0 or caps[i] < caps[i - 1]]
    merged = []
    for j, i in enumerate(keep):
        last = keep[j + 1] if j + 1 < len(keep) else len(tiers)
        steps = max(tiers[k][1] for k in range(i, last))
        rounds = sum(tiers[k][2] for k in range(i, last))
        merged.append((caps[i], steps, rounds))
    for i, (cap, steps, max_rounds) in enumerate(merged):
        next_cap = merged[i + 1][0] if i + 1 < len(merged) else 0

        def cond(carry, next_cap=next_cap, max_rounds=max_rounds):
            r, code = carry
            return (r < max_rounds) & (jnp.sum(jnp.any(_active(code), axis=1)) > next_cap)

        def body(carry, cap=cap, steps=steps):
            r, code = carry
            if cap >= T:
                return r + 1, _march_rays(pk, shape_XYZ, vox_flat, pyr_flat, g, code, see_through, steps)
            return r + 1, _march_compacted(pk, shape_XYZ, vox_flat, pyr_flat, g, code, see_through, cap, steps)

        code = jax.lax.while_loop(cond, body, (jnp.int32(0), code))[1]
    return code


def _march_tiers(view_distance: float) -> tuple[tuple[int, int, int], ...]:
    """MARCH_TIERS with the last tier sized to the view distance: rounds of ~STEPS_PER_BLOCK steps
    per block, and enough rounds to take every tile through the longest possible ray (a bound that
    only a pathological scene approaches; normally the tier stops when the last ray is done)."""
    frac, steps, _ = MARCH_TIERS[-1]
    steps = max(steps, math.ceil(STEPS_PER_BLOCK * view_distance))
    max_steps = MAX_STEPS_PER_BLOCK * view_distance
    return MARCH_TIERS[:-1] + ((frac, steps, frac * math.ceil(max_steps / steps)),)


def _march_views(shape_XYZ, vox_flat, pyr_flat, k_B1, o, d, t0_BP, axis0_BP, t_end_BP, tiers=MARCH_TIERS):
    """March the (B, P) rays of all views: first to the first non-air voxel, then (for the rays that
    stopped at water or a torch) on through see-through voxels to the first opaque one.

    Returns a dict of (B, P) arrays: ``t``/``axis`` entry distance and face axis of the opaque
    voxel hit, ``hit`` its block id (0 = none); ``special_t``/``special`` entry distance and block id
    of the first see-through voxel (inf / AIR if none).
    """
    X, Y, Z = shape_XYZ
    B, P = t0_BP.shape
    G = TILE_RAYS
    tiles_per_view = -(-P // G)
    pk = _Packing.for_shape(X, Y, Z)

    def per_ray(a, fill):  # (B, P) -> (T, G), each view padded to whole tiles
        a = jnp.broadcast_to(a, (B, P))
        return jnp.pad(a, ((0, 0), (0, tiles_per_view * G - P)), constant_values=fill).reshape(-1, G)

    def per_tile(a_B1):  # (B, 1) -> (T, 1)
        return jnp.repeat(a_B1, tiles_per_view, axis=0)

    def per_pixel(a_TG):  # (T, G) -> (B, P)
        return a_TG.reshape(B, tiles_per_view * G)[:, :P]

    g = dict(ox=per_tile(o[0]), oy=per_tile(o[1]), oz=per_tile(o[2]),
             vofs=per_tile(k_B1 * (X * Y * Z)), hofs=per_tile(k_B1 * (NUM_LEVELS * X * Z)),
             dx=per_ray(d[0], 1.0), dy=per_ray(d[1], 1.0), dz=per_ray(d[2], 1.0), tend=per_ray(t_end_BP, -1.0))
    g.update(ix=_safe_inv(g["dx"]), iy=_safe_inv(g["dy"]), iz=_safe_inv(g["dz"]))
    cells0 = _start_cells(o, d, t0_BP, axis0_BP)
    zero = jnp.zeros((B, P), jnp.int32)
    code = per_ray(pk.pack(*cells0, zero, t0_BP >= t_end_BP), 1)

    def voxel_at(cells):
        inside = [(c >= 0) & (c < n) for c, n in zip(cells, shape_XYZ)]
        idx = (jnp.clip(cells[0], 0, X - 1) * Y + jnp.clip(cells[1], 0, Y - 1)) * Z + jnp.clip(cells[2], 0, Z - 1)
        v = vox_flat[k_B1 * (X * Y * Z) + idx].astype(jnp.int32)
        v = jnp.where(inside[0] & inside[2] & (cells[1] < Y), v, int(Block.AIR))
        return jnp.where(cells[1] < 0, int(Block.BEDROCK), v)

    def unpack_pixels(code):
        cx, cy, cz, _, done = (per_pixel(a) for a in pk.unpack(code))
        return (cx, cy, cz), done

    def one_pass(p, carry):
        # Pass 0 stops at any non-air voxel; pass 1 takes the rays that stopped at water or a torch
        # on through see-through voxels. One loop over both keeps one copy of the march to compile.
        code, special_t, special_id = carry
        code = _march(pk, shape_XYZ, vox_flat, pyr_flat, g, code, p == 1, tiers)
        cells, done = unpack_pixels(code)
        v = voxel_at(cells)
        special = (p == 0) & done & ((v == Block.WATER) | (v == Block.TORCH))
        t_in = _cell_times(o, inv, cells)[0]
        special_t = jnp.where(special, jnp.maximum(t_in, 0.0), special_t)
        special_id = jnp.where(special, v, special_id)
        return jnp.where(per_ray(special, False), code & ~1, code), special_t, special_id

    inv = tuple(_safe_inv(c) for c in d)
    init = (code, jnp.full((B, P), jnp.inf, jnp.float32), jnp.full((B, P), int(Block.AIR), jnp.int32))
    code, special_t, special_id = jax.lax.fori_loop(0, 2, one_pass, init)
    cells, done = unpack_pixels(code)
    v = voxel_at(cells)
    hit = done & (v != Block.AIR) & (v != Block.WATER) & (v != Block.TORCH)
    t_in, _, axis_in, _ = _cell_times(o, inv, cells)
    return dict(t=jnp.maximum(t_in, 0.0), axis=axis_in, cells=cells, hit=jnp.where(hit, v, 0),
                special_t=special_t, special=special_id)


def _ray_range(o, d, top_B1, X: int, Z: int, view_distance: float):
    """Clip every ray to the occupied box [0, X] x [-1, top] x [0, Z] and the view distance.

    Returns:
        t0_BP: start distance, axis0_BP: the axis of the entry face, t_end_BP: end distance.
    """
    lo = (0.0, -1.0, 0.0)
    hi = (float(X), top_B1, float(Z))
    t_near, t_far, axis0 = None, None, None
    for i in range(3):
        inv = _safe_inv(d[i])
        t1, t2 = (lo[i] - o[i]) * inv, (hi[i] - o[i]) * inv
        near, far = jnp.minimum(t1, t2), jnp.maximum(t1, t2)
        if t_near is None:
            t_near, t_far, axis0 = near, far, jnp.zeros(near.shape, jnp.int32)
        else:
            axis0 = jnp.where(near > t_near, i, axis0)
            t_near, t_far = jnp.maximum(t_near, near), jnp.minimum(t_far, far)
    inside = t_near <= 0.0
    t0 = jnp.where(inside, 0.0, t_near + START_EPS)
    axis0 = jnp.where(inside, AXIS_NONE, axis0)
    t_end = jnp.minimum(t_far, view_distance)
    return t0, axis0, t_end


# ----------------------------------------------------------------------------------------------
# Shading
# ----------------------------------------------------------------------------------------------


def _block_texel(block, axis, d, f, atlas_flat):
    """Atlas colour of a cube face: block (B, P) id, entry ``axis``, in-voxel hit point ``f`` (3 x (B, P))."""
    tex = tx.TEX
    dx, dy, dz = d
    fx, fy, fz = f
    face = jnp.where(axis == 1, jnp.where(dy < 0, tx.FACE_TOP, tx.FACE_BOTTOM), tx.FACE_SIDE)
    # Texture columns run to the viewer's right on each face (see textures.py).
    col = jnp.where(axis == 0, jnp.where(dx < 0, 1 - fz, fz),
                    jnp.where(axis == 2, jnp.where(dz > 0, 1 - fx, fx), fx))
    row = jnp.where(axis == 1, fz, 1 - fy)
    ci = jnp.clip((col * tex).astype(jnp.int32), 0, tex - 1)
    ri = jnp.clip((row * tex).astype(jnp.int32), 0, tex - 1)
    idx = ((block * tx.NUM_BLOCK_FACES + face) * tex + ri) * tex + ci
    return unpack_rgb(atlas_flat[idx])


def _nearest_face_axis(p):
    """Axis of the voxel face a point lies on: the coordinate closest to a whole number."""
    dist = [jnp.abs(c - jnp.round(c)) for c in p]
    return jnp.where((dist[0] <= dist[1]) & (dist[0] <= dist[2]), 0, jnp.where(dist[1] <= dist[2], 1, 2))


def _face_shade(axis, dy):
    return jnp.where(axis == 0, SHADE_EAST_WEST,
                     jnp.where(axis == 2, SHADE_NORTH_SOUTH, jnp.where(dy < 0, SHADE_TOP, SHADE_BOTTOM)))


def _trace_torch(torch_t, o, d):
    """Ray vs the torch stick in the first torch voxel the ray entered (at ``torch_t``).

    Returns:
        t_BP (inf where missed), axis_BP, and the in-voxel hit point (3 x (B, P)).
    """
    tex = float(tx.TEX)
    entered = jnp.isfinite(torch_t)
    t_in = jnp.where(entered, torch_t, 0.0) + VOXEL_NUDGE
    cell = [jnp.floor(o[i] + d[i] * t_in) for i in range(3)]
    half_w = tx.TORCH_WIDTH / tex / 2.0
    lo = (0.5 - half_w, 0.0, 0.5 - half_w)
    hi = (0.5 + half_w, (tex - tx.TORCH_TOP_ROW) / tex, 0.5 + half_w)
    t_near, t_far, axis = None, None, None
    for i in range(3):
        inv = _safe_inv(d[i])
        base = cell[i] - o[i]
        t1, t2 = (base + lo[i]) * inv, (base + hi[i]) * inv
        near, far = jnp.minimum(t1, t2), jnp.maximum(t1, t2)
        if t_near is None:
            t_near, t_far, axis = near, far, jnp.zeros(near.shape, jnp.int32)
        else:
            axis = jnp.where(near > t_near, i, axis)
            t_near, t_far = jnp.maximum(t_near, near), jnp.minimum(t_far, far)
    ok = entered & (t_near <= t_far) & (t_near > 0)
    t = jnp.where(ok, t_near, jnp.inf)
    f = [o[i] + d[i] * t_near - cell[i] for i in range(3)]
    return t, axis, f


def _torch_color(axis, f, atlas_flat, daylight_B1):
    """Torch stick/flame colour; flame texels ignore shading and daylight (they glow)."""
    tex = tx.TEX
    fx, fy, fz = f
    across = jnp.where(axis == 0, fz, fx)
    ci = tx.TORCH_COL0 + jnp.clip(((across - 0.5) * tex).astype(jnp.int32) + tx.TORCH_WIDTH // 2, 0, tx.TORCH_WIDTH - 1)
    row_along = jnp.clip(tex - 1 - (fy * tex).astype(jnp.int32), tx.TORCH_TOP_ROW, tex - 1)
    ri = jnp.where(axis == 1, tx.TORCH_TOP_ROW, row_along)  # the top face shows the flame tip
    idx = ((int(Block.TORCH) * tx.NUM_BLOCK_FACES + tx.FACE_SIDE) * tex + ri) * tex + ci
    rgb = unpack_rgb(atlas_flat[idx])
    flame = ri < tx.TORCH_TOP_ROW + tx.TORCH_FLAME_ROWS
    light = jnp.where(flame, 1.0, daylight_B1 * jnp.where(axis == 0, SHADE_EAST_WEST, SHADE_NORTH_SOUTH))
    return rgb * light[..., None]


def _sky(dy, daylight_B1):
    """Sky colour by view elevation, (B, P, 3)."""
    w = jnp.clip(dy, 0.0, 1.0) ** SKY_GRADIENT_POWER
    zen, hor = jnp.asarray(SKY_ZENITH_RGB), jnp.asarray(SKY_HORIZON_RGB)
    return (hor + (zen - hor) * w[..., None]) * daylight_B1[..., None]


# ----------------------------------------------------------------------------------------------
# The whole frame
# ----------------------------------------------------------------------------------------------


def _surfaces(m, o, d, t_end, atlas_flat, daylight_B1):
    """Distance and lit colour of the opaque block, torch stick and water surface each ray meets.

    Args:
        m: ``_march_views`` output; o: eye, 3 x (B, 1); d: ray directions, 3 x (B, P);
        t_end: (B, P) where each ray ends (view distance or the array's bounds).

    Returns:
        dict of (t_block, rgb_block), (t_torch, rgb_torch), (t_water, rgb_water): distances (B, P),
        inf where absent, and colours (B, P, 3).
    """
    t_blk = jnp.where(m["hit"] > 0, m["t"], jnp.inf)
    f = [jnp.clip(o[i] + d[i] * m["t"] - c.astype(jnp.float32), 0.0, 1.0) for i, c in enumerate(m["cells"])]
    blk_rgb = _block_texel(m["hit"], m["axis"], d, f, atlas_flat)
    blk_rgb = blk_rgb * (_face_shade(m["axis"], d[1]) * daylight_B1)[..., None]
    torch_t = jnp.where(m["special"] == Block.TORCH, m["special_t"], jnp.inf)
    t_torch, torch_axis, torch_f = _trace_torch(torch_t, o, d)
    t_torch = jnp.where(t_torch < t_end, t_torch, jnp.inf)
    torch_rgb = _torch_color(torch_axis, torch_f, atlas_flat, daylight_B1)
    t_water = jnp.where(m["special"] == Block.WATER, m["special_t"], jnp.inf)
    wp = [o[i] + d[i] * jnp.where(jnp.isfinite(t_water), t_water, 0.0) for i in range(3)]
    water_axis = _nearest_face_axis(wp)
    water_rgb = _block_texel(jnp.full_like(m["hit"], int(Block.WATER)), water_axis, d, [c - jnp.floor(c) for c in wp],
                             atlas_flat)
    water_rgb = water_rgb * (_face_shade(water_axis, d[1]) * daylight_B1)[..., None]
    return dict(t_block=t_blk, rgb_block=blk_rgb, t_torch=t_torch, rgb_torch=torch_rgb, t_water=t_water,
                rgb_water=water_rgb)


def _composite(cfg: RenderConfig, s, t_av, av_rgb, sky, t_end):
    """Nearest surface, water in front of it, then distance fog.

    Returns:
        rgb_BP3 float colour and is_avatar_BP (the avatar is the surface seen).
    """
    t_surf = jnp.minimum(jnp.minimum(s["t_block"], s["t_torch"]), t_av)
    is_av = jnp.isfinite(t_av) & (t_av <= t_surf)
    is_torch = ~is_av & jnp.isfinite(s["t_torch"]) & (s["t_torch"] <= t_surf)
    has_surf = jnp.isfinite(t_surf)
    rgb = jnp.where(is_av[..., None], av_rgb, jnp.where(is_torch[..., None], s["rgb_torch"], s["rgb_block"]))
    rgb = jnp.where(has_surf[..., None], rgb, sky)
    # Water in front of the surface: the more water the ray crosses, the more of its colour.
    wt = s["t_water"]
    in_water = jnp.isfinite(wt) & (wt < t_surf)
    depth = jnp.maximum(jnp.where(has_surf, t_surf, t_end) - wt, 0.0)
    alpha = 1.0 - (1.0 - WATER_SURFACE_ALPHA) * jnp.exp(-depth / WATER_DEPTH_SCALE)
    rgb = jnp.where(in_water[..., None], rgb + (s["rgb_water"] - rgb) * alpha[..., None], rgb)
    # Linear fog from fog_start to the view distance, toward the sky colour of the pixel.
    t_first = jnp.where(in_water, wt, t_surf)
    fog_start = cfg.fog_start_frac * cfg.view_distance
    fog = jnp.clip((t_first - fog_start) / (cfg.view_distance - fog_start), 0.0, 1.0)
    fog = jnp.where(jnp.isfinite(t_first), fog, 0.0)
    return rgb + (sky - rgb) * fog[..., None], is_av


def _render_frames(cfg: RenderConfig, ndc, hud_consts, voxels_KXYZ, atlas_flat, skins_flat, v):
    """Pure, jittable: views (dict of arrays, positions relative to the array origin) -> images.

    Returns:
        rgb_BHW3 uint8, avatar_id_BHW int8 (-1 where no avatar is seen).
    """
    _, X, Y, Z = voxels_KXYZ.shape
    B = v["yaw_B"].shape[0]
    pyramid_KLXZ, top_K = _height_pyramid(voxels_KXYZ)
    k_B1 = v["world_idx_B"][:, None]
    o = tuple(v["eye_B3"][:, i:i + 1] for i in range(3))
    d = _ray_dirs(ndc[0], ndc[1], v["yaw_B"], v["pitch_B"])
    daylight_B1 = v["daylight_B"][:, None]
    # Avatars first: their distance also ends the voxel march early.
    av = dict(feet=v["avatar_feet_BA3"], yaw=v["avatar_yaw_BA"], pitch=v["avatar_pitch_BA"], swing=v["avatar_swing_BA"],
              sneak=v["avatar_sneak_BA"], mask=v["avatar_mask_BA"], skin=v["avatar_skin_BA"])
    t_av, av_id, av_rgb = _avatar_pass(v["eye_B3"], d, av, skins_flat)
    t_av = jnp.where(t_av < cfg.view_distance, t_av, jnp.inf)
    t0, axis0, t_end = _ray_range(o, d, top_K[k_B1], X, Z, cfg.view_distance)
    m = _march_views((X, Y, Z), voxels_KXYZ.reshape(-1), pyramid_KLXZ.reshape(-1), k_B1, o, d, t0, axis0,
                     jnp.minimum(t_end, t_av), _march_tiers(cfg.view_distance))
    surfaces = _surfaces(m, o, d, t_end, atlas_flat, daylight_B1)
    rgb_BP3, is_av = _composite(cfg, surfaces, t_av, av_rgb * daylight_B1[..., None], _sky(d[1], daylight_B1), t_end)
    rgb_BP3 = jnp.clip(rgb_BP3, 0.0, 1.0)
    if cfg.hud:
        rgb_BP3 = hud_lib.composite(rgb_BP3, v["selected_slot_B"], v["hotbar_items_B9"], hud_consts)
    rgb_BHW3 = jnp.round(rgb_BP3 * 255.0).astype(jnp.uint8).reshape(B, cfg.height, cfg.width, 3)
    avatar_id_BHW = jnp.where(is_av, av_id, -1).astype(jnp.int8).reshape(B, cfg.height, cfg.width)
    return rgb_BHW3, avatar_id_BHW


def _next_pow2(n: int) -> int:
    return 1 << max(0, int(n) - 1).bit_length()


@functools.lru_cache(maxsize=None)
def _texture_arrays() -> tuple[jax.Array, jax.Array]:
    """Packed block atlas and skin atlas (uint32 texels), built once per process."""
    return (jnp.asarray(pack_rgb(tx.block_atlas().reshape(-1, 3))),
            jnp.asarray(pack_rgb(tx.skin_atlas().reshape(-1, 3))))


@functools.lru_cache(maxsize=None)
def _jitted_render(cfg: RenderConfig):
    """One jitted render function per config, shared by all Renderers (so compilations are too)."""
    ndc = tuple(jnp.asarray(a) for a in _pixel_ndc(cfg))
    hud_consts = hud_lib.HudLayout.build(cfg.height, cfg.width).device_arrays() if cfg.hud else None

    def fn(voxels_KXYZ, atlas_flat, skins_flat, views):
        return _render_frames(cfg, ndc, hud_consts, voxels_KXYZ, atlas_flat, skins_flat, views)

    return jax.jit(fn)


# Per-view inputs: name -> (dtype, trailing shape after B or (B, A)).
_VIEW_FIELDS = {
    "world_idx_B": (np.int32, ()), "eye_B3": (np.float32, (3,)), "yaw_B": (np.float32, ()),
    "pitch_B": (np.float32, ()), "avatar_feet_BA3": (np.float32, (3,)), "avatar_yaw_BA": (np.float32, ()),
    "avatar_pitch_BA": (np.float32, ()), "avatar_skin_BA": (np.int32, ()), "avatar_swing_BA": (np.float32, ()),
    "avatar_sneak_BA": (bool, ()), "avatar_mask_BA": (bool, ()), "selected_slot_B": (np.int32, ()),
    "hotbar_items_B9": (np.int32, (hud_lib.NUM_SLOTS,)), "daylight_B": (np.float32, ()),
}


class Renderer:
    """Batched first-person renderer of one world: B views of K voxel snapshots per call.

    The texture atlases and HUD are built once and the render function is jitted once per config.
    Calls are bucketed so that shapes (and compilations) repeat: the number of views B and of
    snapshots K are padded up to powers of two, the number of avatars A to at least one.

    Args:
        cfg: image size, field of view, view distance, fog and HUD settings.
    """

    def __init__(self, cfg: RenderConfig):
        self.cfg = cfg
        self._atlas_flat, self._skins_flat = _texture_arrays()
        self._fn = _jitted_render(cfg)

    def render(self, voxels_KXYZ: np.ndarray, origin: tuple[int, int, int],
               views: Views) -> tuple[np.ndarray, np.ndarray]:
        """Render B views of one world.

        Args:
            voxels_KXYZ: (K, X, Y, Z) uint8 snapshots of one world (same origin).
            origin: world coordinates of voxel index (0, 0, 0).
            views: the B views.

        Returns:
            rgb_BHW3 uint8 and avatar_id_BHW int8: the index on axis A of the avatar seen at each
            pixel (nearest surface), -1 where none.
        """
        voxels_KXYZ = np.asarray(voxels_KXYZ)
        if voxels_KXYZ.ndim != 4 or voxels_KXYZ.dtype != np.uint8 or 0 in voxels_KXYZ.shape:
            raise ValueError(f"voxels_KXYZ must be a non-empty (K, X, Y, Z) uint8 array, got "
                             f"{voxels_KXYZ.shape} {voxels_KXYZ.dtype}")
        K = voxels_KXYZ.shape[0]
        B, A = views.num_views, views.num_avatars
        arrays = self._view_arrays(views, origin)
        if B < 1 or arrays["world_idx_B"].min() < 0 or arrays["world_idx_B"].max() >= K:
            raise ValueError(f"need B >= 1 views with world_idx_B in [0, {K}), got B={B} "
                             f"world_idx_B={arrays['world_idx_B']}")
        k_pad, b_pad, a_pad = _next_pow2(K), _next_pow2(B), max(A, 1)
        if k_pad > K:
            voxels_KXYZ = np.concatenate([voxels_KXYZ, np.zeros((k_pad - K,) + voxels_KXYZ.shape[1:], np.uint8)])
        for name, arr in arrays.items():
            if name.endswith("_BA") or name.endswith("_BA3"):
                arr = np.concatenate([arr, np.zeros((B, a_pad - A) + arr.shape[2:], arr.dtype)], axis=1)
            arrays[name] = np.concatenate([arr, np.repeat(arr[-1:], b_pad - B, axis=0)])
        arrays["avatar_mask_BA"][B:] = False
        rgb_BHW3, avatar_id_BHW = self._fn(voxels_KXYZ, self._atlas_flat, self._skins_flat, arrays)
        rgb_BHW3, avatar_id_BHW = np.asarray(rgb_BHW3)[:B], np.asarray(avatar_id_BHW)[:B]
        return rgb_BHW3, avatar_id_BHW

    @staticmethod
    def _view_arrays(views: Views, origin) -> dict[str, np.ndarray]:
        """Views as arrays of the renderer's dtypes, positions relative to ``origin``, shapes checked."""
        B, A = views.num_views, views.num_avatars
        arrays = {}
        for name, (dtype, tail) in _VIEW_FIELDS.items():
            shape = (B, A) + tail if "_BA" in name else (B,) + tail
            arr = np.asarray(getattr(views, name))
            if arr.shape != shape:
                raise ValueError(f"Views.{name} must have shape {shape}, got {arr.shape}")
            arrays[name] = arr.astype(np.float64 if dtype == np.float32 else dtype)
        org = np.asarray(origin, np.float64)
        arrays["eye_B3"] = arrays["eye_B3"] - org
        arrays["avatar_feet_BA3"] = arrays["avatar_feet_BA3"] - org
        for name, (dtype, _) in _VIEW_FIELDS.items():
            arrays[name] = arrays[name].astype(dtype)
        arrays["avatar_skin_BA"] = np.clip(arrays["avatar_skin_BA"], 0, tx.NUM_SKINS - 1)
        arrays["selected_slot_B"] = np.clip(arrays["selected_slot_B"], 0, hud_lib.NUM_SLOTS - 1)
        return arrays
