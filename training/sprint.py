"""``solaris-train sprint``: a complete world model trained within a wall-clock budget, data made meanwhile.

    solaris-train sprint --preset tiny --out OUT --budget-min 8.5 [--init default|PATH] [--data DIR] [--config JSON]
        [--workers N]

One command for a borrowed accelerator (docs/training.md, "GPU sprint"): whatever ``jax.devices()`` holds
(a GPU there, the CPU here) trains while the engine records episodes on the CPU cores.

* **Data while training.** ``Collector`` runs the engine's ``collect`` jobs (``solaris_env.engine.cli``; the
  config's ``collect`` block as ``training.collect.collect_argv`` reads it: >= 10 instances with ``world: mixed``
  give all five flat surfaces and the normal worlds; the seed moves on by 1000 per sprint generation, so a
  continued model sees new episodes) in a ``spawn`` pool of background processes (CPU-only JAX, lower
  priority) writing the usual Duet layout, ``test_fraction`` of the episodes held out in ``duet/test``
  (when a VAE stage will run, a held-out episode is recorded first: they evaluate on it). Training starts once
  ``min_train_episodes`` exist (episodes already in ``--data`` count). Every stage reads the training
  split through ``training.growing_data.growing_stream`` (``train.duet_stream`` / ``vpt_stream`` with the
  stage-config key ``rescan_s``): every ``rescan_s`` seconds the episodes completed since join the sampler; the
  single-player stage reads each bot's view of the Duet episodes instead of a VPT export. The draws depend on
  when episodes arrive: a sprint is neither resumable nor bit-for-bit repeatable, unlike ``solaris-train all``.
* **Stages and time.** From scratch: the VAE, the VAE decoder, stages 1-3 and Self Forcing
  (``training.train``'s functions, ``train.call_stage``) with the config's ``fractions``; from a
  model (``--init``, which has its VAE): the DiT stages with ``fractions_from_init``. A stage is
  open-ended and stops at its deadline (``LoopSpec.deadline``). When a stage is about to start, the time
  left (the budget's end - now - ``reserve_s``, kept for what follows the last stage's last step: its
  teardown, which stops the background encoder and saves its model, and the final export) is planned over
  it and the stages after it (``plan_shares``): each costs its ``overhead_s`` (loading, JIT compiles, the latent
  cache, the VAE's statistics, the save; per device kind) plus a share of the rest
  by fraction; while the overheads and ``min_train_s`` each do not fit, the stage with the smallest
  fraction is dropped. Once stages have run, the overheads are scaled by how those compared with theirs
  (the mean of time-to-first-step / ``overhead_s``, within 0.5-4), so the plan adapts to the machine. A
  stage that overruns its share is paid for by the stages after it; the budget counts from the process's
  start (imports, compiles, the wait for data: all of it). A skipped stage (fraction 0 or dropped) passes
  its input on: its ``model/`` is a link to the previous stage's (from ``--init``, ``vae/`` and
  ``vae-decoder/`` are the init model), so every stage finds the models it reads (Self Forcing's teacher
  is the mp-bidirectional model, whatever that is then).
* **Per device kind** (``devices.<platform>``, platform = ``jax.devices()[0].platform``): background
  ``workers`` (0: every core but two) and their ``worker_nice``, ``reserve_s``, ``min_train_s``,
  ``overhead_s`` per stage and stage-block overrides (``stages``: bigger batches on a GPU). Compute stays
  float32: ``DiTConfig.dtype`` has a bfloat16 setting, but nothing tests training in it (and on GPUs
  XLA's default precision already runs float32 matmuls on the tensor cores). With ``compile_cache``,
  JAX's persistent compilation cache lives in ``WORK/jax-cache`` unless one is configured already (later
  stages recompile the same latent encoder and rollout programs; the collect workers share it).
* **Exports.** ``OUT/model/``: ``checkpoint.save`` with ``shard_bytes`` (safetensors shards of at most
  ``export.shard_mib`` MiB, ``export.max_total_mib`` in all, float16 storage), ``config.json`` and
  ``lineage.json``, rewritten atomically every ``save_every_min`` minutes from the stage ``export_from`` on
  (the live train state, through the stage functions' ``on_model``; skipped when, timed as the previous
  one, it would end past the stage's deadline) and at the end (the last stage's model), so a run killed at
  its limit leaves the last complete model. ``lineage.json``: the command, the
  init model and its own lineage, the devices, per stage its share, wall time, steps and the data it saw,
  the git commit, start and end. ``solaris-train install OUT/model`` makes it the default;
  ``--init OUT/model`` continues it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import shutil
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from solaris_env.paths import portable_text
from training.collect import collect_argv
from training.config_files import read_json_config
from training.growing_data import STREAMS, data_record
from training.stage_config import (
    STAGE_CONFIGS,
    STAGES,
    CollectConfig,
    TrainingConfig,
    load_stage_config,
)

logger = logging.getLogger(__name__)

CONFIG_DIR = Path(__file__).parent / "configs"
REPO = Path(__file__).resolve().parent.parent
LINEAGE_FILE = "lineage.json"
LINEAGE_FORMAT = "solaris_env.sprint_lineage"
VAE_STAGES = ("vae", "vae-decoder")
OPEN_ENDED_STEPS = 10**9  # a sprint stage runs until its deadline
HEARTBEAT_S = 30.0  # a progress line at most this often inside the DiT stages


# ---------------------------------------------------------------------------------------------
# Config
# ---------------------------------------------------------------------------------------------


def _number(value, where: str, low: float = 0.0, integer: bool = False):
    """``value`` if it is a number >= ``low`` (an int with ``integer``), else a ValueError naming ``where``."""
    kind = int if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kind) or not value >= low:
        raise ValueError(f"{where} must be {'an int' if integer else 'a number'} >= {low:g}, got {value!r}")
    return value


@dataclass(frozen=True)
class DeviceSettings:
    """What depends on the accelerator: background collect ``workers`` (0: every core but two) and their
    niceness (> 0: below the trainer), the time kept for the final export, the least training time worth a
    stage's overhead, each stage's overhead (seconds besides its training steps) and stage-block overrides
    ({stage: {key: value}})."""

    workers: int
    worker_nice: int
    reserve_s: float
    min_train_s: float
    overhead_s: dict
    stages: dict

    @classmethod
    def from_dict(cls, block: dict, where: str) -> DeviceSettings:
        keys = [f.name for f in dataclasses.fields(cls)]
        if sorted(block) != sorted(keys):
            raise ValueError(f"{where} must have exactly the keys {keys}, got {sorted(block)}")
        for name in ("overhead_s", "stages"):
            unknown = sorted(set(block[name]) - set(STAGES))
            if unknown:
                raise ValueError(f"{where}.{name} names unknown stages {unknown}; expected stages of {STAGES}")
        missing = sorted(set(STAGES) - set(block["overhead_s"]))
        if missing:
            raise ValueError(f"{where}.overhead_s lacks the stages {missing}")
        return cls(_number(block["workers"], f"{where}.workers", integer=True),
                   _number(block["worker_nice"], f"{where}.worker_nice", integer=True),
                   float(_number(block["reserve_s"], f"{where}.reserve_s")),
                   float(_number(block["min_train_s"], f"{where}.min_train_s")),
                   {s: float(_number(v, f"{where}.overhead_s.{s}")) for s, v in block["overhead_s"].items()},
                   block["stages"])


@dataclass(frozen=True)
class SprintConfig:
    """``training/configs/sprint-<preset>.json`` (module docstring)."""

    preset: str
    stage_config: str  # the base stage blocks: training/configs/<stage_config>.json
    seed: int
    fractions: dict  # {stage: share} from scratch
    fractions_from_init: dict  # {stage: share} from --init (no VAE stages)
    save_every_min: float
    export_from: str  # periodic exports from this stage on
    export: dict  # shard_mib, max_total_mib, storage_dtype
    collect: CollectConfig  # training.collect.collect_argv's block
    min_train_episodes: int
    rescan_s: float
    compile_cache: bool
    devices: dict  # {platform: DeviceSettings}

    @classmethod
    def load(cls, preset: str, path: str | Path | None = None) -> SprintConfig:
        path = Path(path) if path else CONFIG_DIR / f"sprint-{preset}.json"
        if not path.is_file():
            known = sorted(p.stem.removeprefix("sprint-") for p in CONFIG_DIR.glob("sprint-*.json"))
            raise FileNotFoundError(f"no sprint config {path}; presets with one: {known}")
        return cls.from_dict(read_json_config(path), str(path))

    @classmethod
    def from_dict(cls, data: dict, where: str = "sprint config") -> SprintConfig:
        keys = [f.name for f in dataclasses.fields(cls)]
        if sorted(data) != sorted(keys):
            raise ValueError(f"{where}: unknown keys {sorted(set(data) - set(keys))}, missing keys "
                             f"{sorted(set(keys) - set(data))}")
        for name in ("fractions", "fractions_from_init"):
            for stage, share in data[name].items():
                if stage not in STAGES:
                    raise ValueError(f"{where}: {name} names unknown stage {stage!r}; expected stages of {STAGES}")
                _number(share, f"{where}: {name}.{stage}")
            if not sum(data[name].values()) > 0:
                raise ValueError(f"{where}: {name} must give some stage a share > 0, got {data[name]}")
        if set(data["fractions_from_init"]) & set(VAE_STAGES):
            raise ValueError(f"{where}: fractions_from_init must not name {VAE_STAGES} (an --init model has its VAE)")
        if data["export_from"] not in STAGES:
            raise ValueError(f"{where}: export_from must be one of {STAGES}, got {data['export_from']!r}")
        if sorted(data["export"]) != ["max_total_mib", "shard_mib", "storage_dtype"]:
            raise ValueError(f"{where}: export must have exactly the keys max_total_mib, shard_mib, storage_dtype; "
                             f"got {sorted(data['export'])}")
        _number(data["export"]["shard_mib"], f"{where}: export.shard_mib", low=1 / 1024)
        _number(data["export"]["max_total_mib"], f"{where}: export.max_total_mib", low=1 / 1024)
        _number(data["save_every_min"], f"{where}: save_every_min", low=1 / 60)
        _number(data["rescan_s"], f"{where}: rescan_s", low=0.1)
        _number(data["min_train_episodes"], f"{where}: min_train_episodes", low=1, integer=True)
        if not isinstance(data["compile_cache"], bool):
            raise ValueError(  # noqa: TRY004  (a bad config is a ValueError throughout)
                f"{where}: compile_cache must be true or false, got {data['compile_cache']!r}")
        devices = {platform: DeviceSettings.from_dict(block, f"{where}: devices.{platform}")
                   for platform, block in data["devices"].items()}
        collect = CollectConfig.from_dict(data["collect"], f"{where}: collect")
        return cls(**{**data, "devices": devices, "collect": collect})

    def device(self, platform: str) -> DeviceSettings:
        if platform not in self.devices:
            raise ValueError(f"sprint config has no devices.{platform} block (JAX runs on {platform!r}); it has "
                             f"{sorted(self.devices)}")
        return self.devices[platform]


def stage_blocks(cfg: SprintConfig, device: DeviceSettings) -> TrainingConfig:
    """The stage config of ``training.train``'s functions: the base blocks, the device's overrides, and the
    sprint's own settings (open-ended steps, no checkpoints, samples or held-out loss, rescanning data;
    each where the stage's block has the key), every block validated again (``training.stage_config``)."""
    base = load_stage_config(cfg.stage_config)
    if base.preset != cfg.preset:
        raise ValueError(f"stage config {cfg.stage_config!r} is for preset {base.preset!r}, the sprint's is "
                         f"{cfg.preset!r}")
    # no held-out loss either: the test split grows with the data, and may be empty when a stage starts
    sprint = {"steps": OPEN_ENDED_STEPS, "ckpt_every": 0, "sample_every": 0, "test_every": 0,
              "rescan_s": cfg.rescan_s}
    blocks = dict(base.stages)
    for stage in STAGES:
        override = device.stages.get(stage, {})
        block = {**dataclasses.asdict(base.stages[stage]), **override}
        block.update({k: v for k, v in sprint.items() if k in block})
        blocks[stage] = STAGE_CONFIGS[stage].from_dict(block, f"sprint stage override {stage}")
    return dataclasses.replace(base, stages=blocks)


