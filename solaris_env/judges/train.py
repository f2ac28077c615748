"""Train the five judge probes on engine frames with ground-truth labels, and score them on held-out data.

    D=/work/judgedata
    solaris-engine collect --out $D/train   --eval --episodes 24 --resolution 64 --seed 1000
    solaris-engine collect --out $D/train_ttl --eval --eval-types turnToLookEval turnToLookOppositeEval \\
        --episodes 48 --resolution 64 --seed 1001        # more normal-world scenes for same_scenery
    solaris-engine collect --out $D/train_duet --episodes 5 --world normal --resolution 64 --seed 1000
    solaris-engine collect --out $D/train_tr --eval --eval-types translationEval --episodes 48 \\
        --resolution 64 --seed 1002                      # more walkers receding to ~2 pixels for motion
    solaris-engine collect --out $D/train_flat --episodes 60 --world flat --instances 10 \\
        --types lookAround walkLook orbit --resolution 64 --seed 1004 --test-fraction 0
        # all five flat surfaces (variant = instance mod 5: grass, snow, sand, red sand), pitch +-30 deg
    solaris-engine collect --out $D/train_normal --episodes 60 --world normal --instances 10 \\
        --types lookAround walkLook orbit --resolution 64 --seed 1005 --test-fraction 0
    solaris-engine collect --out $D/train_normal2 --episodes 120 --world normal --instances 20 --instance-offset 20 \\
        --types walkLookAway straightLineWalk chase orbit walkLook --resolution 64 --seed 1006 --test-fraction 0
        # partners far away against trees and hills (the fidelity benchmark's normal starts)
    solaris-engine collect --out $D/train_approach --episodes 80 --world flat --instances 10 --types approach \\
        --resolution 64 --seed 1007 --test-fraction 0   # the partner at every distance down to filling the view
    solaris-engine collect --out $D/train_approach_normal --episodes 40 --world normal --instances 10 \\
        --instance-offset 40 --types approach --resolution 64 --seed 1008 --test-fraction 0
    solaris-engine collect --out $D/train_redsand --episodes 60 --world flat --instances 1 --instance-offset 4 \\
        --types lookAround walkLook --resolution 64 --seed 1009 --test-fraction 0   # red sand only (instance 4)
    solaris-engine collect --out $D/heldout --eval --episodes 32 --resolution 64 --seed 2000
    solaris-engine collect --out $D/heldout_approach --episodes 16 --world mixed --instances 8 --instance-offset 60 \\
        --types approach --resolution 64 --seed 2001 --test-fraction 0   # held out: scored with --heldout
    OUT=solaris_env/assets/judges DATA="$D/train $D/train_ttl $D/train_duet" APPR="$D/train_approach $D/train_approach_normal"
    python -m solaris_env.judges.train --data $DATA $APPR --out $OUT --questions structure same_scenery --force
    python -m solaris_env.judges.train --data $DATA $D/train_tr $APPR --out $OUT --questions motion --steps 4000 --force
    python -m solaris_env.judges.train --data $DATA $D/train_flat $D/train_normal $D/train_normal2 $APPR \\
        $D/train_redsand --out $OUT \\
        --questions visible position --steps 6000 --force --heldout $D/heldout $D/heldout_approach
    # the shipped weights: ~3-8 min per probe on 2 shared CPU cores (visible/position 6000 steps: ~7 min each)

Per question: build the examples (:mod:`dataset`, featureless frames included), train a :class:`Probe` with class-balanced
batches, left-right mirror augmentation (answers permuted by ``Question.flip_answers``) and brightness
jitter, then write ``<out>/<question>.safetensors``. Resumable at question granularity: a question
whose file exists is not retrained (``--force`` retrains). Seeded: data draws, init, batches and
augmentation all derive from ``--seed``.

With ``--heldout`` (one or more collects), ``<out>/report.json`` gets, for every probe in ``<out>``, the frame-level accuracy against the
sidecar labels of the held-out episodes and, per eval type and task, the paper's episode-level
accuracy of the probes on the held-out ground-truth videos (the paper's "GT Ep. Acc." column).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from dataclasses import replace
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx

from solaris_env.judges import questions
from solaris_env.judges.config import JudgeConfig, TrainConfig, config_to_dict
from solaris_env.judges.dataset import (
    Examples,
    FrameBank,
    balanced_probabilities,
    build,
)
from solaris_env.judges.episodes import find_episodes
from solaris_env.judges.judge import DEFAULT_WEIGHTS, Judge
from solaris_env.judges.probe import (
    Probe,
    load_probe,
    new_probe,
    num_params,
    save_probe,
)
from solaris_env.judges.scoring import episode_accuracy, judge_episodes, task_accuracy
from solaris_env.paths import portable_path

EVAL_BATCH = 256

# ---------------------------------------------------------------------------------------------
# Step functions
# ---------------------------------------------------------------------------------------------


def make_optimizer(tc: TrainConfig) -> optax.GradientTransformation:
    schedule = optax.warmup_cosine_decay_schedule(0.0, tc.learning_rate, tc.warmup_steps, tc.steps)
    return optax.adamw(schedule, weight_decay=tc.weight_decay)


def augment(x_BFHWC: jax.Array, y_B: jax.Array, flip_B: jax.Array, scale_B: jax.Array,
            perm_A: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Mirror the flagged queries left-right (all their frames; answers permuted) and scale brightness."""
    x = jnp.where(flip_B[:, None, None, None, None], x_BFHWC[:, :, :, ::-1, :], x_BFHWC).astype(jnp.float32)
    x = jnp.clip(x * scale_B[:, None, None, None, None], 0.0, 255.0)
    return x, jnp.where(flip_B, perm_A[y_B], y_B)


