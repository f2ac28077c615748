"""Fuzzing step() and reset() with malformed inputs: every case must raise a clear exception (ValueError or
TypeError whose message names the offending agent or key, or gymnasium's seeding error), never crash and
never be silently accepted, and the env must keep working after each rejected call."""

import copy
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


# ---------------------------------------------------------------------------------------------
# A rejected call changes nothing: not the RNG streams, not the opponents, not the episode
# ---------------------------------------------------------------------------------------------


def turn(dyaw: float) -> dict:
    a = noop()
    a["camera"] = np.array([0.0, dyaw], np.float32)
    return a


class CountingPolicy:
    """A frozen policy with state: its n-th call turns by n degrees (so a skipped or extra call shows)."""

    def __init__(self):
        self.calls = 0

    def __call__(self, observation):
        self.calls += 1
        return turn(float(self.calls))


def record_actions(env, sent: list) -> None:
    """Record (a copy of) every actions argument ``env.step`` gets from now on."""
    step = env.step

    def recording(actions):
        sent.append(copy.deepcopy(actions))
        return step(actions)

    env.step = recording


def single_agent_runs(make, bad, good_steps=3):
    """(observations, actions the multiplayer env got) of a clean run and of one whose first step got ``bad``
    (which must raise) first. The test model's frames barely depend on the actions, so both are compared."""
    runs = []
    for dirty in (False, True):
        env = make()
        obs, _ = env.reset(seed=5)
        sent, frames = [], [obs]
        record_actions(env.unwrapped.env, sent)
        if dirty:
            with pytest.raises(CLEAR):
                env.step(bad)
        for i in range(good_steps):
            frames.append(env.step(env.action_space.sample() if i else good_action(env))[0])
        runs.append((frames, sent))
    return runs


def good_action(env):
    """A valid action of ``env``'s (possibly flat) action space, the same every call."""
    if isinstance(env.action_space, gymnasium.spaces.Dict):
        return turn(3.0)
    return np.zeros(env.action_space.shape, env.action_space.dtype)