def plan_shares(pending: list[tuple[str, float]], overhead_s: dict, min_train_s: float, left_s: float
                ) -> tuple[dict, list[str]]:
    """({stage: seconds}, dropped stages) for the stages still to run, ``pending`` = [(stage, fraction > 0)]
    in order, within ``left_s``: while their overheads plus ``min_train_s`` each exceed it, the stage with
    the smallest fraction (the later of equals) is dropped; each kept stage gets its overhead plus the
    training time left split by fraction."""
    kept = list(pending)
    dropped = []
    while kept and sum(overhead_s[s] + min_train_s for s, _ in kept) > left_s:
        victim = min(reversed(kept), key=lambda sf: sf[1])
        kept.remove(victim)
        dropped.append(victim[0])
    train_s = left_s - sum(overhead_s[s] for s, _ in kept)
    total = sum(f for _, f in kept)
    return {s: overhead_s[s] + train_s * f / total for s, f in kept}, dropped


# ---------------------------------------------------------------------------------------------
# Data made while training: the collector (the growing streams: ``training.growing_data``)
# ---------------------------------------------------------------------------------------------


def _worker_init(height: int, width: int, nice: int, compile_cache: str | None) -> None:
    """A collect worker: CPU-only JAX (the accelerator is the trainer's), ``nice`` below the trainer's
    priority, with the sprint's compilation cache (a later sprint's workers start rendering sooner)."""
    os.environ["JAX_PLATFORMS"] = "cpu"
    if compile_cache:
        os.environ["JAX_COMPILATION_CACHE_DIR"] = compile_cache
    os.nice(nice)
    from solaris_env.engine.cli import get_renderer

    get_renderer(height, width)