@partial(jax.jit, static_argnums=(0, 1), donate_argnums=(2, 3))
def train_step(graphdef, tx, params, opt_state, x_BFHWC, y_B, flip_B, scale_B, perm_A):
    """One AdamW step on softmax cross-entropy; returns (params, opt_state, loss, accuracy)."""
    x, y = augment(x_BFHWC, y_B, flip_B, scale_B, perm_A)

    def loss_fn(p):
        logits = nnx.merge(graphdef, p)(x)
        return optax.softmax_cross_entropy_with_integer_labels(logits, y).mean(), logits

    (loss, logits), grads = jax.value_and_grad(loss_fn, has_aux=True)(params)
    updates, opt_state = tx.update(grads, opt_state, params)
    params = optax.apply_updates(params, updates)
    return params, opt_state, loss, (logits.argmax(-1) == y).mean()


@partial(jax.jit, static_argnums=0)
def predict_step(graphdef, params, x_BFHWC):
    return nnx.merge(graphdef, params)(x_BFHWC).argmax(-1)


# ---------------------------------------------------------------------------------------------
# Train / evaluate one probe
# ---------------------------------------------------------------------------------------------


def train_probe(question: str, bank: FrameBank, ex: Examples, cfg: JudgeConfig, seed: int,
                log=print) -> tuple[Probe, dict]:
    """Train one probe from scratch; returns it and a summary (steps, final loss/accuracy, wall time)."""
    q, tc = questions.get(question), cfg.train
    if len(ex) == 0:
        raise ValueError(f"{question}: no training examples")
    probs = balanced_probabilities(ex.label_N, q.num_answers)
    rng = np.random.default_rng([seed, 1])
    probe = new_probe(question, cfg.probe_for(question), seed)
    graphdef, params = nnx.split(probe)
    tx = make_optimizer(tc)
    opt_state = tx.init(params)
    perm = jnp.asarray(q.flip_permutation())
    t0, losses, accs = time.perf_counter(), [], []
    for step in range(1, tc.steps + 1):
        idx = rng.choice(len(ex), tc.batch_size, p=probs)
        x = bank.frames_NHW3[ex.index_NF[idx]]  # (B, F, S, S, 3) uint8
        flip = rng.random(tc.batch_size) < 0.5
        scale = rng.uniform(1 - tc.brightness_jitter, 1 + tc.brightness_jitter, tc.batch_size).astype(np.float32)
        params, opt_state, loss, acc = train_step(graphdef, tx, params, opt_state, x, ex.label_N[idx], flip,
                                                  scale, perm)
        losses.append(float(loss))
        accs.append(float(acc))
        if not np.isfinite(losses[-1]):
            raise RuntimeError(f"{question}: non-finite loss at step {step}")
        if step % tc.log_every == 0 or step == tc.steps:
            log(f"  {question} step {step}/{tc.steps} loss {np.mean(losses[-tc.log_every:]):.4f} "
                f"acc {np.mean(accs[-tc.log_every:]):.3f} ({time.perf_counter() - t0:.0f} s)")
    summary = {"steps": tc.steps, "loss": float(np.mean(losses[-tc.log_every:])),
               "train_batch_accuracy": float(np.mean(accs[-tc.log_every:])), "wall_s": time.perf_counter() - t0,
               "examples": len(ex), "class_counts": ex.class_counts(), "seed": seed}
    return nnx.merge(graphdef, params), summary


