"""``engine.bots.training_episodes``: the 14 training episode types (docs/engine.md §5): each runs to its end on both
world kinds, records well-formed actions for both players, and does what its type is about (move, build, mine, fight);
sampling weights and spawn distances match the §5.2 table; episodes are deterministic."""

import functools
import json

import numpy as np
import pytest

from solaris_env.engine.blocks import Block
from solaris_env.engine.bots import registry
from solaris_env.engine.bots.runner import NOON_TICKS, PRE_ROLL_TICKS, EpisodeConfig, run_episode
from solaris_env.engine.bots.training_episodes import building, mining

WORLD_KINDS = ("flat", "normal")
MAX_CAMERA_RAD = 0.15 + 1e-5  # per-tick rotation cap (3 rad/s); float32 camera round trip
IDLE_TICKS = 20

# docs/engine.md §5.2: type -> (category, typical s, P %, spawn min, spawn max)
SPEC_TABLE = {
    "buildHouse": ("Building", 120, 3.44, 10, 20),
    "buildStructure": ("Building", 15, 9.73, 8, 15),
    "buildTower": ("Building", 12, 10.87, 8, 15),
    "chase": ("Movement", 10, 11.91, 10, 15),
    "collector": ("Mining", 150, 3.08, 0, 15),
    "mine": ("Mining", 10, 11.91, 10, 15),
    "orbit": ("Movement", 60, 4.86, 10, 15),
    "placeAndMine": ("Mining", 120, 3.44, 4, 8),
    "pve": ("Combat", 60, 4.86, 15, 25),
    "pvp": ("Combat", 15, 9.73, 8, 15),
    "straightLineWalk": ("Movement", 20, 8.42, 10, 15),
    "towerBridge": ("Building", 22, 8.03, 12, 20),
    "walkLook": ("Movement", 60, 4.86, 10, 15),
    "walkLookAway": ("Movement", 60, 4.86, 10, 15),
}
WEIGHT_TOLERANCE = 0.0005  # +-0.05 percentage points
BUILDING = ("buildHouse", "buildStructure", "buildTower", "towerBridge")
MINING = ("mine", "collector", "placeAndMine")
COMBAT = ("pvp", "pve")
MIN_WALK = {"chase": 10.0, "orbit": 5.0, "straightLineWalk": 8.0}  # blocks the walker moves at least
SEED = 0
SEEDS = (0, 1)
DETERMINISM_TYPES = ("buildStructure", "pvp", "placeAndMine", "towerBridge")


@functools.lru_cache(maxsize=None)
def _run(etype: str, world_kind: str, seed: int = SEED):
    return run_episode(EpisodeConfig(seed=seed, episode=seed, world_kind=world_kind, episode_type=etype))


def _events(out, kind: str) -> list[tuple[int, int, int, int]]:
    """All placed or mined (x, y, z, block) edits of both players."""
    return [edit for tick in out.tick_events for ev in tick for edit in getattr(ev, kind)]


def _flag_count(out, key: str) -> int:
    return sum(rec["action"][key] for recs in out.trace.records for rec in recs)


# ---------------------------------------------------------------------------------------------
# Registry and sampling weights
# ---------------------------------------------------------------------------------------------


def test_all_fourteen_types_registered_with_spec_table():
    assert registry.training_types() == sorted(SPEC_TABLE)
    for name, (category, typical, _, dmin, dmax) in SPEC_TABLE.items():
        spec = registry.get(name)
        assert (spec.category, spec.typical_s, spec.spawn_min, spec.spawn_max) == (category, typical, dmin, dmax), name
        assert not spec.is_eval and spec.world is None


def test_sampling_weights_match_spec_percentages():
    weights = registry.sampling_weights()
    assert set(weights) == set(SPEC_TABLE)
    for name, row in SPEC_TABLE.items():
        assert abs(weights[name] - row[2] / 100) <= WEIGHT_TOLERANCE, (name, weights[name], row[2])
    assert abs(sum(weights.values()) - 1.0) < 1e-9


