"""``engine.physics`` and ``engine.game``: player speeds, jump, collision, sneak edge; digging and placing through the
action space."""

import math

import numpy as np
import pytest

from solaris_env.engine import constants as C
from solaris_env.engine.blocks import BREAK_TICKS, Block, Item
from solaris_env.engine.game import Game
from solaris_env.engine.physics import Player, look_vector, wrap_angle, yaw_to
from solaris_env.engine.worldgen import FLAT_SURFACE_Y, WorldConfig, flat_world
from solaris_env.spaces import noop

FEET_Y = FLAT_SURFACE_Y + 1
SMALL = WorldConfig(size_xz=64, height=48, floor_y=40, margin=8)


def make_game(*positions, yaw=0.0):
    if len(positions) == 1:  # a bystander far away
        positions = (positions[0], (12.5, FEET_Y, 12.5))
    world = flat_world(seed=0, variant=0, cfg=SMALL)
    players = [Player(n, skin=k, pos=np.array(p, float), yaw=yaw, on_ground=True)
               for k, (n, p) in enumerate(zip(("Alpha", "Bravo"), positions))]
    return Game(world, players)


def act(**keys):
    a = noop()
    for k, v in keys.items():
        a[k.replace("hotbar_", "hotbar.")] = v
    return a


def run(game, ticks, **keys):
    for _ in range(ticks):
        game.step([act(**keys)] + [noop()] * (len(game.players) - 1))


@pytest.mark.parametrize("keys,speed", [
    ({"forward": 1}, 4.317),
    ({"forward": 1, "sprint": 1}, 5.612),
    ({"forward": 1, "sneak": 1}, 1.295),
    ({"left": 1}, 4.317),
])
def test_ground_speed_matches_vanilla(keys, speed):
    g = make_game((0.5, FEET_Y, 0.5))
    run(g, 20, **keys)  # reach top speed
    start = g.players[0].pos.copy()
    run(g, 40, **keys)
    measured = np.hypot(*(g.players[0].pos - start)[[0, 2]]) / 2.0
    assert measured == pytest.approx(speed, rel=0.02)


def test_forward_is_north_and_left_is_west_at_yaw_zero():
    g = make_game((0.5, FEET_Y, 0.5))
    run(g, 10, forward=1)
    assert g.players[0].pos[2] < 0 and abs(g.players[0].pos[0] - 0.5) < 1e-9
    g = make_game((0.5, FEET_Y, 0.5))
    run(g, 10, left=1)
    assert g.players[0].pos[0] < 0 and abs(g.players[0].pos[2] - 0.5) < 1e-9


def test_jump_height_and_landing():
    g = make_game((0.5, FEET_Y, 0.5))
    heights = []
    g.step([act(jump=1), noop()])
    for _ in range(20):
        heights.append(g.players[0].pos[1] - FEET_Y)
        g.step([noop(), noop()])
    assert max(heights) == pytest.approx(1.25, abs=0.03)
    assert g.players[0].pos[1] == FEET_Y and g.players[0].on_ground


def test_wall_blocks_walking_and_one_block_step_needs_a_jump():
    g = make_game((0.5, FEET_Y, 0.5))
    g.world.set(0, FEET_Y, -3, Block.STONE)
    run(g, 40, forward=1)
    p = g.players[0]
    assert p.pos[2] == pytest.approx(-2 + C.PLAYER_WIDTH / 2)  # flush against the block face
    run(g, 40, forward=1, jump=1)
    assert p.pos[2] < -3 and p.pos[1] >= FEET_Y  # jumped onto / over it


def test_ceiling_stops_a_jump():
    g = make_game((0.5, FEET_Y, 0.5))
    g.world.set(0, FEET_Y + 2, 0, Block.STONE)
    g.step([act(jump=1), noop()])
    for _ in range(10):
        g.step([noop(), noop()])
        assert g.players[0].pos[1] + C.PLAYER_HEIGHT <= FEET_Y + 2 + 1e-9


def test_sneaking_never_walks_off_an_edge_but_walking_does():
    for sneak, falls in ((1, False), (0, True)):
        g = make_game((0.5, FEET_Y + 3, 0.5))
        for y in range(FEET_Y, FEET_Y + 3):  # a 1x1 pillar, 3 high
            g.world.set(0, y, 0, Block.STONE)
        g.players[0].on_ground = True
        run(g, 60, forward=1, sneak=sneak)
        p = g.players[0]
        assert (p.pos[1] < FEET_Y + 3) == falls
        if not falls:  # still over the pillar: the box overlaps the column x,z in [0, 1)
            assert p.pos[2] - C.PLAYER_WIDTH / 2 < 0.0 + 1e-9 and p.pos[2] + C.PLAYER_WIDTH / 2 > 0.0