class Collector:
    """The engine's training-data jobs run by ``workers`` background processes into ``data_dir``.

    ``start()`` returns at once; ``counts()`` tells the finished episodes per split (and failures);
    ``stop()`` ends the workers (an episode being written is abandoned: its staging dir is cleaned at
    the next start, and the final directories never hold part of one)."""

    def __init__(self, data_dir: Path, preset_name: str, block: CollectConfig, workers: int, test_first: bool,
                 nice: int = 0, compile_cache: str | None = None) -> None:
        from solaris_env.engine import cli as engine_cli
        from solaris_env.engine.recorder import clean_staging, episode_complete
        from solaris_env.world_model.config import preset

        self.data_dir = Path(data_dir)
        args = engine_cli.build_parser().parse_args(collect_argv(self.data_dir, preset(preset_name), block))
        args.chunk_ticks = engine_cli.auto_chunk_ticks(*args.resolution)
        clean_staging(self.data_dir)
        jobs = [j for j in engine_cli.training_jobs(args) if not episode_complete(self.data_dir, j.key())]
        first_test = next((j for j in jobs if j.split == "test"), None) if test_first else None
        self.jobs = [first_test, *(j for j in jobs if j is not first_test)] if first_test else jobs
        self.nice, self.compile_cache = nice, compile_cache
        self.workers = workers or max(1, (os.cpu_count() or 1) - 2)  # 0: every core but two (the trainer's)
        self.resolution = args.resolution
        self.done = {"train": 0, "test": 0}
        self.failed: list[str] = []
        self._split = {(j.episode, j.instance): j.split for j in self.jobs}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._pool = None
        self._thread: threading.Thread | None = None

    def start(self) -> Collector:
        import multiprocessing as mp

        from solaris_env.engine.cli import collect_one

        if not self.jobs:
            return self
        ctx = mp.get_context("spawn")
        self._pool = ctx.Pool(self.workers, initializer=_worker_init, initargs=(*self.resolution, self.nice,
                                                                                   self.compile_cache))
        results = self._pool.imap_unordered(collect_one, self.jobs)

        def consume():
            while not self._stop.is_set():
                try:
                    res = results.next(timeout=0.5)
                except ctx.TimeoutError:
                    continue
                except StopIteration:
                    return
                with self._lock:
                    if res["error"] is None:
                        self.done[self._split[(res["episode"], res["instance"])]] += 1
                    else:
                        self.failed.append(res["error"])
                        logger.warning("collect: episode %d failed:\n%s", res["episode"], res["error"])

        self._thread = threading.Thread(target=consume, name="collect-results", daemon=True)
        self._thread.start()
        return self

    def counts(self) -> dict:
        with self._lock:
            return {**self.done, "failed": len(self.failed), "planned": len(self.jobs)}

    def wait_for(self, train: int, test: int, deadline: float) -> None:
        """Block until the data directory holds ``train`` / ``test`` finished episodes; ValueError when every
        job ended without them or ``deadline`` (epoch seconds) passes."""
        while True:
            have = count_episodes(self.data_dir)
            if have["train"] >= train and have["test"] >= test:
                return
            c = self.counts()
            if c["train"] + c["test"] + c["failed"] >= c["planned"] or time.time() > deadline:
                first = self.failed[0] if self.failed else "none failed"
                raise ValueError(f"sprint: {have} episodes in {self.data_dir}, need {train} train and {test} test "
                                 f"(collect {c}; first failure: {first})")
            time.sleep(0.5)

    def stop(self) -> None:
        self._stop.set()
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
        if self._thread is not None:
            self._thread.join()


