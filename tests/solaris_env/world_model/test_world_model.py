"""The streaming WorldModel API: shapes, determinism, per-world reset, flat memory, input checks, and the
streaming step == an offline rollout written here with the DiT's decode (docs/model.md §5.3-§5.5).

Models use the ``test`` preset with random non-degenerate weights (the real init's zero head would make
every velocity 0 and the sampler trivial).
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model import kv_cache
from solaris_env.world_model.action_module import action_windows, left_pad_actions
from solaris_env.world_model.components import abstract_modules
from solaris_env.world_model.conditioning import first_frame_cond
from solaris_env.world_model.config import WorldModelConfig
from solaris_env.world_model.world_model import (Programs, WorldModel, WorldState, encoder_receptive_field,
                                                 frames_to_model, steady_cond_index)

B = 2


def _random_value(stacked: bool, name: str, shape: tuple, rng: np.random.Generator) -> np.ndarray:
    noise = rng.normal(size=shape)
    if name in ("kernel", "head") and len(shape) >= 2:
        per_layer = shape[1:] if stacked else shape
        return noise / np.sqrt(np.prod(per_layer[:-1]))
    if name in ("scale", "weight", "gamma"):
        return 1.0 + 0.1 * noise
    if name in ("embedding", "cls_embedding", "pos_embedding"):
        return noise
    return 0.1 * noise  # biases, modulation tables


def random_model(cfg: WorldModelConfig, seed: int = 0) -> WorldModel:
    """A WorldModel with random weights, built without compiling any initialiser."""
    rng = np.random.default_rng(seed)
    modules = []
    for component, module in zip(("dit", "vae", "image_encoder"), abstract_modules(cfg)):
        graphdef, state = nnx.split(module)
        flat = [(path, jnp.asarray(_random_value(component == "dit" and path[0] == "blocks", str(path[-1]),
                                                 v.shape, rng), v.get_value().dtype))
                for path, v in nnx.to_flat_state(state)]
        modules.append(nnx.merge(graphdef, nnx.from_flat_state(flat)))
    return WorldModel(cfg, *modules)


def three_player_cfg() -> WorldModelConfig:
    base = WorldModelConfig.test()
    return base.replace(num_players=3, dit=dataclasses.replace(base.dit, max_players=3))


def first_frames(model: WorldModel, batch: int = B, seed: int = 0) -> np.ndarray:
    shape = (batch, model.num_players, *model.frame_shape)
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def random_actions(model: WorldModel, batch: int, steps: int, seed: int = 0) -> np.ndarray:
    """(steps, B, P, k, 25): binary keyboard flags, mouse in the camera_linear range."""
    rng = np.random.default_rng(seed)
    kb = model.config.action.keyboard_dim
    shape = (steps, batch, model.num_players, model.frames_per_step, model.action_dim)
    actions = (rng.random(shape) < 0.3).astype(np.float32)
    actions[..., kb:] = rng.uniform(-1.33, 1.33, shape[:-1] + (model.action_dim - kb,))
    return actions


def host(tree):
    return jax.tree.map(np.asarray, tree)


@pytest.fixture(scope="module")
def model() -> WorldModel:
    return random_model(WorldModelConfig.test())


# ---------------------------------------------------------------------------------------------
# Shapes, determinism, flat memory
# ---------------------------------------------------------------------------------------------


def test_properties(model):
    cfg = model.config
    assert model.frame_shape == (cfg.frame_height, cfg.frame_width, 3)
    assert model.num_players == 2 and model.frames_per_step == cfg.vae.temporal_factor == 4
    assert model.cond_frames == steady_cond_index(cfg.vae) + 1


def test_stream_shapes_and_dtypes_two_players(model):
    state = model.init(first_frames(model), jax.random.key(0))
    h, w, _ = model.frame_shape
    assert isinstance(state, WorldState) and state.num_worlds == B
    assert state.frame0_BPHW3.shape == (B, 2, h, w, 3) and state.frame0_BPHW3.dtype == jnp.uint8
    np.testing.assert_array_equal(state.frame_index_B, [1, 1])
    frames, state = model.step(state, random_actions(model, B, 1)[0])
    assert frames.shape == (B, 2, 4, h, w, 3) and frames.dtype == jnp.uint8
    assert state.latent_BP1hwC.shape == (B, 2, 1, 4, 4, 4)
    np.testing.assert_array_equal(state.frame_index_B, [2, 2])


def test_stream_shapes_three_players():
    model3 = random_model(three_player_cfg(), seed=1)
    state = model3.init(first_frames(model3, batch=1), 0)
    frames, state = model3.step(state, random_actions(model3, 1, 1)[0])
    assert state.frame0_BPHW3.shape == (1, 3, 32, 32, 3)
    assert frames.shape == (1, 3, 4, 32, 32, 3) and frames.dtype == jnp.uint8
    assert np.isfinite(np.asarray(state.latent_BP1hwC)).all()


@pytest.mark.slow
def test_concat_variant_streams():
    base = WorldModelConfig.test()
    model_c = random_model(base.replace(dit=dataclasses.replace(base.dit, multiplayer="concat")), seed=2)
    state = model_c.init(first_frames(model_c, batch=1), 0)
    frames, state = model_c.step(state, random_actions(model_c, 1, 1)[0])
    assert frames.shape == (1, 2, 4, 32, 32, 3) and frames.dtype == jnp.uint8
    assert state.dit_cache.layers[0].self_attn.size == model_c.config.cache_tokens  # one stream player
    assert np.isfinite(np.asarray(state.latent_BP1hwC)).all()


def test_fixed_rng_is_deterministic_and_rng_matters(model):
    actions = random_actions(model, B, 2)
    runs = []
    for seed in (0, 0, 1):
        state = model.init(first_frames(model), jax.random.key(seed))
        frames = [np.asarray(state.frame0_BPHW3)]
        for a in actions:
            f, state = model.step(state, a)
            frames.append(np.asarray(f))
        runs.append(frames)
    for a, b in zip(runs[0], runs[1]):
        np.testing.assert_array_equal(a, b)
    assert any(not np.array_equal(a, b) for a, b in zip(runs[0], runs[2]))


def test_memory_flat_and_step_compiles_once(model):
    actions = random_actions(model, B, 20, seed=3)
    state = model.init(first_frames(model), 0)
    _, state = model.step(state, actions[0])
    after_one = jax.tree.map(lambda a: (a.shape, a.dtype), state)
    structure_one = jax.tree.structure(state)
    compiled = model._step_fn._cache_size()
    for a in actions[1:]:
        _, state = model.step(state, a)
    assert jax.tree.map(lambda a: (a.shape, a.dtype), state) == after_one
    assert jax.tree.structure(state) == structure_one
    assert model._step_fn._cache_size() == compiled == 1
    np.testing.assert_array_equal(state.frame_index_B, [21, 21])
    # the cache saturates at the window: every slot valid, shapes unchanged
    assert (np.asarray([c.self_attn.length for c in state.dit_cache.layers]) == model.config.cache_tokens).all()


def test_unrolled_programs_compute_the_same_step(model):
    """Programs(unroll=True) (straight-line sampler steps, used to count FLOPs with XLA's cost analysis)
    computes the same step as the looped programs, and XLA counts more FLOPs in it."""
    state = model.init(first_frames(model), 0)
    actions = jnp.asarray(random_actions(model, B, 1, seed=4)[0])
    looped = model.programs
    unrolled = Programs(model.config, looped.graphdefs, unroll=True)
    frames, new = jax.jit(looped.step)(model.step_params, state, actions)
    frames_u, new_u = jax.jit(unrolled.step)(model.step_params, state, actions)
    np.testing.assert_allclose(np.asarray(new_u.latent_BP1hwC), np.asarray(new.latent_BP1hwC), atol=1e-5)
    assert np.abs(np.asarray(frames_u, int) - np.asarray(frames, int)).max() <= 1
    cost = lambda f: jax.jit(f).lower(model.step_params, state, actions).compile().cost_analysis()["flops"]
    # denoise = the fused first pass + (n - 1) plain passes; XLA counts the loop body once
    fused, plain = cost(looped.first_pass), len(model.config.sampler.ar_timesteps) - 1
    assert (cost(unrolled.denoise) - fused) == pytest.approx(plain * (cost(looped.denoise) - fused), rel=0.05)


def test_rope_positions_beyond_the_table_work(model):
    """frame_index is the RoPE start; angles are computed directly (no table), so any position works."""
    state = model.init(first_frames(model), 0)
    far = 2001
    state = state.replace(frame_index_B=jnp.full((B,), far, jnp.int32))
    frames, state = model.step(state, random_actions(model, B, 1)[0])
    assert np.isfinite(np.asarray(state.latent_BP1hwC)).all()
    np.testing.assert_array_equal(state.frame_index_B, [far + 1] * B)


# ---------------------------------------------------------------------------------------------
# Per-world reset
# ---------------------------------------------------------------------------------------------


def test_reset_worlds_changes_only_masked_worlds_without_recompiling(model):
    actions = random_actions(model, B, 3, seed=5)
    state = model.init(first_frames(model), jax.random.key(7))
    for a in actions[:2]:
        _, state = model.step(state, a)
    before = host(state)
    new_frames = first_frames(model, seed=9)
    state = model.reset_worlds(state, np.array([False, True]), new_frames, rng=jax.random.key(11))
    after = host(state)
    for old, new in zip(jax.tree.leaves(before), jax.tree.leaves(after)):
        np.testing.assert_array_equal(old[0], new[0])  # the untouched world
    # the reset world equals a fresh init of that world with the same key (uint8 frames within 1)
    fresh = host(model.init(new_frames, jax.random.key(11)))
    for got, want in zip(jax.tree.leaves(after), jax.tree.leaves(fresh)):
        np.testing.assert_allclose(got[1].astype(np.float64), want[1].astype(np.float64),
                                   atol=1.0 if got.dtype == np.uint8 else 1e-4)
    assert after.frame_index_B.tolist() == [3, 1]
    # another world, then a step: nothing recompiles
    steps_compiled = model._step_fn._cache_size()
    state = model.reset_worlds(state, np.array([True, False]), new_frames)
    _, state = model.step(state, actions[2])
    assert model._reset_fn._cache_size() == 1
    assert model._step_fn._cache_size() == steps_compiled
    assert np.asarray(state.frame_index_B).tolist() == [2, 2]
    state = model.reset_worlds(state, np.array([False, False]), new_frames)  # no-op
    assert np.asarray(state.frame_index_B).tolist() == [2, 2]


# ---------------------------------------------------------------------------------------------
# Input checks
# ---------------------------------------------------------------------------------------------


def test_bad_inputs_raise_before_compute(model):
    ff = first_frames(model)
    good_actions = random_actions(model, B, 1)[0]
    with pytest.raises(ValueError, match="first_frames must be uint8"):
        model.init(ff.astype(np.float32), 0)
    with pytest.raises(ValueError, match=r"first_frames has shape .*expected \(B, P=2, H=32, W=32, 3\)"):
        model.init(ff[:, :, :16], 0)
    with pytest.raises(ValueError, match="first_frames has 3 players; this model has num_players=2"):
        model.init(np.concatenate([ff, ff[:, :1]], axis=1), 0)
    state = model.init(ff, 0)
    snapshot = host(state)
    expected = r"actions has shape \(2, 2, 3, 25\); expected \(B, P, k, 25\) = \(2, 2, 4, 25\)"
    with pytest.raises(ValueError, match=expected):
        model.step(state, good_actions[:, :, :3])
    with pytest.raises(ValueError, match="actions has 3 players; this model has num_players=2"):
        model.step(state, np.concatenate([good_actions, good_actions[:, :1]], axis=1))
    with pytest.raises(ValueError, match=r"actions has shape \(1, 2, 4, 25\)"):
        model.step(state, good_actions[:1])  # batch differs from the state
    for bad in (np.nan, np.inf):
        broken = good_actions.copy()
        broken[1, 0, 2, 23] = bad
        with pytest.raises(ValueError, match="actions contains NaN or inf"):
            model.step(state, broken)
    with pytest.raises(ValueError, match="actions must be a real-valued array"):
        model.step(state, good_actions.astype(np.complex64))
    with pytest.raises(ValueError, match="state must be the WorldState"):
        model.step({"not": "a state"}, good_actions)
    with pytest.raises(ValueError, match=r"mask_B has shape \(3,\) dtype bool; expected \(2,\) bool"):
        model.reset_worlds(state, np.array([True, False, True]), ff)
    with pytest.raises(ValueError, match="first_frames has 1 worlds; the state has B=2"):
        model.reset_worlds(state, np.array([True, False]), ff[:1])
    # nothing ran: the (donated-on-success) state is intact and still usable
    for a, b in zip(jax.tree.leaves(snapshot), jax.tree.leaves(host(state))):
        np.testing.assert_array_equal(a, b)
    frames, _ = model.step(state, good_actions)
    assert frames.shape[:3] == (B, 2, 4)


# ---------------------------------------------------------------------------------------------
# Streaming == offline rollout (the DiT's decode driven by a loop written here)
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rollout(model):
    return stream_rollout(model)


def stream_rollout(model):
    """Stream ``cond_frames + 1`` steps (past the steady conditioning) and keep what the reference needs."""
    cfg = model.config
    steps = model.cond_frames + 1
    ff = first_frames(model, seed=21)
    first_actions = random_actions(model, B, 1, seed=22)[0][:, :, 0]  # (B, P, 25) action of frame 0
    actions = random_actions(model, B, steps, seed=23)
    rng = jax.random.key(24)
    state = model.init(ff, rng, first_actions=first_actions)
    latents, frames = [np.asarray(state.latent_BP1hwC)], [np.asarray(state.frame0_BPHW3)[:, :, None]]
    cond_table = np.asarray(state.cond_BPFhwC)
    for a in actions:
        f, state = model.step(state, a)
        latents.append(np.asarray(state.latent_BP1hwC))
        frames.append(np.asarray(f))
    return dict(cfg=cfg, ff=ff, first_actions=first_actions, actions=actions, rng=rng, cond_table=cond_table,
                latents=np.concatenate(latents, axis=2), frames=np.concatenate(frames, axis=2))


def _frame_noise(keys_B, shape, num_steps):
    """Per the documented key schedule: (next keys, frame keys, initial noise (B, ...), re-noise draws [s] (B, ...))."""
    nxt, frame_keys, z, eps = [], [], [], []
    for key in keys_B:
        key, frame_key = jax.random.split(key)
        k_noise, k_renoise = jax.random.split(frame_key)
        nxt.append(key)
        frame_keys.append(frame_key)
        z.append(jax.random.normal(k_noise, shape))
        eps.append(jnp.stack([jax.random.normal(k, shape) for k in jax.random.split(k_renoise, num_steps)]))
    return nxt, frame_keys, jnp.stack(z), jnp.stack(eps, axis=1)


def offline_rollout(model, rollout):
    """The reference rollout (docs/model.md §5.5) written out pass by pass (separate denoise and commit
    passes, whole-video conditioning); the commit of frame i - 1 (its clean x0, t = 0) happens before
    frame i."""
    cfg, ff = rollout["cfg"], rollout["ff"]
    num_frames = rollout["latents"].shape[2]
    p, (h, w, _) = model.num_players, model.frame_shape
    dit, vae, encoder = model.modules()
    first = frames_to_model(jnp.asarray(ff)).reshape(B * p, h, w, 3)
    context = encoder(first).reshape(B, p, -1, cfg.context_width)
    cond = jax.jit(lambda f: first_frame_cond(vae, f, num_frames))(first)
    cond = cond.reshape(B, p, *cond.shape[1:])
    # the whole action sequence a_0 .. a_{k(F-1)}, left-padded, cut into per-frame windows
    steps = rollout["actions"].transpose(1, 2, 0, 3, 4).reshape(B, p, -1, model.action_dim)
    seq = jnp.concatenate([jnp.asarray(rollout["first_actions"])[:, :, None], steps], axis=2)
    windows = action_windows(left_pad_actions(seq, cfg.action_left_padding), cfg, num_frames)
    kb = cfg.action.keyboard_dim
    gd, params = nnx.split(dit)

    def decode_pass(prm, x, t, cond, context, *rest, commit=0):
        m = nnx.merge(gd, prm)
        return m.decode(x, t, cond, m.context_kv(context), *rest, commit=commit)

    decode = jax.jit(decode_pass, static_argnames="commit")
    timesteps = [1000.0, 750.0, 500.0, 250.0, 0.0]
    keys = list(jax.random.split(rollout["rng"], B))
    cache = kv_cache.init_cache(cfg, B)
    latents = []
    args = lambda i, x, t: (params, x, jnp.full((B, p, 1), t, jnp.float32), cond[:, :, i:i + 1], context,
                            windows[:, :, i, :, kb:], windows[:, :, i, :, :kb], cache, i)
    for i in range(num_frames):
        keys, frame_keys, z, eps = _frame_noise(keys, (p, 1, cfg.latent_height, cfg.latent_width,
                                                       cfg.latent_channels), 4)
        if i:  # the commit pass writes frame i - 1 (clean)
            _, cache = decode(*args(i - 1, x0, 0.0), commit=1)
        for s, t in enumerate(timesteps[:-1]):
            v, _ = decode(*args(i, z, t))
            x0 = z - (t / 1000.0) * v
            sigma = timesteps[s + 1] / 1000.0
            z = (1 - sigma) * x0 + sigma * eps[s]
        latents.append(x0)
    latents = jnp.concatenate(latents, axis=2)  # (B, P, F, h, w, C)
    video = jax.jit(vae.decode)(latents.reshape(B * p, *latents.shape[2:]))
    video = np.asarray(jnp.clip((video + 1) * 127.5, 0, 255).astype(jnp.uint8))
    return dict(latents=np.asarray(latents), frames=video.reshape(B, p, *video.shape[1:]), cond=np.asarray(cond))


@pytest.fixture(scope="module")
def reference(model, rollout):
    return offline_rollout(model, rollout)


def test_streaming_step_equals_offline_rollout(rollout, reference):
    assert rollout["latents"].shape == reference["latents"].shape
    np.testing.assert_allclose(rollout["latents"], reference["latents"], atol=1e-5, rtol=0)  # measured 1e-6
    assert np.abs(reference["latents"]).mean() > 0.1  # a non-trivial rollout
    assert rollout["frames"].shape == reference["frames"].shape  # 1 + k * steps frames per player
    diff = np.abs(rollout["frames"].astype(int) - reference["frames"].astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 0.01  # uint8 truncation of float noise only


def test_conditioning_table_matches_full_video_encoding_and_is_steady(model, rollout, reference):
    table, full = rollout["cond_table"], reference["cond"]
    steady = steady_cond_index(model.config.vae)
    assert table.shape[2] == steady + 1
    np.testing.assert_allclose(table, full[:, :, :steady + 1], atol=1e-4)
    for i in range(steady + 1, full.shape[2]):  # every later latent frame has the steady conditioning
        np.testing.assert_allclose(full[:, :, i], table[:, :, steady], atol=1e-5)
    assert encoder_receptive_field(model.config.vae) == 80  # test preset: 2+4+4+2+8+4+16+32+8


def test_step_params_round_trip_to_the_stacked_layout(model):
    """StepParams (one DiT block state per layer, what the programs take) and the stacked checkpoint
    layout convert into each other exactly."""
    stacked = model.params
    back = model.programs.stacked_params(model.programs.step_params(stacked))
    for a, b in zip(stacked, back):
        assert jax.tree.structure(a) == jax.tree.structure(b)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert len(model.step_params.dit_layers) == model.config.dit.num_layers


def test_parameter_layouts_on_the_host_give_the_same_model_on_the_default_device(monkeypatch):
    """Where the default backend is an accelerator, the random initialisation and the DiT blocks' (un)stacking
    run on the host CPU (``world_model.on_host``; docs/training.md, "The GPU session"). Posing as a GPU backend
    on this CPU exercises that path: the same parameters come back, as uncommitted arrays."""
    from solaris_env.world_model import world_model as wm

    reference = wm.WorldModel.from_preset("test", seed=3)
    monkeypatch.setattr(wm.jax, "default_backend", lambda: "gpu")
    model = wm.WorldModel.from_preset("test", seed=3)
    params, step_leaves = model.params, jax.tree.leaves(model.step_params)
    monkeypatch.undo()
    got, want = jax.tree.leaves(params), jax.tree.leaves(reference.params)
    assert len(got) == len(want) and len(step_leaves) == len(jax.tree.leaves(reference.step_params))
    for a, b in zip(got, want):
        assert a.dtype == b.dtype and np.array_equal(np.asarray(a), np.asarray(b))
    assert not any(leaf.committed for leaf in got + step_leaves)
    key = jax.random.key(0)  # typed keys keep their type through the move
    assert jax.dtypes.issubdtype(wm._to_default_device(key).dtype, jax.dtypes.prng_key)


def test_a_linear_patch_codec_streams_resets_and_conditions_like_the_reference():
    """The world model on a linear patch codec (VAEConfig.codec, the tiny16 layout's): its empty decoder cache
    streams, resets per world and batches like the convolutional VAE's, and its conditioning is steady from
    latent 1 (a latent sees only its own 4 frames)."""
    cfg = WorldModelConfig.test()
    codec = random_model(cfg.replace(vae=dataclasses.replace(cfg.vae, codec="linear_patch")), seed=3)
    assert codec.cond_frames == 2
    rollout = stream_rollout(codec)
    reference = offline_rollout(codec, rollout)
    test_streaming_step_equals_offline_rollout(rollout, reference)
    table, full = rollout["cond_table"], reference["cond"]
    np.testing.assert_allclose(table, full[:, :, :2], atol=1e-5)
    np.testing.assert_allclose(full[:, :, 2:], np.broadcast_to(table[:, :, 1:2], full[:, :, 2:].shape), atol=1e-5)
    test_reset_worlds_changes_only_masked_worlds_without_recompiling(codec)
