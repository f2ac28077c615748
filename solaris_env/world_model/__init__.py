"""The Solaris world model (docs/model.md): ``WorldModel`` (streaming rollouts, checkpoints), its frozen
configs and presets. Submodules are imported on first use, so ``import solaris_env.world_model`` stays cheap."""

import importlib

_LAZY = {
    "WorldModel": "solaris_env.world_model.world_model",
    "WorldModelConfig": "solaris_env.world_model.config",
    "preset": "solaris_env.world_model.config",
}
__all__ = sorted(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'solaris_env.world_model' has no attribute {name!r}")
