"""``solaris-train all``'s collect block -> the ``solaris-engine collect`` command line."""

from pathlib import Path

import pytest

from solaris_env.engine import cli as engine_cli
from solaris_env.world_model.config import WorldModelConfig
from training.collect import collect_argv

BASE = {"episodes": 12, "world": "mixed", "seed": 11, "test_fraction": 0.05}


def test_the_block_becomes_an_engine_command_line():
    argv = collect_argv(Path("d"), WorldModelConfig.tiny(), BASE)
    args = engine_cli.build_parser().parse_args(argv)
    assert (args.out, args.episodes, args.world, args.seed, args.test_fraction) == ("d", 12, "mixed", 11, 0.05)
    assert args.resolution == (64, 64) and args.types is None
    assert args.instances == engine_cli.build_parser().parse_args(["collect", "--out", "d"]).instances  # default


def test_instances_and_types_are_passed_on():
    argv = collect_argv(Path("d"), WorldModelConfig.tiny(), {**BASE, "instances": 10, "types": ["lookAround"]})
    args = engine_cli.build_parser().parse_args(argv)
    assert args.instances == 10 and args.types == ["lookAround"]


def test_an_unknown_key_is_named():
    with pytest.raises(ValueError, match="unknown keys \\['instance'\\]"):
        collect_argv(Path("d"), WorldModelConfig.tiny(), {**BASE, "instance": 10})
