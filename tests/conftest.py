"""Fixtures shared across test folders."""

import pytest

from solaris_env.engine import cli


@pytest.fixture(scope="session")
def collect_eval(tmp_path_factory):
    """``collect_eval(types, size, seed)`` -> root of a ``solaris-engine collect --eval`` output with one
    episode of each eval type at ``size`` x ``size`` (each distinct request collected once per session)."""
    roots = {}

    def collect(types, size, seed):
        key = (tuple(types), size, seed)
        if key not in roots:
            root = tmp_path_factory.mktemp("eval_sets")
            rc = cli.main(["collect", "--out", str(root), "--eval", "--eval-types", *types, "--episodes", "1",
                           "--resolution", str(size), "--seed", str(seed)])
            assert rc == 0
            roots[key] = root
        return roots[key]

    return collect
