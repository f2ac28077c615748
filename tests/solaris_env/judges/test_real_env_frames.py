"""The shipped ``visible`` / ``position`` judges on the real env's own frames, on every flat surface the partner
tasks start on (the policy evaluation's worlds: grass, snow, sand, red sand), not only the collect's grass."""

import numpy as np
import pytest

from solaris_env.real_env import RealParallelEnv
from solaris_env.spaces import CAMERA_KEY, noop
from solaris_env.tasks import judge_centred, partner_screen, shared_judge

SURFACES = ("plains", "snowy_plains", "desert", "desert_red")


@pytest.fixture(scope="module")
def views():
    """surface -> (frame facing the partner, frame turned 180 degrees away, the partner's truth when facing)."""
    env = RealParallelEnv(num_players=2, world="flat", resolution=64, ticks_per_step=4)
    out = {}
    for seed in range(200):
        obs, infos = env.reset(seed=seed)
        surface = env.game.world.variant
        if surface in out or surface not in SURFACES:
            continue
        facing, truth = obs["Alpha"], partner_screen(infos["Alpha"])
        turn = noop()
        turn[CAMERA_KEY] = np.array([0.0, 20.0], np.float32)
        for _ in range(9):
            obs, *_ = env.step({"Alpha": turn, "Bravo": noop()})
        out[surface] = (facing, obs["Alpha"], truth)
        if len(out) == len(SURFACES):
            break
    assert sorted(out) == sorted(SURFACES), f"resets found only {sorted(out)}"
    return out


@pytest.mark.parametrize("surface", SURFACES)
def test_partner_spawned_ahead_is_seen_centred_and_gone_after_a_half_turn(views, surface):
    facing, away, truth = views[surface]
    assert truth["pixels"] >= 10 and 1 / 3 <= truth["u"] < 2 / 3  # the spawn faces the partner
    judge = shared_judge(None)
    assert judge_centred(judge, facing[None]).tolist() == [True]
    assert judge.answer("visible", away[None]) == ["no"]
