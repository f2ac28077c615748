"""training/checkpointing.py: orbax train-state checkpoints with a JSON ``extra``.

Unit tests use a small NNX MLP's TrainState. The kill test trains the ``test``-preset DiT with
``make_train_step`` on batches drawn by a real ``MultiplayerSegmentSampler`` from a tiny Duet dataset, in a
subprocess that SIGKILLs itself in the middle of a checkpoint save (after the previous checkpoint was
written), then resumes in a fresh process: the resumed run must redo exactly the same losses and batches.
This file is also that subprocess's script (``python test_checkpointing.py worker ...``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
# O0 halves the CPU time of compiling the DiT's train step; the compilation cache lets the resumed process
# load the killed one's executable. Both processes run with the same flags.
XLA_FLAGS = "--xla_backend_optimization_level=0"
KILL_STEP, TOTAL_STEPS, CKPT_EVERY = 6, 8, 2  # saves at 2, 4, 6 (killed mid-save), resumed saves 6, 8
KEEP = 2
BATCH, CLIP_FRAMES = 2, 5  # 5 frames -> 2 latent frames in the test preset
EPISODE_RECORDS = 24


# ---------------------------------------------------------------------------------------------
# Unit tests on a small module
# ---------------------------------------------------------------------------------------------


def _mlp_state(seed: int = 0, width: int = 8, updates: int = 2):
    """A TrainState of a 2-layer MLP after ``updates`` AdamW updates (non-trivial moments and count)."""
    import jax
    import jax.numpy as jnp
    from flax import nnx

    from training.step import TrainState, make_optimizer

    class MLP(nnx.Module):
        def __init__(self, rngs):
            self.a = nnx.Linear(4, width, rngs=rngs)
            self.b = nnx.Linear(width, 3, rngs=rngs)

    tx = make_optimizer(1e-2)
    _, state = TrainState.create(MLP(nnx.Rngs(seed)), tx, rng=seed)
    for i in range(updates):
        grads = jax.tree.map(lambda p, i=i: jnp.sin(p * (i + 1)) + 0.1, state.params)
        upd, opt_state = tx.update(grads, state.opt_state, state.params)
        state = state.replace(params=jax.tree.map(lambda p, u: p + u, state.params, upd), opt_state=opt_state,
                              step=state.step + 1)
    return state


def _assert_bit_exact(restored, original):
    import jax

    assert jax.tree.structure(restored) == jax.tree.structure(original)
    for r, o in zip(jax.tree.leaves(restored), jax.tree.leaves(original)):
        assert r.dtype == o.dtype and r.shape == o.shape
        np.testing.assert_array_equal(np.asarray(r), np.asarray(o))


def test_round_trip_bit_exact(tmp_path):
    import jax

    from training.checkpointing import Checkpointer, abstract_state

    state = _mlp_state()
    extra = {"sampler": {"step": 12, "seed": 3}, "stage": "mp-causal", "config": {"lr": 1e-4, "dims": [1, 2]}}
    with Checkpointer(tmp_path / "ckpt") as ckpt:
        assert ckpt.latest_step() is None
        ckpt.save(7, state, extra)
        assert ckpt.latest_step() == 7
        restored, extra_back = ckpt.restore(7, jax.eval_shape(lambda: state))
    _assert_bit_exact(restored, state)
    assert type(restored) is type(state) and int(restored.step) == 2
    assert extra_back == extra
    # a new Checkpointer on the same directory (a new process) sees and restores it too
    with Checkpointer(tmp_path / "ckpt") as again:
        assert again.latest_step() == 7
        _assert_bit_exact(again.restore(7, state)[0], state)  # a concrete state works as the target too
        placed, _ = again.restore(7, abstract_state(state))
        assert [x.sharding for x in jax.tree.leaves(placed)] == [x.sharding for x in jax.tree.leaves(state)]


def test_round_trip_with_the_parameter_ema(tmp_path):
    """A stage that keeps an EMA of its parameters checkpoints it with the rest (resume restores it)."""
    import jax

    from training.checkpointing import Checkpointer

    state = _mlp_state()
    state = state.replace(ema=jax.tree.map(lambda p: 0.5 * p + 0.25, state.params))
    with Checkpointer(tmp_path) as ckpt:
        ckpt.save(3, state, {"stage": "mp-causal"})
        restored, _ = ckpt.restore(3, jax.eval_shape(lambda: state))
    _assert_bit_exact(restored, state)
    assert restored.final_params is restored.ema


def test_round_trip_several_train_states(tmp_path):
    """Self Forcing keeps a generator and a critic (each with its own optimiser state) in one checkpoint."""
    import jax

    from training.checkpointing import Checkpointer

    state = {"generator": _mlp_state(0), "critic": _mlp_state(1, width=6, updates=3)}
    with Checkpointer(tmp_path) as ckpt:
        ckpt.save(240, state, {"stage": "self-forcing"})
        restored, extra = ckpt.restore(240, jax.eval_shape(lambda: state))
    _assert_bit_exact(restored, state)
    assert extra == {"stage": "self-forcing"}


def test_keep_prunes_old_checkpoints(tmp_path):
    from training.checkpointing import Checkpointer

    state = _mlp_state(updates=0)
    with Checkpointer(tmp_path / "a", keep=2) as ckpt:
        for step in (1, 2, 3, 4, 5):
            ckpt.save(step, state, {"step": step})
        assert ckpt.all_steps() == [4, 5]
    assert sorted(p.name for p in (tmp_path / "a").iterdir() if not p.name.startswith(".")) == ["4", "5"]
    with Checkpointer(tmp_path / "b", keep=1, keep_period=3) as ckpt:
        for step in range(1, 8):
            ckpt.save(step, state)
        assert ckpt.all_steps() == [3, 6, 7]


def test_mismatched_tree_names_the_keys(tmp_path):
    import jax

    from training.checkpointing import Checkpointer, CheckpointMismatchError

    state = _mlp_state()
    with Checkpointer(tmp_path) as ckpt:
        ckpt.save(1, state)
        wider = _mlp_state(width=9)
        with pytest.raises(CheckpointMismatchError, match=r"params\.a\.kernel\.value: saved \(4, 8\) float32, "
                                                          r"expected \(4, 9\) float32"):
            ckpt.restore(1, jax.eval_shape(lambda: wider))
        with pytest.raises(CheckpointMismatchError, match=r"missing from the checkpoint: \['critic\..*unexpected "
                                                          r"key\(s\) in the checkpoint: \['opt_state"):
            ckpt.restore(1, {"critic": state, "generator": state})
        with pytest.raises(FileNotFoundError, match=r"no checkpoint step 2 .*complete steps: \[1\]"):
            ckpt.restore(2, state)


def test_bad_input_is_refused(tmp_path):
    from training.checkpointing import Checkpointer

    state = _mlp_state(updates=0)
    with pytest.raises(ValueError, match="keep must be >= 1"):
        Checkpointer(tmp_path, keep=0)
    with Checkpointer(tmp_path) as ckpt:
        with pytest.raises(ValueError, match=r"JSON-serialisable.*offending keys \['sampler'\]"):
            ckpt.save(1, state, {"sampler": np.arange(3), "stage": "sp"})
        assert ckpt.latest_step() is None  # nothing half-written
        ckpt.save(1, state, {})
        with pytest.raises(ValueError, match="step 1 already exists"):
            ckpt.save(1, state, {})


def test_leftover_temporary_directory_is_ignored_and_cleaned(tmp_path):
    """What an interrupted save leaves (a complete-looking ``<step>.orbax-checkpoint-tmp-*`` directory, even
    with orbax's commit file) is never a checkpoint, and the next Checkpointer removes it."""
    import shutil

    from training.checkpointing import Checkpointer

    state = _mlp_state()
    with Checkpointer(tmp_path) as ckpt:
        ckpt.save(3, state)
    shutil.copytree(tmp_path / "3", tmp_path / "5.orbax-checkpoint-tmp-1700000000000")
    with Checkpointer(tmp_path) as ckpt:
        assert ckpt.latest_step() == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["3"]


# ---------------------------------------------------------------------------------------------
# Kill -9 and resume
# ---------------------------------------------------------------------------------------------


def _write_tiny_duet(root: Path, num_episodes: int = 2) -> None:
    """Duet layout with ``num_episodes`` episodes of EPISODE_RECORDS records per bot: moving-square videos
    (32x32 mp4v) and random Mineflayer actions; Bravo's renderTime lags Alpha's by 7 ms."""
    import cv2

    from solaris_env.spaces import CAMERA_KEY, RECORDED_ACTION_KEYS

    split = root / "duet" / "train"
    split.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for ep in range(num_episodes):
        for bot, lag in (("Alpha", 0), ("Bravo", 7)):
            stem = f"batch_0_{ep:06d}_{bot}_instance_000"
            writer = cv2.VideoWriter(str(split / f"{stem}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 20, (32, 32))
            records = []
            for t in range(EPISODE_RECORDS):
                frame = np.full((32, 32, 3), (40 * ep + 60, 5 * t, 120 + lag * 10), np.uint8)
                x = (3 * t + 11 * ep) % 24
                frame[8:16, x:x + 8] = 255
                writer.write(frame)
                action = {k: bool(rng.integers(2)) for k in RECORDED_ACTION_KEYS if k != CAMERA_KEY}
                action[CAMERA_KEY] = [float(v) for v in rng.normal(0, 0.05, 2)]
                records.append({"action": action, "renderTime": 1_000_000 + 50 * t + lag})
            writer.release()
            (split / f"{stem}.json").write_text(json.dumps(records))


@pytest.fixture(scope="module")
def duet_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("duet")
    _write_tiny_duet(root)
    return root


def _run_worker(run_dir: Path, data_root: Path, cache_dir: Path, kill_at_save: int | None):
    env = dict(os.environ, XLA_FLAGS=XLA_FLAGS, JAX_PLATFORMS="cpu", JAX_COMPILATION_CACHE_DIR=str(cache_dir),
               JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0", JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")
    args = [sys.executable, __file__, "worker", str(run_dir), str(data_root)]
    if kill_at_save is not None:
        args.append(str(kill_at_save))
    return subprocess.run(args, check=False, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.slow  # two processes; ~30 s of CPU (one DiT train-step compile, reused through JAX's cache)
def test_kill9_mid_save_then_resume_gives_the_same_next_losses(tmp_path, duet_root):
    from training.checkpointing import Checkpointer
    from training.metrics import read_metrics

    run_dir, cache = tmp_path / "run", tmp_path / "jax_cache"
    killed = _run_worker(run_dir, duet_root, cache, kill_at_save=KILL_STEP)
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-3000:]
    before = read_metrics(run_dir / "metrics.jsonl")  # the uninterrupted trajectory, steps 1..KILL_STEP
    assert [r["step"] for r in before] == list(range(1, KILL_STEP + 1))
    # the save of KILL_STEP was interrupted after orbax wrote everything but the final rename
    leftovers = [p.name for p in (run_dir / "checkpoints").iterdir() if ".orbax-checkpoint-tmp" in p.name]
    assert [name.split(".")[0] for name in leftovers] == [str(KILL_STEP)], leftovers
    assert (run_dir / "killed_during_save.txt").read_text() == str(KILL_STEP)

    resumed = _run_worker(run_dir, duet_root, cache, kill_at_save=None)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    info = json.loads((run_dir / "resumed.json").read_text())
    assert info["resumed_from"] == KILL_STEP - CKPT_EVERY  # the interrupted save is not a checkpoint
    assert info["sampler_step_after_restore"] == (KILL_STEP - CKPT_EVERY) * BATCH

    after = read_metrics(run_dir / "metrics.jsonl")
    assert [r["step"] for r in after] == list(range(1, TOTAL_STEPS + 1))  # no duplicates, no gaps
    for old, new in zip(before, after):
        if old["step"] > info["resumed_from"]:
            assert new["batch_sha1"] == old["batch_sha1"], (old, new)  # the data stream resumed
            assert new["segments"] == old["segments"]
            np.testing.assert_allclose(new["loss"], old["loss"], rtol=0, atol=1e-6)
        else:
            assert new == old  # kept as written
    with Checkpointer(run_dir / "checkpoints", keep=KEEP) as ckpt:
        assert ckpt.all_steps() == [TOTAL_STEPS - CKPT_EVERY, TOTAL_STEPS]
    assert not [p for p in (run_dir / "checkpoints").iterdir() if ".orbax-checkpoint-tmp" in p.name]
    # the resumed process ran the very program the killed one compiled (restored shardings == fresh ones)
    assert len([p for p in cache.iterdir() if "train_step" in p.name]) == 1, sorted(p.name for p in cache.iterdir())


# ---------------------------------------------------------------------------------------------
# Worker (runs in the subprocess)
# ---------------------------------------------------------------------------------------------


def _features(raw: dict, cfg) -> dict:
    """Clips -> DiT inputs without the VAE / image encoder (a fixed pooling + projection of the frames; the
    real actions through the model's own padding): cheap, deterministic, and different for each clip."""
    import jax.numpy as jnp

    from solaris_env.world_model.action_module import left_pad_actions
    from solaris_env.world_model.dit import to_stream

    obs = raw["obs"].astype(np.float32) / 127.5 - 1.0  # (B, T, P, H, W, 3)
    b, t, p, height, width, _ = obs.shape
    f, h, w = cfg.vae.latent_frames(t), cfg.latent_height, cfg.latent_width
    pooled = obs[:, :: max(1, (t - 1) // max(1, f - 1))][:, :f]  # (B, F, P, H, W, 3)
    pooled = pooled.reshape(b, f, p, h, height // h, w, width // w, 3).mean(axis=(4, 6)).transpose(0, 2, 1, 3, 4, 5)
    proj = np.random.default_rng(123)
    x0 = pooled @ proj.normal(size=(3, cfg.latent_channels)).astype(np.float32)
    cond = pooled[:, :, :1].repeat(f, axis=2) @ proj.normal(size=(3, cfg.in_channels - cfg.out_channels)).astype(
        np.float32)
    first = pooled[:, :, 0].reshape(b, p, -1)
    context = (first @ proj.normal(size=(first.shape[-1], cfg.image_encoder.num_tokens * cfg.context_width))
               .astype(np.float32) / np.sqrt(first.shape[-1])).reshape(b, p, cfg.image_encoder.num_tokens, -1)
    actions = left_pad_actions(jnp.asarray(raw["act"]).transpose(0, 2, 1, 3), cfg.action_left_padding)
    kb = cfg.action.keyboard_dim
    return {"x0": to_stream(cfg, jnp.asarray(x0)), "cond": to_stream(cfg, jnp.asarray(cond)),
            "context": to_stream(cfg, jnp.asarray(context)), "mouse": to_stream(cfg, actions[..., kb:]),
            "keyboard": to_stream(cfg, actions[..., :kb])}


def _kill_when_renaming(step: int, marker: Path) -> None:
    """Fault injection: SIGKILL this process when orbax is about to rename checkpoint ``step``'s temporary
    directory into place (its data, metadata and commit file are written; only the rename is missing)."""
    import threading

    def hook(frame, event, arg):
        if event == "call" and frame.f_code.co_name == "rename" and "orbax" in frame.f_code.co_filename:
            src = str(frame.f_locals.get("src", ""))
            if f"{os.sep}{step}.orbax-checkpoint-tmp" in src:
                marker.write_text(str(step))
                os.kill(os.getpid(), signal.SIGKILL)

    sys.setprofile(hook)
    threading.setprofile(hook)


def worker(run_dir: str, data_root: str, kill_at_save: int | None) -> None:
    import hashlib

    import jax
    import jax.numpy as jnp
    from flax import nnx

    from solaris_env.world_model.config import preset
    from solaris_env.world_model.dit import WorldDiT
    from training.checkpointing import Checkpointer, abstract_state
    from training.distributed import make_mesh, shard_batch, shard_train_state
    from training.duet import DuetDataset
    from training.metrics import MetricsLogger
    from training.samplers import MultiplayerSegmentSampler, next_batch
    from training.step import TrainState, make_optimizer, make_train_step

    run_dir = Path(run_dir)
    cfg = preset("test")
    dataset = DuetDataset(data_root, "train", obs_size=(cfg.frame_height, cfg.frame_width))
    sampler = MultiplayerSegmentSampler(dataset, CLIP_FRAMES, seed=5)
    graphdef, abstract = nnx.split(nnx.eval_shape(lambda: WorldDiT(cfg, rngs=nnx.Rngs(0))))
    rng = np.random.default_rng(0)
    params = jax.tree.map(lambda x: jnp.asarray(rng.normal(size=x.shape) * 0.05, x.dtype), abstract)
    tx = make_optimizer(3e-3)
    graphdef, state = TrainState.create(nnx.merge(graphdef, params), tx, rng=1)
    train_step = make_train_step(graphdef, "forward_bidirectional", "standard", tx)
    # placed on a 1-device mesh, so a fresh and a restored state carry the same shardings (one program)
    mesh = make_mesh(1)
    state = shard_train_state(state, mesh)

    ckpt = Checkpointer(run_dir / "checkpoints", keep=KEEP)
    start = 0
    if (latest := ckpt.latest_step()) is not None:
        state, extra = ckpt.restore(latest, abstract_state(state))
        sampler.load_state_dict(extra["sampler"])
        start = latest
        (run_dir / "resumed.json").write_text(json.dumps({"resumed_from": latest,
                                                          "sampler_step_after_restore": sampler.step}))
    log = MetricsLogger(run_dir / "metrics.jsonl", resume_step=start)
    replay = MultiplayerSegmentSampler(dataset, CLIP_FRAMES, seed=5)  # names the segments of each batch
    for step in range(start, TOTAL_STEPS):
        replay.load_state_dict(sampler.state_dict())
        segments = [list(map(int, segment)) for segment in replay.sample(BATCH)]
        raw = next_batch(dataset, sampler, BATCH)
        state, metrics = train_step(state, shard_batch(_features(raw, cfg), mesh))
        done = step + 1
        log.log(done, loss=float(metrics["loss"]), segments=segments,
                batch_sha1=hashlib.sha1(raw["obs"].tobytes() + raw["act"].tobytes()).hexdigest())
        if done % CKPT_EVERY == 0:
            if done == kill_at_save:
                _kill_when_renaming(done, run_dir / "killed_during_save.txt")
            ckpt.save(done, state, {"sampler": sampler.state_dict(), "stage": "test"})
    log.close()
    ckpt.close()


if __name__ == "__main__" and len(sys.argv) in (4, 5) and sys.argv[1] == "worker":
    worker(sys.argv[2], sys.argv[3], int(sys.argv[4]) if len(sys.argv) == 5 else None)
