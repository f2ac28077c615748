"""The camera warp of ours (``DiTConfig.camera_warp``): the pure functions, and every DiT entry point agreeing
with it on (cached decode == teacher forcing == causal), the cache carrying the previous latent."""

from __future__ import annotations

import dataclasses
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from solaris_env.world_model import camera as camera_lib
from solaris_env.world_model import kv_cache
from solaris_env.world_model.config import DiTConfig, WorldModelConfig

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from test_dit import (TOL, _build, _cfg, _inputs, _rollout, _seq_args,  # noqa: E402  (shared builders)
                      _teacher_forcing, causal_fn)


def _turning(cfg: WorldModelConfig, seed: int):
    """(cfg, random-weight model, inputs) with turns of up to ~135 degrees per latent frame (offsets and shifts
    of several tokens)."""
    inp = _inputs(cfg, seed=seed)
    inp["mouse"] = inp["mouse"] * 3.0
    return cfg, _build(cfg, seed=seed), inp


def _cached_rollout_agrees(cfg, model, inp) -> dict:
    """The cached rollout (denoise / commit passes) == teacher forcing == the causal forward; returns it."""
    out = _rollout(cfg, model, inp)
    np.testing.assert_allclose(out["denoise"], _teacher_forcing(model, inp), atol=TOL, rtol=0)
    v_causal = causal_fn(model, *_seq_args(inp, "clean", jnp.zeros_like(inp["t"])))
    np.testing.assert_allclose(out["commit"], v_causal, atol=TOL, rtol=0)
    return out


# ---------------------------------------------------------------------------------------------
# Camera warp
# ---------------------------------------------------------------------------------------------

WARP = (0.1, 0.06)  # (height, width) latent pixels per degree


def _warp_cfg() -> WorldModelConfig:
    cfg = _cfg(players=2)
    return cfg.replace(dit=dataclasses.replace(cfg.dit, camera_warp=WARP))


def test_frame_turns_and_content_shift_signs():
    mouse = np.zeros((1, 1, 2, 12, 2), np.float32)
    mouse[0, 0, 1, -4:, 0] = 0.5  # yaw left, 4 ticks of 7.5 degrees
    mouse[0, 0, 1, -1, 1] = 0.2  # look up 3 degrees
    mouse[0, 0, 1, 0, 0] = 9.0  # an older tick: not this frame's turn
    turns = camera_lib.frame_turns(jnp.asarray(mouse), 4)
    np.testing.assert_allclose(turns[0, 0], [[0, 0], [30.0, 3.0]], rtol=1e-6)
    shift = camera_lib.content_shift(turns, WARP)
    np.testing.assert_allclose(shift[0, 0, 1], [3.0 * WARP[0], 30.0 * WARP[1]], rtol=1e-6)  # down, right


def test_shift_latents_moves_content_exactly_by_whole_pixels_and_interpolates_between():
    x = jax.random.normal(jax.random.key(0), (2, 5, 6, 3))
    out = camera_lib.shift_latents(x, jnp.asarray([[0.0, 2.0], [-1.0, 0.0]]))
    np.testing.assert_allclose(out[0, :, 2:], x[0, :, :-2], atol=1e-6)  # content moved right by 2
    np.testing.assert_allclose(out[0, :, :2], np.repeat(x[0, :, :1], 2, axis=1), atol=1e-6)  # edge repeated
    np.testing.assert_allclose(out[1, :-1], x[1, 1:], atol=1e-6)  # moved up by 1
    half = camera_lib.shift_latents(x, jnp.asarray([[0.0, 0.5], [0.0, 0.0]]))
    np.testing.assert_allclose(half[0, :, 1:], 0.5 * (x[0, :, 1:] + x[0, :, :-1]), atol=1e-6)
    np.testing.assert_allclose(half[1], x[1], atol=1e-6)
    with pytest.raises(ValueError, match="shift_latents"):
        camera_lib.shift_latents(x, jnp.zeros((2, 3)))


def test_cubic_shift_is_exact_on_whole_pixels_and_ramps_and_blurs_less_when_repeated():
    x = jax.random.normal(jax.random.key(3), (2, 5, 8, 3))
    whole = jnp.asarray([[0.0, 2.0], [-1.0, 0.0]])
    np.testing.assert_allclose(camera_lib.shift_latents(x, whole, "cubic"), camera_lib.shift_latents(x, whole),
                               atol=1e-6)
    ramp = jnp.broadcast_to(jnp.arange(8.0)[None, None, :, None], (1, 4, 8, 1))
    out = camera_lib.shift_latents(ramp, jnp.asarray([[0.0, 0.3]]), "cubic")
    np.testing.assert_allclose(out[0, :, 2:-1, 0], np.broadcast_to(np.arange(2, 7) - 0.3, (4, 5)), atol=1e-5)
    noise = jax.random.normal(jax.random.key(4), (64, 1, 64, 1))
    lin, cub = noise, noise
    for _ in range(8):  # a turn of 0.57 latent pixels per step, shifted step after step
        lin = camera_lib.shift_latents(lin, jnp.tile(jnp.asarray([[0.0, 0.57]]), (64, 1)))
        cub = camera_lib.shift_latents(cub, jnp.tile(jnp.asarray([[0.0, 0.57]]), (64, 1)), "cubic")
    inner = slice(8, None)  # away from the repeated edge
    assert float(jnp.std(cub[:, :, inner])) > 1.25 * float(jnp.std(lin[:, :, inner]))
    with pytest.raises(ValueError, match="interp"):
        camera_lib.shift_latents(x, whole, "nearest")
    with pytest.raises(ValueError, match="warp_interp"):
        DiTConfig(camera_warp=(0.2, 0.1), warp_interp="nearest")


