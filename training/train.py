"""The training stages as functions (``solaris-train`` calls them): VAE, then the paper's four stages.

    out/
      vae/               model/ (a WorldModel checkpoint: trained VAE + its latent statistics)
      sp/                model/ (stage 1: bidirectional, one player, on the VPT-layout export)
      mp-bidirectional/  model/ (stage 2: bidirectional, both players, player embedding learned)
      mp-causal/         model/ (stage 3: block-causal sliding window, Diffusion Forcing)
      self-forcing/      model/ (stage 4: Checkpointed Self Forcing with DMD; the final model)
    each stage dir also holds checkpoints/ (orbax: train state + data-sampler state), metrics.jsonl and
    samples/ (periodic generated-vs-ground-truth videos of both players).

Every stage starts from the previous stage's ``model/`` and resumes from its own latest checkpoint:
a run killed at any point (even ``kill -9``) and restarted continues with the same next loss, because
the train state, the optimiser state, the step RNG and the data sampler are all restored. Stage
hyper-parameters come from ``training/configs/<preset>.json``, one block per stage, each validated into its
dataclass with its defaults (``training.stage_config``; docs/training.md, "Stage configs").
"""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx

from solaris_env.world_model import checkpoint
from solaris_env.world_model.config import WorldModelConfig
from solaris_env.world_model.config import preset as make_preset
from solaris_env.world_model.dit import WorldDiT
from solaris_env.world_model.world_model import WorldModel
from training.checkpointing import Checkpointer, abstract_state
from training.duet import DuetDataset
from training.growing_data import growing_stream
from training.metrics import MetricsLogger
from training.samplers import (
    MultiplayerSegmentSampler,
    SinglePlayerSegmentSampler,
    next_batch,
)
from training.stage_config import (
    FlowStageConfig,
    SelfForcingStageConfig,
    TrainingConfig,
    VAEDecoderStageConfig,
    VAEStageConfig,
)
from training.step import (
    TrainState,
    check_finite,
    make_optimizer,
    make_train_step,
)
from training.surgery import relayout_decoder
from training.vpt import VPTDataset

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class FlowStage:
    """A flow-matching DiT stage (``step.make_train_step``): its DiT entry point, noise type, the stage it
    starts from and its data."""

    entry_point: str
    noise_type: str
    init_from: str
    single_player: bool  # stage 1: VPT-layout single-player clips, player embedding frozen at zero


FLOW_STAGES = {
    "sp": FlowStage("forward_bidirectional", "standard", "vae-decoder", single_player=True),
    "mp-bidirectional": FlowStage("forward_bidirectional", "standard", "sp", single_player=False),
    "mp-causal": FlowStage("forward_causal", "diffusion_forcing", "mp-bidirectional", single_player=False),
}


def stage_dir(out: str | Path, stage: str) -> Path:
    return Path(out) / stage


def model_dir(out: str | Path, stage: str) -> Path:
    return stage_dir(out, stage) / "model"


# ---------------------------------------------------------------------------------------------
# The loop shared by every stage
# ---------------------------------------------------------------------------------------------


@dataclass
class LoopSpec:
    stage: str
    steps: int
    log_every: int
    ckpt_every: int
    sample_every: int
    tokens_per_step: int  # for tokens/s (latent tokens of a batch seen by the DiT; pixels for the VAE)
    lr: float
    fsdp: bool = False  # shard parameters and optimiser state over the "data" mesh axis (else replicated)
    deadline: float | None = None  # epoch seconds: the last step is the one after which the next would end past it
    test_every: int = 0  # ``on_test`` this often and after the last step; 0: never