def count_episodes(data_dir: Path) -> dict:
    """Finished episodes per split of a Duet dataset directory (both bots' commit markers present)."""
    from solaris_env.engine.recorder import TRAIN_DIR

    return {split: sum(1 for p in (Path(data_dir) / TRAIN_DIR / split).glob("*_Alpha_*_episode_info.json")
                       if Path(str(p).replace("_Alpha_", "_Bravo_", 1)).is_file())
            for split in ("train", "test")}


# ---------------------------------------------------------------------------------------------
# Exports and lineage
# ---------------------------------------------------------------------------------------------


def process_start_time() -> float:
    """Epoch seconds at which this process started (Linux ``/proc``; else now): a CLI sprint's clock."""
    try:
        ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        boot = next(int(line.split()[1]) for line in Path("/proc/stat").read_text().splitlines()
                    if line.startswith("btime "))
        return min(time.time(), boot + ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError, StopIteration):
        return time.time()


def git_commit() -> dict | None:
    """The checkout's commit (and whether tracked files differ from it), or None without git."""
    try:
        head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": head, "modified_tracked_files": bool(dirty)}


def read_lineage(model: Path) -> dict | None:
    path = Path(model) / LINEAGE_FILE
    return json.loads(path.read_text()) if path.is_file() else None


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))


