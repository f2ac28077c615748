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

Partner tasks (two players; :class:`PartnerTask`): ONE reward definition, scored from a ``source`` chosen at
construction: ``"judge"`` (the shipped CNN judges of ``solaris_env.judges`` read the frames, one batched call
over the players: works in the dream and the real env) or ``"truth"`` (the real env's ground truth; the dream
env refuses it). The judge answers the same question the truth answers exactly, so the dream return of a
policy (judge) and its real return (truth) are on one scale. Registered twice: ``"<name>"`` is the judge
variant, ``"<name>_truth"`` the ground-truth one.

* ``"face_partner"`` / ``"face_partner_truth"`` (:class:`FacePartnerTask`): 1 for each step that ends with
  the partner in the centre third of the player's screen, else 0.
* ``"approach_partner"`` / ``"approach_partner_truth"`` (:class:`ApproachPartnerTask`): +1 for a step after
  which the player is clearly closer to the partner than ``gap`` steps before (while the partner is on
  screen), -1 when clearly farther, else 0.

Building (:class:`BuildStructureTask`, judge or truth like the partner tasks, any number of players):
``"build_structure"`` / ``"build_structure_truth"``: 1 for each step that ends with a block built this
episode on the player's screen (the ``structure`` question), else 0.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable, Mapping, Sequence
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
# Partner tasks (two players): the judges read the frames, or the engine gives the truth
# ---------------------------------------------------------------------------------------------

REWARD_SOURCES = ("judge", "truth")


@functools.lru_cache(maxsize=4)
def shared_judge(directory: str | None = None):
    """The probes of ``directory`` (None: the shipped ``solaris_env/assets/judges/``), loaded once per process:
    tasks are deep-copied per world, so they look the judge up here instead of holding it."""
    from solaris_env.judges import Judge

    return Judge.load() if directory is None else Judge.load(directory)


def partner_screen(truth_player: Mapping) -> dict:
    """The partner's entry of one player's ground truth: ``{"pixels": n, "u": centroid in [0, 1] | None}``."""
    screen = truth_player.get("screen")
    if screen is None:
        raise ValueError("ground truth has no 'screen' entry (RealParallelEnv infos have it); got keys "
                         f"{sorted(truth_player)}")
    if len(screen) != 1:
        raise ValueError(f"a partner task needs exactly one other player; the truth lists {sorted(screen)}")
    return next(iter(screen.values()))


def judge_centred(judge, frames_NHW3: np.ndarray) -> np.ndarray:
    """(N,) bool: the judge sees the partner ("visible": "yes") in the centre ("position": "center")."""
    visible_N = np.array(judge.answer("visible", frames_NHW3)) == "yes"
    return visible_N & (np.array(judge.answer("position", frames_NHW3)) == "center")


class JudgedTask(Task):
    """Base of the tasks scored from one ``source``: ``"judge"`` (the shipped CNN judges read the frames: dream
    and real env) or ``"truth"`` (the real env's ground truth answers the same question; ``requires_truth``,
    the dream env refuses it).

    Args:
        source: ``"judge"`` or ``"truth"``.
        judge_dir: probe weights for ``source="judge"`` (None: the shipped ``solaris_env/assets/judges/``).

    The thresholds (pixels that make a player "visible", the motion threshold, the structure distance) are the
    judges' labelling rules (``solaris_env.judges.config.LabelConfig``), so the truth is what the probes were
    trained to answer.
    """

    base_name = "judged"

    def __init__(self, source: str = "judge", judge_dir: str | None = None):
        from solaris_env.judges.config import LabelConfig

        if source not in REWARD_SOURCES:
            raise ValueError(f"source must be one of {REWARD_SOURCES}, got {source!r}")
        if judge_dir is not None and source != "judge":
            raise ValueError(f"judge_dir is only used with source='judge', got source={source!r}")
        self.source, self.judge_dir = source, None if judge_dir is None else str(judge_dir)
        self.requires_truth = source == "truth"
        self.name = self.base_name if source == "judge" else f"{self.base_name}_truth"
        self.labels = LabelConfig()

    @property
    def judge(self):
        return shared_judge(self.judge_dir)

    def _truth(self, truth: Sequence[Mapping] | None) -> Sequence[Mapping]:
        if truth is None:
            raise ValueError(f"task {self.name!r} (source='truth') needs the engine's ground truth; in the dream "
                             f"env use {self.base_name!r} (source='judge')")
        if len(truth) != self.num_players:
            raise ValueError(f"truth must hold one dict per player ({self.num_players}), got {len(truth)}")
        return truth


class PartnerTask(JudgedTask):
    """Base of the two-player tasks: a reward about the partner (the other player). See :class:`JudgedTask`."""

    base_name = "partner"

    def reset(self, frames_PHW3: np.ndarray, truth: Sequence[Mapping] | None = None) -> None:
        super().reset(frames_PHW3, truth)
        if self.num_players != 2:
            raise ValueError(f"task {self.name!r} is about one partner: it needs num_players=2, got {self.num_players}")

    def _visible_truth(self, truth_player: Mapping) -> bool:
        return partner_screen(truth_player)["pixels"] >= self.labels.min_visible_pixels