# ---------------------------------------------------------------------------------------------
# Every type on both world kinds
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("world_kind", WORLD_KINDS)
@pytest.mark.parametrize("etype", sorted(SPEC_TABLE))
def test_episode_finishes_with_well_formed_records(etype, world_kind, seed):
    out = _run(etype, world_kind, seed)
    assert not out.aborted, out.abort_reason
    assert out.episode_type == etype
    assert not any(info["encountered_error"] or info["peer_encountered_error"] for info in out.infos)
    n = out.trace.num_ticks
    assert n < registry.get(etype).max_s * 20
    assert [len(recs) for recs in out.trace.records] == [n, n]
    for recs in out.trace.records:
        for rec in recs[:IDLE_TICKS]:
            action = rec["action"]
            assert action["camera"] == [0.0, 0.0]
            assert not any(v for k, v in action.items() if k != "camera")
        camera = np.array([rec["action"]["camera"] for rec in recs])
        assert np.abs(camera).max() <= MAX_CAMERA_RAD


@pytest.mark.parametrize("world_kind", WORLD_KINDS)
@pytest.mark.parametrize("etype", BUILDING)
def test_building_types_place_blocks(etype, world_kind):
    out = _run(etype, world_kind)
    placed = _events(out, "placed")
    assert len(placed) >= 1
    assert _flag_count(out, "place_block") == len(placed)
    assert sum(out.world.get(x, y, z) == b for x, y, z, b in placed) >= 1


@pytest.mark.parametrize("world_kind", WORLD_KINDS)
@pytest.mark.parametrize("etype", MINING)
def test_mining_types_remove_blocks(etype, world_kind):
    out = _run(etype, world_kind)
    mined = [m for m in _events(out, "mined") if m[3] != Block.TORCH]
    assert len(mined) >= 1
    assert _flag_count(out, "mine") >= len(mined)
    assert any(out.world.get(x, y, z) == Block.AIR for x, y, z, _ in mined)


@pytest.mark.parametrize("world_kind", WORLD_KINDS)
@pytest.mark.parametrize("etype", COMBAT)
def test_combat_types_hit_each_other(etype, world_kind):
    out = _run(etype, world_kind)
    hits = [ev.hit_player for tick in out.tick_events for ev in tick if ev.hit_player is not None]
    assert len(hits) >= 1
    assert _flag_count(out, "attack") == len(hits)
    assert set(hits) == {0, 1}  # both bots land hits


@pytest.mark.parametrize("world_kind", WORLD_KINDS)
@pytest.mark.parametrize("etype", sorted(MIN_WALK))
def test_movement_types_move_the_walker(etype, world_kind):
    feet = _run(etype, world_kind).trace.feet_TP3
    moved = np.linalg.norm((feet - feet[0])[:, :, [0, 2]], axis=-1).max(axis=0)  # (P,) farthest from spawn
    assert moved.max() >= MIN_WALK[etype]


def test_mine_ends_underground_near_each_other():
    out = _run("mine", "flat")
    feet = out.trace.feet_TP3
    assert np.all(feet[-1, :, 1] < feet[0, :, 1] - 1.0)  # both dug below their spawn
    assert np.linalg.norm(feet[-1, 0] - feet[-1, 1]) <= 2 * mining.MINE_RADIUS + 0.5


def test_build_house_has_its_block_counts_on_flat_ground():
    placed = _events(_run("buildHouse", "flat"), "placed")
    counts = {b: sum(p[3] == b for p in placed) for b in (building.HOUSE_FLOOR, building.HOUSE_WALL,
                                                          building.HOUSE_ROOF)}
    assert counts == {building.HOUSE_FLOOR: len(building._house_floor()),
                      building.HOUSE_WALL: len(building._house_walls()),
                      building.HOUSE_ROOF: len(building._house_roof())}