class Exporter:
    """Writes ``dest`` (``OUT/model``): the model's shards, config and ``lineage.json``, atomically."""

    def __init__(self, dest: Path, cfg: SprintConfig, lineage: dict, t0: float) -> None:
        self.dest, self.cfg, self.lineage, self.t0 = Path(dest), cfg, lineage, t0
        self.every_s = cfg.save_every_min * 60
        self.last = time.time()
        self.live_s = 0.0  # how long the last export from a live train state took (the model built and written)

    def due(self) -> bool:
        return time.time() - self.last >= self.every_s

    def export(self, model, source: str, step: int | None = None, final: bool = False) -> None:
        from solaris_env.world_model import checkpoint
        from solaris_env.world_model.components import COMPONENTS

        t = time.time()
        self.lineage["exports"].append({"at_s": round(t - self.t0, 1), "stage": source, "step": step, "final": final})
        checkpoint.save(self.dest, model.config, dict(zip(COMPONENTS, model.params)),
                        storage_dtype=self.cfg.export["storage_dtype"],
                        shard_bytes=int(self.cfg.export["shard_mib"] * 2**20),
                        max_total_bytes=int(self.cfg.export["max_total_mib"] * 2**20),
                        extra_files={LINEAGE_FILE: json.dumps(self.lineage, indent=1)})
        self.last = time.time()
        print(f"sprint: exported {source}{'' if step is None else f' at step {step}'} to {self.dest} in "
              f"{self.last - t:.1f} s", flush=True)

    def export_live(self, make_model, source: str, step: int) -> None:
        """Export ``make_model()`` (the model of a live train state), timing the whole for ``live_s``."""
        t = time.time()
        self.export(make_model(), source, step)
        self.live_s = time.time() - t

    def export_dir(self, model: Path, source: str, final: bool = False) -> None:
        from solaris_env.world_model.world_model import WorldModel

        self.export(WorldModel.load(model), source, final=final)


# ---------------------------------------------------------------------------------------------
# The sprint
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SprintArgs:
    """``solaris-train sprint``'s options (``training.cli``)."""

    preset: str
    out: Path
    budget_min: float
    init: str | None = None  # "default", a model directory, or None (from scratch)
    data: Path | None = None  # default: WORK/data
    config: Path | None = None  # default: training/configs/sprint-<preset>.json
    work: Path | None = None  # stage runs, latents; default: a temporary directory, removed after
    started: float | None = None  # epoch seconds the budget counts from (the CLI: the process's start); None: now
    workers: int | None = None  # background collect workers; None: the config's devices.<kind>.workers

    def command(self) -> list[str]:
        cmd = ["solaris-train", "sprint", "--preset", self.preset, "--out", str(self.out),
               "--budget-min", f"{self.budget_min:g}"]
        for flag, value in (("--init", self.init), ("--data", self.data), ("--config", self.config),
                            ("--work", self.work), ("--workers", self.workers)):
            if value is not None:
                cmd += [flag, str(value)]
        return cmd


