"""The streaming world model: B worlds x P players, one latent frame (k video frames) per ``step``.

    model = WorldModel.from_preset("tiny", seed=0)          # or WorldModel.load(path)
    state = model.init(first_frames_BPHW3, jax.random.key(0))
    state.frame0_BPHW3                                      # decoded latent frame 0 (1 frame/player)
    frames_BPkHW3, state = model.step(state, actions_BPk25)  # k = model.frames_per_step
    state = model.reset_worlds(state, done_B, new_first_frames_BPHW3)

Frame 0 (docs/model.md §5.4). As in the reference, latent frame 0 is *generated* from noise conditioned
on the first frame (mask + its VAE encoding + image-encoder tokens), not copied. The causal VAE decodes
latent frame 0 to ONE video frame and every later latent frame to k frames, so ``init`` generates,
decodes latent frame 0 (its commit is left to the first ``step``) and stores that frame in ``state.frame0_BPHW3`` (uint8); every
``step`` then generates latent frame i >= 1 and returns exactly k frames. Video frame index of the
frames returned by the n-th step (n = 1, 2, ...): k*(n-1)+1 .. k*n, frame 0 being ``frame0_BPHW3``.

Actions. ``actions_BPk25`` of step n are the model's 25-dim vectors (keyboard 23 binary flags, then
mouse yaw/pitch after ``camera_linear``; ``spaces.env_action_to_model_vector``) of video frames
k*(n-1)+1 .. k*n. The state keeps the last ``action_window`` actions as a rolling buffer, initialised
with ``first_actions`` (default: all zeros, "no-op") repeated: exactly the reference's left padding
(docs/model.md §4.3), so latent frame i sees actions k*i - action_window + 1 .. k*i, clamped at 0.

One step = few-step sampling of latent frame i (``sampler.sample_frame`` over ``cfg.sampler``
timesteps, x0 prediction + fresh noise; the DiT's passes against the rolling KV cache, update
discarded) and a streaming VAE decode of it (the decoder's causal cache lives in the state). The
reference's commit pass (frame i at t = 0, writing the cache) is fused into the NEXT step's first
pass: ``WorldDiT.decode(..., commit=1)`` runs [clean frame i - 1 at t = 0 ; noisy frame i at
t = 1000] as two block-causal frames and writes only frame i - 1, so the state's cache holds every
generated frame but the last (``latent_BP1hwC``, the pending one). Same numbers as the separate passes
up to float rounding (``test_streaming_step_equals_offline_rollout``).

Static shapes, memory. Every state leaf has a fixed shape with a leading world axis B. The KV caches
are rolling windows (``kv_cache``), the VAE cache holds a fixed number of frames, the action buffer is
``action_window`` long and the first-frame conditioning is a table of ``cond_frames`` latent frames
(below), so memory is flat over arbitrarily long rollouts and ``step`` compiles once. The only growing
quantity is ``frame_index_B`` (int32): it is the DiT's RoPE start frame (absolute positions, as in the
reference). RoPE angles are computed directly as position * frequency in f32 (no table), so there is
no length limit; attention only depends on position differences inside the window, and the f32 angle
rounding error grows like position * 2^-24 rad (about 1e-3 rad after 10^4 latent frames).

Work per step. The context (image-encoder tokens of the first frames) is constant, so ``init`` stores
its cross-attention keys/values for every DiT layer in the state (``context_kv``, ``WorldDiT.context_kv``)
and the passes read them (``WorldDiT.decode``) instead of re-projecting the context 5 times per step.
The denoising passes (``commit=0``) never build the updated KV cache (they attend to "kept cache slots
+ this frame" as two blocks); only the fused first pass writes it.

Per-world independence. Every world has its own PRNG key stream, RoPE start frame and KV-cache fill
level: the DiT and the sampler run under ``jax.vmap`` over worlds (the DiT sees batch 1 per world), the
VAE decode and ``init`` run one world at a time (``lax.map``: the full-resolution convolutions are
~1.5x faster on CPU unbatched). So ``reset_worlds`` can restart some worlds (one compiled program for
any world index, no recompilation) while the others continue.

Noise keys (tests replicate them): world b starts from ``key_b = jax.random.split(rng, B)[b]`` (raw
uint32 keys); each latent frame does ``key_b, frame_key = split(key_b)`` and
``k_noise, k_renoise = split(frame_key)``; the initial noise is ``normal(k_noise, (P, 1, h, w, C))``
and ``k_renoise`` goes to ``sampler.sample_frame``. With warped noise (``SamplerConfig.noise_warp`` > 0) the
frame's draws are ``normal(frame_key, (P, S, h, w, C))`` instead (S = the initial noise and one re-noising per
sampler step), mixed with the previous frame's moved by the turn (``noise_warp``); the state carries them.

First-frame conditioning as a table. The conditioning of latent frame i is the VAE encoding of the
video [first_frame, gray, gray, ...] (``conditioning``). The VAE encoder is causal with a finite
temporal receptive field (``encoder_receptive_field``), so from latent frame ``steady_cond_index``
on it only sees gray frames and is the same tensor for every later frame. ``init`` therefore encodes
latent frames 0..steady (chunked, ``first_frame_cond_start/next`` in a scan) once, and ``step`` reads
entry ``min(i, steady)``: no VAE encoder work per step.

Input checks run on the host before any compute and raise ``ValueError`` naming the field and the
expected value (shapes, dtypes, player count, non-finite actions).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx, struct

from solaris_env.world_model import camera, checkpoint, kv_cache, noise_warp, partner, sampler
from solaris_env.world_model.components import COMPONENTS, abstract_modules
from solaris_env.world_model.conditioning import first_frame_cond_next, first_frame_cond_start
from solaris_env.world_model.config import SamplerConfig, VAEConfig, WorldModelConfig, preset
from solaris_env.world_model.dit import (ContextKV, WorldDiT, block_graphdef, from_stream, stack_blocks,
                                         timesteps_to_stream, to_stream, unstack_blocks)
from solaris_env.world_model.image_encoder import ImageEncoder
from solaris_env.world_model.vae import CausalVideoVAE

# ---------------------------------------------------------------------------------------------
# Helpers (pure)
# ---------------------------------------------------------------------------------------------


def encoder_receptive_field(vae: VAEConfig) -> int:
    """Video frames before the newest one that one VAE-encoder output can depend on.

    Mirrors the layer stack of ``vae.Encoder``: every causal time convolution has 3 taps (2 frames of
    history) at the current temporal stride; ResBlocks have two; a temporal downsample adds its own
    3-tap conv and doubles the stride. Sum of history * stride over the stack. A linear patch codec sees
    only the frames of its own latent.
    """
    if vae.codec == "linear_patch":
        return vae.temporal_factor - 1
    history, stride = 2, 1
    rf = history  # conv_in
    for i in range(len(vae.dim_mult)):
        rf += vae.num_res_blocks * 2 * history * stride
        if i < len(vae.temporal_downsample) and vae.temporal_downsample[i]:
            rf += history * stride
            stride *= 2
    rf += 2 * 2 * history * stride  # middle: two ResBlocks (the attention is per frame)
    rf += history * stride  # head
    return rf


def steady_cond_index(vae: VAEConfig) -> int:
    """First latent frame whose conditioning sees only gray frames (it equals every later one):
    latent i depends on video frames >= k*i - receptive_field, so the smallest i with k*i - rf >= 1."""
    if vae.cond_encoding == "image":  # latents >= 1 are zero (conditioning.py)
        return 1
    k = vae.temporal_factor
    return -(-(encoder_receptive_field(vae) + 1) // k)


def frames_to_model(frames_uint8: jax.Array) -> jax.Array:
    """uint8 [0, 255] -> f32 [-1, 1] (docs/model.md §7.3)."""
    return frames_uint8.astype(jnp.float32) / 127.5 - 1.0


def frames_to_uint8(video: jax.Array) -> jax.Array:
    """[-1, 1] -> uint8 by clip(((x + 1) / 2) * 255) and truncation (docs/model.md §7.3)."""
    return jnp.clip((video.astype(jnp.float32) + 1.0) * 127.5, 0.0, 255.0).astype(jnp.uint8)


def _raw_key(rng) -> jax.Array:
    """int seed, typed key or raw uint32[2] key -> raw uint32[2] key."""
    if isinstance(rng, (int, np.integer)):
        return jax.random.PRNGKey(int(rng))
    rng = jnp.asarray(rng) if not isinstance(rng, jax.Array) else rng
    if jnp.issubdtype(rng.dtype, jax.dtypes.prng_key):
        return jax.random.key_data(rng)
    if rng.shape != (2,) or rng.dtype != jnp.uint32:
        raise ValueError(f"rng must be an int seed or a single PRNG key; got shape {rng.shape} dtype {rng.dtype}")
    return rng


# ---------------------------------------------------------------------------------------------
# State
# ---------------------------------------------------------------------------------------------


@struct.dataclass
class WorldState:
    """Everything a batch of worlds carries between steps; every leaf has a leading world axis B.

    h, w = latent height/width, C = latent channels, Cc = conditioning channels (mask + latent),
    W = action window, A = 25, M/Ce = image-encoder tokens/width, Fc = ``cond_frames``.
    """

    key_B: jax.Array  # (B, 2) uint32: per-world PRNG key stream
    frame_index_B: jax.Array  # (B,) int32: index of the next latent frame = its RoPE start frame
    actions_BPWA: jax.Array  # (B, P, W, A) f32: the last W actions (the left-padded history)
    context_BPMC: jax.Array  # (B, P, M, Ce): image-encoder tokens of the first frames
    context_kv: ContextKV  # their cross-attention K/V, one (B, 1, P, N, M, K) array per DiT layer
    cond_BPFhwC: jax.Array  # (B, P, Fc, h, w, Cc): conditioning of latent frames 0..Fc-1 (last = steady)
    dit_cache: kv_cache.DiTCache  # rolling caches of the committed frames (all but the last), leaves (B, 1, ...)
    vae_cache: Any  # streaming VAE-decoder cache, leaves (B, P, ...)
    latent_BP1hwC: jax.Array  # (B, P, 1, h, w, C) f32: the last generated latent frame (the next step commits it)
    frame0_BPHW3: jax.Array  # (B, P, H, W, 3) uint8: latent frame 0 decoded (init / reset)
    # warped sampling noise only (``SamplerConfig.noise_warp`` > 0; None otherwise): the last latent frame's
    # noises (S = its initial noise and one re-noising draw per sampler step) and the turn's carried sub-pixel shift
    noise_BPShwC: jax.Array | None = None  # (B, P, S, h, w, C) f32
    noise_shift_BP2: jax.Array | None = None  # (B, P, 2) f32, (down, right) latent pixels in [-1/2, 1/2)
    # the partner map only (``DiTConfig.partner_map``; None otherwise): the players' dead-reckoned poses and
    # velocities after the last generated frame (``partner.track``) and that frame's map (``partner.partner_maps``)
    track_BP7: jax.Array | None = None  # (B, P, partner.TRACK_STATE) f32
    partner_BPhw: jax.Array | None = None  # (B, P, h, w) f32

    @property
    def num_worlds(self) -> int:
        return self.frame_index_B.shape[0]


# ---------------------------------------------------------------------------------------------
# Pure programs (functional NNX: graphdefs are static, parameters are arguments)
# ---------------------------------------------------------------------------------------------


class StepParams(NamedTuple):
    """The parameters as the streaming programs take them (``Programs.step_params``).

    The DiT's blocks are one state per layer (``dit.unstack_blocks``) rather than stacked on a layer
    axis: a layer loop over stacked weights copies each layer's slice in every pass (for the tiny preset
    ~a third of a denoising pass at B=1), a Python loop over per-layer buffers reads them in place.
    """

    dit: Any  # the DiT's state without its blocks
    dit_layers: tuple  # one DiTBlock state per layer
    vae: Any
    image_encoder: Any


class Programs:
    """Pure functions of ``(params, ...)`` for one config; ``params`` is a ``StepParams``
    (``step_params`` converts the (dit, vae, image_encoder) states that ``WorldModel.params`` returns).

    ``init``, ``step``, ``reset_one`` are what ``WorldModel`` jits; ``denoise`` and ``decode`` are the
    parts of ``step``, ``first_pass`` the fused commit + first pass of ``denoise`` (the benchmark times
    them separately).
    """

    def __init__(self, cfg: WorldModelConfig, graphdefs: tuple, *, unroll: bool = False):
        self.cfg = cfg
        self.graphdefs = graphdefs
        self.unroll = unroll  # straight-line sampler steps (for XLA's cost analysis only)
        self.timesteps = sampler.ar_schedule(cfg.sampler)
        self.noise_warp = float(cfg.sampler.noise_warp)  # 0: fresh noise for every frame (the reference)
        self.cond_frames = steady_cond_index(cfg.vae) + 1
        self.partner = cfg.dit.partner_map > 0
        # the DiT split into (blocks, rest); the programs merge it with shape-only blocks (never read)
        self._dit_graphdef, blocks, _ = nnx.split(abstract_modules(cfg)[0], nnx.PathContains("blocks"), ...)
        self._blocks_shapes = blocks
        self._block_graphdef = block_graphdef(cfg)

    # -- parameter layouts ------------------------------------------------------------------------------
    def step_params(self, params) -> StepParams:
        """(dit, vae, image_encoder) states (the checkpoint layout) -> ``StepParams`` (new buffers for the
        layers; the caller may drop the stacked ones)."""
        _, blocks, rest = nnx.split(nnx.merge(self.graphdefs[0], params[0]), nnx.PathContains("blocks"), ...)
        return StepParams(rest, unstack_blocks(self.cfg, blocks["blocks"]), params[1], params[2])

    def stacked_params(self, step: StepParams) -> tuple:
        """Inverse of ``step_params``: the (dit, vae, image_encoder) states."""
        blocks = nnx.State({"blocks": stack_blocks(step.dit_layers)})
        return nnx.state(nnx.merge(self._dit_graphdef, blocks, step.dit)), step.vae, step.image_encoder

    # -- per world: the state's fields lose their leading B axis (``ws.actions_BPWA`` is (P, W, A)
    #    here); the DiT sees batch 1, the VAE and the image encoder batch P ------------------------------
    def _modules(self, params: StepParams):
        """(dit, layers, vae, image_encoder): ``dit.blocks`` holds shapes only; ``layers`` are the blocks."""
        dit = nnx.merge(self._dit_graphdef, self._blocks_shapes, params.dit)
        layers = tuple(nnx.merge(self._block_graphdef, s) for s in params.dit_layers)
        return (dit, layers, nnx.merge(self.graphdefs[1], params.vae),
                nnx.merge(self.graphdefs[2], params.image_encoder))

    def _dit_args(self, z_PFhwC, t, ws_parts, start):
        """``WorldDiT.decode`` arguments for one world (DiT batch 1): F frames at positions
        ``start``.., ``t`` a scalar or (F,) timesteps. ``ws_parts`` = (cond (P, F, h, w, Cc), the context
        as its per-layer cross-attention K/V (``WorldDiT.context_kv``, computed at init), the action
        sequence (P, k * (F - 1) + action_window, A), the DiT cache)."""
        cfg = self.cfg
        cond, context_kv, actions, cache = ws_parts
        kb = cfg.action.keyboard_dim
        p, f = z_PFhwC.shape[:2]
        t_1PF = timesteps_to_stream(cfg, jnp.broadcast_to(jnp.asarray(t, jnp.float32), (1, p, f)))
        return (to_stream(cfg, z_PFhwC[None]), t_1PF, to_stream(cfg, cond[None]), context_kv,
                to_stream(cfg, actions[None, :, :, kb:]), to_stream(cfg, actions[None, :, :, :kb]), cache, start)

    def _velocity(self, dit, z_P1hwC, t, ws_parts, start):
        """v of one latent frame (a denoising pass: the cache is read, not updated): v_P1hwC.
        ``dit`` = (the DiT, its blocks one module per layer)."""
        v, _ = dit[0].decode(*self._dit_args(z_P1hwC, t, ws_parts, start), layers=dit[1])
        return from_stream(self.cfg, v)[0]

    def _window(self, ws: WorldState, actions_PkA):
        """The rolling action buffer with this step's k actions appended: (P, W, A)."""
        k = self.cfg.frames_per_step
        return jnp.concatenate([ws.actions_BPWA[:, k:], actions_PkA.astype(jnp.float32)], axis=1)

    def _cond_at(self, ws: WorldState, index):
        """Conditioning of latent frame ``index`` (traced): (P, 1, h, w, Cc)."""
        index = jnp.minimum(index, self.cond_frames - 1)
        return jax.lax.dynamic_slice_in_dim(ws.cond_BPFhwC, index, 1, axis=1)

    def _with_map(self, cond_P1hwC, map_Phw):
        """A frame's conditioning with its partner map (the model has one) or as it is."""
        if not self.partner:
            return cond_P1hwC
        return partner.with_partner(cond_P1hwC, map_Phw[:, None], self.cfg.mask_channels, self.cfg.dit.partner_map)

    def _tracked(self, ws: WorldState, actions_PkA):
        """(the new frame's partner map (P, h, w), the tracker state after its k ticks (P, 7)): the poses dead
        reckoned tick by tick from this step's actions, the map averaged over the k ticks as the latent sums its k
        frames (``partner.latent_frame_maps``). (None, None) without the partner map."""
        if not self.partner:
            return None, None
        kb = self.cfg.action.keyboard_dim
        actions = actions_PkA.astype(jnp.float32)
        poses_PK5, last = partner.track(ws.track_BP7, actions[..., kb:], actions[..., :kb])
        maps = partner.partner_maps(jnp.moveaxis(poses_PK5, 1, 0), self.cfg.latent_height, self.cfg.latent_width)
        return maps.mean(axis=0), last

    def _noise(self, frame_key, num_players: int):
        """(initial noise (P, 1, h, w, C), re-noising key) of one latent frame (fresh noise)."""
        cfg = self.cfg
        k_noise, k_renoise = jax.random.split(frame_key)
        shape = (num_players, 1, cfg.latent_height, cfg.latent_width, cfg.latent_channels)
        return jax.random.normal(k_noise, shape, jnp.float32), k_renoise

    def _fresh_noises(self, frame_key, num_players: int):
        """(P, S, h, w, C): all the noise draws of one latent frame at once (warped noise)."""
        cfg = self.cfg
        shape = (num_players, len(self.timesteps), cfg.latent_height, cfg.latent_width, cfg.latent_channels)
        return jax.random.normal(frame_key, shape, jnp.float32)

    def _warped_noises(self, ws: WorldState, actions_PkA, frame_key):
        """(noises (P, S, h, w, C), carried shift (P, 2)) of latent frame i with warped noise: frame i - 1's moved
        by this step's camera turn (``noise_warp.carry_noise``; the turn read as the camera warp reads it)."""
        cfg = self.cfg
        mouse = self._window(ws, actions_PkA)[:, :, cfg.action.keyboard_dim:]
        shift = camera.content_shift(camera.frame_turns(mouse, cfg.frames_per_step), cfg.dit.camera_warp)
        fresh = self._fresh_noises(frame_key, ws.latent_BP1hwC.shape[0])
        return noise_warp.carry_noise(ws.noise_BPShwC, ws.noise_shift_BP2, fresh, shift, self.noise_warp)

    @staticmethod
    def _split_noises(noises_PShwC):
        """(initial noise (P, 1, h, w, C), re-noising draws (S - 1, P, 1, h, w, C)) of stacked noises."""
        return noises_PShwC[:, :1], jnp.moveaxis(noises_PShwC[:, 1:], 1, 0)[:, :, None]

    def _step_noise(self, ws: WorldState, actions_PkA):
        """Frame i's noise, drawn once per step: (initial noise, re-noising, carried). Fresh noise: re-noising is a
        key and carried None; warped noise: the draws, and carried = (noises, shift) for the next state."""
        _, frame_key = jax.random.split(ws.key_B)
        if not self.noise_warp:
            return (*self._noise(frame_key, ws.latent_BP1hwC.shape[0]), None)
        carried = self._warped_noises(ws, actions_PkA, frame_key)
        return (*self._split_noises(carried[0]), carried)

    def _sample(self, dit, parts, z, renoise, start, first_v=None):
        """The sampler over ``self.timesteps``; ``renoise`` as ``_step_noise`` returns it."""
        denoise = lambda x, t: self._velocity(dit, x, t, parts, start)
        warped = bool(self.noise_warp)
        return sampler.sample_frame(denoise, z, None if warped else renoise, self.timesteps,
                                    self.cfg.sampler.num_train_timesteps, unroll=self.unroll, first_v=first_v,
                                    renoise=renoise if warped else None)

    def _first_pass(self, dit, ws: WorldState, actions_PkA, z, new_map=None):
        """The fused pass of a step: commit latent frame i - 1 (``ws.latent_BP1hwC`` at t = 0) and the
        first denoising pass of frame i from its initial noise ``z``, as one pass of two frames
        (``WorldDiT.decode``, ``commit=1``).

        ``new_map``: frame i's partner map (``_tracked``; the partner map only).

        Returns (v of that pass, the cache with frame i - 1)."""
        i = ws.frame_index_B
        x = jnp.concatenate([ws.latent_BP1hwC, z], axis=1)  # (P, 2, h, w, C): [committed i - 1 (x0) ; noisy i]
        cond = jnp.concatenate([self._with_map(self._cond_at(ws, i - 1), ws.partner_BPhw),
                                self._with_map(self._cond_at(ws, i), new_map)], axis=1)
        actions = jnp.concatenate([ws.actions_BPWA, actions_PkA.astype(jnp.float32)], axis=1)  # windows i-1, i
        t = jnp.asarray([0.0, self.timesteps[0]], jnp.float32)
        v, cache = dit[0].decode(*self._dit_args(x, t, (cond, ws.context_kv, actions, ws.dit_cache), i - 1),
                                 commit=1, layers=dit[1], still_memory=self.cfg.sampler.still_memory)
        return from_stream(self.cfg, v[:, :, 1:])[0], cache

    def _denoise_world(self, params, ws: WorldState, actions_PkA, noise, tracked):
        """Latent frame i of one world and the DiT cache with frame i - 1 committed; ``noise`` from
        ``_step_noise``, ``tracked`` from ``_tracked``."""
        dit = self._modules(params)[:2]
        z, k_renoise, _ = noise
        v, cache = self._first_pass(dit, ws, actions_PkA, z, tracked[0])
        cond = self._with_map(self._cond_at(ws, ws.frame_index_B), tracked[0])
        parts = (cond, ws.context_kv, self._window(ws, actions_PkA), cache)
        return self._sample(dit, parts, z, k_renoise, ws.frame_index_B, first_v=v), cache

    def _first_pass_world(self, params, ws: WorldState, actions_PkA):
        return self._first_pass(self._modules(params)[:2], ws, actions_PkA, self._step_noise(ws, actions_PkA)[0],
                                self._tracked(ws, actions_PkA)[0])

    def _decode_world(self, params, ws: WorldState, x0_P1hwC):
        """(frames (P, k, H, W, 3) uint8, the VAE cache)."""
        vae = self._modules(params)[2]
        video, vae_cache = vae.decode_step(x0_P1hwC, ws.vae_cache)  # (P, k, H, W, 3) in [-1, 1]
        return frames_to_uint8(video), vae_cache

    def _advance(self, ws: WorldState, actions_PkA, x0_P1hwC, dit_cache, vae_cache, carried, tracked) -> WorldState:
        """The bookkeeping after a step: next key, frame index, action buffer, caches, latent, with warped noise
        the draws the step sampled with (``carried``, from ``_step_noise``) and with the partner map the new
        frame's map and tracker state (``tracked``, from ``_tracked``)."""
        next_key, _ = jax.random.split(ws.key_B)
        if carried is not None:
            ws = ws.replace(noise_BPShwC=carried[0], noise_shift_BP2=carried[1])
        if self.partner:
            ws = ws.replace(partner_BPhw=tracked[0], track_BP7=tracked[1])
        return ws.replace(key_B=next_key, frame_index_B=ws.frame_index_B + 1,
                          actions_BPWA=self._window(ws, actions_PkA), dit_cache=dit_cache, vae_cache=vae_cache,
                          latent_BP1hwC=x0_P1hwC)

    def _cond_table(self, vae, first_PHW3):
        """(P, cond_frames, h, w, Cc): conditioning of latent frames 0..steady, encoded chunk by chunk."""
        cond0, enc_state = first_frame_cond_start(vae, first_PHW3)

        def next_cond(state, _):
            cond, state = first_frame_cond_next(vae, state)
            return state, cond[:, 0]

        _, rest = jax.lax.scan(next_cond, enc_state, None, length=self.cond_frames - 1)  # (Fc-1, P, h, w, Cc)
        return jnp.concatenate([cond0, jnp.moveaxis(rest, 0, 1)], axis=1)

    def _init_world(self, params, first_PHW3_uint8, first_actions_PA, key, poses_P5=None):
        """One world: encode the first frames, then generate and decode latent frame 0 (step 1 commits it).
        ``poses_P5``: the players' poses at the first frame (the partner map only)."""
        cfg = self.cfg
        dit, layers, vae, encoder = self._modules(params)
        first = frames_to_model(first_PHW3_uint8)
        context = encoder(first)  # (P, M, Ce)
        context_kv = dit.context_kv(to_stream(cfg, context[None]), layers)  # per layer (1, P, N, M, K)
        dit = (dit, layers)
        cond = self._cond_table(vae, first)
        actions = jnp.repeat(first_actions_PA.astype(jnp.float32)[:, None], cfg.action_window, axis=1)
        cache = kv_cache.init_cache(cfg, 1)  # batch 1: the DiT sees one world at a time
        start = jnp.zeros((), jnp.int32)
        track = map0 = None
        if self.partner:
            track = partner.track_state(poses_P5)
            map0 = partner.partner_maps(poses_P5, cfg.latent_height, cfg.latent_width)
        parts = (self._with_map(cond[:, :1], map0), context_kv, actions, cache)
        key, frame_key = jax.random.split(key)
        p = first.shape[0]
        noises = shift = None
        if self.noise_warp:  # warped noise starts from fresh draws
            noises, shift = self._fresh_noises(frame_key, p), jnp.zeros((p, 2), jnp.float32)
            noise = self._split_noises(noises)
        else:
            noise = self._noise(frame_key, p)
        x0 = self._sample(dit, parts, *noise, start)  # committed by step 1
        video, vae_cache = vae.decode_step(x0, None)  # latent frame 0 -> 1 video frame
        return WorldState(key_B=key, frame_index_B=start + 1, actions_BPWA=actions, context_BPMC=context,
                          context_kv=context_kv,
                          cond_BPFhwC=cond, dit_cache=cache, vae_cache=vae_cache, latent_BP1hwC=x0,
                          frame0_BPHW3=frames_to_uint8(video[:, 0]), noise_BPShwC=noises, noise_shift_BP2=shift,
                          track_BP7=track, partner_BPhw=map0)

    # -- batched over worlds (what gets jitted) -------------------------------------------------------
    def init(self, params, first_frames_BPHW3, first_actions_BPA, rng, poses_BP5=None):
        # one world at a time: dominated by the VAE encoder (cond table), which is faster unbatched on CPU
        keys = jax.random.split(rng, first_frames_BPHW3.shape[0])
        return jax.lax.map(lambda args: self._init_world(params, *args),
                           (first_frames_BPHW3, first_actions_BPA, keys) + (() if poses_BP5 is None else (poses_BP5,)))

    def step(self, params, state: WorldState, actions_BPkA):
        noise = jax.vmap(self._step_noise)(state, actions_BPkA)  # drawn once: the sampler and the next state
        tracked = jax.vmap(self._tracked)(state, actions_BPkA)  # tracked once: the passes and the next state
        x0, dit_cache = self._denoise(params, state, actions_BPkA, noise, tracked)
        frames, vae_cache = self.decode(params, state, x0)
        return frames, jax.vmap(self._advance)(state, actions_BPkA, x0, dit_cache, vae_cache, noise[2], tracked)

    def _denoise(self, params, state: WorldState, actions_BPkA, noise, tracked):
        return jax.vmap(self._denoise_world, in_axes=(None, 0, 0, 0, 0))(params, state, actions_BPkA, noise, tracked)

    def denoise(self, params, state: WorldState, actions_BPkA):
        """Every DiT pass of a step: (x0 (B, P, 1, h, w, C), the caches with the previous frame committed)."""
        return self._denoise(params, state, actions_BPkA, jax.vmap(self._step_noise)(state, actions_BPkA),
                             jax.vmap(self._tracked)(state, actions_BPkA))

    def first_pass(self, params, state: WorldState, actions_BPkA):
        """The fused commit + first denoising pass alone (part of ``denoise``; timed by the benchmark)."""
        return jax.vmap(self._first_pass_world, in_axes=(None, 0, 0))(params, state, actions_BPkA)

    def decode(self, params, state: WorldState, x0_BP1hwC):
        """(frames (B, P, k, H, W, 3) uint8, VAE cache) of the generated latents."""
        # one world at a time: the VAE's full-resolution convolutions run ~1.5x faster on CPU with the
        # activations of P*k frames than with B*P*k (cache locality); the DiT is better batched.
        return jax.lax.map(lambda args: self._decode_world(params, *args), (state, x0_BP1hwC))

    def reset_one(self, params, state: WorldState, index, first_PHW3, first_actions_PA, key, poses_P5=None):
        """Replace world ``index`` (traced int) by a fresh world; the others are untouched."""
        fresh = self._init_world(params, first_PHW3, first_actions_PA, key, poses_P5)
        return jax.tree.map(lambda old, new: old.at[index].set(new), state, fresh)


