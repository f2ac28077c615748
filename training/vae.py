"""Training the causal video VAE on engine frames (the stage before the DiT stages).

The official model uses the pretrained Wan2.1 VAE; nothing can be downloaded here, so our presets
train their own on the engine's recordings. Objective (per clip of T = 1 + k * n frames in [-1, 1]):

    z ~ q(z | x) (reparameterised),  x_hat = decode(z),
    loss = mean((x_hat - x)^2) + l1_weight * mean|x_hat - x| + kl_weight * KL(q || N(0, I)) / num_pixels

Clips are short (a few latent frames) so the encoder and decoder see both the first-frame mode (latent
0 = one frame) and the chunk mode (later latents = k frames with causal history), as the world model
uses them. After training, :func:`latent_statistics` measures the per-channel mean/std of the posterior
means, which become the config's ``latent_mean``/``latent_std`` (the DiT works on normalised latents).

    graphdef, state = TrainState.create(vae, make_optimizer(lr), rng=0)
    step = make_vae_train_step(graphdef, tx, VAELossWeights())
    state, metrics = step(state, video_BTHWC)          # video in [-1, 1]

Decoder fine-tuning (the ``vae-decoder`` stage, :func:`make_decoder_train_step`): a VAE trained on clips
of 1 + k frames has only ever decoded latent 1 with the causal cache of latent 0; from latent 2 on, its
decoder's temporal convolutions see a cache it never saw in training and the reconstruction collapses
(measured on the session-2 tiny VAE: 21 dB for frames 1-4, 14 dB after). Decoding the long streams
the env produces needs a decoder trained on them, and clips that long are too slow for the whole VAE
on our CPU. So the second VAE stage trains only the decoder side (``conv2`` + ``decoder``) on long clips,
from the frozen encoder's posterior means: the latent space, its statistics and every latent the DiT
stages cache or generate stay exactly as they were.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx

from solaris_env.world_model.vae import CausalVideoVAE, kl_divergence, latent_neighbourhood, patchify, sample_posterior
from solaris_env.world_model.world_model import frames_to_model
from training.step import TrainState, make_optimizer


@dataclass(frozen=True)
class VAELossWeights:
    l1: float = 0.1  # a little L1 keeps edges sharper than MSE alone
    kl: float = 1e-6  # per pixel-normalised KL, small (a near-deterministic autoencoder, as LDM/Wan)


def vae_loss(vae: CausalVideoVAE, video_BTHWC: jax.Array, key: jax.Array, weights: VAELossWeights
             ) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Scalar loss and its parts for a clip batch in [-1, 1] (T = 1 + k * n)."""
    mu, logvar = vae.encode_moments(video_BTHWC)
    z = sample_posterior(mu, logvar, key=key)
    recon = vae.decode_raw(z)
    err = recon - video_BTHWC.astype(jnp.float32)
    mse = jnp.mean(jnp.square(err))
    l1 = jnp.mean(jnp.abs(err))
    kl = jnp.mean(kl_divergence(mu, logvar)) / np.prod(video_BTHWC.shape[1:])
    loss = mse + weights.l1 * l1 + weights.kl * kl
    return loss, {"mse": mse, "l1": l1, "kl": kl}


