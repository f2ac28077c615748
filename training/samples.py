"""Generated-vs-ground-truth samples: the streaming rollout of a segment and the videos/sheets of it.

Alignment (``prepare_batch``, docs/model.md §4.3): in a segment, frame j is the observation after action j.
Latent frame 0 is frame 0 (the given first frame); the env step i >= 1 consumes actions
``[k(i-1)+1, k*i]`` and produces frames ``k(i-1)+1 .. k*i``. So a rollout of ``T = 1 + k*n`` frames
reproduces the ground truth's indices one for one.
"""

from __future__ import annotations

import logging
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from solaris_env.world_model.config import WorldModelConfig
from solaris_env.world_model.world_model import WorldModel

logger = logging.getLogger(__name__)


def rollout(model: WorldModel, obs_BTPHW3: np.ndarray, act_BTP25: np.ndarray, seed: int = 0,
            teacher_forced: bool = False, poses_BP5: np.ndarray | None = None) -> np.ndarray:
    """Autoregressive rollout from ``obs[:, 0]`` driven by the segment's actions.

    Args:
        model: the streaming world model.
        obs_BTPHW3: uint8 ground truth, T = 1 + k * n (only frame 0 is given to the model).
        act_BTP25: the segment's model action vectors.
        teacher_forced: after each step, hand the model the ground truth's latent frame (``ground_truth_latents``)
            as the frame the next step commits to its KV cache, instead of its own: every step is then a
            one-step prediction from the true past (the VAE decoder still streams the generated latents).
            A diagnostic: free rollout vs teacher-forced separates the drift from the per-step error.
        poses_BP5: the players' poses at frame 0 (x, y, z, yaw, pitch), which a partner-map model needs
            (``DiTConfig.partner_map``, docs/model.md §8.6); None for other models.
    Returns:
        generated uint8 (B, T, P, H, W, 3); frame 0 is the model's decode of latent frame 0.
    """
    k = model.frames_per_step
    t = obs_BTPHW3.shape[1]
    if (t - 1) % k:
        raise ValueError(f"segment length T={t} must be 1 + k*n for k={k}")
    truth = ground_truth_latents(model, obs_BTPHW3) if teacher_forced else None
    state = model.init(jnp.asarray(obs_BTPHW3[:, 0]), seed, first_actions=jnp.asarray(act_BTP25[:, 0]),
                       poses=None if poses_BP5 is None else jnp.asarray(poses_BP5, jnp.float32))
    out = [np.asarray(state.frame0_BPHW3)[:, None]]
    for i in range(1, 1 + (t - 1) // k):
        chunk = act_BTP25[:, k * (i - 1) + 1: k * i + 1]  # (B, k, P, 25)
        frames, state = model.step(state, jnp.asarray(np.swapaxes(chunk, 1, 2)))
        if truth is not None:
            state = state.replace(latent_BP1hwC=jnp.asarray(truth[:, :, i:i + 1], state.latent_BP1hwC.dtype))
        out.append(np.swapaxes(np.asarray(frames), 1, 2))  # (B, k, P, H, W, 3)
    return np.concatenate(out, axis=1)


def ground_truth_latents(model: WorldModel, obs_BTPHW3: np.ndarray, batch: int = 8) -> np.ndarray:
    """The latents the DiT is trained to predict for these frames (``prepare_batch``'s x0: the VAE's normalised
    posterior mean of each player's clip): f32 (B, P, F, h, w, C), F = 1 + (T - 1) / k."""
    from flax import nnx

    from solaris_env.world_model.world_model import frames_to_model

    graphdef, state = nnx.split(model.modules()[1])
    encode = jax.jit(lambda s, v: nnx.merge(graphdef, s).encode(frames_to_model(v)))
    b, t, p = obs_BTPHW3.shape[:3]
    videos = np.swapaxes(obs_BTPHW3, 1, 2).reshape((b * p, t) + obs_BTPHW3.shape[3:])  # (B*P, T, H, W, 3)
    lat = np.concatenate([np.asarray(encode(state, jnp.asarray(videos[i:i + batch])))
                          for i in range(0, len(videos), batch)])
    return lat.reshape((b, p) + lat.shape[1:]).astype(np.float32)


def vae_reconstructor(model: WorldModel, batch: int = 8):
    """-> ``reconstruct(obs uint8 (B, T, P, H, W, 3)) -> uint8`` of the same shape: the decode of the encoded
    ground truth, i.e. what a DiT that predicted every latent exactly would show (the ceiling of any rollout
    of the model). The encoder and decoder are jitted once; each new (videos, T) shape compiles once."""
    from flax import nnx

    from training.vae import make_reconstruct

    graphdef, params, rest = nnx.split(model.modules()[1], nnx.Param, ...)
    jitted = make_reconstruct(graphdef)

    def reconstruct(obs_BTPHW3: np.ndarray) -> np.ndarray:
        b, t, p = obs_BTPHW3.shape[:3]
        videos = np.swapaxes(obs_BTPHW3, 1, 2).reshape((b * p, t) + obs_BTPHW3.shape[3:])  # (B*P, T, H, W, 3)
        rec = np.concatenate([np.asarray(jitted(params, rest, jnp.asarray(videos[i:i + batch])))
                              for i in range(0, len(videos), batch)])
        return np.swapaxes(rec.reshape((b, p) + rec.shape[1:]), 1, 2)

    return reconstruct


def psnr_per_frame(a_BTPHW3: np.ndarray, b_BTPHW3: np.ndarray) -> np.ndarray:
    """PSNR (dB, peak 255) per (B, T, P) frame."""
    mse = np.mean((a_BTPHW3.astype(np.float64) - b_BTPHW3.astype(np.float64)) ** 2, axis=(-3, -2, -1))
    return 10.0 * np.log10(255.0 ** 2 / np.maximum(mse, 1e-10))


def side_by_side(gen_TPHW3: np.ndarray, gt_TPHW3: np.ndarray) -> np.ndarray:
    """(T, 2H, P*W, 3): generated on top, ground truth below, players left to right."""
    top = np.concatenate(list(np.moveaxis(gen_TPHW3, 1, 0)), axis=2)
    bottom = np.concatenate(list(np.moveaxis(gt_TPHW3, 1, 0)), axis=2)
    return np.concatenate([top, bottom], axis=1)


def write_mp4(path: Path, frames_THW3: np.ndarray, fps: int = 20, scale: int = 4) -> None:
    """Atomic mp4 (mp4v) of RGB frames, upscaled ``scale``x with nearest neighbour for viewing."""
    import cv2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames_THW3.shape[1:3]
    tmp = path.with_name(f".{path.stem}.tmp.mp4")
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w * scale, h * scale))
    for frame in frames_THW3:
        big = cv2.resize(frame, (w * scale, h * scale), interpolation=cv2.INTER_NEAREST)
        writer.write(cv2.cvtColor(big, cv2.COLOR_RGB2BGR))
    writer.release()
    tmp.replace(path)


