"""``solaris_env.tasks``: the registry and its errors; the visual-novelty, see-other-player, partner (face / approach)
and building tasks: ground-truth rewards in real-env states, the judge variants agreeing with the truth on engine
frames, and which variant runs in which env (judge: both envs; truth: the real env only)."""

import numpy as np
import pytest
import torch

from solaris_env.judges.config import ProbeConfig
from solaris_env.spaces import noop
from solaris_env.tasks import (
    JUDGED_TASKS,
    PARTNER_TASKS,
    ApproachPartnerTask,
    BuildStructureTask,
    FacePartnerTask,
    NoTask,
    SeeOtherPlayerTask,
    VisualNoveltyTask,
    make_task,
)

torch.set_num_threads(1)  # docs/model.md §10.2: the judges' small torch ops are far faster single-threaded on these VMs

JUDGE_SIZE = ProbeConfig().image_size  # judge-vs-truth checks render at the probes' input size


@pytest.fixture
def real():
    """``real(**kw)`` -> a two-player RealParallelEnv, 36x36 unless given, at the env's default view distance (the
    partner and building tasks are checked on what a policy sees; overrides ``conftest.real``'s short view)."""
    from solaris_env.real_env import RealParallelEnv

    def make(**kw):
        kw.setdefault("resolution", 36)
        return RealParallelEnv(num_players=2, **kw)

    return make


def turn(dyaw_deg: float, **keys) -> dict:
    a = noop()
    a["camera"] = np.array([0.0, dyaw_deg], np.float32)
    a.update(keys)
    return a


def turn_fully(env, dyaw_deg: float):
    """Alpha turns by ``dyaw_deg``, Bravo stands; steps on until the whole turn is made (the engine turns at most
    8.59 deg a tick and carries the rest over, ``spaces.step_ticks``); returns the last step's outputs."""
    out = env.step({"Alpha": turn(dyaw_deg), "Bravo": noop()})
    while out[4]["Alpha"]["camera_pending"].any():
        out = env.step({"Alpha": noop(), "Bravo": noop()})
    return out


def test_task_registry_and_errors():
    assert isinstance(make_task(None), NoTask) and isinstance(make_task("visual_novelty"), VisualNoveltyTask)
    assert isinstance(make_task(SeeOtherPlayerTask), SeeOtherPlayerTask)
    given = VisualNoveltyTask(threshold=0.1)
    copy = make_task(given)
    assert copy is not given and copy.threshold == 0.1
    with pytest.raises(ValueError, match="unknown task"):
        make_task("win")
    with pytest.raises(ValueError, match="task must be"):
        make_task(3)
    with pytest.raises(ValueError, match="threshold"):
        VisualNoveltyTask(threshold=1.5)
    with pytest.raises(ValueError, match="ground truth"):
        SeeOtherPlayerTask().step(np.zeros((2, 1, 8, 8, 3), np.uint8), [noop(), noop()], truth=None)


def test_see_other_player_task_uses_ground_truth(real):
    env = real(resolution=64, view_distance=48.0, task="see_other_player")
    env.reset(seed=0)  # spawned facing each other
    _, rewards, *_ = env.step({a: noop() for a in env.agents})
    assert rewards == {"Alpha": 1.0, "Bravo": 1.0}
    for _ in range(6):  # Alpha turns 180 degrees away (at 8.59 deg per tick: the rest is carried over)
        _, rewards, _, _, infos = env.step({"Alpha": turn(30.0), "Bravo": noop()})
    while infos["Alpha"]["camera_pending"].any():
        _, rewards, _, _, infos = env.step({"Alpha": noop(), "Bravo": noop()})
    assert rewards == {"Alpha": 0.0, "Bravo": 1.0}
    assert infos["Alpha"]["sees"] == {"Bravo": False}


def test_visual_novelty_rewards_new_views_only(real):
    # a hilly world with trees: a flat world looks the same in every direction (distances < 0.02)
    # 4 ticks a step: a 30 deg turn fits in one step (at most 8.59 deg a tick; spaces.CAMERA_TICK_LIMIT_DEG)
    env = real(resolution=64, view_distance=48.0, world="normal", task="visual_novelty", ticks_per_step=4)
    env.reset(seed=1)
    _, rewards, *_ = env.step({a: noop() for a in env.agents})
    assert rewards == {"Alpha": 0.0, "Bravo": 0.0}  # nothing moved: the same view
    gained = []
    for _ in range(6):  # Alpha turns to new directions
        _, rewards, *_ = env.step({"Alpha": turn(30.0), "Bravo": noop()})
        gained.append(rewards["Alpha"])
        assert rewards["Bravo"] == 0.0
    assert sum(r > 0 for r in gained) >= 4
    back = []
    for _ in range(6):  # and back over views it has seen
        _, rewards, *_ = env.step({"Alpha": turn(-30.0), "Bravo": noop()})
        back.append(rewards["Alpha"])
    assert sum(back) < 0.25 * sum(gained)