def test_place_and_mine_miner_digs_what_the_builder_placed():
    out = _run("placeAndMine", "flat")
    placed = {(x, y, z) for x, y, z, _ in _events(out, "placed")}
    mined = {(x, y, z) for x, y, z, _ in _events(out, "mined")}
    assert placed and placed == mined


def test_abort_sets_error_flags_for_both_bots(monkeypatch):
    monkeypatch.setattr(mining, "_find_site", lambda *args: None)  # placeAndMine: "no location" abort
    out = run_episode(EpisodeConfig(seed=SEED, world_kind="flat", episode_type="placeAndMine"))
    assert out.aborted and "no location" in out.abort_reason
    assert any(info["encountered_error"] for info in out.infos)
    assert all(info["encountered_error"] or info["peer_encountered_error"] for info in out.infos)
    assert [len(recs) for recs in out.trace.records] == [out.trace.num_ticks] * 2


@pytest.mark.parametrize("etype", DETERMINISM_TYPES)
def test_same_config_gives_identical_records(etype):
    first = _run(etype, "normal")
    again = run_episode(EpisodeConfig(seed=SEED, episode=SEED, world_kind="normal", episode_type=etype))
    assert json.dumps(first.trace.records) == json.dumps(again.trace.records)
    assert first.trace.edits == again.trace.edits


def test_sampled_type_uses_the_shared_rng():
    out = run_episode(EpisodeConfig(seed=3, episode=7, world_kind="flat"))
    assert out.episode_type in SPEC_TABLE
    assert out.trace.num_ticks > PRE_ROLL_TICKS


# ---------------------------------------------------------------------------------------------
# lookAround (ours, opt-in)
# ---------------------------------------------------------------------------------------------


def test_look_around_is_opt_in():
    assert registry.opt_in_training_types() == ["approach", "lookAround", "roam"]
    assert "lookAround" not in registry.training_types() and "lookAround" not in registry.sampling_weights()
    assert registry.sampling_weights(["lookAround"]) == {"lookAround": 1.0}  # named: the only type sampled


@pytest.mark.parametrize("world_kind", WORLD_KINDS)
def test_look_around_turns_often_at_varied_rates(world_kind):
    """Camera turns on a large share of ticks, with rates spread over the whole per-tick range and both
    directions, starting and stopping often (so a clip's past does not predict its turns); pitch bounded."""
    out = _run("lookAround", world_kind)
    assert not out.aborted, out.abort_reason
    for recs in out.trace.records:
        camera = np.array([rec["action"]["camera"] for rec in recs[IDLE_TICKS:]])
        yaw = camera[:, 0] if np.abs(camera[:, 0]).sum() >= np.abs(camera[:, 1]).sum() else camera[:, 1]
        turning = np.abs(yaw) > 1e-6
        assert 0.3 < turning.mean() < 0.9
        assert np.abs(camera).max() <= MAX_CAMERA_RAD
        assert (yaw > 0).sum() > 20 and (yaw < 0).sum() > 20
        assert np.percentile(np.abs(yaw[turning]), 90) > 3 * np.percentile(np.abs(yaw[turning]), 10)
        assert np.count_nonzero(np.diff(turning.astype(int))) > 40  # onsets and stops
        assert max(abs(rec["pitch"]) for rec in recs) <= np.radians(30.0) + 0.2  # look_at_player may exceed a bit


# ---------------------------------------------------------------------------------------------
# approach (ours, opt-in)
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("world_kind", WORLD_KINDS)
def test_approach_comes_within_two_blocks_three_times_and_backs_off(world_kind):
    """Three rounds: the players meet (feet <= 2 blocks apart, the stop radius) and part (>= 4 blocks) again."""
    out = _run("approach", world_kind)
    assert not out.aborted, out.abort_reason
    xz = [np.array([[rec["x"], rec["z"]] for rec in recs]) for recs in out.trace.records]
    n = min(len(a) for a in xz)
    dist = np.hypot(*(xz[0][:n] - xz[1][:n]).T)
    assert dist[0] >= 6.0 - 1e-6  # the type's spawn distance
    close, far = dist <= 2.0, dist >= 4.0
    meetings = np.count_nonzero(np.diff(close.astype(int)) == 1)
    assert meetings >= 3 and far[-40:].any()
    assert registry.EPISODES["approach"].in_default_mix is False



