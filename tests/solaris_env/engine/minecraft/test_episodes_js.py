"""``engine/minecraft/episodes.js`` (the real-Minecraft choreographies) against the voxel engine's bots: the same look
profiles, spawn plans and items (Node only, no server; skipped unless the backend's node_modules are installed)."""

import json
import math
import subprocess

import pytest

from solaris_env.engine.bots.controller import rotation_profile
from solaris_env.engine.minecraft import NODE_DIR
from solaris_env.engine.minecraft.install import setup_problem

PROBLEM = setup_problem()
pytestmark = [pytest.mark.minecraft,
              pytest.mark.skipif(PROBLEM is not None, reason=f"Minecraft backend not set up ({PROBLEM})")]


def _node(expr: str):
    """Evaluate a JS expression with episodes.js loaded as E; returns its JSON value."""
    script = f"const E = require('./episodes'); process.stdout.write(JSON.stringify({expr}))"
    out = subprocess.run(["node", "-e", script], cwd=NODE_DIR, capture_output=True, text=True, timeout=60, check=True)
    return json.loads(out.stdout)


@pytest.mark.parametrize("total,speed,easing", [(40.0, math.degrees(3.0), False), (-180.0, math.degrees(3.0), False),
                                                (108.7, 60.0, True), (-3.0, 90.0, False), (0.05, 60.0, True)])
def test_look_profiles_match_the_voxel_engine(total, speed, easing):
    js = _node(f"E.rotationProfile({total}, {speed}, {str(easing).lower()})")
    assert js == pytest.approx(rotation_profile(total, speed, easing), abs=1e-9)


def test_spawn_plans_and_items():
    cfg = "{names: ['Alpha', 'Bravo'], spawnMin: 10, spawnMax: 12}"
    plans = _node(f"[0, 1, 2, 3].map(k => E.planEpisode('rotationEval', {cfg}, () => (k + 0.5) / 4))")
    for plan in plans:
        (ax, az), (bx, bz) = plan["spots"]
        assert 9.5 <= math.hypot(bx - ax, bz - az) <= 12.5  # rounded to whole blocks
        assert [i for i, _ in plan["items"]["Alpha"]] == ["stone", "diamond_pickaxe", "diamond_shovel", "diamond_axe"]
    pam = _node(f"E.planEpisode('placeAndMine', {cfg}, () => 0.3)")
    (ax, az), (bx, bz) = pam["spots"]
    assert math.hypot(bx - ax, bz - az) == 4 and pam["layout"]["builder"] in ("Alpha", "Bravo")
    assert {"oak_planks", "bricks", "dirt", "smooth_sandstone"} <= {i for i, _ in pam["items"]["Alpha"]}
    pvp = _node(f"E.planEpisode('pvp', {cfg}, Math.random)")
    for name in ("Alpha", "Bravo"):
        sword = pvp["layout"]["swords"][name]
        assert pvp["items"][name][-1] == [sword, 1] and sword.endswith("_sword")
    assert sorted(_node("[...E.EVAL_TYPES]")) == sorted(["rotationEval", "translationEval", "oneLooksAwayEval",
                                                         "bothLookAwayEval", "structureEval", "turnToLookEval",
                                                         "turnToLookOppositeEval"])
