"""Sizes and thresholds of the judges: one frozen dataclass per component, nested in JudgeConfig.

- :class:`ProbeConfig`: the small CNN of one probe (input size, conv widths, head width).
- :class:`LabelConfig`: how the ground-truth sidecar becomes a label (ambiguity bands, motion and
  scenery thresholds, the camera model used to project placed blocks).
- :class:`TrainConfig`: the probe training run (steps, batch, learning rate, frame sampling).

Every number the judges use is a field here; ``__post_init__`` rejects bad values with a ValueError
that quotes them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from solaris_env.engine.constants import EYE_HEIGHT, FOV_DEG, PLAYER_HEIGHT
from solaris_env.engine.render import RenderConfig

FUSIONS = ("early", "late")


def _require(cond: bool, msg: str) -> None:
    if not cond:
        raise ValueError(msg)


@dataclass(frozen=True, slots=True)
class ProbeConfig:
    """One probe: ``len(channels)`` stride-2 3x3 convs (ReLU), flatten, a hidden Dense, the answer logits.

    With the defaults a 64x64 input ends as a 4x4x64 map (spatial layout kept for "where on screen"),
    ~127 k parameters (0.5 MB in float32) for a two-frame probe.

    ``fusion`` (two-frame questions): "early" stacks the frames on channels before the first conv (sees
    pixel motion; ``motion``); "late" runs the convs on each frame and combines the two maps as
    [a + b, |a - b|] (order-invariant comparison of two views; ``same_scenery``).
    """

    image_size: int = 64  # frames are resized (INTER_AREA) to image_size x image_size
    channels: tuple[int, ...] = (16, 32, 64, 64)
    kernel_size: int = 3
    hidden: int = 64
    fusion: str = "early"

    def __post_init__(self):
        _require(self.fusion in FUSIONS, f"fusion must be one of {FUSIONS}, got {self.fusion!r}")
        _require(self.image_size >= 8, f"image_size must be >= 8, got {self.image_size}")
        _require(len(self.channels) >= 1 and all(c >= 1 for c in self.channels),
                 f"channels must be positive, got {self.channels}")
        _require(self.image_size % (2 ** len(self.channels)) == 0,
                 f"image_size={self.image_size} must be divisible by 2**len(channels)={2 ** len(self.channels)}")
        _require(self.kernel_size >= 1, f"kernel_size must be >= 1, got {self.kernel_size}")
        _require(self.hidden >= 1, f"hidden must be >= 1, got {self.hidden}")

    @property
    def feature_size(self) -> int:
        """Side of the last conv map (the image halves once per conv)."""
        return self.image_size // (2 ** len(self.channels))


@dataclass(frozen=True, slots=True)
class LabelConfig:
    """Turning the engine's ground truth into the judges' answers.

    A label function returns None ("ambiguous, do not train or score on it") inside the bands below,
    so the probes learn from clear cases only.
    """

    # Visibility: 0 avatar pixels = "no"; at least min_visible_pixels = "yes"; in between ambiguous.
    min_visible_pixels: int = 2
    # Position: u within region_margin of a third boundary (1/3, 2/3) is ambiguous.
    region_margin: float = 0.03
    # Motion between two frames: lateral score = du / motion_u_threshold, radial score =
    # ln(d2 / d1) / motion_log_distance_threshold (d = distance between the players in blocks).
    motion_u_threshold: float = 0.08
    motion_log_distance_threshold: float = 0.15
    motion_still_max: float = 0.4  # both |scores| below this: "no motion"; between this and 1: ambiguous
    motion_dominance: float = 1.5  # the winning |score| must exceed the other by this factor
    # A player at least this far (blocks) covering 0-1 pixels is "too far to resolve" (at 64x64 a walker
    # 18 blocks away is ~2 pixels, often behind the crosshair): its motion is taken from its projected
    # body centre, so walking away until it vanishes is "farther". Nearer unseen players stay unknown.
    motion_far_distance: float = 14.0
    # Structure: a placed block whose centre projects on screen within this distance of the eye = "yes";
    # no placed block with any corner on screen = "no"; anything else ambiguous.
    structure_max_distance: float = 16.0
    # Same scenery: view directions within scenery_same_max_deg and feet within scenery_max_separation
    # blocks = "yes"; directions at least scenery_different_min_deg apart = "no"; else ambiguous.
    scenery_same_max_deg: float = 45.0
    scenery_different_min_deg: float = 110.0
    scenery_max_separation: float = 8.0
    # Camera model of the engine's frames (for projecting placed blocks).
    eye_height: float = EYE_HEIGHT
    avatar_centre_height: float = PLAYER_HEIGHT / 2  # body centre above the feet
    fov_deg: float = FOV_DEG  # vertical
    display_aspect: float = field(default_factory=lambda: RenderConfig().display_aspect)

    def __post_init__(self):
        _require(self.min_visible_pixels >= 1, f"min_visible_pixels must be >= 1, got {self.min_visible_pixels}")
        _require(0.0 <= self.region_margin < 1.0 / 6.0, f"region_margin must be in [0, 1/6), got {self.region_margin}")
        _require(self.motion_u_threshold > 0 and self.motion_log_distance_threshold > 0,
                 f"motion thresholds must be > 0, got {self.motion_u_threshold}, {self.motion_log_distance_threshold}")
        _require(0.0 < self.motion_still_max <= 1.0, f"motion_still_max must be in (0, 1], got {self.motion_still_max}")
        _require(self.motion_dominance >= 1.0, f"motion_dominance must be >= 1, got {self.motion_dominance}")
        _require(self.motion_far_distance > 0, f"motion_far_distance must be > 0, got {self.motion_far_distance}")
        _require(self.structure_max_distance > 0, f"structure_max_distance must be > 0, got {self.structure_max_distance}")
        _require(0.0 <= self.scenery_same_max_deg < self.scenery_different_min_deg <= 180.0,
                 f"need 0 <= scenery_same_max_deg < scenery_different_min_deg <= 180, got "
                 f"{self.scenery_same_max_deg}, {self.scenery_different_min_deg}")
        _require(self.scenery_max_separation > 0, f"scenery_max_separation must be > 0, got {self.scenery_max_separation}")
        _require(1.0 <= self.fov_deg < 180.0, f"fov_deg must be in [1, 180), got {self.fov_deg}")
        _require(self.display_aspect is not None and self.display_aspect > 0,
                 f"display_aspect must be > 0, got {self.display_aspect}")


@dataclass(frozen=True, slots=True)
class TrainConfig:
    """One probe's training run (the same for every question)."""

    steps: int = 2500
    batch_size: int = 64
    learning_rate: float = 2e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    frame_stride: int = 2  # frames of each video kept for training examples (every k-th)
    pair_gap: tuple[int, int] = (10, 60)  # two-frame questions: second frame 10..60 frames later
    pairs_per_frame: int = 3  # two-frame examples drawn per kept first frame
    still_pair_prob: float = 0.2  # motion: a kept frame also pairs with itself (a still view: "no motion")
    cross_episode_pairs: float = 0.25  # same_scenery: extra "no" pairs from two different normal worlds,
    # as a fraction of the within-episode pairs (the eval's hard "no" is a similar-looking but different view)
    brightness_jitter: float = 0.1  # frames are scaled by U(1 - j, 1 + j)
    featureless_fraction: float = 0.05  # extra examples per question made of featureless frames (dataset.py)
    log_every: int = 100

    def __post_init__(self):
        _require(self.steps >= 1, f"steps must be >= 1, got {self.steps}")
        _require(self.batch_size >= 1, f"batch_size must be >= 1, got {self.batch_size}")
        _require(self.learning_rate > 0, f"learning_rate must be > 0, got {self.learning_rate}")
        _require(0 <= self.warmup_steps < self.steps, f"warmup_steps must be in [0, steps={self.steps}), got "
                 f"{self.warmup_steps}")
        _require(self.frame_stride >= 1, f"frame_stride must be >= 1, got {self.frame_stride}")
        _require(1 <= self.pair_gap[0] <= self.pair_gap[1], f"pair_gap must be 1 <= lo <= hi, got {self.pair_gap}")
        _require(self.pairs_per_frame >= 1, f"pairs_per_frame must be >= 1, got {self.pairs_per_frame}")
        _require(0.0 <= self.still_pair_prob <= 1.0, f"still_pair_prob must be in [0, 1], got {self.still_pair_prob}")
        _require(self.cross_episode_pairs >= 0, f"cross_episode_pairs must be >= 0, got {self.cross_episode_pairs}")
        _require(0.0 <= self.brightness_jitter < 1.0, f"brightness_jitter must be in [0, 1), got {self.brightness_jitter}")
        _require(0.0 <= self.featureless_fraction <= 1.0,
                 f"featureless_fraction must be in [0, 1], got {self.featureless_fraction}")
        _require(self.log_every >= 1, f"log_every must be >= 1, got {self.log_every}")