def resolve_init(init: str | None) -> Path | None:
    from training.surgery import model_directory

    return None if init is None else model_directory(init, "--init")


def _link(model: Path, target: Path) -> None:
    """``model`` (a stage's model/ path) -> a symlink to ``target``, replacing whatever is there."""
    if model.is_symlink() or model.is_file():
        model.unlink()
    elif model.exists():
        shutil.rmtree(model)
    model.parent.mkdir(parents=True, exist_ok=True)
    model.symlink_to(Path(target).resolve(), target_is_directory=True)


def run_sprint(args: SprintArgs) -> Path:
    """Run a sprint (module docstring); returns ``OUT/model``."""
    t0 = time.time() if args.started is None else args.started
    if not args.budget_min > 0:
        raise ValueError(f"--budget-min must be > 0, got {args.budget_min}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be an integer >= 1 (or left out for the config's), got {args.workers}")
    cfg = SprintConfig.load(args.preset, args.config)
    if cfg.preset != args.preset:
        raise ValueError(f"sprint config {args.config} is for preset {cfg.preset!r}, --preset is {args.preset!r}")
    init = resolve_init(args.init)
    if init is not None:
        from solaris_env.world_model.checkpoint import read_config
        if (name := read_config(init).name) != cfg.preset:
            raise ValueError(f"--init {args.init}: a {name!r} model; the sprint trains preset {cfg.preset!r}")
    work = Path(tempfile.mkdtemp(prefix="solaris-sprint-")) if args.work is None else Path(args.work)
    try:
        with _compile_cache(work / "jax-cache" if cfg.compile_cache else None):
            return Sprint(args, cfg, init, work, t0).run()
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)


def compile_cache_dir() -> str | None:
    """The persistent compilation cache JAX is configured with, if any."""
    import jax

    return getattr(jax.config, "jax_compilation_cache_dir", None)


@contextlib.contextmanager
def _compile_cache(directory: Path | None):
    """JAX's persistent compilation cache in ``directory`` for the duration, unless one is configured (a JAX
    that refuses the setting only costs the cache: a warning, never the sprint)."""
    import jax

    if directory is None or compile_cache_dir():
        yield
        return
    try:
        jax.config.update("jax_compilation_cache_dir", str(directory))
    except Exception as err:  # noqa: BLE001 - an optional speed-up
        logger.warning("sprint: no persistent compilation cache (%s)", err)
        yield
        return
    try:
        yield
    finally:
        jax.config.update("jax_compilation_cache_dir", None)


