"""The DiT: official parameter tree, and the equalities that tie masks, RoPE offsets and caches together
(docs/model.md §5.3 / §11.1): cached rollout == teacher forcing, commit passes == causal forward.

All numerics run in f32 on the ``test`` preset (window 2 < 4 frames) with randomised weights (the head
is zero-initialised, so an untouched model would predict exactly 0 everywhere).
"""

import ast
import dataclasses
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model import kv_cache
from solaris_env.world_model.action_module import (action_windows, left_pad_actions, mouse_kernel_rows,
                                                   padded_action_length, rescaled_mouse_kernel,
                                                   window_at)
from solaris_env.world_model.config import DiTConfig, WorldModelConfig
from solaris_env.world_model.dit import WorldDiT, count_params, from_stream, timesteps_to_stream, to_stream

TREE = pathlib.Path(__file__).parent / "fixtures" / "solaris-param-tree.txt"
FRAMES, BATCH, TOL = 4, 1, 1e-4

causal_fn = nnx.jit(lambda m, *a: m.forward_causal(*a))
bidirectional_fn = nnx.jit(lambda m, *a: m.forward_bidirectional(*a))
teacher_forcing_fn = nnx.jit(lambda m, *a, kv_grad: m.forward_teacher_forcing(*a, kv_grad=kv_grad),
                             static_argnames="kv_grad")
# the cached pass with the context given raw (its per-layer K/V computed in the same program)
decode_fn = nnx.jit(lambda m, x, t, cond, context, *a, commit=0: m.decode(x, t, cond, m.context_kv(context), *a,
                                                                           commit=commit),
                    static_argnames="commit")


def _cfg(players: int = 2, method: str = "attn") -> WorldModelConfig:
    base = WorldModelConfig.test()
    dit = dataclasses.replace(base.dit, max_players=max(players, 2), multiplayer=method)
    return base.replace(num_players=players, dit=dit)


def _random_value(path: tuple, shape: tuple, rng: np.random.Generator) -> np.ndarray:
    """Non-degenerate random weights: kernels ~ N(0, 1/fan_in), norm gains 1 + noise, small biases."""
    name = str(path[-1])
    noise = rng.normal(size=shape)
    if name == "kernel":
        per_layer = shape[1:] if path[0] == "blocks" else shape
        return noise / np.sqrt(np.prod(per_layer[:-1]))
    if name in ("scale", "weight"):
        return 1.0 + 0.1 * noise
    if name == "embedding":
        return noise
    return 0.1 * noise  # biases, modulation tables


def _build(cfg: WorldModelConfig, seed: int = 0) -> WorldDiT:
    """A model with random weights, built without compiling the initialiser (the head's zero init
    would make every output exactly 0)."""
    graphdef, state = nnx.split(nnx.eval_shape(lambda: WorldDiT(cfg, rngs=nnx.Rngs(0))))
    rng = np.random.default_rng(seed)
    flat = [(path, jnp.asarray(_random_value(path, v.shape, rng), v.dtype)) for path, v in nnx.to_flat_state(state)]
    return nnx.merge(graphdef, nnx.from_flat_state(flat))


def _inputs(cfg: WorldModelConfig, frames: int = FRAMES, seed: int = 0) -> dict:
    ks = jax.random.split(jax.random.key(100 + seed), 8)
    p, t_pad = cfg.stream_players, padded_action_length(cfg, frames)
    latent = (BATCH, p, frames, cfg.latent_height, cfg.latent_width)
    return dict(
        clean=jax.random.normal(ks[0], latent + (cfg.out_channels,)),
        noisy=jax.random.normal(ks[1], latent + (cfg.out_channels,)),
        t=jax.random.uniform(ks[2], (BATCH, p, frames), minval=100.0, maxval=1000.0),
        cond=jax.random.normal(ks[3], latent + (cfg.in_channels - cfg.out_channels,)),
        context=jax.random.normal(ks[4], (BATCH, p, 5, cfg.context_width)),
        mouse=jax.random.normal(ks[5], (BATCH, p, t_pad, cfg.players_in_channels * cfg.action.mouse_dim)),
        keyboard=jax.random.bernoulli(ks[6], 0.3, (BATCH, p, t_pad, cfg.keyboard_in_dim)).astype(jnp.float32),
    )


