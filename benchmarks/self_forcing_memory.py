"""Peak memory and speed of naive vs Checkpointed Self Forcing generator steps (paper Fig. "Checkpointed
Self Forcing" (E); docs/model.md §6.3).

    .venv/bin/python -m benchmarks.self_forcing_memory                      # tiny preset, L_t 6..24, ~10 min
    .venv/bin/python -m benchmarks.self_forcing_memory --lengths 6 --steps 1 --preset test   # smoke run

For every rollout length L_t (latent frames; the student window is ``cfg.dit.window`` = 6 at the tiny
preset) and each mode, one generator step (rollout + generator x0 + teacher/critic DMD + AdamW update,
batch 1, both players) runs in a FRESH subprocess that measures its own resident memory:

1. imports, three DiTs (generator, critic, teacher) and the optimiser state, a random batch of L_t
   latent frames (the step's cost does not depend on the values);
2. ``jit(...).lower(...).compile()`` (compilation memory is not the method's memory), then
   ``malloc_trim(0)`` so freed compiler memory goes back to the OS;
3. baseline = VmRSS; the kernel's high-water mark is reset (``echo 5 > /proc/self/clear_refs``);
4. ``--steps`` steps run (state donated, results blocked on); peak = VmHWM - baseline: the measured extra
   resident memory of the step (activations kept for the backward pass, caches, temporaries).

``peak_mb`` is therefore measured, not estimated; ``xla_temp_mb`` (XLA's ``memory_analysis`` of the
compiled program: its temp buffer) is recorded next to it as a cross-check. ``steps_per_s`` is 1 / the
median step time (2 shared CPU cores: noisy; the load average is recorded). Every step of a
measurement draws the same exit index s (the keys depend on ``state.iteration``, which only the critic
step advances), the same for both modes, so the two modes do identical sampling work.

Writes ``benchmarks/results/self_forcing_memory.json`` (a list of {"L_t", "naive_peak_mb",
"checkpointed_peak_mb", ...} plus metadata) and ``self_forcing_memory.png`` (matplotlib).
Target: checkpointed grows ~linearly in L_t and needs <= 1/3 of the naive peak at L_t = 24.
"""

from __future__ import annotations

import argparse
import ctypes
import itertools
import json
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).parent / "results" / "self_forcing_memory.json"
MODES = ("naive", "checkpointed")
LENGTHS = (6, 12, 18, 24)

# ---------------------------------------------------------------------------------------------
# Process memory (Linux /proc)
# ---------------------------------------------------------------------------------------------


def _status_kb(field: str) -> int:
    match = re.search(rf"^{field}:\s+(\d+) kB", Path("/proc/self/status").read_text(), re.MULTILINE)
    if match is None:
        raise RuntimeError(f"/proc/self/status has no {field} line")
    return int(match.group(1))


def _release_freed_memory() -> None:
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except OSError:  # not glibc: freed memory may stay resident, which only raises the baseline
        pass


def _reset_peak() -> None:
    Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current VmRSS (Linux >= 4.0)


# ---------------------------------------------------------------------------------------------
# Worker: one (mode, L_t) measurement in this process
# ---------------------------------------------------------------------------------------------


def _random_batch(cfg, num_frames: int, seed: int) -> dict:
    import jax
    import jax.numpy as jnp

    from solaris_env.world_model.action_module import padded_action_length

    b, p, t_pad = 1, cfg.stream_players, padded_action_length(cfg, num_frames)
    ks = jax.random.split(jax.random.key(seed), 4)
    latent = (b, p, num_frames, cfg.latent_height, cfg.latent_width)
    return {
        "cond": jax.random.normal(ks[0], latent + (cfg.in_channels - cfg.out_channels,)),
        "context": jax.random.normal(ks[1], (b, p, cfg.image_encoder.num_tokens, cfg.context_width)),
        "mouse": jax.random.normal(ks[2], (b, p, t_pad, cfg.players_in_channels * cfg.action.mouse_dim)),
        "keyboard": jax.random.bernoulli(ks[3], 0.3, (b, p, t_pad, cfg.keyboard_in_dim)).astype(jnp.float32),
    }