def run_loop(spec: LoopSpec, out: Path, state: Any, step_fn: Callable, draw_batch: Callable[[], Any],
             sampler, resume: bool, on_sample: Callable[[Any, int], None] | None = None,
             on_step: Callable[[Any, int], None] | None = None,
             on_test: Callable[[Any], float] | None = None) -> Any:
    """Train ``state`` to ``spec.steps`` updates with checkpoints, metrics and samples; resumable.

    ``step_fn(state, batch) -> (state, metrics)`` donates ``state``; ``draw_batch()`` draws from ``sampler``
    (its ``state_dict`` is checkpointed with the train state). With ``spec.deadline`` (``training.budget``), a
    step is the last one (logged, checkpointed, sampled) when it ends past the deadline or when, after its hooks
    (which may take long: a sprint's export, a held-out test), the next step would, predicted to take as long as
    the slowest of the last three (each from the end of the previous step's hooks to its own end). The first
    step, whose time is mostly the JIT compile, predicts nothing: it is the last when it, or its hooks, end past
    the deadline. At least one step runs. With a deadline every step is waited for before the clock is read
    (JAX dispatches asynchronously, and the host may run steps ahead of the device), so the host no longer
    prepares the next batch while the device computes. ``ckpt_every`` / ``sample_every`` <= 0: no checkpoints /
    samples at all (``training.sprint``, which never resumes). ``on_step(state, step)`` runs after every step.
    ``on_test(state)`` (the held-out loss) runs every ``spec.test_every`` steps and after the last; its value is
    logged as ``test_loss``. Returns the final state.
    """
    from training.distributed import make_mesh, shard_batch, shard_train_state

    directory = stage_dir(out, spec.stage)
    mesh = make_mesh()  # 1-D "data" axis over every device (of every host)
    state = shard_train_state(state, mesh, fsdp=spec.fsdp)
    ckpt = Checkpointer(directory / "checkpoints", keep=2)
    start = 0
    if resume and (latest := ckpt.latest_step()) is not None:
        state, extra = ckpt.restore(latest, abstract_state(state))
        sampler.load_state_dict(extra["sampler"])
        start = latest
        logger.info("%s: resumed at step %d", spec.stage, start)
    metrics_log = MetricsLogger(directory / "metrics.jsonl", resume_step=start)
    bar = metrics_log.progress(total=spec.steps, initial=start, desc=spec.stage)
    t_last, n_last = time.perf_counter(), start
    step_ended = None  # epoch seconds at which the previous step (and its hooks) ended
    recent_s: list[float] = []  # the last few steps' durations (draw + compute), hooks excluded

    def log(done: int, metrics) -> None:
        nonlocal t_last, n_last
        host = check_finite(metrics, done - 1)
        now = time.perf_counter()
        steps_per_s = (done - n_last) / max(now - t_last, 1e-9)
        t_last, n_last = now, done
        metrics_log.log(done, stage=spec.stage, lr=spec.lr, steps_per_s=steps_per_s,
                        tokens_per_s=steps_per_s * spec.tokens_per_step, **host)
        losses = {k: f"{v:.4f}" for k, v in host.items() if k.endswith("loss")}
        bar.set_postfix(**losses, steps_s=f"{steps_per_s:.2f}")

    def hooks(done: int, metrics, last: bool, ran: set) -> None:
        """The step's periodic hooks (and, when ``last``, the final ones), each at most once per step."""
        nonlocal t_last
        due = {"log": done % spec.log_every == 0 or last,
               "test": on_test is not None and spec.test_every > 0 and (done % spec.test_every == 0 or last),
               "ckpt": spec.ckpt_every > 0 and (done % spec.ckpt_every == 0 or last),
               "sample": on_sample is not None and spec.sample_every > 0 and (done % spec.sample_every == 0 or last)}
        for name in [n for n, d in due.items() if d and n not in ran]:
            ran.add(name)
            if name == "log":
                log(done, metrics)
            elif name == "test":
                t_test = time.perf_counter()
                metrics_log.log(done, stage=spec.stage, test_loss=on_test(state))
                t_last += time.perf_counter() - t_test  # the logged steps/s are the training's own
            elif name == "ckpt":
                ckpt.save(done, state, {"sampler": sampler.state_dict(), "stage": spec.stage})
            else:
                on_sample(state, done)

    for step in range(start, spec.steps):
        state, metrics = step_fn(state, shard_batch(draw_batch(), mesh))
        done = step + 1
        last = done == spec.steps
        if not last and spec.deadline is not None:
            jax.block_until_ready(metrics)  # dispatch is asynchronous: the clock must see the step done
            now = time.time()
            if step_ended is not None:
                recent_s = [*recent_s[-2:], now - step_ended]
            if now >= spec.deadline:  # the only rule for the first step, mostly the JIT compile
                last = True
        ran: set = set()
        hooks(done, metrics, last, ran)
        bar.update(1)
        if on_step is not None:
            on_step(state, done)
        # judged after the hooks, which may take long (an export, a held-out test): stop when the next step, predicted
        # to take as long as the slowest of the last three, would end past the deadline (after the first step, when
        # the hooks have taken it past the deadline)
        if not last and spec.deadline is not None and time.time() + max(recent_s, default=0.0) >= spec.deadline:
            last = True
            hooks(done, metrics, last, ran)  # the final log, test, checkpoint and sample not run above
        if last:
            if done != spec.steps:
                logger.warning("%s: time budget reached, stopping at step %d of %d", spec.stage, done, spec.steps)
            break
        step_ended = time.time()
    bar.close()
    metrics_log.close()
    ckpt.close()
    return state


