"""The refiner stage: train the temporal refiner (``solaris_env/world_model/refiner.py``) of a finished model.

    solaris-train refiner --data DATA --out OUT    # OUT/self-forcing/model -> OUT/refiner/model

The refiner sits after the VAE decoder and blends each decoded frame with the previous output frame, so it
must learn how far the model's OWN decodes can be trusted: where they change although the world did not
(a freshly sampled latent every step), where they stay put although it moved. So it trains on the model's
rollouts, never on ground-truth latents:

1. Rollouts (``make_rollouts``): ``rollout_parts`` x ``segments_per_part`` training segments of ``num_frames``
   frames, each rolled out from its first frame with its true actions by the model without a refiner, stored
   with the ground truth in ``OUT/refiner/rollouts/part_XXXX.npz`` (written atomically; a resumed run keeps
   the finished parts; part p samples its segments with seed ``seed + p``).
2. Training: per player sequence, the gates of the whole clip from the decoded frames and actions, the blend
   from the true first frame (as the env starts), loss (``LOSSES``) over frames 1..T-1 against the ground
   truth (frames in [-1, 1]): ``mse``, the mean squared error, or ``log_mse``, the mean over frames of each
   frame's log MSE, i.e. minus the mean per-frame PSNR up to constants -- the aggregation ``training.evaluate``
   scores, which counts a nearly unchanged frame rendered exactly as much as a moving one rendered well (a
   frame's MSE is floored at ``LOG_MSE_FLOOR``, a PSNR of ~56 dB); AdamW, checkpoints, metrics and resume as
   every stage (``train.run_loop``). Batches are drawn by step number (``RolloutSampler``), so a resumed run
   draws the same batches.
3. ``OUT/refiner/model``: the model with the trained refiner (``with_refiner``).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx

from solaris_env.world_model.config import RefinerConfig
from solaris_env.world_model.refiner import Refiner
from solaris_env.world_model.vae import CausalVideoVAE
from solaris_env.world_model.world_model import WorldModel, frames_to_model
from training.step import TrainState, apply_gradients

logger = logging.getLogger(__name__)

LOSSES = ("mse", "log_mse")
LOG_MSE_FLOOR = 1e-5  # per-frame MSE in the [-1, 1] range: 1/6 of one grey level squared
ROLLOUT_KEYS = ("obs", "act", "gen")  # ground truth (B, T, P, H, W, 3) uint8, actions (B, T, P, 25), decodes


def with_refiner(model: WorldModel, refiner: RefinerConfig | None, seed: int = 0) -> WorldModel:
    """The same DiT, VAE and image encoder with the refiner ``refiner`` (its gate freshly initialised, or
    kept when ``model`` already has one of the same config) or without one (None or width 0). Only the gate
    is initialised; every other VAE leaf is ``model``'s own."""
    refiner = refiner or RefinerConfig()
    cfg = model.config.replace(vae=dataclasses.replace(model.config.vae, refiner=refiner))
    dit, vae, encoder = model.modules()
    graphdef, _ = nnx.split(nnx.eval_shape(lambda: CausalVideoVAE(cfg.vae, rngs=nnx.Rngs(0))))
    keep_refiner = model.config.vae.refiner == refiner
    values = [(path, v) for path, v in nnx.to_flat_state(nnx.state(vae)) if path[0] != "refiner" or keep_refiner]
    if refiner.enabled and not keep_refiner:
        fresh = nnx.state(Refiner(refiner, rngs=nnx.Rngs(seed)))
        values += [(("refiner",) + tuple(path), v) for path, v in nnx.to_flat_state(fresh)]
    return WorldModel(cfg, dit, nnx.merge(graphdef, nnx.from_flat_state(values)), encoder)


# ---------------------------------------------------------------------------------------------
# 1. Rollouts of the model
# ---------------------------------------------------------------------------------------------


