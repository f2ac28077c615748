"""``engine.render``, ``engine.textures`` and ``engine.hud``: the JAX voxel renderer, its textures and HUD.

Every render uses one of two configs and the same batch shape (B = 4 views, K = 2 snapshots, A = 2
avatars), so the whole file compiles the renderer only twice.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from solaris_env.engine import hud as hud_lib
from solaris_env.engine import textures as tx
from solaris_env.engine.blocks import NUM_BLOCKS, Block, Item
from solaris_env.engine.constants import EYE_HEIGHT
from solaris_env.engine.render import RenderConfig, Renderer, Views

SIZE = 48
CFG = RenderConfig(height=SIZE, width=SIZE, hud=False, display_aspect=None)  # square pixels: simple geometry
CFG_HUD = RenderConfig(height=SIZE, width=SIZE, hud=True)
ORIGIN = (-32, 48, -32)
WORLD_SHAPE = (64, 32, 64)
GROUND_Y = 63  # the grass layer; players stand at y = GROUND_Y + 1
FEET_Y = GROUND_Y + 1
EYE_Y = FEET_Y + EYE_HEIGHT
NUM_VIEWS, NUM_SNAPSHOTS, NUM_AVATARS = 4, 2, 2
NORTH, SOUTH = 0.0, math.pi
HOTBAR = np.array([Block.GRASS, Block.STONE, Block.OAK_PLANKS, Item.DIAMOND_PICKAXE, Item.DIAMOND_SWORD, Block.TORCH,
                   Block.BRICKS, 0, 0], np.int32)


# ----------------------------------------------------------------------------------------------
# Scene helpers
# ----------------------------------------------------------------------------------------------


def flat_world() -> np.ndarray:
    """(X, Y, Z) uint8: stone, three layers of dirt, grass on top at GROUND_Y."""
    v = np.zeros(WORLD_SHAPE, np.uint8)
    gy = GROUND_Y - ORIGIN[1]
    v[:, :gy - 3] = Block.STONE
    v[:, gy - 3:gy] = Block.DIRT
    v[:, gy] = Block.GRASS
    return v


def put(v: np.ndarray, x: int, y: int, z: int, block: int) -> None:
    v[x - ORIGIN[0], y - ORIGIN[1], z - ORIGIN[2]] = block


def snapshots(*worlds: np.ndarray) -> np.ndarray:
    """(NUM_SNAPSHOTS, X, Y, Z): the given worlds, the last repeated."""
    worlds = list(worlds) + [worlds[-1]] * (NUM_SNAPSHOTS - len(worlds))
    return np.stack(worlds)


def make_views(eyes, yaws, pitches, feet=None, avatar_yaw=None, skins=None, mask=None, world_idx=None,
               slot=None) -> Views:
    """NUM_VIEWS views; fewer given views are padded by repeating the last one. ``feet`` is a list
    (per view) of up to NUM_AVATARS avatar feet positions; missing avatars are masked off."""
    n = len(eyes)

    def pad(rows):
        rows = list(rows)
        return rows + [rows[-1]] * (NUM_VIEWS - n)

    feet_BA3 = np.zeros((NUM_VIEWS, NUM_AVATARS, 3), np.float32)
    present_BA = np.zeros((NUM_VIEWS, NUM_AVATARS), bool)
    for b, fs in enumerate(pad(feet if feet is not None else [[]] * n)):
        for a, f in enumerate(fs):
            feet_BA3[b, a], present_BA[b, a] = f, True
    zeros = np.zeros((NUM_VIEWS, NUM_AVATARS), np.float32)
    return Views(
        world_idx_B=np.asarray(pad(world_idx if world_idx is not None else [0] * n), np.int32),
        eye_B3=np.asarray(pad(eyes), np.float32),
        yaw_B=np.asarray(pad(yaws), np.float32),
        pitch_B=np.asarray(pad(pitches), np.float32),
        avatar_feet_BA3=feet_BA3,
        avatar_yaw_BA=np.asarray(pad(avatar_yaw), np.float32) if avatar_yaw is not None else zeros,
        avatar_pitch_BA=zeros,
        avatar_skin_BA=np.asarray(pad(skins), np.int32) if skins is not None else np.zeros_like(zeros, np.int32),
        avatar_swing_BA=zeros,
        avatar_sneak_BA=np.zeros_like(present_BA),
        avatar_mask_BA=present_BA & (np.asarray(pad(mask), bool) if mask is not None else True),
        selected_slot_B=np.asarray(pad(slot if slot is not None else [0] * n), np.int32),
        hotbar_items_B9=np.tile(HOTBAR, (NUM_VIEWS, 1)),
        daylight_B=np.ones(NUM_VIEWS, np.float32),
    )


@pytest.fixture(scope="module")
def renderer() -> Renderer:
    return Renderer(CFG)


@pytest.fixture(scope="module")
def hud_renderer() -> Renderer:
    return Renderer(CFG_HUD)


def centre(img: np.ndarray, frac: float = 0.25) -> np.ndarray:
    h, w = img.shape[:2]
    dh, dw = max(1, int(h * frac)), max(1, int(w * frac))
    return img[h // 2 - dh:h // 2 + dh, w // 2 - dw:w // 2 + dw]


# ----------------------------------------------------------------------------------------------
# Config, textures, HUD layout (no rendering)
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kwargs", [dict(height=0), dict(width=-3), dict(fov_deg=0.5), dict(fov_deg=180.0),
                                    dict(view_distance=0.0), dict(fog_start_frac=1.0), dict(fog_start_frac=-0.1)])
def test_config_validation(kwargs):
    (name, value), = kwargs.items()
    with pytest.raises(ValueError, match=str(value)):
        RenderConfig(**kwargs)


def test_textures_deterministic_and_shaped():
    atlas = tx.block_atlas()
    assert atlas.shape == (NUM_BLOCKS, tx.NUM_BLOCK_FACES, tx.TEX, tx.TEX, 3) and atlas.dtype == np.uint8
    np.testing.assert_array_equal(atlas, tx.block_atlas())
    grass = atlas[Block.GRASS].astype(int)
    assert grass[tx.FACE_TOP, ..., 1].mean() > grass[tx.FACE_TOP, ..., 0].mean()  # green top
    assert grass[tx.FACE_SIDE, -4:, :, 0].mean() > grass[tx.FACE_SIDE, -4:, :, 1].mean()  # dirt side
    skins = tx.skin_atlas()
    assert skins.shape == (tx.NUM_SKINS, tx.NUM_PARTS, tx.NUM_BOX_FACES, tx.TEX, tx.TEX, 3)
    shirt_alpha = skins[tx.SKIN_ALPHA, tx.PART_BODY, tx.FACE_FRONT].astype(int).mean(axis=(0, 1))
    shirt_bravo = skins[tx.SKIN_BRAVO, tx.PART_BODY, tx.FACE_FRONT].astype(int).mean(axis=(0, 1))
    assert shirt_alpha[0] > shirt_alpha[2] and shirt_bravo[2] > shirt_bravo[0]
    icons = tx.icon_atlas()
    table = tx.icon_of_item()
    assert icons[table[0], ..., 3].max() == 0  # empty slot is transparent
    assert icons[table[Item.DIAMOND_SWORD], ..., 3].max() == 255


def test_hud_layout_fits_screen():
    layout = hud_lib.HudLayout.build(SIZE, SIZE)
    assert layout.bg_alpha_P.shape == (SIZE * SIZE,)
    rows = np.flatnonzero(layout.bg_alpha_P.reshape(SIZE, SIZE).max(axis=1) > 0)
    assert rows.min() > SIZE * 3 // 4, "hotbar sits at the bottom"
    assert layout.cross_P.reshape(SIZE, SIZE)[SIZE // 2, SIZE // 2] == 1.0


# ----------------------------------------------------------------------------------------------
# Rendering
# ----------------------------------------------------------------------------------------------


def test_shapes_dtypes_and_determinism(renderer):
    vox = snapshots(flat_world())
    views = make_views([(0.5, EYE_Y, 0.5)] * 3, [0.0, 1.0, 2.0], [0.0, -0.3, 0.3])
    views = Views(**{k: np.asarray(v)[:3] for k, v in vars(views).items()})  # B = 3 (padded inside)
    rgb, avatar_id = renderer.render(vox, ORIGIN, views)
    assert rgb.shape == (3, SIZE, SIZE, 3) and rgb.dtype == np.uint8
    assert avatar_id.shape == (3, SIZE, SIZE) and avatar_id.dtype == np.int8
    rgb2, avatar_id2 = renderer.render(vox, ORIGIN, views)
    assert rgb.tobytes() == rgb2.tobytes() and avatar_id.tobytes() == avatar_id2.tobytes()


def test_looking_up_sees_only_sky_and_down_sees_grass(renderer):
    vox = snapshots(flat_world())
    rgb, avatar_id = renderer.render(vox, ORIGIN, make_views([(0.5, EYE_Y, 0.5)] * 2, [0.3, 0.3],
                                                             [math.pi / 2, -math.pi / 2]))
    up, down = rgb[0].astype(int), rgb[1].astype(int)
    assert (up[..., 2] > up[..., 0]).all() and (up[..., 2] >= 200).all(), "sky is light blue everywhere"
    assert np.ptp(up.reshape(-1, 3), axis=0).max() < 16, "a narrow sky gradient when looking straight up"
    green = (down[..., 1] > down[..., 0]) & (down[..., 1] > down[..., 2])
    assert green.mean() > 0.95
    assert (avatar_id == -1).all()


def test_block_east_of_north_facing_camera_is_on_the_right(renderer):
    base = flat_world()
    east, west = base.copy(), base.copy()
    for y in range(FEET_Y, FEET_Y + 3):
        put(east, 3, y, -6, Block.BRICKS)
        put(west, -3, y, -6, Block.BRICKS)
    eye = (0.5, EYE_Y, 0.5)
    rgb, _ = renderer.render(np.stack([east, west]), ORIGIN, make_views([eye] * 3, [NORTH] * 3, [0.0] * 3,
                                                                        world_idx=[0, 1, 0]))
    ref, _ = renderer.render(snapshots(base), ORIGIN, make_views([eye], [NORTH], [0.0]))
    for img, side in ((rgb[0], "right"), (rgb[1], "left")):
        changed = np.abs(img.astype(int) - ref[0].astype(int)).sum(-1) > 0
        cols = np.flatnonzero(changed.any(axis=0))
        assert cols.size > 0
        if side == "right":
            assert cols.min() >= SIZE // 2
        else:
            assert cols.max() < SIZE // 2


def test_snapshot_index_selects_the_world(renderer):
    base = flat_world()
    edited = base.copy()
    for y in range(FEET_Y, FEET_Y + 3):
        put(edited, 0, y, -4, Block.BRICKS)
    views = make_views([(0.5, EYE_Y, 0.5)] * 2, [NORTH] * 2, [0.0] * 2, world_idx=[0, 1])
    rgb, _ = renderer.render(np.stack([base, edited]), ORIGIN, views)
    assert not np.array_equal(centre(rgb[0]), centre(rgb[1]))
    ref, _ = renderer.render(snapshots(base), ORIGIN, views)
    np.testing.assert_array_equal(rgb[0], ref[0])


def test_avatar_visible_skins_differ_wall_and_mask_hide_it(renderer):
    base = flat_world()
    walled = base.copy()
    for x in range(-2, 3):
        for y in range(FEET_Y, FEET_Y + 4):
            put(walled, x, y, -2, Block.STONE)
    eye, feet = (0.5, EYE_Y, 0.5), (0.5, FEET_Y, -4.5)  # 5 blocks north, facing the camera (south)
    views = make_views([eye] * 4, [NORTH] * 4, [0.0] * 4, feet=[[feet]] * 4, avatar_yaw=[[SOUTH, 0]] * 4,
                       skins=[[0, 0], [1, 0], [0, 0], [0, 0]], mask=[[True, True]] * 3 + [[False, False]],
                       world_idx=[0, 0, 1, 0])
    rgb, avatar_id = renderer.render(np.stack([base, walled]), ORIGIN, views)
    seen = centre(avatar_id[0]) == 0
    assert seen.sum() > 10, "the avatar covers the centre of the view"
    np.testing.assert_array_equal(avatar_id[0], avatar_id[1])
    alpha_rgb = rgb[0][avatar_id[0] == 0].astype(int).mean(axis=0)
    bravo_rgb = rgb[1][avatar_id[1] == 0].astype(int).mean(axis=0)
    assert alpha_rgb[0] > alpha_rgb[2], "Alpha wears crimson"
    assert bravo_rgb[2] > bravo_rgb[0], "Bravo wears cyan and blue"
    assert (avatar_id[2] == -1).all(), "hidden behind the wall"
    assert (avatar_id[3] == -1).all(), "masked off"
    assert not np.array_equal(rgb[0], rgb[3])


def test_two_avatars_get_their_own_ids(renderer):
    eye = (0.5, EYE_Y, 0.5)
    feet = [(-1.5, FEET_Y, -5.5), (2.5, FEET_Y, -5.5)]  # left and right of the view
    rgb, avatar_id = renderer.render(snapshots(flat_world()), ORIGIN,
                                     make_views([eye], [NORTH], [0.0], feet=[feet], avatar_yaw=[[SOUTH, SOUTH]]))
    cols0 = np.flatnonzero((avatar_id[0] == 0).any(axis=0))
    cols1 = np.flatnonzero((avatar_id[0] == 1).any(axis=0))
    assert cols0.size and cols1.size and cols0.max() < cols1.min()


def test_every_ray_finishes_in_a_covered_hall(renderer):
    """Under a ceiling no column can be skipped, so rays step voxel by voxel for up to ~30 blocks;
    none may be cut short (it would show as sky)."""
    hall = flat_world()
    half = 20
    hall[:, FEET_Y + 4 - ORIGIN[1]] = Block.STONE
    for i in range(-half, half + 1):
        for y in range(FEET_Y, FEET_Y + 4):
            for x, z in ((i, -half), (i, half), (-half, i), (half, i)):
                put(hall, x, y, z, Block.BRICKS)
    views = make_views([(0.5, EYE_Y, 0.5)] * 4, [0.0, 1.6, 3.1, 4.7], [0.0, 0.1, -0.1, 0.0])
    rgb, _ = renderer.render(snapshots(hall), ORIGIN, views)
    blue_excess = rgb[..., 2].astype(int) - rgb[..., 0].astype(int)
    assert blue_excess.max() < 40, "no sky inside the hall"


def test_batched_equals_one_view_at_a_time(renderer):
    vox = snapshots(flat_world())
    eyes = [(0.5, EYE_Y, 0.5), (3.2, EYE_Y + 2, -1.7), (-4.0, EYE_Y, 5.5), (0.5, EYE_Y, 0.5)]
    yaws, pitches = [0.0, 2.0, 4.0, 5.5], [0.0, -0.6, 0.2, -1.2]
    feet = [[(0.5, FEET_Y, -4.5)], [(3.0, FEET_Y, -6.0)], [(-4.0, FEET_Y, 1.5)], [(0.5, FEET_Y, -2.0)]]
    batch = make_views(eyes, yaws, pitches, feet=feet, avatar_yaw=[[1.0, 0.0]] * 4, skins=[[1, 0]] * 4)
    rgb, avatar_id = renderer.render(vox, ORIGIN, batch)
    for b in range(NUM_VIEWS):
        one = make_views([eyes[b]], [yaws[b]], [pitches[b]], feet=[feet[b]], avatar_yaw=[[1.0, 0.0]], skins=[[1, 0]])
        rgb1, avatar_id1 = renderer.render(vox, ORIGIN, one)
        np.testing.assert_array_equal(rgb[b], rgb1[0])
        np.testing.assert_array_equal(avatar_id[b], avatar_id1[0])


def test_fog_pulls_far_blocks_to_the_sky_colour(renderer):
    eye = (0.5, EYE_Y, 10.5)
    near, far = flat_world(), flat_world()
    for x in range(-30, 31):
        for y in range(FEET_Y, FEET_Y + 16):
            put(near, x, y, 4, Block.BRICKS)  # 6 blocks away
            put(far, x, y, -30, Block.BRICKS)  # 40 blocks away, well past the fog start (0.55 * 48)
    views = make_views([eye] * 3, [NORTH, NORTH, SOUTH], [0.0, 0.0, 0.15], world_idx=[0, 1, 1])
    rgb, _ = renderer.render(np.stack([near, far]), ORIGIN, views)
    sky = centre(rgb[2], 0.1).astype(int).mean(axis=(0, 1))  # the sky just above the horizon
    d_near = np.abs(centre(rgb[0], 0.1).astype(int).mean(axis=(0, 1)) - sky).sum()
    d_far = np.abs(centre(rgb[1], 0.1).astype(int).mean(axis=(0, 1)) - sky).sum()
    assert d_far < 0.6 * d_near, (d_far, d_near)


def test_water_is_translucent_and_torch_glows(renderer):
    over_sand, over_dark = flat_world(), flat_world()
    for x in range(-4, 5):
        for z in range(-9, 0):
            put(over_sand, x, GROUND_Y, z, Block.WATER)
            put(over_sand, x, GROUND_Y - 1, z, Block.SAND)
            put(over_dark, x, GROUND_Y, z, Block.WATER)
            put(over_dark, x, GROUND_Y - 1, z, Block.BEDROCK)
    put(over_dark, 0, FEET_Y, 3, Block.TORCH)
    eye = (0.5, EYE_Y, 0.5)
    views = make_views([eye, eye, eye], [NORTH, NORTH, SOUTH], [-0.6, -0.6, -0.45], world_idx=[0, 1, 1])
    rgb, _ = renderer.render(np.stack([over_sand, over_dark]), ORIGIN, views)
    water_sand, water_dark = centre(rgb[0], 0.1).astype(int), centre(rgb[1], 0.1).astype(int)
    assert (water_sand[..., 2] > water_sand[..., 0]).mean() > 0.9, "water tints blue"
    assert water_sand.mean() > water_dark.mean() + 10, "the bottom shows through the water"
    torch_view = rgb[2].astype(int)
    flame = (torch_view[..., 0] > 200) & (torch_view[..., 1] > 150) & (torch_view[..., 2] < 160)
    assert flame.any(), "the torch flame is visible"


def test_hud_highlight_follows_selected_slot(hud_renderer):
    vox = snapshots(flat_world())
    eye = (0.5, EYE_Y, 0.5)
    rgb, _ = hud_renderer.render(vox, ORIGIN, make_views([eye] * 2, [NORTH] * 2, [0.0] * 2, slot=[0, 8]))
    first, last = rgb[0].astype(int), rgb[1].astype(int)
    changed = np.abs(first - last).sum(-1) > 0
    rows, cols = np.nonzero(changed)
    assert rows.size and rows.min() > SIZE * 3 // 4, "only the hotbar changes"
    bottom = slice(SIZE * 3 // 4, SIZE)
    left, right = slice(0, SIZE // 3), slice(SIZE - SIZE // 3, SIZE)
    assert first[bottom, left].mean() > last[bottom, left].mean(), "slot 0 frame on the left"
    assert last[bottom, right].mean() > first[bottom, right].mean(), "slot 8 frame on the right"


def test_square_frames_keep_the_16_9_field_of_view():
    """Square frames show the 16:9 window resampled, not a square crop: with square pixels a 70 deg vertical FOV
    would see only +-35 deg, and the eval's 40 deg turn would push the partner off-screen."""
    import math

    eye, feet = (0.5, EYE_Y, 0.5), (0.5, FEET_Y, -7.5)  # partner 8 blocks north
    yaw = NORTH + math.radians(40)  # turned 40 deg left: the partner is 40 deg to the right
    views = make_views([eye], [yaw], [0.0], feet=[[feet]], avatar_yaw=[[SOUTH, 0]])
    seen = {}
    for aspect in (16 / 9, None):
        cfg = RenderConfig(height=SIZE, width=SIZE, hud=False, display_aspect=aspect)
        _, avatar_id = Renderer(cfg).render(snapshots(flat_world()), ORIGIN, views)
        cols = np.nonzero((avatar_id[0] == 0).any(axis=0))[0]
        seen[aspect] = cols
    assert seen[16 / 9].size > 0 and seen[16 / 9].mean() > SIZE * 2 / 3, "on the right third"
    assert seen[None].size == 0, "square pixels: off-screen"
