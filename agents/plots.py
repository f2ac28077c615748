"""Policy-evaluation pictures drawn with OpenCV (matplotlib is not a dependency), written atomically as PNG.

* :func:`scatter_png`: one point per policy at (real mean return, dream mean return) with its 95 % bootstrap
  intervals as error bars, the y = x diagonal (a perfect dream), the policies numbered with a legend on the right.
* :func:`frames_png`: what the numbers come from: per policy, the learner's frames of one episode in the
  engine over the same episode in the dream, at evenly spaced steps.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

WIDTH, HEIGHT = 960, 600  # pixels
PLOT_SIZE = 480  # the square plot area
MARGIN = 70  # left and top margins of the plot area
COLOURS_BGR = [(180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148), (75, 86, 140),
               (194, 119, 227), (127, 127, 127), (34, 189, 188), (207, 190, 23)]  # the "tab10" palette


def scatter_png(path: str | Path, names: Sequence[str], real: Sequence[dict], dream: Sequence[dict],
                title: str) -> Path:
    """Draw the plot. ``real`` / ``dream``: per policy ``{"mean", "ci_low", "ci_high"}`` (``stats.summarize``)."""
    import cv2

    if not (len(names) == len(real) == len(dream)) or not names:
        raise ValueError(f"need one real and one dream summary per policy, got {len(names)} names, "
                         f"{len(real)} real, {len(dream)} dream")
    values = np.array([[s["ci_low"], s["ci_high"]] for s in (*real, *dream)], np.float64)
    lo, hi = float(values.min()), float(values.max())
    pad = 0.05 * (hi - lo) if hi > lo else 1.0
    lo, hi = lo - pad, hi + pad

    def to_px(x: float, y: float) -> tuple[int, int]:
        return (round(MARGIN + (x - lo) / (hi - lo) * PLOT_SIZE),
                round(MARGIN + PLOT_SIZE - (y - lo) / (hi - lo) * PLOT_SIZE))

    img = np.full((HEIGHT, WIDTH, 3), 255, np.uint8)
    font, black, grey = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0), (200, 200, 200)
    for tick in np.linspace(lo, hi, 6):  # grid, tick labels
        x, y = to_px(tick, tick)
        cv2.line(img, (x, MARGIN), (x, MARGIN + PLOT_SIZE), grey, 1)
        cv2.line(img, (MARGIN, y), (MARGIN + PLOT_SIZE, y), grey, 1)
        cv2.putText(img, f"{tick:.1f}", (x - 14, MARGIN + PLOT_SIZE + 18), font, 0.4, black, 1, cv2.LINE_AA)
        cv2.putText(img, f"{tick:.1f}", (MARGIN - 45, y + 4), font, 0.4, black, 1, cv2.LINE_AA)
    cv2.rectangle(img, (MARGIN, MARGIN), (MARGIN + PLOT_SIZE, MARGIN + PLOT_SIZE), black, 1)
    cv2.line(img, to_px(lo, lo), to_px(hi, hi), (150, 150, 150), 1, cv2.LINE_AA)  # y = x
    cv2.putText(img, title, (MARGIN, 35), font, 0.55, black, 1, cv2.LINE_AA)
    cv2.putText(img, "real return (ground truth)", (MARGIN + PLOT_SIZE // 2 - 100, MARGIN + PLOT_SIZE + 45), font,
                0.5, black, 1, cv2.LINE_AA)
    cv2.putText(img, "dream return (judges)", (5, MARGIN - 12), font, 0.5, black, 1, cv2.LINE_AA)
    for i, (name, r, d) in enumerate(zip(names, real, dream)):
        colour = COLOURS_BGR[i % len(COLOURS_BGR)]
        cx, cy = to_px(r["mean"], d["mean"])
        cv2.line(img, to_px(r["ci_low"], d["mean"]), to_px(r["ci_high"], d["mean"]), colour, 1, cv2.LINE_AA)
        cv2.line(img, to_px(r["mean"], d["ci_low"]), to_px(r["mean"], d["ci_high"]), colour, 1, cv2.LINE_AA)
        cv2.circle(img, (cx, cy), 5, colour, -1, cv2.LINE_AA)
        cv2.putText(img, str(i + 1), (cx + 6, cy - 6), font, 0.45, colour, 1, cv2.LINE_AA)
        legend_y = MARGIN + 10 + 22 * i
        cv2.circle(img, (MARGIN + PLOT_SIZE + 30, legend_y - 4), 5, colour, -1, cv2.LINE_AA)
        label = f"{i + 1}. {name}"
        cv2.putText(img, label if len(label) <= 48 else label[:22] + "..." + label[-23:],
                    (MARGIN + PLOT_SIZE + 42, legend_y), font, 0.42, black, 1, cv2.LINE_AA)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.png")
    if not cv2.imwrite(str(tmp), img):  # drawn in BGR, OpenCV's order
        raise RuntimeError(f"OpenCV could not write {tmp}")
    os.replace(tmp, path)
    return path


FRAME_SCALE = 1  # contact-sheet pixels per frame pixel (the sheets stay ~1 MB: results live in every clone)
LABEL_WIDTH = 170  # the left strip with the policy's name and env


def frames_png(path: str | Path, names: Sequence[str], real: Sequence[Sequence[np.ndarray]],
               dream: Sequence[Sequence[np.ndarray]], columns: int = 6) -> Path:
    """A contact sheet: for each policy an engine row over a dream row, ``columns`` frames each, taken at evenly
    spaced steps of that episode (the first and the last frame included; a shorter episode repeats none).

    Args:
        names: the policies' names, one per row pair.
        real, dream: per policy the learner's (H, W, 3) uint8 RGB frames of one episode (reset frame first).
        columns: frames per row (>= 2).
    """
    import cv2

    if not (len(names) == len(real) == len(dream)) or not names:
        raise ValueError(f"need one real and one dream episode per policy, got {len(names)} names, "
                         f"{len(real)} real, {len(dream)} dream")
    if not isinstance(columns, int) or columns < 2:
        raise ValueError(f"columns must be an int >= 2, got {columns!r}")
    shapes = {np.shape(f) for episode in (*real, *dream) for f in episode}
    if any(len(e) == 0 for e in (*real, *dream)) or len(shapes) != 1 or len(next(iter(shapes))) != 3:
        raise ValueError(f"every episode needs frames of one (H, W, 3) shape, got shapes {sorted(shapes)} and "
                         f"lengths {[len(e) for e in (*real, *dream)]}")
    h, w, _ = next(iter(shapes))

    def row(episode: Sequence[np.ndarray]) -> np.ndarray:
        picks = np.unique(np.linspace(0, len(episode) - 1, columns).round().astype(int))
        strip = np.zeros((h, w * columns, 3), np.uint8)
        for j, i in enumerate(picks):
            strip[:, j * w:(j + 1) * w] = episode[i]
        return strip

    font, white = cv2.FONT_HERSHEY_SIMPLEX, (255, 255, 255)
    rows = []
    for name, r, d in zip(names, real, dream):
        for kind, episode in (("engine", r), ("dream", d)):
            big = cv2.resize(row(episode)[..., ::-1], None, fx=FRAME_SCALE, fy=FRAME_SCALE,
                             interpolation=cv2.INTER_NEAREST)
            label = np.zeros((big.shape[0], LABEL_WIDTH, 3), np.uint8)
            text = name if len(name) <= 22 else name[:9] + "..." + name[-10:]
            cv2.putText(label, text, (6, 20), font, 0.45, white, 1, cv2.LINE_AA)
            cv2.putText(label, f"{kind}, {len(episode) - 1} steps", (6, 40), font, 0.42, white, 1, cv2.LINE_AA)
            rows.append(np.concatenate([label, big], 1))
        rows.append(np.full((4, rows[-1].shape[1], 3), 255, np.uint8))  # a white line between policies
    img = np.concatenate(rows[:-1], 0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp.png")
    if not cv2.imwrite(str(tmp), img):  # BGR, OpenCV's order
        raise RuntimeError(f"OpenCV could not write {tmp}")
    os.replace(tmp, path)
    return path