class Sprint:
    """One sprint's state: the clock, the plan, the collector, the lineage record and the exports."""

    def __init__(self, args: SprintArgs, cfg: SprintConfig, init: Path | None, work: Path, t0: float) -> None:
        import jax

        self.args, self.cfg, self.init, self.t0 = args, cfg, init, t0
        self.end = t0 + args.budget_min * 60
        self.data = Path(args.data) if args.data else work / "data"
        self.run_dir = work / "run"
        self.platform = jax.devices()[0].platform
        self.device = cfg.device(self.platform)
        if args.workers is not None:  # two sprints side by side share the machine's cores (training/gpu_call.sh)
            self.device = dataclasses.replace(self.device, workers=args.workers)
        init_lineage = read_lineage(init) if init else None
        generation = (init_lineage or {}).get("generation", 0) + 1
        self.collect_block = dataclasses.replace(cfg.collect, seed=cfg.collect.seed + 1000 * (generation - 1))
        self.lineage = {
            "format": LINEAGE_FORMAT, "version": 1, "generation": generation,
            "command": [portable_text(a, parts=3) for a in args.command()],  # no machine's absolute paths
            "preset": cfg.preset, "config": dataclasses.asdict(cfg),
            "init": None if init is None else {"model": portable_text(args.init, parts=3), "lineage": init_lineage},
            "devices": [str(d) for d in jax.devices()], "platform": self.platform,
            "device_kind": jax.devices()[0].device_kind, "git": git_commit(), "start_time": _iso(t0),
            "budget_s": round(self.end - t0, 1), "collect": dataclasses.asdict(self.collect_block), "stages": [],
            "exports": []}
        self.exporter = Exporter(Path(args.out) / "model", cfg, self.lineage, t0)

    def left_s(self) -> float:
        """Seconds left for training: to the budget's end less the reserve for the final export."""
        return self.end - self.device.reserve_s - time.time()

    def run(self) -> Path:
        from training.train import model_dir

        fractions = self.cfg.fractions_from_init if self.init else self.cfg.fractions
        order = [s for s in self.stage_order() if fractions.get(s, 0) > 0]
        need_test = int(any(s in VAE_STAGES for s in order))  # the VAE stages evaluate on duet/test
        collector = Collector(self.data, self.cfg.preset, self.collect_block, self.device.workers, bool(need_test),
                              self.device.worker_nice, compile_cache_dir()).start()
        print(f"sprint: {self.platform} ({self.lineage['device_kind']}); budget {self.args.budget_min:g} min, "
              f"{time.time() - self.t0:.0f} s spent starting; recording {len(collector.jobs)} episodes with "
              f"{collector.workers} workers into {self.data}", flush=True)
        try:
            collector.wait_for(self.cfg.min_train_episodes, need_test, self.end - self.device.reserve_s)
            self.lineage["first_data_s"] = round(time.time() - self.t0, 1)
            print(f"sprint: {count_episodes(self.data)} episodes after {self.lineage['first_data_s']:.0f} s; "
                  f"training", flush=True)
            latest = self.train_stages({s: fractions[s] for s in order})
        finally:
            collector.stop()
        self.lineage["collected"] = {**collector.counts(),
                                     **{f"on_disk_{k}": v for k, v in count_episodes(self.data).items()}}
        self.lineage["end_time"] = _iso(time.time())  # of training; the final export follows
        self.lineage["training_wall_s"] = round(time.time() - self.t0, 1)
        self.exporter.export_dir(model_dir(self.run_dir, latest), latest, final=True)
        self.print_timing()
        return self.exporter.dest

    def stage_order(self) -> list[str]:
        return [s for s in STAGES if not (self.init and s in VAE_STAGES)]

    def train_stages(self, fractions: dict) -> str:
        """Every stage in order, trained (``plan_shares``) or skipped; returns the last stage trained."""
        from training.train import model_dir

        latest, trained = None, False
        if self.init is not None:
            for stage in VAE_STAGES:
                _link(model_dir(self.run_dir, stage), self.init)
            latest = VAE_STAGES[-1]
        dropped: dict[str, str] = {}
        ratios: list[float] = []  # each trained stage's time to its first step / its configured overhead
        for stage in self.stage_order():
            record = {"stage": stage, "fraction": fractions.get(stage, 0.0), "start_s": round(time.time() - self.t0, 1)}
            self.lineage["stages"].append(record)
            if stage in fractions and latest is None and stage != "vae":
                dropped[stage] = "no input model (the VAE stage did not run)"
            if stage in fractions and stage not in dropped:
                left = self.left_s()
                scale = min(max(sum(ratios) / len(ratios), 0.5), 4.0) if ratios else 1.0
                overhead = {s: v * scale for s, v in self.device.overhead_s.items()}
                later = STAGES[STAGES.index(stage):]
                pending = [(s, f) for s, f in fractions.items() if s in later and s not in dropped]
                shares, no_time = plan_shares(pending, overhead, self.device.min_train_s, left)
                record["overhead_scale"] = round(scale, 2)
                dropped.update({s: f"no time: {left:.0f} s left for {', '.join(p for p, _ in pending)}"
                                for s in no_time})
            reason = "fraction 0" if stage not in fractions else dropped.get(stage)
            if reason is not None:
                record.update(status="skipped", reason=reason)
                if latest is not None:
                    _link(model_dir(self.run_dir, stage), model_dir(self.run_dir, latest))
                print(f"sprint: {stage}: skipped ({reason})", flush=True)
                continue
            record.update(share_s=round(shares[stage], 1), **self.train_stage(stage, time.time() + shares[stage]))
            latest, trained = stage, True
            if record["first_step_s"] is not None and self.device.overhead_s[stage] > 0:
                ratios.append(record["first_step_s"] / self.device.overhead_s[stage])
            held_out = record.get("held_out", {})
            psnr = f"; held-out {held_out['test_psnr_db']:.2f} dB" if "test_psnr_db" in held_out else ""
            print(f"sprint: {stage}: {record['steps']} steps in {record['wall_s']:.1f} s (share "
                  f"{shares[stage]:.1f} s, first step after {record['first_step_s']} s, last {record['steps_per_s']} "
                  f"steps/s{psnr}); data {record['data']}", flush=True)
        if not trained:
            raise ValueError(f"sprint: no stage ran within {self.args.budget_min:g} min (see the skip reasons above)")
        return latest

    def train_stage(self, stage: str, deadline: float) -> dict:
        """Train ``stage`` until ``deadline``; returns its lineage record: wall time, steps, when its first step
        ended (setup and JIT compile: seconds after the stage's start), the steps per second of its last logged
        stretch, its last losses, its teardown (from the end of the last step: the background encoder stopped, the
        model saved), the VAE stages' held-out PSNR (overall and per latent) and the data it saw."""
        from training.metrics import read_metrics
        from training.train import call_stage, stage_dir

        shutil.rmtree(stage_dir(self.run_dir, stage), ignore_errors=True)  # no stale checkpoints
        exportable = STAGES.index(stage) >= STAGES.index(self.cfg.export_from)
        t_start, n_streams = time.time(), len(STREAMS)
        beat, first_step_at, last_step_at = [t_start], [], [t_start]

        def on_model(step: int, make_model) -> None:
            # a periodic export that would end past the stage's deadline is left to the final one, which follows
            if exportable and self.exporter.due() and time.time() + self.exporter.live_s < deadline:
                self.exporter.export_live(make_model, stage, step)
            progress(step)

        def progress(step: int) -> None:
            last_step_at[0] = time.time()
            if not first_step_at:
                first_step_at.append(last_step_at[0])
            if time.time() - beat[0] >= HEARTBEAT_S:
                beat[0] = time.time()
                print(f"sprint: {stage}: step {step}, {beat[0] - t_start:.0f} s in, {deadline - beat[0]:.0f} s to "
                      f"its deadline", flush=True)

        kw = {"seed": self.cfg.seed, "steps": OPEN_ENDED_STEPS, "resume": False, "deadline": deadline}
        if stage in VAE_STAGES:
            kw["on_step"] = lambda state, step: progress(step)
        else:
            kw["on_model"] = on_model
        call_stage(stage, self.run_dir, self.data, stage_blocks(self.cfg, self.device), **kw)
        metrics = read_metrics(stage_dir(self.run_dir, stage) / "metrics.jsonl")
        summary = stage_dir(self.run_dir, stage) / "summary.json"  # the VAE stages' held-out PSNR
        summary = json.loads(summary.read_text()) if summary.is_file() else {}
        seen = data_record(STREAMS[n_streams:])
        del STREAMS[n_streams:]  # their datasets (and frame caches) go with the stage
        last = metrics[-1] if metrics else {}
        held_out = {k: summary[k] for k in ("num_frames", "test_psnr_db", "test_psnr_by_latent_db") if k in summary}
        if "after" in summary:  # vae-decoder
            held_out.update(num_frames=summary["num_frames"], **summary["after"])
        end = time.time()
        return {"status": "ran", "wall_s": round(end - t_start, 1), "steps": last.get("step", 0),
                "first_step_s": round(first_step_at[0] - t_start, 1) if first_step_at else None,
                "teardown_s": round(end - last_step_at[0], 1),  # after the last step: stop the encoder, save
                "steps_per_s": last.get("steps_per_s"), "losses": {k: v for k, v in last.items() if k.endswith("loss")},
                **({"held_out": held_out} if held_out else {}), "data": seen}

    def print_timing(self) -> None:
        print("sprint: stage              status   share_s   wall_s    steps  train episodes (start -> end)")
        for r in self.lineage["stages"]:
            d = r.get("data") or {}
            seen = f"{d['episodes_at_start']} -> {d['episodes_at_end']}" if d else r.get("reason", "")
            share, wall = r.get("share_s", 0.0), r.get("wall_s", 0.0)
            print(f"sprint: {r['stage']:<18} {r['status']:<7} {share:8.1f} {wall:8.1f} {r.get('steps', 0):8d}  {seen}")
        total, budget = time.time() - self.t0, self.end - self.t0
        print(f"sprint: total {total:.1f} s of the {budget:.0f} s budget ({'within' if total <= budget else 'OVER'}); "
              f"data after {self.lineage['first_data_s']:.0f} s; collected {self.lineage['collected']}", flush=True)


__all__ = ["Collector", "Exporter", "SprintArgs", "SprintConfig", "plan_shares", "run_sprint", "stage_blocks"]
