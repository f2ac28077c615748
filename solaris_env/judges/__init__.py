"""Judges of the paper's evaluation (docs/engine.md §7): small CNN probes trained on engine ground truth.

The paper's judge is a cloud VLM; ours are five probes, one per question (``questions.QUESTIONS``:
visible, position, motion, structure, same_scenery), trained on engine frames with the labels of
the ground-truth sidecar (:mod:`labels`) and shipped under ``solaris_env/assets/judges/``. The
optional :mod:`vlm` judge sends the paper's exact prompts to an OpenAI-compatible endpoint.

    from solaris_env.judges import Judge
    judge = Judge.load()
    judge.answer("position", frames_NHW3)        # ["left", "no player", ...]

Modules: ``config`` (sizes, thresholds), ``questions``, ``labels`` (ground truth -> answers),
``probe`` (the CNN, safetensors I/O), ``episodes`` / ``dataset`` (collected data -> examples),
``train`` (``python -m solaris_env.judges.train``), ``judge`` (the API), ``scoring`` (episode-level
accuracy), ``evaluate`` (``python -m solaris_env.judges.evaluate``), ``vlm``.
"""

from solaris_env.judges.judge import DEFAULT_WEIGHTS, Judge
from solaris_env.judges.questions import EVAL_TYPE_QUESTION, QUESTIONS, TASKS, Question
from solaris_env.judges.scoring import (
           QueryResult,
           episode_accuracy,
           judge_episodes,
           task_accuracy,
)

__all__ = [
           "DEFAULT_WEIGHTS",
           "EVAL_TYPE_QUESTION",
           "QUESTIONS",
           "TASKS",
           "Judge",
           "QueryResult",
           "Question",
           "episode_accuracy",
           "judge_episodes",
           "task_accuracy",
]
