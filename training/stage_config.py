"""The stage configs of ``solaris-train`` (docs/training.md, "Stage configs"): ``training/configs/<preset>.json``
(its ``extends`` chain resolved by ``training.config_files``) validated into frozen dataclasses, one per stage
kind, with every default in this module.

A block is built with ``from_dict(block, where)``: an unknown key, a missing required key, a value of the wrong
type or outside its range raises a ValueError that names ``where`` (the file and the stage), the field and what
it expects. ``TrainingConfig`` is the whole file: the preset, the seed, the ``collect`` block (``CollectConfig``:
``training.collect``), the ``all`` block (``AllConfig``: ``training.cli.budget_settings``) and one block per stage.
The sprint applies its overrides to ``to_dict()``'s blocks and validates the result again
(``training.sprint.stage_blocks``); its own ``collect`` block is a ``CollectConfig`` too.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path

from training.config_files import read_json_config

CONFIG_DIR = Path(__file__).parent / "configs"
STAGES = ("vae", "vae-decoder", "sp", "mp-bidirectional", "mp-causal", "self-forcing")  # ``all``, in order
ELASTIC_STAGES = ("sp", "mp-bidirectional", "mp-causal")  # may end early to keep ``all`` within its time budget
COLLECT_WORLDS = ("flat", "normal", "mixed")  # ``solaris-engine collect --world``
TIMES_OF_DAY = ("cycle", "day")  # ``solaris-engine collect --time-of-day`` (``engine.bots.runner.TIMES_OF_DAY``)


def _field(default=dataclasses.MISSING, *, low=None, high=None, above=None, below=None, choices=None):
    """A dataclass field with its allowed values: ``low <= x``, ``x <= high``, ``above < x``, ``x < below``,
    ``x in choices``."""
    return field(default=default, metadata={"low": low, "high": high, "above": above, "below": below,
                                            "choices": choices})


def _tuple_items(kind) -> tuple[type, int | None]:
    """A tuple field's item type and length: ``tuple[float, float]`` -> (float, 2), ``tuple[str, ...]`` ->
    (str, None: any length >= 1)."""
    args = typing.get_args(kind)
    return args[0], (None if args[-1] is Ellipsis else len(args))


def _expected(kind, meta: dict) -> str:
    """What a field takes, in words: "an int >= 1", "a number in [0, 1)", "one of ('mse', 'log_mse')"."""
    if meta.get("choices") is not None:
        return f"one of {meta['choices']}"
    if kind is bool:
        return "true or false"
    if kind is str:
        return "a string"
    if typing.get_origin(kind) is tuple:
        item, n = _tuple_items(kind)
        items = "strings" if item is str else "numbers"
        return f"a non-empty list of {items}" if n is None else f"a list of {n} {items}"
    if dataclasses.is_dataclass(kind):
        return f"an object with the keys of {kind.__name__}"
    words = "an int" if kind is int else "a number"
    low, high, above, below = (meta.get(k) for k in ("low", "high", "above", "below"))
    if low is not None and (below is not None or high is not None):
        return f"{words} in [{low:g}, {below:g})" if below is not None else f"{words} in [{low:g}, {high:g}]"
    bounds = [f">= {low:g}" if low is not None else None, f"> {above:g}" if above is not None else None,
              f"< {below:g}" if below is not None else None, f"<= {high:g}" if high is not None else None]
    return " ".join([words, *filter(None, bounds)])


def _convert(value, kind, meta: dict, where: str, name: str):
    """``value`` checked against the field's type and range (ints accepted for numbers, lists for tuples)."""
    optional = isinstance(kind, types.UnionType)  # ``X | None``
    if optional:
        if value is None:
            return None
        kind = next(k for k in typing.get_args(kind) if k is not type(None))
    if dataclasses.is_dataclass(kind) and isinstance(value, dict):
        return kind.from_dict(value, f"{where}: {name}")
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if typing.get_origin(kind) is tuple:
        item, n = _tuple_items(kind)
        ok = isinstance(value, (list, tuple)) and (len(value) == n if n is not None else len(value) >= 1) and all(
            isinstance(v, str) if item is str else isinstance(v, (int, float)) and not isinstance(v, bool)
            for v in value)
        value = tuple(v if item is str else float(v) for v in value) if ok else value
    elif kind is int:
        ok = number and isinstance(value, int)
    elif kind is float:
        ok, value = number, float(value) if number else value
    else:
        ok = isinstance(value, kind)
    low, high, above, below, choices = (meta.get(k) for k in ("low", "high", "above", "below", "choices"))
    ok = ok and (low is None or value >= low) and (high is None or value <= high) and (
        above is None or value > above) and (below is None or value < below) and (choices is None or value in choices)
    if not ok:
        expected = _expected(kind, meta) + (" or null" if optional else "")
        raise ValueError(f"{where}: {name} must be {expected}, got {value!r}")
    return value