def test_pitch_is_clamped_and_camera_record_reports_the_applied_delta():
    g = make_game((0.5, FEET_Y, 0.5))
    ev = None
    for _ in range(3):
        ev = g.step([act(camera=np.array([-60.0, 0.0], np.float32)), noop()])[0]  # look up 60 deg/tick
    assert g.players[0].pitch == pytest.approx(math.pi / 2)
    assert ev.record["camera"][1] == pytest.approx(math.radians(90 - 120), abs=1e-6) or ev.record["camera"][1] == 0.0
    ev = g.step([act(camera=np.array([0.0, 30.0], np.float32)), noop()])[0]  # turn right 30 deg
    assert ev.record["camera"][0] == pytest.approx(-math.radians(30), abs=1e-6)  # Mineflayer: right is negative
    ev = g.step([noop(), noop()])[0]
    assert ev.record["camera"] == [0.0, 0.0]


def test_mine_then_place_round_trip():
    g = make_game((0.5, FEET_Y, 0.5))
    p = g.players[0]
    p.hotbar[0] = [int(Block.COBBLESTONE), 5]
    p.hotbar[1] = [int(Item.DIAMOND_PICKAXE), 1]
    target = (0, FEET_Y, -2)
    g.world.set(*target, Block.STONE)
    p.pitch = -math.atan2(FEET_Y + C.EYE_HEIGHT - (FEET_Y + 0.5), 2.0)  # aim at the block centre
    assert g.target(0).block == target
    g.step([act(hotbar_2=1), noop()])
    mines = []
    for _ in range(int(BREAK_TICKS[Block.STONE]) + 2):
        ev = g.step([act(attack=1), noop()])[0]
        mines.append(ev.record["mine"])
        if ev.mined:
            break
    assert g.world.get(*target) == Block.AIR
    assert len(mines) == BREAK_TICKS[Block.STONE] and all(mines)
    # Aim at the floor block behind where the stone was, and place cobblestone on its top face.
    g.step([act(hotbar_1=1), noop()])
    p.pitch = -math.atan2(C.EYE_HEIGHT, 2.0)  # the top face centre of the floor block under the hole
    hit = g.target(0)
    assert hit.block == (0, FEET_Y - 1, -2) and hit.normal == (0, 1, 0)
    ev = g.step([act(use=1), noop()])[0]
    assert ev.record["place_block"] and g.world.get(*target) == Block.COBBLESTONE
    assert p.hotbar[0] == [int(Block.COBBLESTONE), 4]


def test_hotbar_record_is_a_one_tick_event():
    g = make_game((0.5, FEET_Y, 0.5))
    recs = [g.step([act(hotbar_3=1), noop()])[0].record for _ in range(3)]
    assert [r["hotbar.3"] for r in recs] == [True, False, False]
    assert g.players[0].selected_slot == 2


def test_cannot_place_a_block_inside_a_player():
    g = make_game((0.5, FEET_Y, 0.5), (0.5, FEET_Y, -1.5))
    p = g.players[0]
    p.hotbar[0] = [int(Block.STONE), 64]
    p.selected_slot = 0
    p.pitch = -math.atan2(C.EYE_HEIGHT, 2.0)  # aims at the floor right under Bravo
    g.step([act(use=1), noop()])
    assert g.world.get(0, FEET_Y, -2) == Block.AIR


def test_attack_hits_the_other_player_with_knockback_and_cooldown():
    g = make_game((0.5, FEET_Y, 0.5), (0.5, FEET_Y, -2.0))
    recs = [g.step([act(attack=1), noop()])[0].record["attack"] for _ in range(C.ATTACK_COOLDOWN_TICKS + 1)]
    assert recs[0] and not any(recs[1:-1]) and g.players[1].hits_taken >= 1
    assert g.players[1].pos[2] < -2.0  # pushed away (north)


def test_determinism_same_actions_same_state():
    def rollout():
        g = make_game((0.5, FEET_Y, 0.5), (3.5, FEET_Y, 0.5))
        from solaris_env.spaces import make_action_space
        space = make_action_space(seed=1)
        for _ in range(200):
            g.step([space.sample(), space.sample()])
        return np.concatenate([np.r_[p.pos, p.yaw, p.pitch] for p in g.players]), g.world.blocks_XYZ.copy()

    a, wa = rollout()
    b, wb = rollout()
    assert np.array_equal(a, b) and np.array_equal(wa, wb)


def test_look_vector_and_yaw_conventions():
    assert np.allclose(look_vector(0.0, 0.0), [0, 0, -1])
    assert np.allclose(look_vector(math.pi / 2, 0.0), [-1, 0, 0])  # west
    assert np.allclose(look_vector(0.0, math.pi / 2), [0, 1, 0], atol=1e-12)
    assert yaw_to(np.zeros(3), np.array([-1.0, 0, 0])) == pytest.approx(math.pi / 2)
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)


def test_bad_actions_name_the_agent():
    g = make_game((0.5, FEET_Y, 0.5), (3.5, FEET_Y, 0.5))
    bad = noop()
    del bad["jump"]
    with pytest.raises(ValueError, match="Bravo.*jump|jump.*Bravo"):
        g.step([noop(), bad])
    with pytest.raises(ValueError, match="expected 2 actions"):
        g.step([noop()])
