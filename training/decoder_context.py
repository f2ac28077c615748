"""``solaris-train decoder-context``: a linear patch codec's decoder refitted in closed form to read a k x k
neighbourhood of latents, the encoder, the latent space, the DiT and the image encoder kept bit for bit
(docs/model.md §7.1, "Linear patch codec"; docs/training.md, "Modules").

    solaris-train decoder-context default --context 3 --data data/mixed12 --out runs/ctx3
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from flax import nnx

from solaris_env.world_model.vae import CausalVideoVAE
from solaris_env.world_model.world_model import WorldModel
from training.surgery import model_directory
from training.train import duet_stream, next_batch
from training.vae import fit_patch_decoder, relayout_patch_decoder


def with_decoder_context(model: str | Path, dest: str | Path, context: int, data_dir: str | Path,
                         clips: int = 2048, num_frames: int = 25, seed: int = 0) -> tuple[Path, dict]:
    """Write ``model`` to ``dest`` with its linear patch codec's decoder reading ``context`` x ``context`` latent
    positions, fitted in closed form (``training.vae.fit_patch_decoder``) to ``clips`` single-player clips of
    ``num_frames`` frames from ``data_dir``'s training split. The encoder, the latent statistics, the DiT and
    the image encoder are kept bit for bit: the DiT's latents mean what they meant, only their pixels change
    (docs/model.md §7.1). Returns (dest, the fit's facts)."""
    base = WorldModel.load(model_directory(model))
    cfg = base.config
    if cfg.vae.codec != "linear_patch":
        raise ValueError(f"{model}: its codec is {cfg.vae.codec!r}; decoder-context needs 'linear_patch'")
    vae_cfg = dataclasses.replace(cfg.vae, decoder_context=context)  # validates the context
    dit, vae, encoder = base.modules()
    fresh = CausalVideoVAE(vae_cfg, rngs=nnx.Rngs(seed))
    fresh.patch_in.kernel[...] = vae.patch_in.kernel[...]
    fresh.patch_in.bias[...] = vae.patch_in.bias[...]
    # start from the model's own decoder re-laid for the new window, so the fit's "before" is that decoder
    fresh.patch_out.kernel[...] = relayout_patch_decoder(vae.patch_out.kernel[...], cfg.vae.z_dim,
                                                         cfg.vae.decoder_context, context)
    fresh.patch_out.bias[...] = vae.patch_out.bias[...]
    dataset, sampler = duet_stream(Path(data_dir), cfg, num_frames, seed)
    per_draw = 8

    def draws():
        for _ in range(max(1, -(-clips // (per_draw * cfg.num_players)))):
            obs = next_batch(dataset, sampler, per_draw)["obs"]  # (B, T, P, H, W, 3)
            yield np.swapaxes(obs, 1, 2).reshape((-1,) + obs.shape[1:2] + obs.shape[3:])

    fit = fit_patch_decoder(fresh, draws())
    WorldModel(cfg.replace(vae=vae_cfg), dit, fresh, encoder).save(dest)
    return Path(dest), fit
