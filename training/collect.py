"""The training data of ``solaris-train``: a stage config's ``collect`` block as the ``solaris-engine collect``
command that records it (docs/training.md "Stage configs"; ``solaris-train all`` and the sprint's background
collect run it)."""

from __future__ import annotations

from pathlib import Path


def collect_if_missing(data: Path, preset_name: str, collect_cfg: dict) -> None:
    """Record the training data with the engine unless ``data/duet/train`` already holds episodes
    (a collect is itself resumable: finished episodes are skipped). Optional ``collect_cfg`` keys:
    ``instances`` (the flat surface is instance mod 5, so >= 10 covers all five with ``world: mixed``) and
    ``types`` (a list of episode types)."""
    from solaris_env.engine import cli as engine_cli
    from solaris_env.world_model.config import preset

    argv = collect_argv(data, preset(preset_name), collect_cfg)
    rc = engine_cli.main(argv)
    if rc:
        raise SystemExit(f"solaris-engine {' '.join(argv)} failed with exit code {rc}")


def collect_argv(data: Path, cfg, collect_cfg: dict) -> list[str]:
    """The ``solaris-engine`` arguments of the ``collect`` block of a stage config."""
    unknown = set(collect_cfg) - {"episodes", "world", "seed", "test_fraction", "instances", "types"}
    if unknown:
        raise ValueError(f"collect config: unknown keys {sorted(unknown)}; expected episodes, world, seed, "
                         f"test_fraction and optionally instances, types")
    argv = ["collect", "--out", str(data), "--episodes", str(collect_cfg["episodes"]), "--world", collect_cfg["world"],
            "--resolution", f"{cfg.frame_width}x{cfg.frame_height}", "--seed", str(collect_cfg["seed"]),
            "--test-fraction", str(collect_cfg["test_fraction"])]
    if "instances" in collect_cfg:
        argv += ["--instances", str(int(collect_cfg["instances"]))]
    if "types" in collect_cfg:
        argv += ["--types", *map(str, collect_cfg["types"])]
    return argv
