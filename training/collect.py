"""The training data of ``solaris-train``: a stage config's ``collect`` block (``training.stage_config.CollectConfig``)
as the ``solaris-engine collect`` command that records it (docs/training.md "Stage configs"; ``solaris-train all``
and the sprint's background collect run it)."""

from __future__ import annotations

from pathlib import Path

from training.stage_config import CollectConfig


def collect_if_missing(data: Path, preset_name: str, collect_cfg: CollectConfig) -> None:
    """Record the training data with the engine unless ``data/duet/train`` already holds episodes
    (a collect is itself resumable: finished episodes are skipped)."""
    from solaris_env.engine import cli as engine_cli
    from solaris_env.world_model.config import preset

    argv = collect_argv(data, preset(preset_name), collect_cfg)
    rc = engine_cli.main(argv)
    if rc:
        raise SystemExit(f"solaris-engine {' '.join(argv)} failed with exit code {rc}")


def collect_argv(data: Path, cfg, collect_cfg: CollectConfig) -> list[str]:
    """The ``solaris-engine`` arguments of the ``collect`` block of a stage config."""
    c = collect_cfg
    argv = ["collect", "--out", str(data), "--episodes", str(c.episodes), "--world", c.world,
            "--resolution", f"{cfg.frame_width}x{cfg.frame_height}", "--seed", str(c.seed),
            "--test-fraction", str(c.test_fraction)]
    if c.instances is not None:
        argv += ["--instances", str(c.instances)]
    if c.types is not None:
        argv += ["--types", *c.types]
    if c.time_of_day is not None:
        argv += ["--time-of-day", c.time_of_day]
    return argv