def fit_linear_patch_codec(vae: CausalVideoVAE, clips_uint8) -> dict:
    """Fit a linear patch codec (``VAEConfig.codec = "linear_patch"``) to clips: the z_dim leading principal
    components of their (tf, sf, sf, 3) patches in [-1, 1] (``vae.patchify``; a clip is a stream start, T = 1 +
    tf * n). Encoder: mu = V^T (p - m); decoder: p = V mu + m, the best linear codec of that latent size in
    mean squared error (docs/model.md §7.1, "Linear patch codec"). ``clips_uint8``: an iterable of
    (B, T, H, W, 3) uint8 arrays. -> the fit's facts."""
    cfg = vae.cfg
    if cfg.codec != "linear_patch":
        raise ValueError(f"fit_linear_patch_codec: the VAE's codec is {cfg.codec!r}, expected 'linear_patch'")
    tf, sf, z = cfg.temporal_factor, cfg.spatial_factor, cfg.z_dim
    d = tf * sf * sf * 3
    second, first, n = np.zeros((d, d)), np.zeros(d), 0
    for clip in clips_uint8:
        p = np.asarray(patchify(frames_to_model(jnp.asarray(clip)), tf, sf, True), np.float64).reshape(-1, d)
        second += p.T @ p
        first += p.sum(0)
        n += len(p)
    if n <= d:
        raise ValueError(f"fit_linear_patch_codec: {n} patches for a {d}-dimensional fit; give more clips")
    mean = first / n
    eigval, eigvec = np.linalg.eigh(second / n - np.outer(mean, mean))
    eigval, eigvec = eigval[::-1], eigvec[:, ::-1][:, :z]  # descending
    dtype = vae.patch_in.kernel[...].dtype
    vae.patch_in.kernel[...] = jnp.asarray(eigvec, dtype)
    vae.patch_in.bias[...] = jnp.asarray(-mean @ eigvec, dtype)
    # the decoder reads the centre position only (the other taps of a decoder_context > 1 at zero), until
    # fit_patch_decoder fits them
    vae.patch_out.kernel[...] = jnp.asarray(relayout_patch_decoder(eigvec.T, z, 1, cfg.decoder_context), dtype)
    vae.patch_out.bias[...] = jnp.asarray(mean, dtype)
    return {"patches": int(n), "variance_kept": float(eigval[:z].sum() / eigval.sum()),
            "component_std": [round(float(v), 4) for v in np.sqrt(np.maximum(eigval[:z], 0.0))]}


