"""The FID InceptionV3: 2048-d pool3 features of frames, for a true FID next to the in-domain Fréchet distance.

This is the network of TensorFlow's FID (the 2015-12-05 Inception graph) as ported to PyTorch by the
``pytorch-fid`` package: torchvision's InceptionV3 layout with the FID differences -- the average pools
inside the Mixed blocks ignore the zero padding (``count_include_pad=False``) and the last block
(``Mixed_7c``) max-pools in its pool branch. Frames are resized bilinearly to 299 x 299
(``align_corners=False``), scaled from [0, 1] to [-1, 1], and the features are the 2048-d output of the
global average pool after ``Mixed_7c``.

Weights are never downloaded. The user supplies the standard file ``pt_inception-2015-12-05-6726825d.pth``
(a plain torch state dict, published with the releases of github.com/mseitzer/pytorch-fid), loaded with
``torch.load(..., weights_only=True)``; its 1008-class ``fc`` is ignored.

FID numbers from these features are comparable to pytorch-fid's only for frames at the same resolution
resized the same way: our frames are 64 x 64 and upsampled to 299 x 299, so compare FIDs between
models on the same eval data, not with FIDs of other datasets or resolutions.

    features = InceptionFeatures.load("pt_inception-2015-12-05-6726825d.pth")
    f_ND = features(frames_NHW3)                    # (N, 2048) float64
    frechet_distance(f_ND, g_MD)                    # the FID of two frame sets
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

STANDARD_WEIGHTS = "pt_inception-2015-12-05-6726825d.pth"  # the pytorch-fid release file
INPUT_SIZE = 299  # frames are resized to INPUT_SIZE x INPUT_SIZE
POOL3_DIM = 2048  # the feature width: channels out of Mixed_7c
STEM_CHANNELS = 192  # channels into Mixed_5b
BN_EPS = 1e-3  # the TensorFlow graph's BatchNorm epsilon
IGNORED_KEYS = ("fc.weight", "fc.bias")  # the 1008-class classifier of the weights file; FID does not use it
OPTIONAL_SUFFIX = ".num_batches_tracked"  # BatchNorm step counters: unused in eval mode, may be absent
BATCH_SIZE = 32  # frames per forward (the last chunk is padded)

# ---------------------------------------------------------------------------------------------
# Layers
# ---------------------------------------------------------------------------------------------


def _same_padding(kernel: tuple[int, int], stride: int) -> tuple[int, int]:
    """Inside the Mixed blocks stride-1 convs keep the size and stride-2 convs use no padding."""
    return ((kernel[0] - 1) // 2, (kernel[1] - 1) // 2) if stride == 1 else (0, 0)


class ConvBN(nn.Module):
    """Conv2d (no bias) -> BatchNorm2d (eps 1e-3) -> ReLU; state-dict keys ``conv.weight`` and ``bn.*``.

    Args:
        c_in, c_out: channels.
        kernel: ``k`` or ``(kh, kw)``.
        stride: conv stride.
        padding: ``(ph, pw)``; None = ``_same_padding`` (the Mixed blocks' rule).
    """

    def __init__(self, c_in: int, c_out: int, kernel: int | tuple[int, int], stride: int = 1,
                 padding: tuple[int, int] | None = None):
        super().__init__()
        kernel = (kernel, kernel) if isinstance(kernel, int) else kernel
        padding = _same_padding(kernel, stride) if padding is None else padding
        self.conv = nn.Conv2d(c_in, c_out, kernel, stride=stride, padding=padding, bias=False)
        self.bn = nn.BatchNorm2d(c_out, eps=BN_EPS)

    def forward(self, x_NCHW: torch.Tensor) -> torch.Tensor:
        return F.relu(self.bn(self.conv(x_NCHW)))


def _chain(x: torch.Tensor, *layers: nn.Module) -> torch.Tensor:
    for layer in layers:
        x = layer(x)
    return x


def _avg_pool_keep(x: torch.Tensor) -> torch.Tensor:
    """3x3 average pool, stride 1, size kept; padded zeros are not counted (TensorFlow's pool, FID)."""
    return F.avg_pool2d(x, kernel_size=3, stride=1, padding=1, count_include_pad=False)


def _max_pool_keep(x: torch.Tensor) -> torch.Tensor:
    return F.max_pool2d(x, kernel_size=3, stride=1, padding=1)


def _max_pool_halve(x: torch.Tensor) -> torch.Tensor:
    return F.max_pool2d(x, kernel_size=3, stride=2)


# ---------------------------------------------------------------------------------------------
# Mixed blocks (each concatenates its branches on the channel axis)
# ---------------------------------------------------------------------------------------------


class Mixed35(nn.Module):
    """35 x 35 block (``Mixed_5b/c/d``): 1x1 | 1x1-5x5 | 1x1-3x3-3x3 | avg-pool-1x1 -> 224 + pool_features."""

    def __init__(self, c_in: int, pool_features: int):
        super().__init__()
        self.branch1x1 = ConvBN(c_in, 64, 1)
        self.branch5x5_1 = ConvBN(c_in, 48, 1)
        self.branch5x5_2 = ConvBN(48, 64, 5)
        self.branch3x3dbl_1 = ConvBN(c_in, 64, 1)
        self.branch3x3dbl_2 = ConvBN(64, 96, 3)
        self.branch3x3dbl_3 = ConvBN(96, 96, 3)
        self.branch_pool = ConvBN(c_in, pool_features, 1)
        self.out_channels = 64 + 64 + 96 + pool_features

    def forward(self, x_NCHW: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.branch1x1(x_NCHW),
                          _chain(x_NCHW, self.branch5x5_1, self.branch5x5_2),
                          _chain(x_NCHW, self.branch3x3dbl_1, self.branch3x3dbl_2, self.branch3x3dbl_3),
                          self.branch_pool(_avg_pool_keep(x_NCHW))], dim=1)


class Reduce35To17(nn.Module):
    """``Mixed_6a``: 3x3/2 | 1x1-3x3-3x3/2 | max-pool/2 -> 384 + 96 + c_in channels at 17 x 17."""

    def __init__(self, c_in: int):
        super().__init__()
        self.branch3x3 = ConvBN(c_in, 384, 3, stride=2)
        self.branch3x3dbl_1 = ConvBN(c_in, 64, 1)
        self.branch3x3dbl_2 = ConvBN(64, 96, 3)
        self.branch3x3dbl_3 = ConvBN(96, 96, 3, stride=2)
        self.out_channels = 384 + 96 + c_in

    def forward(self, x_NCHW: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.branch3x3(x_NCHW),
                          _chain(x_NCHW, self.branch3x3dbl_1, self.branch3x3dbl_2, self.branch3x3dbl_3),
                          _max_pool_halve(x_NCHW)], dim=1)


