"""Rendering shared by the real and the dream env: all players' current frames side by side."""

from __future__ import annotations

import numpy as np


class SideBySideRender:
    """Mixin for ParallelEnvs that keep their players' current frames in ``self._frames`` (P, H, W, 3).

    ``render_mode="rgb_array"`` returns the (H, P*W, 3) sheet; ``"human"`` shows it in an OpenCV window.
    """

    render_mode: str | None
    _frames: np.ndarray | None

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
