"""The building task (``build_structure``): ground-truth rewards from the real env's placed/mined blocks and the
player's pose (the structure judge's labelling rule), and the bookkeeping of built blocks."""

import numpy as np

from solaris_env.spaces import noop
from solaris_env.tasks import BuildStructureTask


def act(pitch_deg: float = 0.0, yaw_deg: float = 0.0, **keys) -> dict:
    a = noop()
    a["camera"] = np.array([pitch_deg, yaw_deg], np.float32)
    a.update(keys)
    return a


def turn(env, pitch_deg: float = 0.0, yaw_deg: float = 0.0, **keys) -> tuple[dict, dict]:
    """Alpha turns by (pitch, yaw) -- over as many steps as the per-tick turn limit needs (docs/actions.md
    section 5) -- while Bravo idles; the last step's rewards and infos."""
    _, rewards, _, _, infos = env.step({"Alpha": act(pitch_deg, yaw_deg, **keys), "Bravo": act()})
    while np.any(infos["Alpha"]["camera_pending"]):
        _, rewards, _, _, infos = env.step({"Alpha": act(), "Bravo": act()})
    return rewards, infos


def test_truth_rewards_a_placed_block_in_view_for_every_player_who_sees_it(real):
    env = real(task="build_structure_truth")
    env.reset(seed=0)  # facing each other on flat ground, nothing built
    rewards, _ = turn(env, 30.0, **{"hotbar.1": 1})  # look down, pick blocks
    assert rewards == {"Alpha": 0.0, "Bravo": 0.0}
    _, rewards, _, _, infos = env.step({"Alpha": act(use=1), "Bravo": act()})
    assert len(infos["Alpha"]["placed"]) == 1
    assert rewards == {"Alpha": 1.0, "Bravo": 1.0}  # Alpha's block stands between the two
    rewards, _ = turn(env, yaw_deg=180.0)
    assert rewards == {"Alpha": 0.0, "Bravo": 1.0}  # Alpha turned its back on it
    rewards, _ = turn(env, yaw_deg=180.0)
    assert rewards == {"Alpha": 1.0, "Bravo": 1.0}
    env.reset(seed=0)  # a new episode forgets the built blocks
    rewards, _ = turn(env, 30.0)
    assert rewards == {"Alpha": 0.0, "Bravo": 0.0}


def truth(placed=(), mined=(), yaw=0.0):
    """One player at the origin looking along -Z (yaw 0, level)."""
    return [{"pos": np.zeros(3), "yaw": yaw, "pitch": 0.0, "placed": list(placed), "mined": list(mined)}]


def test_truth_counts_blocks_built_minus_mined_within_the_structure_distance():
    task = BuildStructureTask(source="truth")
    frames = np.zeros((1, 1, 8, 8, 3), np.uint8)
    task.reset(frames[:, 0], truth())
    reward = lambda **kw: task.step(frames, [noop()], truth(**kw)).rewards_P.tolist()
    assert reward() == [0.0]
    assert reward(placed=[(0, 1, -6, 3)]) == [1.0]  # 6 blocks ahead at eye level (x, y, z, block id)
    assert reward() == [1.0]  # still there
    assert reward(yaw=np.pi) == [0.0]  # looking away
    assert reward(mined=[(0, 1, -6, 3)]) == [0.0]  # gone
    assert reward(placed=[(0, 1, -30, 3)]) == [0.0]  # beyond LabelConfig.structure_max_distance (16)
    task.reset(frames[:, 0], truth())
    assert reward() == [0.0]
