"""``engine.minecraft.records``: raw tick rows -> Mineflayer records, and the pose-based ground truth (no Minecraft
needed)."""

import math

import numpy as np
import pytest

from solaris_env.engine.game import RECORD_BOOL_KEYS
from solaris_env.engine.minecraft.collect import frames_from_rgba, render_size
from solaris_env.engine.minecraft.records import (
    action_record,
    build_records,
    camera_axes,
    catchup_ticks,
    ground_truth,
    project_box,
    wrap_pi,
)

CONTROLS_OFF = {k: False for k in ("forward", "back", "left", "right", "jump", "sprint", "sneak")}


def row(t, yaw=0.0, pitch=0.0, yaw_next=None, pitch_next=None, controls=None, events=None, rt=None, dt=50.0,
        x=0.0, z=0.0):
    return {"t": t, "x": x, "y": 5.0, "z": z, "yaw": yaw, "pitch": pitch,
            "yaw_next": yaw if yaw_next is None else yaw_next, "pitch_next": pitch if pitch_next is None else pitch_next,
            "controls": {**CONTROLS_OFF, **(controls or {})}, "events": events or {}, "quickBarSlot": 0,
            "renderTime": 1_700_000_000_000 + 50 * t if rt is None else rt, "physicsTime": 50.0 * t,
            "worldAgeTicks": 6000 + t, "isInWater": False, "dtMs": None if t == 0 else dt}


def test_action_record_has_exactly_the_24_keys_and_sustained_controls():
    rec = action_record(row(0, controls={"forward": True, "sneak": True}))
    assert set(rec) == set(RECORD_BOOL_KEYS) | {"camera"}
    assert len(rec) == 24
    assert rec["forward"] and rec["sneak"] and not rec["back"]
    assert rec["camera"] == [0.0, 0.0]


def test_once_flags_mine_sustained_and_hotbar():
    rec = action_record(row(0, events={"attack": 2, "place_block": 1, "mine": True, "hotbar": 3}))
    assert rec["attack"] and rec["place_block"] and rec["mine"] and rec["hotbar.3"]
    assert not rec["use"] and not rec["hotbar.1"]
    with pytest.raises(ValueError, match="events.hotbar"):
        action_record(row(0, events={"hotbar": 10}))
    bad = row(0)
    del bad["controls"]["sprint"]
    with pytest.raises(ValueError, match="sprint"):
        action_record(bad)


def test_camera_delta_is_shortest_arc_in_mineflayer_sign():
    # turning left across the 0/2pi seam: yaw 6.2 -> 0.1 is +0.183 rad, not -6.1
    rec = action_record(row(0, yaw=6.2, yaw_next=0.1, pitch=0.0, pitch_next=0.2))
    assert rec["camera"][0] == pytest.approx(0.1 + 2 * math.pi - 6.2, abs=1e-6)
    assert rec["camera"][1] == pytest.approx(0.2, abs=1e-6)
    assert wrap_pi(math.pi) == pytest.approx(math.pi)
    assert wrap_pi(-math.pi) == pytest.approx(math.pi)


def test_build_records_layout_and_strictly_increasing_render_time():
    rows = [row(0), row(1, rt=1_700_000_000_000), row(2)]  # duplicate renderTime at tick 1
    recs = build_records(rows, episode=7)
    assert [r["frame_count"] for r in recs] == [0, 1, 2]
    assert all(r["episode_id"] == 7 for r in recs)
    rts = [r["renderTime"] for r in recs]
    assert rts[0] < rts[1] < rts[2]
    assert recs[0]["relativeTimeMs"] == 0.0 and recs[2]["epochTime"] == rts[2] / 1000
    assert recs[0]["extra_info"] == {"seed": 42}
    with pytest.raises(ValueError, match="consecutive"):
        build_records([row(0), row(2)], episode=0)


def test_catchup_ticks_counts_bursts():
    rows = [row(0), row(1, dt=50), row(2, dt=1.0), row(3, dt=0.5), row(4, dt=49)]
    assert catchup_ticks(rows) == 2