@dataclass(frozen=True, slots=True)
class JudgeConfig:
    """Everything a judge run needs, nested. ``probe`` sizes every probe; the questions named in
    ``late_fusion`` get it with ``fusion="late"`` (:meth:`probe_for`)."""

    probe: ProbeConfig = ProbeConfig()
    labels: LabelConfig = LabelConfig()
    train: TrainConfig = TrainConfig()
    late_fusion: tuple[str, ...] = ("same_scenery",)

    def probe_for(self, question: str) -> ProbeConfig:
        return dataclasses.replace(self.probe, fusion="late" if question in self.late_fusion else "early")


# ---------------------------------------------------------------------------------------------
# (De)serialisation: configs travel in the safetensors metadata as JSON
# ---------------------------------------------------------------------------------------------


def config_to_dict(cfg) -> dict:
    return dataclasses.asdict(cfg)


def config_from_dict(cls, data: dict, where: str = "config"):
    """Rebuild a (nested) frozen config; unknown keys are an error naming them, tuples come back as tuples."""
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise ValueError(f"{where}: unknown keys {unknown}; known: {sorted(names)}")
    kwargs = {}
    for key, value in data.items():
        default = getattr(cls(), key)
        if dataclasses.is_dataclass(default):
            kwargs[key] = config_from_dict(type(default), value, f"{where}.{key}")
        elif isinstance(default, tuple):
            kwargs[key] = tuple(value)
        else:
            kwargs[key] = value
    return cls(**kwargs)
