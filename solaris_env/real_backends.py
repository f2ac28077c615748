"""The real env's backends by name (docs/architecture.md §2): ``"voxel"``, our engine
(``real_env.RealParallelEnv``), and ``"minecraft"``, real Minecraft 1.20.1 stepped in real time
(``minecraft_env.MinecraftParallelEnv``, needs ``solaris-engine setup-minecraft``).

    env = make_real_env(backend="minecraft", resolution=64, task="see_other_player")
"""

from __future__ import annotations

from typing import Any

from solaris_env.minecraft_env import MinecraftParallelEnv
from solaris_env.real_env import RealParallelEnv

BACKENDS: dict[str, type[RealParallelEnv]] = {"voxel": RealParallelEnv, "minecraft": MinecraftParallelEnv}


def make_real_env(backend: str = "voxel", **kwargs: Any) -> RealParallelEnv:
    """The real env on ``backend`` (a name in ``BACKENDS``), built with ``kwargs`` (see the backend's class)."""
    if not isinstance(backend, str) or backend not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {backend!r}")
    return BACKENDS[backend](**kwargs)