def test_camera_axes_match_mineflayer_convention():
    right, up, fwd = camera_axes(0.0, 0.0)  # yaw 0 faces north (-Z)
    np.testing.assert_allclose(fwd, [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(right, [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(up, [0, 1, 0], atol=1e-12)
    _, _, fwd = camera_axes(math.pi / 2, 0.0)  # west
    np.testing.assert_allclose(fwd, [-1, 0, 0], atol=1e-12)


def test_projection_centre_left_and_behind():
    eye = np.array([0.0, 1.62, 0.0])
    box = (np.array([-0.3, 0.0, -10.3]), np.array([0.3, 1.8, -9.7]))  # 10 blocks north
    u0, v0, u1, v1 = project_box(eye, 0.0, 0.0, *box, fov_deg=70, aspect=16 / 9)
    assert u0 < 0.5 < u1 and v0 < 0.5 < v1
    # turning right (negative yaw) puts it on the left of the screen
    u0, _, u1, _ = project_box(eye, -math.radians(30), 0.0, *box, fov_deg=70, aspect=16 / 9)
    assert (u0 + u1) / 2 < 1 / 3
    assert project_box(eye, math.pi, 0.0, *box, fov_deg=70, aspect=16 / 9) is None  # behind


def test_ground_truth_from_records():
    a = build_records([row(t, yaw=0.0, x=0.0, z=0.0) for t in range(3)], 0)  # Alpha looks north at Bravo
    b = build_records([row(t, yaw=0.0, x=0.0, z=-10.0) for t in range(3)], 0)  # Bravo looks away
    gt = ground_truth({"Alpha": a, "Bravo": b}, (64, 64), 70.0, 16 / 9)
    assert gt["num_frames"] == 3 and gt["players"] == ["Alpha", "Bravo"]
    assert gt["sight"]["Alpha"]["Bravo"]["visible"] == [True] * 3
    assert gt["sight"]["Alpha"]["Bravo"]["region"] == ["center"] * 3
    assert gt["sight"]["Bravo"]["Alpha"]["visible"] == [False] * 3
    assert gt["sight"]["Alpha"]["Bravo"]["distance"] == [10.0] * 3


def test_frames_from_rgba_flips_and_resamples():
    rh, rw = render_size(8, 8)
    assert (rh, rw) == (8, 14)
    f = np.zeros((2, rh, rw, 4), np.uint8)
    f[:, 0] = 255  # bottom row first in gl.readPixels -> the image's last row
    out = frames_from_rgba(f.tobytes(), rh, rw, 8, 8)
    assert out.shape == (2, 8, 8, 3)
    assert out[:, -1].min() == 255 and out[:, 0].max() == 0
    with pytest.raises(ValueError, match="whole number"):
        frames_from_rgba(f.tobytes()[:-1], rh, rw, 8, 8)


def test_edit_events_tables_in_tick_then_bot_order():
    from solaris_env.engine.minecraft.records import edit_events

    rows = {"Alpha": [row(0), row(1, events={"placed": [[1, 5, 2, "oak_planks"]], "hits": ["Bravo"]}), row(2)],
            "Bravo": [row(0, events={"mined": [[3, 4, 3, "grass_block"]]}), row(1), row(2, events={"hits": ["Alpha"]})]}
    blocks, hits = edit_events(rows, 2)  # tick 2 is past num_ticks
    assert blocks == {"tick": [0, 1], "player": ["Bravo", "Alpha"], "action": ["mine", "place"], "x": [3, 1],
                      "y": [4, 5], "z": [3, 2], "block": ["grass_block", "oak_planks"]}
    assert hits == {"tick": [1], "attacker": ["Alpha"], "victim": ["Bravo"]}


def _collect_args(**kw):
    import argparse

    base = dict(out="/tmp/x", seed=0, eval=False, eval_types=None, types=None, episodes=4, instances=1,
                instance_offset=0, test_fraction=0.0, resolution=(64, 64))
    return argparse.Namespace(**{**base, **kw})


def test_minecraft_jobs_cover_the_implemented_types_and_name_unknown_ones():
    from solaris_env.engine.cli import minecraft_jobs
    from solaris_env.engine.eval_protocol import EVAL_KEYS
    from solaris_env.engine.minecraft.collect import EVAL_TYPES, SPAWN, TRAINING_TYPES

    assert sorted(EVAL_TYPES) == sorted(EVAL_KEYS)  # all 7 eval types
    assert set(TRAINING_TYPES) >= {"walkLook", "walkLookAway", "chase", "orbit", "straightLineWalk", "pvp",
                                   "buildStructure", "buildTower", "placeAndMine", "mine"}
    assert SPAWN["structureEval"] == (6.0, 6.0) and SPAWN["pvp"] == (8.0, 15.0)
    jobs = minecraft_jobs(_collect_args(episodes=len(TRAINING_TYPES)))
    assert [j.episode_type for j in jobs] == list(TRAINING_TYPES)
    jobs = minecraft_jobs(_collect_args(eval=True, episodes=2))
    assert sorted({j.eval_type for j in jobs}) == sorted(EVAL_TYPES) and len(jobs) == 2 * len(EVAL_TYPES)
    with pytest.raises(SystemExit, match=r"training types \['pve'\] are not implemented"):
        minecraft_jobs(_collect_args(types=["walkLook", "pve"]))
    with pytest.raises(SystemExit, match=r"eval types \['nopeEval'\] are not implemented"):
        minecraft_jobs(_collect_args(eval=True, eval_types=["nopeEval"]))
