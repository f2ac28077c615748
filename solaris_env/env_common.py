"""What the real and the dream env share: per-agent spaces built once, and all players' frames side by side."""

from __future__ import annotations

import numpy as np


class PlayerViewsEnv:
    """Mixin for ParallelEnvs with one first-person view per player.

    The env builds ``self._observation_spaces`` / ``self._action_spaces`` (agent -> space) once in
    ``__init__`` and keeps the players' current frames in ``self._frames`` (P, H, W, 3).
    ``render_mode="rgb_array"`` returns the (H, P*W, 3) sheet; ``"human"`` shows it in an OpenCV window.
    """

    render_mode: str | None
    _frames: np.ndarray | None
    _observation_spaces: dict
    _action_spaces: dict

    def observation_space(self, agent: str):
        return self._observation_spaces[agent]

    def action_space(self, agent: str):
        return self._action_spaces[agent]

    def render(self) -> np.ndarray | None:
        if self.render_mode is None or self._frames is None:
            return None
        sheet = np.concatenate(list(self._frames), axis=1)  # (H, P*W, 3)
        if self.render_mode == "human":
            import cv2

            cv2.imshow(self.metadata["name"], cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
            cv2.waitKey(1)
            return None
        return sheet

    def close(self) -> None:
        if self.render_mode == "human":
            import cv2

            cv2.destroyAllWindows()