@dataclass(frozen=True, kw_only=True)
class _Block:
    """A validated config block (module docstring)."""

    @classmethod
    def from_dict(cls, block: dict, where: str):
        fields = {f.name: f for f in dataclasses.fields(cls)}
        if not isinstance(block, dict):
            raise ValueError(  # noqa: TRY004  (a bad config is a ValueError throughout)
                f"{where}: expected an object with the keys of {cls.__name__}, got {block!r}")
        unknown = sorted(set(block) - set(fields))
        if unknown:
            raise ValueError(f"{where}: unknown keys {unknown}; {cls.__name__} takes {sorted(fields)}")
        missing = sorted(n for n, f in fields.items() if n not in block and f.default is dataclasses.MISSING)
        if missing:
            raise ValueError(f"{where}: missing keys {missing} (required by {cls.__name__})")
        hints = typing.get_type_hints(cls)
        return cls(**{n: _convert(v, hints[n], fields[n].metadata, where, n) for n, v in block.items()})


@dataclass(frozen=True, kw_only=True)
class StageConfig(_Block):
    """What every stage has: its updates, batch, clip length and loop cadences (``train.LoopSpec``;
    ``ckpt_every`` 0: no checkpoints)."""

    steps: int = _field(low=1)
    batch_size: int = _field(low=1)  # global: split over the processes (``train.local_batch_size``)
    num_frames: int = _field(low=1)  # frames of a training clip
    log_every: int = _field(low=1)
    ckpt_every: int = _field(low=0)


@dataclass(frozen=True, kw_only=True)
class VAEDecoderStageConfig(StageConfig):
    """``vae-decoder``: the VAE's decoder side fine-tuned on long clips (``train.train_vae_decoder``)."""

    lr: float = _field(above=0)
    sample_every: int = _field(low=0)  # held-out PSNR (the VAE: and a reconstruction) this often; 0: never
    eval_clips: int = _field(low=1)  # held-out clips of the PSNR
    rescan_s: float | None = _field(None, low=0)  # the sprint's growing data (``train.duet_stream``); None, 0: off


@dataclass(frozen=True, kw_only=True)
class VAEStageConfig(VAEDecoderStageConfig):
    """``vae``: the decoder stage's keys, ``stats_clips``, the clips of the latent statistics, and
    ``codec_fit_clips``, the clips whose patches fit a ``linear_patch`` codec (``VAEConfig.codec``)."""

    stats_clips: int = _field(low=1)
    codec_fit_clips: int = _field(2048, low=1)


@dataclass(frozen=True, kw_only=True)
class FlowStageConfig(StageConfig):
    """``sp``, ``mp-bidirectional``, ``mp-causal``: flow matching of the DiT (``train.train_flow``).
    ``ema_decay`` > 0: the stage saves that exponential moving average of the DiT's parameters (0: the spec's
    recipe).
    ``test_every`` > 0: every that many updates (and after the last) the loss of the parameters the stage would
    save, on ``test_batches`` fixed batches of the data's test split with fixed timesteps and noise, is logged as
    ``test_loss`` (the reference's cadence: 200 updates, 16 batches; docs/training.md).
    ``remat``: the backward pass recomputes each DiT layer from its input instead of keeping its activations: the
    same updates; 1.3-1.4x the steps per second of a tiny16 stage 3 on our memory-bound 2-core CPUs (session 66).
    The sprint turns it off on a GPU (``sprint-tiny.json``), where it would only add compute."""

    lr: float = _field(above=0)
    sample_every: int = _field(low=0)
    ema_decay: float = _field(0.0, low=0, below=1)
    rescan_s: float | None = _field(None, low=0)
    test_every: int = _field(0, low=0)  # held-out loss this often (``step.make_test_loss``); 0: never
    test_batches: int = _field(16, low=1)  # fixed batches of the data's test split it averages over
    remat: bool = _field(True)  # the backward pass recomputes each DiT layer (``step.make_train_step``)
    # the partner map only: the share of frames whose partner cells the camera warp's input loses (``step.drop_partner``)
    partner_dropout: float = _field(0.0, low=0, high=1)
    # the partner map only: the loss weight of the cells it marks (``step.partner_cells``) against 1 elsewhere
    partner_weight: float = _field(1.0, above=0)


@dataclass(frozen=True, kw_only=True)
class SelfForcingStageConfig(StageConfig):
    """``self-forcing``: Checkpointed Self Forcing with DMD (``train.train_self_forcing``; docs/model.md §6.3);
    ``generator``: how the generator's rollout is differentiated."""

    generator_lr: float = _field(above=0)
    critic_lr: float = _field(above=0)
    sample_every: int = _field(low=0)
    generator: str = _field("checkpointed", choices=("checkpointed", "naive"))
    rescan_s: float | None = _field(None, low=0)


