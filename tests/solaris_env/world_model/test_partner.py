"""The partner map (``partner.py``, docs/model.md §8.6): projection, coverage, dead reckoning, and the streaming
model's use of them."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from solaris_env.world_model import partner


def pose(x=0.0, y=0.0, z=0.0, yaw=0.0, pitch=0.0):
    return jnp.array([x, y, z, yaw, pitch], jnp.float32)


def test_partner_straight_ahead_is_centred_and_shrinks_with_distance():
    viewer = pose()
    near, valid_near = partner.box_on_screen(viewer, pose(z=-4.0))  # yaw 0 looks north (-Z)
    far, valid_far = partner.box_on_screen(viewer, pose(z=-8.0))
    assert bool(valid_near) and bool(valid_far)
    for box in (near, far):
        assert abs(float(box[0] + box[2]) / 2 - 0.5) < 1e-6  # centred left-right
    width = lambda b: float(b[2] - b[0])
    assert width(far) < width(near)
    # the box's nearest face (0.3 blocks closer) sets its width: 0.6 / (d - 0.3) / (2 tan(half width angle))
    tx = partner.VIEW_HALF_TAN[1]
    assert width(near) == pytest.approx(0.6 / (3.7 * tx) / 2, rel=1e-5)
    # the feet are below the eye: the box spans the horizon (v = 0.5) at eye height 1.62 of 1.8
    assert float(near[1]) < 0.5 < float(near[3])


def test_partner_to_the_left_behind_and_turning():
    viewer = pose()
    left, _ = partner.box_on_screen(viewer, pose(x=-2.0, z=-6.0))  # -X is to the left when facing -Z
    assert float(left[2]) < 0.5
    _, behind = partner.box_on_screen(viewer, pose(z=6.0))
    assert not bool(behind)
    # turning left (+yaw) by the partner's bearing centres it
    bearing = math.atan2(2.0, 6.0)
    centred, _ = partner.box_on_screen(pose(yaw=bearing), pose(x=-2.0, z=-6.0))
    assert abs(float(centred[0] + centred[2]) / 2 - 0.5) < 2e-3  # the box is seen a little from the side


def test_coverage_is_the_covered_share_of_each_cell():
    box = jnp.array([[0.25, 0.5, 0.625, 1.0]])  # cells of a 4 x 8 grid: columns 2..5 (half of 4), rows 2..3
    cov = np.asarray(partner.coverage(box, jnp.array([True]), 4, 8))[0]
    assert cov.shape == (4, 8)
    assert cov[2:, 2:5].min() == 1.0 and cov[:2].max() == 0.0
    np.testing.assert_allclose(cov[2:, 5], 0.0)
    assert cov.sum() == pytest.approx(0.375 * 8 * 0.5 * 4)  # the box's area in cells
    np.testing.assert_array_equal(partner.coverage(box, jnp.array([False]), 4, 8), 0.0)
    outside = jnp.array([[1.2, 0.2, 1.5, 0.8]])  # off the right edge
    assert float(partner.coverage(outside, jnp.array([True]), 4, 8).sum()) == 0.0


def test_partner_maps_and_latent_frames():
    poses = jnp.stack([pose(), pose(z=-5.0, yaw=math.pi)])  # facing each other
    maps = partner.partner_maps(poses, 16, 16)
    assert maps.shape == (2, 16, 16)
    np.testing.assert_allclose(maps[0], maps[1], atol=1e-6)  # the same geometry both ways
    assert float(maps[0].sum()) > 0
    with pytest.raises(ValueError, match="two players"):
        partner.partner_maps(jnp.zeros((3, 5)), 16, 16)
    video = jnp.arange(9, dtype=jnp.float32)[:, None, None] * jnp.ones((9, 2, 2))  # T = 1 + 4 * 2
    latent = partner.latent_frame_maps(video, 4)
    np.testing.assert_allclose(latent[:, 0, 0], [0.0, 2.5, 6.5])
    with pytest.raises(ValueError, match="1 \\+ k"):
        partner.latent_frame_maps(video[:8], 4)


def test_with_partner_puts_the_map_after_the_mask():
    cond = jnp.arange(2 * 3 * 6, dtype=jnp.float32).reshape(2, 3, 6)  # 2 mask + 4 latent channels
    out = partner.with_partner(cond, jnp.full((2, 3), -1.0), 2)
    assert out.shape == (2, 3, 7)
    np.testing.assert_array_equal(out[..., :2], cond[..., :2])
    np.testing.assert_array_equal(out[..., 2], -1.0)
    np.testing.assert_array_equal(out[..., 3:], cond[..., 2:])
    with pytest.raises(ValueError, match="must match"):
        partner.with_partner(cond, jnp.zeros((2, 4)), 2)


def test_tracking_walks_and_turns_like_minecraft():
    from solaris_env.spaces import CAMERA_SCALE_DEG, MODEL_ACTION_DIM, MODEL_INDEX

    keys = np.zeros((60, MODEL_ACTION_DIM - 2), np.float32)
    keys[:, MODEL_INDEX["forward"]] = 1
    mouse = np.zeros((60, 2), np.float32)
    poses, last = partner.track(partner.track_state(pose()), jnp.asarray(mouse), jnp.asarray(keys))
    assert poses.shape == (60, 5) and last.shape == (7,)
    step = np.diff(np.asarray(poses[:, 2]))
    assert step[-1] == pytest.approx(-partner.WALK_SPEED, rel=1e-3)  # top speed north (-Z) after the ramp
    assert step[0] > step[-1]  # it accelerates
    # a left turn (+cameraX) of 90 degrees, then forward walks west (-X)
    mouse[:1, 0] = 90.0 / CAMERA_SCALE_DEG
    poses, _ = partner.track(partner.track_state(pose()), jnp.asarray(mouse), jnp.asarray(keys))
    assert float(poses[0, 3]) == pytest.approx(math.pi / 2)
    assert float(poses[-1, 0]) < -5.0 and abs(float(poses[-1, 2])) < 1e-3
    with pytest.raises(ValueError, match="5 numbers"):
        partner.track_state(jnp.zeros(4))


def test_projection_and_tracking_against_the_engine():
    """The box's centre against the renderer's avatar pixels, and dead reckoning against the engine's poses,
    on flat worlds with both players walking and turning (the dream env's per-tick actions)."""
    from solaris_env.dream_env import world_actions
    from solaris_env.real_env import RealParallelEnv
    from solaris_env.spaces import noop

    env = RealParallelEnv(num_players=2, world="flat", resolution=64, ticks_per_step=4, hud=False)
    agents = env.possible_agents
    errors_u, errors_pos = [], []
    for seed in range(3):
        obs, infos = env.reset(seed=seed)
        start = env.engine_state()
        state = partner.track_state(jnp.asarray(start.poses))
        pending = np.zeros((2, 2))
        for t in range(12):  # (step 0 stands: the engine's first tick after a reset is airborne)
            actions = {a: {**noop(), "forward": int(t % 3 != 0), "left": int(p == 1 and t > 0),
                           "camera": np.array([0.0, 6.0 if p == 0 else -4.0], np.float32)}
                       for p, a in enumerate(agents)}
            infos = env.step(actions)[4]
            ticks, _, pending = world_actions(actions, agents, agents, 4, pending)
            ticks = jnp.asarray(ticks)
            _, state = partner.track(state, ticks[..., 23:], ticks[..., :23])
            truth = env.engine_state().poses
            errors_pos.append(np.hypot(*(np.asarray(state[:, [0, 2]]) - truth[:, [0, 2]]).T).max())
            box, valid = partner.box_on_screen(jnp.asarray(truth), jnp.asarray(truth[::-1]))
            for p, a in enumerate(agents):
                seen = infos[a]["screen"][agents[1 - p]]
                if seen["pixels"] >= 4 and bool(valid[p]):
                    errors_u.append(abs(float(box[p, 0] + box[p, 2]) / 2 - seen["u"]))
    assert len(errors_u) >= 10
    # (a partner cut by the frame edge shows its visible part's centroid, not the box's centre)
    assert np.median(errors_u) < 0.01 and np.quantile(errors_u, 0.9) < 0.02
    assert max(errors_pos) < 0.05  # blocks, after 48 ticks on a flat world


def _partner_model(tmp_path, scale=10.0):
    """A test-preset model (camera warp on, as shipped) and the same weights with the partner map turned on."""
    import dataclasses

    from solaris_env.world_model.config import preset
    from solaris_env.world_model.world_model import WorldModel
    from training import cli

    base = preset("test")
    cfg = base.replace(dit=dataclasses.replace(base.dit, camera_warp=(0.1, 0.06), walk_warp=0.1,
                                               warp_geometry="rotation"))
    from solaris_env.world_model import checkpoint
    from solaris_env.world_model.components import COMPONENTS

    params = WorldModel.from_config(cfg, seed=1).params
    head = params[0]["head"]["head"]["kernel"]  # zero at initialisation: give the DiT an output that reads its input
    head.set_value(0.05 * jax.random.normal(jax.random.key(2), head.get_value().shape))
    checkpoint.save(tmp_path / "base", cfg, dict(zip(COMPONENTS, params)))
    assert cli.main(["action-conditioning", str(tmp_path / "base"), "--partner-map", str(scale),
                     "--out", str(tmp_path / "pm")]) == 0
    return WorldModel.load(tmp_path / "base"), WorldModel.load(tmp_path / "pm")


def _inputs(model, b=2, steps=3):
    rng = np.random.default_rng(0)
    h, w, _ = model.frame_shape
    first = rng.integers(0, 256, (b, 2, h, w, 3), dtype=np.uint8)
    actions = np.zeros((steps, b, 2, model.frames_per_step, model.action_dim), np.float32)
    actions[..., 0, 23] = 0.4  # Alpha turns left 6 degrees per tick
    from solaris_env.spaces import MODEL_INDEX
    actions[:, :, 1, :, MODEL_INDEX["forward"]] = 1  # Bravo walks
    poses = np.array([[[0.0, 64.0, 0.0, 0.3, 0.0], [-2.0, 64.0, -6.0, math.pi, 0.0]]] * b, np.float32)
    return first, actions, poses


def test_a_zero_map_row_keeps_the_function_and_the_state_tracks_the_poses(tmp_path):
    base, pm = _partner_model(tmp_path)
    cfg = pm.config
    assert cfg.dit.partner_map == 10.0 and cfg.in_channels == base.config.in_channels + 1
    kernel = pm.params[0]["patch_embedding"]["kernel"].get_value()
    at = cfg.out_channels + cfg.mask_channels  # the map's row: after the noisy latent and the mask
    np.testing.assert_array_equal(kernel[..., at, :], 0.0)
    first, actions, poses = _inputs(pm)
    with pytest.raises(ValueError, match="poses"):
        pm.init(first, 0)
    with pytest.raises(ValueError, match=r"poses has shape \(2, 5\)"):
        pm.init(first, 0, poses=poses[0])
    s_base, s_pm = base.init(first, 0), pm.init(first, 0, poses=poses)
    np.testing.assert_array_equal(s_base.frame0_BPHW3, s_pm.frame0_BPHW3)
    track = partner.track_state(jnp.asarray(poses))
    np.testing.assert_allclose(s_pm.partner_BPhw, partner.partner_maps(jnp.asarray(poses), *s_pm.partner_BPhw.shape[-2:]))
    for a in actions:
        f_base, s_base = base.step(s_base, a)
        f_pm, s_pm = pm.step(s_pm, a)
        # the zero row: the same frames up to float rounding (the extra input channel changes the patch matmul's
        # shape, and with it XLA's summation order on some CPUs): a grey level on a few pixels at most
        diff = np.abs(np.asarray(f_base, np.int16) - np.asarray(f_pm, np.int16))
        assert diff.max() <= 1 and np.count_nonzero(diff) <= 1e-3 * diff.size, (diff.max(), np.count_nonzero(diff))
        poses_BPK5, track = partner.track(track, jnp.asarray(a[..., 23:]), jnp.asarray(a[..., :23]))
        np.testing.assert_allclose(s_pm.track_BP7, track, atol=1e-5)
        maps = partner.partner_maps(jnp.moveaxis(poses_BPK5, 2, 1), *s_pm.partner_BPhw.shape[-2:]).mean(axis=1)
        np.testing.assert_allclose(s_pm.partner_BPhw, maps, atol=1e-6)
    assert float(jnp.abs(s_pm.partner_BPhw).sum()) > 0  # the partners are in view


def test_the_map_reaches_the_dit(tmp_path):
    """With a non-zero map row the frames depend on where the partner is."""
    from solaris_env.world_model import checkpoint
    from solaris_env.world_model.components import COMPONENTS
    from solaris_env.world_model.world_model import WorldModel

    _, pm = _partner_model(tmp_path)
    params = pm.params
    k = params[0]["patch_embedding"]["kernel"]
    at = pm.config.out_channels + pm.config.mask_channels
    k.set_value(k.get_value().at[..., at, :].set(0.5))
    checkpoint.save(tmp_path / "read", pm.config, dict(zip(COMPONENTS, params)))
    model = WorldModel.load(tmp_path / "read")
    first, actions, poses = _inputs(pm, b=1, steps=1)
    far = poses.copy()
    far[:, 1, :3] = [40.0, 64.0, 40.0]  # Bravo out of Alpha's view, Alpha out of Bravo's
    frames = [np.asarray(model.step(model.init(first, 0, poses=p), actions[0])[0]) for p in (poses, far)]
    assert np.abs(frames[0].astype(int) - frames[1].astype(int)).max() > 0


def test_the_dream_envs_pass_the_start_poses(tmp_path):
    """The dream env and the vector env start a partner-map model from an engine game's poses or a bundled scene's,
    and refuse a start from given frames alone with a message that says why."""
    from solaris_env.dream_env import DreamParallelEnv
    from solaris_env.real_env import RealParallelEnv
    from solaris_env.spaces import noop
    from solaris_env.start_scenes import load_start_scenes
    from solaris_env.vector_env import DreamVectorEnv

    _, pm = _partner_model(tmp_path)
    h, w, _ = pm.frame_shape
    real = RealParallelEnv(num_players=2, world="flat", resolution=(h, w))
    starts = []
    for seed in (0, 1):
        real.reset(seed=seed)
        starts.append(real.engine_state())
    env = DreamParallelEnv(model=pm, start_states=starts)
    env.reset(seed=0, options={"engine_state": starts[1]})
    np.testing.assert_allclose(env._state.track_BP7[0, :, :5], starts[1].poses, atol=1e-5)
    env.step({a: noop() for a in env.agents})
    frames = {a: np.zeros((h, w, 3), np.uint8) for a in env.possible_agents}
    with pytest.raises(ValueError, match="needs the players' poses"):
        env.reset(seed=0, options={"frames": frames})
    vec = DreamVectorEnv(2, model=pm, start_states=starts)
    vec.reset(seed=0, options={"engine_state": starts})
    np.testing.assert_allclose(vec._state.track_BP7[:, :, :5], np.stack([s.poses for s in starts]), atol=1e-5)
    vec.reset(seed=1)  # sampled from the engine states
    with pytest.raises(ValueError, match="needs the players' poses"):
        DreamVectorEnv(2, model=pm, start_states=np.zeros((1, 2, h, w, 3), np.uint8)).reset(seed=0)
    scenes = load_start_scenes(2, h, w)
    bundled = DreamParallelEnv(model=pm)  # the default start: the bundled scenes, which carry their poses
    _, infos = bundled.reset(seed=3)
    np.testing.assert_allclose(bundled._state.track_BP7[0, :, :5], scenes.poses_SP5[infos["Alpha"]["scene"]],
                               atol=1e-5)
    vec = DreamVectorEnv(2, model=pm)
    _, infos = vec.reset(seed=4)
    np.testing.assert_allclose(vec._state.track_BP7[:, :, :5],
                               scenes.poses_SP5[[s["scene"] for s in infos["start"]]], atol=1e-5)