def contact_sheet(gen_TPHW3: np.ndarray, gt_TPHW3: np.ndarray, every: int) -> np.ndarray:
    """A PNG-able grid: one column per ``every``-th frame; rows = (player p generated, player p truth)."""
    idx = np.arange(0, gen_TPHW3.shape[0], every)
    rows = []
    for p in range(gen_TPHW3.shape[1]):
        rows.append(np.concatenate(list(gen_TPHW3[idx, p]), axis=1))
        rows.append(np.concatenate(list(gt_TPHW3[idx, p]), axis=1))
    return np.concatenate(rows, axis=0)


def write_png(path: Path, image_HW3: np.ndarray, scale: int = 2) -> None:
    import cv2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w, _ = image_HW3.shape
    big = cv2.resize(image_HW3, (w * scale, h * scale), interpolation=cv2.INTER_NEAREST)
    tmp = path.with_name(f".{path.stem}.tmp.png")
    cv2.imwrite(str(tmp), cv2.cvtColor(big, cv2.COLOR_RGB2BGR))
    tmp.replace(path)


def bidirectional_sample(cfg: WorldModelConfig, dit, vae, encoder, obs_BTPHW3: np.ndarray, act_BTP25: np.ndarray,
                         seed: int = 0) -> np.ndarray:
    """Sample a whole clip at once with a bidirectional DiT (stages 1-2) and the N-step shifted schedule;
    -> uint8 (B, T, P, H, W, 3)."""
    from solaris_env.world_model import sampler
    from solaris_env.world_model.dit import from_stream, timesteps_to_stream
    from solaris_env.world_model.world_model import frames_to_uint8
    from training.step import prepare_batch

    batch = prepare_batch(vae, encoder, jnp.asarray(obs_BTPHW3), jnp.asarray(act_BTP25), cfg)
    x_shape = batch["x0"].shape

    def denoise(x, t):
        t_BPF = timesteps_to_stream(cfg, jnp.full((x_shape[0], cfg.num_players, x_shape[2]), t, jnp.float32))
        return dit.forward_bidirectional(x, t_BPF, batch["cond"], batch["context"], batch["mouse"], batch["keyboard"])

    x0 = sampler.sample_bidirectional(denoise, x_shape, jax.random.PRNGKey(seed),
                                      sampler.bidirectional_schedule(cfg.sampler))
    z = from_stream(cfg, x0)  # (B, P, F, h, w, C)
    b, p = z.shape[:2]
    video = vae.decode(z.reshape((b * p,) + z.shape[2:]))  # (B*P, T, H, W, 3)
    video = frames_to_uint8(video).reshape((b, p) + video.shape[1:])
    return np.asarray(jnp.swapaxes(video, 1, 2))


