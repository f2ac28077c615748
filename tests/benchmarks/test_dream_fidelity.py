"""``benchmarks.dream_fidelity``: the metrics on hand-made cases, the programs, and one tiny end-to-end run."""

import json
import math

import numpy as np
import pytest

from benchmarks import dream_fidelity as df


def _scene_HW3(seed: int = 0, size: int = 64) -> np.ndarray:
    """A smooth random RGB scene (blobs a few pixels wide: structure the coarse motion estimate can follow)."""
    rng = np.random.default_rng(seed)
    coarse = rng.uniform(0, 255, (size // 4, size // 4, 3)).astype(np.float32)
    import cv2

    return np.clip(cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC), 0, 255).astype(np.uint8)


def _moving_THW3(motion, steps: int = 6, size: int = 64) -> np.ndarray:
    """Frames of the scene seen by a camera that moves by ``motion`` (yaw, pitch, log zoom) every step."""
    scene = _scene_HW3(size=size)
    out = []
    for t in range(steps):
        m = np.asarray(motion, np.float64) * t
        out.append(np.stack([df.warp_HW(scene[..., c].astype(np.float32), m) for c in range(3)], -1))
    return np.clip(np.stack(out), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------------------------------------
# Frame statistics
# ---------------------------------------------------------------------------------------------


def test_view_change_is_mean_abs_grey_difference():
    a = np.zeros((2, 4, 4, 3), np.uint8)
    a[1] = 6  # every pixel +6 in every channel
    np.testing.assert_allclose(df.view_change_T(a), [6.0])
    assert df.view_change_T(a[:1]).shape == (0,)
    with pytest.raises(ValueError, match=r"\(T, H, W, 3\)"):
        df.view_change_T(a[0])


def test_frozen_dream_has_view_change_ratio_zero_and_frozen_fraction_one():
    engine = _moving_THW3((4.0, 0.0, 0.0))
    frozen = np.repeat(engine[:1], len(engine), axis=0)
    ce, cd = df.view_change_T(engine), df.view_change_T(frozen)
    assert (ce > df.FROZEN_ENGINE_MIN).all()
    assert df.ratio(cd.sum(), ce.sum()) == 0.0
    is_frozen, counted = df.frozen_T(cd, ce)
    assert df.ratio(is_frozen.sum(), counted.sum()) == 1.0
    # the engine against itself: ratio 1, nothing frozen
    assert df.ratio(ce.sum(), ce.sum()) == 1.0
    assert df.frozen_T(ce, ce)[0].sum() == 0
    assert df.ratio(1.0, 0.0) is None  # nothing to compare with


def _scored(within_e, within_d, change=4.0):
    """A Scored of len(within_e) steps whose only informative values are the view changes."""
    n = len(within_e)
    rollout = df.Rollout("forward", "learner", 0, None, "grass", True, 0, [], np.zeros((n + 1, 2, 2, 3), np.uint8),
                         np.zeros(n + 1), [None] * (n + 1), np.zeros((n + 1, 2)), np.asarray(within_e, np.float32))
    z, c = np.zeros(n), np.full(n, change)
    return df.Scored(rollout, c, c, z + 1, z + 1, z, z, z, z, np.zeros(n, bool), np.zeros((n, 3)), np.zeros((n, 3)),
                     [None] * n, [None] * n, [None] * n, [None] * n, [None] * n, [None] * n, None, None,
                     rollout.within_T, None if within_d is None else np.asarray(within_d, np.float32))


def test_within_step_change_sees_a_dream_that_jumps_once_per_step():
    """Inside a step: the engine against itself gives ratio 1; a dream that holds one picture for the step's k
    frames (and jumps between steps, so its per-step view change is the engine's) gives 0; a row with one frame
    per step (the formula) gives None."""
    step = _moving_THW3((2.0, 0.0, 0.0))[:4]  # one env step of k = 4 moving frames
    held = np.repeat(step[:1], 4, axis=0)
    assert df.within_step_change(step) == pytest.approx(float(df.view_change_T(step).mean())) and \
        df.within_step_change(step) > 1.0
    assert df.within_step_change(held) == 0.0 and df.within_step_change(step[:1]) == 0.0
    engine = [df.within_step_change(step)] * 5
    mask = np.ones(5, bool)
    assert df.summarize([(_scored(engine, engine), mask)])["within_step_change_ratio"] == 1.0
    jumping = df.summarize([(_scored(engine, [0.0] * 5), mask)])
    assert jumping["within_step_change_ratio"] == 0.0 and jumping["view_change_ratio"] == 1.0
    assert df.summarize([(_scored(engine, None), mask)])["within_step_change_ratio"] is None


def test_drifting_dream_on_a_still_engine_has_drift_fraction_one():
    still = np.repeat(_scene_HW3(0)[None], 6, axis=0)  # the engine stands still: every step changes 0
    drifting = np.stack([np.clip(f.astype(int) + 4 * i, 0, 255) for i, f in enumerate(still)]).astype(np.uint8)
    ce, cd = df.view_change_T(still), df.view_change_T(drifting)
    assert (ce < df.DRIFT_ENGINE_MAX).all() and (cd > df.DRIFT_DREAM_MIN).all()
    is_drifting, counted = df.drift_T(cd, ce)
    assert counted.all() and df.ratio(is_drifting.sum(), counted.sum()) == 1.0
    # the engine against itself, and a frozen dream of it: nothing drifts
    assert df.drift_T(ce, ce)[0].sum() == 0
    # a moving engine is not counted, whatever the dream does
    moving = df.view_change_T(_moving_THW3((4.0, 0.0, 0.0)))
    assert df.drift_T(moving, moving)[1].sum() == 0


def test_stand_still_program_is_the_no_op():
    from solaris_env.spaces import CAMERA_KEY, noop

    assert df.PROGRAMS["stand_still"].kind == "learner"
    action, want = df.learner_action("stand_still", 5), noop()
    assert set(action) == set(want)
    assert all(np.array_equal(action[k], want[k]) for k in want if k != CAMERA_KEY)
    assert np.array_equal(action[CAMERA_KEY], np.zeros(2, np.float32))


def test_sharpness_of_a_blurred_copy_is_lower():
    import cv2

    frames = np.stack([_scene_HW3(s) for s in range(3)])
    noisy = np.clip(frames + np.random.default_rng(0).integers(-40, 40, frames.shape), 0, 255).astype(np.uint8)
    blurred = np.stack([cv2.GaussianBlur(f, (0, 0), 1.5) for f in noisy])
    ratio = df.sharpness_T(blurred).sum() / df.sharpness_T(noisy).sum()
    assert ratio < 0.5
    flat = np.full((1, 8, 8, 3), 100, np.uint8)
    assert df.sharpness_T(flat)[0] == 0.0


def test_psnr():
    a = np.zeros((2, 4, 4, 3), np.uint8)
    b = a.copy()
    b[1] = 255
    p = df.psnr_T(a, b)
    assert p[0] == np.inf and p[1] == pytest.approx(0.0)
    with pytest.raises(ValueError, match="differ in shape"):
        df.psnr_T(a, b[:1])


def test_colour_error_compares_block_means_not_detail():
    """Equal frames score 0; a frame whose colours moved by 20 grey levels scores 20; fine detail that keeps
    each block's mean (a checkerboard against its flat mean) scores 0; a darkened sky half scores half."""
    sky_ground = np.zeros((3, 64, 64, 3), np.uint8)
    sky_ground[:, :32] = (120, 160, 230)
    sky_ground[:, 32:] = (80, 140, 50)
    assert df.colour_error_T(sky_ground, sky_ground).tolist() == [0.0, 0.0, 0.0]
    brighter = sky_ground.astype(np.int16) + 20
    np.testing.assert_allclose(df.colour_error_T(sky_ground, brighter.astype(np.uint8)), 20.0)
    checker = np.full((1, 64, 64, 3), 100, np.uint8)
    checker[0, ::2, ::2] = checker[0, 1::2, 1::2] = 200
    checker[0, ::2, 1::2] = checker[0, 1::2, ::2] = 0
    assert df.colour_error_T(checker, np.full_like(checker, 100))[0] == pytest.approx(0.0)
    dark_sky = sky_ground.copy()
    dark_sky[:, :32] = (20, 30, 60)
    want = np.mean([100, 130, 170]) / 2  # the sky half's blocks differ by the mean of 100, 130, 170
    np.testing.assert_allclose(df.colour_error_T(sky_ground, dark_sky), want)
    with pytest.raises(ValueError, match="equal"):
        df.colour_error_T(sky_ground, sky_ground[:1])
    with pytest.raises(ValueError, match="blocks"):
        df.colour_error_T(sky_ground[:, :30], sky_ground[:, :30])


# ---------------------------------------------------------------------------------------------
# Direction of motion
# ---------------------------------------------------------------------------------------------


def test_warp_turn_right_moves_content_left():
    img = np.zeros((64, 64), np.float32)
    img[:, 40:44] = 255  # a vertical bar right of the centre
    moved = df.warp_HW(img, (10.0, 0.0, 0.0))
    cols = np.flatnonzero(moved[32] > 128)
    assert cols.mean() < 40  # turning right: the bar moves left (~0.45 px/deg at the centre, more at the sides)
    down = df.warp_HW(np.where(np.arange(64)[:, None] > 40, 255.0, 0.0).astype(np.float32) + 0 * img,
                      (0.0, 10.0, 0.0))
    assert np.flatnonzero(down[:, 32] > 128).min() < 40  # looking down: the ground rises in the view
    zoom = df.warp_HW(img, (0.0, 0.0, 0.2))
    assert np.flatnonzero(zoom[32] > 128).mean() > 42  # zooming in: off-centre content moves outwards


@pytest.mark.parametrize("motion", [(4.0, 0.0, 0.0), (-6.0, 0.0, 0.0), (0.0, 5.0, 0.0), (0.0, 0.0, 0.06)])
def test_fit_motion_recovers_a_known_camera_motion(motion):
    frames = df.prepare_THW(_moving_THW3(motion, steps=3))
    fitted = df.fit_motion(frames[0], frames[1])
    assert (np.abs(fitted - np.asarray(motion)) <= [0.75, 0.75, 0.015]).all(), fitted
    assert df.has_motion(fitted[None])[0]


def test_direction_agreement_engine_self_frozen_reversed_mirrored():
    for motion in [(5.0, 0.0, 0.0), (0.0, 0.0, 0.05), (-3.0, 2.0, 0.0)]:
        engine = _moving_THW3(motion, steps=6)
        s = df.direction_scores(engine, engine)
        assert s["valid"].all() and (s["engine"] > 0.5).all()
        assert df.direction_agreement(s["engine"], s["dream"], s["valid"]) == pytest.approx(1.0)
        frozen = df.direction_scores(engine, np.repeat(engine[:1], len(engine), 0), motion_T3=s["motion"])
        assert df.direction_agreement(s["engine"], frozen["dream"], s["valid"]) == pytest.approx(0.0, abs=1e-9)
        reversed_ = df.direction_scores(engine, engine[::-1], motion_T3=s["motion"])
        assert df.direction_agreement(s["engine"], reversed_["dream"], s["valid"]) < -0.8
    turning = _moving_THW3((5.0, 0.0, 0.0), steps=6)
    s = df.direction_scores(turning)
    mirrored = df.direction_scores(turning, turning[:, :, ::-1], motion_T3=s["motion"])
    assert df.direction_agreement(s["engine"], mirrored["dream"], s["valid"]) < -0.5


def test_direction_score_is_antisymmetric_and_zero_for_equal_frames():
    f = df.prepare_THW(_moving_THW3((4.0, 1.0, 0.02), steps=2))
    m = df.fit_motion(f[0], f[1])
    assert df.direction_score(f[0], f[1], m) == pytest.approx(-df.direction_score(f[1], f[0], m))
    assert df.direction_score(f[0], f[0], m) == 0.0
    still = np.repeat(_scene_HW3()[None], 3, 0)
    s = df.direction_scores(still)
    assert not s["valid"].any()  # no motion: nothing to agree with
    assert df.direction_agreement(s["engine"], s["engine"], s["valid"]) is None


def test_camera_constants_match_the_renderer():
    from solaris_env.engine.constants import FOV_DEG
    from solaris_env.engine.render import RenderConfig

    assert df.FOV_DEG == FOV_DEG and df.DISPLAY_ASPECT == RenderConfig().display_aspect


# ---------------------------------------------------------------------------------------------
# Partner ground truth
# ---------------------------------------------------------------------------------------------


def test_partner_truth_follows_the_judges_labels():
    assert [df.visible_truth(n) for n in (0, 1, 2, 50)] == ["no", None, "yes", "yes"]
    assert df.position_truth(0, None) == "no player"
    assert df.position_truth(1, 0.5) is None
    assert [df.position_truth(9, u) for u in (0.1, 0.5, 0.9)] == ["left", "center", "right"]
    assert df.position_truth(9, 1 / 3 + 0.01) is None  # too close to a third boundary
    hits, n = df.agreement(["yes", "no", "yes", "no"], ["yes", "yes", None, "no"], np.array([1, 1, 1, 0], bool))
    assert (hits, n) == (1, 2)


def test_balanced_partner_agreement_gives_a_constant_answer_one_over_the_classes():
    """The judges answer "yes" (and "center") to noise; on truths that are mostly "yes" plain agreement rewards
    that, the balanced one scores it 1 / classes and a perfect judge 1."""
    truth = ["yes"] * 9 + ["no"] * 3 + [None]
    scope = np.ones(len(truth), bool)
    always_yes = ["yes"] * len(truth)
    hits, n = df.agreement(always_yes, truth, scope)
    assert hits / n == pytest.approx(0.75)
    per_class = df.class_agreement(always_yes, truth, scope)
    assert per_class == {"yes": [9, 9], "no": [0, 3]}
    assert df.balanced_agreement(per_class) == pytest.approx(0.5)
    assert df.balanced_agreement(df.class_agreement(truth[:-1] + ["no"], truth, scope)) == pytest.approx(1.0)
    assert np.isnan(df.balanced_agreement({}))
    positions = ["left", "center", "right", "no player"] * 2
    assert df.balanced_agreement(df.class_agreement(["center"] * 8, positions, np.ones(8, bool))) == 0.25


def _scored_rollout(program, dir_e, dir_d, valid, change_d, sharp_d, pos_truth, pos_d, kind="learner"):
    """A Scored of len(dir_e) steps with the given direction scores, view changes (the engine's 4 per step),
    sharpness (the engine's 10) and partner positions."""
    n = len(dir_e)
    rollout = df.Rollout(program, kind, 0, None, "grass", True, 0, [], np.zeros((n + 1, 2, 2, 3), np.uint8),
                         np.zeros(n + 1), [None] * (n + 1), np.zeros((n + 1, 2)))
    vis_truth = ["no" if t == "no player" else ("yes" if t else None) for t in pos_truth]
    return df.Scored(rollout, np.full(n, 4.0), np.asarray(change_d, float), np.full(n, 10.0),
                     np.asarray(sharp_d, float), np.zeros(n), np.zeros(n), np.asarray(dir_e, float),
                     np.asarray(dir_d, float), np.asarray(valid, bool), np.zeros((n, 3)), np.zeros((n, 3)),
                     vis_truth, list(pos_truth), [None] * n, list(pos_truth), [None] * n, list(pos_d), None, None)


def _rollouts(rng, n=4, steps=40, quality=0.5):
    """n random rollouts per program of forward, random and partner_toward; the dream's direction scores are
    ``quality`` times the engine's plus noise, its positions right with probability ``quality``."""
    out = []
    for program in ("forward", "random", "partner_toward"):
        for _ in range(n):
            de = rng.uniform(0.3, 1.0, steps)
            truth = list(rng.choice(["left", "center", "right", "no player"], steps))
            pos_d = [t if rng.random() < quality else "center" for t in truth]
            out.append(_scored_rollout(program, de, quality * de + rng.normal(0, 0.2, steps), rng.random(steps) < 0.7,
                                       rng.uniform(0, 8, steps), rng.uniform(5, 12, steps), truth, pos_d,
                                       "partner" if program == "partner_toward" else "learner"))
    return out


def test_headline_sums_reproduce_summarize():
    """The bootstrap's ratio-of-sums metrics are the overall table's, and the late sharpness is that of random
    play's steps 33 on."""
    scored = _rollouts(np.random.default_rng(0))
    point = df.headline(np.stack([df.rollout_sums(s) for s in scored]).sum(0))[0]
    overall = df.summarize([(s, np.ones(len(s.steps), bool)) for s in scored])
    assert point[0] == pytest.approx(overall["direction_agreement"], abs=5e-4)
    assert point[1] == pytest.approx(overall["view_change_ratio"], abs=5e-4)
    assert point[3] == pytest.approx(overall["position_balanced_dream"], abs=5e-4)
    late = df.summarize([(s, df.window_mask(s.steps, df.LATE_STEPS)) for s in scored if s.rollout.program == "random"])
    assert point[2] == pytest.approx(late["sharpness_ratio"], abs=5e-4)
    assert np.isnan(df.headline(np.zeros(len(df.rollout_sums(scored[0]))))).all()  # nothing counted: no value


def test_bootstrap_pairs_models_on_the_same_draws():
    """A model against itself differs by exactly 0 on every draw; a better model's difference lies above 0 on
    every draw; intervals hold the point value; a stratum of one rollout is always drawn as itself."""
    rng = np.random.default_rng(1)
    weak, strong = _rollouts(rng, quality=0.3), _rollouts(np.random.default_rng(1), quality=0.9)
    sums = {"weak": np.stack([df.rollout_sums(s) for s in weak]),
            "same": np.stack([df.rollout_sums(s) for s in weak]),
            "strong": np.stack([df.rollout_sums(s) for s in strong])}
    strata = [s.rollout.program for s in weak]
    u = df.bootstrap(sums, strata, draws=300)
    for m in df.HEADLINE:
        assert u["differences"]["same"][m] == {"value": 0.0, "interval": [0.0, 0.0], "share_above_zero": 0.0}
        lo, hi = u["models"]["weak"][m]["interval"]
        assert lo <= u["models"]["weak"][m]["value"] <= hi and lo < hi
    for m in ("direction_agreement", "position_balanced_dream"):
        d = u["differences"]["strong"][m]
        assert d["interval"][0] > 0 and d["share_above_zero"] == 1.0
    one = {k: v[:1] for k, v in sums.items()}  # one rollout: every draw is that rollout
    single = df.bootstrap(one, strata[:1], draws=50)["models"]["weak"]["direction_agreement"]
    assert single["interval"][0] == single["interval"][1] == single["value"]
    with pytest.raises(ValueError, match="one row of sums per rollout"):
        df.bootstrap({"a": sums["weak"][:3]}, strata)


# ---------------------------------------------------------------------------------------------
# Programs and start states
# ---------------------------------------------------------------------------------------------


def test_programs_are_long_enough_and_pitch_stays_bounded():
    for p in df.PROGRAMS.values():
        assert p.steps >= (256 if p.name in ("random", "bot") else 64)
        assert p.kind in ("learner", "partner", "both")
    for name, sign in (("pitch_up", -1), ("pitch_down", 1)):
        d = np.array([df.learner_action(name, t)["camera"][0] for t in range(64)])
        assert (np.sign(d) == sign).mean() == 0.75  # the program's way, mostly
        cum = np.cumsum(d)
        assert np.abs(cum).max() <= 30 and (np.sign(cum[cum != 0]) == sign).all()
    assert df.learner_action("yaw_left_15", 0)["camera"].tolist() == [0.0, -15.0]
    assert df.learner_action("mine", 0)["hotbar.2"] == 1 and df.learner_action("mine", 5)["attack"] == 1
    assert [df.learner_action("place", t)["use"] for t in range(3, 20)].count(1) == 3
    with pytest.raises(ValueError, match="not a learner program"):
        df.learner_action("partner_toward", 0)


def test_partner_programs_close_the_loop_on_the_engine():
    def infos(d):
        return {df.LEARNER: {"pos": np.zeros(3)}, df.PARTNER: {"pos": np.array([d, 0.0, 0.0])}}

    assert df.partner_action("partner_toward", 0, infos(8.0))["forward"] == 1
    assert df.partner_action("partner_toward", 0, infos(1.5))["forward"] == 0
    assert df.partner_action("partner_away", 0, infos(8.0))["back"] == 1
    assert df.partner_action("partner_away", 0, infos(25.0))["back"] == 0
    across = [df.partner_action("partner_across", t, infos(8.0)) for t in range(64)]
    assert sum(a["left"] for a in across) == sum(a["right"] for a in across) == 32


def test_random_play_is_seeded_and_bounded():
    infos = {a: {"pitch": 0.3} for a in (df.LEARNER, df.PARTNER)}
    a, b = df.RandomPlay(3), df.RandomPlay(3)
    for t in range(20):
        x, y = a(t, infos), b(t, infos)
        for agent in x:
            assert np.array_equal(x[agent]["camera"], y[agent]["camera"])
            assert np.abs(x[agent]["camera"]).max() <= 15


def test_merge_ticks():
    from solaris_env.spaces import noop, step_ticks

    ticks = [noop() for _ in range(4)]
    ticks[0]["forward"] = ticks[1]["forward"] = 1  # held on half of the ticks: held
    ticks[0]["jump"] = 1  # one tick of a held key: not held
    ticks[3]["use"] = 1  # a once-key on any tick
    ticks[2]["attack"] = 1  # attack is held (digging): one tick of four is not held
    for t in ticks:
        t["camera"] = np.array([1.0, 9.0], np.float32)
    a = df.merge_ticks(ticks)
    assert (a["forward"], a["jump"], a["use"], a["attack"]) == (1, 0, 1, 0)
    assert a["camera"][0] == 4.0  # summed
    assert 34.37 < a["camera"][1] < 34.38  # clipped at what 4 ticks turn (4 x 8.594 deg): nothing carried over
    _, pending = step_ticks(a, 4)
    assert not pending.any()


class _FakeState:
    def __init__(self, world, in_view):
        self.world, self.in_view = world, in_view


def test_assign_states_puts_a_normal_world_first_and_partner_programs_in_view():
    states = [_FakeState(w, v) for w in df.WORLD_CLASSES for v in (True, False)] + \
             [_FakeState("normal", v) for v in (True, False)]
    programs = list(df.PROGRAMS.values())
    out = df.assign_states(states, programs, 3, 2)
    assert out["bot"] == []
    for p in programs:
        if p.name == "bot":
            continue
        idx = out[p.name]
        assert len(idx) == (2 if p.steps > 64 else 3) and len(set(idx)) == len(idx)
        assert states[idx[0]].world == "normal"
        if p.kind == "partner":
            assert all(states[i].in_view for i in idx)
    used = {i for v in out.values() for i in v}
    assert {states[i].world for i in used} == set(df.WORLD_CLASSES)


def test_stand_still_comes_last_and_leaves_the_other_programs_start_states():
    """The assignment's cursors carry over between programs, so a program added in the middle would move the
    start states of every later one and break comparisons with earlier results; ``stand_still`` (session 47) is
    last."""
    states = [_FakeState(w, v) for w in df.WORLD_CLASSES for v in (True, False)] + \
             [_FakeState("normal", v) for v in (True, False)]
    programs = list(df.PROGRAMS.values())
    assert programs[-1].name == "stand_still"
    with_it, without = df.assign_states(states, programs, 3, 2), df.assign_states(states, programs[:-1], 3, 2)
    assert {k: v for k, v in with_it.items() if k != "stand_still"} == without


def test_model_specs_and_labels_never_absolute():
    assert df.model_label("default") == "shipped default"
    assert df.model_label(df.FORMULA) == "formula: the default's warps alone, no model"
    assert df.model_label("preset:test") == "preset test (random init)"
    assert df.model_label(str(df.REPO / "runs" / "a" / "model")) == "runs/a/model"
    assert not df.model_label("/somewhere/else/runs/b/model").startswith("/")


def test_sampler_overrides_in_a_model_spec():
    """``SPEC@name=value``: the same weights under another rollout setting, labelled so."""
    assert df.split_spec("default@noise_warp=0") == ("default", {"noise_warp": 0.0})
    assert df.split_spec("runs/a/model") == ("runs/a/model", {})
    assert df.split_spec("default@bidirectional_steps=5") == ("default", {"bidirectional_steps": 5})  # int stays int
    assert isinstance(df.split_spec("default@bidirectional_steps=5")[1]["bidirectional_steps"], int)
    assert df.model_label("default@noise_warp=0,shift=3") == "shipped default, sampler noise_warp 0, sampler shift 3"
    model = df.load_model("preset:test@shift=3,bidirectional_steps=4")
    assert (model.config.sampler.shift, model.config.sampler.bidirectional_steps) == (3.0, 4)
    for bad, match in (("default@eta=1", "SamplerConfig fields"), ("default@noise_warp", "SamplerConfig fields"),
                       ("default@noise_warp=x", "must be a number"),
                       ("default@bidirectional_steps=2.5", "must be an integer")):
        with pytest.raises(ValueError, match=match):
            df.split_spec(bad)
    with pytest.raises(ValueError, match="noise_warp"):  # the test preset has no camera warp to move noise by
        df.load_model("preset:test@noise_warp=0.5")
    with pytest.raises(ValueError, match="no sampler"):
        df.load_model(df.FORMULA + "@noise_warp=0")


def test_warp_formula_replays_the_warps_on_pixels():
    """The reference row: standing still keeps the frame bit for bit, a right turn moves the content left by
    the camera warp's pixels per degree, walking forward magnifies the view about its centre."""
    from solaris_env.world_model.config import WorldModelConfig

    cfg = WorldModelConfig.tiny16()
    formula = df.WarpFormula(cfg)
    assert formula.pixels_per_degree == pytest.approx((cfg.dit.camera_warp[0] * 4, cfg.dit.camera_warp[1] * 4))
    yy, xx = np.mgrid[0:64, 0:64]
    first = np.stack([(xx * 4) % 256, (yy * 4) % 256, (xx * yy) % 256], -1).astype(np.uint8)
    yaw = 2.0 / formula.pixels_per_degree[1]  # a right turn that moves the content 2 pixels left
    actions = [{df.LEARNER: df.make_action(), df.PARTNER: df.make_action()},
               {df.LEARNER: df.make_action(camera=(0.0, yaw)), df.PARTNER: df.make_action()},
               {df.LEARNER: df.make_action(forward=1), df.PARTNER: df.make_action()}]
    rollout = df.Rollout("test", "learner", 0, None, "grass", False, 0, actions, first[None], np.zeros(1),
                         [None], np.zeros((1, 2)))
    frames = formula.rollout(rollout)
    assert frames.shape == (4, 64, 64, 3) and frames.dtype == np.uint8
    np.testing.assert_array_equal(frames[1], first)
    np.testing.assert_allclose(frames[2][:, :-2].astype(float), first[:, 2:].astype(float), atol=1)
    np.testing.assert_array_equal(frames[2][:, -2:], np.repeat(first[:, -1:], 2, axis=1))  # the edge repeated
    centre = frames[3][28:36, 28:36].astype(float)
    assert np.abs(frames[3].astype(float) - frames[2].astype(float)).mean() > 1.0
    assert np.abs(np.diff(centre, axis=1)).mean() < np.abs(np.diff(frames[2][28:36, 28:36].astype(float), axis=1)).mean()
    with pytest.raises(ValueError, match="camera warp"):
        df.WarpFormula(WorldModelConfig.test())


# ---------------------------------------------------------------------------------------------
# End to end (test preset: random weights, 32 x 32)
# ---------------------------------------------------------------------------------------------


def test_dream_seed_moves_only_the_dream_reset_seed():
    """``--dream-seed`` adds to the dream's reset seed (its sampling noise) and leaves the start state and the
    actions as the engine played them."""
    class Recorder:  # what dream_rollout uses of a dream env
        possible_agents = [df.LEARNER, df.PARTNER]

        def __init__(self):
            self.resets, self.steps = [], []

        def step_frames(self):  # (P, k, H, W, 3)
            frames = np.zeros((2, 2, 2, 2, 3), np.uint8)
            frames[0, 1] = 3  # the learner's k = 2 frames differ by 3 grey levels, the partner's not at all
            return frames

        def reset(self, seed, options):
            self.resets.append((seed, options["engine_state"]))
            return {df.LEARNER: np.zeros((2, 2, 3), np.uint8)}, {}

        def step(self, action):
            self.steps.append(action)
            return {df.LEARNER: np.full((2, 2, 3), len(self.steps), np.uint8)}, {}, {}, {}, {}

    actions = [{df.LEARNER: df.make_action(forward=1), df.PARTNER: df.make_action()}] * 3
    rollout = df.Rollout("forward", "learner", 0, "START", "grass", True, 41, actions,
                         np.zeros((4, 2, 2, 3), np.uint8), np.zeros(4), [None] * 4, np.zeros((4, 2)))
    for dream_seed in (0, 5):
        env = Recorder()
        frames, within = df.dream_rollout(env, rollout, dream_seed)
        assert env.resets == [(41 + dream_seed, "START")] and env.steps == actions
        assert frames.shape == (4, 2, 2, 3) and frames[3, 0, 0, 0] == 3
        np.testing.assert_allclose(within, [3.0, 3.0, 3.0])  # the learner's step frames, not the partner's
    with pytest.raises(ValueError, match="--dream-seed"):
        df.main(["--dream-seed", "-1"])


def _rollout_of(steps: int, seed: int, start: str = "START") -> "df.Rollout":
    return df.Rollout("p", "learner", 0, start, "grass", True, seed, [None] * steps, np.zeros((steps + 1, 2, 2, 3)),
                      np.zeros(steps + 1), [None] * (steps + 1), np.zeros((steps + 1, 2)))


def test_dream_batches_group_rollouts_by_length_in_even_batches():
    rollouts = [_rollout_of(n, i) for i, n in enumerate([64] * 7 + [256, 64, 256, 64])]
    assert df.dream_batches(rollouts, 4) == [[0, 1, 2], [3, 4, 5], [6, 8, 10], [7, 9]]  # 9 of 64: 3 + 3 + 3
    assert df.dream_batches(rollouts, 16) == [[0, 1, 2, 3, 4, 5, 6, 8, 10], [7, 9]]
    assert df.dream_batches(rollouts, 1) == [[i] for i in (0, 1, 2, 3, 4, 5, 6, 8, 10, 7, 9)]
    assert df.dream_batches([], 4) == []
    with pytest.raises(ValueError, match="batch"):
        df.dream_batches(rollouts, 0)


def test_batched_dream_rollouts_equal_one_world_at_a_time():
    """``dream_rollouts`` (worlds joined on the batch axis) gives each rollout the frames and within-step changes
    of ``dream_rollout`` (one ``DreamParallelEnv`` reset and step at a time): the same start, model seed, noise
    and per-tick actions (turns carried between steps), rollouts of two lengths."""
    from solaris_env.dream_env import DreamParallelEnv

    env = DreamParallelEnv(preset="test")
    h, w = env.model.frame_shape[:2]
    starts = {s: np.random.default_rng(i).integers(0, 256, (2, h, w, 3), dtype=np.uint8)
              for i, s in enumerate(("A", "B", "C"))}

    class Starts:  # engine states stand-in: a name -> fixed start frames
        def from_options(self, options):
            return starts[options["engine_state"]], {"start": "engine_state"}

    env.start_frames = Starts()
    act = lambda i: {df.LEARNER: df.make_action(forward=i % 2, camera=[0.0, 50.0 * (i % 3)]),
                     df.PARTNER: df.make_action(left=1, camera=[-20.0, 0.0])}
    rollouts = [_rollout_of(n, seed, start) for n, seed, start in ((3, 7, "A"), (2, 8, "B"), (3, 9, "C"))]
    for r in rollouts:
        r.actions = [act(i) for i in range(len(r.actions))]
    batched = df.dream_rollouts(env, rollouts, dream_seed=2, batch=2)
    for r, (frames, within) in zip(rollouts, batched):
        ref_frames, ref_within = df.dream_rollout(env, r, dream_seed=2)
        assert frames.shape == ref_frames.shape == (len(r.actions) + 1, h, w, 3)
        assert np.abs(frames.astype(int) - ref_frames).max() <= 1
        np.testing.assert_allclose(within, ref_within, atol=0.05)


@pytest.mark.slow  # ~50 s on 2 shared cores, ~45 of them building and compiling the test-preset model
def test_end_to_end_tiny_run_writes_json_png_mp4(tmp_path):
    out = tmp_path / "fid.json"
    result = df.main(["--model", "preset:test", "--quick", "--steps", "3", "--per-program", "1",
                      "--programs", "forward", "yaw_right_15", "partner_toward", "bot", "--out", str(out)])
    text = out.read_text()
    assert json.loads(text)["benchmark"] == "dream_fidelity"
    assert (tmp_path / "fid.png").stat().st_size > 0 and (tmp_path / "fid.mp4").stat().st_size > 0
    assert str(tmp_path) not in text and str(df.REPO) not in text  # no absolute paths
    setup = result["setup"]
    assert setup["models"] == [{"spec": "preset:test", "name": "preset test (random init)"}]
    assert setup["dream_seed"] == 0
    assert {s["world"] for s in setup["start_states"]} == set(df.WORLD_CLASSES)
    assert {s["partner_in_view"] for s in setup["start_states"]} == {True, False}
    assert setup["bot_episode"]["type"]
    res = result["results"]["preset test (random init)"]
    assert set(res["programs"]) == {"forward", "yaw_right_15", "partner_toward", "bot"}
    row = res["programs"]["yaw_right_15"]["windows"]["1-8"]
    assert row["steps"] == 3 and row["view_change_engine"] > 1.0
    assert row["sharpness_ratio"] is not None and row["psnr_db"] > 0
    assert res["programs"]["partner_toward"]["all"]["visible_counted_steps"] >= 1
    assert "normal" in res["surfaces"] and res["overall"]["steps"] > 0
    v = result["estimator_validation"]["all"]
    assert v["valid_steps"] > 0 and v["agreement_self"] == 1.0 and v["agreement_frozen"] == 0.0
    assert v["agreement_reversed"] == -1.0
    u = result["uncertainty"]["models"]["preset test (random init)"]
    assert set(u) == set(df.HEADLINE) and u["view_change_ratio"]["value"] == res["overall"]["view_change_ratio"]
    assert math.isfinite(result["wall_s"]) and "machine" in result
