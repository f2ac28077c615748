"""The full-size ``solaris`` preset end to end on an accelerator: official checkpoint round trip + streaming.

    python -m benchmarks.solaris_full_size                     # on a GPU (~5 min on one H100)
    python -m benchmarks.solaris_full_size --preset test       # CPU smoke run at reduced sizes

No official weights can be downloaded here, so the check is on weights of our own in the official layout:

1. build the preset with random weights (``WorldModel.from_preset``);
2. write them as the three official orbax ``StandardCheckpointer`` directories (``solaris.pt``,
   ``vae.pt``, ``clip.pt``: docs/model.md §9.2, the reference's key trees and dtypes) and load that directory
   with ``WorldModel.load`` -- every parameter must come back equal to what the files hold (the reference's
   bf16 leaves cast back to f32), and the DiT key tree must equal ``solaris-param-tree.txt``;
3. stream from the loaded model: ``init`` at each B in ``--worlds``, then ``--steps`` env steps, timing each (frames
   ready) and reading the accelerator's peak memory; frames must be uint8 of the right shape and not
   constant.

Writes ``benchmarks/results/solaris_full_size.json`` (or ``--out``): sizes, save/load seconds, the step
latencies (first call = compile), player-frames/s and the device's peak bytes in use.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.machine import machine_info, write_result

RESULTS = Path(__file__).parent / "results" / "solaris_full_size.json"
TREE = (Path(__file__).resolve().parent.parent / "tests" / "solaris_env" / "world_model" / "fixtures"
        / "solaris-param-tree.txt")


def official_layout(cfg, dtype: str):
    """The preset with the parts the reference always has (VAE middle attention, CLIP head), computing in
    ``dtype`` (parameters stay f32)."""
    enc = cfg.image_encoder
    return cfg.replace(dit=dataclasses.replace(cfg.dit, dtype=dtype),
                       vae=dataclasses.replace(cfg.vae, middle_attention=True, dtype=dtype),
                       image_encoder=dataclasses.replace(enc, proj_dim=enc.proj_dim or 8, dtype=dtype))


def official_dit_keys() -> dict[str, tuple[int, ...]]:
    out = {}
    for line in TREE.read_text().splitlines():
        if line.strip() and not line.startswith("TOTAL"):
            key, shape, *_ = ast.literal_eval(line)
            out[key] = tuple(shape)
    return out


def write_official(model, directory: Path) -> dict[str, dict]:
    """solaris.pt / vae.pt / clip.pt as the reference stores them; returns {file: flat tree written}."""
    import jax.numpy as jnp

    from solaris_env.world_model import checkpoint, official

    _, vae, encoder = model.modules()
    dit = dict(checkpoint.flat_params(model.params[0]))
    key = "blocks/action_model/proj_mouse/kernel"  # the one bf16 leaf of the reference's DiT
    dit[key] = dit[key].astype(jnp.bfloat16)
    trees = {"dit": dit, "vae": official.to_official_vae(vae), "image_encoder": official.to_official_image_encoder(encoder)}
    for name, flat in trees.items():
        official.save_official(directory / checkpoint.OFFICIAL_FILES[name], flat)
    return trees


def compare_loaded(model, loaded) -> int:
    """Every parameter of ``loaded`` equals ``model``'s after the reference's storage dtypes; count."""
    from solaris_env.world_model import checkpoint, official

    stored = {f"vae/{ours}": dt for ours, (_, _, dt) in official.vae_leaf_map(model.config.vae).items()}
    stored["dit/blocks/action_model/proj_mouse/kernel"] = "bfloat16"

    def flat(m):
        return {f"{c}/{k}": np.asarray(v) for c, p in zip(("dit", "vae", "image_encoder"), m.params)
                for k, v in checkpoint.flat_params(p).items()}

    want, got = flat(model), flat(loaded)
    if want.keys() != got.keys():
        raise AssertionError(f"key trees differ: {sorted(want.keys() ^ got.keys())[:10]}")
    for k, w in want.items():
        w = w.astype(stored.get(k, "float32")).astype(w.dtype) if w.dtype == np.float32 else w
        if got[k].dtype != w.dtype or not np.array_equal(got[k], w):
            raise AssertionError(f"{k}: loaded value differs from the one written")
    return len(want)


def stream(model, b: int, steps: int) -> dict:
    """``init`` B worlds, then ``steps`` env steps: latencies (the first call of each compiles)."""
    import jax

    rng = np.random.default_rng(b)
    p, k = model.num_players, model.frames_per_step
    first = rng.integers(0, 256, (b, p, *model.frame_shape), dtype=np.uint8)
    t0 = time.perf_counter()
    state = jax.block_until_ready(model.init(first, 0))
    init_first_s = time.perf_counter() - t0
    step_s, frames = [], None
    for _ in range(steps):
        actions = (rng.random((b, p, k, model.action_dim)) < 0.2).astype(np.float32)
        t0 = time.perf_counter()
        frames, state = model.step(state, actions)
        frames.block_until_ready()
        step_s.append(time.perf_counter() - t0)
    frames = np.asarray(frames)
    if frames.shape != (b, p, k, *model.frame_shape) or frames.dtype != np.uint8 or frames.std() == 0:
        raise AssertionError(f"bad frames: {frames.shape} {frames.dtype} std {frames.std()}")
    steady = statistics.median(step_s[1:]) if len(step_s) > 1 else step_s[0]
    return {"worlds": b, "players": p, "frames_per_step": k, "init_first_call_s": init_first_s,
            "step_first_call_s": step_s[0], "step_s_median": steady, "step_s": step_s,
            "env_steps_per_s": 1.0 / steady, "player_frames_per_s": b * p * k / steady}


def peak_device_bytes() -> int | None:
    import jax

    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="solaris", choices=["solaris", "tiny", "test"])
    parser.add_argument("--worlds", type=int, nargs="+", default=[1])
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--dtype", default="float32", choices=["float32", "bfloat16"], help="compute dtype")
    parser.add_argument("--skip-round-trip", action="store_true", help="only stream (step 2 skipped)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()

    import jax

    from solaris_env.world_model import checkpoint
    from solaris_env.world_model.config import preset
    from solaris_env.world_model.world_model import WorldModel, param_count

    load_before = os.getloadavg()
    cfg = official_layout(preset(args.preset), args.dtype)
    t0 = time.perf_counter()
    model = WorldModel.from_config(cfg, seed=0)
    jax.block_until_ready(model.step_params)
    build_s = time.perf_counter() - t0

    dit_shapes = {k: tuple(v.shape) for k, v in checkpoint.flat_params(model.params[0]).items()}
    tree_matches = None
    if args.preset == "solaris":
        tree_matches = dit_shapes == official_dit_keys()
        if not tree_matches:
            raise AssertionError("the solaris preset's DiT tree differs from solaris-param-tree.txt")

    round_trip = None
    loaded = model
    if not args.skip_round_trip:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            write_official(model, Path(tmp))
            save_s = time.perf_counter() - t0
            disk_bytes = sum(f.stat().st_size for f in Path(tmp).rglob("*") if f.is_file())
            t0 = time.perf_counter()
            loaded = WorldModel.load(tmp, config=cfg)
            jax.block_until_ready(loaded.step_params)
            load_s = time.perf_counter() - t0
        round_trip = {"save_s": save_s, "load_s": load_s, "disk_bytes": disk_bytes,
                      "params_checked_equal": compare_loaded(model, loaded)}
        del model

    streams = [stream(loaded, b, args.steps) for b in args.worlds]

    dev = jax.devices()[0]
    result = {
        "preset": args.preset, "config_note": "official layout (VAE middle attention, CLIP head)",
        "device": {"platform": dev.platform, "kind": dev.device_kind, "count": jax.device_count()},
        "params": param_count(loaded), "dit_tree_equals_official": tree_matches,
        "compute_dtype": args.dtype, "official_round_trip": round_trip,
        "build_s": build_s,
        "frame_shape": list(loaded.frame_shape), "dit_passes_per_step": len(loaded.config.sampler.ar_timesteps) + 1,
        "stream": streams,
        "peak_device_bytes": peak_device_bytes(),
        "machine": machine_info(load_before),
    }
    print(json.dumps({k: v for k, v in result.items() if k not in ("machine",)}, indent=2))
    write_result(args.out, result)


if __name__ == "__main__":
    main()
