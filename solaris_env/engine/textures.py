"""Procedural, deterministic textures of the voxel renderer: blocks, player skins and hotbar icons.

Nothing is loaded from disk: every texture is drawn from a numpy generator seeded by the texture's
name, so the atlas is byte-identical across runs and machines and independent of drawing order.

Texture-space convention (shared with ``render.py``): a face texture is ``[row, col]`` with row 0 at
the top of the face as a viewer sees it and col 0 at the viewer's left. Top and bottom faces use
``row = z``, ``col = x`` (row 0 on the north / model-front edge).

Outputs:
    block_atlas()  -> (NUM_BLOCKS, NUM_BLOCK_FACES, TEX, TEX, 3) uint8, faces (top, side, bottom).
    skin_atlas()   -> (NUM_SKINS, NUM_PARTS, NUM_BOX_FACES, TEX, TEX, 3) uint8.
    icon_atlas()   -> (NUM_ICONS, TEX, TEX, 4) uint8 RGBA, with ``icon_of_item()`` mapping item ids to rows.
"""

from __future__ import annotations

import zlib
from typing import Callable

import numpy as np

from solaris_env.engine.blocks import NUM_BLOCKS, Block, Item

TEX = 16  # texels per block edge (Minecraft's resolution)
SEED = 20_251_122  # base seed of every texture generator; a texture's own seed adds crc32(name)

# Block face variants, in atlas order.
FACE_TOP, FACE_SIDE, FACE_BOTTOM = 0, 1, 2
NUM_BLOCK_FACES = 3

# Torch geometry in texels (Minecraft: a 2x10 texel stick centred in the block, flame on top).
TORCH_COL0 = 7  # first stick column
TORCH_WIDTH = 2
TORCH_TOP_ROW = 6  # the stick spans rows TORCH_TOP_ROW .. TEX-1, i.e. 10/16 of a block tall
TORCH_FLAME_ROWS = 2  # the top rows of the stick are the (emissive) flame

# ----------------------------------------------------------------------------------------------
# Helpers
# ----------------------------------------------------------------------------------------------

RGB = tuple[int, int, int]


def _rng(name: str) -> np.random.Generator:
    """Generator seeded by the texture's name only, so textures do not depend on drawing order."""
    return np.random.default_rng([SEED, zlib.crc32(name.encode())])


def _noisy(rng: np.random.Generator, rgb: RGB, amp: float, size: int = TEX) -> np.ndarray:
    """(size, size, 3) float texture of one colour with per-texel brightness noise of relative ``amp``."""
    gain_HW1 = 1.0 + amp * rng.standard_normal((size, size, 1))
    return np.asarray(rgb, np.float64)[None, None, :] * gain_HW1


def _specks(tex_HW3: np.ndarray, rng: np.random.Generator, rgb: RGB, frac: float, blob: bool = False) -> np.ndarray:
    """Paint a fraction ``frac`` of texels (optionally grown into 2-texel blobs) with ``rgb`` +- noise."""
    out = tex_HW3.copy()
    mask_HW = rng.random(tex_HW3.shape[:2]) < frac
    if blob:
        mask_HW |= np.roll(mask_HW, 1, axis=1) & (rng.random(mask_HW.shape) < 0.7)
        mask_HW |= np.roll(mask_HW, 1, axis=0) & (rng.random(mask_HW.shape) < 0.5)
    speck_HW3 = _noisy(rng, rgb, 0.08, tex_HW3.shape[0])
    out[mask_HW] = speck_HW3[mask_HW]
    return out


def _u8(tex: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(tex), 0, 255).astype(np.uint8)


