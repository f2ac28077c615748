"""Fuzzing step() and reset() with malformed inputs: every case must raise a clear exception (ValueError or
TypeError whose message names the offending agent or key, or gymnasium's seeding error), never crash and
never be silently accepted, and the env must keep working after each rejected call."""

import math

import gymnasium
import numpy as np
import pytest

from solaris_env.spaces import BINARY_KEYS, noop
from solaris_env.wrappers.sb3 import SB3VecEnv

CLEAR = (ValueError, TypeError, gymnasium.error.Error)

BAD_BINARY = [2, -1, 0.5, "1", None, np.array([1, 0]), float("nan"), [1], {"x": 1}, 1.0]
BAD_CAMERA = [None, "up", [1.0], [1.0, 2.0, 3.0], [[1.0, 2.0]], [math.nan, 0.0], [0.0, math.inf], [181.0, 0.0],
              [0.0, -200.0], np.array([1j, 0.0]), np.array(["a", "b"]), 5.0]
BAD_ACTION_VALUES = [None, 1, "forward", [], np.zeros(25), {}, {"forward": 1}]


def mutate(rng: np.random.Generator) -> tuple[dict, str]:
    """A valid action broken in 1-3 random ways; returns it and a key the error may name."""
    action = noop()
    for key in BINARY_KEYS:
        action[key] = int(rng.integers(2))
    named = []
    for _ in range(int(rng.integers(1, 4))):
        kind = int(rng.integers(4))
        if kind == 0:
            key = BINARY_KEYS[int(rng.integers(len(BINARY_KEYS)))]
            action[key] = BAD_BINARY[int(rng.integers(len(BAD_BINARY)))]
        elif kind == 1:
            key = "camera"
            action[key] = BAD_CAMERA[int(rng.integers(len(BAD_CAMERA)))]
        elif kind == 2:
            key = (*BINARY_KEYS, "camera")[int(rng.integers(len(BINARY_KEYS) + 1))]
            action.pop(key, None)
        else:
            key = ("fly", "hotbar.0", "Forward", "camera2")[int(rng.integers(4))]
            action[key] = 1
        named.append(key)
    return action, "|".join(named)


def assert_rejected(call, *names: str) -> None:
    with pytest.raises(CLEAR) as err:
        call()
    message = str(err.value)
    assert message, "the error has no message"
    for name in names:
        assert name in message, f"{name!r} not in {message!r}"


def fuzz_parallel_step(env, cases: int, seed: int) -> None:
    env.reset(seed=0)
    rng = np.random.default_rng(seed)
    agents = list(env.agents)
    for bad in (None, [], "Alpha", 3, (noop(), noop())):
        assert_rejected(lambda bad=bad: env.step(bad), "actions")
    assert_rejected(lambda: env.step({}), "missing")
    assert_rejected(lambda: env.step({agents[0]: noop()}), agents[1])
    assert_rejected(lambda: env.step({**{a: noop() for a in agents}, "Zulu": noop()}), "Zulu")
    assert_rejected(lambda: env.step({**{a: noop() for a in agents}, 5: noop()}), "5")
    for value in BAD_ACTION_VALUES:
        assert_rejected(lambda value=value: env.step({agents[0]: noop(), agents[1]: value}), agents[1])
    for i in range(cases):
        action, _ = mutate(rng)
        victim = agents[i % len(agents)]
        actions = {a: noop() for a in agents}
        actions[victim] = action
        assert_rejected(lambda actions=actions: env.step(actions), victim)
    obs, *_ = env.step({a: noop() for a in agents})  # still works
    assert set(obs) == set(agents)


