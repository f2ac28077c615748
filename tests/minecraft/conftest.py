"""Minecraft tests skip where the backend is not installed, except in CI: there `.ci/run` installs it
(`solaris-engine setup-minecraft`), so a missing backend means the setup failed and every test marked
``minecraft`` fails, naming what is missing, instead of skipping."""

import os

import pytest

from solaris_env.engine.minecraft.install import setup_problem


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


@pytest.hookimpl(tryfirst=True)  # before the skipif markers are evaluated
def pytest_runtest_setup(item):
    if in_ci() and item.get_closest_marker("minecraft") is not None:
        problem = setup_problem()
        if problem is not None:
            pytest.fail(f"CI: the Minecraft backend is not set up ({problem}); `solaris-engine setup-minecraft` "
                        "failed or was not run", pytrace=False)
