"""``solaris_env.minecraft_env`` (MinecraftParallelEnv, ``make_real_env(backend="minecraft")``): the real env on real
Minecraft, with PettingZoo's API test (skipped unless the backend is set up). No seed test: the env documents that
it has no seeded reproducibility of trajectories (real time, network timing).

Two games are started in this module (~15 s each with the chunk-meshing warm-up), one after the other."""

import math
import os
import signal
import threading
import time

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from solaris_env.engine.minecraft.install import setup_problem
from solaris_env.engine.minecraft.records import EYE_HEIGHT, project_box
from solaris_env.engine.minecraft.supervisor import _group_alive
from solaris_env.minecraft_env import MinecraftParallelEnv
from solaris_env.real_backends import make_real_env
from solaris_env.real_env import RealParallelEnv
from solaris_env.spaces import CAMERA_TICK_LIMIT_DEG, noop

PROBLEM = setup_problem()
pytestmark = pytest.mark.minecraft
needs_minecraft = pytest.mark.skipif(PROBLEM is not None, reason=f"Minecraft backend not set up ({PROBLEM}); "
                                                                 "run `solaris-engine setup-minecraft`")
SIZE = 64


def test_bad_backend_names_the_field_and_the_choices():
    with pytest.raises(ValueError, match=r"backend must be one of \['voxel', 'minecraft'\], got 'unreal'"):
        make_real_env(backend="unreal")
    assert type(make_real_env()) is RealParallelEnv  # the default stays the voxel engine


@needs_minecraft
def test_unsupported_options_raise_clear_errors():
    with pytest.raises(ValueError, match="hud"):
        make_real_env(backend="minecraft", hud=True)
    with pytest.raises(ValueError, match="world"):
        make_real_env(backend="minecraft", world="normal")
    env = make_real_env(backend="minecraft")  # nothing is started before reset
    assert type(env) is MinecraftParallelEnv and env.bridge is None
    with pytest.raises(NotImplementedError, match="engine_state"):
        env.engine_state()
    with pytest.raises(NotImplementedError, match="engine_state"):
        env.reset(options={"engine_state": object()})
    env.close()


@pytest.fixture(scope="module")
def env():
    env = make_real_env(backend="minecraft", resolution=SIZE, max_steps=60, task="see_other_player")
    yield env
    env.close()


def _turn_to(info: dict, target: np.ndarray) -> np.ndarray:
    """The MineRL camera [dpitch, dyaw] (degrees, + down / + right) that points a player's eyes at ``target``."""
    eye = info["pos"] + [0.0, EYE_HEIGHT, 0.0]
    d = target - eye
    yaw = math.atan2(-d[0], -d[2])  # Mineflayer: yaw 0 = -Z, + = left
    pitch = math.atan2(d[1], math.hypot(d[0], d[2]))
    dyaw = (yaw - info["yaw"] + math.pi) % (2 * math.pi) - math.pi
    return np.array([-math.degrees(pitch - info["pitch"]), -math.degrees(dyaw)], np.float32)


def _finish_turns(env, out):
    """No-op steps until every camera turn is done (a player turns at most 8.59 deg a tick and the env carries the
    rest over, ``spaces.step_ticks``): the last step's outputs (``out`` when nothing was pending)."""
    while any(info["camera_pending"].any() for info in out[4].values()):
        out = env.step({a: noop() for a in env.agents})
    return out


def _step(env, cameras=None):
    """One step with these camera turns for the players (the others stand), then until the turns are done."""
    actions = {a: noop() for a in env.agents}
    for a, cam in (cameras or {}).items():
        actions[a]["camera"] = cam
    return _finish_turns(env, env.step(actions))


@needs_minecraft
@pytest.mark.timeout(300)
def test_parallel_api(env):
    parallel_api_test(env, num_cycles=20)
    assert env.metadata["name"] == "solaris_real_minecraft_v0"


def _truth_box(viewer: dict, other_feet: np.ndarray) -> tuple[slice, slice]:
    """Rows and columns of the frame covered by the other player's hitbox, projected from the poses."""
    u0, v0, u1, v1 = project_box(viewer["pos"] + [0.0, EYE_HEIGHT, 0.0], viewer["yaw"], viewer["pitch"],
                                 other_feet - [0.3, 0.0, 0.3], other_feet + [0.3, 1.8, 0.3], 70.0, 16 / 9)
    r0, c0 = int(v0 * SIZE), int(u0 * SIZE)
    return slice(r0, max(r0 + 1, math.ceil(v1 * SIZE))), slice(c0, max(c0 + 1, math.ceil(u1 * SIZE)))


def _contrast(frame: np.ndarray, rows: slice, cols: slice, right: bool = False) -> float:
    """Mean |difference| between the box and the same rows 3 box widths beside it (left when it fits)."""
    f = frame.astype(np.int16)
    w = cols.stop - cols.start
    shift = -3 * w if cols.start - 3 * w >= 0 and not right else 3 * w
    return float(np.abs(f[rows, cols] - f[rows, cols.start + shift:cols.stop + shift]).mean())