def frame_accuracy(probe: Probe, bank: FrameBank, ex: Examples) -> dict:
    """Accuracy of a probe on labelled examples of real frames: overall, balanced (mean over classes) and per
    class; the featureless examples (``episode_N == -1``, dataset.py) apart as ``featureless_accuracy``."""
    q = questions.get(ex.question)
    real = ex.episode_N >= 0
    if not real.any():
        return {"examples": 0}
    pred_N = _predict(probe, bank, ex)
    pred, label = pred_N[real], ex.label_N[real]
    per_class = {a: float((pred[label == i] == i).mean()) for i, a in enumerate(q.answers) if (label == i).any()}
    out = {"examples": len(label), "accuracy": float((pred == label).mean()),
           "balanced_accuracy": float(np.mean(list(per_class.values()))), "per_class": per_class,
           "class_counts": {a: int((label == i).sum()) for i, a in enumerate(q.answers)}}
    if (~real).any():
        out["featureless_examples"] = int((~real).sum())
        out["featureless_accuracy"] = float((pred_N[~real] == ex.label_N[~real]).mean())
    return out


def _predict(probe: Probe, bank: FrameBank, ex: Examples) -> np.ndarray:
    graphdef, params = nnx.split(probe)
    preds = []
    for i in range(0, len(ex), EVAL_BATCH):
        idx = ex.index_NF[i:i + EVAL_BATCH]
        pad = EVAL_BATCH - len(idx)
        idx = np.concatenate([idx, np.repeat(idx[-1:], pad, 0)]) if pad else idx
        preds.append(np.asarray(predict_step(graphdef, params, bank.frames_NHW3[idx]))[:EVAL_BATCH - pad])
    return np.concatenate(preds)


# ---------------------------------------------------------------------------------------------
# Main
# ---------------------------------------------------------------------------------------------


