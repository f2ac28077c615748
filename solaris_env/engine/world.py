"""The voxel world: a dense ``uint8`` block array with a world-coordinate origin.

Coordinates follow Minecraft: +Y up, -Z north, +X east; block (x, y, z) spans [x, x+1) x [y, y+1) x
[z, z+1). The array covers a finite box; outside it is air above ``origin[1]`` and bedrock below,
so nothing falls out of the world.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solaris_env.engine.blocks import SOLID, Block


@dataclass
class World:
    """A finite voxel world.

    Attributes:
        blocks_XYZ: (X, Y, Z) uint8 block ids, indexed ``[x - ox, y - oy, z - oz]``.
        origin: world coordinates (ox, oy, oz) of array index (0, 0, 0).
        kind: ``"flat"`` or ``"normal"``.
        variant: surface/biome variant name (e.g. ``"plains"``), for episode_info.
        seed: the generator seed.
        version: bumped on every edit; renderers re-upload the array when it changes.
    """

    blocks_XYZ: np.ndarray
    origin: tuple[int, int, int]
    kind: str
    variant: str
    seed: int
    version: int = 0
    spawn_center: tuple[float, float] = (0.0, 0.0)
    edits: list[tuple[int, int, int, int, int]] = field(default_factory=list)  # (x, y, z, old, new)

    def __post_init__(self):
        if self.blocks_XYZ.dtype != np.uint8 or self.blocks_XYZ.ndim != 3:
            raise ValueError(f"blocks_XYZ must be a 3-D uint8 array, got {self.blocks_XYZ.dtype} {self.blocks_XYZ.shape}")
        self.solid_XYZ = SOLID[self.blocks_XYZ]  # (X, Y, Z) bool, kept in sync by set()

    def any_solid(self, lo: tuple[int, int, int], hi: tuple[int, int, int]) -> bool:
        """Whether any block in the inclusive integer box [lo, hi] collides (box sides and below count as solid)."""
        ox, oy, oz = self.origin
        X, Y, Z = self.blocks_XYZ.shape
        i0, j0, k0 = lo[0] - ox, lo[1] - oy, lo[2] - oz
        i1, j1, k1 = hi[0] - ox, hi[1] - oy, hi[2] - oz
        if i0 < 0 or k0 < 0 or i1 >= X or k1 >= Z or j0 < 0:
            return True
        if j0 >= Y:
            return False
        return bool(self.solid_XYZ[i0 : i1 + 1, j0 : min(j1, Y - 1) + 1, k0 : k1 + 1].any())

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.blocks_XYZ.shape)  # type: ignore[return-value]

    def in_bounds(self, x: int, y: int, z: int) -> bool:
        ox, oy, oz = self.origin
        X, Y, Z = self.blocks_XYZ.shape
        return 0 <= x - ox < X and 0 <= y - oy < Y and 0 <= z - oz < Z

    def get(self, x: int, y: int, z: int) -> int:
        """Block id at integer world coordinates (bedrock below the array, air elsewhere outside)."""
        ox, oy, oz = self.origin
        X, Y, Z = self.blocks_XYZ.shape
        i, j, k = x - ox, y - oy, z - oz
        if j < 0:
            return int(Block.BEDROCK)
        if 0 <= i < X and j < Y and 0 <= k < Z:
            return int(self.blocks_XYZ[i, j, k])
        if not (0 <= i < X and 0 <= k < Z):
            return int(Block.BEDROCK)  # the world's side walls are invisible bedrock for physics
        return int(Block.AIR)

    def is_solid(self, x: int, y: int, z: int) -> bool:
        return bool(SOLID[self.get(x, y, z)])

    def set(self, x: int, y: int, z: int, block: int) -> None:
        """Set a block; raises ValueError outside the world box."""
        if not self.in_bounds(x, y, z):
            raise ValueError(f"block position {(x, y, z)} is outside the world box origin={self.origin} shape={self.shape}")
        ox, oy, oz = self.origin
        old = int(self.blocks_XYZ[x - ox, y - oy, z - oz])
        self.blocks_XYZ[x - ox, y - oy, z - oz] = block
        self.solid_XYZ[x - ox, y - oy, z - oz] = SOLID[block]
        self.version += 1
        self.edits.append((x, y, z, old, int(block)))

    def surface_y(self, x: int, z: int) -> int:
        """The y of the first non-solid block above the highest solid block in column (x, z) (feet level)."""
        ox, oy, oz = self.origin
        i, k = x - ox, z - oz
        X, Y, Z = self.blocks_XYZ.shape
        if not (0 <= i < X and 0 <= k < Z):
            raise ValueError(f"column {(x, z)} is outside the world box")
        solid = SOLID[self.blocks_XYZ[i, :, k]]
        idx = np.nonzero(solid)[0]
        return oy + (int(idx[-1]) + 1 if idx.size else 0)

    def copy(self) -> "World":
        return World(self.blocks_XYZ.copy(), self.origin, self.kind, self.variant, self.seed, self.version,
                     self.spawn_center, list(self.edits))
