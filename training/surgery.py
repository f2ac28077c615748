"""Model surgery: functions that change a trained model's layout or weights without training it
(docs/training.md, "Modules"). Each writes a new model directory (``checkpoint.save``) or returns a
rebuilt module; none draws data or takes an optimiser step (``training.decoder_context`` fits a decoder to data).

* ``relayout_decoder``: a VAE rebuilt in another decoder layout, warm-started (the ``vae-decoder`` stage);
* ``with_decoder``: a model given the decoder of a ``vae-decoder`` stage of the same latent space
  (``solaris-train with-decoder``);
* ``with_vae``: a model's DiT and image encoder with another model's whole VAE, a new latent space of the same
  shape, to retrain the DiT on (``solaris-train with-vae``);
* ``with_action_conditioning``: a model under another action conditioning computing the same function
  (``solaris-train action-conditioning``);
* ``official_dit``: a model's autoencoder and image encoder under a freshly initialised DiT in the official
  layout, with none of our DiT options (``solaris-train official-dit``: the start of issue 23's control row);
* ``fresh_dit``: a model's autoencoder and image encoder under a freshly initialised DiT of other sizes (token grid,
  width, depth) with every option of the model (``solaris-train fresh-dit``: the start of a new DiT lineage);
* ``install_default``: a model copied, as float16 single-file weights, to the package's default-model
  directory (``solaris-train install``).
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from solaris_env.world_model import checkpoint
from solaris_env.world_model.action_module import rescaled_mouse_kernel
from solaris_env.world_model.components import COMPONENTS
from solaris_env.world_model.config import VAEConfig
from solaris_env.world_model.dit import skip_gate
from solaris_env.world_model.vae import CausalVideoVAE
from solaris_env.world_model.world_model import WorldModel
from training.vae import DECODER_MODULES

DEFAULT_MODEL_DIR = Path(__file__).resolve().parent.parent / "solaris_env" / "assets" / "default"


def model_directory(spec: str | Path, what: str = "model") -> Path:
    """The directory of a model named ``spec``: 'default' (the shipped model) or a directory holding its
    ``config.json``; ``what`` names the argument in the error."""
    path = DEFAULT_MODEL_DIR if str(spec) == "default" else Path(spec)
    if not (path / "config.json").is_file():
        raise FileNotFoundError(f"{what} {spec}: {path} holds no model (config.json); expected 'default' or a "
                                f"model directory")
    return path


def relayout_decoder(vae, target: VAEConfig, seed: int):
    """``vae`` rebuilt with ``target``'s (decoder) layout: every parameter whose path and shape exist in
    both is copied (so the encoder side, and the latent space, are exactly ``vae``'s), the rest is
    freshly initialised. Returns (the new VAE, the copied decoder-side paths as strings)."""
    fresh = CausalVideoVAE(target, rngs=nnx.Rngs(seed))
    old = dict(nnx.to_flat_state(nnx.state(vae, nnx.Param)))
    new = nnx.state(fresh, nnx.Param)
    copied = []
    for path, var in nnx.to_flat_state(new):
        src = old.get(path)
        if src is not None and src.get_value().shape == var.get_value().shape:
            var.set_value(src.get_value())
            if path[0] in DECODER_MODULES:
                copied.append("/".join(map(str, path)))
        elif path[0] not in DECODER_MODULES:
            raise ValueError(f"relayout_decoder: encoder-side parameter {'/'.join(map(str, path))} does not match "
                             f"(target layout {target.decoder_layout()} must change only the decoder)")
    nnx.update(fresh, new)
    return fresh, copied


def with_decoder(model: str | Path, decoder_from: str | Path, dest: str | Path) -> Path:
    """Write ``model`` with the VAE decoder side of ``decoder_from`` (a ``vae-decoder`` stage output) to
    ``dest``. Allowed only when both share the encoder side bit for bit (encoder, moments conv, latent
    statistics), i.e. the same latent space: the DiT's latents decode exactly as through that stage."""
    base, donor = WorldModel.load(model), WorldModel.load(decoder_from)
    (dit, vae, encoder), (_, donor_vae, _) = base.modules(), donor.modules()
    mine, theirs = nnx.state(vae, nnx.Param), nnx.state(donor_vae, nnx.Param)
    stats = lambda c: (c.vae.latent_mean, c.vae.latent_std)
    for name in mine:
        if name in DECODER_MODULES:
            continue
        same = all(np.array_equal(np.asarray(a), np.asarray(b))
                   for a, b in zip(jax.tree.leaves(mine[name]), jax.tree.leaves(theirs[name])))
        if not same:
            raise ValueError(f"{decoder_from}: its VAE {name!r} differs from {model}'s: not the same latent space")
    if stats(base.config) != stats(donor.config) or base.config.vae.with_decoder_layout(donor.config.vae) != donor.config.vae:
        raise ValueError(f"{decoder_from}: VAE config / latent statistics differ from {model}'s")
    WorldModel(base.config.replace(vae=donor.config.vae), dit, donor_vae, encoder).save(dest)
    return Path(dest)


def with_vae(model: str | Path, vae_from: str | Path, dest: str | Path) -> Path:
    """Write ``model``'s DiT and image encoder with the whole VAE of ``vae_from`` (its weights, layout and
    latent statistics) to ``dest``. The latents must have the same shape (channels, grid, frames per latent)
    over the same frames, so the DiT runs on them unchanged; their meaning changes, so the DiT is then
    retrained on them (stage 3 from ``dest``): its action module and attention keep what they learned."""
    base = WorldModel.load(model_directory(model))
    donor = WorldModel.load(model_directory(vae_from, "--vae-from"))
    shape = lambda c: {"latent_channels": c.latent_channels, "latent_grid": (c.latent_height, c.latent_width),
                       "frames_per_latent": c.frames_per_step, "frame": (c.frame_height, c.frame_width)}
    if shape(base.config) != shape(donor.config):
        raise ValueError(f"--vae-from {vae_from}: its latents {shape(donor.config)} differ from {model}'s "
                         f"{shape(base.config)}; the DiT needs the same latent shape")
    (dit, _, encoder), (_, vae, _) = base.modules(), donor.modules()
    WorldModel(base.config.replace(vae=donor.config.vae), dit, vae, encoder).save(dest)
    return Path(dest)


def with_action_conditioning(model: str | Path, dest: str | Path, mouse_input_gain: float | None = None,
                             camera_warp: tuple[float, float] | None = None,
                             walk_warp: float | None = None, previous_skip: bool | None = None,
                             warp_interp: str | None = None, jump_warp: float | None = None,
                             warp_geometry: str | None = None, partner_map: float | None = None) -> Path:
    """Write ``model`` under another action conditioning, computing the same function (None keeps a setting):

    * ``mouse_input_gain``: the mouse rows of every ``mouse_mlp`` first kernel scaled by old / new gain, so
      further training moves the camera pathway ``new / old`` times faster per Adam step;
    * ``camera_warp=(h, w)``: turns on ``DiTConfig.camera_warp`` (latent pixels per degree) with the patch
      embedding's new input rows (the warped previous latent) at zero; from a model that has it, only its scale
      changes (the weights are kept: the function changes wherever the camera turns);
    * ``walk_warp``: sets ``DiTConfig.walk_warp`` (eye heights per tick; needs the camera warp, given or already
      on). The weights are kept: the function changes only where the movement keys are held, and fine-tuning
      teaches the DiT to read the walked warp;
    * ``jump_warp``: sets ``DiTConfig.jump_warp`` (eye heights per block of a simulated jump; needs the camera
      warp). The weights are kept: the function changes only where the jump key lifts the player;
    * ``previous_skip=True``: turns on ``DiTConfig.previous_skip`` with its gates at zero (needs the camera warp,
      given or already on); from a model that has it, its trained gates are kept;
    * ``warp_interp``: sets ``DiTConfig.warp_interp`` (how the camera warp samples between latent pixels); the
      weights are kept, the function changes wherever the camera turns by a fraction of a latent pixel;
    * ``warp_geometry``: sets ``DiTConfig.warp_geometry`` (what a turn does to the warped previous latent: a
      uniform shift or the camera's rotation); the weights are kept, the function changes wherever the camera
      turns.
    * ``partner_map``: sets ``DiTConfig.partner_map`` (the map's input scale); turned on, the patch embedding's new
      input row (the map, after the mask channels) starts at zero, so the function is unchanged until fine-tuning
      teaches the DiT to read it; from a model that has it, only its scale changes.
    """
    base = WorldModel.load(model)
    old = base.config
    action = dataclasses.replace(
        old.action,
        mouse_input_gain=old.action.mouse_input_gain if mouse_input_gain is None else float(mouse_input_gain))
    dit = old.dit if camera_warp is None else dataclasses.replace(old.dit, camera_warp=tuple(map(float, camera_warp)))
    if walk_warp is not None:
        dit = dataclasses.replace(dit, walk_warp=float(walk_warp))
    if jump_warp is not None:
        dit = dataclasses.replace(dit, jump_warp=float(jump_warp))
    if previous_skip is not None:
        dit = dataclasses.replace(dit, previous_skip=bool(previous_skip))
    if warp_interp is not None:
        dit = dataclasses.replace(dit, warp_interp=warp_interp)
    if warp_geometry is not None:
        dit = dataclasses.replace(dit, warp_geometry=warp_geometry)
    if partner_map is not None:
        dit = dataclasses.replace(dit, partner_map=float(partner_map))
    if old.dit.partner_map and not dit.partner_map:
        raise ValueError(f"{model} was trained with partner_map; dropping it would drop its patch embedding's map row")
    if old.dit.previous_skip and not dit.previous_skip:
        raise ValueError(f"{model} was trained with previous_skip; dropping it would drop its trained skip gates")
    if old.dit.camera_warp_enabled and not dit.camera_warp_enabled:
        raise ValueError(f"{model} was trained with camera_warp={old.dit.camera_warp}; dropping it would drop its "
                         "patch embedding's trained warp rows")
    cfg = old.replace(action=action, dit=dit)
    dit_state, vae_state, encoder_state = base.params
    pe = dit_state["patch_embedding"]["kernel"]
    if dit.partner_map and not old.dit.partner_map:  # the map's row after the noisy latent and the mask, at zero
        k = pe.get_value()
        at = old.out_channels + old.mask_channels
        pe.set_value(jnp.concatenate([k[..., :at, :], jnp.zeros_like(k[..., :1, :]), k[..., at:, :]], axis=-2))
    if cfg.patch_in_channels != pe.get_value().shape[-2]:  # the warped previous latent's rows, at zero
        k = pe.get_value()
        pad = [(0, 0)] * k.ndim
        pad[-2] = (0, cfg.patch_in_channels - k.shape[-2])
        pe.set_value(jnp.pad(k, pad))
    if dit.previous_skip and not old.dit.previous_skip:  # the gates at zero, as a fresh model has them
        dit_state["skip_gate"] = nnx.state(skip_gate(cfg, nnx.Rngs(0)), nnx.Param)
    kernel = dit_state["blocks"]["action_model"]["mouse_mlp"]["layers"][0]["kernel"]
    kernel.set_value(rescaled_mouse_kernel(kernel.get_value(), old, action.mouse_input_gain))
    checkpoint.save(dest, cfg, dict(zip(COMPONENTS, (dit_state, vae_state, encoder_state))))
    return Path(dest)


def official_dit(model: str | Path, dest: str | Path, seed: int = 0) -> Path:
    """Write ``model``'s VAE and image encoder, unchanged, with a freshly initialised DiT (``seed``) in the
    official layout to ``dest``: our options at their official values (``DiTConfig.camera_warp``,
    ``walk_warp``, ``jump_warp``, ``partner_map`` and ``previous_skip`` off, ``warp_interp`` linear, ``warp_geometry`` shift,
    ``ActionConfig.mouse_input_gain`` 1, and the sampler's ``noise_warp`` 0, fresh noise: it moves the noise with
    the camera warp, and ``still_memory`` 0), every size as ``model``'s. Trained through the DiT stages with the
    same steps and data as ``model``'s DiT, it is the control that measures those options (docs/training.md,
    "The control row")."""
    base = WorldModel.load(model_directory(model))
    old = base.config
    dit = dataclasses.replace(old.dit, camera_warp=(0.0, 0.0), walk_warp=0.0, jump_warp=0.0, partner_map=0.0,
                              previous_skip=False, warp_interp="linear", warp_geometry="shift")
    cfg = old.replace(dit=dit, action=dataclasses.replace(old.action, mouse_input_gain=1.0),
                      sampler=dataclasses.replace(old.sampler, noise_warp=0.0, still_memory=0.0))
    return _save_under_fresh_dit(base, cfg, dest, seed)


def fresh_dit(model: str | Path, dest: str | Path, patch: int | None = None, dim: int | None = None,
              num_layers: int | None = None, seed: int = 0) -> Path:
    """Write ``model``'s VAE and image encoder, unchanged, with a freshly initialised DiT (``seed``) of other sizes
    to ``dest``: ``patch`` the DiT's spatial patch (the token grid: a 16 × 16 latent at patch 2 is 64 tokens per
    player-frame), ``dim`` its width, ``num_layers`` its depth; each left None keeps ``model``'s. Every option
    (the warps, the skip, the partner map, the sampler) stays ``model``'s. The heads keep ``model``'s head width
    (the DiT's and the action module's, whose hidden widths follow ``dim``), the FFN its ratio to the width, and the
    action module runs in the first ``min(num_action_blocks, num_layers)`` blocks. Trained through stage 3, it is a
    new lineage on the same latent space (docs/history.md, session 89)."""
    base = WorldModel.load(model_directory(model))
    old = base.config
    patch = old.dit.patch_size[1] if patch is None else int(patch)
    dim = old.dit.dim if dim is None else int(dim)
    num_layers = old.dit.num_layers if num_layers is None else int(num_layers)
    latent_hw = (old.latent_height, old.latent_width)
    if patch < 1 or any(n % patch for n in latent_hw):
        raise ValueError(f"patch={patch} must be >= 1 and divide the latent grid {latent_hw[0]}x{latent_hw[1]}")
    if dim < 1 or dim % old.dit.head_dim or dim % old.action.head_dim:
        raise ValueError(f"dim={dim} must be a positive multiple of the DiT's head width {old.dit.head_dim} and the "
                         f"action module's {old.action.head_dim}")
    if num_layers < 1:
        raise ValueError(f"num_layers={num_layers} must be >= 1")
    dit = dataclasses.replace(old.dit, dim=dim, num_heads=dim // old.dit.head_dim, num_layers=num_layers,
                              ffn_dim=old.dit.ffn_dim * dim // old.dit.dim,
                              patch_size=(old.dit.patch_size[0], patch, patch))
    action = dataclasses.replace(old.action, mouse_hidden_dim=dim, keyboard_hidden_dim=dim,
                                 num_heads=dim // old.action.head_dim,
                                 num_action_blocks=min(old.action.num_action_blocks, num_layers))
    return _save_under_fresh_dit(base, old.replace(dit=dit, action=action), dest, seed)


def _save_under_fresh_dit(base: WorldModel, cfg, dest: str | Path, seed: int) -> Path:
    """Write ``base``'s VAE and image encoder, unchanged, with the DiT ``cfg`` initialises at ``seed`` to ``dest``."""
    fresh, _, _ = WorldModel.from_config(cfg, seed=seed).params
    _, vae_state, encoder_state = base.params
    checkpoint.save(dest, cfg, dict(zip(COMPONENTS, (fresh, vae_state, encoder_state))))
    return Path(dest)


def install_default(model: str | Path, dest: str | Path | None = None, extra_files: tuple = (),
                    noise_warp: float | None = None, still_memory: float | None = None) -> Path:
    """Copy a stage's ``model/`` (weights, either layout, + config; a ``lineage.json`` beside them comes along)
    and ``extra_files`` (training log, eval summary) to the package's default-model directory, atomically
    (the env loads it when no checkpoint is named). ``noise_warp`` and ``still_memory`` (None keeps the model's)
    are written into the installed config's sampler (``SamplerConfig``; rollout settings: the weights are the
    same)."""
    model, dest = Path(model), Path(dest) if dest else DEFAULT_MODEL_DIR
    loaded = WorldModel.load(model)  # refuse to install anything that does not load
    settings = {name: float(value) for name, value in (("noise_warp", noise_warp), ("still_memory", still_memory))
                if value is not None}
    if settings:  # SamplerConfig and WorldModelConfig validate them (a clear error naming the field)
        loaded = loaded.with_sampler(dataclasses.replace(loaded.config.sampler, **settings))
    if (model / "lineage.json").is_file():
        extra_files = (model / "lineage.json", *extra_files)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.tmp-", dir=dest.parent))
    try:  # shipped in float16 storage (half the size; loads back as float32)
        checkpoint.save(tmp / "model", loaded.config, dict(zip(COMPONENTS, loaded.params)), storage_dtype="float16")
        for f in (tmp / "model").iterdir():
            f.replace(tmp / f.name)
        (tmp / "model").rmdir()
        for f in map(Path, extra_files):
            shutil.copy2(f, tmp / f.name)
        tmp.chmod(0o755)  # mkdtemp makes it private; the package directory is world-readable
        for f in tmp.iterdir():
            f.chmod(0o644)
        if dest.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{dest.name}.old-", dir=dest.parent))
            dest.replace(old / dest.name)
            tmp.replace(dest)
            shutil.rmtree(old)
        else:
            tmp.replace(dest)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return dest