class Mixed17(nn.Module):
    """17 x 17 block (``Mixed_6b..e``) with factorised 7x7 convs (1x7 and 7x1) of ``c7`` channels -> 768."""

    def __init__(self, c_in: int, c7: int):
        super().__init__()
        self.branch1x1 = ConvBN(c_in, 192, 1)
        self.branch7x7_1 = ConvBN(c_in, c7, 1)
        self.branch7x7_2 = ConvBN(c7, c7, (1, 7))
        self.branch7x7_3 = ConvBN(c7, 192, (7, 1))
        self.branch7x7dbl_1 = ConvBN(c_in, c7, 1)
        self.branch7x7dbl_2 = ConvBN(c7, c7, (7, 1))
        self.branch7x7dbl_3 = ConvBN(c7, c7, (1, 7))
        self.branch7x7dbl_4 = ConvBN(c7, c7, (7, 1))
        self.branch7x7dbl_5 = ConvBN(c7, 192, (1, 7))
        self.branch_pool = ConvBN(c_in, 192, 1)
        self.out_channels = 4 * 192

    def forward(self, x_NCHW: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.branch1x1(x_NCHW),
                          _chain(x_NCHW, self.branch7x7_1, self.branch7x7_2, self.branch7x7_3),
                          _chain(x_NCHW, self.branch7x7dbl_1, self.branch7x7dbl_2, self.branch7x7dbl_3,
                                 self.branch7x7dbl_4, self.branch7x7dbl_5),
                          self.branch_pool(_avg_pool_keep(x_NCHW))], dim=1)