@pytest.mark.parametrize("interp", ["linear", "cubic"])
@pytest.mark.parametrize("shift", [0.3, 0.7, 1.6, -0.4, -1.5, 2.0])
def test_shift_interpolates_the_signal_extended_by_its_edges(interp, shift):
    """A shift reads the frame as if its edge pixels repeated outward forever, so the strip a shift uncovers is
    the edge value (where the kernel sees only the extension), never the edge mixed with the wrong weights."""
    x = np.asarray(jax.random.normal(jax.random.key(5), (1, 3, 9, 2)))
    out = np.asarray(camera_lib.shift_latents(jnp.asarray(x), jnp.asarray([[0.0, shift]]), interp))
    pad = 4
    ext = np.concatenate([np.repeat(x[:, :, :1], pad, 2), x, np.repeat(x[:, :, -1:], pad, 2)], axis=2)
    src = np.arange(9) - shift + pad  # where each output column reads, in the extended signal
    lo = np.floor(src).astype(int)
    t = (src - lo)[None, None, :, None]
    if interp == "linear":
        ref = (1 - t) * ext[:, :, lo] + t * ext[:, :, lo + 1]
    else:
        w = camera_lib._cubic_weights(t)
        ref = sum(float_w * ext[:, :, lo + k - 1] for k, float_w in enumerate(np.asarray(w)))
    np.testing.assert_allclose(out, ref, atol=1e-5)
    edge = np.arange(9) - shift <= (0 if interp == "linear" else -1)  # the kernel reads only the left extension
    np.testing.assert_allclose(out[0][:, edge], np.broadcast_to(x[0][:, :1], out[0][:, edge].shape), atol=1e-6)


def test_camera_warp_config_and_cache():
    with pytest.raises(ValueError, match="camera_warp"):
        DiTConfig(camera_warp=(float("nan"), 0.0))
    with pytest.raises(ValueError, match="camera_warp"):
        DiTConfig(multiplayer="concat", camera_warp=(0.1, 0.1))
    cfg = _warp_cfg()
    assert cfg.patch_in_channels == cfg.in_channels + cfg.out_channels
    assert WorldModelConfig.test().patch_in_channels == WorldModelConfig.test().in_channels
    cache = kv_cache.init_cache(cfg, 3)
    assert cache.latent.shape == (3, 2, cfg.latent_height, cfg.latent_width, cfg.out_channels)  # once, not per layer
    assert kv_cache.init_cache(WorldModelConfig.test(), 1).latent is None


@pytest.fixture(scope="module")
def warp_model():
    return _turning(_warp_cfg(), seed=31)


def test_warp_cached_rollout_equals_teacher_forcing_and_causal(warp_model):
    cfg, model, inp = warp_model
    out = _cached_rollout_agrees(cfg, model, inp)
    last = inp["clean"][:, :, -1]
    np.testing.assert_allclose(out["cache"].latent, jnp.broadcast_to(last, out["cache"].latent.shape), atol=1e-6)


def test_warp_input_reaches_the_next_frame_only(warp_model):
    """Changing frame i's latent changes frame i + 1's output through the warp even with the attention unable
    to see it (a bidirectional pass has no mask; compare causal outputs of frame i + 1 with and without)."""
    cfg, model, inp = warp_model
    i = 1
    x = inp["clean"]
    moved = x.at[:, :, i].add(1.0)
    t = jnp.zeros_like(inp["t"])
    base = causal_fn(model, x, t, inp["cond"], inp["context"], inp["mouse"], inp["keyboard"])
    other = causal_fn(model, moved, t, inp["cond"], inp["context"], inp["mouse"], inp["keyboard"])
    delta = jnp.abs(other - base).max(axis=(0, 1, 3, 4, 5))
    assert float(delta[:i].max()) == 0.0 and float(delta[i + 1]) > 1e-4, delta


def test_warp_reads_the_given_clean_latents(warp_model):
    """Training hands the clean latents (what a rollout commits) to the warp; by default it reads x itself."""
    cfg, model, inp = warp_model
    args = _seq_args(inp)
    fn = nnx.jit(lambda m, *a, clean=None: m.forward_causal(*a, clean=clean))
    base = fn(model, *args)
    np.testing.assert_array_equal(fn(model, *args, clean=inp["noisy"]), base)
    delta = jnp.abs(fn(model, *args, clean=inp["clean"]) - base).max(axis=(0, 1, 3, 4, 5))
    assert float(delta[0]) == 0.0 and float(delta[1:].min()) > 1e-4, delta  # frame 0 has no previous frame


# ---------------------------------------------------------------------------------------------
# Walk warp
# ---------------------------------------------------------------------------------------------

def _keys(*held: str, ticks: int = 4, window: int = 12) -> np.ndarray:
    """(1, 1, 1, window, 23) keyboard window holding ``held`` over its last ``ticks`` ticks."""
    from solaris_env.spaces import KEYBOARD_DIM, MODEL_INDEX
    kb = np.zeros((1, 1, 1, window, KEYBOARD_DIM), np.float32)
    for name in held:
        kb[..., window - ticks:, MODEL_INDEX[name]] = 1.0
    return kb


@pytest.mark.parametrize("held, ticks, expected", [
    ((), 4, (0.0, 0.0)),
    (("forward",), 4, (4.0, 0.0)),
    (("forward",), 2, (2.0, 0.0)),
    (("back",), 4, (-4.0, 0.0)),
    (("right",), 4, (0.0, 4.0)),
    (("left",), 3, (0.0, -3.0)),
    (("forward", "back"), 4, (0.0, 0.0)),
    (("forward", "right"), 4, (4 / np.sqrt(2), 4 / np.sqrt(2))),  # a diagonal is no faster
    (("forward", "sprint"), 4, (4 * camera_lib.SPRINT_FACTOR, 0.0)),
    (("back", "sprint"), 4, (-4.0, 0.0)),  # sprint only forward
    (("forward", "sneak"), 4, (4 * camera_lib.SNEAK_FACTOR, 0.0)),
    (("jump", "attack"), 4, (0.0, 0.0)),
])
def test_frame_moves_reads_the_movement_keys_of_the_frames_last_ticks(held, ticks, expected):
    np.testing.assert_allclose(camera_lib.frame_moves(jnp.asarray(_keys(*held, ticks=ticks)), 4)[0, 0, 0],
                               expected, rtol=1e-6, atol=1e-6)