def test_visual_novelty_target_terminates_and_memory_is_a_ring():
    task = VisualNoveltyTask(threshold=0.01, memory=3, target=2)
    rng = np.random.default_rng(0)
    task.reset(np.zeros((2, 16, 16, 3), np.uint8))
    frames = rng.integers(0, 256, (2, 1, 16, 16, 3), dtype=np.uint8)
    out = task.step(frames, [noop(), noop()])
    assert (out.rewards_P > 0).all() and not out.terminations_P.any()
    out = task.step(frames, [noop(), noop()])  # the same view again: nothing new
    assert (out.rewards_P == 0).all()
    out = task.step(rng.integers(0, 256, (2, 1, 16, 16, 3), dtype=np.uint8), [noop(), noop()])
    assert out.terminations_P.all()
    for _ in range(3):
        task.step(rng.integers(0, 256, (2, 1, 16, 16, 3), dtype=np.uint8), [noop(), noop()])
    assert task.distance_to_memory(np.zeros((2, 8, 8, 3), np.float32)).min() > 0.01  # black view forgotten


def test_face_partner_truth_is_one_when_the_partner_is_centred(real):
    env = real(task="face_partner_truth")
    _, infos = env.reset(seed=0)  # a constructed state: the players spawn facing each other
    for a in env.agents:
        screen = infos[a]["screen"]
        (partner,) = screen.values()
        assert partner["pixels"] >= 2 and abs(partner["u"] - 0.5) < 0.05
    _, rewards, terminations, _, _ = env.step({a: noop() for a in env.agents})
    assert rewards == {"Alpha": 1.0, "Bravo": 1.0} and not any(terminations.values())
    _, rewards, _, _, infos = turn_fully(env, 35.0)  # partner pushed to the left third
    assert rewards == {"Alpha": 0.0, "Bravo": 1.0}
    assert infos["Alpha"]["screen"]["Bravo"]["u"] < 1 / 3
    _, rewards, _, _, infos = turn_fully(env, 150.0)  # behind
    assert rewards["Alpha"] == 0.0 and infos["Alpha"]["screen"]["Bravo"] == {"pixels": 0, "u": None}


def test_face_partner_judge_agrees_with_the_truth_on_engine_frames(real):
    env = real(resolution=JUDGE_SIZE, task="face_partner_truth")
    judge_task = FacePartnerTask(source="judge")
    agree, total = 0, 0
    for seed in (1, 2):
        env.reset(seed=seed)
        judge_task.reset(env.step_frames()[:, 0])
        for dyaw in (0.0, 0.0, 45.0, 90.0, -180.0):  # centred, centred, off to the side, gone, back
            _, rewards, *_ = env.step({"Alpha": turn(dyaw), "Bravo": noop()})
            by_judge = judge_task.step(env.step_frames(), None).rewards_P
            agree += int(by_judge[0] == rewards["Alpha"]) + int(by_judge[1] == rewards["Bravo"])
            total += 2
    assert agree >= total - 2, f"judge and truth agree on {agree}/{total} rewards"


def test_approach_partner_truth_rewards_closing_in_and_punishes_backing_off(real):
    env = real(task="approach_partner_truth", ticks_per_step=4)
    env.reset(seed=0)  # facing each other 6-10 blocks apart
    closer = [env.step({"Alpha": turn(0.0, forward=1), "Bravo": noop()})[1]["Alpha"] for _ in range(5)]
    assert closer[0] == 0.0 and closer[1:] == [1.0] * 4  # the first step moves < the threshold
    env.reset(seed=0)
    farther = [env.step({"Alpha": turn(0.0, back=1), "Bravo": noop()})[1]["Alpha"] for _ in range(5)]
    assert sum(farther) <= -3
    env.reset(seed=0)
    env.step({"Alpha": turn(180.0), "Bravo": noop()})  # turn away: the partner is out of sight
    unseen = [env.step({"Alpha": turn(0.0, forward=1), "Bravo": noop()})[1]["Alpha"] for _ in range(5)]
    assert unseen[2:] == [0.0] * 3  # walking away unseen: neither judge nor truth can score it