class Reduce17To8(nn.Module):
    """``Mixed_7a``: 1x1-3x3/2 | 1x1-1x7-7x1-3x3/2 | max-pool/2 -> 320 + 192 + c_in channels at 8 x 8."""

    def __init__(self, c_in: int):
        super().__init__()
        self.branch3x3_1 = ConvBN(c_in, 192, 1)
        self.branch3x3_2 = ConvBN(192, 320, 3, stride=2)
        self.branch7x7x3_1 = ConvBN(c_in, 192, 1)
        self.branch7x7x3_2 = ConvBN(192, 192, (1, 7))
        self.branch7x7x3_3 = ConvBN(192, 192, (7, 1))
        self.branch7x7x3_4 = ConvBN(192, 192, 3, stride=2)
        self.out_channels = 320 + 192 + c_in

    def forward(self, x_NCHW: torch.Tensor) -> torch.Tensor:
        return torch.cat([_chain(x_NCHW, self.branch3x3_1, self.branch3x3_2),
                          _chain(x_NCHW, self.branch7x7x3_1, self.branch7x7x3_2, self.branch7x7x3_3,
                                 self.branch7x7x3_4),
                          _max_pool_halve(x_NCHW)], dim=1)


class Mixed8(nn.Module):
    """8 x 8 block (``Mixed_7b/c``): 1x1 | 1x1-(1x3, 3x1) | 1x1-3x3-(1x3, 3x1) | pool-1x1 -> 2048.

    Args:
        c_in: input channels.
        max_pool: the pool branch max-pools (``Mixed_7c`` of the FID graph) instead of average-pooling.
    """

    def __init__(self, c_in: int, max_pool: bool):
        super().__init__()
        self.branch1x1 = ConvBN(c_in, 320, 1)
        self.branch3x3_1 = ConvBN(c_in, 384, 1)
        self.branch3x3_2a = ConvBN(384, 384, (1, 3))
        self.branch3x3_2b = ConvBN(384, 384, (3, 1))
        self.branch3x3dbl_1 = ConvBN(c_in, 448, 1)
        self.branch3x3dbl_2 = ConvBN(448, 384, 3)
        self.branch3x3dbl_3a = ConvBN(384, 384, (1, 3))
        self.branch3x3dbl_3b = ConvBN(384, 384, (3, 1))
        self.branch_pool = ConvBN(c_in, 192, 1)
        self.pool = _max_pool_keep if max_pool else _avg_pool_keep
        self.out_channels = 320 + 2 * 384 + 2 * 384 + 192

    def forward(self, x_NCHW: torch.Tensor) -> torch.Tensor:
        a = self.branch3x3_1(x_NCHW)
        b = _chain(x_NCHW, self.branch3x3dbl_1, self.branch3x3dbl_2)
        return torch.cat([self.branch1x1(x_NCHW),
                          self.branch3x3_2a(a), self.branch3x3_2b(a),
                          self.branch3x3dbl_3a(b), self.branch3x3dbl_3b(b),
                          self.branch_pool(self.pool(x_NCHW))], dim=1)


# ---------------------------------------------------------------------------------------------
# The network
# ---------------------------------------------------------------------------------------------