def _seq_args(inp: dict, x_key: str = "noisy", t=None):
    t = inp["t"] if t is None else t
    return inp[x_key], t, inp["cond"], inp["context"], inp["mouse"], inp["keyboard"]


@pytest.fixture(scope="module")
def cfg2():
    return _cfg(players=2)


@pytest.fixture(scope="module")
def model2(cfg2):
    return _build(cfg2)


@pytest.fixture(scope="module")
def inp2(cfg2):
    return _inputs(cfg2)


# ---------------------------------------------------------------------------------------------
# Parameter tree
# ---------------------------------------------------------------------------------------------


def _official_tree() -> tuple[dict, int]:
    shapes, total = {}, None
    for line in TREE.read_text().splitlines():
        if line.startswith("TOTAL"):
            total = int(line.split()[1])
        elif line.strip():
            path, shape, _dtype, _kind = ast.literal_eval(line)
            shapes[path] = tuple(shape)
    return shapes, total


def _abstract_tree(cfg: WorldModelConfig) -> tuple[dict, int]:
    model = nnx.eval_shape(lambda: WorldDiT(cfg, rngs=nnx.Rngs(0)))
    flat = nnx.to_flat_state(nnx.state(model, nnx.Param))
    return {"/".join(map(str, path)): tuple(v.shape) for path, v in flat}, count_params(model)


def test_solaris_param_tree_matches_the_official_checkpoint():
    official, official_total = _official_tree()
    ours, total = _abstract_tree(WorldModelConfig.solaris())
    assert official_total == 1_824_481_856
    assert total == official_total
    assert ours == official  # every key and every shape


def test_concat_variant_param_count():
    cfg = WorldModelConfig.solaris(dit=DiTConfig(multiplayer="concat"))
    ours, total = _abstract_tree(cfg)
    assert total == 1_832_512_128
    assert ours["patch_embedding/kernel"] == (1, 2, 2, 72, 1536)
    assert ours["img_emb/proj/1/kernel"] == (2560, 2560)
    assert ours["blocks/action_model/mouse_mlp/layers/0/kernel"] == (30, 1584, 1024)
    assert ours["blocks/action_model/keyboard_embed/layers/0/kernel"] == (30, 46, 128)


def test_real_initialisation_starts_at_zero_velocity():
    cfg = _cfg(players=2)
    # an RBG key compiles the initialiser about twice as fast as threefry on CPU
    model = nnx.jit(lambda: WorldDiT(cfg, rngs=nnx.Rngs(jax.random.key(0, impl="unsafe_rbg"))))()
    assert not np.asarray(model.head.head.kernel[...]).any()  # zero head: the untrained model predicts v = 0
    stacked = np.asarray(model.blocks.modulation[...])
    assert stacked.shape == (cfg.dit.num_layers, 1, 6, cfg.dit.dim)
    assert not np.allclose(stacked[0], stacked[1])  # per-layer rngs differ
    assert np.asarray(model.blocks.self_attn.norm_q.weight[...]).min() == 1.0


# ---------------------------------------------------------------------------------------------
# Action windows
# ---------------------------------------------------------------------------------------------


def test_action_windows_align_frame_k_i_with_latent_frame_i(cfg2):
    k, window, frames = cfg2.frames_per_step, cfg2.action_window, 3
    raw = jnp.arange(k * (frames - 1) + 1, dtype=jnp.float32).reshape(1, 1, -1, 1)  # actions 0..k(F-1)
    padded = left_pad_actions(raw, cfg2.action_left_padding)
    assert padded.shape[2] == padded_action_length(cfg2, frames)
    windows = np.asarray(action_windows(padded, cfg2, frames))[0, 0, :, :, 0]
    for i in range(frames):
        want = [max(0, a) for a in range(k * i - window + 1, k * i + 1)]  # clamped at action 0
        np.testing.assert_array_equal(windows[i], want)
        np.testing.assert_array_equal(np.asarray(window_at(padded, cfg2, i))[0, 0, :, 0], want)
    with pytest.raises(ValueError):
        action_windows(padded[:, :, 1:], cfg2, frames)


# ---------------------------------------------------------------------------------------------
# Cached rollout == teacher forcing; commit == causal
# ---------------------------------------------------------------------------------------------