def measure(mode: str, num_frames: int, preset: str, steps: int, seed: int = 0) -> dict:
    import jax
    from flax import nnx

    from solaris_env.world_model.config import preset as make_preset
    from solaris_env.world_model.dit import WorldDiT
    from training import self_forcing as sf

    cfg = make_preset(preset)
    sf_cfg = sf.SelfForcingConfig()
    graphdef = nnx.split(nnx.eval_shape(lambda: WorldDiT(cfg, rngs=nnx.Rngs(0))))[0]
    init = jax.jit(lambda key: nnx.state(WorldDiT(cfg, rngs=nnx.Rngs(key))))
    generator, critic, teacher = (nnx.merge(graphdef, init(jax.random.key(seed + i))) for i in range(3))
    gen_tx, critic_tx = sf.make_optimizers(sf_cfg)
    graphs, state = sf.create_self_forcing_state(generator, critic, teacher, gen_tx, critic_tx, rng=seed)
    del generator, critic, teacher
    batch = _random_batch(cfg, num_frames, seed)
    make_step = {"naive": sf.make_naive_generator_step, "checkpointed": sf.make_checkpointed_generator_step}[mode]
    step = make_step(graphs, gen_tx, sf_cfg)
    jax.block_until_ready((state, batch))
    rss_init_mb = _status_kb("VmRSS") / 1024

    t0 = time.perf_counter()
    compiled = step.lower(state, batch).compile()
    compile_s = time.perf_counter() - t0
    analysis = compiled.memory_analysis()
    xla_temp_mb = None if analysis is None else analysis.temp_size_in_bytes / 2**20

    _release_freed_memory()
    baseline_mb = _status_kb("VmRSS") / 1024
    _reset_peak()
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        state, metrics = compiled(state, batch)
        jax.block_until_ready((state, metrics))
        times.append(time.perf_counter() - t0)
    peak_mb = _status_kb("VmHWM") / 1024 - baseline_mb
    return {"mode": mode, "L_t": num_frames, "peak_mb": round(peak_mb, 1), "xla_temp_mb": xla_temp_mb and
            round(xla_temp_mb, 1), "baseline_rss_mb": round(baseline_mb, 1), "rss_after_init_mb": round(rss_init_mb, 1),
            "compile_s": round(compile_s, 2), "step_s": [round(t, 3) for t in times],
            "steps_per_s": round(1.0 / statistics.median(times), 4), "loss": float(metrics["loss"]),
            "exit_index": int(metrics["exit_index"])}


# ---------------------------------------------------------------------------------------------
# Driver: one subprocess per measurement, JSON + plot
# ---------------------------------------------------------------------------------------------


