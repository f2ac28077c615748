"""Tasks: the rewards and terminations of an episode, computed from what the players see.

A :class:`Task` scores ONE world (all of its P players). The env calls ``reset`` when an episode starts and
``step`` once per env step with every frame of that step (k frames per player in the dream env, 1 in the
real env), the actions sent, and, in the real env only, the engine's ground truth (one dict per player:
the env's info dict with ``pos``, ``yaw``, ``pitch``, ``sees``, ``placed``, ``mined``). A task that needs
ground truth sets ``requires_truth = True``; the dream env refuses it. Vector envs build one task per world
(``make_task`` copies a given instance), so tasks may keep per-episode state.

Tasks (``TASKS``, the names ``task=`` accepts):

* ``"none"`` (:class:`NoTask`, the default): zero reward, never terminates.
* ``"visual_novelty"`` (:class:`VisualNoveltyTask`, frames only, works in the dream and the real env):
  a count-free exploration reward. Each player keeps a memory of small colour thumbnails of the views it
  has seen this episode; a view whose thumbnail is further than ``threshold`` (mean absolute colour
  difference in [0, 1]) from every remembered one earns ``distance - threshold`` and is remembered.
  Looking at the same scene again earns nothing, so the return grows only by turning to, walking to or
  building new sights. Measured in the engine at 64x64: turning 30 deg in a hilly world with trees moves a
  view 0.04-0.1 from the previous ones; in a flat world every direction looks alike (< 0.02: no reward),
  so exploration there has to walk or build. It never terminates (episodes end by truncation), unless ``target`` is set: then
  a player terminates once it has collected ``target`` novel views.
* ``"see_other_player"`` (:class:`SeeOtherPlayerTask`, real env only: ground truth): each step, the fraction
  of the other players that are visible on screen (from the renderer's per-pixel player ids).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np


class TaskStep(NamedTuple):
    rewards_P: np.ndarray  # (P,) float32
    terminations_P: np.ndarray  # (P,) bool


class Task:
    """Base class: zero reward, never terminates. Subclasses override ``reset``/``step``.

    Attributes:
        name: the registry name (``TASKS``).
        requires_truth: True when ``step`` reads the engine's ground truth (real env only).
    """

    name = "none"
    requires_truth = False

    def reset(self, frames_PHW3: np.ndarray, truth: Sequence[Mapping] | None = None) -> None:
        """Start an episode from each player's first frame (P, H, W, 3) uint8."""
        self.num_players = frames_PHW3.shape[0]

    def step(self, frames_PkHW3: np.ndarray, actions: Sequence[Mapping[str, Any]],
             truth: Sequence[Mapping] | None = None) -> TaskStep:
        """Score one env step.

        Args:
            frames_PkHW3: uint8 (P, k, H, W, 3), every frame of the step for every player.
            actions: the P env actions of the step (no-ops for players whose agent already ended).
            truth: per-player ground-truth dicts (real env) or None (dream env).
        """
        p = frames_PkHW3.shape[0]
        return TaskStep(np.zeros(p, np.float32), np.zeros(p, bool))


class NoTask(Task):
    """The default task: zero reward, never terminates."""


# ---------------------------------------------------------------------------------------------
# Visual novelty (frames only)
# ---------------------------------------------------------------------------------------------


def thumbnails(frames_NHW3: np.ndarray, size: int) -> np.ndarray:
    """(N, H, W, 3) uint8 -> (N, size, size, 3) float32 in [0, 1]: area-averaged colour thumbnails."""
    import cv2

    return np.stack([cv2.resize(f, (size, size), interpolation=cv2.INTER_AREA) for f in frames_NHW3]
                    ).astype(np.float32) / 255.0