def relayout_patch_decoder(kernel: np.ndarray, z_dim: int, k_from: int, k_to: int) -> np.ndarray:
    """A linear patch decoder's kernel ((k_from² · z_dim, D), rows as ``vae.latent_neighbourhood`` orders them)
    re-laid for a (k_to x k_to) neighbourhood: the taps both windows share, centred, are kept, new taps are zero,
    so a wider decoder decodes exactly as the narrower one."""
    old = np.asarray(kernel).reshape(k_from, k_from, z_dim, -1)
    out = np.zeros((k_to, k_to, z_dim, old.shape[-1]), old.dtype)
    r = min(k_from, k_to) // 2
    out[k_to // 2 - r:k_to // 2 + r + 1, k_to // 2 - r:k_to // 2 + r + 1] = \
        old[k_from // 2 - r:k_from // 2 + r + 1, k_from // 2 - r:k_from // 2 + r + 1]
    return out.reshape(k_to * k_to * z_dim, -1)


PATCH_DECODER_RIDGE = 1e-7  # x the mean diagonal of the normal equations: keeps the solve well posed (1e-3 shrank
# the small, fine components by ~6 %: a blurrier decode, session 66)


def fit_patch_decoder(vae: CausalVideoVAE, clips_uint8) -> dict:
    """Fit a linear patch codec's decoder (``patch_out``) to clips in closed form, its encoder (the latent space)
    kept: the least-squares map from each latent position's ``decoder_context`` x ``decoder_context``
    neighbourhood of raw latents (``vae.latent_neighbourhood``) to its (tf, sf, sf, 3) pixel patch, with a
    small ridge (``PATCH_DECODER_RIDGE``). With a context of 1 it is the principal-component decoder again (up
    to the ridge); wider, the neighbours estimate what the components leave out (docs/model.md §7.1).
    ``clips_uint8``: an iterable of (B, T, H, W, 3) uint8 stream starts (T = 1 + tf * n). -> the fit's facts:
    patches, and the mean squared error per patch entry of the decoder before and after, on those clips."""
    cfg = vae.cfg
    if cfg.codec != "linear_patch":
        raise ValueError(f"fit_patch_decoder: the VAE's codec is {cfg.codec!r}, expected 'linear_patch'")
    tf, sf, k = cfg.temporal_factor, cfg.spatial_factor, cfg.decoder_context
    d, f = tf * sf * sf * 3, k * k * cfg.z_dim + 1
    xtx, xty, yty, n = np.zeros((f, f)), np.zeros((f, d)), 0.0, 0
    old = np.concatenate([np.asarray(vae.patch_out.kernel[...], np.float64),
                          np.asarray(vae.patch_out.bias[...], np.float64)[None]])
    for clip in clips_uint8:
        video = frames_to_model(jnp.asarray(clip))
        y = np.asarray(patchify(video, tf, sf, True), np.float64).reshape(-1, d)
        mu = vae.encode_moments(video)[0]
        x = np.asarray(latent_neighbourhood(mu, k), np.float64).reshape(len(y), -1)
        x = np.concatenate([x, np.ones((len(x), 1))], axis=1)
        xtx += x.T @ x
        xty += x.T @ y
        yty += float(np.sum(y * y))
        n += len(y)
    if n <= f:
        raise ValueError(f"fit_patch_decoder: {n} patches for a {f}-input fit; give more clips")
    ridge = PATCH_DECODER_RIDGE * np.trace(xtx) / f
    w = np.linalg.solve(xtx + ridge * np.eye(f), xty)
    mse = lambda m: float((yty - 2.0 * np.sum(m * xty) + np.sum(m * (xtx @ m))) / (n * d))
    dtype = vae.patch_out.kernel[...].dtype
    vae.patch_out.kernel[...] = jnp.asarray(w[:-1], dtype)
    vae.patch_out.bias[...] = jnp.asarray(w[-1], dtype)
    return {"patches": int(n), "decoder_context": k, "mse_before": mse(old), "mse_after": mse(w)}


def make_vae_train_step(graphdef: nnx.GraphDef, tx: optax.GradientTransformation, weights: VAELossWeights):
    """-> jitted ``step(state, video_BTHWC uint8) -> (state, metrics)``, state donated."""

    def loss_fn(params, rest, video, key):
        return vae_loss(nnx.merge(graphdef, params, rest), video, key, weights)

    def step(state: TrainState, video_uint8: jax.Array):
        key = jax.random.fold_in(state.rng, state.step)
        video = frames_to_model(video_uint8)
        (loss, parts), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params, state.rest, video, key)
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        metrics = {"loss": loss, **parts, "psnr": psnr_from_mse(parts["mse"]), "grad_norm": optax.tree.norm(grads)}
        return state.replace(params=params, opt_state=opt_state, step=state.step + 1), metrics

    return jax.jit(step, donate_argnums=(0,))


DECODER_MODULES = ("conv2", "decoder")  # what the vae-decoder stage trains; the rest is frozen


def decoder_labels(params) -> object:
    """optax labels: ``train`` for the decoder side (``DECODER_MODULES``), ``frozen`` for the encoder side."""
    return jax.tree_util.tree_map_with_path(
        lambda path, _: "train" if getattr(path[0], "key", None) in DECODER_MODULES else "frozen", params)


def decoder_loss(vae: CausalVideoVAE, video_BTHWC: jax.Array, weights: VAELossWeights
                 ) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Reconstruction loss of the decoder from the frozen encoder's posterior mean (no KL, no sampling:
    the world model decodes means)."""
    mu, _ = vae.encode_moments(video_BTHWC)
    recon = vae.decode_raw(jax.lax.stop_gradient(mu))
    err = recon - video_BTHWC.astype(jnp.float32)
    mse = jnp.mean(jnp.square(err))
    l1 = jnp.mean(jnp.abs(err))
    return mse + weights.l1 * l1, {"mse": mse, "l1": l1}


def make_decoder_optimizer(lr: float, params) -> optax.GradientTransformation:
    """AdamW (the VAE stage's) on the decoder side, nothing on the encoder side."""
    return optax.multi_transform({"train": make_optimizer(lr), "frozen": optax.set_to_zero()}, decoder_labels(params))


def make_decoder_train_step(graphdef: nnx.GraphDef, tx: optax.GradientTransformation, weights: VAELossWeights):
    """-> jitted ``step(state, video_BTHWC uint8) -> (state, metrics)``, state donated; ``tx`` from
    :func:`make_decoder_optimizer` (the encoder side gets zero updates)."""

    def loss_fn(params, rest, video):
        return decoder_loss(nnx.merge(graphdef, params, rest), video, weights)

    def step(state: TrainState, video_uint8: jax.Array):
        video = frames_to_model(video_uint8)
        (loss, parts), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params, state.rest, video)
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        metrics = {"loss": loss, **parts, "psnr": psnr_from_mse(parts["mse"]), "grad_norm": optax.tree.norm(grads)}
        return state.replace(params=params, opt_state=opt_state, step=state.step + 1), metrics

    return jax.jit(step, donate_argnums=(0,))