def fuzz_parallel_reset(env) -> None:
    shape = env.observation_space("Alpha").shape
    good = {a: np.zeros(shape, np.uint8) for a in env.possible_agents}
    bad_frames = [None, 3, [good["Alpha"], good["Bravo"]], {"Alpha": good["Alpha"]},
                  {**good, "Zulu": good["Alpha"]}, {**good, "Bravo": good["Bravo"].astype(np.float32)},
                  {**good, "Bravo": good["Bravo"][..., :2]}, {**good, "Bravo": np.zeros((4, 4, 3), np.uint8)},
                  {**good, "Bravo": good["Bravo"].tolist()}]
    if hasattr(env, "start_frames"):  # the dream env takes start frames
        for frames in bad_frames:
            assert_rejected(lambda frames=frames: env.reset(options={"frames": frames}), "frames")
    for state in (None, {"world": 1}, "state", 3, good):
        assert_rejected(lambda state=state: env.reset(options={"engine_state": state}), "engine_state")
    for options in ("frames", 3, ["frames"]):
        assert_rejected(lambda options=options: env.reset(options=options), "options")
    for seed in ("abc", 1.5, -1, [1, 2]):
        with pytest.raises(CLEAR):
            env.reset(seed=seed)
    obs, _ = env.reset(seed=1)
    assert set(obs) == set(env.possible_agents)


def test_fuzz_dream_parallel_env(dream):
    env = dream(max_steps=1000)
    fuzz_parallel_step(env, cases=300, seed=0)
    fuzz_parallel_reset(env)
    three = {a: np.zeros((env.height, env.width, 3), np.uint8) for a in env.possible_agents}
    with pytest.raises(ValueError, match="not both"):
        env.reset(options={"frames": three, "engine_state": None})


def test_fuzz_real_parallel_env(real):
    env = real(max_steps=1000)
    fuzz_parallel_step(env, cases=300, seed=1)
    fuzz_parallel_reset(env)
    with pytest.raises(ValueError, match="world"):
        env.reset(options={"world": "moon"})


def test_fuzz_vector_env(vector):
    env = vector(max_steps=1000)
    env.reset(seed=0)
    n = env.num_envs
    good = [{a: noop() for a in env.possible_agents} for _ in range(n)]
    assert_rejected(lambda: env.step(good[:1]), "one {agent: action} dict per world")
    assert_rejected(lambda: env.step(None), "actions")
    assert_rejected(lambda: env.step("x"), "actions")
    batch = env.action_space.sample()
    short = {a: {k: np.asarray(v)[:1] for k, v in keys.items()} for a, keys in batch.items()}
    assert_rejected(lambda: env.step(short), "leading world axis")
    assert_rejected(lambda: env.step({"Alpha": batch["Alpha"]}), "missing ['Bravo']")
    assert_rejected(lambda: env.step([{"Alpha": noop()}, good[1]]), "world 0", "Bravo")
    rng = np.random.default_rng(2)
    for i in range(100):
        action, _ = mutate(rng)
        world = [dict(w) for w in good]
        world[i % n]["Bravo"] = action
        assert_rejected(lambda world=world: env.step(world), f"world {i % n}", "Bravo")
    for mask in (np.array([True]), np.array([1, 0]), "all"):
        assert_rejected(lambda mask=mask: env.reset(options={"reset_mask": mask}), "reset_mask")
    assert_rejected(lambda: env.reset(options={"frames": np.zeros((n, 2, 8, 8, 3), np.uint8)}), "frames")
    assert_rejected(lambda: env.reset(options={"engine_state": [None] * (n + 1)}), "engine_state")
    env.step(good)  # still works


def test_fuzz_sb3_adapter_and_flat_actions(vector):
    venv = SB3VecEnv(vector(max_steps=1000))
    venv.reset()
    n = venv.num_envs
    for bad in (np.zeros((n, 24), np.int64), np.zeros((n,), np.int64), np.zeros((n + 1, 25), np.int64)):
        assert_rejected(lambda bad=bad: venv.step(bad), "shape")
    rng = np.random.default_rng(3)
    for _ in range(50):
        bad = np.stack([venv.action_space.sample() for _ in range(n)])
        slot, entry = int(rng.integers(n)), int(rng.integers(25))
        bad[slot, entry] = (-1, 2, 99)[int(rng.integers(3))] if entry < 23 else (-1, 11, 50)[int(rng.integers(3))]
        assert_rejected(lambda bad=bad: venv.step(bad), f"slot {slot}", f"entry {entry}")
    assert_rejected(lambda: venv.step(np.full((n, 25), 0.5)), "integer")
    venv.step(np.zeros((n, 25), np.int64))
