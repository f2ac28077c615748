"""solaris_env: a multiplayer Minecraft world model as PettingZoo/Gymnasium environments, and the
voxel engine that makes its data. Heavy frameworks (jax, torch) are imported lazily."""

__version__ = "0.1.0"


def __getattr__(name):
    if name == "RealParallelEnv":
        from solaris_env.real_env import RealParallelEnv

        return RealParallelEnv
    if name in ("DreamParallelEnv", "parallel_env"):
        from solaris_env import dream_env

        return getattr(dream_env, name)
    raise AttributeError(f"module 'solaris_env' has no attribute {name!r}")
