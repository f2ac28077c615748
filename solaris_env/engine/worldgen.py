"""Seeded world generators: ``flat`` (superflat, five surface variants) and ``normal`` (terrain).

Both return a :class:`World` whose box is centred on x = z = 0. Layouts follow docs/engine.md §2.3-§2.4:
superflat = bedrock 1, stone, dirt 2, surface 1 with the surface block at y = 63 (feet at y = 64);
the variant is picked by ``instance mod 5`` (plains/grass, windswept_hills/grass, snowy_plains/snow,
desert/sand, desert/red_sand). ``normal`` is value-noise hills with a sea level, sand shores, snowy
tops, oak trees, and stone with coal/iron/diamond ore below.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from solaris_env.engine.blocks import Block
from solaris_env.engine.world import World

FLAT_SURFACE_Y = 63
FLAT_VARIANTS: tuple[tuple[str, Block], ...] = (
    ("plains", Block.GRASS),
    ("windswept_hills", Block.GRASS),
    ("snowy_plains", Block.SNOW),
    ("desert", Block.SAND),
    ("desert_red", Block.RED_SAND),
)
WORLD_KINDS = ("flat", "normal")


@dataclass(frozen=True, slots=True)
class WorldConfig:
    """Size of the generated world box.

    The horizontal size bounds how far episodes can roam (chase runs ~100 blocks in the paper; we
    clamp goals to ``size_xz / 2 - margin``). Height covers bedrock to the highest tree top.
    """

    size_xz: int = 160
    height: int = 64
    floor_y: int = 40  # world y of the array's bottom layer (bedrock)
    sea_level: int = 62
    margin: int = 24  # keep players this far from the box sides so fog hides the edge

    def __post_init__(self):
        if self.size_xz < 2 * self.margin + 16:
            raise ValueError(f"size_xz={self.size_xz} must be >= 2*margin+16 = {2 * self.margin + 16}")
        if not self.floor_y < FLAT_SURFACE_Y < self.floor_y + self.height - 8:
            raise ValueError(f"floor_y={self.floor_y}, height={self.height} must contain y={FLAT_SURFACE_Y} with 8 blocks of headroom")

    @property
    def origin(self) -> tuple[int, int, int]:
        return (-self.size_xz // 2, self.floor_y, -self.size_xz // 2)

    @property
    def playable_half_extent(self) -> float:
        return self.size_xz / 2 - self.margin


def generate(kind: str, seed: int, variant: int = 0, cfg: WorldConfig = WorldConfig()) -> World:
    """Generate a world. ``variant`` selects the superflat surface (``variant mod 5``); unused for normal."""
    if kind == "flat":
        return flat_world(seed, variant, cfg)
    if kind == "normal":
        return normal_world(seed, cfg)
    raise ValueError(f"world kind must be one of {WORLD_KINDS}, got {kind!r}")


def flat_world(seed: int, variant: int, cfg: WorldConfig = WorldConfig()) -> World:
    name, surface = FLAT_VARIANTS[variant % len(FLAT_VARIANTS)]
    blocks = np.zeros((cfg.size_xz, cfg.height, cfg.size_xz), np.uint8)
    top = FLAT_SURFACE_Y - cfg.floor_y
    blocks[:, 0] = Block.BEDROCK
    blocks[:, 1 : top - 2] = Block.STONE
    blocks[:, top - 2 : top] = Block.DIRT
    blocks[:, top] = surface
    return World(blocks, cfg.origin, "flat", name, seed)


def _value_noise(rng: np.random.Generator, size: int, cell: int) -> np.ndarray:
    """Smooth 2D noise in [0, 1): random values on a ``cell``-spaced grid, smoothstep-interpolated."""
    n = size // cell + 2
    grid = rng.random((n, n))
    t = (np.arange(size) / cell)
    i = t.astype(int)
    f = t - i
    f = f * f * (3 - 2 * f)
    a = grid[i][:, i] * (1 - f)[None, :] + grid[i][:, i + 1] * f[None, :]
    b = grid[i + 1][:, i] * (1 - f)[None, :] + grid[i + 1][:, i + 1] * f[None, :]
    return a * (1 - f)[:, None] + b * f[:, None]


def _heightmap(rng: np.random.Generator, cfg: WorldConfig) -> np.ndarray:
    n = cfg.size_xz
    h = 0.55 * _value_noise(rng, n, 48) + 0.3 * _value_noise(rng, n, 20) + 0.15 * _value_noise(rng, n, 8)
    # Map to heights around sea level: valleys dip under the sea, hills rise ~16 blocks.
    return np.round(cfg.sea_level - 5 + h * 22).astype(np.int32)  # (X, Z) world y of the top solid block


def _place_tree(blocks: np.ndarray, i: int, j: int, k: int, height: int) -> None:
    """An oak: ``height`` logs from array y index j, a leaf blob around the top."""
    X, Y, Z = blocks.shape
    top = j + height
    for dy in range(-2, 2):
        r = 2 if dy < 0 else 1
        y = top + dy
        if not 0 <= y < Y:
            continue
        for dx in range(-r, r + 1):
            for dz in range(-r, r + 1):
                if abs(dx) == r and abs(dz) == r and (dy >= 0 or (dx + dz + y) % 2):
                    continue  # round the corners
                x, z = i + dx, k + dz
                if 0 <= x < X and 0 <= z < Z and blocks[x, y, z] == Block.AIR:
                    blocks[x, y, z] = Block.LEAVES
    blocks[i, j : min(top, Y), k] = Block.OAK_LOG


def normal_world(seed: int, cfg: WorldConfig = WorldConfig()) -> World:
    rng = np.random.default_rng([seed, 0x5017])
    n, H, oy = cfg.size_xz, cfg.height, cfg.floor_y
    top_XZ = np.clip(_heightmap(rng, cfg), oy + 6, oy + H - 12)
    y_Y = oy + np.arange(H)  # world y of each array layer
    below = y_Y[None, :, None] <= top_XZ[:, None, :]  # (X, Y, Z) solid ground
    depth = top_XZ[:, None, :] - y_Y[None, :, None]  # 0 at the surface block

    blocks = np.zeros((n, H, n), np.uint8)
    blocks[below] = Block.STONE
    blocks[below & (depth < 3)] = Block.DIRT
    shore = top_XZ <= cfg.sea_level + 1
    snowy = top_XZ >= cfg.sea_level + 14
    surface_block = np.where(shore, Block.SAND, np.where(snowy, Block.SNOW, Block.GRASS)).astype(np.uint8)
    surf = depth == 0
    blocks[surf] = np.broadcast_to(surface_block[:, None, :], blocks.shape)[surf]
    blocks[below & (depth > 0) & (depth < 3) & shore[:, None, :]] = Block.SAND
    # Water fills the air under sea level.
    water = (~below) & (y_Y[None, :, None] <= cfg.sea_level)
    blocks[water] = Block.WATER

    # Ores and gravel in the stone, rarer and deeper for the valuable ones.
    u = rng.random(blocks.shape)
    stone = blocks == Block.STONE
    blocks[stone & (u < 0.012)] = Block.COAL_ORE
    blocks[stone & (u >= 0.012) & (u < 0.018) & (y_Y[None, :, None] < 60)] = Block.IRON_ORE
    blocks[stone & (u >= 0.018) & (u < 0.0205) & (y_Y[None, :, None] < 52)] = Block.DIAMOND_ORE
    blocks[stone & (u >= 0.03) & (u < 0.036)] = Block.GRAVEL
    blocks[:, 0] = Block.BEDROCK

    # Trees on grass, not too close to each other or the box sides.
    tree_p = 0.012 * (_value_noise(rng, n, 32) > 0.45)
    cand = np.argwhere((surface_block == Block.GRASS) & (rng.random((n, n)) < tree_p))
    for i, k in cand:
        if 3 <= i < n - 3 and 3 <= k < n - 3:
            j = int(top_XZ[i, k] - oy + 1)
            if j + 7 < H and not (blocks[i - 1 : i + 2, j, k - 1 : k + 2] != Block.AIR).any():
                _place_tree(blocks, int(i), j, int(k), int(rng.integers(4, 7)))
    return World(blocks, cfg.origin, "normal", "normal", seed)
