"""An episode's trace: everything needed to render and record it after simulation.

Simulation (physics, bots) and rendering are decoupled: the runner steps the game and appends the
state of every tick here; the capture step renders all frames later in large batches (which is what
makes collection fast) by replaying the block edits on the initial world.

Frame/action pairing (docs/engine.md §4.3): frame t = render(s_t), record t = the action applied during
s_t -> s_{t+1}; an edit made during step t is therefore first visible in frame t + 1.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solaris_env.engine.game import Game


@dataclass
class Trace:
    """Per-tick state of all P players over T ticks (arrays are filled by ``append`` and frozen by ``finish``)."""

    player_names: list[str]
    skins: list[int]
    initial_blocks_XYZ: np.ndarray  # (X, Y, Z) uint8 at tick 0
    origin: tuple[int, int, int]
    edits: list[tuple[int, int, int, int, int]] = field(default_factory=list)  # (tick, x, y, z, new block)
    # Per tick (lists while recording, stacked to arrays by finish()):
    feet_TP3: list | np.ndarray = field(default_factory=list)
    eye_TP3: list | np.ndarray = field(default_factory=list)
    yaw_TP: list | np.ndarray = field(default_factory=list)
    pitch_TP: list | np.ndarray = field(default_factory=list)
    swing_TP: list | np.ndarray = field(default_factory=list)
    sneak_TP: list | np.ndarray = field(default_factory=list)
    selected_slot_TP: list | np.ndarray = field(default_factory=list)
    hotbar_TP9: list | np.ndarray = field(default_factory=list)
    daylight_T: list | np.ndarray = field(default_factory=list)
    records: list[list[dict]] = field(default_factory=list)  # [player][tick] Mineflayer record dicts

    @classmethod
    def start(cls, game: Game) -> "Trace":
        return cls([p.name for p in game.players], [p.skin for p in game.players],
                   game.world.blocks_XYZ.copy(), game.world.origin, records=[[] for _ in game.players])

    @property
    def num_ticks(self) -> int:
        return len(self.yaw_TP)

    def append_state(self, game: Game) -> None:
        """Store s_t (call before stepping tick t)."""
        ps = game.players
        self.feet_TP3.append(np.array([p.pos for p in ps], np.float32))
        self.eye_TP3.append(np.array([p.eye for p in ps], np.float32))
        self.yaw_TP.append(np.array([p.yaw for p in ps], np.float32))
        self.pitch_TP.append(np.array([p.pitch for p in ps], np.float32))
        self.swing_TP.append(np.array([p.swing_angle() for p in ps], np.float32))
        self.sneak_TP.append(np.array([p.sneaking for p in ps], bool))
        self.selected_slot_TP.append(np.array([p.selected_slot for p in ps], np.int32))
        self.hotbar_TP9.append(np.array([[it for it, _ in p.hotbar] for p in ps], np.int32))
        self.daylight_T.append(game.daylight())

    def append_edits(self, tick: int, edits: list[tuple[int, int, int, int]]) -> None:
        self.edits.extend((tick, x, y, z, b) for x, y, z, b in edits)

    def finish(self) -> "Trace":
        for name in ("feet_TP3", "eye_TP3", "yaw_TP", "pitch_TP", "swing_TP", "sneak_TP", "selected_slot_TP",
                     "hotbar_TP9", "daylight_T"):
            setattr(self, name, np.asarray(getattr(self, name)))
        self.daylight_T = self.daylight_T.astype(np.float32)
        return self

    def snapshots(self, t0: int, t1: int) -> tuple[np.ndarray, np.ndarray]:
        """World snapshots for frames [t0, t1): (voxels_KXYZ, world_idx_T) with K distinct versions."""
        blocks = self.initial_blocks_XYZ.copy()
        ox, oy, oz = self.origin
        edits = sorted(self.edits, key=lambda e: e[0])
        e = 0
        while e < len(edits) and edits[e][0] + 1 <= t0:  # edits visible by frame t0
            _, x, y, z, b = edits[e]
            blocks[x - ox, y - oy, z - oz] = b
            e += 1
        snaps, idx = [blocks.copy()], []
        for t in range(t0, t1):
            changed = False
            while e < len(edits) and edits[e][0] + 1 <= t:
                _, x, y, z, b = edits[e]
                blocks[x - ox, y - oy, z - oz] = b
                e += 1
                changed = True
            if changed:
                snaps.append(blocks.copy())
            idx.append(len(snaps) - 1)
        return np.stack(snaps), np.asarray(idx, np.int32)