def _rollout(cfg, model, inp) -> dict:
    """Per frame i: denoise pass on the noisy latent (cache discarded), the same with the query's RoPE
    start shifted to i+1 (negative control), then the commit pass on the clean latent (cache kept)."""
    cache = kv_cache.init_cache(cfg, BATCH, jnp.float32)
    zero_t = jnp.zeros_like(inp["t"])
    out = {"denoise": [], "shifted": [], "commit": []}
    for i in range(FRAMES):
        sl = slice(i, i + 1)
        common = (inp["cond"][:, :, sl], inp["context"], window_at(inp["mouse"], cfg, i),
                  window_at(inp["keyboard"], cfg, i), cache)
        v, _ = decode_fn(model, inp["noisy"][:, :, sl], inp["t"][:, :, sl], *common, i)
        v_shift, _ = decode_fn(model, inp["noisy"][:, :, sl], inp["t"][:, :, sl], *common, i + 1)
        v_commit, cache = decode_fn(model, inp["clean"][:, :, sl], zero_t[:, :, sl], *common, i, commit=1)
        out["denoise"].append(v[:, :, 0])
        out["shifted"].append(v_shift[:, :, 0])
        out["commit"].append(v_commit[:, :, 0])
    out = {k: jnp.stack(v, axis=2) for k, v in out.items()}
    out["cache"] = cache
    return out


def _teacher_forcing(model, inp, kv_grad=True):
    return teacher_forcing_fn(model, inp["clean"], inp["noisy"], jnp.zeros_like(inp["t"]), inp["t"], inp["cond"],
                              inp["context"], inp["mouse"], inp["keyboard"], kv_grad=kv_grad)


@pytest.fixture(scope="module")
def rollout(cfg2, model2, inp2):
    return _rollout(cfg2, model2, inp2)


def test_cached_rollout_equals_teacher_forcing(model2, inp2, rollout):
    v_tf = _teacher_forcing(model2, inp2)
    assert v_tf.shape == inp2["noisy"].shape
    assert float(jnp.abs(v_tf).mean()) > 0.05  # non-trivial outputs
    np.testing.assert_allclose(rollout["denoise"], v_tf, atol=TOL, rtol=0)


def test_commit_passes_equal_causal_forward(model2, inp2, rollout):
    v_causal = causal_fn(model2, *_seq_args(inp2, "clean", jnp.zeros_like(inp2["t"])))
    np.testing.assert_allclose(rollout["commit"], v_causal, atol=TOL, rtol=0)


@pytest.mark.slow
def test_three_player_rollout_equals_teacher_forcing_and_causal():
    cfg = _cfg(players=3)
    model, inp = _build(cfg, seed=3), _inputs(cfg, seed=3)
    out = _rollout(cfg, model, inp)
    np.testing.assert_allclose(out["denoise"], _teacher_forcing(model, inp), atol=TOL, rtol=0)
    v_causal = causal_fn(model, *_seq_args(inp, "clean", jnp.zeros_like(inp["t"])))
    np.testing.assert_allclose(out["commit"], v_causal, atol=TOL, rtol=0)


def test_shifted_query_rope_start_changes_outputs(rollout):
    """Negative control: a query one frame ahead of its keys differs (frame 0 has only itself as key,
    and a common shift of q and k cancels)."""
    diff = jnp.abs(rollout["shifted"] - rollout["denoise"]).mean(axis=(0, 1, 3, 4, 5))
    assert float(diff[0]) < 1e-5
    assert (diff[1:] > 1e-3).all(), diff


decode_ctx_kv_fn = nnx.jit(lambda m, *a, commit: m.decode(*a, commit=commit), static_argnames="commit")
context_kv_fn = nnx.jit(lambda m, c: m.context_kv(c))


