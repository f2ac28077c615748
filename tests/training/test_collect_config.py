"""``solaris-train all``'s collect block (``training.stage_config.CollectConfig``) -> the ``solaris-engine
collect`` command line."""

from pathlib import Path

import pytest

from solaris_env.engine import cli as engine_cli
from solaris_env.world_model.config import WorldModelConfig
from training.collect import collect_argv
from training.stage_config import CollectConfig, load_stage_config

BASE = {"episodes": 12, "world": "mixed", "seed": 11, "test_fraction": 0.05}


def _block(**changes) -> CollectConfig:
    return CollectConfig.from_dict({**BASE, **changes}, "collect")


def test_the_block_becomes_an_engine_command_line():
    argv = collect_argv(Path("d"), WorldModelConfig.tiny(), _block())
    args = engine_cli.build_parser().parse_args(argv)
    assert (args.out, args.episodes, args.world, args.seed, args.test_fraction) == ("d", 12, "mixed", 11, 0.05)
    assert args.resolution == (64, 64) and args.types is None
    assert args.instances == engine_cli.build_parser().parse_args(["collect", "--out", "d"]).instances  # default


def test_instances_and_types_are_passed_on():
    argv = collect_argv(Path("d"), WorldModelConfig.tiny(), _block(instances=10, types=["lookAround"]))
    args = engine_cli.build_parser().parse_args(argv)
    assert args.instances == 10 and args.types == ["lookAround"]


def test_the_time_of_day_is_passed_on_and_names_its_values():
    parse = lambda block: engine_cli.build_parser().parse_args(collect_argv(Path("d"), WorldModelConfig.tiny(), block))
    assert parse(_block(time_of_day="day")).time_of_day == "day"
    assert parse(_block()).time_of_day is None  # absent: the engine's default (the natural cycle)
    from solaris_env.engine.bots.runner import TIMES_OF_DAY
    from training.stage_config import TIMES_OF_DAY as CONFIG_TIMES
    assert CONFIG_TIMES == TIMES_OF_DAY


@pytest.mark.parametrize("changes, message", [
    ({"instance": 10}, "collect config: unknown keys \\['instance'\\]"),
    ({"world": "moon"}, "collect config: world must be one of \\('flat', 'normal', 'mixed'\\), got 'moon'"),
    ({"instances": 0}, "collect config: instances must be an int >= 1 or null, got 0"),
    ({"time_of_day": "dusk"}, "collect config: time_of_day must be one of \\('cycle', 'day'\\)"),
])
def test_a_bad_block_is_named(changes, message):
    with pytest.raises(ValueError, match=message):
        CollectConfig.from_dict({**BASE, **changes}, "collect config")


@pytest.mark.parametrize("preset", ["tiny", "tiny16", "test"])
def test_every_shipped_collect_block_parses_as_engine_arguments(preset):
    block = load_stage_config(preset).collect
    args = engine_cli.build_parser().parse_args(collect_argv(Path("d"), WorldModelConfig.tiny(), block))
    assert (args.episodes, args.world, args.seed, args.test_fraction) == (
        block.episodes, block.world, block.seed, block.test_fraction)
