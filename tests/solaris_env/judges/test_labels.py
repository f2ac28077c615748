"""Label extraction: the sidecar gives the paper's expected answers at the judge's query frames, and each
label function behaves as documented on hand-built sidecars (ambiguity bands, thresholds, projection)."""

import math

import numpy as np
import pytest

from solaris_env.judges import labels as L
from solaris_env.judges import questions
from solaris_env.judges.config import LabelConfig
from solaris_env.judges.questions import for_prompt_key
from solaris_env.judges.scoring import query_views

CFG = LabelConfig()
H = W = 64


def label_of(question, gt, views):
    if question == "visible":
        return L.visible_label(gt, *views[0])
    if question == "position":
        return L.position_label(gt, *views[0])
    if question == "motion":
        (bot, f1), (_, f2) = views
        return L.motion_label(gt, bot, f1, f2)
    if question == "structure":
        return L.structure_label(gt, *views[0])
    return L.same_scenery_label(gt, views[0], views[1])


def test_sidecar_labels_equal_the_judges_expected_answers(episodes):
    checked = 0
    for ep in episodes.values():
        queries = ep.queries()
        assert queries, ep.key
        for q in queries:
            question = for_prompt_key(q.prompt_key).name
            assert label_of(question, ep.gt, query_views(q)) == q.expected, (ep.key, q)
            checked += 1
    assert checked >= len(episodes)


def test_projection_matches_the_renderers_avatar_centroid(episodes):
    gt = episodes["rotationEval"].gt
    errs = []
    for f in range(0, gt["num_frames"], 5):
        s = gt["sight"]["Alpha"]["Bravo"]
        if L.pixel_count(gt, "Alpha", "Bravo", f) < 8:
            continue
        pose, other = gt["pose"]["Alpha"], gt["pose"]["Bravo"]
        eye = np.array([pose["x"][f], pose["y"][f] + CFG.eye_height, pose["z"][f]])
        centre = np.array([[other["x"][f], other["y"][f] + 0.9, other["z"][f]]])  # mid-height of the avatar
        u, v, depth = L.project(centre, eye, pose["yaw"][f], pose["pitch"][f])
        assert depth[0] > 0
        errs.append((abs(u[0] - s["u"][f]), abs(v[0] - s["v"][f])))
    errs = np.array(errs)
    assert len(errs) and errs[:, 0].max() < 1.0 / W  # horizontal: within a pixel
    # vertical: the pose has no sneak flag, a sneaking viewer's eye is 0.35 lower (~2 px at 10 blocks)
    assert errs[:, 1].max() < 4.0 / H


# ---------------------------------------------------------------------------------------------
# Hand-built sidecars
# ---------------------------------------------------------------------------------------------


def sidecar(pixels, u=None, distance=None, poses=None, blocks=None):
    """Two players; Bravo as seen by Alpha has ``pixels[t]`` avatar pixels at centroid ``u[t]``."""
    T = len(pixels)
    u = u or [0.5] * T
    distance = distance or [10.0] * T

    def sight(px):
        return {"visible": [p > 0 for p in px], "pixel_fraction": [p / (H * W) for p in px],
                "u": [uu if p else None for uu, p in zip(u, px)], "v": [0.5 if p else None for p in px],
                "distance": distance}

    still = {"x": [0.5] * T, "y": [64.0] * T, "z": [0.5] * T, "yaw": [0.0] * T, "pitch": [0.0] * T}
    return {"num_frames": T, "frame_size": [H, W], "players": ["Alpha", "Bravo"],
            "regions": {"left_max_u": 1 / 3, "right_min_u": 2 / 3},
            "sight": {"Alpha": {"Bravo": sight(pixels)}, "Bravo": {"Alpha": sight([0] * T)}},
            "pose": poses or {"Alpha": still, "Bravo": still},
            "blocks": blocks or {k: [] for k in ("tick", "player", "action", "x", "y", "z", "block")}}


def test_visible_label_has_an_ambiguity_band():
    gt = sidecar([0, 1, CFG.min_visible_pixels, 50])
    assert [L.visible_label(gt, "Alpha", f) for f in range(4)] == ["no", None, "yes", "yes"]
    assert L.visible_label(gt, "Bravo", 3) == "no"


def test_position_label_by_thirds_with_a_margin():
    us = [0.1, 1 / 3 + CFG.region_margin / 2, 0.5, 0.9, 0.5]
    gt = sidecar([20, 20, 20, 20, 0], u=us)
    assert [L.position_label(gt, "Alpha", f) for f in range(5)] == ["left", None, "center", "right", "no player"]


