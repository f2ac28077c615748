"""The probe network: a small CNN that answers one judge question from one or two frames.

Input ``x_BFHWC``: B queries of F frames (the question's ``num_frames``), H = W = ``image_size``,
C = 3, uint8 RGB, scaled to [0, 1] and passed through ``len(channels)`` stride-2 convs. Early fusion
stacks the F frames along channels first (a two-frame question sees motion from the first conv on);
late fusion runs the convs on each frame and combines two maps as [a + b, |a - b|] (the same answer
for either order). The last map is flattened (keeping where on screen things are) into a hidden
Dense layer and the answer logits ``logits_BA`` (A = the question's answers, in ``Question.answers``
order).

A two-frame early-fusion probe whose question has ``reverse_answers`` (``motion``) is equivariant to playing
the pair backwards: it runs the network on (a, b) and on (b, a) and averages the first logits with the second
ones permuted by ``Question.reverse_permutation`` (closer <-> farther, left <-> right). So answer(b, a) is the
reversed answer(a, b) for every input, in training and in use, and two identical frames give "closer" and
"farther" the same logit: a still view can no longer read as one direction only.

Weights travel as safetensors with the configs in the metadata (:func:`save_probe`,
:func:`load_probe`), written atomically.
"""

from __future__ import annotations

import itertools
import json
import os
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from solaris_env.judges import questions
from solaris_env.judges.config import ProbeConfig, config_from_dict, config_to_dict

FORMAT = "solaris_env.judge_probe/v1"


class Probe(nnx.Module):
    """CNN probe for one question.

    Args:
        cfg: the network sizes.
        num_frames: frames per query (F).
        num_answers: logits (A).
        rngs: parameter initialisation.
        reverse_perm: for a two-frame early-fusion probe, the answer permutation of the reversed pair
            (``Question.reverse_permutation``): the probe is made equivariant to the frame order (module doc).
    """

    def __init__(self, cfg: ProbeConfig, num_frames: int, num_answers: int, *, rngs: nnx.Rngs,
                 reverse_perm: tuple[int, ...] | None = None):
        if num_frames < 1 or num_answers < 2:
            raise ValueError(f"need num_frames >= 1 and num_answers >= 2, got {num_frames}, {num_answers}")
        if cfg.fusion == "late" and num_frames != 2:
            raise ValueError(f"late fusion compares two frames, got num_frames={num_frames}")
        if reverse_perm is not None:
            if num_frames != 2 or cfg.fusion != "early":
                raise ValueError(f"reverse_perm needs a two-frame early-fusion probe, got num_frames={num_frames}, "
                                 f"fusion={cfg.fusion!r}")
            if sorted(reverse_perm) != list(range(num_answers)):
                raise ValueError(f"reverse_perm must be a permutation of range({num_answers}), got {reverse_perm}")
            reverse_perm = tuple(int(i) for i in reverse_perm)
        self.cfg = cfg
        self.num_frames = num_frames
        self.reverse_perm = reverse_perm
        late = cfg.fusion == "late"
        widths = (3 if late else 3 * num_frames, *cfg.channels)
        k = cfg.kernel_size
        self.convs = nnx.List([nnx.Conv(cin, cout, kernel_size=(k, k), strides=(2, 2), padding="SAME", rngs=rngs)
                               for cin, cout in itertools.pairwise(widths)])
        flat = cfg.feature_size ** 2 * cfg.channels[-1] * (2 if late else 1)
        self.hidden = nnx.Linear(flat, cfg.hidden, rngs=rngs)
        self.head = nnx.Linear(cfg.hidden, num_answers, rngs=rngs)

    def _encode(self, x_NHWD: jax.Array) -> jax.Array:
        for conv in self.convs:
            x_NHWD = jax.nn.relu(conv(x_NHWD))  # each halves H and W
        return x_NHWD

    def __call__(self, x_BFHWC: jax.Array) -> jax.Array:
        """uint8 (or float in [0, 255]) frames (B, F, H, W, 3) -> logits (B, A)."""
        B, F, H, W, C = x_BFHWC.shape
        x = x_BFHWC.astype(jnp.float32) / 255.0
        if self.cfg.fusion == "late":
            f_BFhwD = self._encode(x.reshape(B * F, H, W, C)).reshape(B, F, *self._feature_shape())
            a, b = f_BFhwD[:, 0], f_BFhwD[:, 1]
            f_BhwD = jnp.concatenate([a + b, jnp.abs(a - b)], axis=-1)
            return self._logits(f_BhwD)
        if self.reverse_perm is not None:  # both orders in one batch: (a, b) then (b, a)
            x = jnp.concatenate([x, x[:, ::-1]], axis=0)
        logits = self._logits(self._encode(jnp.transpose(x, (0, 2, 3, 1, 4)).reshape(len(x), H, W, F * C)))
        if self.reverse_perm is None:
            return logits
        forward_BA, backward_BA = logits[:B], logits[B:]
        return 0.5 * (forward_BA + backward_BA[:, jnp.asarray(self.reverse_perm)])

    def _logits(self, f_BhwD: jax.Array) -> jax.Array:
        h_BD = jax.nn.relu(self.hidden(f_BhwD.reshape(len(f_BhwD), -1)))
        return self.head(h_BD)

    def _feature_shape(self) -> tuple[int, int, int]:
        s = self.cfg.feature_size
        return s, s, self.cfg.channels[-1]


