"""Game constants of the voxel engine, in Minecraft units (blocks, ticks at 20 Hz, radians).

Values follow vanilla Minecraft (Java 1.21) player physics so that recorded motion matches the
statistics of the paper's data (docs/engine.md §3.1: walk ~4.317 b/s, sprint ~5.612, sneak ~1.3).
"""

import math

TICKS_PER_SECOND = 20
TICK_MS = 1000 // TICKS_PER_SECOND

# Player body.
PLAYER_WIDTH = 0.6
PLAYER_HEIGHT = 1.8
PLAYER_SNEAK_HEIGHT = 1.5
EYE_HEIGHT = 1.62
SNEAK_EYE_HEIGHT = 1.27
REACH = 4.5  # blocks, from the eye

# Movement (per tick). Horizontal velocity follows v <- v * friction + accel * input, whose fixed
# point accel / (1 - friction) is the top speed; vanilla's ground friction is 0.6 * 0.91.
GROUND_FRICTION = 0.6 * 0.91
AIR_FRICTION = 0.91
WALK_SPEED = 4.317 / TICKS_PER_SECOND
SPRINT_SPEED = 5.612 / TICKS_PER_SECOND
SNEAK_SPEED = 1.295 / TICKS_PER_SECOND
AIR_ACCEL = 0.02
AIR_SPRINT_ACCEL = 0.026
GRAVITY = 0.08
VERTICAL_DRAG = 0.98
JUMP_VELOCITY = 0.42  # -> apex ~1.25 blocks
SPRINT_JUMP_BOOST = 0.2
WATER_DRAG = 0.8
WATER_GRAVITY = 0.02
WATER_SWIM_UP = 0.04
SNEAK_EDGE_PROBE = 0.05  # the step by which sneaking shrinks a move that would leave the ground

# Camera.
PITCH_LIMIT = math.pi / 2
FOV_DEG = 70.0
# Mineflayer's default look speed (3 rad/s = 171.887 deg/s) and its 0.15 deg mouse step.
DEFAULT_LOOK_SPEED_DEG = math.degrees(3.0)
LOOK_STEP_DEG = 0.15

# Combat.
ATTACK_COOLDOWN_TICKS = 10
KNOCKBACK = 0.4

HOTBAR_SIZE = 9
STACK_SIZE = 64
