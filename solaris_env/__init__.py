"""solaris_env: a multiplayer Minecraft world model as PettingZoo/Gymnasium environments, and the
voxel engine that makes its data. Heavy frameworks (jax, torch) are imported lazily.

The single-agent Gymnasium ids ``solaris_env/Dream-v0`` and ``solaris_env/Real-v0``
(``solaris_env.wrappers.single_agent``) are registered as soon as both this package and gymnasium are
imported, in either order: importing gymnasium costs ~0.2-0.6 s, which ``import solaris_env`` (and so the
``solaris-env`` CLI's start-up) does not pay unless gymnasium is used.
"""

import importlib.abc
import importlib.util
import sys

from solaris_env.lazy import lazy_getattr

__version__ = "0.1.0"

_LAZY = {
    "RealParallelEnv": "solaris_env.real_env",
    "EngineState": "solaris_env.real_env",
    "make_real_env": "solaris_env.real_backends",
    "DreamParallelEnv": "solaris_env.dream_env",
    "parallel_env": "solaris_env.dream_env",
    "DreamVectorEnv": "solaris_env.vector_env",
    "WorldModel": "solaris_env.world_model.world_model",
}
__all__ = sorted(_LAZY)

__getattr__ = lazy_getattr(__name__, _LAZY)


def _register_gymnasium_envs() -> None:
    from solaris_env.registration import register_envs

    register_envs()


class _RegisterAfterGymnasium(importlib.abc.MetaPathFinder):
    """Registers our ids right after the ``gymnasium`` package finishes importing (then removes itself)."""

    def find_spec(self, name, path, target=None):
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        exec_module = spec.loader.exec_module

        def exec_then_register(module):
            exec_module(module)
            _register_gymnasium_envs()

        spec.loader.exec_module = exec_then_register
        return spec


if "gymnasium" in sys.modules:
    _register_gymnasium_envs()
elif not any(isinstance(f, _RegisterAfterGymnasium) for f in sys.meta_path):
    sys.meta_path.insert(0, _RegisterAfterGymnasium())