def assert_same(a, b, where="") -> None:
    """Nested dicts / lists / arrays are equal."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            assert_same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    else:
        assert np.array_equal(a, b), f"{where} differs after a rejected call"


def assert_same_runs(runs):
    clean, dirty = runs
    assert_same(clean, dirty)


@pytest.mark.parametrize("opponent", ["random", "noop", "policy"])
def test_a_rejected_learner_action_changes_nothing_in_the_single_agent_dream_env(model, opponent):
    def make():
        env = gymnasium.make("solaris_env/Dream-v0", model=model, max_steps=50,
                             opponent=CountingPolicy() if opponent == "policy" else opponent)
        env.action_space.seed(1)
        return env

    bad = turn(0.0)
    bad["camera"] = np.array([0.0, 500.0], np.float32)
    assert_same_runs(single_agent_runs(make, bad))


@pytest.mark.parametrize("opponent", ["bot", "random"])
def test_a_rejected_learner_action_changes_nothing_in_the_single_agent_real_env(opponent):
    def make():
        env = gymnasium.make("solaris_env/Real-v0", resolution=36, view_distance=24.0, max_steps=50,
                             opponent=opponent)
        env.action_space.seed(1)
        return env

    assert_same_runs(single_agent_runs(make, {**noop(), "forward": 2}, good_steps=30))


def test_a_rejected_flat_action_changes_nothing(model):
    def make():
        env = gymnasium.make("solaris_env/Dream-v0", model=model, max_steps=50, opponent="random",
                             flatten="multidiscrete")
        env.action_space.seed(1)
        return env

    bad = np.zeros(25, np.int64)
    bad[24] = 11  # camera bin outside [0, 10]
    assert_same_runs(single_agent_runs(make, bad))


def test_a_rejected_sb3_batch_changes_no_world_and_no_opponent(vector):
    def run(dirty: bool):
        venv = SB3VecEnv(vector(max_steps=50), learners=["Alpha"], opponent="random")
        venv.seed(4)
        frames, sent = [venv.reset()], []
        record_actions(venv.vec_env, sent)
        good = np.zeros((venv.num_envs, 25), np.int64)
        good[:, 23:] = 5  # camera bins at 0 deg
        if dirty:
            bad = good.copy()
            bad[1, 0] = 2  # slot 1 (world 1): world 0's opponent must not act first
            with pytest.raises(ValueError, match="slot 1"):
                venv.step(bad)
        for _ in range(2):
            frames.append(venv.step(good)[0])
        return frames, sent

    assert_same_runs([run(False), run(True)])


# ---------------------------------------------------------------------------------------------
# A failed reset changes nothing
# ---------------------------------------------------------------------------------------------

BAD_RESETS = [{"seed": 7, "options": {"frame": None}}, {"seed": 7, "options": {"engine_state": "nope"}},
              {"seed": 7, "options": 3}, {"seed": True}, {"seed": -1}, {"seed": 7, "options": {"engine_states": 1}}]


def parallel_run_after(env, bad: dict | None) -> list:
    """reset(seed=1), a step, maybe a failing reset, a step, then an unseeded reset and a step."""
    noops = {a: turn(4.0) for a in env.possible_agents}
    out = [env.reset(seed=1)[0], env.step(noops)[0]]
    if bad is not None:
        with pytest.raises(CLEAR):
            env.reset(**bad)
    out += [env.step(noops)[0], env.reset()[0], env.step(noops)[0]]
    return [np.stack([o[a] for a in env.possible_agents]) for o in out]


@pytest.mark.parametrize("bad", BAD_RESETS, ids=lambda b: str(b))
def test_a_failed_reset_changes_nothing_in_the_dream_env(dream, bad):
    assert_same_runs([parallel_run_after(dream(), None), parallel_run_after(dream(), bad)])


@pytest.mark.parametrize("bad", BAD_RESETS + [{"seed": 7, "options": {"world": "moon"}}], ids=lambda b: str(b))
def test_a_failed_reset_changes_nothing_in_the_real_env(real, bad):
    assert_same_runs([parallel_run_after(real(), None), parallel_run_after(real(), bad)])


def test_a_failed_reset_changes_nothing_in_the_vector_env(vector):
    bads = [{"seed": 7, "options": {"frame": None}}, {"seed": 7, "options": {"reset_mask": "all"}},
            {"seed": 7, "options": {"engine_state": [None] * 3}}, {"seed": True}]

    def run(bad):
        env = vector(max_steps=50)
        noops = [{a: turn(4.0) for a in env.possible_agents}] * env.num_envs
        out = [env.reset(seed=1)[0], env.step(noops)[0]]
        if bad is not None:
            with pytest.raises(CLEAR):
                env.reset(**bad)
        seed_before = env.np_random_seed
        out += [env.step(noops)[0], env.reset()[0], env.step(noops)[0]]
        assert env.np_random_seed == seed_before
        return out

    clean = run(None)
    for bad in bads:
        assert_same_runs([clean, run(bad)])


def test_a_failed_reset_changes_nothing_in_the_wrappers(model, vector):
    def run(bad):
        env = gymnasium.make("solaris_env/Dream-v0", model=model, max_steps=50, opponent="random")
        out = [env.reset(seed=1)[0], env.step(turn(2.0))[0]]
        if bad is not None:
            with pytest.raises(CLEAR):
                env.reset(**bad)
        out += [env.step(turn(2.0))[0], env.reset()[0], env.step(turn(2.0))[0]]
        return out

    clean = run(None)
    for bad in ({"seed": 7, "options": {"frame": None}}, {"seed": True}):
        assert_same_runs([clean, run(bad)])

    def run_sb3(bad):
        venv = SB3VecEnv(vector(max_steps=50), learners=["Alpha"])
        venv.seed(1)
        first = venv.reset()
        if bad:
            venv.set_options({"frame": None})
            with pytest.raises(ValueError, match="frame"):
                venv.reset()
            venv.set_options(None)
        return [first, venv.reset()]

    assert_same_runs([run_sb3(False), run_sb3(True)])


# ---------------------------------------------------------------------------------------------
# Quietly accepted nonsense is refused, with the argument named
# ---------------------------------------------------------------------------------------------


def test_unknown_reset_options_are_refused_naming_the_key(dream, real, vector):
    d, r, v = dream(), real(), vector()
    frames = {a: np.zeros((d.height, d.width, 3), np.uint8) for a in d.possible_agents}
    for env, options in [(d, {"frame": frames}), (d, {"engine_states": None}), (d, {"world": "flat"}),
                         (r, {"worlds": "flat"}), (r, {"frames": frames}), (v, {"frame": None}),
                         (v, {"options": 1}), (d, {5: 1})]:
        assert_rejected(lambda env=env, options=options: env.reset(options=options), "options",
                        repr(next(iter(options))))
    d.reset(seed=0, options={"options": 1})  # PettingZoo's API-test probe is accepted (and ignored)
    r.reset(seed=0, options={"options": 1})


@pytest.mark.parametrize("value", [2.5, math.nan, None, "2", True, 0, -1, np.float64(3.0)])
def test_max_steps_must_be_a_positive_int(dream, real, vector, value):
    for make in (dream, real, vector):
        assert_rejected(lambda make=make: make(max_steps=value), "max_steps", "int")
    assert dream(max_steps=np.int64(3)).max_steps == 3


def test_numpy_integer_seeds_are_accepted_and_bools_refused(dream, real, vector, model):
    for make in (dream, real):
        env = make()
        a, _ = env.reset(seed=3)
        b, _ = env.reset(seed=np.int64(3))
        assert all(np.array_equal(a[x], b[x]) for x in a)
        for seed in (True, False, np.bool_(True), 3.0, "3"):
            assert_rejected(lambda env=env, seed=seed: env.reset(seed=seed), "seed")
    v = vector()
    a, _ = v.reset(seed=3)
    assert np.array_equal(a, v.reset(seed=np.uint32(3))[0])
    assert_rejected(lambda: v.reset(seed=True), "seed")
    single = gymnasium.make("solaris_env/Dream-v0", model=model, opponent="noop")
    assert np.array_equal(single.reset(seed=np.int64(3))[0], single.reset(seed=3)[0])
    assert_rejected(lambda: single.reset(seed=True), "seed")


# ---------------------------------------------------------------------------------------------
# Observations are the caller's
# ---------------------------------------------------------------------------------------------


def test_writing_into_observations_and_infos_changes_nothing_in_the_env(dream, real, vector):
    for env in (dream(render_mode="rgb_array"), real(render_mode="rgb_array", ticks_per_step=2)):
        for obs, infos in (env.reset(seed=0), env.step({a: noop() for a in env.possible_agents})[::4]):
            sheet, frames = env.render().copy(), env.step_frames().copy()
            for a in obs:
                obs[a][:] = 7
                if "frames" in infos[a]:
                    infos[a]["frames"][:] = 7
            assert np.array_equal(env.render(), sheet) and np.array_equal(env.step_frames(), frames)
            with pytest.raises(ValueError, match="read-only"):
                env.step_frames()[:] = 0
    v = vector(render_mode="rgb_array")
    for obs in (v.reset(seed=0)[0], v.step([{a: noop() for a in v.possible_agents}] * v.num_envs)[0]):
        sheet = v.render().copy()
        obs[:] = 7
        assert np.array_equal(v.render(), sheet)