def _write_json(path: Path, obj) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        json.dump(obj, f, indent=2)
    os.chmod(tmp, 0o644)  # mkstemp makes 0600; shipped files must be readable by all
    os.replace(tmp, path)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m solaris_env.judges.train", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, nargs="+", help="solaris-engine collect output(s) with ground-truth sidecars")
    p.add_argument("--out", default=str(DEFAULT_WEIGHTS), help="directory for <question>.safetensors + report.json")
    p.add_argument("--heldout", default=None, nargs="+",
                   help="collect(s) of other seeds to score the probes on (report.json)")
    p.add_argument("--questions", nargs="+", default=None, choices=sorted(questions.QUESTIONS),
                   help="train only these (default: all five)")
    p.add_argument("--steps", type=int, default=TrainConfig().steps, help="training steps per probe")
    p.add_argument("--batch-size", type=int, default=TrainConfig().batch_size)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--force", action="store_true", help="retrain questions whose weights already exist")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    cfg = JudgeConfig(train=replace(TrainConfig(), steps=args.steps, batch_size=args.batch_size,
                                    warmup_steps=min(TrainConfig().warmup_steps, args.steps - 1)))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    names = args.questions or list(questions.QUESTIONS)
    log = partial(print, file=sys.stderr, flush=True)

    todo = [n for n in names if args.force or not (out / f"{n}.safetensors").is_file()]
    if todo:
        episodes = [e for d in args.data for e in find_episodes(d)]
        log(f"{len(episodes)} training episodes under {args.data}; training {todo}")
        t0 = time.perf_counter()
        bank, examples = build(episodes, cfg, args.seed, todo)
        log(f"frame bank {bank.frames_NHW3.shape} in {time.perf_counter() - t0:.0f} s; "
            + ", ".join(f"{n}: {len(examples[n])}" for n in todo))
        for k, name in enumerate(todo):
            probe, summary = train_probe(name, bank, examples[name], cfg, args.seed + 1000 * k, log)
            summary.update(config=config_to_dict(cfg), data=[portable_path(d) for d in args.data],
                           params=num_params(probe))
            save_probe(out / f"{name}.safetensors", name, probe, summary)
            log(f"wrote {out / f'{name}.safetensors'} ({num_params(probe)} parameters)")
        del bank, examples
    if args.heldout:  # every probe in --out, not only the ones trained now
        present = [n for n in questions.QUESTIONS if (out / f"{n}.safetensors").is_file()]
        report = heldout_report(out, present, args.heldout, cfg, args.seed, log)
        _write_json(out / "report.json", report)
        log(json.dumps(report["episode_level"], indent=1))
    return 0


def heldout_report(out: Path, names: list[str], heldout: list[str], cfg: JudgeConfig, seed: int, log) -> dict:
    """Frame-level accuracy per question and the paper's episode-level accuracy on held-out episodes."""
    episodes = [e for d in heldout for e in find_episodes(d)]
    probes = {n: load_probe(out / f"{n}.safetensors")[1] for n in names}
    bank, examples = build(episodes, cfg, seed + 1, names)
    frame = {n: frame_accuracy(probes[n], bank, examples[n]) for n in names}
    del bank, examples
    judged = [e for e in episodes if e.is_eval and questions.EVAL_TYPE_QUESTION[e.episode_type] in probes]
    results = judge_episodes(Judge(probes), judged)
    per_type = episode_accuracy(results)
    wrong = [{"episode": r.episode, "query": r.index, "expected": r.expected, "answer": r.answer}
             for r in results if not r.correct]
    for n in names:
        log(f"{n}: held-out frame accuracy {frame[n].get('accuracy', float('nan')):.4f} "
            f"(balanced {frame[n].get('balanced_accuracy', float('nan')):.4f}, {frame[n]['examples']} examples; "
            f"featureless {frame[n].get('featureless_accuracy', float('nan')):.4f})")
    return {"heldout": [portable_path(d) for d in heldout], "episodes": len(episodes), "frame_level": frame,
            "episode_level": per_type, "tasks": task_accuracy(per_type), "wrong_queries": wrong,
            "weights": {n: read_extra(out / f"{n}.safetensors") for n in names}}


def read_extra(path: Path) -> dict:
    from solaris_env.judges.probe import read_metadata

    extra = read_metadata(path)["extra"]
    out = {k: extra[k] for k in ("steps", "examples", "class_counts", "params", "wall_s", "seed", "data") if k in extra}
    if "data" in out:  # probes trained before paths were recorded portably
        out["data"] = [portable_path(d) for d in out["data"]]
    return out


if __name__ == "__main__":
    raise SystemExit(main())
