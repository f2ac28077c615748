"""Block and item registry of the voxel engine.

Block ids are small integers stored in the world's ``uint8`` voxel array; the renderer indexes its
texture atlas by them, physics reads ``SOLID``, the bots read ``BREAK_TICKS``. Every per-block table
is built from the one ``_PROPS`` list below, so adding a block is one line.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class Block(IntEnum):
    AIR = 0
    GRASS = 1
    DIRT = 2
    STONE = 3
    COBBLESTONE = 4
    OAK_PLANKS = 5
    OAK_LOG = 6
    LEAVES = 7
    SAND = 8
    WATER = 9
    BRICKS = 10
    BEDROCK = 11
    SNOW = 12
    COAL_ORE = 13
    IRON_ORE = 14
    DIAMOND_ORE = 15
    TORCH = 16
    RED_SAND = 17
    SMOOTH_SANDSTONE = 18
    GRAVEL = 19


# (block, minecraft name, solid for collision, opaque for rendering, ticks to break with the right
# diamond tool, 0 = instant, -1 = unbreakable). Break ticks follow vanilla: ceil(30*hardness/8) with
# a diamond tool (speed 8), e.g. stone 1.5 -> 6 ticks.
_PROPS: tuple[tuple[Block, str, bool, bool, int], ...] = (
    (Block.AIR, "air", False, False, -1),
    (Block.GRASS, "grass_block", True, True, 3),
    (Block.DIRT, "dirt", True, True, 2),
    (Block.STONE, "stone", True, True, 6),
    (Block.COBBLESTONE, "cobblestone", True, True, 8),
    (Block.OAK_PLANKS, "oak_planks", True, True, 8),
    (Block.OAK_LOG, "oak_log", True, True, 8),
    (Block.LEAVES, "oak_leaves", True, True, 1),
    (Block.SAND, "sand", True, True, 2),
    (Block.WATER, "water", False, False, -1),
    (Block.BRICKS, "bricks", True, True, 8),
    (Block.BEDROCK, "bedrock", True, True, -1),
    (Block.SNOW, "snow_block", True, True, 1),
    (Block.COAL_ORE, "coal_ore", True, True, 12),
    (Block.IRON_ORE, "iron_ore", True, True, 12),
    (Block.DIAMOND_ORE, "diamond_ore", True, True, 12),
    (Block.TORCH, "torch", False, False, 0),
    (Block.RED_SAND, "red_sand", True, True, 2),
    (Block.SMOOTH_SANDSTONE, "smooth_sandstone", True, True, 8),
    (Block.GRAVEL, "gravel", True, True, 3),
)
assert [p[0] for p in _PROPS] == list(Block), "_PROPS must list every Block in id order"

NUM_BLOCKS = len(Block)
NAMES: tuple[str, ...] = tuple(p[1] for p in _PROPS)
SOLID = np.array([p[2] for p in _PROPS], dtype=bool)  # (NUM_BLOCKS,) collides with players
OPAQUE = np.array([p[3] for p in _PROPS], dtype=bool)  # (NUM_BLOCKS,) a full cube that hides what is behind
BREAK_TICKS = np.array([p[4] for p in _PROPS], dtype=np.int32)  # (NUM_BLOCKS,)
BY_NAME = {name: b for b, name, *_ in _PROPS}

# Blocks a player may hold and place. Tools and weapons are items, not blocks: they live in
# ``Item`` ids above 255 so a hotbar slot can hold either.
PLACEABLE = frozenset(b for b in Block if b not in (Block.AIR, Block.WATER, Block.BEDROCK))


class Item(IntEnum):
    """Non-block items that a hotbar slot can hold (ids > 255 keep them apart from blocks)."""

    EMPTY = 0
    DIAMOND_PICKAXE = 256
    DIAMOND_SHOVEL = 257
    DIAMOND_AXE = 258
    WOODEN_SWORD = 259
    STONE_SWORD = 260
    IRON_SWORD = 261
    GOLDEN_SWORD = 262
    DIAMOND_SWORD = 263
    NETHERITE_SWORD = 264


def item_name(item_id: int) -> str:
    """Minecraft name of a hotbar item id (block ids < 256, ``Item`` ids >= 256)."""
    if item_id == 0:
        return "air"
    if item_id < 256:
        return NAMES[item_id]
    return Item(item_id).name.lower()
