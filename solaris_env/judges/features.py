"""Judge features of frames and the Fréchet distance between two sets of them.

The five-task benchmark reports, next to judge accuracy, a Fréchet distance per task (the paper's FID
column). Without the standard InceptionV3 FID weights (nothing is downloaded) we use an in-domain
stand-in: the penultimate activations of the shipped single-frame probes (``visible``, ``position``,
``structure``; each the ReLU output of its hidden Dense layer, ``ProbeConfig.hidden`` = 64 wide),
concatenated per frame. These features were trained on engine frames to see players and structures,
so the distance is comparable between models on the same eval data, but NOT to FID numbers.

    features = FrameFeatures.load()                 # the shipped probes
    f_ND = features(frames_NHW3)                    # (N, 192) float64 for the default probes
    frechet_distance(f_ND, g_MD)                    # >= 0; 0 for identical sets
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from solaris_env.judges.episodes import resize_frame
from solaris_env.judges.judge import DEFAULT_WEIGHTS
from solaris_env.judges.probe import Probe, load_probe

FEATURE_PROBES = ("visible", "position", "structure")  # the single-frame questions
CHUNK = 256  # frames per jitted forward (the last chunk is padded)


def probe_penultimate(probe: Probe, x_BHWC: jax.Array) -> jax.Array:
    """Hidden-layer activations (B, hidden) of a single-frame probe for uint8 frames (B, H, W, 3)."""
    if probe.num_frames != 1:
        raise ValueError(f"penultimate features need a single-frame probe, this one takes {probe.num_frames}")
    x = x_BHWC.astype(jnp.float32) / 255.0
    f_BhwD = probe._encode(x)  # the same convs as Probe.__call__ (early fusion with F = 1 is the plain frame)
    return jax.nn.relu(probe.hidden(f_BhwD.reshape(x.shape[0], -1)))


def _penultimate(graphdef, state, x_BHWC):
    return probe_penultimate(nnx.merge(graphdef, state), x_BHWC)


_penultimate_jit = jax.jit(_penultimate, static_argnums=0)


class FrameFeatures:
    """Per-frame feature vectors: the concatenated penultimate activations of some single-frame probes.

    Args:
        probes: question name -> its trained single-frame :class:`Probe` (all with the same image size).
    """

    def __init__(self, probes: dict[str, Probe]):
        if not probes:
            raise ValueError("FrameFeatures needs at least one probe")
        sizes = {p.cfg.image_size for p in probes.values()}
        if len(sizes) != 1:
            raise ValueError(f"probes disagree on the input size: {sizes}")
        for name, p in probes.items():
            if p.num_frames != 1:
                raise ValueError(f"probe {name!r} takes {p.num_frames} frames; features need single-frame probes")
        self.names = tuple(probes)
        self.size = sizes.pop()
        self.dim = sum(p.cfg.hidden for p in probes.values())
        self._split = [nnx.split(p) for p in probes.values()]

    @classmethod
    def load(cls, directory: str | Path = DEFAULT_WEIGHTS, names: Sequence[str] = FEATURE_PROBES) -> FrameFeatures:
        """Probes ``<directory>/<name>.safetensors`` (default: the shipped ``visible``, ``position``, ``structure``)."""
        probes = {}
        for name in names:
            path = Path(directory) / f"{name}.safetensors"
            if not path.is_file():
                raise FileNotFoundError(f"no probe for {name!r}: {path} is missing")
            stored, probe, _ = load_probe(path)
            if stored != name:
                raise ValueError(f"{path} holds the probe of {stored!r}, not {name!r}")
            probes[name] = probe
        return cls(probes)

    def __call__(self, frames_NHW3: np.ndarray) -> np.ndarray:
        """uint8 frames (N, H, W, 3), any size (INTER_AREA to the probes' size) -> float64 (N, dim)."""
        frames_NHW3 = np.asarray(frames_NHW3)
        if frames_NHW3.ndim != 4 or frames_NHW3.shape[-1] != 3 or frames_NHW3.dtype != np.uint8:
            raise ValueError(f"frames must be uint8 (N, H, W, 3), got {frames_NHW3.dtype} {frames_NHW3.shape}")
        if frames_NHW3.shape[1:3] != (self.size, self.size):
            frames_NHW3 = np.stack([resize_frame(f, self.size) for f in frames_NHW3]) if len(frames_NHW3) else \
                np.zeros((0, self.size, self.size, 3), np.uint8)
        out = []
        for i in range(0, len(frames_NHW3), CHUNK):
            chunk = frames_NHW3[i:i + CHUNK]
            pad = CHUNK - len(chunk)
            if pad:
                chunk = np.concatenate([chunk, np.zeros((pad, *chunk.shape[1:]), chunk.dtype)])
            feats = [np.asarray(_penultimate_jit(g, s, chunk)) for g, s in self._split]
            out.append(np.concatenate(feats, axis=-1)[:CHUNK - pad])
        return np.concatenate(out).astype(np.float64) if out else np.zeros((0, self.dim), np.float64)


# ---------------------------------------------------------------------------------------------
# Fréchet distance
# ---------------------------------------------------------------------------------------------


def gaussian_stats(f_ND: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (D,) and covariance (D, D) (unbiased, as FID) of N >= 2 feature vectors."""
    f_ND = np.asarray(f_ND, np.float64)
    if f_ND.ndim != 2 or len(f_ND) < 2:
        raise ValueError(f"need (N >= 2, D) features, got shape {f_ND.shape}")
    return f_ND.mean(axis=0), np.cov(f_ND, rowvar=False).reshape(f_ND.shape[1], f_ND.shape[1])


def _psd_sqrt(a_DD: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh((a_DD + a_DD.T) / 2)
    return (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T


def frechet_distance_stats(mu1: np.ndarray, cov1: np.ndarray, mu2: np.ndarray, cov2: np.ndarray) -> float:
    """||mu1 - mu2||^2 + Tr(cov1 + cov2 - 2 (cov1 cov2)^(1/2)) of two Gaussians.

    Tr((cov1 cov2)^(1/2)) = Tr((s cov2 s)^(1/2)) with s = cov1^(1/2): a symmetric PSD matrix, so its
    square root comes from an eigendecomposition (stable also for singular covariances).
    """
    s = _psd_sqrt(cov1)
    w = np.linalg.eigvalsh((s @ cov2 @ s + (s @ cov2 @ s).T) / 2)
    tr_sqrt = float(np.sqrt(np.clip(w, 0.0, None)).sum())
    d = float(np.sum((mu1 - mu2) ** 2) + np.trace(cov1) + np.trace(cov2) - 2.0 * tr_sqrt)
    return max(d, 0.0)  # rounding can leave a tiny negative value for identical sets


def frechet_distance(f_ND: np.ndarray, g_MD: np.ndarray) -> float:
    """Fréchet distance between Gaussians fitted to two feature sets (N, D) and (M, D)."""
    if np.shape(f_ND)[1:] != np.shape(g_MD)[1:]:
        raise ValueError(f"feature sets differ in width: {np.shape(f_ND)} vs {np.shape(g_MD)}")
    return frechet_distance_stats(*gaussian_stats(f_ND), *gaussian_stats(g_MD))