def write_stage_sample(stem: Path, cfg: WorldModelConfig, dit, vae, encoder, data_dir: Path, entry_point: str,
                       seed: int = 0, num_frames: int | None = None) -> dict:
    """Generate one held-out segment (duet/test, or vpt/test for one player) with the stage's model and
    write ``<stem>.mp4`` (generated over ground truth) and ``<stem>.json`` (PSNR); returns the summary, or
    None (a warning, nothing written) when no held-out episode holds ``num_frames`` frames or the model reads the
    partner map (its rollouts start from poses, which these batches do not carry)."""
    from training.duet import DuetDataset
    from training.samplers import (
        MultiplayerSegmentSampler,
        SinglePlayerSegmentSampler,
        next_batch,
    )
    from training.vpt import VPTDataset

    stem = Path(stem)
    if cfg.dit.partner_map:
        logger.warning("sample %s skipped: a partner-map model starts from the players' poses, which the sample "
                       "batches do not carry (benchmarks.eval_tasks and benchmarks.dream_fidelity pass them)", stem)
        return None
    k = cfg.frames_per_step
    num_frames = num_frames or 1 + k * 8
    size = (cfg.frame_height, cfg.frame_width)
    try:
        if cfg.num_players == 1:
            dataset = VPTDataset(data_dir, "test", obs_size=size)
            sampler = SinglePlayerSegmentSampler(dataset, num_frames, seed=seed + 20_000)
        else:
            dataset = DuetDataset(data_dir, "test", obs_size=size)
            sampler = MultiplayerSegmentSampler(dataset, num_frames, seed=seed + 20_000)
    except (ValueError, FileNotFoundError) as err:  # no held-out episode long enough: a sample is optional,
        logger.warning("sample %s skipped: %s", stem, err)  # never a reason to lose the stage's model
        return None
    raw = next_batch(dataset, sampler, 1)
    if entry_point == "forward_bidirectional":
        gen = bidirectional_sample(cfg, dit, vae, encoder, raw["obs"], raw["act"], seed)
    else:
        gen = rollout(WorldModel(cfg, dit, vae, encoder), raw["obs"], raw["act"], seed)
    write_mp4(stem.with_suffix(".mp4"), side_by_side(gen[0], raw["obs"][0]))
    summary = {"psnr_db": float(psnr_per_frame(gen, raw["obs"])[:, 1:].mean()), "frames": int(num_frames)}
    write_json(stem.with_suffix(".json"), summary)
    return summary


def write_json(path: Path, obj) -> None:
    """Atomic JSON file (a temporary name, then ``os.replace``)."""
    import json

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(obj, indent=1))
    tmp.replace(path)
