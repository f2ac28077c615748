"""Wan2.1-style causal video VAE (docs/model.md §7.1), or in its place a linear patch codec
(``VAEConfig.codec = "linear_patch"``: one matrix each way between a latent position's pixel patch and its
latent numbers, no convolutions, no temporal cache; docs/model.md §7.1, "Linear patch codec").

Video ``x_BTHWC`` in [-1, 1] with T = 1 + tf * (F - 1) frames <-> latents ``z_BFhwc`` with
h = H / sf, w = W / sf (tf = ``cfg.temporal_factor``, sf = ``cfg.spatial_factor``; 4 and 8 for solaris).
Every layer mixes frames only through causal time convolutions, so latent frame i depends on video
frames <= tf * i and decoded frame t on latents <= ceil(t / tf).

Streaming. Every layer maps ``(x_BTHWC, cache) -> (y, new_cache)``. The cache is plain data (a pytree of
arrays, returned and passed back); ``cache=None`` means "start of a stream". What a layer keeps:

- ``CausalConv3d`` with a k-frame kernel: the last k - 1 frames of its input (zeros before the start,
  which is exactly causal zero padding).
- time downsampling (encoder, 3-tap stride-2 conv): frame 0 of a stream passes through un-convolved,
  then windows [0, 1, 2], [2, 3, 4], ... are convolved; the cache is the last input frame.
- time upsampling (decoder, 3-tap conv C -> 2C, then depth-to-time x2): frame 0 of a stream passes
  through (1 -> 1 frame); frames 1.. form a causal sequence that starts from zero history, so they never
  see frame 0 through this conv (the Wan "Rep" cache); the cache is the last 2 input frames.

Hence one call over a whole video (``encode``/``decode``, the "cacheless" form used for training) equals
any split into chunks of [1 + tf * k, tf * k', tf * k'', ...] frames for the encoder and [F0, F1, ...]
latents for the decoder, up to float summation order.

Parameter tree (solaris preset): 126,892,533 parameters, the official count. Names follow the Wan layers
(encoder/decoder ``conv_in``, ``down``/``up``, ``middle``, ``head``; ``conv1`` / ``conv2`` are the 1x1x1
moment / latent convs) but the reference checkpoint's paths and a few shapes (e.g. RMSNorm gamma
(C, 1, 1, 1), list-indexed ``residual`` layers) differ, so ``vae.pt`` would need a key-mapping converter.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from solaris_env.world_model.config import VAEConfig

Cache = Any  # a pytree of arrays; None = the start of a stream
_NORM_EPS = 1e-12  # RMS_norm divides by max(||x||, eps), like torch's F.normalize
_LOGVAR_RANGE = (-30.0, 20.0)
LOGVAR_INIT = -8.0  # the encoder's initial log-variance (std 0.018): CausalVideoVAE.__init__


# ---------------------------------------------------------------------------------------------
# Latent normalisation and the posterior (the only place these formulas live)
# ---------------------------------------------------------------------------------------------


def normalize_latents(mu_BFhwc: jax.Array, cfg: VAEConfig) -> jax.Array:
    """z = (mu - mean) / std per channel; the identity when the config has no statistics."""
    if not cfg.latent_mean:
        return mu_BFhwc
    mean, std = jnp.asarray(cfg.latent_mean, mu_BFhwc.dtype), jnp.asarray(cfg.latent_std, mu_BFhwc.dtype)
    return (mu_BFhwc - mean) / std


def denormalize_latents(z_BFhwc: jax.Array, cfg: VAEConfig) -> jax.Array:
    """mu = z * std + mean per channel (inverse of ``normalize_latents``)."""
    if not cfg.latent_mean:
        return z_BFhwc
    mean, std = jnp.asarray(cfg.latent_mean, z_BFhwc.dtype), jnp.asarray(cfg.latent_std, z_BFhwc.dtype)
    return z_BFhwc * std + mean


def sample_posterior(mu_BFhwc: jax.Array, logvar_BFhwc: jax.Array, *, key: jax.Array) -> jax.Array:
    """Reparameterised sample mu + exp(logvar / 2) * eps of the diagonal Gaussian posterior (raw latents).

    logvar is clipped to [-30, 20] first (as in LDM/Wan-style VAEs) so exp() stays finite.
    """
    logvar = jnp.clip(logvar_BFhwc, *_LOGVAR_RANGE)
    return mu_BFhwc + jnp.exp(0.5 * logvar) * jax.random.normal(key, mu_BFhwc.shape, mu_BFhwc.dtype)


def kl_divergence(mu_BFhwc: jax.Array, logvar_BFhwc: jax.Array) -> jax.Array:
    """Per-sample KL(q || N(0, I)) summed over latent elements, shape (B,)."""
    logvar = jnp.clip(logvar_BFhwc, *_LOGVAR_RANGE)
    kl = 0.5 * (jnp.square(mu_BFhwc) + jnp.exp(logvar) - 1.0 - logvar)
    return kl.reshape(kl.shape[0], -1).sum(-1)


# ---------------------------------------------------------------------------------------------
# The linear patch codec's layout (VAEConfig.codec = "linear_patch", docs/model.md §7.1, "Linear patch codec")
# ---------------------------------------------------------------------------------------------


def patchify(video_BTHWC: jax.Array, tf: int, sf: int, first: bool) -> jax.Array:
    """Video -> one (tf, sf, sf, 3) pixel patch per latent position, flattened: (B, F, H/sf, W/sf, tf*sf*sf*3),
    entry order (t, dy, dx, rgb). ``first``: the video starts a stream (T = 1 + tf * (F - 1)); its frame 0 is
    repeated tf times, so the first latent's patch is that of a chunk in which nothing moves. Otherwise
    T = tf * F."""
    B, T, H, W, C = video_BTHWC.shape
    if first:
        video_BTHWC = jnp.concatenate([jnp.repeat(video_BTHWC[:, :1], tf, axis=1), video_BTHWC[:, 1:]], axis=1)
    F = video_BTHWC.shape[1] // tf
    assert F * tf == video_BTHWC.shape[1] and H % sf == 0 and W % sf == 0, \
        f"patchify: video (T, H, W)={T, H, W} does not split into {tf}x{sf}x{sf} patches (first={first})"
    x = video_BTHWC.reshape(B, F, tf, H // sf, sf, W // sf, sf, C).transpose(0, 1, 3, 5, 2, 4, 6, 7)
    return x.reshape(B, F, H // sf, W // sf, tf * sf * sf * C)


def latent_neighbourhood(z_BFhwC: jax.Array, k: int) -> jax.Array:
    """Each latent position's (k x k) neighbourhood, the grid's edge repeated past its border, flattened:
    (B, F, h, w, k*k*C), entry order (dy, dx, channel) row-major over the window, so the centre position's C
    channels are entries [(k*k // 2) * C, (k*k // 2 + 1) * C). k = 1 returns ``z_BFhwC`` itself."""
    if k == 1:
        return z_BFhwC
    r = k // 2
    h, w = z_BFhwC.shape[2:4]
    padded = jnp.pad(z_BFhwC, ((0, 0), (0, 0), (r, r), (r, r), (0, 0)), mode="edge")
    return jnp.concatenate([padded[:, :, dy:dy + h, dx:dx + w] for dy in range(k) for dx in range(k)], axis=-1)


def unpatchify(patches_BFhwD: jax.Array, tf: int, sf: int, first: bool) -> jax.Array:
    """The inverse of ``patchify``: (B, F, h, w, tf*sf*sf*3) -> video (B, T, h*sf, w*sf, 3). ``first``: the
    first latent gives one frame, the mean of its patch's tf frames (T = 1 + tf * (F - 1))."""
    B, F, h, w, D = patches_BFhwD.shape
    x = patches_BFhwD.reshape(B, F, h, w, tf, sf, sf, D // (tf * sf * sf)).transpose(0, 1, 4, 2, 5, 3, 6, 7)
    video = x.reshape(B, F * tf, h * sf, w * sf, -1)
    if first:
        video = jnp.concatenate([jnp.mean(video[:, :tf], axis=1, keepdims=True), video[:, tf:]], axis=1)
    return video


# ---------------------------------------------------------------------------------------------
# Primitives: convolutions with a time axis, RMS norm
# ---------------------------------------------------------------------------------------------


def _conv2d(x_NHWC: jax.Array, kernel_HWIO: jax.Array, stride: int, pad_hw: tuple) -> jax.Array:
    return jax.lax.conv_general_dilated(x_NHWC, kernel_HWIO, (stride, stride), pad_hw,
                                        dimension_numbers=("NHWC", "HWIO", "NHWC"))


def _time_conv_valid(x_BTHWC: jax.Array, kernel_KHWIO: jax.Array, bias_O: jax.Array, stride_t: int) -> jax.Array:
    """A 3D convolution, VALID in time (the caller pads), 'same' zero padding in space, spatial stride 1.

    The k time taps are folded into channels and run as one 2D convolution: on XLA:CPU that runs ~5x
    faster than a 3D convolution and compiles faster than a sum of k 2D convolutions.
    """
    B, T, H, W, C = x_BTHWC.shape
    k, kh, kw, c_in, c_out = kernel_KHWIO.shape
    t_out = (T - k) // stride_t + 1
    assert t_out >= 1 and C == c_in, f"time conv with {k} taps on {C} channels got (T, C) = {(T, C)}"
    taps = [x_BTHWC[:, i:i + stride_t * (t_out - 1) + 1:stride_t] for i in range(k)]  # k x (B, t_out, H, W, C)
    x = jnp.concatenate(taps, axis=-1).reshape(B * t_out, H, W, k * C)  # channel = tap * C + c
    kernel = kernel_KHWIO.transpose(1, 2, 0, 3, 4).reshape(kh, kw, k * c_in, c_out)
    y = _conv2d(x, kernel, 1, ((kh // 2, kh // 2), (kw // 2, kw // 2)))
    return y.reshape(B, t_out, H, W, c_out) + bias_O


class CausalConv3d(nnx.Module):
    """3D conv, causal in time: frame t sees input frames t-k+1..t; symmetric zero padding in space.

    Cache: the last k-1 input frames (B, k-1, H, W, C_in); None = zeros (start of the stream).
    """

    def __init__(self, in_dim: int, out_dim: int, kernel: tuple[int, int, int], *, dtype, param_dtype,
                 rngs: nnx.Rngs, kernel_init=nnx.initializers.lecun_normal()):
        self.kernel = nnx.Param(kernel_init(rngs.params(), (*kernel, in_dim, out_dim), param_dtype))
        self.bias = nnx.Param(jnp.zeros((out_dim,), param_dtype))
        self.dtype = dtype

    @property
    def history(self) -> int:
        return self.kernel.shape[0] - 1

    def conv_valid(self, x_BTHWC: jax.Array, stride_t: int = 1) -> jax.Array:
        x = x_BTHWC.astype(self.dtype)
        return _time_conv_valid(x, self.kernel[...].astype(self.dtype), self.bias[...].astype(self.dtype), stride_t)

    def __call__(self, x_BTHWC: jax.Array, cache: Cache) -> tuple[jax.Array, Cache]:
        if self.history == 0:
            return self.conv_valid(x_BTHWC), None
        if cache is None:
            B, _, H, W, C = x_BTHWC.shape
            cache = jnp.zeros((B, self.history, H, W, C), x_BTHWC.dtype)
        x = jnp.concatenate([cache.astype(x_BTHWC.dtype), x_BTHWC], axis=1)
        return self.conv_valid(x), x[:, -self.history:]


class RMSNorm(nnx.Module):
    """Wan RMS_norm: L2-normalise over channels, times sqrt(C) and a learned gamma (no bias)."""

    def __init__(self, dim: int, *, param_dtype):
        self.gamma = nnx.Param(jnp.ones((dim,), param_dtype))

    def __call__(self, x_BTHWC: jax.Array) -> jax.Array:
        x = x_BTHWC.astype(jnp.float32)
        norm = jnp.sqrt(jnp.sum(jnp.square(x), axis=-1, keepdims=True))
        y = x / jnp.maximum(norm, _NORM_EPS) * np.sqrt(x.shape[-1]) * self.gamma[...].astype(jnp.float32)
        return y.astype(x_BTHWC.dtype)


# ---------------------------------------------------------------------------------------------
# Blocks; each maps (x_BTHWC, cache) -> (y_BTHWC, new_cache)
# ---------------------------------------------------------------------------------------------


class ResBlock(nnx.Module):
    """norm -> SiLU -> conv3^3 -> norm -> SiLU -> conv3^3, plus a 1x1x1 shortcut when C changes."""

    def __init__(self, in_dim: int, out_dim: int, *, dtype, param_dtype, rngs: nnx.Rngs):
        kw = dict(dtype=dtype, param_dtype=param_dtype, rngs=rngs)
        self.norm1 = RMSNorm(in_dim, param_dtype=param_dtype)
        self.conv1 = CausalConv3d(in_dim, out_dim, (3, 3, 3), **kw)
        self.norm2 = RMSNorm(out_dim, param_dtype=param_dtype)
        self.conv2 = CausalConv3d(out_dim, out_dim, (3, 3, 3), **kw)
        self.shortcut = CausalConv3d(in_dim, out_dim, (1, 1, 1), **kw) if in_dim != out_dim else None

    def __call__(self, x_BTHWC: jax.Array, cache: Cache) -> tuple[jax.Array, Cache]:
        c1, c2 = cache if cache is not None else (None, None)
        h, c1 = self.conv1(nnx.silu(self.norm1(x_BTHWC)), c1)
        h, c2 = self.conv2(nnx.silu(self.norm2(h)), c2)
        skip = x_BTHWC if self.shortcut is None else self.shortcut(x_BTHWC, None)[0]
        return skip + h, (c1, c2)


class SpatialAttention(nnx.Module):
    """Single-head self-attention over the h*w positions of each frame (no time mixing, no cache).
    The output projection starts at zero, so the block starts as the identity (as in Wan)."""

    def __init__(self, dim: int, *, dtype, param_dtype, rngs: nnx.Rngs):
        self.norm = RMSNorm(dim, param_dtype=param_dtype)
        self.to_qkv = nnx.Linear(dim, 3 * dim, dtype=dtype, param_dtype=param_dtype, rngs=rngs)
        self.proj = nnx.Linear(dim, dim, kernel_init=nnx.initializers.zeros_init(), dtype=dtype,
                               param_dtype=param_dtype, rngs=rngs)

    def __call__(self, x_BTHWC: jax.Array, cache: Cache) -> tuple[jax.Array, Cache]:
        B, T, H, W, C = x_BTHWC.shape
        qkv = self.to_qkv(self.norm(x_BTHWC)).reshape(B * T, H * W, 1, 3 * C)  # (B*T, L, N=1, 3C)
        q, k, v = jnp.split(qkv, 3, axis=-1)
        o = jax.nn.dot_product_attention(q, k, v)  # scale 1/sqrt(C)
        return x_BTHWC + self.proj(o.reshape(B, T, H, W, C)), cache


class Downsample(nnx.Module):
    """Spatial /2 (pad right/bottom by 1, 3x3 stride-2 conv), then optionally time /2 (causal 3-tap
    stride-2 conv in which frame 0 of the stream passes through). Cache: the last input frame."""

    def __init__(self, dim: int, temporal: bool, *, dtype, param_dtype, rngs: nnx.Rngs):
        kw = dict(dtype=dtype, param_dtype=param_dtype, rngs=rngs)
        self.conv = nnx.Conv(dim, dim, (3, 3), strides=2, padding=((0, 1), (0, 1)), **kw)
        self.time_conv = CausalConv3d(dim, dim, (3, 1, 1), **kw) if temporal else None

    def __call__(self, x_BTHWC: jax.Array, cache: Cache) -> tuple[jax.Array, Cache]:
        B, T, H, W, C = x_BTHWC.shape
        x = self.conv(x_BTHWC.reshape(B * T, H, W, C)).reshape(B, T, H // 2, W // 2, C)
        if self.time_conv is None:
            return x, None
        if cache is None:  # stream start: T = 1 + 2k; frame 0 passes, windows [0,1,2], [2,3,4], ...
            assert T % 2 == 1, f"a stream must start with an odd number of frames here, got {T}"
            y = x if T == 1 else jnp.concatenate([x[:, :1], self.time_conv.conv_valid(x, 2)], axis=1)
        else:  # T = 2k frames after the cached last frame: windows [c,0,1], [1,2,3], ...
            assert T % 2 == 0, f"chunks after the first must have an even number of frames here, got {T}"
            y = self.time_conv.conv_valid(jnp.concatenate([cache.astype(x.dtype), x], axis=1), 2)
        return y, x[:, -1:]


class Upsample(nnx.Module):
    """Optionally time x2 (causal 3-tap conv C -> 2C, then depth-to-time; frame 0 of the stream passes
    through), then nearest x2 in space and a 3x3 conv C -> C/2. Cache: the last 2 time-conv inputs."""

    def __init__(self, dim: int, temporal: bool, *, dtype, param_dtype, rngs: nnx.Rngs):
        kw = dict(dtype=dtype, param_dtype=param_dtype, rngs=rngs)
        self.time_conv = CausalConv3d(dim, 2 * dim, (3, 1, 1), **kw) if temporal else None
        self.conv = nnx.Conv(dim, dim // 2, (3, 3), padding=((1, 1), (1, 1)), **kw)

    def _time_upsample(self, x_BTHWC: jax.Array, cache: Cache) -> tuple[jax.Array, Cache]:
        first, rest = (x_BTHWC[:, :1], x_BTHWC[:, 1:]) if cache is None else (None, x_BTHWC)
        if rest.shape[1] == 0:  # the first latent frame alone: nothing to convolve, history stays zero
            B, _, H, W, C = x_BTHWC.shape
            return first, jnp.zeros((B, self.time_conv.history, H, W, C), x_BTHWC.dtype)
        y, cache = self.time_conv(rest, cache)  # (B, T', H, W, 2C); channel halves are frames 2t, 2t+1
        B, T, H, W, C2 = y.shape
        y = y.reshape(B, T, H, W, 2, C2 // 2).transpose(0, 1, 4, 2, 3, 5).reshape(B, 2 * T, H, W, C2 // 2)
        return (y if first is None else jnp.concatenate([first, y], axis=1)), cache

    def __call__(self, x_BTHWC: jax.Array, cache: Cache) -> tuple[jax.Array, Cache]:
        x = x_BTHWC
        if self.time_conv is not None:
            x, cache = self._time_upsample(x, cache)
        B, T, H, W, C = x.shape
        x = jnp.repeat(jnp.repeat(x.reshape(B * T, H, W, C), 2, axis=1), 2, axis=2)  # nearest x2
        return self.conv(x).reshape(B, T, 2 * H, 2 * W, C // 2), cache


class Head(nnx.Module):
    """RMS norm -> SiLU -> causal conv 3^3 (the last layer of the encoder and of the decoder)."""

    def __init__(self, in_dim: int, out_dim: int, *, dtype, param_dtype, rngs: nnx.Rngs):
        self.norm = RMSNorm(in_dim, param_dtype=param_dtype)
        self.conv = CausalConv3d(in_dim, out_dim, (3, 3, 3), dtype=dtype, param_dtype=param_dtype, rngs=rngs)

    def __call__(self, x_BTHWC: jax.Array, cache: Cache) -> tuple[jax.Array, Cache]:
        return self.conv(nnx.silu(self.norm(x_BTHWC)), cache)


def _run_layers(layers, x_BTHWC: jax.Array, cache: Cache) -> tuple[jax.Array, list]:
    """Apply (x, cache) -> (x, cache) layers in order; ``cache`` is None or one entry per layer."""
    caches = [None] * len(layers) if cache is None else cache
    assert len(caches) == len(layers), f"cache has {len(caches)} entries for {len(layers)} layers"
    new_caches = []
    for layer, c in zip(layers, caches):
        x_BTHWC, c = layer(x_BTHWC, c)
        new_caches.append(c)
    return x_BTHWC, new_caches


def _middle(dim: int, attention: bool, kw: dict) -> list:
    attn = [SpatialAttention(dim, **kw)] if attention else []
    return [ResBlock(dim, dim, **kw), *attn, ResBlock(dim, dim, **kw)]


# ---------------------------------------------------------------------------------------------
# Encoder, decoder, VAE
# ---------------------------------------------------------------------------------------------


class Encoder(nnx.Module):
    """video (B, T, H, W, 3) -> moments (B, F, h, w, 2 * z_dim). Stage widths base_dim * dim_mult[i]."""

    def __init__(self, cfg: VAEConfig, *, rngs: nnx.Rngs):
        kw = dict(dtype=jnp.dtype(cfg.dtype), param_dtype=jnp.dtype(cfg.param_dtype), rngs=rngs)
        dims = [cfg.base_dim * m for m in (1, *cfg.dim_mult)]
        self.conv_in = CausalConv3d(3, dims[0], (3, 3, 3), **kw)
        down = []
        for i, (in_dim, out_dim) in enumerate(zip(dims[:-1], dims[1:])):
            down += [ResBlock(in_dim if j == 0 else out_dim, out_dim, **kw) for j in range(cfg.num_res_blocks)]
            if i < len(cfg.temporal_downsample):
                down.append(Downsample(out_dim, cfg.temporal_downsample[i], **kw))
        self.down = nnx.List(down)
        self.middle = nnx.List(_middle(dims[-1], cfg.middle_attention, kw))
        self.head = Head(dims[-1], 2 * cfg.z_dim, **kw)

    def __call__(self, x_BTHWC: jax.Array, cache: Cache) -> tuple[jax.Array, Cache]:
        return _run_layers([self.conv_in, *self.down, *self.middle, self.head], x_BTHWC, cache)


class Decoder(nnx.Module):
    """latents (B, F, h, w, z_dim) -> video (B, T, H, W, 3), T = 1 + tf * (F - 1) from a stream start.

    Stage i runs num_res_blocks + 1 ResBlocks at width decoder_dim * dim_mult[-1 - i]; every stage but the
    last ends with an Upsample that halves the channels (so stage i > 0 starts at half the previous width).
    With ``decoder_head_upscale`` u > 1 the last log2(u) stages are not built: the head predicts u x u
    RGB pixels per position of the last built stage (depth-to-space, channel = (dy * u + dx) * 3 + rgb).
    """

    def __init__(self, cfg: VAEConfig, *, rngs: nnx.Rngs):
        kw = dict(dtype=jnp.dtype(cfg.dtype), param_dtype=jnp.dtype(cfg.param_dtype), rngs=rngs)
        num_stages = len(cfg.dim_mult) - cfg.head_upscale_stages
        dims = [cfg.decoder_dim * m for m in (cfg.dim_mult[-1], *cfg.dim_mult[::-1])][:num_stages + 1]
        temporal_upsample = cfg.temporal_downsample[::-1]
        self.upscale = cfg.decoder_head_upscale
        self.conv_in = CausalConv3d(cfg.z_dim, dims[0], (3, 3, 3), **kw)
        self.middle = nnx.List(_middle(dims[0], cfg.middle_attention, kw))
        up = []
        for i, out_dim in enumerate(dims[1:]):
            in_dim = dims[0] if i == 0 else dims[i] // 2
            up += [ResBlock(in_dim if j == 0 else out_dim, out_dim, **kw) for j in range(cfg.num_res_blocks + 1)]
            if i < num_stages - 1:
                up.append(Upsample(out_dim, temporal_upsample[i], **kw))
        self.up = nnx.List(up)
        self.head = Head(dims[-1], 3 * self.upscale ** 2, **kw)

    def __call__(self, z_BFhwc: jax.Array, cache: Cache) -> tuple[jax.Array, Cache]:
        x, cache = _run_layers([self.conv_in, *self.middle, *self.up, self.head], z_BFhwc, cache)
        if self.upscale > 1:  # depth-to-space: one-frame patches of u x u pixels
            x = unpatchify(x, 1, self.upscale, first=False)
        return x, cache


class CausalVideoVAE(nnx.Module):
    """The causal video VAE. Public latents are normalised (``normalize_latents``); ``*_raw`` /
    ``encode_moments`` work on raw latents for VAE training.

    Args:
      cfg: sizes, temporal layout and latent statistics (``VAEConfig``).
      rngs: parameter initialisation.
    """

    def __init__(self, cfg: VAEConfig, *, rngs: nnx.Rngs):
        kw = dict(dtype=jnp.dtype(cfg.dtype), param_dtype=jnp.dtype(cfg.param_dtype), rngs=rngs)
        self.cfg = cfg
        if cfg.codec == "linear_patch":
            # patch <-> latent, one matrix each way (training.vae.fit_linear_patch_codec sets them); the decoder's
            # reads the decoder_context**2 latent positions around each one (latent_neighbourhood)
            d = cfg.temporal_factor * cfg.spatial_factor ** 2 * 3
            self.patch_in = nnx.Linear(d, cfg.z_dim, **kw)
            self.patch_out = nnx.Linear(cfg.decoder_context ** 2 * cfg.z_dim, d, **kw)
            return
        self.encoder = Encoder(cfg, rngs=rngs)
        self.conv1 = CausalConv3d(2 * cfg.z_dim, 2 * cfg.z_dim, (1, 1, 1), **kw)  # moments (mu, logvar)
        # the logvar half starts at LOGVAR_INIT everywhere (weights 0): a near-deterministic posterior from the
        # first update, so the decoder sees the encoder's signal at once (docs/model.md §7.1)
        self.conv1.kernel[...] = self.conv1.kernel[...].at[..., cfg.z_dim:].set(0.0)
        self.conv1.bias[...] = self.conv1.bias[...].at[cfg.z_dim:].set(LOGVAR_INIT)
        self.conv2 = CausalConv3d(cfg.z_dim, cfg.z_dim, (1, 1, 1), **kw)  # latent -> decoder input
        self.decoder = Decoder(cfg, rngs=rngs)

    # -- helpers ---------------------------------------------------------------------------------
    def normalize(self, mu_BFhwc: jax.Array) -> jax.Array:
        return normalize_latents(mu_BFhwc, self.cfg)

    def denormalize(self, z_BFhwc: jax.Array) -> jax.Array:
        return denormalize_latents(z_BFhwc, self.cfg)

    def _moments(self, video_BTHWC: jax.Array, cache: Cache) -> tuple[jax.Array, jax.Array, Cache]:
        self._check_video(video_BTHWC, first=cache is None)
        if self.cfg.codec == "linear_patch":  # no history: the cache only marks "after the stream's start"
            patches = patchify(video_BTHWC, self.cfg.temporal_factor, self.cfg.spatial_factor, first=cache is None)
            mu = self.patch_in(patches).astype(jnp.float32)
            return mu, jnp.full_like(mu, LOGVAR_INIT), ()
        h, cache = self.encoder(video_BTHWC, cache)
        mu, logvar = jnp.split(self.conv1(h, None)[0].astype(jnp.float32), 2, axis=-1)
        return mu, logvar, cache

    def _check_video(self, video_BTHWC: jax.Array, first: bool) -> None:
        _, T, H, W, C = video_BTHWC.shape
        tf, sf = self.cfg.temporal_factor, self.cfg.spatial_factor
        assert C == 3 and H % sf == 0 and W % sf == 0, f"video (T,H,W,C)={T, H, W, C} needs C=3, H,W % {sf} == 0"
        ok = (T - 1) % tf == 0 if first else (T % tf == 0 and T > 0)
        assert ok, (f"{'a stream starts with 1 + ' if first else 'later chunks have '}{tf}*k frames "
                    f"(temporal_factor {tf}), got T={T}")

    # -- encoding ----------------------------------------------------------------------------------
    def encode_moments(self, video_BTHWC: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(mu, logvar) of the raw posterior, each (B, F, h, w, z_dim); T = 1 + tf * (F - 1). Training."""
        mu, logvar, _ = self._moments(video_BTHWC, None)
        return mu, logvar

    def encode(self, video_BTHWC: jax.Array) -> jax.Array:
        """Video (B, T, H, W, 3) in [-1, 1], T = 1 + tf * (F - 1) -> normalised mu (B, F, h, w, z_dim)."""
        return self.normalize(self.encode_moments(video_BTHWC)[0])

    def encode_chunked(self, video_BTHWC: jax.Array, cache: Cache = None) -> tuple[jax.Array, Cache]:
        """One chunk of a stream -> (normalised mu (B, F_chunk, h, w, z_dim), cache for the next chunk).

        Start with ``cache=None`` and 1 + tf * k frames (Wan uses 1), then pass back the returned cache
        with tf * k frames per chunk (Wan uses tf). Equals ``encode`` of the concatenated chunks.
        """
        mu, _, cache = self._moments(video_BTHWC, cache)
        return self.normalize(mu), cache

    # -- decoding ----------------------------------------------------------------------------------
    def _decode_raw(self, latent_BFhwc: jax.Array, cache: Cache) -> tuple[jax.Array, Cache]:
        if self.cfg.codec == "linear_patch":
            patches = self.patch_out(latent_neighbourhood(latent_BFhwc, self.cfg.decoder_context))
            return unpatchify(patches, self.cfg.temporal_factor, self.cfg.spatial_factor, first=cache is None), ()
        x, _ = self.conv2(latent_BFhwc, None)
        return self.decoder(x, cache)

    def decode_raw(self, latent_BFhwc: jax.Array) -> jax.Array:
        """Raw (un-normalised) latents (B, F, h, w, z_dim) -> un-clipped video (B, 1 + tf*(F-1), H, W, 3)."""
        return self._decode_raw(latent_BFhwc, None)[0].astype(jnp.float32)

    def decode(self, z_BFhwc: jax.Array) -> jax.Array:
        """Normalised latents (B, F, h, w, z_dim) -> video (B, 1 + tf * (F - 1), H, W, 3) in [-1, 1]."""
        return jnp.clip(self.decode_raw(self.denormalize(z_BFhwc)), -1.0, 1.0)

    def decode_step(self, z_B1hwc: jax.Array, cache: Cache = None) -> tuple[jax.Array, Cache]:
        """One normalised latent frame -> (video (B, t, H, W, 3) in [-1, 1], cache); t = 1 for the first
        step of a stream (``cache=None``), tf afterwards. Steps concatenate to ``decode`` of all frames."""
        assert z_B1hwc.shape[1] == 1, f"decode_step takes one latent frame, got {z_B1hwc.shape[1]}"
        video, cache = self._decode_raw(self.denormalize(z_B1hwc), cache)
        return jnp.clip(video.astype(jnp.float32), -1.0, 1.0), cache