@pytest.mark.parametrize("method", ["attn", "concat"])
def test_denoise_pass_leaves_the_cache_and_equals_the_commit_pass(method):
    """``decode`` with the context's per-layer K/V (``context_kv``, one (B, P, N, M, K) array per layer):
    a denoising pass (commit=0) returns the cache as it was and the commit pass's velocity, against an
    empty cache and one holding a frame; the commit pass writes the frame into every layer."""
    cfg = _cfg(players=2, method=method)
    model, inp = _build(cfg, seed=7), _inputs(cfg, seed=7)
    ctx_kv = context_kv_fn(model, inp["context"])
    layers, b, p = cfg.dit.num_layers, BATCH, cfg.stream_players
    assert len(ctx_kv.k_BPNMK) == len(ctx_kv.v_BPNMK) == layers
    assert {a.shape for a in ctx_kv.k_BPNMK + ctx_kv.v_BPNMK} == {
        (b, p, cfg.dit.num_heads, inp["context"].shape[2], cfg.dit.head_dim)}
    cache = kv_cache.init_cache(cfg, BATCH, jnp.float32)
    per_frame = p * cfg.tokens_per_frame
    for i in range(2):
        sl = slice(i, i + 1)
        rest = (window_at(inp["mouse"], cfg, i), window_at(inp["keyboard"], cfg, i), cache, i)
        head = (inp["noisy"][:, :, sl], inp["t"][:, :, sl], inp["cond"][:, :, sl])
        v_commit, cache_new = decode_ctx_kv_fn(model, *head, ctx_kv, *rest, commit=1)
        v, cache_same = decode_ctx_kv_fn(model, *head, ctx_kv, *rest, commit=0)
        assert float(jnp.abs(v_commit).mean()) > 0.05
        np.testing.assert_allclose(v, v_commit, atol=1e-5, rtol=0)
        jax.tree.map(np.testing.assert_array_equal, cache_same, cache)
        assert [int(c.self_attn.length) for c in cache_new.layers] == [(i + 1) * per_frame] * layers
        _, cache = decode_ctx_kv_fn(model, inp["clean"][:, :, sl], jnp.zeros_like(inp["t"][:, :, sl]),
                                    inp["cond"][:, :, sl], ctx_kv, *rest, commit=1)
    with pytest.raises(ValueError, match="context_kv.k"):
        decode_ctx_kv_fn(model, *head, ctx_kv._replace(k_BPNMK=ctx_kv.k_BPNMK[1:]), *rest, commit=0)
    with pytest.raises(ValueError, match="commit=2"):  # more frames committed than given
        decode_ctx_kv_fn(model, *head, ctx_kv, *rest, commit=2)


def test_cache_after_rollout(cfg2, rollout):
    cache = rollout["cache"]
    lengths = lambda name: np.asarray([getattr(layer, name).length for layer in cache.layers])
    np.testing.assert_array_equal(lengths("self_attn"), [cfg2.cache_tokens] * cfg2.dit.num_layers)
    # the action caches exist for every layer but only layers < num_action_blocks write them
    n_action = cfg2.action.num_action_blocks
    assert (lengths("mouse")[:n_action] == cfg2.dit.window).all()
    assert (lengths("keyboard")[n_action:] == 0).all()


# ---------------------------------------------------------------------------------------------
# Players, actions, causality
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("players,perm", [(2, [1, 0]), (3, [2, 0, 1])])
def test_permuting_players_permutes_outputs(players, perm):
    cfg = _cfg(players)
    model, inp = _build(cfg, seed=players), _inputs(cfg, seed=players)
    out = causal_fn(model, *_seq_args(inp))
    permuted = {k: v[:, perm] for k, v in inp.items()}
    swapped = nnx.clone(model)
    emb = swapped.player_embed.embedding
    emb[...] = emb[...].at[:players].set(emb[...][jnp.asarray(perm)])
    out_perm = causal_fn(swapped, *_seq_args(permuted))
    np.testing.assert_allclose(out_perm, out[:, perm], atol=TOL, rtol=0)
    assert float(jnp.abs(out[:, 0] - out[:, 1]).mean()) > 1e-3  # the players really differ


@pytest.mark.parametrize("stream", ["mouse", "keyboard"])
def test_action_of_frame_k_i_reaches_latent_frame_i_and_no_earlier(cfg2, model2, inp2, stream):
    i, k, pad = 2, cfg2.frames_per_step, cfg2.action_left_padding
    base = causal_fn(model2, *_seq_args(inp2))

    def changed(video_frame):
        inp = dict(inp2)
        inp[stream] = inp2[stream].at[:, :, video_frame + pad].add(1.0)
        return jnp.abs(causal_fn(model2, *_seq_args(inp)) - base).max(axis=(0, 1, 3, 4, 5))

    at_ki = changed(k * i)
    assert float(at_ki[:i].max()) == 0.0, at_ki
    assert float(at_ki[i]) > 1e-4, at_ki
    after = changed(k * i + 1)  # belongs to latent frame i+1's window, not frame i's
    assert float(after[:i + 1].max()) == 0.0, after
    assert float(after[i + 1]) > 1e-4, after