# ---------------------------------------------------------------------------------------------
# Time of day (EpisodeConfig.time_of_day)
# ---------------------------------------------------------------------------------------------


def test_day_episodes_start_at_noon_and_play_the_same_as_the_cycle():
    cycle = _run("buildStructure", "flat", 1)  # seed 1 draws a night-time start
    day = run_episode(EpisodeConfig(seed=1, episode=1, world_kind="flat", episode_type="buildStructure",
                                    time_of_day="day"))
    age_cycle = [rec["worldAgeTicks"] for rec in cycle.trace.records[0]]
    age_day = [rec["worldAgeTicks"] for rec in day.trace.records[0]]
    assert age_day == list(range(NOON_TICKS, NOON_TICKS + len(age_day)))
    strip = lambda out: [{k: v for k, v in rec.items() if k != "worldAgeTicks"} for recs in out.trace.records
                         for rec in recs]
    assert strip(day) == strip(cycle)  # only the clock differs: the same world, bots and actions
    assert np.all(np.asarray(day.trace.daylight_T) == 1.0) and max(cycle.trace.daylight_T) < 0.5


def test_time_of_day_names_its_values():
    with pytest.raises(ValueError, match="time_of_day must be one of"):
        EpisodeConfig(seed=0, time_of_day="night")


# ---------------------------------------------------------------------------------------------
# roam (ours, opt-in)
# ---------------------------------------------------------------------------------------------


def _held_runs(keys_T: np.ndarray) -> list[int]:
    """Lengths (ticks) of the runs of an unchanged key set."""
    change = np.flatnonzero(np.any(keys_T[1:] != keys_T[:-1], axis=1)) + 1
    return np.diff(np.concatenate([[0], change, [len(keys_T)]])).tolist()


@pytest.mark.parametrize("world_kind", WORLD_KINDS)
def test_roam_holds_step_actions_for_many_steps_and_walks(world_kind):
    """Key sets held for >= 4 steps of 4 ticks on most ticks, every WASD key used (by the two players together), the
    camera still on a good share of the walking ticks and turning both ways on others (within the per-tick cap), and
    the players really move."""
    out = _run("roam", world_kind)
    assert not out.aborted, out.abort_reason
    assert registry.EPISODES["roam"].in_default_mix is False
    used = np.zeros(4, int)
    for recs in out.trace.records:
        recs = recs[IDLE_TICKS:]
        keys = np.array([[rec["action"][k] for k in ("forward", "back", "left", "right", "sprint", "jump")]
                         for rec in recs], int)
        runs = np.array(_held_runs(keys))
        assert runs[runs >= 16].sum() > 0.6 * len(recs)
        used += keys[:, :4].sum(axis=0)
        camera = np.array([rec["action"]["camera"] for rec in recs])
        assert np.abs(camera).max() <= MAX_CAMERA_RAD
        turning = np.abs(camera).sum(axis=1) > 1e-6
        walking = keys[:, :4].any(axis=1)
        assert 0.3 < 1 - turning[walking].mean() < 0.9
        yaw = camera[:, 0] if np.abs(camera[:, 0]).sum() >= np.abs(camera[:, 1]).sum() else camera[:, 1]
        assert (yaw > 0).sum() > 20 and (yaw < 0).sum() > 20
        xz = np.array([[rec["x"], rec["z"]] for rec in recs])
        assert np.hypot(*np.diff(xz, axis=0).T).sum() > 50.0
    assert (used > 16).all(), used  # both players together use every WASD key
