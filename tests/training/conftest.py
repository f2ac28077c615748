"""A tiny real Duet dataset shared by the training tests: 4 walkLook episodes at 32x32 (3 train, 1 test),
collected once per session, plus its VPT-layout export."""

import pytest

from solaris_env.engine import cli as engine_cli


@pytest.fixture(scope="session")
def tiny_duet(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny_duet")
    argv = ["collect", "--out", str(out), "--resolution", "32", "--seed", "4", "--episodes", "4", "--world", "flat",
            "--types", "walkLook", "--test-fraction", "0.25"]
    assert engine_cli.main(argv) == 0
    assert engine_cli.main(["export-vpt", str(out), "--out", str(out)]) == 0
    return out