def test_bidirectional_sees_the_future_and_causal_does_not(model2, inp2):
    later = dict(inp2, noisy=inp2["noisy"].at[:, :, -1].add(1.0))
    for fn, sees_future in ((bidirectional_fn, True), (causal_fn, False)):
        delta = jnp.abs(fn(model2, *_seq_args(later)) - fn(model2, *_seq_args(inp2)))[:, :, 0]
        assert (float(delta.max()) > 1e-4) == sees_future, (fn, float(delta.max()))


def test_causal_window_drops_frames_older_than_the_window(cfg2, model2, inp2):
    """Window 2 and one layer of reach per block: frame 0 can influence frame 3 only through frames
    1-2 across layers, so change frame 0 and check frame 1 (in window) does change."""
    changed = dict(inp2, noisy=inp2["noisy"].at[:, :, 0].add(1.0))
    delta = jnp.abs(causal_fn(model2, *_seq_args(changed)) - causal_fn(model2, *_seq_args(inp2)))
    assert float(delta[:, :, 1].max()) > 1e-4


def test_kv_grad_false_stops_gradients_through_clean_keys(model2, inp2):
    """Forward-mode derivative of the noisy half w.r.t. the clean latents: nonzero with kv_grad=True,
    exactly zero with kv_grad=False (clean and noisy tokens interact only through keys/values).
    The model is used functionally (split outside, merged inside jvp), as a training step would."""
    graphdef, state = nnx.split(model2)
    tangent = jax.random.normal(jax.random.key(7), inp2["clean"].shape)

    @jax.jit
    def tangents(state, clean):
        def noisy_half(clean, kv_grad):
            return nnx.merge(graphdef, state).forward_teacher_forcing(
                clean, inp2["noisy"], jnp.zeros_like(inp2["t"]), inp2["t"], inp2["cond"], inp2["context"],
                inp2["mouse"], inp2["keyboard"], kv_grad=kv_grad)
        return [jax.jvp(lambda c: noisy_half(c, kv_grad), (clean,), (tangent,)) for kv_grad in (True, False)]

    (v_with, dv_with), (v_without, dv_without) = tangents(state, inp2["clean"])
    np.testing.assert_allclose(v_without, v_with, atol=1e-6)  # stop-gradient changes no value
    assert float(jnp.abs(dv_with).max()) > 1e-4
    assert float(jnp.abs(dv_without).max()) == 0.0


def test_only_the_first_num_action_blocks_use_their_action_module(cfg2, model2, inp2):
    base = causal_fn(model2, *_seq_args(inp2))
    n_action = cfg2.action.num_action_blocks
    for layer, should_change in ((n_action - 1, True), (n_action, False)):
        perturbed = nnx.clone(model2)
        kernel = perturbed.blocks.action_model.t_qkv.kernel
        kernel[...] = kernel[...].at[layer].add(0.5)
        delta = float(jnp.abs(causal_fn(perturbed, *_seq_args(inp2)) - base).max())
        assert (delta > 1e-4) == should_change, (layer, delta)


def _with_gain(cfg, model, gain: float, rescale: bool):
    """``model``'s weights under ``mouse_input_gain = gain`` (mouse kernel rows rescaled or kept)."""
    new_cfg = cfg.replace(action=dataclasses.replace(cfg.action, mouse_input_gain=gain))
    graphdef, _ = nnx.split(nnx.eval_shape(lambda: WorldDiT(new_cfg, rngs=nnx.Rngs(0))))
    state = nnx.state(nnx.clone(model))
    if rescale:
        kernel = state["blocks"]["action_model"]["mouse_mlp"]["layers"][0]["kernel"]
        kernel.set_value(rescaled_mouse_kernel(kernel.get_value(), cfg, gain))
    return nnx.merge(graphdef, state)


def test_mouse_input_gain_scales_the_mouse_window_only(cfg2, model2, inp2):
    """Gain g with the same weights == gain 1 fed g * mouse (keyboard untouched), and it changes outputs."""
    gained = _with_gain(cfg2, model2, 4.0, rescale=False)
    base = causal_fn(model2, *_seq_args(inp2))
    out = causal_fn(gained, *_seq_args(inp2))
    fed = causal_fn(model2, *_seq_args(dict(inp2, mouse=4.0 * inp2["mouse"])))
    np.testing.assert_allclose(out, fed, atol=TOL, rtol=TOL)
    assert float(jnp.abs(out - base).max()) > 1e-3