# ---------------------------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------------------------


def local_batch_size(batch_size: int) -> int:
    """Rows this process loads: the global batch split over the processes (multi-host)."""
    if batch_size % jax.process_count():
        raise ValueError(f"batch_size {batch_size} must be a multiple of the process count {jax.process_count()}")
    return batch_size // jax.process_count()


def _ranks() -> dict:
    """Each process draws its own disjoint episodes (the samplers' rank partition)."""
    return {"rank": jax.process_index(), "num_ranks": jax.process_count()}


def duet_stream(data_dir: Path, cfg: WorldModelConfig, num_frames: int, seed: int, split: str = "train",
                rescan_s: float | None = None):
    """(dataset, sampler) of the Duet episodes; ``rescan_s`` (a stage-config key): the training split picks up
    the episodes written meanwhile every ``rescan_s`` seconds (``training.growing_data``)."""
    if rescan_s and split == "train":
        return growing_stream(data_dir, cfg, num_frames, seed, rescan_s, single_player=False, **_ranks())
    dataset = DuetDataset(data_dir, split, obs_size=(cfg.frame_height, cfg.frame_width), frame_cache_mb=4096)
    return dataset, MultiplayerSegmentSampler(dataset, num_frames, seed=seed, **(_ranks() if split == "train" else {}))


def vpt_stream(data_dir: Path, cfg: WorldModelConfig, num_frames: int, seed: int, split: str = "train",
               rescan_s: float | None = None):
    """(dataset, sampler) of single-player episodes: the VPT-layout export; with ``rescan_s``, each bot's
    view of the growing Duet episodes instead (``duet_stream``)."""
    if rescan_s and split == "train":
        return growing_stream(data_dir, cfg, num_frames, seed, rescan_s, single_player=True, **_ranks())
    if not (Path(data_dir) / "vpt" / split / "episodes_info.json").is_file():
        from solaris_env.engine.vpt_export import export_vpt
        export_vpt(data_dir, data_dir)  # links the Duet videos; single-player actions per bot
    dataset = VPTDataset(data_dir, split, obs_size=(cfg.frame_height, cfg.frame_width), frame_cache_mb=4096)
    return dataset, SinglePlayerSegmentSampler(dataset, num_frames, seed=seed, **(_ranks() if split == "train" else {}))


# ---------------------------------------------------------------------------------------------
# VAE
# ---------------------------------------------------------------------------------------------