def psnr_from_mse(mse_pm1: jax.Array) -> jax.Array:
    """PSNR in dB of a mean squared error measured on [-1, 1] images (peak-to-peak 2)."""
    return 10.0 * jnp.log10(4.0 / jnp.maximum(mse_pm1, 1e-12))


def make_reconstruct(graphdef: nnx.GraphDef):
    """-> jitted ``reconstruct(params, rest, video uint8 (B, T, H, W, 3)) -> uint8`` through the posterior
    mean (what the world model uses), clipped and quantised like generated frames."""
    encode_decode = make_encode_reconstruct(graphdef)
    return jax.jit(lambda params, rest, video_uint8: encode_decode(params, rest, video_uint8)[0])


def make_encode_reconstruct(graphdef: nnx.GraphDef):
    """-> jitted ``(params, rest, video uint8 (B, T, H, W, 3)) -> (reconstruction uint8, raw posterior mean
    (B, F, h, w, z_dim) float32)``: one program for a VAE stage's held-out PSNR and its latent statistics."""

    def encode_reconstruct(params, rest, video_uint8):
        vae = nnx.merge(graphdef, params, rest)
        mu, _ = vae.encode_moments(frames_to_model(video_uint8))
        recon = jnp.clip(vae.decode_raw(mu), -1.0, 1.0)
        return jnp.clip((recon + 1.0) * 127.5, 0.0, 255.0).astype(jnp.uint8), mu.astype(jnp.float32)

    return jax.jit(encode_reconstruct)


def psnr_per_latent_step(rec_BTHW3: np.ndarray, gt_BTHW3: np.ndarray, k: int) -> list[float]:
    """PSNR (dB) of each latent frame's video frames: [frame 0], then frames k(j-1)+1 .. kj for j >= 1."""
    spans = [(0, 1)] + [(k * (j - 1) + 1, k * j + 1) for j in range(1, 1 + (rec_BTHW3.shape[1] - 1) // k)]
    return [psnr_uint8(rec_BTHW3[:, a:b], gt_BTHW3[:, a:b]) for a, b in spans]


def psnr_uint8(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB between two uint8 arrays (peak 255), over all elements."""
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10.0 * np.log10(255.0 ** 2 / max(mse, 1e-12)))


def latent_statistics(mu_chunks: list) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Per-channel mean and std of posterior means (each chunk (..., z_dim), e.g. ``make_encode_reconstruct``'s)."""
    total, total_sq, count = 0.0, 0.0, 0
    for mu in mu_chunks:
        flat = np.asarray(mu, np.float64).reshape(-1, np.shape(mu)[-1])
        total, total_sq, count = total + flat.sum(0), total_sq + np.square(flat).sum(0), count + len(flat)
    if count == 0:
        raise ValueError("latent_statistics: no clips given")
    mean = total / count
    std = np.sqrt(np.maximum(total_sq / count - mean ** 2, 1e-12))
    return tuple(float(m) for m in mean), tuple(float(s) for s in std)