@pytest.mark.parametrize("gain", [0.5, 10.0])
def test_rescaled_mouse_kernel_keeps_the_function(cfg2, model2, inp2, gain):
    """The mouse rows scaled by old/new gain compute the same velocities (`solaris-train action-conditioning --mouse-gain`)."""
    rescaled = _with_gain(cfg2, model2, gain, rescale=True)
    np.testing.assert_allclose(causal_fn(rescaled, *_seq_args(inp2)), causal_fn(model2, *_seq_args(inp2)),
                               atol=TOL, rtol=TOL)
    k_old = model2.blocks.action_model.mouse_mlp.layers[0].kernel[...]
    k_new = rescaled.blocks.action_model.mouse_mlp.layers[0].kernel[...]
    rows = mouse_kernel_rows(cfg2)
    np.testing.assert_array_equal(k_new[:, :cfg2.dit.dim], k_old[:, :cfg2.dit.dim])  # token rows untouched
    np.testing.assert_allclose(k_new[:, rows], k_old[:, rows] / gain, rtol=1e-6)


@pytest.mark.parametrize("gain", [0.0, -1.0, float("nan"), float("inf")])
def test_mouse_input_gain_must_be_positive_and_finite(cfg2, gain):
    with pytest.raises(ValueError, match="mouse_input_gain"):
        dataclasses.replace(cfg2.action, mouse_input_gain=gain)
    with pytest.raises(ValueError, match="mouse_input_gain"):
        rescaled_mouse_kernel(jnp.ones((1, cfg2.mouse_in_dim, 4)), cfg2, gain)


# ---------------------------------------------------------------------------------------------
# Validation and the concat variant
# ---------------------------------------------------------------------------------------------


def test_bad_shapes_raise_value_errors(cfg2, model2, inp2):
    args = list(_seq_args(inp2))
    bad = {
        0: inp2["noisy"][..., :1],  # wrong latent channels
        1: inp2["t"][:, :, :1],  # t frames
        2: inp2["cond"][..., :1],
        3: inp2["context"][..., :1],
        4: inp2["mouse"][:, :, 1:],  # T_pad off by one
        5: inp2["keyboard"][..., :3],
    }
    for idx, value in bad.items():
        wrong = list(args)
        wrong[idx] = value
        with pytest.raises(ValueError):
            model2.forward_causal(*wrong)
    cache = kv_cache.init_cache(cfg2, BATCH)
    with pytest.raises(ValueError, match="mouse"):  # F frames take the actions of F frames, not one window
        model2.decode(*_seq_args(inp2)[:3], model2.context_kv(inp2["context"]),
                      inp2["mouse"][:, :, :cfg2.action_window], inp2["keyboard"][:, :, :cfg2.action_window], cache, 0)


def test_concat_stream_helpers_and_forward_shapes():
    cfg = _cfg(players=2, method="concat")
    inp = _inputs(_cfg(players=2))  # per-player tensors (B, 2, ...)
    x = inp["noisy"]
    stacked = to_stream(cfg, x)
    assert stacked.shape == x.shape[:1] + (1,) + x.shape[2:5] + (2 * x.shape[5],)
    np.testing.assert_array_equal(stacked[:, 0, ..., :x.shape[5]], x[:, 0])  # player-major channels
    np.testing.assert_array_equal(from_stream(cfg, stacked), x)
    assert timesteps_to_stream(cfg, inp["t"]).shape == (BATCH, 1, FRAMES)
    stream_inputs = (to_stream(cfg, x), timesteps_to_stream(cfg, inp["t"]), to_stream(cfg, inp["cond"]),
                     to_stream(cfg, inp["context"]), to_stream(cfg, inp["mouse"]), to_stream(cfg, inp["keyboard"]))
    model = nnx.eval_shape(lambda: WorldDiT(cfg, rngs=nnx.Rngs(0)))
    graphdef, state = nnx.split(model)
    out = jax.eval_shape(lambda s, *a: nnx.merge(graphdef, s).forward_causal(*a), state, *stream_inputs)
    assert out.shape == stacked.shape
    assert from_stream(cfg, jnp.zeros(out.shape)).shape == x.shape
