"""The five judge questions of the paper's evaluation (docs/engine.md §7.2) and which eval type asks which.

A question fixes how many images it looks at, its answer vocabulary (the exact words the paper's VLM
is asked to answer with), and which prompt of ``eval_protocol.PROMPTS`` a VLM judge gets. The probe
of a question outputs one logit per answer, in ``answers`` order.

``flip_answers`` says how an answer changes when every image is mirrored left-right (the training
augmentation): screen left and right swap, nothing else changes. ``reverse_answers`` says how the answer of a
two-image question changes when the two images swap order: played backwards, a partner coming closer goes
farther and one moving left moves right. The probe of such a question scores both orders at once and so is
exactly consistent with itself: on two identical images "closer" and "farther" get the same probability
(``probe.Probe``).
"""

from __future__ import annotations

from dataclasses import dataclass

from solaris_env.engine.eval_protocol import EVAL_KEYS, PROMPTS


@dataclass(frozen=True, slots=True)
class Question:
    """One judge question.

    Attributes:
        name: our key (``visible``, ``position``, ``motion``, ``structure``, ``same_scenery``).
        answers: the answer words, in logit order.
        num_frames: images per query (two-frame questions see them in order).
        prompt_key: key into ``eval_protocol.PROMPTS`` (the paper's exact prompt).
        flip_answers: answer -> answer after mirroring the images left-right (identity if absent).
        reverse_answers: answer -> answer after swapping the two images (two-image questions whose answer
            depends on the order; empty: the order does not matter or the question has one image).
    """

    name: str
    answers: tuple[str, ...]
    num_frames: int
    prompt_key: str
    flip_answers: tuple[tuple[str, str], ...] = ()
    reverse_answers: tuple[tuple[str, str], ...] = ()

    @property
    def prompt(self) -> str:
        return PROMPTS[self.prompt_key]

    @property
    def num_answers(self) -> int:
        return len(self.answers)

    def index(self, answer: str) -> int:
        """Logit index of an answer; ValueError naming the vocabulary otherwise."""
        try:
            return self.answers.index(answer)
        except ValueError:
            raise ValueError(f"{self.name}: answer {answer!r} is not one of {self.answers}") from None

    def flip_permutation(self) -> tuple[int, ...]:
        """perm[i] = index of the answer that answer i becomes under a left-right mirror."""
        return self._permutation(self.flip_answers)

    def reverse_permutation(self) -> tuple[int, ...] | None:
        """perm[i] = index of the answer that answer i becomes when the two images swap order; None when the
        question has no ``reverse_answers``."""
        return self._permutation(self.reverse_answers) if self.reverse_answers else None

    def _permutation(self, pairs: tuple[tuple[str, str], ...]) -> tuple[int, ...]:
        swap = dict(pairs)
        return tuple(self.index(swap.get(a, a)) for a in self.answers)


_LR = (("left", "right"), ("right", "left"))
_BACKWARDS = (("closer", "farther"), ("farther", "closer"), *_LR)

QUESTIONS: dict[str, Question] = {q.name: q for q in (
    Question("visible", ("no", "yes"), 1, "one_looks_away"),
    Question("position", ("left", "center", "right", "no player"), 1, "rotation", _LR),
    Question("motion", ("closer", "farther", "left", "right", "no motion"), 2, "translation", _LR, _BACKWARDS),
    Question("structure", ("no", "yes"), 1, "structure"),
    Question("same_scenery", ("no", "yes"), 2, "turn_to_look"),
)}

# Eval type -> the question its queries ask (through the prompt key of docs/engine.md §7.2).
_PROMPT_QUESTION = {"translation": "motion", "rotation": "position", "one_looks_away": "visible",
                    "both_look_away": "visible", "structure": "structure", "turn_to_look": "same_scenery",
                    "turn_to_look_opposite": "same_scenery"}
EVAL_TYPE_QUESTION: dict[str, str] = {etype: _PROMPT_QUESTION[key] for etype, key in EVAL_KEYS.items()}

# The paper's five tasks (docs/engine.md §7.5): a task's accuracy is the mean of its eval types' accuracies.
TASKS: dict[str, tuple[str, ...]] = {
    "Movement": ("translationEval", "rotationEval"),
    "Grounding": ("oneLooksAwayEval",),
    "Memory": ("bothLookAwayEval",),
    "Building": ("structureEval",),
    "Consistency": ("turnToLookEval", "turnToLookOppositeEval"),
}


def get(name: str) -> Question:
    """The question called ``name``; ValueError listing the known ones otherwise."""
    if name not in QUESTIONS:
        raise ValueError(f"unknown question {name!r}; known: {sorted(QUESTIONS)}")
    return QUESTIONS[name]


def for_prompt_key(prompt_key: str) -> Question:
    """The question an eval query with this ``Query.prompt_key`` asks."""
    if prompt_key not in _PROMPT_QUESTION:
        raise ValueError(f"unknown prompt key {prompt_key!r}; known: {sorted(_PROMPT_QUESTION)}")
    return QUESTIONS[_PROMPT_QUESTION[prompt_key]]
