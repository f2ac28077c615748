"""Episode-level scoring of the paper (docs/engine.md §7.5, the paper's appendix "Evaluation Details").

An episode counts as accurate iff the judge's answer matches the expected answer at every query of
the episode, over all query points and perspectives (Memory: 2 points x 2 players = 4 queries;
Consistency: 1 query showing both players). Queries the judge could not answer (``answer`` None,
e.g. a VLM API error) are left out, as in the reference; an episode without any answered query is
left out. A task's accuracy is the mean over its eval types (Movement = translation + rotation,
Consistency = same side + opposite sides; equal to pooling when the types have equal episode counts).

The judge is anything with ``answer(question, *frame_batches) -> list[str | None]`` (the probe
:class:`Judge` or :class:`VLMJudge`); frames come from a ``frames(episode, bot, index) -> HxWx3``
callable, so generated videos can be judged with the same queries (the ground truth by default).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from solaris_env.engine.eval_protocol import Query
from solaris_env.judges import questions
from solaris_env.judges.episodes import Episode, read_video


@dataclass(frozen=True)
class QueryResult:
    """One answered query: which episode (``eval_type`` + ``episode`` key), its index, expected and given answer."""

    eval_type: str
    episode: str
    index: int
    question: str
    expected: str
    answer: str | None

    @property
    def correct(self) -> bool:
        return self.answer is not None and self.answer.strip().lower() == self.expected


def query_views(query: Query) -> list[tuple[str, int]]:
    """(bot, frame) of each image of a query: one bot per image, or all images from ``bots[0]``."""
    if len(query.bots) == len(query.frames):
        return list(zip(query.bots, query.frames))
    if len(query.bots) == 1:
        return [(query.bots[0], f) for f in query.frames]
    raise ValueError(f"query with bots {query.bots} and frames {query.frames}: cannot pair them")


def episode_accuracy(results: Iterable[QueryResult]) -> dict[str, dict]:
    """Per eval type: ``episodes`` (scored), ``correct`` (all queries right), ``accuracy`` (fraction),
    ``queries``, ``query_accuracy``, ``unanswered`` (queries left out)."""
    by_episode: dict[tuple[str, str], list[QueryResult]] = defaultdict(list)
    for r in results:
        by_episode[(r.eval_type, r.episode)].append(r)
    stats: dict[str, dict] = defaultdict(lambda: {"episodes": 0, "correct": 0, "queries": 0, "queries_correct": 0,
                                                  "unanswered": 0})
    for (etype, _), rs in sorted(by_episode.items()):
        s = stats[etype]
        answered = [r for r in rs if r.answer is not None]
        s["unanswered"] += len(rs) - len(answered)
        s["queries"] += len(answered)
        s["queries_correct"] += sum(r.correct for r in answered)
        if answered:
            s["episodes"] += 1
            s["correct"] += all(r.correct for r in answered)
    out = {}
    for etype, s in sorted(stats.items()):
        out[etype] = {**s, "accuracy": s["correct"] / s["episodes"] if s["episodes"] else float("nan"),
                      "query_accuracy": s["queries_correct"] / s["queries"] if s["queries"] else float("nan")}
    return out


def task_accuracy(per_type: dict[str, dict]) -> dict[str, float]:
    """The paper's five tasks: mean episode accuracy of their eval types (types not scored are skipped)."""
    out = {}
    for task, types in questions.TASKS.items():
        accs = [per_type[t]["accuracy"] for t in types if t in per_type and per_type[t]["episodes"]]
        if accs:
            out[task] = float(np.mean(accs))
    return out


# ---------------------------------------------------------------------------------------------
# Judging episodes
# ---------------------------------------------------------------------------------------------


def ground_truth_frames(size: int | None = None) -> Callable[[Episode, str, int], np.ndarray]:
    """A ``frames(episode, bot, index)`` source reading the recorded videos; keeps the videos of the
    current episode only (episodes are judged one after the other)."""
    cache: dict[str, np.ndarray] = {}
    current: list[str] = [""]

    def frames(ep: Episode, bot: str, index: int) -> np.ndarray:
        if current[0] != ep.key:
            cache.clear()
            current[0] = ep.key
        if bot not in cache:
            cache[bot] = read_video(ep.video_path(bot), size)
        video = cache[bot]
        if not 0 <= index < len(video):
            raise ValueError(f"{ep.key}: frame {index} of {bot} outside its {len(video)} frames")
        return video[index]

    return frames


def judge_episodes(judge, episodes: Sequence[Episode],
                   frames: Callable[[Episode, str, int], np.ndarray] | None = None) -> list[QueryResult]:
    """Ask ``judge`` every query of every eval episode (batched per question); returns one result per query."""
    frames = frames or ground_truth_frames()
    pending: dict[str, list[tuple[Episode, int, Query, list[np.ndarray]]]] = defaultdict(list)
    for ep in episodes:
        for i, query in enumerate(ep.queries()):
            q = questions.for_prompt_key(query.prompt_key)
            pending[q.name].append((ep, i, query, [frames(ep, bot, f) for bot, f in query_views(query)]))
    results = []
    for name, items in pending.items():
        F = questions.get(name).num_frames
        batches = [np.stack([imgs[k] for _, _, _, imgs in items]) for k in range(F)]
        answers = judge.answer(name, *batches)
        results += [QueryResult(ep.episode_type, ep.key, i, name, query.expected, a)
                    for (ep, i, query, _), a in zip(items, answers)]
    return results