@needs_minecraft
@pytest.mark.timeout(300)
def test_looking_at_the_other_player_shows_it(env):
    obs, infos = env.reset(seed=3)
    assert set(obs) == {"Alpha", "Bravo"} and obs["Alpha"].shape == (SIZE, SIZE, 3) and obs["Alpha"].dtype == np.uint8
    assert infos["Alpha"]["sees"]["Bravo"] and infos["Bravo"]["sees"]["Alpha"]  # spawned facing each other
    # Alpha turns away: the truth says Bravo is off screen
    obs, rewards, _, _, infos = _step(env, {"Alpha": np.array([0.0, 180.0], np.float32)})
    assert not infos["Alpha"]["sees"]["Bravo"] and infos["Bravo"]["sees"]["Alpha"]
    assert rewards["Alpha"] == 0.0 and rewards["Bravo"] == 1.0  # see_other_player gets the truth
    away = obs["Alpha"]
    # ... and back, aiming at Bravo's chest from the poses in the infos
    bravo = infos["Bravo"]["pos"]
    _step(env, {"Alpha": _turn_to(infos["Alpha"], bravo + [0.0, 1.0, 0.0])})
    obs, rewards, _, _, infos = _step(env)  # let the viewer's 50 ms entity tween settle
    a = infos["Alpha"]
    assert a["sees"]["Bravo"] and abs(a["screen"]["Bravo"]["u"] - 0.5) < 0.05 and rewards["Alpha"] == 1.0
    assert infos["Alpha"]["action_record"]["camera"] == [0.0, 0.0]  # the last step did not turn
    # where the pose-based ground truth puts Bravo, Alpha's frame shows something else than beside it and
    # than the same pixels when Alpha looked away
    rows, cols = _truth_box(a, infos["Bravo"]["pos"])
    assert _contrast(obs["Alpha"], rows, cols) > 10, "Alpha's view shows no player where the poses put Bravo"
    assert np.abs(obs["Alpha"][rows, cols].astype(np.int16) - away[rows, cols]).mean() > 10
    # alignment: a 25 degree turn right shows Bravo left of centre in that very step's frame, where the truth
    # (from the pose reported with the frame) puts it; a frame one tick behind would still show it centred
    obs, _, _, _, infos = _step(env, {"Alpha": np.array([0.0, 25.0], np.float32)})
    a = infos["Alpha"]
    assert a["screen"]["Bravo"]["u"] < 0.4
    last_tick = 25.0 - 2 * CAMERA_TICK_LIMIT_DEG  # 25 deg: 8.59 + 8.59 + 7.81 over three ticks (steps)
    assert a["action_record"]["camera"][0] == pytest.approx(-math.radians(last_tick), abs=0.01)
    rows, cols = _truth_box(a, infos["Bravo"]["pos"])
    assert _contrast(obs["Alpha"], rows, cols) > 10, "the frame does not show Bravo where this step's pose puts it"
    centre = slice(SIZE // 2 - (cols.stop - cols.start) // 2, SIZE // 2 + (cols.stop - cols.start + 1) // 2)
    assert _contrast(obs["Alpha"], rows, centre, right=True) < _contrast(obs["Alpha"], rows, cols) / 2


@needs_minecraft
@pytest.mark.timeout(300)
def test_ticks_per_step_late_ticks_are_reported_and_close_leaves_no_processes():
    env = make_real_env(backend="minecraft", resolution=36, ticks_per_step=4)
    try:
        env.reset(seed=0)
        pids = env.bridge.pids()
        bridge_pid = env.bridge.bridge.pid
        assert len(pids) == 3  # Xvfb, server, bridge
        _step(env)
        assert env.step_frames().shape == (2, 4, 36, 36, 3)
        # a slow policy: the game kept ticking in real time, and the step says so
        time.sleep(0.4)
        _, _, _, _, infos = _step(env)
        timing = infos["Alpha"]["timing"]
        assert timing["idle_ticks"] >= 5 and not timing["realtime"], timing
        assert len(timing["late_ms"]) == 4
        # the bridge stalls mid-step (as under CPU load): the late ticks are caught up, beyond 4 dropped
        stall = threading.Timer(0.05, lambda: (os.kill(bridge_pid, signal.SIGSTOP), time.sleep(0.5),
                                               os.kill(bridge_pid, signal.SIGCONT)))
        stall.start()
        _, _, _, _, infos = _step(env)
        stall.join()
        timing = infos["Bravo"]["timing"]
        assert timing["catchup_ticks"] >= 1 and max(timing["late_ms"]) > 100 and not timing["realtime"], timing
        # ~10 ticks were due after the stall: 4 ran back to back, the rest were dropped (this step's, or the
        # next step's when this one had its frames before the skip)
        _, _, _, _, infos = _step(env)
        assert timing["dropped_ticks"] + infos["Bravo"]["timing"]["dropped_ticks"] >= 1, (timing, infos["Bravo"])
    finally:
        env.close()
    assert env.bridge is None
    for pid in pids:
        assert not _group_alive(pid), f"process group {pid} still alive after close()"


@needs_minecraft
@pytest.mark.timeout(300)
def test_attack_hits_the_player_in_reach():
    env = make_real_env(backend="minecraft", resolution=36, spawn_distance=(1.5, 2.0))
    try:
        _, infos = env.reset(seed=0)
        _step(env, {"Alpha": _turn_to(infos["Alpha"], infos["Bravo"]["pos"] + [0.0, 1.0, 0.0])})
        before = infos["Bravo"]["pos"]
        attack = noop()
        attack["attack"] = 1
        _, _, _, _, infos = env.step({"Alpha": attack, "Bravo": noop()})
        assert infos["Alpha"]["action_record"]["attack"]  # hit a player (not just a swing)
        for _ in range(10):
            _, _, _, _, infos = _step(env)
        pushed = infos["Bravo"]["pos"] - before
        away = before - infos["Alpha"]["pos"]
        assert np.all(np.isfinite(infos["Bravo"]["pos"]))
        assert pushed @ away / np.linalg.norm(away) > 0.5, "the hit player was not knocked back"
    finally:
        env.close()


def _ground_in_front(info: dict) -> np.ndarray:
    """The grass cell (y = 4, the superflat surface) one block in front of a player standing on it."""
    fwd = np.array([-math.sin(info["yaw"]), 0.0, -math.cos(info["yaw"])])
    cell = np.floor(info["pos"]) + np.round(fwd)
    cell[1] = 4
    return cell


def _act(**keys) -> dict:
    a = noop()
    for k, v in keys.items():
        a[k.replace("hotbar_", "hotbar.")] = v
    return a


def _until(env, action: dict, key: str, max_steps: int) -> tuple[int, dict, dict]:
    """Step Alpha with ``action`` until its ``infos[key]`` is non-empty: (steps taken, obs, infos)."""
    for n in range(1, max_steps + 1):
        obs, _, _, _, infos = env.step({"Alpha": dict(action), "Bravo": noop()})
        if infos["Alpha"][key]:
            return n, obs, infos
    raise AssertionError(f"no {key} event within {max_steps} steps: {infos['Alpha']}")


@needs_minecraft
@pytest.mark.timeout(300)
def test_attack_digs_and_use_places_and_reset_restores_the_world():
    from solaris_env.engine.blocks import Block

    env = make_real_env(backend="minecraft", resolution=SIZE)
    try:
        _, infos = env.reset(seed=0)
        cell = _ground_in_front(infos["Alpha"])
        # look at the top of the grass block in front (empty hand: the start kit leaves slot 5 empty)
        obs, _, _, _, infos = _step(env, {"Alpha": _turn_to(infos["Alpha"], cell + [0.5, 1.0, 0.5])})
        obs, _, _, _, infos = _step(env)
        before = obs["Alpha"].astype(int)
        # by hand grass takes 0.9 s (hardness 0.6, as the recorder's mineflayer dig): mine is sustained meanwhile
        steps, _, infos = _until(env, _act(attack=1), "mined", 40)
        assert infos["Alpha"]["mined"] == [(*cell.astype(int).tolist(), int(Block.GRASS))]
        assert 8 <= steps <= 25, steps  # ~18 ticks; fewer steps when the game ticked between steps
        assert infos["Bravo"]["mined"] == [] and infos["Alpha"]["placed"] == []
        for _ in range(5):  # the viewer meshes the changed chunk section
            obs, _, _, _, infos = _step(env)
        assert not infos["Alpha"]["action_record"]["mine"]
        changed = np.abs(obs["Alpha"].astype(int) - before).mean()
        assert changed > 1.0, f"the frame did not change after the dig (mean abs diff {changed:.2f})"
        # hotbar.1 holds the kit's stone: use fills the hole
        steps, _, infos = _until(env, _act(use=1, hotbar_1=1), "placed", 10)
        assert infos["Alpha"]["placed"] == [(*cell.astype(int).tolist(), int(Block.STONE))]
        assert infos["Alpha"]["action_record"]["place_block"] and steps <= 3, steps
        # the same seed spawns the same way: the cell is grass again (reset restored it); a shovel digs it in
        # 3 ticks
        _, infos = env.reset(seed=0)
        assert np.array_equal(_ground_in_front(infos["Alpha"]), cell)
        _finish_turns(env, env.step({"Alpha": _act(camera=_turn_to(infos["Alpha"], cell + [0.5, 1.0, 0.5]), hotbar_3=1),
                                     "Bravo": noop()}))
        steps, _, infos = _until(env, _act(attack=1), "mined", 10)
        assert infos["Alpha"]["mined"] == [(*cell.astype(int).tolist(), int(Block.GRASS))] and steps <= 5, steps
        # bad input names the field, in the env and in the bridge's protocol
        with pytest.raises(ValueError, match="'use'"):
            env.step({"Alpha": _act(use=2), "Bravo": noop()})
        with pytest.raises(RuntimeError, match="action.hotbar"):
            env.bridge.step([[{"controls": {}, "hotbar": 12}, {"controls": {}}]])
        _step(env)  # the bridge still steps
    finally:
        env.close()
