"""Shared by every test folder: the eval-set fixture, and the rule for tests marked ``minecraft``: they skip where
the real-Minecraft backend is not installed, except in CI (``CI=true``): there `.ci/run` installs it (`solaris-engine
setup-minecraft`), so a missing backend means the setup failed and every test marked ``minecraft`` fails, naming what is
missing, instead of skipping."""

import os

# XLA with most optimisations off (`jax_disable_most_optimizations`), in this process and in every subprocess a
# test starts, unless the caller set JAX_DISABLE_MOST_OPTIMIZATIONS itself (0 keeps them). The suite's time is
# mostly compiling tiny programs: with an empty compilation cache on 2 cores it went from 47 to 38 minutes;
# compile-bound tests run 1.5-2x faster, tests that run 1000 steps up to 2x slower (docs/history.md, session 35).
# Set before anything imports jax.
os.environ.setdefault("JAX_DISABLE_MOST_OPTIMIZATIONS", "1")

import pytest  # noqa: E402

from solaris_env.engine import cli  # noqa: E402
from solaris_env.engine.minecraft.install import setup_problem  # noqa: E402


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


@pytest.hookimpl(tryfirst=True)  # before the skipif markers are evaluated
def pytest_runtest_setup(item):
    if in_ci() and item.get_closest_marker("minecraft") is not None:
        problem = setup_problem()
        if problem is not None:
            pytest.fail(f"CI: the Minecraft backend is not set up ({problem}); `solaris-engine setup-minecraft` "
                        "failed or was not run", pytrace=False)


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