def run_worker(mode: str, num_frames: int, args) -> dict:
    cmd = [sys.executable, "-m", "benchmarks.self_forcing_memory", "--worker", mode, "--lengths", str(num_frames),
           "--preset", args.preset, "--steps", str(args.steps)]
    out = subprocess.run(cmd, check=False, capture_output=True, text=True, cwd=Path(__file__).parent.parent)
    if out.returncode != 0:
        raise RuntimeError(f"worker {mode} L_t={num_frames} failed:\n{out.stderr[-4000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def plot(rows: list[dict], path: Path, window: int) -> str:
    """Write the PNG with matplotlib, or with OpenCV where matplotlib is not installed; -> the library used."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return _plot_cv2(rows, path, window)
    lengths = [r["L_t"] for r in rows]
    fig, ax = plt.subplots(figsize=(5.5, 4))
    ax.plot(lengths, [r["naive_peak_mb"] for r in rows], "o-", color="tab:red", label="naive Self Forcing")
    ax.plot(lengths, [r["checkpointed_peak_mb"] for r in rows], "o-", color="tab:green",
            label="Checkpointed Self Forcing")
    ax.set_xlabel(f"rollout length L_t (latent frames, window {window})")
    ax.set_ylabel("peak step memory (MB, measured RSS)")
    ax.set_title("Self Forcing generator step, tiny preset, batch 1")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=120)
    os.replace(tmp, path)
    return "matplotlib"


def _plot_cv2(rows: list[dict], path: Path, window: int) -> str:
    """The same chart drawn with OpenCV primitives (matplotlib is not a dependency of this project)."""
    import cv2
    import numpy as np

    width, height, left, right, top, bottom = 640, 440, 70, 20, 40, 60
    img = np.full((height, width, 3), 255, np.uint8)
    lengths = [r["L_t"] for r in rows]
    series = (("naive Self Forcing", "naive_peak_mb", (40, 40, 214)),
              ("Checkpointed Self Forcing", "checkpointed_peak_mb", (44, 160, 44)))  # BGR
    y_max = 1.1 * max(max(r[key] for r in rows) for _, key, _ in series)
    x_lo, x_hi = min(lengths), max(lengths)
    to_px = lambda x, y: (int(left + (x - x_lo) / max(x_hi - x_lo, 1) * (width - left - right)),
                          int(height - bottom - y / y_max * (height - top - bottom)))
    font, black, grey = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0), (200, 200, 200)
    for k in range(6):  # y grid and labels
        y = y_max * k / 5
        _, py = to_px(x_lo, y)
        cv2.line(img, (left, py), (width - right, py), grey, 1)
        cv2.putText(img, f"{y:.0f}", (8, py + 4), font, 0.4, black, 1, cv2.LINE_AA)
    for x in lengths:
        px, py = to_px(x, 0)
        cv2.putText(img, str(x), (px - 8, py + 18), font, 0.45, black, 1, cv2.LINE_AA)
    cv2.line(img, to_px(x_lo, 0), to_px(x_hi, 0), black, 1)
    cv2.line(img, (left, top), (left, height - bottom), black, 1)
    for i, (label, key, color) in enumerate(series):
        pts = [to_px(r["L_t"], r[key]) for r in rows]
        for a, b in itertools.pairwise(pts):
            cv2.line(img, a, b, color, 2, cv2.LINE_AA)
        for pt in pts:
            cv2.circle(img, pt, 4, color, -1, cv2.LINE_AA)
        cv2.putText(img, label, (left + 10, top + 18 + 18 * i), font, 0.5, color, 1, cv2.LINE_AA)
    cv2.putText(img, "peak step memory (MB, measured RSS), tiny preset, batch 1", (left - 40, 22), font, 0.5, black,
                1, cv2.LINE_AA)
    cv2.putText(img, f"rollout length L_t (latent frames, window {window})", (left + 120, height - 15), font, 0.5,
                black, 1, cv2.LINE_AA)
    tmp = path.with_suffix(".tmp.png")
    cv2.imwrite(str(tmp), img)
    os.replace(tmp, path)
    return "opencv (matplotlib not installed)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="tiny")
    parser.add_argument("--lengths", type=int, nargs="+", default=list(LENGTHS))
    parser.add_argument("--steps", type=int, default=3, help="timed steps per measurement")
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--worker", choices=MODES, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(measure(args.worker, args.lengths[0], args.preset, args.steps)))
        return

    from benchmarks.machine import machine_info
    from solaris_env.world_model.config import preset as make_preset

    load_before = os.getloadavg()
    cfg = make_preset(args.preset)
    rows, raw = [], []
    for num_frames in args.lengths:
        res = {mode: run_worker(mode, num_frames, args) for mode in MODES}
        raw.extend(res.values())
        rows.append({"L_t": num_frames, "naive_peak_mb": res["naive"]["peak_mb"],
                     "checkpointed_peak_mb": res["checkpointed"]["peak_mb"],
                     "ratio_checkpointed_over_naive": round(res["checkpointed"]["peak_mb"] / res["naive"]["peak_mb"], 3),
                     "naive_steps_per_s": res["naive"]["steps_per_s"],
                     "checkpointed_steps_per_s": res["checkpointed"]["steps_per_s"]})
        print(json.dumps(rows[-1]), flush=True)
    out = {
        "results": rows,
        "measurements": raw,
        "config": {"preset": cfg.name, "window": cfg.dit.window, "dim": cfg.dit.dim, "num_layers": cfg.dit.num_layers,
                   "tokens_per_frame_per_player": cfg.tokens_per_frame, "players": cfg.num_players, "batch": 1,
                   "ar_timesteps": list(cfg.sampler.ar_timesteps), "steps_per_measurement": args.steps,
                   "dtype": cfg.dit.dtype},
        "method": "peak = VmHWM - VmRSS baseline, in a fresh subprocess per measurement, after compile + "
                  "malloc_trim, HWM reset via /proc/self/clear_refs; a generator step = rollout (random exit) "
                  "+ generator x0 + DMD (teacher, critic) + AdamW update",
        "machine": machine_info(load_before),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(out, indent=2) + "\n")
    os.replace(tmp, args.out)
    png = args.out.with_suffix(".png")
    library = plot(rows, png, cfg.dit.window)
    print(f"wrote {args.out} and {png} (plotted with {library})")


if __name__ == "__main__":
    main()
