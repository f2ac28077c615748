"""``solaris_env`` (the package's ``__init__``): its public names import from its top level, lazily (no jax until one is
used)."""

import subprocess
import sys


def test_public_names_import_from_the_top_level():
    from solaris_env import DreamParallelEnv, DreamVectorEnv, EngineState, RealParallelEnv, WorldModel, parallel_env
    from solaris_env.world_model import WorldModel as WM
    from solaris_env.world_model import WorldModelConfig, preset

    assert WM is WorldModel and callable(parallel_env)
    assert preset("test").name == "test" and isinstance(preset("test"), WorldModelConfig)
    for cls in (DreamParallelEnv, DreamVectorEnv, EngineState, RealParallelEnv):
        assert isinstance(cls, type)


def test_importing_the_package_loads_no_framework():
    code = ("import sys, solaris_env, solaris_env.world_model; "
            "print(sorted(m for m in ('jax', 'torch', 'gymnasium') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_unknown_names_raise_attribute_error():
    import pytest

    import solaris_env
    import solaris_env.world_model

    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        solaris_env.Nope
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        solaris_env.world_model.Nope
