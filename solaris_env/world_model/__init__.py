"""The Solaris world model (docs/model.md): ``WorldModel`` (streaming rollouts, checkpoints), its frozen
configs and presets. Submodules are imported on first use, so ``import solaris_env.world_model`` stays cheap."""

from solaris_env.lazy import lazy_getattr

_LAZY = {
    "WorldModel": "solaris_env.world_model.world_model",
    "WorldModelConfig": "solaris_env.world_model.config",
    "preset": "solaris_env.world_model.config",
}
__all__ = sorted(_LAZY)
__getattr__ = lazy_getattr(__name__, _LAZY)