@dataclass(frozen=True, kw_only=True)
class CollectConfig(_Block):
    """The ``collect`` block: the training data as ``solaris-engine collect`` records it
    (``training.collect.collect_argv``; ``solaris-train all``, the sprint's background collect). ``instances``:
    episode e runs on instance e mod this (the flat surface is instance mod 5, so >= 10 covers all five with
    ``world: mixed``); ``types``: only these episode types; ``time_of_day``: "day" records every episode at noon, as
    the envs start, "cycle" at a random time of day (``solaris-engine collect --time-of-day``). None: the
    engine's default."""

    episodes: int = _field(low=1)
    world: str = _field(choices=COLLECT_WORLDS)
    seed: int = _field(low=0)
    test_fraction: float = _field(low=0, high=1)  # the episodes in duet/test (``recorder.split_of``)
    instances: int | None = _field(None, low=1)
    types: tuple[str, ...] | None = _field(None)
    time_of_day: str | None = _field(None, choices=TIMES_OF_DAY)


@dataclass(frozen=True, kw_only=True)
class AllConfig(_Block):
    """The ``all`` block: the wall-clock budget of ``solaris-train all`` (``training.cli.budget_settings``,
    ``training.budget``). ``time_budget_min`` 0 or None: no budget, every stage runs its steps; else
    ``elastic_stage`` ends early so that ``reserve_min`` minutes are left for the stages after it
    (``--time-budget-min`` overrides the budget)."""

    time_budget_min: float | None = _field(None, low=0)
    elastic_stage: str = _field("mp-causal", choices=ELASTIC_STAGES)
    reserve_min: float = _field(0.0, low=0)


STAGE_CONFIGS: dict[str, type[StageConfig]] = {
    "vae": VAEStageConfig, "vae-decoder": VAEDecoderStageConfig, "sp": FlowStageConfig,
    "mp-bidirectional": FlowStageConfig, "mp-causal": FlowStageConfig,
    "self-forcing": SelfForcingStageConfig}


@dataclass(frozen=True)
class TrainingConfig:
    """A stage-config file: ``preset``, ``seed``, the ``collect`` block (None: ``all`` cannot record data), the
    ``all`` block (absent: its defaults, no budget) and ``stages`` ({stage: its block}; every stage of
    ``STAGES``)."""

    preset: str
    stages: dict
    seed: int = _field(0, low=0)
    collect: CollectConfig | None = None
    all: AllConfig = field(default_factory=AllConfig)

    @classmethod
    def from_dict(cls, data: dict, where: str) -> TrainingConfig:
        top = ("preset", "seed", "collect", "all")
        unknown = sorted(set(data) - set(top) - set(STAGE_CONFIGS))
        if unknown:
            raise ValueError(f"{where}: unknown keys {unknown}; expected {list(top)} and the stages "
                             f"{list(STAGES)}")
        missing = [s for s in ("preset", *STAGES) if s not in data]
        if missing:
            raise ValueError(f"{where}: missing keys {missing}")
        if not isinstance(data["preset"], str) or not data["preset"]:
            raise ValueError(f"{where}: preset must be a preset name, got {data['preset']!r}")
        stages = {s: STAGE_CONFIGS[s].from_dict(data[s], f"{where} [{s}]") for s in STAGE_CONFIGS if s in data}
        given = {}  # the optional keys present; the absent ones take the field defaults above
        if "seed" in data:
            seed_meta = next(f.metadata for f in dataclasses.fields(cls) if f.name == "seed")
            given["seed"] = _convert(data["seed"], int, seed_meta, where, "seed")
        if "collect" in data:
            given["collect"] = CollectConfig.from_dict(data["collect"], f"{where} [collect]")
        if "all" in data:
            given["all"] = AllConfig.from_dict(data["all"], f"{where} [all]")
        return cls(data["preset"], stages, **given)

    def to_dict(self) -> dict:
        """The file's layout (``from_dict(to_dict())`` gives this config back), every default written out."""
        out = {"preset": self.preset, "seed": self.seed, "all": dataclasses.asdict(self.all)}
        if self.collect is not None:
            out["collect"] = dataclasses.asdict(self.collect)
        return {**out, **{s: dataclasses.asdict(block) for s, block in self.stages.items()}}


def load_stage_config(preset_name: str, path: str | Path | None = None) -> TrainingConfig:
    """The validated stage config: ``path`` or ``training/configs/<preset>.json``."""
    path = Path(path) if path else CONFIG_DIR / f"{preset_name}.json"
    if not path.is_file():
        raise FileNotFoundError(f"no stage config {path}; presets with one: "
                                f"{sorted(p.stem for p in CONFIG_DIR.glob('*.json'))}")
    return TrainingConfig.from_dict(read_json_config(path), str(path))