# ---------------------------------------------------------------------------------------------
# The streaming API
# ---------------------------------------------------------------------------------------------


class WorldModel:
    """Batched streaming world model (see the module docstring for the contract).

    Args:
        config: the world-model config.
        dit, vae, image_encoder: the three networks (concrete modules; they are split once here).
    """

    def __init__(self, config: WorldModelConfig, dit: WorldDiT, vae: CausalVideoVAE, image_encoder: ImageEncoder):
        graphdefs, params = zip(*(nnx.split(m) for m in (dit, vae, image_encoder)))
        programs = Programs(config, tuple(graphdefs))
        self._setup(config, programs, on_host(programs.step_params, tuple(params)))  # the only copy kept

    def _setup(self, config: WorldModelConfig, programs: Programs, step_params: StepParams) -> None:
        self._cfg = config
        self.programs = programs
        self._step_params = step_params
        # jit once; the state is donated (callers must use the returned state, not the old one)
        # The jitted calls take the parameters as a flat list of arrays: flattening the NNX state tree (some
        # 550 Variables for tiny) in Python on every call cost ~4 ms per step; a list flattens in C++.
        self._param_leaves, treedef = jax.tree.flatten(self._step_params)
        on_leaves = lambda program: lambda leaves, *args: program(jax.tree.unflatten(treedef, leaves), *args)
        self._init_fn = jax.jit(on_leaves(self.programs.init))
        self._step_fn = jax.jit(on_leaves(self.programs.step), donate_argnums=(1,))
        self._reset_fn = jax.jit(on_leaves(self.programs.reset_one), donate_argnums=(1,))

    # -- construction -----------------------------------------------------------------------------
    @classmethod
    def from_preset(cls, name: str, seed: int = 0, **override) -> "WorldModel":
        """Random initialisation of a preset (``config.preset``); ``override`` replaces config fields."""
        return cls.from_config(preset(name, **override), seed)

    @classmethod
    def from_config(cls, config: WorldModelConfig, seed: int = 0) -> "WorldModel":
        """Random initialisation (the modules' own initialisers, compiled with an RBG key for speed)."""
        graphdefs, initialise = _initializer(config)
        with _host_default():
            states = initialise(jax.random.key(seed, impl="unsafe_rbg"))
        return cls(config, *(nnx.merge(g, s) for g, s in zip(graphdefs, states)))

    @classmethod
    def load(cls, path, config: WorldModelConfig | None = None) -> "WorldModel":
        """Load our checkpoint (``save``) or an official orbax directory (``solaris.pt``, ``vae.pt``,
        ``clip.pt``; ``config`` defaults to the solaris preset). See ``checkpoint``."""
        with _host_default():
            config, modules = checkpoint.load_modules(path, config)
        return cls(config, *modules)

    def with_sampler(self, sampler: SamplerConfig) -> "WorldModel":
        """The same weights (shared, not copied) under another sampler config: timesteps, warped noise."""
        new = object.__new__(type(self))
        config = dataclasses.replace(self._cfg, sampler=sampler)
        new._setup(config, Programs(config, self.programs.graphdefs), self._step_params)
        return new

    def save(self, path) -> None:
        """Write our checkpoint format (safetensors + JSON config, atomically)."""
        checkpoint.save(path, self._cfg, dict(zip(COMPONENTS, self.params)))

    # -- properties -----------------------------------------------------------------------------------
    @property
    def config(self) -> WorldModelConfig:
        return self._cfg

    @property
    def params(self) -> tuple:
        """(dit, vae, image_encoder) parameter states, the DiT's blocks stacked on a layer axis (the
        checkpoint and training layout; built from ``step_params`` on each call)."""
        return on_host(self.programs.stacked_params, self._step_params)

    @property
    def step_params(self) -> StepParams:
        """The parameters as ``programs`` take them."""
        return self._step_params

    def modules(self) -> tuple:
        """Fresh (dit, vae, image_encoder) modules with this model's parameters."""
        graphdefs = self.programs.graphdefs
        return tuple(nnx.merge(g, p) for g, p in zip(graphdefs, self.params))

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        return (self._cfg.frame_height, self._cfg.frame_width, 3)

    @property
    def num_players(self) -> int:
        return self._cfg.num_players

    @property
    def frames_per_step(self) -> int:
        """k: video frames per ``step`` (the VAE's temporal factor)."""
        return self._cfg.frames_per_step

    @property
    def action_dim(self) -> int:
        return self._cfg.action.action_dim

    @property
    def cond_frames(self) -> int:
        return self.programs.cond_frames

    # -- streaming ------------------------------------------------------------------------------------
    def init(self, first_frames, rng, first_actions=None, poses=None) -> WorldState:
        """Start B worlds from their first frames.

        Args:
            first_frames: (B, P, H, W, 3) uint8.
            rng: int seed or PRNG key; world b uses ``jax.random.split(rng, B)[b]``.
            first_actions: optional (B, P, 25) action of frame 0 (left-padding value); default zeros.
            poses: (B, P, 5) the players' [x, y, z, yaw, pitch] at the first frames (feet in blocks, Mineflayer
                radians; ``real_env.EngineState.poses``): required by a model with ``dit.partner_map``, which
                dead reckons them from the actions (docs/model.md §8.6); not read by any other model.
        Returns:
            the state; ``state.frame0_BPHW3`` is latent frame 0 decoded (one frame per player).
        """
        first_frames = self._check_frames(first_frames, "first_frames")
        b = first_frames.shape[0]
        first_actions = self._check_first_actions(first_actions, b)
        extra = (self._check_poses(poses, b),) if self.programs.partner else ()
        return self._init_fn(self._param_leaves, first_frames, first_actions, _raw_key(rng), *extra)

    def step(self, state: WorldState, actions) -> tuple[jax.Array, WorldState]:
        """Generate one latent frame per world: ``actions`` (B, P, k, 25) -> (frames (B, P, k, H, W, 3)
        uint8, new state). ``state`` is donated: use only the returned one."""
        self._check_state(state)
        actions = self._check_actions(actions, state.num_worlds, (self.frames_per_step,), "actions",
                                      "(B, P, k, 25)")
        return self._step_fn(self._param_leaves, state, actions)

    def reset_worlds(self, state: WorldState, mask_B, first_frames, rng=None, first_actions=None,
                     poses=None) -> WorldState:
        """Restart the worlds where ``mask_B`` is True from ``first_frames[b]`` (other rows ignored).

        Each reset world is re-initialised exactly like ``init`` (one compiled program for any world
        index, so nothing recompiles); the other worlds' entries are untouched. ``rng=None`` continues
        each reset world's own key stream; with ``rng``, world b gets ``split(rng, B)[b]`` as in ``init``.
        ``state`` is donated. ``poses`` (B, P, 5) as ``init`` (rows of the reset worlds read).
        """
        self._check_state(state)
        b = state.num_worlds
        mask = np.asarray(mask_B)
        if mask.shape != (b,) or mask.dtype != np.bool_:
            raise ValueError(f"mask_B has shape {mask.shape} dtype {mask.dtype}; expected ({b},) bool")
        first_frames = self._check_frames(first_frames, "first_frames", batch=b)
        first_actions = self._check_first_actions(first_actions, b)
        poses = self._check_poses(poses, b) if self.programs.partner else None
        # host copy: the state's buffers are donated by the first reset below
        keys = np.asarray(state.key_B if rng is None else jax.random.split(_raw_key(rng), b))
        for index in np.flatnonzero(mask):
            extra = () if poses is None else (poses[index],)
            state = self._reset_fn(self._param_leaves, state, jnp.int32(index), first_frames[index],
                                   first_actions[index], keys[index], *extra)
        return state

    # -- input checks (host side, before any compute) -----------------------------------------------
    def _check_frames(self, frames, name: str, batch: int | None = None) -> jax.Array:
        dtype = getattr(frames, "dtype", None)
        if dtype is None or np.dtype(dtype) != np.uint8:
            raise ValueError(f"{name} must be uint8 in [0, 255]; got dtype {dtype}")
        shape = tuple(frames.shape)
        p, (h, w, c) = self.num_players, self.frame_shape
        if len(shape) != 5 or shape[2:] != (h, w, c) or shape[0] < 1:
            raise ValueError(f"{name} has shape {shape}; expected (B, P={p}, H={h}, W={w}, 3)")
        if shape[1] != p:
            raise ValueError(f"{name} has {shape[1]} players; this model has num_players={p}")
        if batch is not None and shape[0] != batch:
            raise ValueError(f"{name} has {shape[0]} worlds; the state has B={batch}")
        return jnp.asarray(frames)

    def _check_actions(self, actions, batch: int, middle: tuple, name: str, layout: str) -> jax.Array:
        dtype = getattr(actions, "dtype", None)
        real = dtype is not None and any(jnp.issubdtype(dtype, kind) for kind in (jnp.floating, jnp.integer,
                                                                                  jnp.bool_))
        if not real:
            raise ValueError(f"{name} must be a real-valued array (float, int or bool); got dtype {dtype}")
        expected = (batch, self.num_players, *middle, self.action_dim)
        shape = tuple(actions.shape)
        if len(shape) == len(expected) and shape[1] != self.num_players:
            raise ValueError(f"{name} has {shape[1]} players; this model has num_players={self.num_players}")
        if shape != expected:
            raise ValueError(f"{name} has shape {shape}; expected {layout} = {expected}")
        host_actions = np.asarray(actions, np.float32)
        if not np.isfinite(host_actions).all():
            raise ValueError(f"{name} contains NaN or inf values; every entry must be finite")
        return jnp.asarray(host_actions)

    def _check_first_actions(self, first_actions, batch: int) -> jax.Array:
        if first_actions is None:
            return jnp.zeros((batch, self.num_players, self.action_dim), jnp.float32)
        return self._check_actions(first_actions, batch, (), "first_actions", "(B, P, 25)")

    def _check_poses(self, poses, batch: int) -> jax.Array:
        if poses is None:
            raise ValueError("this model reads the partner map (dit.partner_map): init / reset_worlds need poses "
                             f"(B, P={self.num_players}, 5) [x, y, z, yaw, pitch] of the first frames "
                             "(real_env.EngineState.poses)")
        host = np.asarray(poses, np.float32)
        if host.shape != (batch, self.num_players, partner.POSE):
            raise ValueError(f"poses has shape {host.shape}; expected (B, P, 5) = {(batch, self.num_players, 5)}")
        if not np.isfinite(host).all():
            raise ValueError("poses contains NaN or inf values; every entry must be finite")
        return jnp.asarray(host)

    def _check_state(self, state) -> None:
        if not isinstance(state, WorldState):
            raise ValueError(f"state must be the WorldState returned by init/step; got {type(state).__name__}")
        p = state.actions_BPWA.shape[1]
        if p != self.num_players:
            raise ValueError(f"state has {p} players; this model has num_players={self.num_players}")
        if (state.noise_BPShwC is None) == bool(self.programs.noise_warp):
            raise ValueError(f"state.noise_BPShwC is {'missing' if state.noise_BPShwC is None else 'set'}, but this "
                             f"model samples with sampler.noise_warp={self._cfg.sampler.noise_warp}: pass a state "
                             f"from init/step of a model with the same sampler setting")


