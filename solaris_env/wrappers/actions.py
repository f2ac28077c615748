"""``FlatActions``: the MineRL Dict action as a flat ``MultiDiscrete`` (camera in bins) or ``Box`` for SB3,
through ``solaris_env.spaces.FlatActionCodec`` (the exposed keys -- all 23 by default -- then the exposed camera axes, [dpitch, dyaw] by default)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from solaris_env.spaces import CAMERA_AXES, FlatActionCodec


class FlatActions(gym.ActionWrapper):
    """Args:
        env: a single-agent env with the MineRL Dict action space.
        kind: ``"multidiscrete"`` (keys as 2-way choices, camera as ``camera_bins`` bins per axis) or ``"box"``
            (Box(-1, 1, (25,)): a key is pressed iff > 0, camera = value * camera_max_deg).
        camera_bins: odd number of camera bins per axis (multidiscrete).
        camera_max_deg: the largest camera turn per step, degrees.
        keys: the binary keys the flat action exposes (None: all 23); the others are never pressed.
        camera_axes: the camera axes it exposes (("pitch", "yaw"), ("yaw",), ...); the others never turn.
    """

    def __init__(self, env: gym.Env, kind: str = "multidiscrete", camera_bins: int = 11, camera_max_deg: float = 10.0,
                 keys: Sequence[str] | None = None, camera_axes: Sequence[str] = CAMERA_AXES):
        super().__init__(env)
        self.codec = FlatActionCodec(camera_bins=camera_bins, camera_max_deg=camera_max_deg, kind=kind, keys=keys,
                                     camera_axes=camera_axes)
        self.action_space = self.codec.space

    def action(self, action: Any) -> dict[str, Any]:
        """Flat (len(keys) + len(camera_axes),) -> env action; ValueError on a wrong shape, dtype or range."""
        return self.codec.decode(np.asarray(action))
