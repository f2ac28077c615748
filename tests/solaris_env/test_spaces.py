"""``solaris_env.spaces``: the env action contract, camera conventions, action converters, and ``step_ticks`` (one
step's action split into k engine ticks)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from solaris_env import spaces as sp
from solaris_env.spaces import CAMERA_TICK_LIMIT_DEG, ONCE_KEYS, noop, step_ticks

FIXTURES = Path(__file__).parent / "fixtures"
SLICES = FIXTURES / "mineflayer_action_slices"
CONVERTERS = FIXTURES / "dataset_converters"


def _load(path: Path):
    with open(path) as f:
        return json.load(f)


def _action(**overrides):
    action = sp.noop()
    action.update(overrides)
    return action


# ---------------------------------------------------------------------------------------------
# Space structure, noop, validation
# ---------------------------------------------------------------------------------------------


def test_key_tuples():
    assert len(sp.BINARY_KEYS) == 23
    assert sp.BINARY_KEYS[-9:] == tuple(f"hotbar.{k}" for k in range(1, 10))
    assert len(sp.MODEL_ACTION_KEYS) == 25
    assert (sp.KEYBOARD_DIM, sp.MOUSE_DIM) == (23, 2)
    assert sp.MODEL_ACTION_KEYS[16:18] == ("sneak", "sprint")
    assert sp.MODEL_ACTION_KEYS[23:] == ("cameraX", "cameraY")
    assert set(sp.BINARY_KEYS) == set(sp.MODEL_ACTION_KEYS[:23])
    assert len(sp.RECORDED_ACTION_KEYS) == 24


def test_action_space_structure_and_samples():
    space = sp.make_action_space(seed=0)
    assert tuple(space.spaces) == sp.ACTION_KEYS
    assert all(space[k].n == 2 for k in sp.BINARY_KEYS)
    cam = space["camera"]
    assert cam.shape == (2,) and cam.dtype == np.float32
    assert cam.low.tolist() == [-180, -180] and cam.high.tolist() == [180, 180]
    for _ in range(20):
        sample = space.sample()
        assert space.contains(sample)
        assert space.contains(sp.validate_action(sample))


def test_action_space_seeding_is_deterministic():
    a, b = sp.make_action_space(seed=3).sample(), sp.make_action_space(seed=3).sample()
    assert all(np.array_equal(a[k], b[k]) for k in sp.ACTION_KEYS)


def test_noop_is_valid():
    action = sp.noop()
    assert sp.make_action_space().contains(action)
    assert action["camera"].dtype == np.float32 and not action["camera"].any()
    assert all(action[k] == 0 for k in sp.BINARY_KEYS)
    out = sp.validate_action(action)
    assert list(out) == list(sp.ACTION_KEYS)


@pytest.mark.parametrize("value", [True, 1, np.int64(1), np.uint8(1), np.array(1), np.bool_(True)])
def test_validate_accepts_binary_forms(value):
    out = sp.validate_action(_action(jump=value))
    assert out["jump"] == 1 and type(out["jump"]) is int


def test_validate_returns_copy_with_float32_camera():
    action = _action(camera=[1, -2])
    out = sp.validate_action(action)
    assert out["camera"].dtype == np.float32 and out["camera"].tolist() == [1.0, -2.0]
    assert action["camera"] == [1, -2]


def _without(key):
    action = sp.noop()
    del action[key]
    return action


BAD_ACTIONS = [
    ("unknown key", _action(fly=1), "fly"),
    ("missing key", _without("sneak"), "sneak"),
    ("missing camera", _without("camera"), "camera"),
    ("binary 2", _action(attack=2), "attack"),
    ("binary -1", _action(use=-1), "use"),
    ("binary float", _action(forward=1.0), "forward"),
    ("binary string", _action(forward="1"), "forward"),
    ("binary array", _action(forward=np.array([1])), "forward"),
    ("camera shape 3", _action(camera=np.zeros(3)), "camera"),
    ("camera shape (1,2)", _action(camera=np.zeros((1, 2))), "camera"),
    ("camera scalar", _action(camera=0.0), "camera"),
    ("camera strings", _action(camera=["a", "b"]), "camera"),
    ("camera ragged", _action(camera=[1.0, [2.0]]), "camera"),
    ("camera None", _action(camera=None), "camera"),
    ("camera bool", _action(camera=[True, False]), "camera"),
    ("camera nan", _action(camera=[np.nan, 0.0]), "camera"),
    ("camera inf", _action(camera=[0.0, np.inf]), "camera"),
    ("camera > 180", _action(camera=[0.0, 180.5]), "camera"),
    ("camera < -180", _action(camera=[-181.0, 0.0]), "camera"),
]


@pytest.mark.parametrize("case, action, key", BAD_ACTIONS, ids=[c[0] for c in BAD_ACTIONS])
def test_validate_rejects_bad_input(case, action, key):
    with pytest.raises(ValueError, match=f"agent 'alpha'.*{key}"):
        sp.validate_action(action, agent="alpha")


def test_validate_rejects_non_dict():
    with pytest.raises(ValueError, match="dict"):
        sp.validate_action([0] * 24)


def test_validate_accepts_camera_bounds():
    out = sp.validate_action(_action(camera=[-180.0, 180.0]))
    assert out["camera"].tolist() == [-180.0, 180.0]


# ---------------------------------------------------------------------------------------------
# Camera conventions
# ---------------------------------------------------------------------------------------------


def test_camera_signs():
    dyaw, dpitch = sp.minerl_camera_to_mineflayer([0.0, 10.0])  # MineRL: turn right 10 deg
    assert dyaw == pytest.approx(-math.radians(10)) and dpitch == 0.0
    dyaw, dpitch = sp.minerl_camera_to_mineflayer([10.0, 0.0])  # MineRL: look down 10 deg
    assert dpitch == pytest.approx(-math.radians(10)) and dyaw == 0.0
    vec = sp.env_action_to_model_vector(_action(camera=[0.0, 10.0]))
    assert vec[23] < 0 and vec[24] == 0.0


def test_camera_exact_zero():
    dyaw, dpitch = sp.minerl_camera_to_mineflayer(np.zeros(2, np.float32))
    assert (dyaw, dpitch) == (0.0, 0.0) and math.copysign(1, dyaw) == 1.0
    back = sp.mineflayer_to_minerl_camera(0.0, 0.0)
    assert back.dtype == np.float32 and back.tolist() == [0.0, 0.0]
    assert not np.signbit(back).any()


@pytest.mark.parametrize("camera", [[0.0, 10.0], [-45.5, 3.25], [180.0, -180.0], [0.15, -0.15]])
def test_camera_round_trip(camera):
    back = sp.mineflayer_to_minerl_camera(*sp.minerl_camera_to_mineflayer(camera))
    np.testing.assert_allclose(back, np.float32(camera), atol=1e-5)


def test_camera_helpers_reject_nan():
    with pytest.raises(ValueError, match="camera"):
        sp.minerl_camera_to_mineflayer([np.nan, 0.0])
    with pytest.raises(ValueError, match="camera"):
        sp.mineflayer_to_minerl_camera(0.0, np.inf)


# ---------------------------------------------------------------------------------------------
# Env action -> model vector, camera_linear
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("key", sp.BINARY_KEYS)
def test_env_to_model_each_key(key):
    vec = sp.env_action_to_model_vector(_action(**{key: 1}))
    assert vec.shape == (25,) and vec.dtype == np.float32
    assert np.flatnonzero(vec).tolist() == [sp.MODEL_ACTION_KEYS.index(key)]


def test_env_to_model_camera():
    vec = sp.env_action_to_model_vector(_action(camera=[-6.0, 9.0]))  # look up 6, turn right 9
    np.testing.assert_allclose(vec[23:], [-0.6, 0.4], atol=1e-6)
    batch = sp.env_actions_to_model_vectors([sp.noop(), _action(camera=[-6.0, 9.0])])
    assert batch.shape == (2, 25) and np.array_equal(batch[1], vec) and not batch[0].any()
    assert sp.env_actions_to_model_vectors([]).shape == (0, 25)


@pytest.mark.parametrize(
    "deg, expected",
    [(1.0, 0.066667), (6.0, 0.4), (9.0, 0.6), (20.0, 1.333333), (35.0, 1.333333), (-90.0, -1.333333), (0.0, 0.0)],
)
def test_camera_linear_values(deg, expected):
    vec = np.zeros(25, np.float32)
    vec[23] = vec[24] = deg
    out = sp.camera_linear(vec)
    np.testing.assert_allclose(out[23:], [expected, expected], atol=1e-6)


def test_camera_linear_fixture():
    vec_in = np.array(_load(CONVERTERS / "camera_linear_matrix_game2.input.json"), np.float32)
    expected = np.array(_load(CONVERTERS / "camera_linear_matrix_game2.expected.json"), np.float32)
    assert vec_in.shape == (29, 25)
    out = sp.camera_linear(vec_in)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, expected, atol=1e-6)
    assert np.array_equal(vec_in, np.array(_load(CONVERTERS / "camera_linear_matrix_game2.input.json"), np.float32))


def test_camera_linear_passes_keyboard_through_and_checks_shape():
    vec = np.ones((3, 25), np.float32)
    assert np.array_equal(sp.camera_linear(vec)[:, :23], vec[:, :23])
    with pytest.raises(ValueError, match="25"):
        sp.camera_linear(np.zeros((3, 24)))


# ---------------------------------------------------------------------------------------------
# Mineflayer records
# ---------------------------------------------------------------------------------------------


def test_mineflayer_all_off_fixture():
    out = sp.mineflayer_records_to_vectors(_load(SLICES / "all_off.json"))
    assert out.shape == (1, 25) and out.dtype == np.float32
    assert not out.any()


def test_mineflayer_each_boolean_on_fixture():
    out = sp.mineflayer_records_to_vectors(_load(SLICES / "each_boolean_on.json"))
    expected_hot = [11, 12, 13, 14, 15, 17, 16, 19, 20, 20, 16, 20, 20, 19] + list(range(2, 11))
    assert out.shape == (23, 25)
    expected = np.zeros((23, 25), np.float32)
    expected[np.arange(23), expected_hot] = 1.0
    assert np.array_equal(out, expected)


def test_mineflayer_camera_ranges_fixture():
    out = sp.mineflayer_records_to_vectors(_load(SLICES / "camera_ranges.json"))
    yaws = [0.0] + [s * 180.0 / 2**n for n in range(6) for s in (1, -1)]
    pitches = [s * 90.0 / 2**n for n in range(5) for s in (1, -1)]
    expected = np.array([(y, 0.0) for y in yaws] + [(0.0, p) for p in pitches])
    assert out.shape == (23, 25)
    np.testing.assert_allclose(out[:, 23:], expected, atol=1e-3)
    assert not out[:, :23].any()


def _recorded_action(**overrides):
    action = {k: False for k in sp.RECORDED_ACTION_KEYS}
    action["camera"] = [0.0, 0.0]
    action.update(overrides)
    return action


def _records(**action_overrides):
    """Two records: a clean one, then one with the overrides (so errors name record 1)."""
    return [{"action": _recorded_action()}, {"action": _recorded_action(**action_overrides)}]


def test_mineflayer_combines_or():
    out = sp.mineflayer_records_to_vectors(_records(attack=True, mine=True, use=True, mount=True))
    assert np.flatnonzero(out[1]).tolist() == [19, 20]


@pytest.mark.parametrize(
    "records, match",
    [
        (_records(fly=True), "record 1.*fly"),
        ([{"action": {k: v for k, v in _recorded_action().items() if k != "mine"}}], "record 0.*mine"),
        (_records(jump=2), "record 1.*jump"),
        (_records(camera=[0.0]), "record 1.*camera"),
        (_records(camera=[float("nan"), 0.0]), "record 1.*camera"),
        ([{"x": 0}], "record 0.*action"),
    ],
)
def test_mineflayer_rejects_bad_records(records, match):
    with pytest.raises(ValueError, match=match):
        sp.mineflayer_records_to_vectors(records)


# ---------------------------------------------------------------------------------------------
# VPT JSONL
# ---------------------------------------------------------------------------------------------


def _vpt_tick(keys=(), buttons=(), new_buttons=(), dx=0.0, dy=0.0, hotbar=0):
    return {
        "keyboard": {"keys": list(keys), "newKeys": [], "chars": ""},
        "mouse": {"dx": dx, "dy": dy, "buttons": list(buttons), "newButtons": list(new_buttons)},
        "hotbar": hotbar,
    }


@pytest.mark.parametrize(
    "key, name",
    [
        ("escape", "ESC"), ("s", "back"), ("q", "drop"), ("w", "forward"), ("e", "inventory"),
        ("space", "jump"), ("a", "left"), ("d", "right"), ("left.shift", "sneak"),
        ("left.control", "sprint"), ("f", "swapHands"), ("1", "hotbar.1"), ("9", "hotbar.9"),
    ],
)
def test_vpt_key_mapping(key, name):
    out = sp.vpt_jsonl_to_vectors([_vpt_tick(keys=[f"key.keyboard.{key}", "key.keyboard.t"])])
    assert np.flatnonzero(out[0]).tolist() == [sp.MODEL_ACTION_KEYS.index(name)]


def test_vpt_buttons_and_camera():
    lines = [json.dumps(_vpt_tick(buttons=[1, 2], dx=10, dy=-4)), "", json.dumps(_vpt_tick(buttons=[0]))]
    out = sp.vpt_jsonl_to_vectors(lines)
    assert out.shape == (2, 25)
    assert np.flatnonzero(out[0, :23]).tolist() == [20, 21]
    np.testing.assert_allclose(out[0, 23:], [1.5, -0.6], atol=1e-6)
    assert np.flatnonzero(out[1]).tolist() == [19]


def test_vpt_attack_stuck_rule():
    ticks = [
        _vpt_tick(buttons=[0], new_buttons=[0]),  # tick 0: attack "stuck" from before the recording
        _vpt_tick(buttons=[0, 1]),
        _vpt_tick(buttons=[0], new_buttons=[0]),  # real press: un-sticks
        _vpt_tick(buttons=[0]),
    ]
    out = sp.vpt_jsonl_to_vectors(ticks)
    assert out[:, 19].tolist() == [0, 0, 1, 1]
    assert out[1, 20] == 1
    not_stuck = sp.vpt_jsonl_to_vectors([_vpt_tick(buttons=[0], new_buttons=[0, 1]), _vpt_tick(buttons=[0])])
    assert not_stuck[:, 19].tolist() == [1, 1]


def test_vpt_hotbar_pulse():
    out = sp.vpt_jsonl_to_vectors([_vpt_tick(hotbar=h) for h in (0, 0, 3, 3, 3, 8, 0)])
    hot = [np.flatnonzero(row).tolist() for row in out]
    assert hot == [[], [], [2 + 3], [], [], [2 + 8], [2]]
    first = sp.vpt_jsonl_to_vectors([_vpt_tick(hotbar=4)])
    assert np.flatnonzero(first[0]).tolist() == [2 + 4]


def test_vpt_rejects_missing_fields():
    with pytest.raises(ValueError, match="tick 1"):
        sp.vpt_jsonl_to_vectors([_vpt_tick(), {"keyboard": {"keys": []}, "hotbar": 0}])


# ---------------------------------------------------------------------------------------------
# FlatActionCodec
# ---------------------------------------------------------------------------------------------


def test_codec_multidiscrete_space_and_bins():
    codec = sp.FlatActionCodec(camera_bins=11, camera_max_deg=10.0)
    assert codec.space.nvec.tolist() == [2] * 23 + [11, 11]
    bins = codec.bin_centers_deg
    assert bins[5] == 0.0 and bins[0] == -10.0 and bins[-1] == 10.0
    assert np.array_equal(bins, -bins[::-1])


def test_codec_box_space():
    codec = sp.FlatActionCodec(kind="box")
    assert codec.space.shape == (25,) and codec.space.dtype == np.float32
    assert codec.space.low.min() == -1 and codec.space.high.max() == 1


@pytest.mark.parametrize("kind", ["multidiscrete", "box"])
@pytest.mark.parametrize("bins, max_deg", [(11, 10.0), (3, 180.0), (21, 7.3)])
def test_codec_round_trips(kind, bins, max_deg):
    codec = sp.FlatActionCodec(camera_bins=bins, camera_max_deg=max_deg, kind=kind)
    codec.space.seed(0)
    for _ in range(50):
        action = codec.decode(codec.space.sample())
        assert sp.make_action_space().contains(action)
        flat = codec.encode(action)
        assert codec.space.contains(flat)
        again = codec.decode(flat)
        assert all(np.array_equal(again[k], action[k]) for k in sp.ACTION_KEYS)


@pytest.mark.parametrize("kind", ["multidiscrete", "box"])
def test_codec_encode_noop_and_lossy_camera(kind):
    codec = sp.FlatActionCodec(kind=kind)
    noop_back = codec.decode(codec.encode(sp.noop()))
    assert noop_back["camera"].tolist() == [0.0, 0.0] and not any(noop_back[k] for k in sp.BINARY_KEYS)
    back = codec.decode(codec.encode(_action(camera=[2.6, -90.0], attack=1)))
    assert back["attack"] == 1
    assert back["camera"][1] == -10.0  # beyond camera_max_deg: saturates
    if kind == "multidiscrete":
        assert back["camera"][0] == 2.0  # snapped to the nearest 2-degree bin
    else:
        assert back["camera"][0] == pytest.approx(2.6, abs=1e-5)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"camera_bins": 10}, "camera_bins"),
        ({"camera_bins": 1}, "camera_bins"),
        ({"camera_max_deg": 0.0}, "camera_max_deg"),
        ({"camera_max_deg": 200.0}, "camera_max_deg"),
        ({"kind": "discrete"}, "kind"),
        ({"keys": ["fly"]}, "'fly' is not a binary key"),
        ({"keys": ["use", "use"]}, "no repeats"),
        ({"keys": "forward"}, "sequence of key names"),
        ({"camera_axes": ("yaw", "pitch")}, "camera_axes"),
        ({"camera_axes": ("roll",)}, "camera_axes"),
        ({"camera_axes": ("yaw", "yaw")}, "camera_axes"),
        ({"camera_axes": "yaw"}, "camera_axes"),
        ({"keys": (), "camera_axes": ()}, "at least one key or camera axis"),
    ],
)
def test_codec_rejects_bad_config(kwargs, match):
    with pytest.raises(ValueError, match=match):
        sp.FlatActionCodec(**kwargs)


@pytest.mark.parametrize("kind", ["multidiscrete", "box"])
def test_codec_key_subset_exposes_only_those_keys(kind):
    codec = sp.FlatActionCodec(kind=kind, keys=("use", "forward"))
    assert codec.space.shape == (4,)
    if kind == "multidiscrete":
        assert codec.space.nvec.tolist() == [2, 2, 11, 11]
    codec.space.seed(0)
    pressed = set()
    for _ in range(50):
        action = codec.decode(codec.space.sample())
        assert sp.make_action_space().contains(action)
        pressed |= {k for k in sp.BINARY_KEYS if action[k]}
        again = codec.decode(codec.encode(action))
        assert all(np.array_equal(again[k], action[k]) for k in sp.ACTION_KEYS)
    assert pressed == {"use", "forward"}  # the order given is kept: entry 0 is "use"
    assert codec.encode(_action(use=1))[0] in (1, 1.0) and codec.encode(_action(use=1))[1] in (0, -1.0)
    with pytest.raises(ValueError, match="presses 'attack', which this codec does not expose"):
        codec.encode(_action(attack=1))
    with pytest.raises(ValueError, match=r"expected shape \(4,\)"):
        codec.decode(np.zeros(25, np.int64 if kind == "multidiscrete" else np.float32))
    bad = np.zeros(4, np.int64 if kind == "multidiscrete" else np.float32)
    bad[1] = 5
    with pytest.raises(ValueError, match="entry 1 \\('forward'\\)"):
        codec.decode(bad)
    rebuilt = sp.FlatActionCodec(**codec.config())
    assert rebuilt.keys == codec.keys and rebuilt.space == codec.space


def test_codec_camera_only():
    codec = sp.FlatActionCodec(keys=())
    assert codec.space.nvec.tolist() == [11, 11]
    action = codec.decode(np.array([5, 10]))
    assert action["camera"].tolist() == [0.0, 10.0] and not any(action[k] for k in sp.BINARY_KEYS)
    assert sp.FlatActionCodec().config()["keys"] == list(sp.BINARY_KEYS)


@pytest.mark.parametrize("kind", ["multidiscrete", "box"])
@pytest.mark.parametrize("axes", [("yaw",), ("pitch",)])
def test_codec_single_camera_axis(kind, axes):
    codec = sp.FlatActionCodec(kind=kind, keys=("jump",), camera_axes=axes)
    assert codec.space.shape == (2,)
    axis = sp.CAMERA_AXES.index(axes[0])
    codec.space.seed(0)
    turned = 0.0
    for _ in range(30):
        action = codec.decode(codec.space.sample())
        assert action["camera"][1 - axis] == 0.0
        turned = max(turned, abs(float(action["camera"][axis])))
        again = codec.decode(codec.encode(action))
        assert all(np.array_equal(again[k], action[k]) for k in sp.ACTION_KEYS)
    assert turned > 0
    camera = np.zeros(2, np.float32)
    camera[1 - axis] = 3.0
    with pytest.raises(ValueError, match=f"about {sp.CAMERA_AXES[1 - axis]!r}"):
        codec.encode(_action(camera=camera))
    bad = np.zeros(2, np.int64 if kind == "multidiscrete" else np.float32)
    bad[1] = 40
    with pytest.raises(ValueError, match=f"entry 1 \\('camera\\[{axis}\\]'\\)"):
        codec.decode(bad)
    assert sp.FlatActionCodec(**codec.config()).space == codec.space


def test_codec_decode_errors():
    md = sp.FlatActionCodec()
    with pytest.raises(ValueError, match="shape"):
        md.decode(np.zeros(24, np.int64))
    with pytest.raises(ValueError, match="integer"):
        md.decode(np.zeros(25, np.float32))
    with pytest.raises(ValueError, match="'jump'"):
        md.decode(np.eye(25, dtype=np.int64)[4] * 2)
    with pytest.raises(ValueError, match=r"camera\[1\]"):
        md.decode(np.r_[np.zeros(24), 11].astype(np.int64))
    box = sp.FlatActionCodec(kind="box")
    with pytest.raises(ValueError, match=r"camera\[0\]"):
        box.decode(np.r_[np.zeros(23), 1.5, 0.0])
    with pytest.raises(ValueError, match="'forward'"):
        box.decode(np.r_[np.nan, np.zeros(24)])
    with pytest.raises(ValueError, match="camera"):
        md.encode(_action(camera=[0.0, 200.0]))


def act(dyaw: float = 0.0, **keys) -> dict:
    a = noop()
    a["camera"] = np.array([0.0, dyaw], np.float32)
    a.update(keys)
    return a


def test_step_ticks_hold_movement_send_once_keys_once_and_spread_the_camera():
    ticks, pending = step_ticks(act(12.0, forward=1, jump=1, attack=1, **{"hotbar.2": 1}), 4)
    assert len(ticks) == 4 and ticks[0]["attack"] == 1 and np.array_equal(pending, [0.0, 0.0])
    yaw = [t["camera"][1] for t in ticks]  # at most CAMERA_TICK_LIMIT_DEG a tick, from the first tick on
    assert yaw[0] == np.float32(CAMERA_TICK_LIMIT_DEG) and yaw[2:] == [0.0, 0.0]
    assert yaw[1] == pytest.approx(12.0 - CAMERA_TICK_LIMIT_DEG, abs=1e-5)
    for t in ticks[1:]:
        assert t["forward"] == 1 and t["jump"] == 1 and t["attack"] == 1  # held: digging needs every tick
        assert all(t[k] == 0 for k in ONCE_KEYS)
    with pytest.raises(ValueError, match="ticks per step"):
        step_ticks(noop(), 0)
    ticks, pending = step_ticks(act(40.0), 4)  # 40 deg does not fit in 4 ticks: the rest is carried, never dropped
    assert all(t["camera"][1] == np.float32(CAMERA_TICK_LIMIT_DEG) for t in ticks)
    assert pending[1] == pytest.approx(40.0 - 4 * CAMERA_TICK_LIMIT_DEG, abs=1e-5)