def _same(tex_HW3: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return tex_HW3, tex_HW3, tex_HW3


# ----------------------------------------------------------------------------------------------
# Block textures: each returns (top, side, bottom) float (TEX, TEX, 3) arrays in [0, 255]
# ----------------------------------------------------------------------------------------------

GRASS_GREEN: RGB = (98, 160, 56)
DIRT_BROWN: RGB = (134, 96, 67)
STONE_GREY: RGB = (126, 126, 126)


def _dirt(name: str = "dirt") -> np.ndarray:
    rng = _rng(name)
    tex = _noisy(rng, DIRT_BROWN, 0.10)
    tex = _specks(tex, rng, (104, 74, 52), 0.12)
    return _specks(tex, rng, (160, 118, 84), 0.06)


def _stone(name: str = "stone") -> np.ndarray:
    rng = _rng(name)
    tex = _noisy(rng, STONE_GREY, 0.06)
    tex = _specks(tex, rng, (108, 108, 108), 0.18, blob=True)
    return _specks(tex, rng, (142, 142, 142), 0.08)


def _grass() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = _rng("grass")
    top = _noisy(rng, GRASS_GREEN, 0.11)
    top = _specks(top, rng, (78, 132, 42), 0.15)
    side = _dirt("grass_side")
    # A green fringe of 2..5 texels hanging irregularly from the top edge.
    fringe_W = rng.integers(2, 6, size=TEX)
    rows_H1 = np.arange(TEX)[:, None]
    fringe_HW = rows_H1 < fringe_W[None, :]
    side[fringe_HW] = top[fringe_HW]
    return top, side, _dirt("grass_bottom")


def _cobblestone() -> np.ndarray:
    rng = _rng("cobblestone")
    # Voronoi stones on a torus: each texel takes its nearest seed; edges between cells are mortar.
    seeds_N2 = rng.random((11, 2)) * TEX
    yy, xx = np.mgrid[0:TEX, 0:TEX] + 0.5
    d_HWN = np.full((TEX, TEX, len(seeds_N2)), np.inf)
    for oy in (-TEX, 0, TEX):
        for ox in (-TEX, 0, TEX):
            dy = yy[..., None] - (seeds_N2[None, None, :, 0] + oy)
            dx = xx[..., None] - (seeds_N2[None, None, :, 1] + ox)
            d_HWN = np.minimum(d_HWN, np.hypot(dy, dx))
    d_sorted = np.sort(d_HWN, axis=-1)
    edge_HW = (d_sorted[..., 1] - d_sorted[..., 0]) < 1.0
    cell_HW = np.argmin(d_HWN, axis=-1)
    cell_gain_N = 0.85 + 0.3 * rng.random(len(seeds_N2))
    tex = _noisy(rng, (128, 128, 128), 0.05) * cell_gain_N[cell_HW][..., None]
    tex[edge_HW] = _noisy(rng, (72, 72, 72), 0.06)[edge_HW]
    return tex


def _planks() -> np.ndarray:
    rng = _rng("oak_planks")
    tex = _noisy(rng, (162, 130, 78), 0.05)
    # Grain: faint horizontal streaks.
    tex *= (1.0 + 0.06 * rng.standard_normal((TEX, 1, 1)))
    board_h = 4
    for r in range(board_h - 1, TEX, board_h):
        tex[r] = _noisy(rng, (104, 82, 48), 0.05)[r]
        seam_col = int(rng.integers(0, TEX))
        tex[r - board_h + 1:r, seam_col] = (118, 94, 56)
    return tex


def _log() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = _rng("oak_log")
    side = _noisy(rng, (104, 82, 50), 0.06)
    # Bark: dark vertical furrows of random length.
    for c in range(TEX):
        if rng.random() < 0.45:
            r0 = int(rng.integers(0, TEX))
            length = int(rng.integers(4, 12))
            rows = np.arange(r0, r0 + length) % TEX
            side[rows, c] = _noisy(rng, (74, 57, 33), 0.05)[rows, c]
    # Top: concentric rings inside a bark rim.
    yy, xx = np.mgrid[0:TEX, 0:TEX] + 0.5 - TEX / 2
    ring_HW = np.maximum(np.abs(yy), np.abs(xx))
    top = _noisy(rng, (178, 146, 92), 0.04)
    top[(np.floor(ring_HW) % 3) == 1] *= 0.82
    top[ring_HW > TEX / 2 - 1] = side[ring_HW > TEX / 2 - 1]
    return top, side, top


def _leaves() -> np.ndarray:
    rng = _rng("leaves")
    tex = _noisy(rng, (58, 104, 30), 0.12)
    tex = _specks(tex, rng, (34, 66, 18), 0.25, blob=True)  # dark holes of "fast" graphics
    return _specks(tex, rng, (84, 136, 46), 0.10)


def _water() -> np.ndarray:
    rng = _rng("water")
    rows_H1 = np.arange(TEX)[:, None]
    cols_1W = np.arange(TEX)[None, :]
    wave_HW = 0.5 + 0.5 * np.sin(2 * np.pi * (cols_1W / TEX + 2 * rows_H1 / TEX))
    tex = _noisy(rng, (52, 86, 214), 0.04) * (0.9 + 0.2 * wave_HW[..., None])
    return tex


def _bricks() -> np.ndarray:
    rng = _rng("bricks")
    tex = _noisy(rng, (150, 76, 58), 0.07)
    mortar = _noisy(rng, (168, 158, 150), 0.04)
    course_h, brick_w = 4, 8
    for r in range(TEX):
        if r % course_h == course_h - 1:
            tex[r] = mortar[r]
        else:
            offset = (r // course_h) % 2 * (brick_w // 2)
            tex[r, (offset + brick_w - 1) % TEX] = mortar[r, (offset + brick_w - 1) % TEX]
            tex[r, (offset + 2 * brick_w - 1) % TEX] = mortar[r, (offset + 2 * brick_w - 1) % TEX]
    # Each course a slightly different shade.
    return tex * (0.92 + 0.16 * rng.random((TEX // course_h, 1, 1))).repeat(course_h, axis=0)


def _bedrock() -> np.ndarray:
    rng = _rng("bedrock")
    tex = _noisy(rng, (84, 84, 84), 0.10)
    tex = _specks(tex, rng, (34, 34, 34), 0.30, blob=True)
    return _specks(tex, rng, (150, 150, 150), 0.12, blob=True)


def _plain(name: str, rgb: RGB, amp: float, speck_rgb: RGB | None = None, frac: float = 0.0) -> np.ndarray:
    rng = _rng(name)
    tex = _noisy(rng, rgb, amp)
    if speck_rgb is not None:
        tex = _specks(tex, rng, speck_rgb, frac)
    return tex


def _ore(name: str, speck_rgb: RGB, dark_rgb: RGB) -> np.ndarray:
    rng = _rng(name)
    tex = _stone(name + "_stone")
    # 4 clusters of 3-5 coloured texels with a darker rim texel.
    for _ in range(4):
        r, c = (int(v) for v in rng.integers(1, TEX - 2, size=2))
        cells = [(r, c), (r, c + 1), (r + 1, c), (r + 1, c + 1), (r - 1, c)][: int(rng.integers(3, 6))]
        for rr, cc in cells:
            tex[rr, cc] = _noisy(rng, speck_rgb, 0.08, 1)[0, 0]
        tex[r + 1, c - 1] = dark_rgb
    return tex


def _gravel() -> np.ndarray:
    rng = _rng("gravel")
    tex = _noisy(rng, (132, 126, 124), 0.08)
    tex = _specks(tex, rng, (96, 88, 86), 0.22, blob=True)
    tex = _specks(tex, rng, (168, 160, 156), 0.14, blob=True)
    return _specks(tex, rng, (118, 100, 92), 0.08)


def _sandstone() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    tex = _plain("smooth_sandstone", (216, 204, 158), 0.02)
    return _same(tex)


def _torch() -> np.ndarray:
    """Only the stick/flame texels matter (the renderer draws a 2x10 texel stick); the rest is black."""
    rng = _rng("torch")
    tex = np.zeros((TEX, TEX, 3))
    c0, c1 = TORCH_COL0, TORCH_COL0 + TORCH_WIDTH
    tex[TORCH_TOP_ROW:, c0:c1] = _noisy(rng, (118, 88, 48), 0.08)[TORCH_TOP_ROW:, c0:c1]
    tex[TORCH_TOP_ROW:, c0] *= 0.8  # left half of the stick in shadow
    flame = slice(TORCH_TOP_ROW, TORCH_TOP_ROW + TORCH_FLAME_ROWS)
    tex[flame, c0:c1] = (255, 214, 92)
    tex[TORCH_TOP_ROW, c0:c1] = (255, 250, 200)  # white-hot tip
    return tex


_BLOCK_BUILDERS: dict[Block, Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]]] = {
    Block.AIR: lambda: _same(np.zeros((TEX, TEX, 3))),
    Block.GRASS: _grass,
    Block.DIRT: lambda: _same(_dirt()),
    Block.STONE: lambda: _same(_stone()),
    Block.COBBLESTONE: lambda: _same(_cobblestone()),
    Block.OAK_PLANKS: lambda: _same(_planks()),
    Block.OAK_LOG: _log,
    Block.LEAVES: lambda: _same(_leaves()),
    Block.SAND: lambda: _same(_plain("sand", (219, 207, 163), 0.04, (196, 180, 134), 0.12)),
    Block.WATER: lambda: _same(_water()),
    Block.BRICKS: lambda: _same(_bricks()),
    Block.BEDROCK: lambda: _same(_bedrock()),
    Block.SNOW: lambda: _same(_plain("snow", (242, 250, 250), 0.02, (222, 232, 238), 0.10)),
    Block.COAL_ORE: lambda: _same(_ore("coal_ore", (38, 38, 38), (60, 60, 60))),
    Block.IRON_ORE: lambda: _same(_ore("iron_ore", (216, 176, 146), (150, 110, 86))),
    Block.DIAMOND_ORE: lambda: _same(_ore("diamond_ore", (98, 236, 228), (40, 150, 140))),
    Block.TORCH: lambda: _same(_torch()),
    Block.RED_SAND: lambda: _same(_plain("red_sand", (190, 102, 34), 0.05, (160, 84, 26), 0.12)),
    Block.SMOOTH_SANDSTONE: _sandstone,
    Block.GRAVEL: lambda: _same(_gravel()),
}
assert set(_BLOCK_BUILDERS) == set(Block), "every Block needs a texture builder"


def block_atlas() -> np.ndarray:
    """All block textures.

    Returns:
        (NUM_BLOCKS, NUM_BLOCK_FACES, TEX, TEX, 3) uint8, faces ordered (top, side, bottom).
    """
    atlas = np.zeros((NUM_BLOCKS, NUM_BLOCK_FACES, TEX, TEX, 3), np.uint8)
    for block, build in _BLOCK_BUILDERS.items():
        for face, tex in enumerate(build()):
            atlas[block, face] = _u8(tex)
    return atlas


def torch_texel_mask() -> np.ndarray:
    """(TEX, TEX) bool: the torch texels that are drawn (the stick and its flame)."""
    mask_HW = np.zeros((TEX, TEX), bool)
    mask_HW[TORCH_TOP_ROW:, TORCH_COL0:TORCH_COL0 + TORCH_WIDTH] = True
    return mask_HW


# ----------------------------------------------------------------------------------------------
# Player skins
# ----------------------------------------------------------------------------------------------

# Parts of the Minecraft player model and their sizes in model pixels (x width, y height, z depth).
PART_HEAD, PART_BODY, PART_RIGHT_ARM, PART_LEFT_ARM, PART_RIGHT_LEG, PART_LEFT_LEG = range(6)
NUM_PARTS = 6
PART_SIZE_PX: tuple[tuple[int, int, int], ...] = (
    (8, 8, 8), (8, 12, 4), (4, 12, 4), (4, 12, 4), (4, 12, 4), (4, 12, 4),
)
# Box faces, in the part's own frame; the model faces -Z.
FACE_NEG_X, FACE_POS_X, FACE_NEG_Y, FACE_POS_Y, FACE_FRONT, FACE_BACK = range(6)
NUM_BOX_FACES = 6

SKIN_ALPHA, SKIN_BRAVO = 0, 1
NUM_SKINS = 2


def _face_size(part: int, face: int) -> tuple[int, int]:
    """(rows, cols) of a box face in model pixels."""
    w, h, d = PART_SIZE_PX[part]
    if face in (FACE_NEG_X, FACE_POS_X):
        return h, d
    if face in (FACE_NEG_Y, FACE_POS_Y):
        return d, w
    return h, w


# Palettes: (skin, skin_shadow, hair, eye, mouth, shirt, shirt_trim, trousers, shoes, crown).
_PALETTES: dict[int, dict[str, RGB]] = {
    # Alpha: pink skin and snout, golden crown, crimson shirt, dark trousers (a Technoblade-like look).
    SKIN_ALPHA: dict(skin=(238, 160, 168), skin_dark=(214, 128, 140), hair=(238, 160, 168), eye=(30, 20, 24),
                     mouth=(196, 96, 112), shirt=(156, 18, 36), trim=(104, 8, 20), trousers=(38, 36, 52),
                     shoes=(20, 20, 24), crown=(236, 196, 46)),
    # Bravo: tanned skin, brown hair, cyan shirt, blue trousers, grey shoes.
    SKIN_BRAVO: dict(skin=(196, 138, 98), skin_dark=(168, 112, 76), hair=(78, 50, 26), eye=(56, 84, 170),
                     mouth=(128, 72, 52), shirt=(0, 172, 190), trim=(0, 120, 140), trousers=(44, 60, 150),
                     shoes=(92, 92, 96), crown=(78, 50, 26)),
}


def _head_face(skin: int, face: int, rng: np.random.Generator) -> np.ndarray:
    pal = _PALETTES[skin]
    rows, cols = _face_size(PART_HEAD, face)
    tex = _noisy(rng, pal["skin"], 0.03, max(rows, cols))[:rows, :cols]
    if face == FACE_POS_Y:
        tex[:] = pal["hair"]
        if skin == SKIN_ALPHA:  # crown ring seen from above
            tex[0, :] = tex[-1, :] = tex[:, 0] = tex[:, -1] = pal["crown"]
        return tex
    if face == FACE_NEG_Y:
        return tex
    hair_rows = {FACE_FRONT: 2, FACE_BACK: rows - 1}.get(face, 3)  # the back of the head is mostly hair
    tex[:hair_rows] = pal["hair"]
    if skin == SKIN_ALPHA:
        tex[0] = pal["crown"]
        tex[1, ::2] = pal["crown"]  # crown points
    if face == FACE_FRONT:
        tex[4, 1] = tex[4, 6] = (250, 250, 250)  # eye whites
        tex[4, 2] = tex[4, 5] = pal["eye"]
        if skin == SKIN_ALPHA:
            tex[5:7, 2:6] = pal["skin_dark"]  # snout
            tex[6, 3] = tex[6, 4] = pal["mouth"]  # nostrils
        else:
            tex[6, 3:5] = pal["mouth"]
            tex[5, 3:5] = pal["skin_dark"]  # nose shadow
    return tex


def _body_face(skin: int, face: int, rng: np.random.Generator) -> np.ndarray:
    pal = _PALETTES[skin]
    rows, cols = _face_size(PART_BODY, face)
    tex = _noisy(rng, pal["shirt"], 0.05, max(rows, cols))[:rows, :cols]
    if face == FACE_FRONT:
        tex[0, 2:6] = pal["trim"]  # collar
        tex[1, 3:5] = pal["skin"]
        tex[rows - 1] = pal["trim"]  # belt line
        if skin == SKIN_ALPHA:
            tex[3:9, 3:5] = pal["trim"]  # buttoned front
    elif face not in (FACE_NEG_Y, FACE_POS_Y):
        tex[rows - 1] = pal["trim"]
    return tex


def _arm_face(skin: int, face: int, rng: np.random.Generator) -> np.ndarray:
    pal = _PALETTES[skin]
    rows, cols = _face_size(PART_RIGHT_ARM, face)
    tex = _noisy(rng, pal["skin"], 0.03, max(rows, cols))[:rows, :cols]
    sleeve_rows = 9 if skin == SKIN_ALPHA else 4  # Alpha long sleeves, Bravo a T-shirt
    if face == FACE_POS_Y:
        tex[:] = pal["shirt"]
    elif face != FACE_NEG_Y:
        tex[:sleeve_rows] = _noisy(rng, pal["shirt"], 0.05, 12)[:sleeve_rows, :cols]
        tex[sleeve_rows - 1] = pal["trim"]
    return tex


def _leg_face(skin: int, face: int, rng: np.random.Generator) -> np.ndarray:
    pal = _PALETTES[skin]
    rows, cols = _face_size(PART_RIGHT_LEG, face)
    tex = _noisy(rng, pal["trousers"], 0.06, max(rows, cols))[:rows, :cols]
    shoe_rows = 3
    if face == FACE_NEG_Y:
        tex[:] = pal["shoes"]
    elif face != FACE_POS_Y:
        tex[rows - shoe_rows:] = pal["shoes"]
    return tex


_PART_BUILDERS = (_head_face, _body_face, _arm_face, _arm_face, _leg_face, _leg_face)


def _upsample(tex_hw3: np.ndarray) -> np.ndarray:
    """Nearest-neighbour resample of a native-size face to (TEX, TEX, 3)."""
    rows, cols = tex_hw3.shape[:2]
    r_idx = (np.arange(TEX) * rows) // TEX
    c_idx = (np.arange(TEX) * cols) // TEX
    return tex_hw3[r_idx][:, c_idx]


def skin_atlas() -> np.ndarray:
    """Per-part, per-face skin textures, each face resampled from its native pixel size to TEX x TEX.

    Returns:
        (NUM_SKINS, NUM_PARTS, NUM_BOX_FACES, TEX, TEX, 3) uint8.
    """
    atlas = np.zeros((NUM_SKINS, NUM_PARTS, NUM_BOX_FACES, TEX, TEX, 3), np.uint8)
    for skin in range(NUM_SKINS):
        for part, build in enumerate(_PART_BUILDERS):
            for face in range(NUM_BOX_FACES):
                rng = _rng(f"skin{skin}_part{part}_face{face}")
                atlas[skin, part, face] = _u8(_upsample(build(skin, face, rng)))
    return atlas


# ----------------------------------------------------------------------------------------------
# Hotbar icons
# ----------------------------------------------------------------------------------------------

HANDLE_BROWN: RGB = (110, 80, 40)
# Tool-head colours by material.
_MATERIAL_RGB: dict[str, RGB] = {
    "wooden": (168, 132, 76), "stone": (128, 128, 128), "iron": (220, 220, 220),
    "golden": (250, 214, 60), "diamond": (74, 226, 214), "netherite": (74, 64, 72),
}
_ITEM_SHAPES: dict[Item, tuple[str, str]] = {
    Item.DIAMOND_PICKAXE: ("pickaxe", "diamond"),
    Item.DIAMOND_SHOVEL: ("shovel", "diamond"),
    Item.DIAMOND_AXE: ("axe", "diamond"),
    Item.WOODEN_SWORD: ("sword", "wooden"),
    Item.STONE_SWORD: ("sword", "stone"),
    Item.IRON_SWORD: ("sword", "iron"),
    Item.GOLDEN_SWORD: ("sword", "golden"),
    Item.DIAMOND_SWORD: ("sword", "diamond"),
    Item.NETHERITE_SWORD: ("sword", "netherite"),
}
assert set(_ITEM_SHAPES) == set(Item) - {Item.EMPTY}, "every tool Item needs an icon shape"


def _paint_diagonal(icon: np.ndarray, r0: int, c0: int, length: int, rgb: RGB, width: int = 1) -> None:
    """Paint an up-right diagonal (row decreasing, col increasing) starting at (r0, c0)."""
    for i in range(length):
        for w in range(width):
            r, c = r0 - i, c0 + i + w
            if 0 <= r < TEX and 0 <= c < TEX:
                icon[r, c] = (*rgb, 255)


def _tool_icon(shape: str, material: str) -> np.ndarray:
    """(TEX, TEX, 4) RGBA pixel art of a tool pointing up-right, handle at the bottom left."""
    icon = np.zeros((TEX, TEX, 4), np.uint8)
    head = _MATERIAL_RGB[material]
    dark = tuple(int(v * 0.6) for v in head)
    if shape == "sword":
        _paint_diagonal(icon, 14, 1, 4, HANDLE_BROWN, 2)
        _paint_diagonal(icon, 13, 1, 1, dark)  # pommel
        for r, c in ((12, 3), (13, 4), (11, 2), (14, 5)):  # crossguard
            icon[r, c] = (*dark, 255)
        _paint_diagonal(icon, 11, 5, 10, head, 2)
        _paint_diagonal(icon, 12, 5, 10, dark)  # blade edge
        return icon
    _paint_diagonal(icon, 14, 1, 11, HANDLE_BROWN, 2)
    if shape == "pickaxe":
        rows_H1, cols_1W = np.mgrid[0:TEX, 0:TEX]
        rr, cc = rows_H1 - 15.0, cols_1W - 0.0
        radius = np.hypot(rr, cc)
        arc = (radius > 11.5) & (radius < 14.0) & (rows_H1 < 11) & (cols_1W > 4)
        icon[arc] = (*head, 255)
        icon[arc & (radius > 13.0)] = (*dark, 255)
    elif shape == "shovel":
        rows_H1, cols_1W = np.mgrid[0:TEX, 0:TEX]
        blade = (np.abs(rows_H1 - 3.5) + np.abs(cols_1W - 11.5)) < 4.0
        icon[blade] = (*head, 255)
        icon[blade & ((rows_H1 + cols_1W) < 13)] = (*dark, 255)
    elif shape == "axe":
        icon[1:7, 6:11] = (*head, 255)
        icon[1:7, 6] = (*dark, 255)
        icon[1, 6:11] = (*dark, 255)
        _paint_diagonal(icon, 9, 6, 6, HANDLE_BROWN, 2)
    return icon


MAX_ITEM_ID = max(int(i) for i in Item)
NUM_ICONS = NUM_BLOCKS + len(_ITEM_SHAPES)  # row 0 (air) is the empty icon


def icon_of_item() -> np.ndarray:
    """(MAX_ITEM_ID + 1,) int32: the icon row of each hotbar item id (0 = empty, blocks, then tools)."""
    table = np.zeros(MAX_ITEM_ID + 1, np.int32)
    table[:NUM_BLOCKS] = np.arange(NUM_BLOCKS)
    for i, item in enumerate(_ITEM_SHAPES):
        table[int(item)] = NUM_BLOCKS + i
    return table


def icon_atlas() -> np.ndarray:
    """Hotbar icons: blocks show their side texture, tools and swords a pixel-art shape.

    Returns:
        (NUM_ICONS, TEX, TEX, 4) uint8 RGBA; row 0 (empty slot) is fully transparent.
    """
    blocks = block_atlas()
    icons = np.zeros((NUM_ICONS, TEX, TEX, 4), np.uint8)
    icons[1:NUM_BLOCKS, :, :, :3] = blocks[1:, FACE_SIDE]
    icons[1:NUM_BLOCKS, :, :, 3] = 255
    icons[Block.TORCH, :, :, 3] = np.where(torch_texel_mask(), 255, 0)
    for i, (shape, material) in enumerate(_ITEM_SHAPES.values()):
        icons[NUM_BLOCKS + i] = _tool_icon(shape, material)
    return icons