class FacePartnerTask(PartnerTask):
    """Reward 1 for each step that ends with the partner centred on the player's screen, else 0.

    Judge: for the step's last frame the ``visible`` probe says "yes" and the ``position`` probe "center" (the
    visibility gate removes most false centres: on 64x64 engine frames with no partner the position probe alone
    said "center" in 1 of 187 flat and 11 of 176 normal-world views, with the gate in 0 and 6; it cost no true
    centre). Truth: at least ``min_visible_pixels`` avatar pixels whose centroid lies in the middle third of the
    screen (the split of the judge's "left" / "center" / "right", ``engine.capture``). Never terminates.
    """

    base_name = "face_partner"

    def step(self, frames_PkHW3: np.ndarray, actions, truth=None) -> TaskStep:
        p = frames_PkHW3.shape[0]
        if self.source == "judge":
            centred_P = judge_centred(self.judge, frames_PkHW3[:, -1])
        else:
            centred_P = np.array([self._centred_truth(t) for t in self._truth(truth)])
        return TaskStep(centred_P.astype(np.float32), np.zeros(p, bool))

    def _centred_truth(self, truth_player: Mapping) -> bool:
        from solaris_env.engine.capture import REGION_LEFT_MAX_U, REGION_RIGHT_MIN_U

        u = partner_screen(truth_player)["u"]
        return self._visible_truth(truth_player) and REGION_LEFT_MAX_U <= u < REGION_RIGHT_MIN_U


class ApproachPartnerTask(PartnerTask):
    """+1 for a step after which the player is clearly closer to the partner than ``gap`` steps before, -1
    when clearly farther, 0 otherwise; only while the partner is on screen.

    Judge: the ``visible`` probe says "yes" for both frames and the ``motion`` probe, shown (the frame
    ``gap`` steps ago, the frame now), answers "closer" / "farther". Both, because the truth's rule below needs
    the partner's screen position in both frames: a partner that leaves the screen has no motion answer, and
    on such pairs (a close avatar, then none) the probe, never trained on them, said "farther" (63 false -1s
    on 564 steps of seeker-walk episodes, docs/evaluation.md). Truth: the answer the motion probe was
    trained to give, by its labelling rule (``judges.labels.motion_class``): the partner is clearly visible (at
    least ``min_visible_pixels``) in either frame and has a screen position in both (its avatar's centroid, or,
    at ``motion_far_distance`` blocks or more, the projection of its body centre); the distance's log ratio
    ln(d_now / d_then) is the radial score and the centroid's shift the lateral one, and "closer" / "farther"
    needs the radial score beyond the threshold and dominant. A player pressed against the partner, whose avatar
    fills or leaves the screen, earns nothing for the jitter of a tiny distance. Early in an episode the first
    frame stands in for the frame ``gap`` steps ago. Never terminates.

    Args:
        gap: env steps between the compared frames. The motion probe was trained on pairs 10-60 video frames
            apart; with the dream's k = 4 frames per step the default 3 steps is 12 frames (walking covers
            ~2.6 blocks, a clear "closer" from the spawn distance of 6-10 blocks).
        source, judge_dir: see :class:`PartnerTask`.
    """

    base_name = "approach_partner"

    def __init__(self, source: str = "judge", judge_dir: str | None = None, gap: int = 3):
        super().__init__(source, judge_dir)
        if not isinstance(gap, (int, np.integer)) or gap < 1:
            raise ValueError(f"gap must be an int >= 1, got {gap!r}")
        self.gap = int(gap)

    def reset(self, frames_PHW3: np.ndarray, truth=None) -> None:
        super().reset(frames_PHW3, truth)
        # the last `gap` steps, oldest first: frames (judge) or partner distances (truth), and visibility
        self._history: list[tuple[Any, np.ndarray]] = [self._observe(frames_PHW3, truth)]

    def step(self, frames_PkHW3: np.ndarray, actions, truth=None) -> TaskStep:
        p = frames_PkHW3.shape[0]
        then, visible_then_P = self._history[0]
        now, visible_now_P = self._observe(frames_PkHW3[:, -1], truth)
        self._history = (self._history + [(now, visible_now_P)])[-self.gap:]  # next step compares with t+1-gap
        if self.source == "judge":  # only with the partner on screen in both frames (the class doc)
            motion_P = np.where(visible_then_P & visible_now_P, self.judge.answer("motion", then, now), None)
        else:  # None unless the partner is on screen: the label rule
            motion_P = np.array([self._motion_truth(a, b) for a, b in zip(then, now)])
        rewards_P = (motion_P == "closer").astype(np.float32) - (motion_P == "farther").astype(np.float32)
        return TaskStep(rewards_P.astype(np.float32), np.zeros(p, bool))

    def _observe(self, frames_PHW3: np.ndarray, truth) -> tuple[Any, np.ndarray]:
        """What a step keeps: (frames (P, H, W, 3) or per player (distance, screen u or None, clearly visible),
        partner visible (P,) bool)."""
        if self.source == "judge":
            return frames_PHW3.copy(), np.array(self.judge.answer("visible", frames_PHW3)) == "yes"
        from solaris_env.judges.labels import far_screen_u, visibility_of

        truth = self._truth(truth)
        pos_P3 = np.stack([np.asarray(t["pos"], np.float64) for t in truth])
        distance_P = np.linalg.norm(pos_P3 - pos_P3[::-1], axis=-1)  # two players: each one's partner is the other
        seen = []
        for t, d, partner_3 in zip(truth, distance_P, pos_P3[::-1]):
            screen = partner_screen(t)
            clear = visibility_of(screen["pixels"], self.labels)
            u = screen["u"] if clear else None
            if not clear and d >= self.labels.motion_far_distance:  # too far to resolve: where it would be
                eye = np.asarray(t["pos"], np.float64) + np.array([0.0, self.labels.eye_height, 0.0])
                u = far_screen_u(eye, float(t["yaw"]), float(t["pitch"]), partner_3, self.labels)
            seen.append((float(d), u, clear is True))
        return seen, np.array([s[2] for s in seen])

    def _motion_truth(self, then: tuple, now: tuple) -> str | None:
        """The motion label of one player's partner between two observations (d, u, clearly visible)."""
        from solaris_env.judges.labels import motion_class, motion_scores_of

        (d1, u1, clear1), (d2, u2, clear2) = then, now
        if not (clear1 or clear2) or u1 is None or u2 is None:
            return None
        return motion_class(*motion_scores_of(u1, u2, d1, d2, self.labels), self.labels)