class VisualNoveltyTask(Task):
    """Reward for seeing views unlike any seen before in the episode (see the module docstring).

    Args:
        threshold: views closer than this (mean absolute colour difference of thumbnails, in [0, 1]) to
            a remembered view count as already seen.
        thumb_size: thumbnail side in pixels (coarse on purpose: small shifts and generation noise blur out).
        memory: views remembered per player; the oldest is forgotten beyond it.
        target: terminate a player after this many novel views (None: never).
    """

    name = "visual_novelty"

    def __init__(self, threshold: float = 0.03, thumb_size: int = 8, memory: int = 512, target: int | None = None):
        if not 0.0 <= threshold < 1.0:
            raise ValueError(f"threshold must be in [0, 1), got {threshold}")
        if thumb_size < 1 or memory < 1:
            raise ValueError(f"thumb_size and memory must be >= 1, got {thumb_size} and {memory}")
        if target is not None and target < 1:
            raise ValueError(f"target must be None or >= 1, got {target}")
        self.threshold, self.thumb_size, self.memory, self.target = threshold, thumb_size, memory, target

    def reset(self, frames_PHW3: np.ndarray, truth=None) -> None:
        super().reset(frames_PHW3, truth)
        p, s = frames_PHW3.shape[0], self.thumb_size
        self._memory_PMss3 = np.zeros((p, self.memory, s, s, 3), np.float32)
        self._count_P = np.zeros(p, np.int64)  # views ever remembered (ring index = count % memory)
        self._novel_P = np.zeros(p, np.int64)
        self._remember(np.arange(p), thumbnails(frames_PHW3, s))

    def step(self, frames_PkHW3: np.ndarray, actions, truth=None) -> TaskStep:
        p = frames_PkHW3.shape[0]
        thumb_Pss3 = thumbnails(frames_PkHW3[:, -1], self.thumb_size)  # the view at the end of the step
        distance_P = self.distance_to_memory(thumb_Pss3)
        novel_P = distance_P > self.threshold
        self._remember(np.flatnonzero(novel_P), thumb_Pss3[novel_P])
        self._novel_P += novel_P
        rewards_P = np.where(novel_P, distance_P - self.threshold, 0.0).astype(np.float32)
        done_P = np.zeros(p, bool) if self.target is None else self._novel_P >= self.target
        return TaskStep(rewards_P, done_P)

    def distance_to_memory(self, thumb_Pss3: np.ndarray) -> np.ndarray:
        """(P,) smallest mean absolute difference between each player's thumbnail and its memory."""
        out = np.empty(len(thumb_Pss3), np.float32)
        for i, thumb in enumerate(thumb_Pss3):
            stored = self._memory_PMss3[i, : min(self._count_P[i], self.memory)]
            out[i] = np.abs(stored - thumb).mean(axis=(1, 2, 3)).min()
        return out

    def _remember(self, players: np.ndarray, thumbs_Nss3: np.ndarray) -> None:
        for i, thumb in zip(players, thumbs_Nss3):
            self._memory_PMss3[i, self._count_P[i] % self.memory] = thumb
            self._count_P[i] += 1


# ---------------------------------------------------------------------------------------------
# Ground-truth tasks (real env)
# ---------------------------------------------------------------------------------------------


class SeeOtherPlayerTask(Task):
    """Reward = the fraction of the other players visible on this player's screen (engine ground truth)."""

    name = "see_other_player"
    requires_truth = True

    def step(self, frames_PkHW3: np.ndarray, actions, truth=None) -> TaskStep:
        if truth is None:
            raise ValueError(f"task {self.name!r} needs the engine's ground truth; use it with the real env")
        p = frames_PkHW3.shape[0]
        rewards_P = np.array([np.mean(list(t["sees"].values())) if t["sees"] else 0.0 for t in truth], np.float32)
        return TaskStep(rewards_P, np.zeros(p, bool))


# ---------------------------------------------------------------------------------------------
# Registry
# ---------------------------------------------------------------------------------------------

TASKS: dict[str, type[Task]] = {t.name: t for t in (NoTask, VisualNoveltyTask, SeeOtherPlayerTask)}


def make_task(task: Any = None) -> Task:
    """``task=`` of the envs -> a fresh Task: None (zero reward), a name in ``TASKS``, a Task subclass (built
    with no arguments) or a Task instance (deep-copied, so every world gets its own state)."""
    if task is None:
        return NoTask()
    if isinstance(task, str):
        if task not in TASKS:
            raise ValueError(f"unknown task {task!r}; choose from {sorted(TASKS)} or pass a Task")
        return TASKS[task]()
    if isinstance(task, type) and issubclass(task, Task):
        return task()
    if isinstance(task, Task):
        return copy.deepcopy(task)
    raise ValueError(f"task must be None, a name in {sorted(TASKS)}, a Task subclass or a Task instance; "
                     f"got {type(task).__name__}")
