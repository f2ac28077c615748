"""The ``Judge`` API: answer the paper's judge questions about frames with the trained probes.

    from solaris_env.judges import Judge
    judge = Judge.load()                                   # the shipped probes (solaris_env/assets/judges/)
    judge.answer("visible", frames_NHW3)                   # -> ["yes", "no", ...]
    judge.answer("motion", first_NHW3, second_NHW3)        # two-frame questions take two batches
    judge.answer("same_scenery", alpha_NHW3, bravo_NHW3)

Frames are RGB uint8, (N, H, W, 3) batches or single (H, W, 3) frames, any size (resized with
INTER_AREA to the probe's input). A question takes exactly ``Question.num_frames`` arguments, all
with the same N. Batches run through one jitted forward in fixed-size chunks (one compile per probe).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import jax
import numpy as np
from flax import nnx

from solaris_env.judges import questions
from solaris_env.judges.episodes import resize_frame
from solaris_env.judges.probe import Probe, load_probe

DEFAULT_WEIGHTS = Path(__file__).resolve().parent.parent / "assets" / "judges"
CHUNK = 64  # queries per jitted forward at most (a smaller last chunk is padded to a power of two)


def _padded_size(n: int) -> int:
    """The batch a chunk of ``n`` queries runs at: the next power of two, at most ``CHUNK`` (few compiled shapes;
    an env step's 2 frames no longer pay for 64)."""
    return min(CHUNK, 1 << max(n - 1, 0).bit_length())


def _forward(graphdef, state, x_BFHWC):
    return jax.nn.softmax(nnx.merge(graphdef, state)(x_BFHWC), axis=-1)


_forward_jit = jax.jit(_forward, static_argnums=0)


class Judge:
    """Answers judge questions with one probe per question.

    Args:
        probes: question name -> its trained :class:`Probe` (any subset of the five questions).
    """

    def __init__(self, probes: Mapping[str, Probe]):
        for name, probe in probes.items():
            q = questions.get(name)
            if probe.num_frames != q.num_frames:
                raise ValueError(f"probe for {name} takes {probe.num_frames} frames, the question {q.num_frames}")
        self._split = {name: nnx.split(probe) for name, probe in probes.items()}
        self._size = {name: probe.cfg.image_size for name, probe in probes.items()}

    @classmethod
    def load(cls, directory: str | Path = DEFAULT_WEIGHTS, names: list[str] | None = None) -> Judge:
        """Probes from ``<directory>/<question>.safetensors`` (default: the shipped ones, all five)."""
        directory = Path(directory)
        names = list(questions.QUESTIONS) if names is None else [questions.get(n).name for n in names]
        probes = {}
        for name in names:
            path = directory / f"{name}.safetensors"
            if not path.is_file():
                raise FileNotFoundError(f"no probe for {name!r}: {path} is missing (train it with "
                                        f"python -m solaris_env.judges.train)")
            stored, probe, _ = load_probe(path)
            if stored != name:
                raise ValueError(f"{path} holds the probe of {stored!r}, not {name!r}")
            probes[name] = probe
        return cls(probes)

    @property
    def questions(self) -> list[str]:
        return list(self._split)

    def _inputs(self, question: str, frames: tuple) -> np.ndarray:
        q = questions.get(question)
        if question not in self._split:
            raise ValueError(f"this judge has no probe for {question!r}; it has {self.questions}")
        if len(frames) != q.num_frames:
            raise ValueError(f"{question} takes {q.num_frames} frame batch(es), got {len(frames)}")
        batches = []
        for k, f in enumerate(frames):
            f = np.asarray(f)
            if f.ndim == 3:
                f = f[None]
            if f.ndim != 4 or f.shape[-1] != 3 or f.dtype != np.uint8:
                raise ValueError(f"{question}: frames[{k}] must be uint8 (N, H, W, 3) or (H, W, 3), got "
                                 f"{f.dtype} {f.shape}")
            size = self._size[question]
            batches.append(np.stack([resize_frame(x, size) for x in f]) if len(f) else
                           np.zeros((0, size, size, 3), np.uint8))
        if len({len(b) for b in batches}) != 1:
            raise ValueError(f"{question}: frame batches differ in length: {[len(b) for b in batches]}")
        return np.stack(batches, axis=1)  # (N, F, S, S, 3)

    def probabilities(self, question: str, *frames) -> np.ndarray:
        """(N, A) answer probabilities, columns in ``Question.answers`` order."""
        x_NFHWC = self._inputs(question, frames)
        graphdef, state = self._split[question]
        N = len(x_NFHWC)
        out = []
        for i in range(0, N, CHUNK):
            chunk = x_NFHWC[i:i + CHUNK]
            n = len(chunk)
            pad = _padded_size(n) - n
            if pad:
                chunk = np.concatenate([chunk, np.zeros((pad, *chunk.shape[1:]), chunk.dtype)])
            out.append(np.asarray(_forward_jit(graphdef, state, chunk))[:n])
        return np.concatenate(out) if out else np.zeros((0, questions.get(question).num_answers), np.float32)

    def answer(self, question: str, *frames) -> list[str]:
        """The most likely answer word per query."""
        answers = questions.get(question).answers
        return [answers[i] for i in self.probabilities(question, *frames).argmax(axis=-1)]