def test_approach_partner_compares_with_the_frame_gap_steps_back():
    task = ApproachPartnerTask(source="truth", gap=2)
    def truth(distance):  # Alpha at x = 0, Bravo at x = distance; both see each other
        seen = {"pixels": 10, "u": 0.5}
        return [{"pos": np.zeros(3), "screen": {"Bravo": seen}},
                {"pos": np.array([distance, 0.0, 0.0]), "screen": {"Alpha": seen}}]
    frames = np.zeros((2, 1, 8, 8, 3), np.uint8)
    task.reset(frames[:, 0], truth(10.0))
    # step t compares d_t with d_(t-2) (d_0 early on), threshold |ln ratio| >= 0.15: 9.5 vs 10 (-0.05), 9 vs 10
    # (-0.11), 8 vs 9.5 (-0.17: closer), 7 vs 9 (-0.25: closer), 7 vs 8 (-0.13)
    rewards = [task.step(frames, [noop(), noop()], truth(d)).rewards_P.tolist() for d in (9.5, 9.0, 8.0, 7.0, 7.0)]
    assert rewards == [[0, 0], [0, 0], [1, 1], [1, 1], [0, 0]]


def test_approach_partner_truth_is_the_motion_judges_labelling_rule():
    task = ApproachPartnerTask(source="truth", gap=1)
    def truth(distance, u, pixels=10):  # Alpha at x = 0 looking along -z, Bravo at x = distance
        seen = {"pixels": pixels, "u": u if pixels else None}
        return [{"pos": np.zeros(3), "yaw": 0.0, "pitch": 0.0, "screen": {"Bravo": seen}},
                {"pos": np.array([distance, 0.0, 0.0]), "yaw": 0.0, "pitch": 0.0, "screen": {"Alpha": seen}}]
    frames = np.zeros((2, 1, 8, 8, 3), np.uint8)
    def reward(then, now):
        task.reset(frames[:, 0], truth(*then))
        return task.step(frames, [noop(), noop()], truth(*now)).rewards_P[0]
    assert reward((10.0, 0.5), (8.0, 0.5)) == 1.0  # radial alone: closer
    assert reward((8.0, 0.5), (10.0, 0.52)) == -1.0  # radial dominates a small drift: farther
    assert reward((10.0, 0.5), (8.0, 0.9)) == 0.0  # the partner swept across the screen: lateral dominates
    assert reward((10.0, 0.5), (8.0, 0.6)) == 0.0  # neither dominates (radial -1.5, lateral 1.25): ambiguous
    assert reward((1.0, 0.5, 0), (0.5, 0.5, 0)) == 0.0  # pressed against the partner, no avatar on screen


def test_approach_partner_judge_scores_only_pairs_with_the_partner_on_both_screens(real):
    """A partner seen, then gone off screen (Alpha turned away) earns 0 whatever the motion probe says of the
    pair: the truth's rule has no motion answer without the partner's position in both frames."""
    from solaris_env.tasks import shared_judge

    env = real(resolution=JUDGE_SIZE, ticks_per_step=4)
    obs, _ = env.reset(seed=0)  # facing each other 6-10 blocks apart
    seen = np.stack([obs[a] for a in env.possible_agents])
    obs = turn_fully(env, 180.0)[0]
    gone = np.stack([obs[a] for a in env.possible_agents])
    assert shared_judge().answer("visible", np.stack([seen[0], gone[0]])) == ["yes", "no"]
    task = ApproachPartnerTask(source="judge", gap=1)
    task.reset(seen)
    assert task.step(gone[:, None], [noop(), noop()]).rewards_P[0] == 0.0


def test_registry_names_and_sources():
    for name, cls in JUDGED_TASKS.items():
        judge, truth = make_task(name), make_task(f"{name}_truth")
        assert isinstance(judge, cls) and judge.source == "judge" and not judge.requires_truth and judge.name == name
        assert isinstance(truth, cls) and truth.source == "truth" and truth.requires_truth
        assert truth.name == f"{name}_truth"
    with pytest.raises(ValueError, match="source must be one of"):
        FacePartnerTask(source="oracle")
    with pytest.raises(ValueError, match="judge_dir"):
        FacePartnerTask(source="truth", judge_dir="x")
    with pytest.raises(ValueError, match="gap"):
        ApproachPartnerTask(gap=0)
    with pytest.raises(ValueError, match="source='truth'.*ground truth"):
        task = FacePartnerTask(source="truth")
        task.reset(np.zeros((2, 8, 8, 3), np.uint8))
        task.step(np.zeros((2, 1, 8, 8, 3), np.uint8), [noop(), noop()], truth=None)