@functools.lru_cache(maxsize=8)
def _initializer(config: WorldModelConfig):
    """(graphdefs, jitted key -> parameter states) for a config; cached so re-seeding does not recompile."""
    graphdefs = tuple(nnx.split(m)[0] for m in abstract_modules(config))

    def make(key):
        k_dit, k_vae, k_enc = jax.random.split(key, 3)
        return (nnx.state(WorldDiT(config, rngs=nnx.Rngs(k_dit))),
                nnx.state(CausalVideoVAE(config.vae, rngs=nnx.Rngs(k_vae))),
                nnx.state(ImageEncoder(config.image_encoder, rngs=nnx.Rngs(k_enc))))

    return graphdefs, jax.jit(make)


def _host_default():
    """Where the default backend is an accelerator: a context in which new arrays and computations go to the
    host CPU (``jax.default_device``); elsewhere nothing changes."""
    if jax.default_backend() == "cpu":
        return contextlib.nullcontext()
    return jax.default_device(jax.local_devices(backend="cpu")[0])


def on_host(fn, tree):
    """``fn(tree)`` computed on the host CPU, its result on the default device, uncommitted.

    For the parameter layouts (random initialisation, the DiT blocks' unstacking and stacking): on an
    accelerator each of their small programs compiles alone, in seconds each on a GPU (a lent H200 spent
    ~50 s building tiny16 before its first VAE step) and in milliseconds on the CPU. On a CPU backend this
    is ``fn(tree)``."""
    if jax.default_backend() == "cpu":
        return fn(tree)
    host = jax.local_devices(backend="cpu")[0]
    with jax.default_device(host):
        out = fn(jax.device_put(tree, host))
    return jax.tree.map(_to_default_device, out)


def _to_default_device(a):
    """A host array as a new, uncommitted array on the default device (one transfer; keys keep their type)."""
    if not isinstance(a, jax.Array):
        return a
    if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
        return jax.random.wrap_key_data(_to_default_device(jax.random.key_data(a)), impl=jax.random.key_impl(a))
    return jnp.asarray(np.asarray(a))


def param_count(model: WorldModel) -> dict[str, int]:
    return {name: sum(math.prod(v.shape) for v in jax.tree.leaves(p)) for name, p in zip(COMPONENTS, model.params)}


__all__ = ["WorldModel", "WorldState", "Programs", "StepParams", "encoder_receptive_field", "steady_cond_index",
           "frames_to_model", "frames_to_uint8", "param_count"]