class FIDInceptionV3(nn.Module):
    """The FID InceptionV3 up to its 2048-d pool3 features (no classifier, no auxiliary head).

    ``forward`` takes float frames (N, 3, H, W) in [0, 1] of any size and returns (N, 2048).
    """

    def __init__(self):
        super().__init__()
        # stem: 299 -> 149 -> 147 -> 147 -> (max-pool) 73 -> 73 -> 71 -> (max-pool) 35
        self.Conv2d_1a_3x3 = ConvBN(3, 32, 3, stride=2, padding=(0, 0))
        self.Conv2d_2a_3x3 = ConvBN(32, 32, 3, padding=(0, 0))
        self.Conv2d_2b_3x3 = ConvBN(32, 64, 3, padding=(1, 1))
        self.Conv2d_3b_1x1 = ConvBN(64, 80, 1)
        self.Conv2d_4a_3x3 = ConvBN(80, STEM_CHANNELS, 3, padding=(0, 0))
        self.Mixed_5b = Mixed35(STEM_CHANNELS, pool_features=32)
        self.Mixed_5c = Mixed35(self.Mixed_5b.out_channels, pool_features=64)
        self.Mixed_5d = Mixed35(self.Mixed_5c.out_channels, pool_features=64)
        self.Mixed_6a = Reduce35To17(self.Mixed_5d.out_channels)
        self.Mixed_6b = Mixed17(self.Mixed_6a.out_channels, c7=128)
        self.Mixed_6c = Mixed17(self.Mixed_6b.out_channels, c7=160)
        self.Mixed_6d = Mixed17(self.Mixed_6c.out_channels, c7=160)
        self.Mixed_6e = Mixed17(self.Mixed_6d.out_channels, c7=192)
        self.Mixed_7a = Reduce17To8(self.Mixed_6e.out_channels)
        self.Mixed_7b = Mixed8(self.Mixed_7a.out_channels, max_pool=False)
        self.Mixed_7c = Mixed8(self.Mixed_7b.out_channels, max_pool=True)
        if self.Mixed_7c.out_channels != POOL3_DIM:
            raise ValueError(f"Mixed_7c gives {self.Mixed_7c.out_channels} channels, expected {POOL3_DIM}")

    def pool3(self, x_N3SS: torch.Tensor) -> torch.Tensor:
        """(N, 3, 299, 299) in [-1, 1] -> (N, 2048): the global average pool after Mixed_7c."""
        x = _chain(x_N3SS, self.Conv2d_1a_3x3, self.Conv2d_2a_3x3, self.Conv2d_2b_3x3)
        x = _chain(_max_pool_halve(x), self.Conv2d_3b_1x1, self.Conv2d_4a_3x3)
        x = _chain(_max_pool_halve(x), self.Mixed_5b, self.Mixed_5c, self.Mixed_5d, self.Mixed_6a,
                   self.Mixed_6b, self.Mixed_6c, self.Mixed_6d, self.Mixed_6e,
                   self.Mixed_7a, self.Mixed_7b, self.Mixed_7c)  # (N, 2048, 8, 8)
        return F.adaptive_avg_pool2d(x, 1).flatten(1)

    def forward(self, x_N3HW: torch.Tensor) -> torch.Tensor:
        x = F.interpolate(x_N3HW, size=(INPUT_SIZE, INPUT_SIZE), mode="bilinear", align_corners=False)
        return self.pool3(2.0 * x - 1.0)


# ---------------------------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------------------------


def _state_dict_problems(net: nn.Module, state: Mapping) -> list[str]:
    """Missing, unexpected and mis-shaped keys of ``state`` against ``net`` (``fc.*`` ignored)."""
    own = net.state_dict()
    problems = []
    for key, value in state.items():
        if key in IGNORED_KEYS:
            continue
        if key not in own:
            problems.append(f"unexpected key {key!r}")
        elif not isinstance(value, torch.Tensor):
            problems.append(f"key {key!r} holds a {type(value).__name__}, expected a tensor")
        elif tuple(value.shape) != tuple(own[key].shape):
            problems.append(f"key {key!r} has shape {tuple(value.shape)}, expected {tuple(own[key].shape)}")
    problems += [f"missing key {key!r}" for key in own if key not in state and not key.endswith(OPTIONAL_SUFFIX)]
    return problems