def new_probe(question: str, cfg: ProbeConfig, seed: int) -> Probe:
    """A freshly initialised probe for ``question`` (use ``JudgeConfig.probe_for`` to pick its fusion)."""
    q = questions.get(question)
    return Probe(cfg, q.num_frames, q.num_answers, rngs=nnx.Rngs(seed), reverse_perm=_reverse_perm(q, cfg))


def _reverse_perm(q: questions.Question, cfg: ProbeConfig) -> tuple[int, ...] | None:
    """The reversal permutation the probe of ``q`` is built with: the question's, for an early-fusion probe
    (late fusion already answers both orders alike)."""
    return q.reverse_permutation() if cfg.fusion == "early" else None


def num_params(probe: Probe) -> int:
    return sum(int(np.prod(v.shape)) for v in jax.tree.leaves(nnx.state(probe, nnx.Param)))


# ---------------------------------------------------------------------------------------------
# safetensors I/O
# ---------------------------------------------------------------------------------------------


def _flat(state) -> dict[str, np.ndarray]:
    return {"/".join(map(str, path)): np.asarray(v.get_value() if isinstance(v, nnx.Variable) else v)
            for path, v in nnx.to_flat_state(state)}


def save_probe(path: str | Path, question: str, probe: Probe, extra: dict | None = None) -> Path:
    """Write the probe's parameters + its question and config (safetensors metadata) atomically."""
    from safetensors.numpy import save_file

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: np.ascontiguousarray(v, np.float32) for k, v in _flat(nnx.state(probe, nnx.Param)).items()}
    meta = {"format": FORMAT, "question": question, "probe_config": json.dumps(config_to_dict(probe.cfg)),
            "extra": json.dumps(extra or {})}
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        save_file(tensors, tmp, metadata=meta)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; shipped weights must be readable by all
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def read_metadata(path: str | Path) -> dict:
    """The probe file's metadata: question, probe_config (dict), extra (dict)."""
    from safetensors import safe_open

    with safe_open(str(path), framework="numpy") as f:
        meta = f.metadata() or {}
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path}: format {meta.get('format')!r}, expected {FORMAT!r}")
    return {"question": meta["question"], "probe_config": json.loads(meta["probe_config"]),
            "extra": json.loads(meta.get("extra", "{}"))}


def load_probe(path: str | Path) -> tuple[str, Probe, dict]:
    """(question, probe, extra) from a file written by :func:`save_probe`; shapes are checked."""
    from safetensors.numpy import load_file

    meta = read_metadata(path)
    cfg = config_from_dict(ProbeConfig, meta["probe_config"], f"{path}: probe_config")
    q = questions.get(meta["question"])
    abstract = nnx.eval_shape(lambda: Probe(cfg, q.num_frames, q.num_answers, rngs=nnx.Rngs(0),
                                            reverse_perm=_reverse_perm(q, cfg)))
    graphdef, state = nnx.split(abstract)
    values = load_file(str(path))
    expected = {"/".join(map(str, path)): tuple((v.get_value() if isinstance(v, nnx.Variable) else v).shape)
                for path, v in nnx.to_flat_state(nnx.state(abstract, nnx.Param))}
    found = {k: tuple(v.shape) for k, v in values.items()}
    if expected != found:
        missing, unexpected = sorted(set(expected) - set(found)), sorted(set(found) - set(expected))
        wrong = sorted(k for k in set(expected) & set(found) if expected[k] != found[k])
        raise ValueError(f"{path}: parameters do not match the {q.name} probe: missing {missing}, unexpected "
                         f"{unexpected}, wrong shapes {[(k, found[k], expected[k]) for k in wrong]}")
    flat = [(p, jnp.asarray(values["/".join(map(str, p))])) for p, _ in nnx.to_flat_state(state)]
    return q.name, nnx.merge(graphdef, nnx.from_flat_state(flat)), meta["extra"]