class BuildStructureTask(JudgedTask):
    """Reward 1 for each step that ends with a structure the players built this episode on the player's screen
    (within ``LabelConfig.structure_max_distance`` blocks), else 0: place blocks ahead, then keep them in view.

    Judge: the ``structure`` probe says "yes" for the step's last frame. Truth: the blocks placed minus those
    mined since ``reset`` (the real env's ``placed`` / ``mined`` infos, any player's) projected from the
    player's pose (``judges.labels.structure_on_screen``, the probe's labelling rule; an ambiguous view, a
    block only partly on screen, counts 0). In the flat worlds of the start states every raised block is a
    built one, which is what the probe learned. Never terminates.
    """

    base_name = "build_structure"

    def reset(self, frames_PHW3: np.ndarray, truth: Sequence[Mapping] | None = None) -> None:
        super().reset(frames_PHW3, truth)
        self._built: dict[tuple[int, int, int], None] = {}

    def step(self, frames_PkHW3: np.ndarray, actions, truth=None) -> TaskStep:
        p = frames_PkHW3.shape[0]
        if self.source == "judge":
            seen_P = np.array(self.judge.answer("structure", frames_PkHW3[:, -1])) == "yes"
        else:
            seen_P = self._seen_truth(self._truth(truth))
        return TaskStep(seen_P.astype(np.float32), np.zeros(p, bool))

    def _seen_truth(self, truth: Sequence[Mapping]) -> np.ndarray:
        from solaris_env.judges.labels import structure_on_screen

        for t in truth:  # this step's edits (x, y, z, block), every player's (placed before mined, as applied)
            self._built.update((tuple(int(c) for c in cell[:3]), None) for cell in t.get("placed", ()))
            for cell in t.get("mined", ()):
                self._built.pop(tuple(int(c) for c in cell[:3]), None)
        cells_N3 = np.asarray(list(self._built), np.float64).reshape(-1, 3)
        seen = []
        for t in truth:
            eye_3 = np.asarray(t["pos"], np.float64) + np.array([0.0, self.labels.eye_height, 0.0])
            seen.append(structure_on_screen(cells_N3, eye_3, float(t["yaw"]), float(t["pitch"]), self.labels) == "yes")
        return np.array(seen)


# ---------------------------------------------------------------------------------------------
# Registry
# ---------------------------------------------------------------------------------------------

PARTNER_TASKS: dict[str, type[PartnerTask]] = {t.base_name: t for t in (FacePartnerTask, ApproachPartnerTask)}
JUDGED_TASKS: dict[str, type[JudgedTask]] = {**PARTNER_TASKS, BuildStructureTask.base_name: BuildStructureTask}

TASKS: dict[str, Callable[[], Task]] = {
    **{t.name: t for t in (NoTask, VisualNoveltyTask, SeeOtherPlayerTask)},
    **{name: functools.partial(cls, source="judge") for name, cls in JUDGED_TASKS.items()},
    **{f"{name}_truth": functools.partial(cls, source="truth") for name, cls in JUDGED_TASKS.items()},
}


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