def test_motion_label_directions_still_and_ambiguous():
    d0 = 10.0
    closer, farther = d0 * math.exp(-3 * CFG.motion_log_distance_threshold), d0 * math.exp(3 * CFG.motion_log_distance_threshold)
    lat = 3 * CFG.motion_u_threshold
    gt = sidecar([20] * 7 + [0],
                 u=[0.5, 0.5 + lat, 0.5 - lat, 0.5, 0.5, 0.5 + CFG.motion_u_threshold * 0.1, 0.5 + lat, 0.5],
                 distance=[d0, d0, d0, closer, farther, d0, d0 * math.exp(2.9 * CFG.motion_log_distance_threshold), d0])
    got = [L.motion_label(gt, "Alpha", 0, f) for f in range(1, 8)]
    assert got == ["right", "left", "closer", "farther", "no motion", None, None]  # mixed, then not visible
    # played backwards, every label is the reversed one: what the motion probe's equivariance assumes
    back = dict(questions.get("motion").reverse_answers)
    assert [L.motion_label(gt, "Alpha", f, 0) for f in range(1, 8)] == [back.get(a, a) if a else a for a in got]


def test_structure_label_projects_placed_blocks():
    T = 3
    poses = {"Alpha": {"x": [0.5] * T, "y": [64.0] * T, "z": [0.5] * T, "yaw": [0.0, 0.0, 0.0],
                       "pitch": [0.0] * T}}
    poses["Bravo"] = poses["Alpha"]
    blocks = {"tick": [0, 1], "player": ["Bravo"] * 2, "action": ["place", "place"], "x": [0, 0], "y": [64, 64],
              "z": [-6, -60], "block": ["stone"] * 2}
    gt = sidecar([0] * T, poses=poses, blocks=blocks)
    assert L.placed_blocks(gt, 0) == []
    assert L.structure_label(gt, "Alpha", 0) == "no"  # nothing built yet
    assert L.placed_blocks(gt, 1) == [(0, 64, -6)]
    assert L.structure_label(gt, "Alpha", 1) == "yes"  # yaw 0 looks at -z: 6 blocks ahead
    assert L.structure_label(gt, "Alpha", 2) == "yes"
    gt_far = sidecar([0] * T, poses=poses, blocks={**blocks, "tick": [1, 5], "z": [-60, -6]})
    assert L.structure_label(gt_far, "Alpha", 2) is None  # only the block 60 away is built: on screen, too far
    poses["Alpha"]["yaw"][2] = math.pi
    assert L.structure_label(gt, "Alpha", 2) == "no"  # looking away from both
    mined = {**blocks, "tick": [0, 0, 1], "action": ["place", "place", "mine"], "x": [0, 0, 0], "y": [64] * 3,
             "z": [-6, -60, -6], "block": ["stone"] * 3}
    assert L.placed_blocks(sidecar([0] * T, poses=poses, blocks=mined), 2) == [(0, 64, -60)]


def test_same_scenery_label_from_view_directions_and_separation():
    T = 4
    a = {"x": [0.5] * T, "y": [64.0] * T, "z": [0.5] * T, "yaw": [0.0] * T, "pitch": [0.0] * T}
    b = {"x": [4.5, 4.5, 4.5, 40.5], "y": [64.0] * T, "z": [0.5] * T, "yaw": [0.2, math.pi, math.pi / 2, 0.0],
         "pitch": [0.0] * T}
    gt = sidecar([0] * T, poses={"Alpha": a, "Bravo": b})
    got = [L.same_scenery_label(gt, ("Alpha", f), ("Bravo", f)) for f in range(T)]
    assert got == ["yes", "no", None, None]  # same way; opposite; 90 deg apart; same way but 40 blocks apart
    assert L.view_angle_deg(gt, ("Alpha", 1), ("Bravo", 1)) == pytest.approx(180.0)


def test_label_errors_name_the_problem():
    gt = sidecar([0, 5])
    with pytest.raises(ValueError, match=r"frame must be in \[0, 2\)"):
        L.visible_label(gt, "Alpha", 2)
    with pytest.raises(ValueError, match="viewer 'Charlie'"):
        L.position_label(gt, "Charlie", 0)
    with pytest.raises(ValueError, match="display_aspect"):
        LabelConfig(display_aspect=0.0)


def test_motion_into_the_distance_uses_the_projected_body():
    T = 4
    alpha = {"x": [0.5] * T, "y": [64.0] * T, "z": [0.5] * T, "yaw": [0.0] * T, "pitch": [0.0] * T}
    # Bravo straight ahead (yaw 0 looks at -z): 10 blocks, then 20 (1 pixel), 20 but far off to the side, 10 unseen
    bravo = {"x": [0.5, 0.5, 60.5, 0.5], "y": [64.0] * T, "z": [-9.5, -19.5, -19.5, -9.5], "yaw": [0.0] * T,
             "pitch": [0.0] * T}
    dist = [10.0, 20.0, math.hypot(60, 20), 10.0]
    gt = sidecar([20, 1, 0, 0], distance=dist, poses={"Alpha": alpha, "Bravo": bravo})
    assert dist[1] >= CFG.motion_far_distance > dist[3]
    assert L.motion_label(gt, "Alpha", 0, 1) == "farther"  # walked away until too small to see
    assert L.motion_label(gt, "Alpha", 1, 0) == "closer"
    assert L.motion_label(gt, "Alpha", 0, 2) is None  # gone off screen: no answer
    assert L.motion_label(gt, "Alpha", 0, 3) is None  # near but unseen (occluded): no answer
    assert L.motion_label(gt, "Alpha", 1, 2) is None  # never clearly visible
