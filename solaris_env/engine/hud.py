"""Minecraft-like HUD: a 9-slot hotbar centred at the bottom (item icons, selected-slot frame) and a
crosshair at the centre.

The layout is rasterised once per resolution in numpy (``HudLayout.build``): every HUD pixel gets
its background colour and coverage, the coverage of each slot's selection frame, the icon texel
seen by each of its sub-samples and its crosshair coverage. Inside the jitted renderer only the
selected slot and the slot items vary per view (``composite``). Sizes are in Minecraft GUI units,
scaled so that the screen is ``GUI_SCREEN_HEIGHT`` units tall (1280x720 at GUI scale 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from solaris_env.engine import textures as tx
from solaris_env.engine.constants import HOTBAR_SIZE

NUM_SLOTS = HOTBAR_SIZE
GUI_SCREEN_HEIGHT = 240.0  # GUI units per screen height (720 px / GUI scale 3)
MAX_WIDTH_FRAC = 0.95  # on narrow screens the hotbar is shrunk to this fraction of the width
# Vanilla hotbar geometry (widgets.png), GUI units.
HOTBAR_W, HOTBAR_H = 182.0, 22.0
SLOT_PITCH = 20.0
ICON_OFFSET = 3.0  # icon top-left inside a slot
ICON_SIZE = 16.0
BORDER = 1.0  # slot border thickness
SELECT_SIZE, SELECT_BORDER = 24.0, 2.0  # the selection frame around the selected slot
CROSS_ARM, CROSS_THICK = 4.0, 1.0  # crosshair half-length and thickness (at least 1 pixel each)
SUPERSAMPLE = 4  # sub-samples per pixel edge when rasterising

SLOT_RGB, SLOT_ALPHA = (0.12, 0.12, 0.12), 0.55
BORDER_RGB, BORDER_ALPHA = (0.55, 0.55, 0.55), 0.85
SELECT_RGB = (0.92, 0.92, 0.92)


@dataclass(frozen=True)
class HudLayout:
    """Per-resolution HUD rasterisation, as full-frame (P = H * W) arrays so that compositing is
    elementwise (no scatter) inside the renderer.

    Attributes:
        bg_rgb_P3: premultiplied hotbar background colour; bg_alpha_P: its coverage.
        select_alpha_9P: coverage of each slot's selection frame.
        icon_slot_P: int32 slot whose icon a pixel shows (0 where none, see icon_idx_P).
        icon_idx_P: int32 index of the pixel among the M icon pixels, -1 where none.
        icon_table: uint32 (NUM_ICONS * M + 1,) each icon's premultiplied RGBA as seen by each icon
            pixel (averaged over its sub-samples), R | G << 8 | B << 16 | A << 24; the last entry is
            transparent.
        cross_P: crosshair coverage (drawn by inverting the colour, like Minecraft).
    """

    bg_rgb_P3: np.ndarray
    bg_alpha_P: np.ndarray
    select_alpha_9P: np.ndarray
    icon_slot_P: np.ndarray
    icon_idx_P: np.ndarray
    icon_table: np.ndarray
    cross_P: np.ndarray

    @staticmethod
    def build(height: int, width: int) -> "HudLayout":
        gui = min(height / GUI_SCREEN_HEIGHT, MAX_WIDTH_FRAC * width / HOTBAR_W)  # pixels per GUI unit
        x0 = width / 2.0 - HOTBAR_W * gui / 2.0
        y0 = height - HOTBAR_H * gui
        ss = SUPERSAMPLE
        sub = (np.arange(ss) + 0.5) / ss
        rows = (np.arange(height)[:, None] + sub[None, :]).reshape(-1)  # (H*ss,)
        cols = (np.arange(width)[:, None] + sub[None, :]).reshape(-1)
        gy = ((rows - y0) / gui)[:, None]  # (H*ss, 1) GUI coordinates of every sub-sample
        gx = ((cols - x0) / gui)[None, :]  # (1, W*ss)
        in_bar = (gx >= 0) & (gx < HOTBAR_W) & (gy >= 0) & (gy < HOTBAR_H)
        slot = np.clip(np.floor((gx - 1.0) / SLOT_PITCH), 0, NUM_SLOTS - 1).astype(np.int32)
        sx = gx - 1.0 - slot * SLOT_PITCH  # position inside the slot's 20-unit cell
        sy = gy - 1.0
        on_border = in_bar & ((sx < BORDER) | (sx >= SLOT_PITCH - BORDER) | (sy < BORDER) | (sy >= SLOT_PITCH - BORDER)
                              | (gx < 1.0) | (gx >= HOTBAR_W - 1.0) | (gy < 1.0) | (gy >= HOTBAR_H - 1.0))
        alpha = np.where(on_border, BORDER_ALPHA, np.where(in_bar, SLOT_ALPHA, 0.0))
        color = np.where(on_border[..., None], BORDER_RGB, SLOT_RGB) * alpha[..., None]
        ix, iy = gx - ICON_OFFSET - slot * SLOT_PITCH, gy - ICON_OFFSET
        in_icon = in_bar & (ix >= 0) & (ix < ICON_SIZE) & (iy >= 0) & (iy < ICON_SIZE)
        texel = (np.clip(np.floor(iy), 0, tx.TEX - 1) * tx.TEX + np.clip(np.floor(ix), 0, tx.TEX - 1)).astype(np.int32)
        icon_slot = np.where(in_icon, slot, -1)
        # Selection frames: 24x24 units centred on each slot, SELECT_BORDER thick.
        select = np.zeros((NUM_SLOTS,) + in_bar.shape, np.float64)
        for s in range(NUM_SLOTS):
            fx, fy = gx - (s * SLOT_PITCH - 1.0), gy + 1.0
            inside = (fx >= 0) & (fx < SELECT_SIZE) & (fy >= 0) & (fy < SELECT_SIZE)
            inner = ((fx >= SELECT_BORDER) & (fx < SELECT_SIZE - SELECT_BORDER)
                     & (fy >= SELECT_BORDER) & (fy < SELECT_SIZE - SELECT_BORDER))
            select[s] = inside & ~inner
        # Crosshair: snapped to whole pixels so that it stays crisp at low resolution.
        arm = max(1, int(round(CROSS_ARM * gui)))
        half = max(1, int(round(CROSS_THICK * gui))) // 2
        cr, cc = height // 2, width // 2
        cross = np.zeros((height, width))
        cross[cr - arm:cr + arm + 1, cc - half:cc + half + 1] = 1.0
        cross[cr - half:cr + half + 1, cc - arm:cc + arm + 1] = 1.0

        def pool(a):  # (H*ss, W*ss, ...) sub-samples -> (P, ...) pixel means
            a = np.broadcast_to(a, (height * ss, width * ss) + a.shape[2:])
            pooled = a.reshape(height, ss, width, ss, *a.shape[2:]).mean(axis=(1, 3))
            return pooled.reshape((height * width,) + a.shape[2:])

        def subsamples(a):  # (H*ss, W*ss) -> (P, ss*ss)
            a = np.broadcast_to(a, (height * ss, width * ss))
            return a.reshape(height, ss, width, ss).transpose(0, 2, 1, 3).reshape(height * width, ss * ss)

        # Icons: each pixel shows the icon of the slot covering most of its sub-samples.
        slot_PS, texel_PS = subsamples(icon_slot), subsamples(texel)
        votes = np.stack([(slot_PS == s).sum(axis=1) for s in range(NUM_SLOTS)], axis=1)  # (P, 9)
        icon_pix = np.flatnonzero(votes.max(axis=1) > 0)
        pix_slot = votes[icon_pix].argmax(axis=1)
        in_slot_MS = slot_PS[icon_pix] == pix_slot[:, None]
        icons = tx.icon_atlas().astype(np.float64) / 255.0  # (NUM_ICONS, TEX, TEX, 4)
        table = np.zeros((tx.NUM_ICONS * len(icon_pix) + 1, 4))
        for row in range(tx.NUM_ICONS):
            rgba_MS4 = icons[row].reshape(-1, 4)[texel_PS[icon_pix]] * in_slot_MS[..., None]
            rgba_MS4[..., :3] *= rgba_MS4[..., 3:]
            table[row * len(icon_pix):(row + 1) * len(icon_pix)] = rgba_MS4.mean(axis=1)
        table_u8 = np.clip(np.rint(table * 255.0), 0, 255).astype(np.uint32)
        icon_slot_P = np.zeros(height * width, np.int32)
        icon_slot_P[icon_pix] = pix_slot
        icon_idx_P = np.full(height * width, -1, np.int32)
        icon_idx_P[icon_pix] = np.arange(len(icon_pix))
        return HudLayout(
            bg_rgb_P3=pool(color).astype(np.float32),
            bg_alpha_P=pool(alpha).astype(np.float32),
            select_alpha_9P=np.stack([pool(select[s]) for s in range(NUM_SLOTS)]).astype(np.float32),
            icon_slot_P=icon_slot_P,
            icon_idx_P=icon_idx_P,
            icon_table=sum(table_u8[:, c] << (8 * c) for c in range(4)).astype(np.uint32),
            cross_P=cross.reshape(-1).astype(np.float32),
        )

    def device_arrays(self) -> dict[str, jax.Array]:
        """The layout plus the item->icon table, as device arrays for ``composite``."""
        arrays = {name: jnp.asarray(getattr(self, name)) for name in self.__dataclass_fields__}
        arrays["icon_of_item"] = jnp.asarray(tx.icon_of_item())
        return arrays


def composite(rgb_BP3: jax.Array, selected_slot_B: jax.Array, hotbar_items_B9: jax.Array,
              consts: dict[str, jax.Array]) -> jax.Array:
    """Draw the HUD over flattened frames (elementwise; only the slot choice and items vary per view).

    Args:
        rgb_BP3: (B, H*W, 3) float colours in [0, 1].
        selected_slot_B: (B,) int32 selected slot 0..8.
        hotbar_items_B9: (B, 9) int32 item ids (0 = empty).
        consts: ``HudLayout.device_arrays()``.

    Returns:
        (B, H*W, 3) float colours with the HUD drawn.
    """
    c = rgb_BP3 * (1.0 - consts["bg_alpha_P"][None, :, None]) + consts["bg_rgb_P3"][None]
    sel = consts["select_alpha_9P"][selected_slot_B][..., None]  # (B, P, 1)
    c = c + (jnp.asarray(SELECT_RGB) - c) * sel
    item_to_icon = consts["icon_of_item"]
    icon_row_B9 = item_to_icon[jnp.clip(hotbar_items_B9, 0, item_to_icon.shape[0] - 1)]
    table = consts["icon_table"]
    num_icon_pix = (table.shape[0] - 1) // tx.NUM_ICONS
    idx_P = consts["icon_idx_P"][None, :]
    row_BP = icon_row_B9[:, consts["icon_slot_P"]]  # (B, P) icon of the slot under each pixel
    packed = table[jnp.where(idx_P >= 0, row_BP * num_icon_pix + idx_P, table.shape[0] - 1)]
    rgba = jnp.stack([((packed >> (8 * ch)) & 255).astype(jnp.float32) for ch in range(4)], axis=-1) / 255.0
    c = c * (1.0 - rgba[..., 3:]) + rgba[..., :3]
    cross = consts["cross_P"][None, :, None]
    return c + (1.0 - 2.0 * c) * cross  # invert under the crosshair