@pytest.mark.parametrize("players", [1, 3])
def test_partner_tasks_need_two_players(players):
    for cls in PARTNER_TASKS.values():
        with pytest.raises(ValueError, match="num_players=2"):
            cls(source="truth").reset(np.zeros((players, 8, 8, 3), np.uint8))


def test_dream_env_runs_the_judge_tasks_and_refuses_the_truth_ones(model):
    from solaris_env.dream_env import DreamParallelEnv

    for name in JUDGED_TASKS:
        env = DreamParallelEnv(model=model, task=name, max_steps=4)
        env.reset(seed=0)
        for _ in range(4):
            _, rewards, *_ = env.step({a: turn(10.0, forward=1) for a in env.agents})
            assert set(rewards) == {"Alpha", "Bravo"} and all(r in (-1.0, 0.0, 1.0) for r in rewards.values())
        with pytest.raises(ValueError, match="ground truth"):
            DreamParallelEnv(model=model, task=f"{name}_truth")


def look(pitch_deg: float = 0.0, yaw_deg: float = 0.0, **keys) -> dict:
    a = noop()
    a["camera"] = np.array([pitch_deg, yaw_deg], np.float32)
    a.update(keys)
    return a


def look_fully(env, pitch_deg: float = 0.0, yaw_deg: float = 0.0, **keys) -> tuple[dict, dict]:
    """Alpha turns by (pitch, yaw) -- over as many steps as the per-tick turn limit needs (docs/actions.md
    section 5) -- while Bravo idles; the last step's rewards and infos."""
    _, rewards, _, _, infos = env.step({"Alpha": look(pitch_deg, yaw_deg, **keys), "Bravo": look()})
    while np.any(infos["Alpha"]["camera_pending"]):
        _, rewards, _, _, infos = env.step({"Alpha": look(), "Bravo": look()})
    return rewards, infos


def test_truth_rewards_a_placed_block_in_view_for_every_player_who_sees_it(real):
    env = real(task="build_structure_truth")
    env.reset(seed=0)  # facing each other on flat ground, nothing built
    rewards, _ = look_fully(env, 30.0, **{"hotbar.1": 1})  # look down, pick blocks
    assert rewards == {"Alpha": 0.0, "Bravo": 0.0}
    _, rewards, _, _, infos = env.step({"Alpha": look(use=1), "Bravo": look()})
    assert len(infos["Alpha"]["placed"]) == 1
    assert rewards == {"Alpha": 1.0, "Bravo": 1.0}  # Alpha's block stands between the two
    rewards, _ = look_fully(env, yaw_deg=180.0)
    assert rewards == {"Alpha": 0.0, "Bravo": 1.0}  # Alpha turned its back on it
    rewards, _ = look_fully(env, yaw_deg=180.0)
    assert rewards == {"Alpha": 1.0, "Bravo": 1.0}
    env.reset(seed=0)  # a new episode forgets the built blocks
    rewards, _ = look_fully(env, 30.0)
    assert rewards == {"Alpha": 0.0, "Bravo": 0.0}


def build_truth(placed=(), mined=(), yaw=0.0):
    """One player at the origin looking along -Z (yaw 0, level)."""
    return [{"pos": np.zeros(3), "yaw": yaw, "pitch": 0.0, "placed": list(placed), "mined": list(mined)}]


def test_truth_counts_blocks_built_minus_mined_within_the_structure_distance():
    task = BuildStructureTask(source="truth")
    frames = np.zeros((1, 1, 8, 8, 3), np.uint8)
    task.reset(frames[:, 0], build_truth())
    reward = lambda **kw: task.step(frames, [noop()], build_truth(**kw)).rewards_P.tolist()
    assert reward() == [0.0]
    assert reward(placed=[(0, 1, -6, 3)]) == [1.0]  # 6 blocks ahead at eye level (x, y, z, block id)
    assert reward() == [1.0]  # still there
    assert reward(yaw=np.pi) == [0.0]  # looking away
    assert reward(mined=[(0, 1, -6, 3)]) == [0.0]  # gone
    assert reward(placed=[(0, 1, -30, 3)]) == [0.0]  # beyond LabelConfig.structure_max_distance (16)
    task.reset(frames[:, 0], build_truth())
    assert reward() == [0.0]
