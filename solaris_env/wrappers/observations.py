"""Observation wrappers for our ParallelEnvs (dream or real): resize the frames, stack the last n frames.

They wrap the multiplayer env, so every agent sees the same transform and the single-agent, SB3 and
recorder wrappers sit on top unchanged. ``infos[agent]["frames"]`` (the dream env's k frames per step) is
left at the model's size.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces as gym_spaces
from pettingzoo.utils.wrappers import BaseParallelWrapper


def _size(size: Any) -> tuple[int, int]:
    h, w = (size, size) if isinstance(size, (int, np.integer)) else tuple(size)
    if not (isinstance(h, (int, np.integer)) and isinstance(w, (int, np.integer)) and h >= 1 and w >= 1):
        raise ValueError(f"size must be an int or (height, width) of positive ints, got {size!r}")
    return int(h), int(w)


class ResizeFrames(BaseParallelWrapper):
    """Resize every observation to (height, width) (area averaging down, bilinear up); uint8 kept.

    Args:
        env: a ParallelEnv with (H, W, C) uint8 observations.
        size: an int (square) or (height, width). SB3's CNN policies want at least 36x36.
    """

    def __init__(self, env: Any, size: Any):
        super().__init__(env)
        self.size = _size(size)
        self._spaces = {}
        for a in env.possible_agents:
            c = env.observation_space(a).shape[-1]
            self._spaces[a] = gym_spaces.Box(0, 255, (*self.size, c), np.uint8)

    def observation_space(self, agent: str):
        return self._spaces[agent]

    def _resize(self, frame: np.ndarray) -> np.ndarray:
        import cv2

        h, w = self.size
        interp = cv2.INTER_AREA if h <= frame.shape[0] and w <= frame.shape[1] else cv2.INTER_LINEAR
        out = cv2.resize(frame, (w, h), interpolation=interp)
        return out.reshape(h, w, frame.shape[-1])

    def reset(self, seed: int | None = None, options: dict | None = None):
        obs, infos = self.env.reset(seed=seed, options=options)
        return {a: self._resize(o) for a, o in obs.items()}, infos

    def step(self, actions: dict):
        obs, *rest = self.env.step(actions)
        return ({a: self._resize(o) for a, o in obs.items()}, *rest)


class StackFrames(BaseParallelWrapper):
    """Each observation becomes the last ``n`` frames stacked on the channel axis, oldest first:
    (H, W, C) -> (H, W, n*C) uint8 (an image for SB3's CNN policies). At reset the first frame is repeated.
    """

    def __init__(self, env: Any, n: int):
        super().__init__(env)
        if not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"n must be an int >= 1, got {n!r}")
        self.n = int(n)
        self._spaces = {}
        for a in env.possible_agents:
            h, w, c = env.observation_space(a).shape
            self._spaces[a] = gym_spaces.Box(0, 255, (h, w, self.n * c), np.uint8)
        self._stacks: dict[str, np.ndarray] = {}

    def observation_space(self, agent: str):
        return self._spaces[agent]

    def reset(self, seed: int | None = None, options: dict | None = None):
        obs, infos = self.env.reset(seed=seed, options=options)
        self._stacks = {a: np.concatenate([o] * self.n, axis=-1) for a, o in obs.items()}
        return {a: s.copy() for a, s in self._stacks.items()}, infos

    def step(self, actions: dict):
        obs, *rest = self.env.step(actions)
        out = {}
        for a, o in obs.items():
            c = o.shape[-1]
            self._stacks[a] = np.concatenate([self._stacks[a][..., c:], o], axis=-1)
            out[a] = self._stacks[a].copy()
        return (out, *rest)