def train_vae(out: str | Path, data_dir: str | Path, preset_name: str, sc: VAEStageConfig, seed: int = 0,
              steps: int | None = None, resume: bool = True, fsdp: bool = False,
              deadline: float | None = None, on_step: Callable | None = None) -> Path:
    """Train the preset's VAE on single-player clips of the Duet data; write ``out/vae/model``. ``deadline``
    as ``train_flow``'s; ``on_step`` as ``run_loop``'s."""
    from training import vae as V
    from training.samples import write_json, write_png

    out, data_dir = Path(out), Path(data_dir)
    steps = sc.steps if steps is None else steps  # 0: a linear patch codec as fitted
    cfg = make_preset(preset_name)
    cfg = cfg.replace(vae=dataclasses.replace(cfg.vae, latent_mean=(), latent_std=()))
    model = WorldModel.from_config(cfg, seed=seed)
    _, vae, _ = model.modules()
    sampler, draw, batch_size = single_player_clips(data_dir, cfg, sc, seed)
    if cfg.vae.codec == "linear_patch":
        # fitted in closed form; --steps 0 keeps the fit, a resumed run loads its checkpoint over it
        draws = max(1, sc.codec_fit_clips // (batch_size * cfg.num_players))
        fit = V.fit_linear_patch_codec(vae, (np.asarray(draw()) for _ in range(draws)))
        _log_json(stage_dir(out, "vae") / "codec_fit.jsonl", fit)
    tx = make_optimizer(sc.lr)
    graphdef, state = TrainState.create(vae, tx, rng=seed)
    step_fn = V.make_vae_train_step(graphdef, tx, V.VAELossWeights())
    test_clips = _fixed_clips(data_dir, cfg, sc.num_frames, sc.eval_clips, seed)
    reconstruct = V.make_reconstruct(graphdef)
    samples = stage_dir(out, "vae") / "samples"

    def on_sample(st, step):
        psnr = np.mean([V.psnr_uint8(np.asarray(reconstruct(st.params, st.rest, c)), c) for c in test_clips])
        _log_json(stage_dir(out, "vae") / "eval.jsonl", {"step": step, "test_psnr_db": float(psnr)})
        gt, rec = test_clips[0][:4], np.asarray(reconstruct(st.params, st.rest, test_clips[0][:4]))
        rows = [np.concatenate(list(clip), axis=1) for pair in zip(gt, rec) for clip in pair]  # truth over recon
        write_png(samples / f"recon_{step:06d}.png", np.concatenate(rows, axis=0), scale=1)

    spec = LoopSpec("vae", steps, sc.log_every, sc.ckpt_every, sc.sample_every,
                    tokens_per_step=batch_size * cfg.num_players * sc.num_frames * cfg.frame_height
                    * cfg.frame_width, lr=sc.lr, fsdp=fsdp, deadline=deadline)
    state = run_loop(spec, out, state, step_fn, draw, sampler, resume, on_sample, on_step)

    # the held-out PSNR and the latent statistics through one program, on chunks of the held-out clips' shape
    encode_reconstruct = V.make_encode_reconstruct(graphdef)
    chunk = len(test_clips[0])
    draws = max(1, sc.stats_clips // (batch_size * cfg.num_players))
    stats = np.concatenate([np.asarray(draw()) for _ in range(draws)])
    stats_chunks = [stats[i:i + chunk] for i in range(0, len(stats), chunk)]
    mean, std = V.latent_statistics([encode_reconstruct(state.params, state.rest, c)[1] for c in stats_chunks])
    recs = [np.asarray(encode_reconstruct(state.params, state.rest, c)[0]) for c in test_clips]
    test_psnr = float(np.mean([V.psnr_uint8(rec, c) for rec, c in zip(recs, test_clips)]))
    by_latent = V.psnr_per_latent_step(np.concatenate(recs), np.concatenate(test_clips), cfg.frames_per_step)
    final_cfg = cfg.replace(vae=dataclasses.replace(cfg.vae, latent_mean=mean, latent_std=std))
    trained_vae = nnx.merge(graphdef, state.params, state.rest)
    dit, _, encoder = model.modules()
    WorldModel(final_cfg, dit, trained_vae, encoder).save(model_dir(out, "vae"))
    write_json(stage_dir(out, "vae") / "summary.json",
                {"steps": int(state.step), "num_frames": sc.num_frames, "test_psnr_db": test_psnr,
                 "test_psnr_by_latent_db": by_latent, "latent_mean": mean, "latent_std": std})
    return model_dir(out, "vae")


def train_vae_decoder(out: str | Path, data_dir: str | Path, preset_name: str, sc: VAEDecoderStageConfig,
                      seed: int = 0, steps: int | None = None, resume: bool = True, fsdp: bool = False,
                      deadline: float | None = None, on_step: Callable | None = None) -> Path:
    """Fine-tune the decoder side of ``out/vae/model`` on long clips (``training.vae``: the encoder, the
    latent statistics and so every latent stay fixed); write ``out/vae-decoder/model``.

    The decoder takes the preset's decoder layout (``VAEConfig.decoder_layout``); when the trained VAE's
    differs, it is rebuilt in that layout, warm-started from every trained leaf of the same path and shape
    (``training.surgery.relayout_decoder``)."""
    from training import vae as V
    from training.samples import write_json

    out, data_dir = Path(out), Path(data_dir)
    steps = steps or sc.steps
    cfg, (dit, vae, encoder) = load_stage_model(out, "vae")
    if cfg.vae.codec != "wan":
        raise ValueError(f"the vae-decoder stage fine-tunes a convolutional decoder; {model_dir(out, 'vae')} is a "
                         f"{cfg.vae.codec!r} codec (VAEConfig.codec), which has none: skip this stage")
    target = cfg.vae.with_decoder_layout(make_preset(preset_name).vae)
    if target != cfg.vae:
        vae, copied = relayout_decoder(vae, target, seed)
        cfg = cfg.replace(vae=target)
        _log_json(stage_dir(out, "vae-decoder") / "relayout.jsonl", {"decoder_layout": target.decoder_layout(),
                                                                      "warm_started_leaves": copied})
    k = cfg.frames_per_step
    params = nnx.state(vae, nnx.Param)
    tx = V.make_decoder_optimizer(sc.lr, params)
    graphdef, state = TrainState.create(vae, tx, rng=seed)
    step_fn = V.make_decoder_train_step(graphdef, tx, V.VAELossWeights())
    sampler, draw, batch_size = single_player_clips(data_dir, cfg, sc, seed)
    test_clips = _fixed_clips(data_dir, cfg, sc.num_frames, sc.eval_clips, seed)
    reconstruct = V.make_reconstruct(graphdef)

    def test_psnr(st) -> dict:
        rec = np.concatenate([np.asarray(reconstruct(st.params, st.rest, c)) for c in test_clips])
        gt = np.concatenate(test_clips)
        return {"test_psnr_db": V.psnr_uint8(rec, gt), "test_psnr_by_latent_db": V.psnr_per_latent_step(rec, gt, k)}

    before = test_psnr(state)
    _log_json(stage_dir(out, "vae-decoder") / "eval.jsonl", {"step": 0, **before})

    def on_sample(st, step):
        _log_json(stage_dir(out, "vae-decoder") / "eval.jsonl", {"step": step, **test_psnr(st)})

    spec = LoopSpec("vae-decoder", steps, sc.log_every, sc.ckpt_every, sc.sample_every,
                    tokens_per_step=batch_size * cfg.num_players * sc.num_frames * cfg.frame_height
                    * cfg.frame_width, lr=sc.lr, fsdp=fsdp, deadline=deadline)
    state = run_loop(spec, out, state, step_fn, draw, sampler, resume, on_sample, on_step)
    after = test_psnr(state)
    WorldModel(cfg, dit, nnx.merge(graphdef, state.params, state.rest), encoder).save(model_dir(out, "vae-decoder"))
    write_json(stage_dir(out, "vae-decoder") / "summary.json",
               {"steps": int(state.step), "num_frames": sc.num_frames, "before": before, "after": after})
    return model_dir(out, "vae-decoder")


def single_player_clips(data_dir: Path, cfg: WorldModelConfig, sc: VAEDecoderStageConfig, seed: int):
    """(sampler, draw, local batch size) of the VAE stages: ``draw()`` gives B segments x P players as
    B*P single-player clips (B*P, T, H, W, 3) uint8."""
    dataset, sampler = duet_stream(data_dir, cfg, sc.num_frames, seed, rescan_s=sc.rescan_s)
    batch_size = local_batch_size(sc.batch_size)

    def draw():
        obs = next_batch(dataset, sampler, batch_size)["obs"]
        return jnp.asarray(np.swapaxes(obs, 1, 2).reshape((-1,) + obs.shape[1:2] + obs.shape[3:]))

    return sampler, draw, batch_size


def _fixed_clips(data_dir: Path, cfg: WorldModelConfig, num_frames: int, count: int, seed: int) -> list[np.ndarray]:
    """Held-out single-player clips (duet/test), the same every run: list of (n, T, H, W, 3) uint8."""
    dataset, sampler = duet_stream(data_dir, cfg, num_frames, seed + 10_000, split="test")
    obs = next_batch(dataset, sampler, max(1, count // cfg.num_players))["obs"]
    clips = np.swapaxes(obs, 1, 2).reshape((-1,) + obs.shape[1:2] + obs.shape[3:])
    return [clips[i:i + 8] for i in range(0, len(clips), 8)]


# ---------------------------------------------------------------------------------------------
# Flow-matching stages 1-3
# ---------------------------------------------------------------------------------------------


def load_stage_model(out: Path, stage: str, num_players: int | None = None) -> tuple[WorldModelConfig, tuple]:
    """(config, (dit, vae, image_encoder)) of a finished stage, the DiT rebuilt for ``num_players``."""
    path = model_dir(out, stage)
    if not (path / "config.json").is_file():
        raise FileNotFoundError(f"stage {stage!r} has no finished model at {path}; run `solaris-train {stage}` first")
    model = WorldModel.load(path)
    cfg = model.config if num_players is None else model.config.replace(num_players=num_players)
    dit, vae, encoder = model.modules()
    if num_players is not None:
        graphdef = nnx.split(nnx.eval_shape(lambda: WorldDiT(cfg, rngs=nnx.Rngs(0))))[0]
        dit = nnx.merge(graphdef, nnx.state(dit))
    return cfg, (dit, vae, encoder)


def _frozen_player_embedding(params) -> Any:
    """optax labels: the player embedding is frozen (stage 1 has none; it stays zero until stage 2)."""
    return jax.tree_util.tree_map_with_path(
        lambda path, _: "frozen" if any(getattr(k, "key", None) == "player_embed" for k in path) else "train", params)


def compile_ahead(step_fn, state: Any, batch_shapes: Any, fsdp: bool) -> threading.Thread:
    """Compile the jitted ``step_fn`` for ``run_loop``'s placement of ``state`` and of a batch shaped like
    ``batch_shapes`` on a background thread, which the caller joins before the first step; JAX keeps the
    executable, so that step compiles nothing. A DiT stage's train step compiles while its latent cache starts
    (on a GPU each took a minute or more, one after the other). A failure is logged, and the first step then
    compiles as before."""
    from training.distributed import batch_sharding, make_mesh, state_shardings

    mesh = make_mesh()
    placed = lambda x, sharding: jax.ShapeDtypeStruct(np.shape(x), x.dtype, sharding=sharding)
    abstract_state = jax.tree.map(placed, state, state_shardings(state, mesh, fsdp))
    abstract_batch = jax.tree.map(lambda x: placed(x, batch_sharding(mesh)), batch_shapes)

    def work():
        t0 = time.perf_counter()
        try:
            step_fn.lower(abstract_state, abstract_batch).compile()
            logger.info("train step compiled ahead in %.0f s", time.perf_counter() - t0)
        except Exception as err:  # noqa: BLE001 - the first step compiles it instead
            logger.warning("compiling the train step ahead failed (%s); the first step compiles it", err)

    thread = threading.Thread(target=work, name="compile-ahead", daemon=True)
    thread.start()
    return thread


def _stage_latent_clips(out: Path, data_dir: Path, cfg: WorldModelConfig, vae, dataset):
    """``dataset``'s latent clips, cached in ``out/latents`` under the stage's VAE."""
    from training.latents import latent_clips

    clips = latent_clips(dataset, cfg, vae, Path(out) / "latents", canonical_dir=Path(data_dir) / "duet")
    clips.with_poses = cfg.dit.partner_map > 0
    return clips


def clip_stream(out: Path, data_dir: Path, cfg: WorldModelConfig, vae,
                sc: FlowStageConfig | SelfForcingStageConfig, seed: int,
                single_player: bool, deadline: float | None = None):
    """(LatentClips, resumable sampler) of a DiT stage (its batches: ``latents.make_prepare_latents`` of
    ``clips.next_batch``); the latent cache of the
    stage's VAE lives in ``out/latents``. Without a ``deadline`` (epoch seconds) or a growing dataset it is
    built whole before training; with either, a short share of the stage's time is spent on it and the rest is
    encoded in the background while batches come from the ready episodes (``LatentClips.build_for_stage``).
    The caller ``close()``s the clips when the stage ends."""
    dataset, sampler = (vpt_stream if single_player else duet_stream)(data_dir, cfg, sc.num_frames, seed,
                                                                      rescan_s=sc.rescan_s)
    clips = _stage_latent_clips(out, data_dir, cfg, vae, dataset)
    t0 = time.perf_counter()
    n = clips.build_for_stage(deadline)
    logger.info("latent cache: %d videos ready in %.0f s (%s)", n, time.perf_counter() - t0, dict(clips.cache.stats))
    if deadline is not None or sc.rescan_s:
        clips.encode_in_background()
    return clips, sampler


def heldout_batches(out: Path, data_dir: Path, cfg: WorldModelConfig, vae, prepare: Callable, num_frames: int,
                    batch_size: int, count: int, seed: int, single_player: bool) -> list[dict]:
    """``count`` fixed DiT batches (``prepare``d) of the data's test split, drawn once with ``seed``; the latent
    cache of ``out/latents`` serves them as it serves training. Raises if the test split has no episodes."""
    why = (f"test_every > 0 needs held-out episodes, but {data_dir} has none in its test split (collect with "
           f"--test-fraction > 0, or set the stage's test_every to 0)")
    try:
        dataset, sampler = (vpt_stream if single_player else duet_stream)(data_dir, cfg, num_frames, seed,
                                                                          split="test")
    except FileNotFoundError as err:
        raise ValueError(f"{why}: {err}") from None
    if not dataset.valid_ids:
        raise ValueError(why)
    clips = _stage_latent_clips(out, data_dir, cfg, vae, dataset)
    try:
        clips.build_for_stage(None)
        return [prepare(clips.next_batch(sampler, batch_size, num_frames)) for _ in range(count)]
    finally:
        clips.close()


def train_flow(stage: str, out: str | Path, data_dir: str | Path, sc: FlowStageConfig, seed: int = 0,
               steps: int | None = None, resume: bool = True, fsdp: bool = False,
               deadline: float | None = None, on_model: Callable | None = None) -> Path:
    """Stages 1-3: flow matching of the DiT with the stage's entry point and noise type; ``deadline``
    (epoch seconds, ``training.budget``) may end the stage before ``steps``; ``on_model(step, make_model)``
    runs after every step, ``make_model()`` giving the current ``WorldModel`` (``training.sprint``)."""
    if stage not in FLOW_STAGES:
        raise ValueError(f"stage must be one of {sorted(FLOW_STAGES)}, got {stage!r}")
    fs = FLOW_STAGES[stage]
    out, data_dir = Path(out), Path(data_dir)
    steps = steps or sc.steps
    base_cfg = checkpoint.read_config(model_dir(out, fs.init_from))
    players = 1 if fs.single_player else make_preset(base_cfg.name).num_players
    cfg, (dit, vae, encoder) = load_stage_model(out, fs.init_from, num_players=players)
    ema_decay = sc.ema_decay
    adamw = make_optimizer(sc.lr)
    if fs.single_player:
        params = nnx.state(dit, nnx.Param)
        dit.player_embed.embedding.set_value(jnp.zeros_like(dit.player_embed.embedding[...]))
        tx = optax.multi_transform({"train": adamw, "frozen": optax.set_to_zero()}, _frozen_player_embedding(params))
    else:
        tx = adamw
    graphdef, state = TrainState.create(dit, tx, rng=seed, ema=ema_decay > 0)
    if sc.partner_dropout and not cfg.dit.partner_map:
        raise ValueError(f"partner_dropout={sc.partner_dropout} drops the cells the partner map marks; the model has "
                         "no partner map (dit.partner_map)")
    if sc.partner_weight != 1.0 and not cfg.dit.partner_map:
        raise ValueError(f"partner_weight={sc.partner_weight} weights the cells the partner map marks; the model has "
                         "no partner map (dit.partner_map)")
    train_step = make_train_step(graphdef, fs.entry_point, fs.noise_type, tx, ema_decay, sc.remat,
                                 sc.partner_dropout, cfg.mask_channels, sc.partner_weight)
    from training.latents import batch_spec, make_prepare_latents

    batch_size = local_batch_size(sc.batch_size)
    prepare = make_prepare_latents(cfg, vae, encoder)
    on_test = None
    if sc.test_every > 0:  # before any thread starts: a missing test split fails here
        from training.step import make_test_loss

        test_loss = make_test_loss(graphdef, fs.entry_point, fs.noise_type,
                                   heldout_batches(out, data_dir, cfg, vae, prepare, sc.num_frames, batch_size,
                                                   sc.test_batches, seed, fs.single_player))
        on_test = lambda st: float(test_loss(st.final_params, st.rest))
    ahead = compile_ahead(train_step, state, jax.eval_shape(prepare, batch_spec(cfg, batch_size, sc.num_frames)), fsdp)
    clips, sampler = clip_stream(out, data_dir, cfg, vae, sc, seed, fs.single_player, deadline)
    ahead.join()

    def draw():
        return prepare(clips.next_batch(sampler, batch_size, sc.num_frames))

    def on_sample(st, step):
        from training.samples import write_stage_sample
        write_stage_sample(stage_dir(out, stage) / "samples" / f"step_{step:06d}", cfg,
                           nnx.merge(graphdef, st.final_params, st.rest), vae, encoder, data_dir, fs.entry_point, seed)

    frames = cfg.vae.latent_frames(sc.num_frames)
    spec = LoopSpec(stage, steps, sc.log_every, sc.ckpt_every, sc.sample_every,
                    tokens_per_step=batch_size * cfg.num_players * frames * cfg.tokens_per_frame, lr=sc.lr,
                    fsdp=fsdp, deadline=deadline, test_every=sc.test_every)

    def current(st) -> WorldModel:
        return WorldModel(cfg, nnx.merge(graphdef, st.final_params, st.rest), vae, encoder)

    try:
        state = run_loop(spec, out, state, train_step, draw, sampler, resume, on_sample, _model_hook(on_model, current),
                         on_test)
    finally:
        clips.close()  # the background encoder, if any
    current(state).save(model_dir(out, stage))
    return model_dir(out, stage)


def _model_hook(on_model: Callable | None, current: Callable[[Any], WorldModel]) -> Callable | None:
    """``run_loop``'s ``on_step`` from a stage's ``on_model(step, make_model)`` and its state -> model."""
    if on_model is None:
        return None
    return lambda st, step: on_model(step, lambda: current(st))


# ---------------------------------------------------------------------------------------------
# Stage 4: Checkpointed Self Forcing with DMD
# ---------------------------------------------------------------------------------------------


def train_self_forcing(out: str | Path, data_dir: str | Path, sc: SelfForcingStageConfig, seed: int = 0,
                       steps: int | None = None, resume: bool = True, fsdp: bool = False,
                       deadline: float | None = None, on_model: Callable | None = None) -> Path:
    """Stage 4: generator from mp-causal, critic and frozen teacher from mp-bidirectional (docs/model.md
    §6.3); ``steps`` counts iterations (a critic update each, a generator update every 5th). The
    generator mode is ``sc.generator``: "checkpointed" or "naive". ``deadline`` and ``on_model`` as
    ``train_flow``'s."""
    from training import self_forcing as SF
    from training.latents import make_prepare_latents

    out, data_dir = Path(out), Path(data_dir)
    steps = steps or sc.steps
    cfg, (generator, vae, encoder) = load_stage_model(out, "mp-causal")
    _, (teacher, _, _) = load_stage_model(out, "mp-bidirectional")
    critic = teacher  # both start from stage 2; create_self_forcing_state gives each its own copy
    sf_cfg = SF.SelfForcingConfig(generator_lr=sc.generator_lr, critic_lr=sc.critic_lr)
    gen_tx, critic_tx = SF.make_optimizers(sf_cfg)
    graphs, state = SF.create_self_forcing_state(generator, critic, teacher, gen_tx, critic_tx, rng=seed)
    del critic, teacher
    make_generator_step = {"checkpointed": SF.make_checkpointed_generator_step,
                           "naive": SF.make_naive_generator_step}[sc.generator]
    iteration = SF.make_iteration(make_generator_step(graphs, gen_tx, sf_cfg),
                                  SF.make_critic_step(graphs, critic_tx, sf_cfg), sf_cfg)
    prepare = make_prepare_latents(cfg, vae, encoder)
    clips, sampler = clip_stream(out, data_dir, cfg, vae, sc, seed, single_player=False, deadline=deadline)
    batch_size = local_batch_size(sc.batch_size)

    def draw():
        return SF.conditioning_batch(prepare(clips.next_batch(sampler, batch_size, sc.num_frames)))

    def on_sample(st, step):
        from training.samples import write_stage_sample
        dit = nnx.merge(graphs.generator, st.generator.params, st.generator.rest)
        write_stage_sample(stage_dir(out, "self-forcing") / "samples" / f"step_{step:06d}", cfg, dit, vae, encoder,
                           data_dir, "forward_causal", seed)

    frames = cfg.vae.latent_frames(sc.num_frames)
    spec = LoopSpec("self-forcing", steps, sc.log_every, sc.ckpt_every, sc.sample_every,
                    tokens_per_step=batch_size * cfg.num_players * frames * cfg.tokens_per_frame,
                    lr=sf_cfg.generator_lr, fsdp=fsdp, deadline=deadline)

    def current(st) -> WorldModel:
        return WorldModel(cfg, nnx.merge(graphs.generator, st.generator.params, st.generator.rest), vae, encoder)

    try:
        state = run_loop(spec, out, state, iteration, draw, sampler, resume, on_sample, _model_hook(on_model, current))
    finally:
        clips.close()  # the background encoder, if any
    current(state).save(model_dir(out, "self-forcing"))
    return model_dir(out, "self-forcing")


# ---------------------------------------------------------------------------------------------
# Small file helpers
# ---------------------------------------------------------------------------------------------


def call_stage(stage: str, out, data, config: TrainingConfig, **kw) -> Path:
    """Run ``stage``'s function of this module on its block of ``config`` with keyword arguments ``kw``
    (seed, steps, resume, fsdp, deadline, on_model: see the functions); ``solaris-train`` and the sprint call it."""
    sc = config.stages.get(stage)
    if sc is None:
        raise ValueError(f"the stage config of preset {config.preset!r} has no {stage!r} block; it has "
                         f"{sorted(config.stages)}")
    if stage == "vae":
        return train_vae(out, data, config.preset, sc, **kw)
    if stage == "vae-decoder":
        return train_vae_decoder(out, data, config.preset, sc, **kw)
    if stage in FLOW_STAGES:
        return train_flow(stage, out, data, sc, **kw)
    return train_self_forcing(out, data, sc, **kw)


def _log_json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        f.write(json.dumps(obj) + "\n")