def test_frame_moves_ignores_older_ticks_and_names_a_short_keyboard():
    kb = _keys("forward", ticks=8)  # 4 of the 8 held ticks belong to the previous latent frame
    np.testing.assert_allclose(camera_lib.frame_moves(jnp.asarray(kb), 4)[0, 0, 0], [4.0, 0.0])
    with pytest.raises(ValueError, match="movement keys"):
        camera_lib.frame_moves(jnp.zeros((1, 1, 1, 12, 2)), 4)


def test_walk_source_geometry():
    h = w = 8
    moves = jnp.asarray([[0.0, 0.0], [0.5, 0.0], [-0.5, 0.0], [0.0, 0.5]])
    rows, cols = (np.asarray(a) for a in camera_lib.walk_source(h, w, moves))
    grid_r, grid_c = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    np.testing.assert_allclose(rows[0], grid_r, atol=1e-5)  # standing still: every pixel from itself
    np.testing.assert_allclose(cols[0], grid_c, atol=1e-5)
    centre = (h - 1) / 2
    # forward: every pixel comes from nearer the centre (the view expands), more so far from the horizon
    assert np.all(np.abs(rows[1] - centre) < np.abs(grid_r - centre))
    assert np.all(np.abs(cols[1] - centre) <= np.abs(grid_c - centre) + 1e-6)
    drift = np.abs(rows[1] - grid_r)[:, 0]
    assert np.all(np.diff(drift[h // 2:]) > 0) and np.all(np.diff(drift[:h // 2]) < 0)
    np.testing.assert_allclose(rows[1], (h - 1) - rows[1][::-1], atol=1e-5)  # the floor mirrors the ceiling
    # back: from further out (the view shrinks)
    assert np.all(np.abs(rows[2] - centre) > np.abs(grid_r - centre))
    # strafe right: the content moves left, the nearest rows (top and bottom) most; the rows stay
    np.testing.assert_allclose(rows[3], grid_r, atol=1e-5)
    shift = (cols[3] - grid_c)[:, 0]
    assert np.all(shift > 0) and shift[0] == pytest.approx(shift[-1], abs=1e-5) and shift[0] > shift[h // 2 - 1]


def test_walk_latents_is_exact_standing_still_and_samples_the_source():
    x = jax.random.normal(jax.random.key(1), (2, 6, 6, 3))
    moves = jnp.asarray([[0.0, 0.0], [0.6, -0.3]])
    out = camera_lib.walk_latents(x, moves)
    np.testing.assert_allclose(out[0], x[0], atol=1e-5)
    rows, cols = camera_lib.walk_source(6, 6, moves)
    r, c = 1, 4  # the source of one output pixel, bilinear by hand
    sr, sc = float(rows[1, r, c]), float(cols[1, r, c])
    r0, c0 = int(np.floor(sr)), int(np.floor(sc))
    fr, fc = sr - r0, sc - c0
    clip = lambda i: min(max(i, 0), 5)
    px = lambda i, j: np.asarray(x[1, clip(i), clip(j)])
    want = ((1 - fr) * ((1 - fc) * px(r0, c0) + fc * px(r0, c0 + 1))
            + fr * ((1 - fc) * px(r0 + 1, c0) + fc * px(r0 + 1, c0 + 1)))
    np.testing.assert_allclose(out[1, r, c], want, atol=1e-5)
    with pytest.raises(ValueError, match="walk_latents"):
        camera_lib.walk_latents(x, jnp.zeros((3, 2)))


def test_walk_warp_config():
    with pytest.raises(ValueError, match="walk_warp"):
        DiTConfig(walk_warp=0.1)  # no camera warp to carry it
    with pytest.raises(ValueError, match="walk_warp"):
        DiTConfig(camera_warp=WARP, walk_warp=-0.1)
    with pytest.raises(ValueError, match="walk_warp"):
        DiTConfig(camera_warp=WARP, walk_warp=float("inf"))
    assert DiTConfig(camera_warp=WARP, walk_warp=0.1).walk_warp == 0.1


def _walking(seed: int):
    cfg = _warp_cfg()
    cfg = cfg.replace(dit=dataclasses.replace(cfg.dit, walk_warp=0.13))
    inp = _inputs(cfg, seed=seed)
    return cfg, _build(cfg, seed=seed), inp


def test_walk_warp_cached_rollout_equals_teacher_forcing_and_causal():
    cfg, model, inp = _walking(32)
    from solaris_env.spaces import MODEL_INDEX
    inp["keyboard"] = inp["keyboard"].at[..., MODEL_INDEX["forward"]].set(1.0)  # walking in every frame
    _cached_rollout_agrees(cfg, model, inp)


def test_walk_warp_moves_the_warp_input_only_when_walking():
    """The same weights with and without the walk: the outputs differ where the movement keys are held, and
    are equal where they are not (the turn-only warp is unchanged)."""
    from solaris_env.spaces import MODEL_INDEX
    cfg, model, inp = _walking(33)
    still = cfg.replace(dit=dataclasses.replace(cfg.dit, walk_warp=0.0))
    model_still = _build(still, seed=33)
    nnx.update(model_still, nnx.state(model))
    for name in ("forward", "back", "left", "right"):
        inp["keyboard"] = inp["keyboard"].at[..., MODEL_INDEX[name]].set(0.0)
    args = lambda i: (i["clean"], jnp.zeros_like(i["t"]), i["cond"], i["context"], i["mouse"], i["keyboard"])
    np.testing.assert_array_equal(causal_fn(model, *args(inp)), causal_fn(model_still, *args(inp)))
    walking = dict(inp, keyboard=inp["keyboard"].at[..., MODEL_INDEX["forward"]].set(1.0))
    delta = jnp.abs(causal_fn(model, *args(walking)) - causal_fn(model_still, *args(walking)))
    delta = delta.max(axis=(0, 1, 3, 4, 5))
    assert float(delta[0]) == 0.0 and float(delta[1:].min()) > 1e-4, delta  # frame 0 has no previous frame


# ---------------------------------------------------------------------------------------------
# Previous-frame skip
# ---------------------------------------------------------------------------------------------

def _skipping(seed: int, walk: float = 0.0):
    cfg = _warp_cfg()
    cfg = cfg.replace(dit=dataclasses.replace(cfg.dit, walk_warp=walk, previous_skip=True))
    return cfg, _build(cfg, seed=seed), _turning(cfg, seed)[2]


def test_previous_skip_config():
    with pytest.raises(ValueError, match="previous_skip"):
        DiTConfig(previous_skip=True)  # no camera warp, so no previous latent
    assert DiTConfig(camera_warp=WARP, previous_skip=True).previous_skip
    assert not DiTConfig().previous_skip  # the official layout


def test_previous_skip_cached_rollout_equals_teacher_forcing_and_causal():
    cfg, model, inp = _skipping(34, walk=0.13)
    from solaris_env.spaces import MODEL_INDEX
    inp["keyboard"] = inp["keyboard"].at[..., MODEL_INDEX["forward"]].set(1.0)
    _cached_rollout_agrees(cfg, model, inp)


def test_previous_skip_adds_the_gated_noisy_and_previous_latents():
    """v(skip) - v(the same weights without it) = g_x(t) * x - g_b(t) * base: base is the previous latent (no
    turn, no walk: the warp is the identity) where the mask is 0, the first-frame latent where it is 1; g_x, g_b =
    the two halves of the gate's bias when its kernel is zero."""
    cfg, model, inp = _skipping(35)
    plain_cfg = cfg.replace(dit=dataclasses.replace(cfg.dit, previous_skip=False))
    plain = _build(plain_cfg, seed=35)
    nnx.update(plain, nnx.state(model).filter(lambda path, _: path[0] != "skip_gate"))
    bias_x, bias_b = jnp.linspace(-1.0, 2.0, cfg.out_channels), jnp.linspace(1.5, -0.5, cfg.out_channels)
    bias = jnp.concatenate([bias_x, bias_b])
    model.skip_gate.kernel.set_value(jnp.zeros_like(model.skip_gate.kernel.get_value()))
    model.skip_gate.bias.set_value(bias)
    mask = jnp.zeros(inp["cond"].shape[:-1] + (1,)).at[:, :, 0].set(1.0)
    cond = inp["cond"].at[..., :1].set(mask)
    first = cond[..., cond.shape[-1] - cfg.out_channels:]
    still = dict(inp, mouse=jnp.zeros_like(inp["mouse"]), keyboard=jnp.zeros_like(inp["keyboard"]), cond=cond)
    args = _seq_args(still, "noisy")
    clean = inp["clean"]
    fn = nnx.jit(lambda m, *a: m.forward_causal(*a, clean=clean))
    delta = fn(model, *args) - fn(plain, *args)
    prev = jnp.concatenate([first[:, :, :1], clean[:, :, :-1]], axis=2)
    np.testing.assert_allclose(delta, bias_x * inp["noisy"] - bias_b * prev, atol=1e-4, rtol=1e-5)


def test_previous_skip_gate_learns_from_zero():
    """At their zero initialisation both gates still get a gradient (through x and base), so fine-tuning can open
    them."""
    cfg, model, inp = _skipping(36)
    model.skip_gate.kernel.set_value(jnp.zeros_like(model.skip_gate.kernel.get_value()))
    model.skip_gate.bias.set_value(jnp.zeros_like(model.skip_gate.bias.get_value()))
    args = _seq_args(inp, "noisy")

    def loss(m):
        return jnp.mean(jnp.square(m.forward_causal(*args, clean=inp["clean"]) - inp["clean"]))

    grads = nnx.grad(loss)(model)
    assert float(jnp.abs(grads["skip_gate"]["bias"].get_value()).min()) > 0
    assert float(jnp.abs(grads["skip_gate"]["kernel"].get_value()).max()) > 0


# ---------------------------------------------------------------------------------------------
# Jump warp
# ---------------------------------------------------------------------------------------------

def test_jump_constants_are_the_engines():
    from solaris_env.engine import constants as C
    assert (camera_lib.JUMP_VELOCITY, camera_lib.GRAVITY, camera_lib.VERTICAL_DRAG) == (
        C.JUMP_VELOCITY, C.GRAVITY, C.VERTICAL_DRAG)


def test_jump_ticks_follow_the_engine_on_flat_ground():
    """The jump key alone, simulated, against the engine's player on a flat world: held, tapped, and pressed in
    the air (ignored)."""
    from solaris_env.real_env import RealParallelEnv
    from solaris_env.spaces import noop
    rng = np.random.default_rng(0)
    jumps = np.concatenate([np.ones(30), np.zeros(6), (rng.random(60) < 0.2)]).astype(np.float32)
    env = RealParallelEnv(num_players=2, world="flat", resolution=(16, 16), ticks_per_step=1)
    _, infos = env.reset(seed=3)
    agent = env.possible_agents[0]
    y0, ys = infos[agent]["pos"][1], []
    for j in jumps:
        a = {name: noop() for name in env.possible_agents}
        a[agent]["jump"] = int(j)
        _, _, _, _, infos = env.step(a)
        ys.append(infos[agent]["pos"][1] - y0)
    heights, states = camera_lib.jump_ticks(jnp.asarray(jumps)[None, None], jnp.zeros((1, 1, 2)))
    assert heights.shape == (1, 1, len(jumps)) and states.shape == (1, 1, len(jumps), 2)
    np.testing.assert_allclose(np.asarray(heights[0, 0]), ys, atol=2e-3)
    assert max(ys) > 1.2 and ys[11] == pytest.approx(0.0, abs=1e-3)  # a jump peaks at ~1.25 and lasts 12 ticks


def test_frame_lifts_mean_heights_and_carried_state():
    from solaris_env.spaces import MODEL_INDEX
    jump_key = MODEL_INDEX["jump"]
    k, frames = 4, 5
    kb = np.zeros((2, 2, 8 + k * frames, 23), np.float32)
    kb[0, 0, :, jump_key] = 1.0  # held through the padding and every frame
    kb[1, 1, 8 + k:8 + k + 1, jump_key] = 1.0  # one tap in frame 1
    lift, after = camera_lib.frame_lifts(jnp.asarray(kb), frames, k)
    heights, _ = camera_lib.jump_ticks(jnp.asarray(kb[..., 8:, jump_key]), jnp.zeros((2, 2, 2)))
    means = np.asarray(heights).reshape(2, 2, frames, k).mean(-1)
    np.testing.assert_allclose(lift[..., 1], means, atol=1e-6)
    np.testing.assert_allclose(lift[..., 0], np.concatenate([np.zeros((2, 2, 1)), means[..., :-1]], -1), atol=1e-6)
    assert float(lift[0, 1].max()) == 0.0 and float(lift[1, 1, 1, 1]) > 0.5 and float(lift[1, 1, 0, 1]) == 0.0
    # frame by frame with the state carried (a rollout's cache) == the whole clip at once
    state = None
    for f in range(frames):
        window = jnp.asarray(kb[:, :, k * f:k * f + 12])
        one, after_f = camera_lib.frame_lifts(window, 1, k, state)
        np.testing.assert_allclose(one[:, :, 0], lift[:, :, f], atol=1e-6)
        np.testing.assert_allclose(after_f[:, :, 0], after[:, :, f], atol=1e-6)
        state = after_f[:, :, 0]
    with pytest.raises(ValueError, match="jump key"):
        camera_lib.frame_lifts(jnp.zeros((1, 1, 7, 23)), 2, 4)


def test_walk_source_rising_moves_the_floor_only():
    h = w = 8
    moves = jnp.zeros((3, 2))
    eyes = jnp.asarray([[1.0, 1.0], [1.0, 1.5], [1.5, 1.0]])
    rows, cols = (np.asarray(a) for a in camera_lib.walk_source(h, w, moves, eyes))
    grid_r, grid_c = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    np.testing.assert_allclose(rows[0], grid_r, atol=1e-5)
    centre = (h - 1) / 2
    # rising: a floor pixel came from nearer the horizon (the ground drops away below), v_src = v * H0 / H1
    floor = slice(h // 2, h)
    np.testing.assert_allclose(rows[1][floor] - centre, (grid_r[floor] - centre) / 1.5, atol=1e-5)
    assert np.all(np.abs(rows[2][floor] - centre) > np.abs(grid_r[floor] - centre))  # falling: from further out
    for i in (1, 2):  # the sky half and the columns stay
        np.testing.assert_allclose(rows[i][:h // 2], grid_r[:h // 2], atol=1e-5)
        np.testing.assert_allclose(cols[i], grid_c, atol=1e-5)
    # with H0 = H1 = 1 the walk is the walk warp's
    walk = jnp.asarray([[0.5, 0.3]])
    np.testing.assert_allclose(camera_lib.walk_source(h, w, walk, jnp.ones((1, 2)))[0],
                               camera_lib.walk_source(h, w, walk)[0], atol=1e-6)
    x = jax.random.normal(jax.random.key(2), (3, h, w, 2))
    out = camera_lib.walk_latents(x, moves, jnp.asarray([[1.3, 1.3], [1.0, 1.5], [1.0, 1.0]]))
    np.testing.assert_array_equal(out[0], x[0])  # one height, no move: bit for bit
    assert float(jnp.abs(out[1] - x[1]).max()) > 1e-3


def test_jump_warp_config_and_cache():
    with pytest.raises(ValueError, match="jump_warp"):
        DiTConfig(jump_warp=0.6)  # no camera warp to carry it
    with pytest.raises(ValueError, match="jump_warp"):
        DiTConfig(camera_warp=WARP, jump_warp=-1.0)
    cfg = _jumping(0)[0]
    assert kv_cache.init_cache(cfg, 3).jump.shape == (3, 2, camera_lib.JUMP_STATE)
    assert kv_cache.init_cache(_warp_cfg(), 1).jump is None


def _jumping(seed: int):
    cfg = _warp_cfg()
    cfg = cfg.replace(dit=dataclasses.replace(cfg.dit, walk_warp=0.13, jump_warp=1 / 1.62, previous_skip=True))
    return cfg, _build(cfg, seed=seed), _inputs(cfg, seed=seed)  # jump pressed on 30 % of the ticks


def test_jump_warp_cached_rollout_equals_teacher_forcing_and_causal():
    cfg, model, inp = _jumping(34)
    out = _cached_rollout_agrees(cfg, model, inp)
    want = camera_lib.frame_lifts(inp["keyboard"], inp["clean"].shape[2], cfg.frames_per_step)[1][:, :, -1]
    np.testing.assert_allclose(out["cache"].jump, want, atol=1e-6)


def test_jump_warp_changes_the_output_only_when_jumping():
    from solaris_env.spaces import MODEL_INDEX
    cfg, model, inp = _jumping(35)
    flat = cfg.replace(dit=dataclasses.replace(cfg.dit, jump_warp=0.0))
    model_flat = _build(flat, seed=35)
    nnx.update(model_flat, nnx.state(model))
    args = lambda i: (i["clean"], jnp.zeros_like(i["t"]), i["cond"], i["context"], i["mouse"], i["keyboard"])
    grounded = dict(inp, keyboard=inp["keyboard"].at[..., MODEL_INDEX["jump"]].set(0.0))
    np.testing.assert_allclose(causal_fn(model, *args(grounded)), causal_fn(model_flat, *args(grounded)),
                               atol=1e-5, rtol=0)  # the same up to float rounding (other fused arithmetic)
    held = dict(inp, keyboard=inp["keyboard"].at[..., MODEL_INDEX["jump"]].set(1.0))
    delta = jnp.abs(causal_fn(model, *args(held)) - causal_fn(model_flat, *args(held))).max(axis=(0, 1, 3, 4, 5))
    assert float(delta[1:].max()) > 1e-4, delta


# ---------------------------------------------------------------------------------------------
# Turning as a rotation (warp_geometry = "rotation")
# ---------------------------------------------------------------------------------------------

TINY16_WARP = (0.1996, 0.1122)  # the shipped default's camera warp on its 16 x 16 latents


def _reference_source(h: int, w: int, left_deg: float, up_deg: float, tan_v: float, tan_h: float):
    """Where each pixel of the turned view looks in the previous view, with rotation matrices: the camera turned
    left by ``left_deg`` about the world's vertical, then up by ``up_deg`` about its own right axis; a pixel's ray
    in the new camera, expressed in the old camera's frame, projected (x right, y up, z ahead)."""
    a, b = np.radians(left_deg), np.radians(up_deg)
    yaw = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])  # turn left: +x goes ahead
    pitch = np.array([[1, 0, 0], [0, np.cos(b), np.sin(b)], [0, -np.sin(b), np.cos(b)]])  # look up
    u = (np.arange(w) + 0.5) / w * 2 - 1
    v = 1 - (np.arange(h) + 0.5) / h * 2
    rays = np.stack(np.broadcast_arrays(u[None, :] * tan_h, v[:, None] * tan_v, np.ones((h, w))), -1)
    old = rays @ (yaw @ pitch).T
    su, sv = old[..., 0] / old[..., 2] / tan_h, old[..., 1] / old[..., 2] / tan_v
    return (1 - sv) / 2 * h - 0.5, (su + 1) / 2 * w - 0.5


def test_view_tangents_read_the_engines_field_of_view_from_the_warp():
    """The shipped warp's pixels per degree at the centre are those of the engine's camera: 70 degrees vertical,
    shown 16:9 in the square frame."""
    tan_v, tan_h = camera_lib.view_tangents(16, 16, TINY16_WARP)
    assert tan_v == pytest.approx(np.tan(np.radians(35.0)), rel=2e-3)
    assert tan_h == pytest.approx(np.tan(np.radians(35.0)) * 16 / 9, rel=2e-3)


@pytest.mark.parametrize("left, up", [(15.0, 0.0), (-5.0, 0.0), (0.0, 8.0), (0.0, -12.0), (10.0, -6.0), (-30.0, 25.0)])
def test_turn_source_is_the_cameras_rotation(left, up):
    h, w = 12, 16
    tan_v, tan_h = camera_lib.view_tangents(h, w, TINY16_WARP)
    row, col = camera_lib.turn_source(h, w, jnp.asarray([[left, up]]), TINY16_WARP)
    ref_row, ref_col = _reference_source(h, w, left, up, tan_v, tan_h)
    np.testing.assert_allclose(row[0], ref_row, atol=2e-3)
    np.testing.assert_allclose(col[0], ref_col, atol=2e-3)


def test_turn_source_moves_the_centre_as_the_shift_and_the_sides_faster():
    """No turn: every pixel reads itself. A small turn moves the view's centre by the warp's pixels per degree
    (the uniform shift's speed); a yaw moves the side columns ~2.5x faster on the engine's 102-degree-wide view."""
    h = w = 16
    row, col = camera_lib.turn_source(h, w, jnp.zeros((1, 2)), TINY16_WARP)
    np.testing.assert_allclose(row[0], np.broadcast_to(np.arange(h)[:, None], (h, w)), atol=1e-5)
    np.testing.assert_allclose(col[0], np.broadcast_to(np.arange(w)[None, :], (h, w)), atol=1e-5)
    d = 0.01
    row, col = camera_lib.turn_source(64, 64, jnp.asarray([[d, 0.0], [0.0, d]]), TINY16_WARP)
    shift_w = (31.5 - float(col[0, 32, 31] + col[0, 32, 32]) / 2) / d  # content moves right = source moves left
    shift_h = (31.5 - float(row[1, 31, 32] + row[1, 32, 32]) / 2) / d
    assert shift_w == pytest.approx(TINY16_WARP[1], rel=1e-2) and shift_h == pytest.approx(TINY16_WARP[0], rel=1e-2)
    row, col = camera_lib.turn_source(h, w, jnp.asarray([[5.0, 0.0]]), TINY16_WARP)
    centre, side = 7.5 - float(col[0, 8, 7] + col[0, 8, 8]) / 2, float(-col[0, 8, 0])
    assert centre == pytest.approx(5 * TINY16_WARP[1], rel=0.02) and 2.2 < side / centre < 2.8


@pytest.mark.parametrize("interp", ["linear", "cubic"])
def test_turn_latents_samples_the_source_on_the_edge_extended_frame(interp):
    """No turn returns the frame; a turn equals sampling the frame (edges repeated) at ``turn_source`` with the
    interpolation's separable weights, computed here pixel by pixel."""
    x = np.asarray(jax.random.normal(jax.random.key(7), (2, 6, 8, 3)))
    turns = jnp.asarray([[0.0, 0.0], [12.0, -7.0]])
    out = np.asarray(camera_lib.turn_latents(jnp.asarray(x), turns, WARP, interp))
    np.testing.assert_allclose(out[0], x[0], atol=1e-6)
    row, col = (np.asarray(a[1]) for a in camera_lib.turn_source(6, 8, turns, WARP))
    taps = (-1, 0, 1, 2) if interp == "cubic" else (0, 1)

    def weights(t):
        return np.asarray(camera_lib._cubic_weights(t)) if interp == "cubic" else np.array([1 - t, t])

    for r in range(6):
        for c in range(8):
            r0, c0 = int(np.floor(row[r, c])), int(np.floor(col[r, c]))
            wr, wc = weights(row[r, c] - r0), weights(col[r, c] - c0)
            ref = sum(wr[a] * wc[b] * x[1, np.clip(r0 + da, 0, 5), np.clip(c0 + db, 0, 7)]
                      for a, da in enumerate(taps) for b, db in enumerate(taps))
            np.testing.assert_allclose(out[1, r, c], ref, atol=1e-5)


def test_warp_geometry_config():
    assert DiTConfig().warp_geometry == "shift"
    with pytest.raises(ValueError, match="warp_geometry"):
        DiTConfig(camera_warp=WARP, warp_geometry="fisheye")
    with pytest.raises(ValueError, match="warp_geometry"):
        DiTConfig(camera_warp=(0.0, 0.1), warp_geometry="rotation")  # no vertical field of view to read
    assert DiTConfig(camera_warp=WARP, warp_geometry="rotation").warp_geometry == "rotation"


def _rotating(seed: int):
    cfg = _warp_cfg()
    cfg = cfg.replace(dit=dataclasses.replace(cfg.dit, warp_geometry="rotation", previous_skip=True))
    return cfg, _build(cfg, seed=seed), _turning(cfg, seed)[2]


def test_rotation_warp_cached_rollout_equals_teacher_forcing_and_causal():
    _cached_rollout_agrees(*_rotating(34))


def test_rotation_warp_changes_the_output_only_when_turning():
    """The same weights under both geometries: equal outputs without a turn, different ones with a turn."""
    cfg, model, inp = _rotating(35)
    shift = cfg.replace(dit=dataclasses.replace(cfg.dit, warp_geometry="shift"))
    model_shift = _build(shift, seed=35)
    nnx.update(model_shift, nnx.state(model))
    args = lambda i: (i["clean"], jnp.zeros_like(i["t"]), i["cond"], i["context"], i["mouse"], i["keyboard"])
    delta = jnp.abs(causal_fn(model, *args(inp)) - causal_fn(model_shift, *args(inp))).max(axis=(0, 1, 3, 4, 5))
    assert float(delta[0]) == 0.0 and float(delta[1:].min()) > 1e-4, delta  # frame 0 has no previous frame
    still = dict(inp, mouse=jnp.zeros_like(inp["mouse"]))
    np.testing.assert_allclose(causal_fn(model, *args(still)), causal_fn(model_shift, *args(still)), atol=1e-6)


# ---------------------------------------------------------------------------------------------
# Still memory (SamplerConfig.still_memory): the warp's input blended while the view holds still
# ---------------------------------------------------------------------------------------------

def test_holds_still_reads_the_frames_last_ticks():
    k = 4
    mouse = np.zeros((1, 1, 4, 12, 2), np.float32)
    kb = np.concatenate([_keys(), _keys("forward"), _keys("attack", ticks=8), _keys()], axis=2)
    kb[0, 0, 2, -k:] = 0.0  # frame 2: the key was down only in the previous frame's ticks
    mouse[0, 0, 3, -1, 1] = 0.01  # frame 3: the smallest look up
    still = camera_lib.holds_still(jnp.asarray(mouse), jnp.asarray(kb), k)
    np.testing.assert_array_equal(still[0, 0], [True, False, True, False])
    mouse[0, 0, 3, 0, 1] = 0.0
    mouse[0, 0, 3, :-k, 0] = 5.0  # older turns do not count
    mouse[0, 0, 3, -1, 1] = 0.0
    lift = np.zeros((1, 1, 4, 2), np.float32)
    lift[0, 0, 0] = [0.3, 0.2]  # still falling after a jump: the view moves
    still = camera_lib.holds_still(jnp.asarray(mouse), jnp.asarray(kb), k, jnp.asarray(lift))
    np.testing.assert_array_equal(still[0, 0], [False, False, True, True])


def test_still_memories_blend_only_still_frames_and_chain():
    from solaris_env.world_model.dit import _still_memories
    rng = np.random.default_rng(0)
    prev = jnp.asarray(rng.normal(size=(1, 2, 3, 3, 4)), jnp.float32)
    x = jnp.asarray(rng.normal(size=(1, 2, 3, 3, 3, 4)), jnp.float32)
    for still, m in ((None, 0.5), (jnp.ones((1, 2, 3), bool), 0.0)):  # off: the frames themselves
        p, mem = _still_memories(prev, x, still, m)
        np.testing.assert_array_equal(p, jnp.concatenate([prev[:, :, None], x[:, :, :-1]], axis=2))
        np.testing.assert_array_equal(mem, x)
    still = jnp.asarray([[[True, True, False], [False, True, True]]])
    p, mem = _still_memories(prev, x, still, 0.75)
    a0 = 0.75 * prev[:, 0] + 0.25 * x[:, 0, 0]  # player 0: frames 0 and 1 blend, frame 2 moves
    a1 = 0.75 * a0 + 0.25 * x[:, 0, 1]
    np.testing.assert_allclose(mem[:, 0], jnp.stack([a0, a1, x[:, 0, 2]], axis=1), atol=1e-6)
    np.testing.assert_allclose(p[:, 0], jnp.stack([prev[:, 0], a0, a1], axis=1), atol=1e-6)
    b1 = 0.75 * x[:, 1, 0] + 0.25 * x[:, 1, 1]  # player 1: frame 0 moves, frames 1 and 2 blend
    np.testing.assert_allclose(mem[:, 1], jnp.stack([x[:, 1, 0], b1, 0.75 * b1 + 0.25 * x[:, 1, 2]], axis=1),
                               atol=1e-6)


def test_still_memory_config():
    cfg = _warp_cfg()
    from solaris_env.world_model.config import SamplerConfig
    for bad in (-0.1, 1.0, 1.5):
        with pytest.raises(ValueError, match="still_memory"):
            SamplerConfig(still_memory=bad)
    with pytest.raises(ValueError, match="still_memory"):
        WorldModelConfig.test().replace(sampler=SamplerConfig(still_memory=0.5))  # no camera warp
    assert cfg.replace(sampler=SamplerConfig(still_memory=0.5)).sampler.still_memory == 0.5


def test_still_memory_blends_the_committed_latent_only_while_still(warp_model):
    """decode(commit=1) with still_memory: the cache's latent is the blend of the committed frame and the cache's
    previous latent where the frame holds still and is not given, the frame itself otherwise; the pass's output
    is the same (the blend is the next frame's input)."""
    cfg, model, inp = warp_model
    fn = nnx.jit(lambda m, x, t, cond, context, mouse, keyboard, cache, sm: m.decode(
        x, t, cond, m.context_kv(context), mouse, keyboard, cache, 1, commit=1, still_memory=sm),
        static_argnames="sm")
    from solaris_env.world_model.action_module import window_at
    cache = kv_cache.init_cache(cfg, 1, jnp.float32)
    cache = cache.replace(latent=jax.random.normal(jax.random.key(7), cache.latent.shape))
    cond = inp["cond"][:, :, 1:2].at[..., 0].set(0.0)  # not a given frame
    mouse = window_at(jnp.zeros_like(inp["mouse"]), cfg, 1).at[:, 1, ..., 0].set(0.5)  # player 1 turns
    keyboard = window_at(jnp.zeros_like(inp["keyboard"]), cfg, 1)
    x, t = inp["clean"][:, :, 1:2], jnp.zeros_like(inp["t"][:, :, 1:2])
    v0, c0 = fn(model, x, t, cond, inp["context"], mouse, keyboard, cache, 0.0)
    v1, c1 = fn(model, x, t, cond, inp["context"], mouse, keyboard, cache, 0.6)
    np.testing.assert_array_equal(v1, v0)
    np.testing.assert_array_equal(c0.latent, x[:, :, 0])
    np.testing.assert_allclose(c1.latent[:, 0], 0.6 * cache.latent[:, 0] + 0.4 * x[:, 0, 0], atol=1e-6)
    np.testing.assert_array_equal(c1.latent[:, 1], x[:, 1, 0])  # turning
    given = cond.at[..., 0].set(1.0)
    _, c2 = fn(model, x, t, given, inp["context"], mouse, keyboard, cache, 0.6)
    np.testing.assert_array_equal(c2.latent, x[:, :, 0])
    with pytest.raises(ValueError, match="still_memory"):
        fn(model, x, t, cond, inp["context"], mouse, keyboard, cache, 1.0)


def test_the_streaming_model_blends_its_warp_input_while_still_and_nowhere_else():
    """A rollout of the test preset with the camera warp: with still_memory m the cache's latent after each step is
    m * the one before + (1 - m) * the committed frame while nobody moves, and the committed frame once a player
    turns; the frames of a still world differ from those without (the blend is the next frame's input)."""
    from solaris_env.spaces import CAMERA_SCALE_DEG
    from solaris_env.world_model.config import SamplerConfig
    from test_world_model import first_frames, host, random_model
    cfg = WorldModelConfig.test()
    cfg = cfg.replace(dit=dataclasses.replace(cfg.dit, camera_warp=WARP))
    plain = random_model(cfg)
    model = plain.with_sampler(SamplerConfig(still_memory=0.5))
    still = np.zeros((1, 2, model.frames_per_step, model.action_dim), np.float32)
    turning = still.copy()
    turning[:, 1, :, model.config.action.keyboard_dim] = 10.0 / CAMERA_SCALE_DEG  # player 1 turns left
    state = model.init(first_frames(model, 1), jax.random.key(0))
    ref = plain.init(first_frames(model, 1), jax.random.key(0))
    for i, actions in enumerate((still, still, still, turning)):
        before = host(state)
        frames, state = model.step(state, actions)
        ref_frames, ref = plain.step(ref, actions)
        after = host(state)
        committed = before.latent_BP1hwC[:, :, 0]
        if i == 0:  # frame 0 is given: nothing to blend with
            np.testing.assert_array_equal(after.dit_cache.latent[:, 0], committed)  # (B, 1, P, ...): DiT batch 1
            np.testing.assert_array_equal(np.asarray(frames), np.asarray(ref_frames))
            continue
        blend = 0.5 * before.dit_cache.latent[:, 0] + 0.5 * committed
        # the frame committed now was made by the previous step's actions: still for both players
        np.testing.assert_allclose(after.dit_cache.latent[:, 0], blend, atol=1e-5)
        if actions is turning:  # the frame player 1 turned for is committed by the next step, as it is
            _, state = model.step(state, turning)
            latent = host(state).dit_cache.latent[:, 0]
            np.testing.assert_array_equal(latent[:, 1], after.latent_BP1hwC[:, 1, 0])
            np.testing.assert_allclose(latent[:, 0], 0.5 * after.dit_cache.latent[:, 0, 0]
                                       + 0.5 * after.latent_BP1hwC[:, 0, 0], atol=1e-5)
    assert not np.array_equal(np.asarray(frames), np.asarray(ref_frames))
