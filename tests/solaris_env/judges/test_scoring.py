"""Episode-level scoring (the paper's rule) on hand-built results, and judging collected episodes end to end."""

import math

import numpy as np
import pytest

from solaris_env.engine.eval_protocol import Query
from solaris_env.judges import questions
from solaris_env.judges.scoring import (
    QueryResult,
    episode_accuracy,
    ground_truth_frames,
    judge_episodes,
    query_views,
    task_accuracy,
)


def r(etype, ep, i, expected, answer, question="visible"):
    return QueryResult(etype, ep, i, question, expected, answer)


def test_an_episode_is_correct_only_if_all_its_queries_are():
    results = [
        r("bothLookAwayEval", "e0", 0, "no", "no"), r("bothLookAwayEval", "e0", 1, "yes", "yes"),
        r("bothLookAwayEval", "e0", 2, "no", "no"), r("bothLookAwayEval", "e0", 3, "yes", "yes"),
        r("bothLookAwayEval", "e1", 0, "no", "no"), r("bothLookAwayEval", "e1", 1, "yes", "no"),
        r("bothLookAwayEval", "e1", 2, "no", "no"), r("bothLookAwayEval", "e1", 3, "yes", "yes"),
        r("bothLookAwayEval", "e2", 0, "no", " No\n"), r("bothLookAwayEval", "e2", 1, "yes", None),  # VLM-style answer, API error
    ]
    s = episode_accuracy(results)["bothLookAwayEval"]
    assert (s["episodes"], s["correct"]) == (3, 2)  # e0 all right, e1 one wrong, e2 its answered query right
    assert s["accuracy"] == pytest.approx(2 / 3)
    assert (s["queries"], s["queries_correct"], s["unanswered"]) == (9, 8, 1)
    assert s["query_accuracy"] == pytest.approx(8 / 9)


def test_episodes_without_answers_are_left_out_and_types_kept_apart():
    results = [r("rotationEval", "a", 0, "left", None, "position"),
               r("rotationEval", "b", 0, "left", "left", "position"),
               r("structureEval", "a", 0, "yes", "no", "structure")]
    per_type = episode_accuracy(results)
    assert per_type["rotationEval"]["episodes"] == 1 and per_type["rotationEval"]["accuracy"] == 1.0
    assert per_type["structureEval"]["accuracy"] == 0.0
    assert math.isnan(episode_accuracy([r("rotationEval", "a", 0, "left", None)])["rotationEval"]["accuracy"])


def test_task_accuracy_is_the_mean_over_its_eval_types():
    per_type = {"translationEval": {"episodes": 4, "accuracy": 1.0}, "rotationEval": {"episodes": 4, "accuracy": 0.5},
                "structureEval": {"episodes": 2, "accuracy": 0.5}, "turnToLookEval": {"episodes": 0, "accuracy": 0.0}}
    assert task_accuracy(per_type) == {"Movement": 0.75, "Building": 0.5}


def test_query_views_pair_bots_and_frames():
    assert query_views(Query(("Alpha",), (10, 50), "left", "translation", 10)) == [("Alpha", 10), ("Alpha", 50)]
    assert query_views(Query(("Alpha", "Bravo"), (80, 80), "yes", "turn_to_look", 60)) == [("Alpha", 80),
                                                                                           ("Bravo", 80)]
    with pytest.raises(ValueError, match="cannot pair"):
        query_views(Query(("Alpha", "Bravo"), (1, 2, 3), "yes", "turn_to_look", 0))


class ConstantJudge:
    """Answers every query with the same word (and records what it was asked)."""

    def __init__(self, word):
        self.word, self.asked = word, []

    def answer(self, question, *frames):
        self.asked.append((question, [np.asarray(f).shape for f in frames]))
        return [self.word] * len(frames[0])


def test_judge_episodes_asks_each_query_with_its_frames(episodes):
    eps = list(episodes.values())
    judge = ConstantJudge("yes")
    results = judge_episodes(judge, eps, ground_truth_frames())
    assert len(results) == sum(len(e.queries()) for e in eps)
    for question, shapes in judge.asked:
        q = questions.get(question)
        assert len(shapes) == q.num_frames and all(s[1:] == (64, 64, 3) for s in shapes)
    per_type = episode_accuracy(results)
    # "yes" is right for the same-side consistency and building queries, wrong for the rest
    assert per_type["turnToLookEval"]["accuracy"] == 1.0 and per_type["structureEval"]["accuracy"] == 1.0
    assert per_type["turnToLookOppositeEval"]["accuracy"] == 0.0
    assert per_type["oneLooksAwayEval"]["accuracy"] == 0.0  # its "no" query fails
    assert per_type["oneLooksAwayEval"]["query_accuracy"] == 0.5