def _atomic_savez(path: Path, **arrays) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".npz", dir=path.parent)
    os.close(fd)
    try:
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def make_rollouts(model: WorldModel, data_dir: str | Path, directory: str | Path, parts: int, segments: int,
                  num_frames: int, seed: int) -> list[Path]:
    """Write the missing ``part_XXXX.npz`` of ``parts`` (module docstring, 1.); returns every part's path.
    ``model`` must have no refiner (its frames are the decodes the refiner will see)."""
    from training.duet import DuetDataset
    from training.samplers import MultiplayerSegmentSampler, next_batch
    from training.samples import rollout

    if model.config.vae.refiner.enabled:
        raise ValueError("make_rollouts needs the model without its refiner (with_refiner(model, None))")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = [directory / f"part_{p:04d}.npz" for p in range(parts)]
    todo = [p for p, path in enumerate(paths) if not path.is_file()]
    if not todo:
        return paths
    cfg = model.config
    dataset = DuetDataset(data_dir, "train", obs_size=(cfg.frame_height, cfg.frame_width))
    for p in todo:
        sampler = MultiplayerSegmentSampler(dataset, num_frames, seed=seed + p)
        seg = next_batch(dataset, sampler, segments, num_frames)
        gen = rollout(model, seg["obs"], seg["act"], seed + p)
        _atomic_savez(paths[p], obs=seg["obs"], act=seg["act"].astype(np.float32), gen=gen)
        logger.info("refiner: rollout part %d/%d written (%d segments of %d frames)", p + 1, parts, segments,
                    num_frames)
    return paths


def load_rollouts(paths: list[Path]) -> dict[str, np.ndarray]:
    """The parts as player sequences: obs/gen (N, T, H, W, 3) uint8, act (N, T, 25) f32, N = segments x P."""
    out = {key: [] for key in ROLLOUT_KEYS}
    for path in paths:
        with np.load(path) as part:
            for key in ROLLOUT_KEYS:
                x = np.swapaxes(part[key], 1, 2)  # (B, P, T, ...)
                out[key].append(x.reshape((-1,) + x.shape[2:]))
    return {key: np.concatenate(v) for key, v in out.items()}


class RolloutSampler:
    """Batch n = ``batch`` distinct sequences drawn with ``default_rng((seed, n))``: a pure function of the
    step, so the checkpointed state is just the step."""

    def __init__(self, num_sequences: int, batch: int, seed: int):
        if not 0 < batch <= num_sequences:
            raise ValueError(f"refiner batch_size must be in [1, {num_sequences}] (the rollouts' player "
                             f"sequences), got {batch}")
        self.num, self.batch, self.seed, self.step = num_sequences, batch, seed, 0

    def next_indices(self) -> np.ndarray:
        rng = np.random.default_rng((self.seed, self.step))
        self.step += 1
        return np.sort(rng.choice(self.num, self.batch, replace=False))

    def state_dict(self) -> dict:
        return {"step": self.step}

    def load_state_dict(self, state: dict) -> None:
        self.step = int(state["step"])


# ---------------------------------------------------------------------------------------------
# 2. The objective
# ---------------------------------------------------------------------------------------------


def refiner_loss(graphdef: nnx.GraphDef, params, rest, batch: dict, loss: str = "mse") -> jax.Array:
    """The loss of the refined frames 1..T-1 (module docstring, 2.); ``batch`` holds one clip per player
    sequence: obs/gen (N, T, H, W, 3) uint8, act (N, T, 25)."""
    refiner = nnx.merge(graphdef, params, rest)
    truth, decoded = frames_to_model(batch["obs"]), frames_to_model(batch["gen"])
    refined = refiner(decoded[:, 1:], decoded[:, 0], truth[:, 0], batch["act"][:, 1:])
    mse_NT = jnp.mean(jnp.square(refined - truth[:, 1:]), axis=(-3, -2, -1))
    if loss == "mse":
        return jnp.mean(mse_NT)
    if loss == "log_mse":
        return jnp.mean(jnp.log10(mse_NT + LOG_MSE_FLOOR))
    raise ValueError(f"refiner loss must be one of {LOSSES}, got {loss!r}")


def make_refiner_step(graphdef: nnx.GraphDef, tx: optax.GradientTransformation, loss: str = "mse") -> Callable:
    """-> jitted ``step(state, batch) -> (state, metrics)`` (``state`` donated)."""
    if loss not in LOSSES:
        raise ValueError(f"refiner loss must be one of {LOSSES}, got {loss!r}")

    def step(state: TrainState, batch: dict) -> tuple[TrainState, dict]:
        value, grads = jax.value_and_grad(lambda p: refiner_loss(graphdef, p, state.rest, batch, loss))(state.params)
        return apply_gradients(state, value, grads, tx, 0.0)

    return jax.jit(step, donate_argnums=(0,))
