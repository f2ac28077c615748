"""Quick renderer speed check: frames/s of ``engine.render.Renderer`` on a typical two-player scene.

    .venv/bin/python benchmarks/render_speed.py              # ~1-2 min on 2 CPU cores
    .venv/bin/python benchmarks/render_speed.py --world flat --repeats 3

Scene: a generated world (``worldgen``; "flat" = superflat grass, "normal" = hills, trees, water),
pairs of players 6-12 blocks apart looking roughly at each other, every fourth view looking down
at the ground; each view draws the other player. Prints, per (resolution, views per call), the
best-of-``repeats`` wall time per call, frames/s and the first-call (compile) time. The official
numbers come from ``benchmarks/engine_throughput.py``.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from solaris_env.engine.constants import EYE_HEIGHT
from solaris_env.engine.render import RenderConfig, Renderer, Views
from solaris_env.engine.worldgen import generate

CASES = ((64, 64), (64, 32), (64, 1), (128, 16), (128, 1))  # (resolution, views per call)
PAIR_DISTANCE = (6.0, 12.0)
LOOK_DOWN_EVERY = 4
LOOK_DOWN_PITCH = -1.0
HOTBAR = (1, 3, 5, 256, 263, 16, 10, 259, 0)


def pair_views(world, num_views: int, seed: int = 0) -> Views:
    """Views of players standing on the surface, each looking at the other (with some jitter)."""
    rng = np.random.default_rng(seed)
    B = num_views
    eye, yaw, pitch = np.zeros((B, 3)), np.zeros(B), np.zeros(B)
    feet, avatar_yaw = np.zeros((B, 1, 3)), np.zeros((B, 1))
    for b in range(B):
        x, z = rng.uniform(-12, 12, size=2)
        ang = rng.uniform(0, 2 * math.pi)
        dist = rng.uniform(*PAIR_DISTANCE)
        ox, oz = x - dist * math.sin(ang), z - dist * math.cos(ang)
        me = (x, world.surface_y(int(math.floor(x)), int(math.floor(z))), z)
        other = (ox, world.surface_y(int(math.floor(ox)), int(math.floor(oz))), oz)
        eye[b] = (me[0], me[1] + EYE_HEIGHT, me[2])
        yaw[b] = ang + rng.normal(0, 0.3)
        pitch[b] = LOOK_DOWN_PITCH if b % LOOK_DOWN_EVERY == LOOK_DOWN_EVERY - 1 else rng.normal(0, 0.15)
        feet[b, 0], avatar_yaw[b, 0] = other, ang + math.pi
    ones = np.ones((B, 1))
    return Views(
        world_idx_B=np.zeros(B, np.int32), eye_B3=eye.astype(np.float32), yaw_B=yaw.astype(np.float32),
        pitch_B=pitch.astype(np.float32), avatar_feet_BA3=feet.astype(np.float32),
        avatar_yaw_BA=avatar_yaw.astype(np.float32), avatar_pitch_BA=np.zeros((B, 1), np.float32),
        avatar_skin_BA=np.ones((B, 1), np.int32), avatar_swing_BA=0.3 * ones.astype(np.float32),
        avatar_sneak_BA=np.zeros((B, 1), bool), avatar_mask_BA=ones.astype(bool),
        selected_slot_B=np.arange(B, dtype=np.int32) % 9, hotbar_items_B9=np.tile(np.array(HOTBAR, np.int32), (B, 1)),
        daylight_B=np.ones(B, np.float32))


def main(args: argparse.Namespace) -> None:
    world = generate(args.world, seed=args.seed)
    voxels_KXYZ = world.blocks_XYZ[None]
    print(f"world={args.world} shape={world.blocks_XYZ.shape}")
    for size, num_views in CASES:
        renderer = Renderer(RenderConfig(height=size, width=size))
        views = pair_views(world, num_views, args.seed)
        t = time.perf_counter()
        renderer.render(voxels_KXYZ, world.origin, views)
        first = time.perf_counter() - t
        best = math.inf
        for _ in range(args.repeats):
            t = time.perf_counter()
            renderer.render(voxels_KXYZ, world.origin, views)
            best = min(best, time.perf_counter() - t)
        print(f"{size:4d}x{size:<4d} B={num_views:3d}: {best * 1000:8.2f} ms/call {num_views / best:8.0f} frames/s"
              f"   (first call {first:.1f} s)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", choices=("flat", "normal"), default="normal")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=10)
    main(parser.parse_args())