def load_fid_state_dict(net: FIDInceptionV3, state: Mapping, source: str = "state dict") -> FIDInceptionV3:
    """Copy ``state`` into ``net`` after a strict key and shape check; ValueError naming every bad key."""
    if not isinstance(state, Mapping):
        raise ValueError(f"{source}: expected a state dict (key -> tensor), got {type(state).__name__}")
    problems = _state_dict_problems(net, state)
    if problems:
        shown = "; ".join(problems[:10]) + (f"; ... ({len(problems) - 10} more)" if len(problems) > 10 else "")
        raise ValueError(f"{source} is not the FID InceptionV3 ({STANDARD_WEIGHTS}): {shown}")
    net.load_state_dict({k: v for k, v in state.items() if k not in IGNORED_KEYS}, strict=False)
    return net


def load_fid_inception(path: str | Path) -> FIDInceptionV3:
    """The FID InceptionV3 with the weights of ``path`` (a torch state dict), in eval mode, no gradients.

    Loaded with ``weights_only=True`` (no arbitrary unpickling); FileNotFoundError if absent, ValueError
    if a key is missing, unknown or mis-shaped. Never downloads anything.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no FID Inception weights at {path}: supply {STANDARD_WEIGHTS} "
                                "(from the pytorch-fid releases); nothing is downloaded")
    state = torch.load(path, map_location="cpu", weights_only=True)
    net = load_fid_state_dict(FIDInceptionV3(), state, source=str(path))
    net.eval()
    net.requires_grad_(False)
    return net


# ---------------------------------------------------------------------------------------------
# Features of uint8 frames
# ---------------------------------------------------------------------------------------------


class InceptionFeatures:
    """Per-frame FID features: uint8 frames (N, H, W, 3) -> pool3 activations (N, 2048) float64.

    Runs ``batch_size`` frames per forward (the last chunk zero-padded, its padding dropped) in eval mode
    under ``torch.no_grad()``; the torch thread count is left to the caller.

    Args:
        net: a loaded :class:`FIDInceptionV3` (see :func:`load_fid_inception`).
        batch_size: frames per forward.
        device: torch device of the forward passes.
    """

    dim = POOL3_DIM

    def __init__(self, net: FIDInceptionV3, batch_size: int = BATCH_SIZE, device: str = "cpu"):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.net = net.eval().to(device)
        self.batch_size = batch_size
        self.device = torch.device(device)

    @classmethod
    def load(cls, path: str | Path, batch_size: int = BATCH_SIZE, device: str = "cpu") -> InceptionFeatures:
        """Features of the FID InceptionV3 weights at ``path`` (see :func:`load_fid_inception`)."""
        return cls(load_fid_inception(path), batch_size, device)

    def __call__(self, frames_NHW3: np.ndarray) -> np.ndarray:
        frames_NHW3 = np.asarray(frames_NHW3)
        if frames_NHW3.ndim != 4 or frames_NHW3.shape[-1] != 3 or frames_NHW3.dtype != np.uint8:
            raise ValueError(f"frames must be uint8 (N, H, W, 3), got {frames_NHW3.dtype} {frames_NHW3.shape}")
        out_ND = np.zeros((len(frames_NHW3), self.dim), np.float64)
        with torch.no_grad():
            for i in range(0, len(frames_NHW3), self.batch_size):
                chunk = frames_NHW3[i:i + self.batch_size]
                n = len(chunk)
                if n < self.batch_size:
                    chunk = np.concatenate([chunk, np.zeros((self.batch_size - n, *chunk.shape[1:]), np.uint8)])
                x_BHW3 = torch.from_numpy(np.ascontiguousarray(chunk)).to(self.device)
                x_B3HW = x_BHW3.permute(0, 3, 1, 2).float() / 255.0
                out_ND[i:i + n] = self.net(x_B3HW)[:n].cpu().numpy()
        return out_ND
