"""``solaris-engine``: collect training/eval data with the voxel engine, and preview what was collected.

    solaris-engine collect --out data --episodes 64 --world mixed --resolution 64 --seed 0 --workers 2
    solaris-engine collect --out data --eval --episodes 32 --resolution 1280x720
    solaris-engine preview data --out preview.png          # + preview.mp4 (Alpha | Bravo)
    solaris-engine export-vpt data --out data              # duet/{train,test} -> vpt/{train,test} (stage 1)

Training episodes are numbered 0..N-1; episode e runs on instance ``offset + e mod --instances``
(flat surface variant = instance mod 5; ``--world mixed`` = flat on even instances, normal on odd
ones) and is written as batch ``--seed``. Eval episodes follow the reference (docs/data-format.md §5): per
type, flat-world types run on 2 instances with ids 0..ceil(N/2)-1 each, normal-world types
(turnToLook*) on 1 instance with ids 0..N-1. After an eval collect, ``eval/eval_ids_<Type>.json``
(rows ``[ep, s1, s1+257, s2, s2+257]``, s = the judge's frame1 = end of the first sneak run + 25,
docs/engine.md §7.1/§7.4) and ``eval/structure_building_summary.json`` (docs/engine.md §7.3) are rebuilt
from everything on disk.
Every frame shows a 16:9 game window (70 deg vertical FOV, ~102 deg horizontal) resampled to the
requested size (``RenderConfig.display_aspect``), so square frames such as 64x64 keep the reference's
field of view and rotationEval's 40 deg turn leaves the other player on screen.

Re-running a collect skips finished episodes (all files present). Aborted episodes (a bot failed, or
the episode hit its time cap) are still written, with ``encountered_error`` /
``peer_encountered_error`` in episode_info and ``aborted`` / ``abort_reason`` in the sidecar; a
crash while simulating, rendering or writing one episode is reported, leaves none of its files, and
makes the exit status 1 after the other episodes are done. Ctrl-C, at any moment (a JAX compile included), ends
the collect with one line, ``solaris-engine: interrupted``, and status 130; a re-run resumes. Argument and other
errors are one line too (``--debug`` shows the traceback; ``solaris_env.cli_support``).

Heavy modules (numpy, jax, the renderer, OpenCV) are imported inside the commands so that
``--help`` is instant.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from solaris_env.cli_support import (
    add_debug_flag,
    non_negative_int,
    positive_int,
    run_command,
)

# The 7 eval sets of the paper (docs/engine.md §6, docs/data-format.md §5).
SPEC_EVAL_TYPES = ("rotationEval", "translationEval", "structureEval", "bothLookAwayEval", "oneLooksAwayEval",
                   "turnToLookEval", "turnToLookOppositeEval")
DEFAULT_EVAL_EPISODES = 32  # pairs per eval type (docs/data-format.md §5)
EVAL_INSTANCES_FLAT = 2  # flat-world eval types: 2 instances x N/2 episodes
EVAL_INSTANCES_NORMAL = 1  # turnToLook*: 1 normal-world instance x N episodes
MAX_CHUNK_TICKS = 32  # auto --chunk-ticks: at most this many ticks per renderer call (bigger batches were
# not faster on CPU: a batch marches until its slowest ray is done) ...
CHUNK_PIXEL_BUDGET = 1 << 21  # ... and at most this many pixels (views x H x W) per call (CPU memory)
PREVIEW_EPISODES = 3
PREVIEW_COLUMNS = 8
PREVIEW_MIN_CELL = 96  # contact-sheet cells are upscaled (nearest) to at least this height


# ---------------------------------------------------------------------------------------------
# Jobs
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Job:
    """One episode to collect (picklable for the worker pool)."""

    out: str
    seed: int
    episode: int
    instance: int
    world_kind: str
    episode_type: str | None  # None: sampled by the runner from all training types
    eval_type: str | None
    split: str
    chunk_ticks: int
    height: int
    width: int
    time_of_day: str = "cycle"  # training episodes: ``EpisodeConfig.time_of_day``

    def key(self):
        from solaris_env.engine.recorder import EpisodeKey

        return EpisodeKey(self.episode, self.instance, batch=self.seed, eval_type=self.eval_type)


def world_for_instance(world: str, instance: int) -> str:
    if world == "mixed":
        return "flat" if instance % 2 == 0 else "normal"
    return world


def training_jobs(args) -> list[Job]:
    import numpy as np

    from solaris_env.engine.bots import registry
    from solaris_env.engine.bots.runner import EpisodeConfig, episode_seeds
    from solaris_env.engine.recorder import split_of

    types = args.types
    if types:
        known = registry.training_types() + registry.opt_in_training_types()
        unknown = sorted(set(types) - set(known))
        if unknown:
            raise SystemExit(f"unknown training types {unknown}; known: {known}")
    jobs = []
    for e in range(args.episodes):
        instance = args.instance_offset + e % args.instances
        kind = world_for_instance(args.world, instance)
        etype = None
        if types:  # same draw as the runner's, over the restricted set
            shared, _ = episode_seeds(EpisodeConfig(args.seed, instance, e, kind))
            etype = registry.sample_type(np.random.default_rng(shared), types)
        jobs.append(Job(str(args.out), args.seed, e, instance, kind, etype, None,
                        split_of(args.seed, instance, e, args.test_fraction), args.chunk_ticks, *args.resolution,
                        args.time_of_day or "cycle"))
    return jobs


def eval_jobs(args, types: list[str]) -> list[Job]:
    from solaris_env.engine.bots import registry

    jobs = []
    n = args.episodes if args.episodes is not None else DEFAULT_EVAL_EPISODES
    for etype in types:
        world = registry.get(etype).world or "flat"
        n_inst = EVAL_INSTANCES_NORMAL if world == "normal" else EVAL_INSTANCES_FLAT
        per_instance = -(-n // n_inst)
        pairs = [(i, e) for i in range(n_inst) for e in range(per_instance)][:n]
        jobs += [Job(str(args.out), args.seed, e, args.instance_offset + i, world, etype, etype, "test",
                     args.chunk_ticks, *args.resolution) for i, e in pairs]
    return jobs


# ---------------------------------------------------------------------------------------------
# Workers
# ---------------------------------------------------------------------------------------------

_RENDERER = None  # one per process, built on first use by get_renderer and reused (jit compiles once)


def get_renderer(height: int, width: int):
    """This process's renderer for ``height x width`` (built on first use, reused afterwards)."""
    global _RENDERER
    if _RENDERER is None or (_RENDERER.cfg.height, _RENDERER.cfg.width) != (height, width):
        from solaris_env.engine.render import RenderConfig, Renderer

        _RENDERER = Renderer(RenderConfig(height=height, width=width))
    return _RENDERER


def _init_worker(height: int, width: int) -> None:
    """Pool worker start: leave Ctrl-C to the parent (it stops the pool and prints the one line), build the
    renderer once."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    get_renderer(height, width)


def collect_one(job: Job) -> dict:
    """Simulate, render and write one episode (in the current process, with its renderer)."""
    from solaris_env.engine.bots.runner import EpisodeConfig, run_episode
    from solaris_env.engine.capture import ground_truth, render_episode
    from solaris_env.engine.recorder import write_episode

    t_start = time.perf_counter()
    result = {"episode": job.episode, "instance": job.instance, "eval_type": job.eval_type, "ticks": 0,
              "aborted": False, "error": None}
    try:
        output = run_episode(EpisodeConfig(job.seed, job.instance, job.episode, job.world_kind, job.episode_type,
                                           time_of_day=job.time_of_day))
        renderer = get_renderer(job.height, job.width)
        frames_PTHW3, avatar_id_PTHW = render_episode(output.trace, renderer, job.chunk_ticks)
        gt = ground_truth(output.trace, avatar_id_PTHW, output.tick_events)
        write_episode(job.out, job.key(), output, frames_PTHW3, gt, job.split)
        result.update(ticks=output.trace.num_ticks, aborted=output.aborted, type=output.episode_type)
    except Exception:  # noqa: BLE001 - reported per episode; the collect goes on
        result["error"] = traceback.format_exc()
    result["wall_s"] = time.perf_counter() - t_start
    return result


def run_jobs(jobs: list[Job], workers: int) -> list[dict]:
    """Run jobs with a tqdm bar; ``workers == 1`` runs in-process, else a 'spawn' pool whose workers
    each build their renderer once (pool initializer)."""
    from tqdm import tqdm

    results = []
    with tqdm(total=len(jobs), unit="ep", desc="collect", dynamic_ncols=True) as bar:

        def done(res: dict) -> None:
            results.append(res)
            bar.update(1)
            bar.set_postfix(ticks=sum(r["ticks"] for r in results), aborted=sum(r["aborted"] for r in results),
                            failed=sum(r["error"] is not None for r in results))

        if workers <= 1:
            for job in jobs:
                done(collect_one(job))
            return results
        import multiprocessing as mp

        size = (jobs[0].height, jobs[0].width)
        with mp.get_context("spawn").Pool(workers, initializer=_init_worker, initargs=size) as pool:
            for res in pool.imap_unordered(collect_one, jobs):
                done(res)
    return results


# ---------------------------------------------------------------------------------------------
# Eval bookkeeping: eval_ids and the structure summary
# ---------------------------------------------------------------------------------------------


def write_eval_bookkeeping(out: Path, types: list[str]) -> None:
    """Rebuild ``eval_ids_<Type>.json`` for each type and the structure summary from the files on disk.

    Row ids are indices in the loader's sorted ``*_Alpha_*.mp4`` glob (docs/data-format.md §7.1); starts are the
    judge's frame1 (``eval_protocol.eval_ids_row``). The summary comes from the sidecars' episode_info dicts.
    """
    from solaris_env.engine.eval_protocol import eval_ids_row, structure_summary

    eval_root = out / "eval"
    for etype in types:
        rows = []
        for ep, alpha_mp4 in enumerate(sorted((eval_root / etype / "test").glob("*_Alpha_*.mp4"))):
            alpha_json = alpha_mp4.with_name(alpha_mp4.name.removesuffix("_camera.mp4") + ".json")
            bravo_json = alpha_json.with_name(alpha_json.name.replace("_Alpha_", "_Bravo_", 1))
            try:
                rows.append(eval_ids_row(ep, json.loads(alpha_json.read_text()), json.loads(bravo_json.read_text())))
            except ValueError as e:
                print(f"warning: {alpha_mp4.name}: no eval_ids row ({e})", file=sys.stderr)
        (eval_root / f"eval_ids_{etype}.json").write_text(json.dumps(rows))
    infos = [info for sc in sorted((eval_root / "structureEval" / "test").glob("*_groundtruth.json"))
             for info in json.loads(sc.read_text())["episode_info"].values()]
    summary = structure_summary(infos)
    if summary:
        (eval_root / "structure_building_summary.json").write_text(json.dumps(summary, indent=2))


# ---------------------------------------------------------------------------------------------
# Commands
# ---------------------------------------------------------------------------------------------


def parse_resolution(text: str) -> tuple[int, int]:
    """'64' -> (64, 64); '1280x720' -> (height 720, width 1280)."""
    try:
        if "x" in text:
            w, h = (int(v) for v in text.lower().split("x"))
        else:
            w = h = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must be R or WxH, got {text!r}") from None
    if h < 8 or w < 8:
        raise argparse.ArgumentTypeError(f"resolution must be at least 8x8, got {text!r}")
    return h, w


def auto_chunk_ticks(height: int, width: int, players: int = 2) -> int:
    """Largest power of two <= MAX_CHUNK_TICKS whose views fit CHUNK_PIXEL_BUDGET (at least 1)."""
    chunk = MAX_CHUNK_TICKS
    while chunk > 1 and chunk * players * height * width > CHUNK_PIXEL_BUDGET:
        chunk //= 2
    return chunk


def cmd_collect(args) -> int:
    if args.time_of_day == "cycle" and (args.eval or args.backend == "minecraft"):
        raise SystemExit("collect: --time-of-day cycle is for the voxel backend's training data; eval episodes and "
                         "the minecraft backend always start at noon (--time-of-day day)")
    if args.backend == "minecraft":
        return cmd_collect_minecraft(args)
    from solaris_env.engine.bots import registry
    from solaris_env.engine.recorder import clean_staging, episode_complete

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.chunk_ticks is None:
        args.chunk_ticks = auto_chunk_ticks(*args.resolution)
    n_stale = clean_staging(out)
    if n_stale:
        print(f"removed {n_stale} stale staging dir(s) under {out}", file=sys.stderr)
    if args.eval:
        types = args.eval_types or registry.eval_types()
        unknown = sorted(set(types) - set(registry.eval_types()))
        if unknown:
            raise SystemExit(f"unknown eval types {unknown}; registered: {registry.eval_types()}")
        missing = sorted(set(SPEC_EVAL_TYPES) - set(types))
        if missing and not args.eval_types:
            print(f"warning: eval types not registered yet: {missing}", file=sys.stderr)
        jobs = eval_jobs(args, types)
    else:
        if args.episodes is None:
            raise SystemExit("collect: --episodes is required for training data")
        jobs = training_jobs(args)
    todo = [j for j in jobs if not episode_complete(out, j.key())]
    print(f"{len(jobs)} episodes, {len(jobs) - len(todo)} already complete, {len(todo)} to collect", file=sys.stderr)
    t0 = time.perf_counter()
    results = run_jobs(todo, args.workers) if todo else []
    wall = time.perf_counter() - t0
    failed = [r for r in results if r["error"] is not None]
    for r in failed:
        print(f"episode {r['episode']} instance {r['instance']} failed:\n{r['error']}", file=sys.stderr)
    ticks = sum(r["ticks"] for r in results)
    print(f"wrote {len(results) - len(failed)} episodes ({sum(r['aborted'] for r in results)} aborted, "
          f"{len(failed)} failed), {ticks} ticks = {ticks / 20:.1f} s of gameplay in {wall:.1f} s", file=sys.stderr)
    if args.eval:
        write_eval_bookkeeping(out, types)
    clean_staging(out, remove_root=True)
    return 1 if failed else 0


def minecraft_jobs(args) -> list[Job]:
    """The collect's jobs for the Minecraft backend: the same numbering, restricted to the types record.js has."""
    from solaris_env.engine.minecraft.collect import EVAL_TYPES, TRAINING_TYPES
    from solaris_env.engine.recorder import split_of

    if args.eval:
        types = args.eval_types or list(EVAL_TYPES)
        unknown = sorted(set(types) - set(EVAL_TYPES))
        if unknown:
            raise SystemExit(f"--backend minecraft: eval types {unknown} are not implemented; available: {EVAL_TYPES}")
        n = args.episodes if args.episodes is not None else DEFAULT_EVAL_EPISODES
        per_instance = -(-n // EVAL_INSTANCES_FLAT)
        pairs = [(i, e) for i in range(EVAL_INSTANCES_FLAT) for e in range(per_instance)][:n]
        return [Job(str(args.out), args.seed, e, args.instance_offset + i, "flat", t, t, "test", 0, *args.resolution)
                for t in types for i, e in pairs]
    if args.episodes is None:
        raise SystemExit("collect: --episodes is required for training data")
    types = args.types or list(TRAINING_TYPES)
    unknown = sorted(set(types) - set(TRAINING_TYPES))
    if unknown:
        raise SystemExit(f"--backend minecraft: training types {unknown} are not implemented; available: {TRAINING_TYPES}")
    jobs = []
    for e in range(args.episodes):
        instance = args.instance_offset + e % args.instances
        jobs.append(Job(str(args.out), args.seed, e, instance, "flat", types[e % len(types)], None,
                        split_of(args.seed, instance, e, args.test_fraction), 0, *args.resolution))
    return jobs


def cmd_collect_minecraft(args) -> int:
    """``collect --backend minecraft``: episodes run one after another, each on a fresh flat world (the server restarts)."""
    from solaris_env.engine.minecraft.collect import MinecraftSession
    from solaris_env.engine.recorder import clean_staging, episode_complete

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.workers != 1:
        print("warning: --backend minecraft records one episode at a time (--workers ignored)", file=sys.stderr)
    clean_staging(out)
    jobs = minecraft_jobs(args)
    todo = [j for j in jobs if not episode_complete(out, j.key())]
    print(f"{len(jobs)} episodes, {len(jobs) - len(todo)} already complete, {len(todo)} to collect", file=sys.stderr)
    failed = 0
    t0 = time.perf_counter()
    with MinecraftSession(seed=args.seed) as session:
        for job in todo:
            try:
                res = session.record(out, job.key(), job.episode_type, job.seed, job.height, job.width, job.split)
                print(f"episode {job.episode} ({job.episode_type}): {res['ticks']} ticks, aborted={res['aborted']} "
                      f"{res['abort_reason']}", file=sys.stderr)
            except Exception:  # noqa: BLE001 - reported per episode; the collect goes on
                failed += 1
                print(f"episode {job.episode} instance {job.instance} failed:\n{traceback.format_exc()}",
                      file=sys.stderr)
    print(f"wrote {len(todo) - failed} episodes ({failed} failed) in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    if args.eval:
        write_eval_bookkeeping(out, sorted({j.eval_type for j in jobs}))
    clean_staging(out, remove_root=True)
    return 1 if failed else 0


def cmd_setup_minecraft(args) -> int:
    from solaris_env.engine.minecraft.install import setup

    return setup(skip_apt=args.skip_apt, force_npm=args.force_npm)


def cmd_preview(args) -> int:
    episodes = sorted(Path(args.dir).rglob("*_Alpha_*.mp4"))
    if not episodes:
        raise SystemExit(f"no *_Alpha_*.mp4 under {args.dir}")
    out = Path(args.out)
    video = Path(args.video) if args.video else out.with_suffix(".mp4")
    png = out if out.suffix.lower() != ".mp4" else out.with_suffix(".png")
    contact_sheet(episodes[: args.rows], png, args.columns)
    if not 0 <= args.episode < len(episodes):
        raise SystemExit(f"--episode must be in [0, {len(episodes)}), got {args.episode}")
    side_by_side(episodes[args.episode], video)
    print(f"wrote {png} and {video}", file=sys.stderr)
    return 0


def cmd_export_vpt(args) -> int:
    from solaris_env.engine.vpt_export import export_vpt

    counts = export_vpt(args.src, args.out, link=not args.copy)
    for split, c in counts.items():
        print(f"vpt/{split}: {c}", file=sys.stderr)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="solaris-engine", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_debug_flag(parser, top=True)
    sub = parser.add_subparsers(dest="command", required=True)

    c = sub.add_parser("collect", help="simulate, render and record episodes")
    c.add_argument("--out", required=True, help="output root (gets duet/{train,test}/ or eval/<Type>/test/)")
    c.add_argument("--episodes", type=positive_int, default=None,
                   help=f"training: number of episodes; eval: episodes per type (default {DEFAULT_EVAL_EPISODES})")
    c.add_argument("--world", choices=("flat", "normal", "mixed"), default="mixed",
                   help="training world kind; mixed = flat on even instances, normal on odd ones")
    c.add_argument("--resolution", type=parse_resolution, default=(64, 64), help="R (square) or WxH, e.g. 1280x720")
    c.add_argument("--seed", type=int, default=0, help="collect seed; also the training batch id")
    c.add_argument("--workers", type=positive_int, default=1,
                   help="processes, each with its own renderer (1 = in-process)")
    c.add_argument("--instances", type=positive_int, default=2, help="training: episode e runs on instance e mod this")
    c.add_argument("--instance-offset", type=non_negative_int, default=0, help="added to every instance id")
    c.add_argument("--test-fraction", type=float, default=0.01, help="training: deterministic fraction in duet/test")
    c.add_argument("--types", nargs="+", default=None, help="training: sample only these episode types (also the opt-in ones, e.g. lookAround)")
    c.add_argument("--time-of-day", choices=("cycle", "day"), default=None,
                   help="training: 'cycle' (default) starts each episode at a random time of day (the reference's "
                        "natural cycle), 'day' at noon, as the eval episodes, the envs and the minecraft backend do")
    c.add_argument("--eval", action="store_true", help="collect the eval sets instead of training data")
    c.add_argument("--eval-types", nargs="+", default=None, help="eval: these types (default: all registered)")
    c.add_argument("--chunk-ticks", type=positive_int, default=None,
                   help=f"ticks rendered per renderer call (x 2 views); default: <= {MAX_CHUNK_TICKS} within "
                        f"{CHUNK_PIXEL_BUDGET} pixels")
    c.add_argument("--backend", choices=("voxel", "minecraft"), default="voxel",
                   help="voxel: our engine; minecraft: real Minecraft 1.20.1 (needs `setup-minecraft`)")
    add_debug_flag(c)
    c.set_defaults(func=cmd_collect)

    m = sub.add_parser("setup-minecraft", help="install the real-Minecraft backend (apt packages, npm ci, patch)")
    m.add_argument("--skip-apt", action="store_true", help="fail instead of running apt-get for missing packages")
    m.add_argument("--force-npm", action="store_true", help="run npm ci even if node_modules looks built")
    add_debug_flag(m)
    m.set_defaults(func=cmd_setup_minecraft)

    p = sub.add_parser("preview", help="contact sheet PNG + side-by-side mp4 of collected episodes")
    p.add_argument("dir", help="a collect output dir (searched recursively for *_Alpha_*.mp4)")
    p.add_argument("--out", required=True, help="contact sheet PNG path")
    p.add_argument("--video", default=None, help="side-by-side mp4 path (default: --out with .mp4)")
    p.add_argument("--episode", type=int, default=0, help="index (sorted like the loader) of the episode to video")
    p.add_argument("--rows", type=int, default=PREVIEW_EPISODES, help="episodes in the contact sheet")
    p.add_argument("--columns", type=int, default=PREVIEW_COLUMNS, help="frames per row")
    add_debug_flag(p)
    p.set_defaults(func=cmd_preview)

    v = sub.add_parser("export-vpt", help="export each bot recording of a collect as a single-player VPT episode")
    v.add_argument("src", help="a collect output dir (reads SRC/duet/{train,test})")
    v.add_argument("--out", required=True, help="output root (gets vpt/{train,test}/episodes_info.json + engine/)")
    v.add_argument("--copy", action="store_true", help="copy the mp4s instead of hard-linking them")
    add_debug_flag(v)
    v.set_defaults(func=cmd_export_vpt)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Errors print one line (``--debug``: the traceback); Ctrl-C prints one line and exits with status 130
    (``solaris_env.cli_support``)."""
    args = build_parser().parse_args(argv)
    return run_command("solaris-engine", args.func, args, debug=args.debug)


# ---------------------------------------------------------------------------------------------
# Preview
# ---------------------------------------------------------------------------------------------


def _bravo_of(alpha_mp4: Path) -> Path:
    return alpha_mp4.with_name(alpha_mp4.name.replace("_Alpha_", "_Bravo_", 1))


def episode_label(alpha_mp4: Path) -> str:
    """'<stem> <episode type>' from the episode_info (training) or the sidecar (eval)."""
    stem = alpha_mp4.name.removesuffix(".mp4").removesuffix("_camera")
    info = alpha_mp4.with_name(stem + "_episode_info.json")
    sidecar = alpha_mp4.with_name(stem.replace("_Alpha_instance_", "_instance_") + "_groundtruth.json")
    etype = alpha_mp4.parent.parent.name
    if info.is_file():
        etype = json.loads(info.read_text())["episode_type"]
    elif sidecar.is_file():
        etype = json.loads(sidecar.read_text())["episode_type"]
    return f"{stem.replace('_Alpha', '')}  {etype}"


def _read_frames(path: Path, indices=None):
    """RGB frames of a video (all, or those at ``indices``)."""
    import cv2

    cap = cv2.VideoCapture(str(path))
    frames, i, want = [], 0, None if indices is None else set(int(k) for k in indices)
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        if want is None or i in want:
            frames.append(bgr[..., ::-1])
        i += 1
    cap.release()
    return frames


def _frame_count(path: Path) -> int:
    import cv2

    cap = cv2.VideoCapture(str(path))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    return n


def contact_sheet(alpha_videos: list[Path], png: Path, columns: int) -> None:
    """Rows = episodes x (Alpha, Bravo), columns = frames evenly spread over time, a label per row."""
    import numpy as np
    from PIL import Image, ImageDraw

    rows, labels = [], []
    for alpha in alpha_videos:
        label = episode_label(alpha)
        for bot, path in (("Alpha", alpha), ("Bravo", _bravo_of(alpha))):
            n = _frame_count(path)
            idx = np.linspace(0, max(n - 1, 0), columns).round().astype(int)
            frames = _read_frames(path, idx)
            by_index = dict(zip(sorted(set(idx.tolist())), frames))
            rows.append([by_index[k] for k in idx.tolist() if k in by_index])
            labels.append(f"{label}  {bot}  ({n} frames)")
    h, w = rows[0][0].shape[:2]
    scale = max(1, -(-PREVIEW_MIN_CELL // h))
    ch, cw, label_h, gap = h * scale, w * scale, 14, 2
    sheet = Image.new("RGB", (columns * (cw + gap), len(rows) * (ch + label_h + gap)), (24, 24, 24))
    draw = ImageDraw.Draw(sheet)
    for r, (frames, label) in enumerate(zip(rows, labels)):
        y = r * (ch + label_h + gap)
        draw.text((2, y + 1), label, fill=(235, 235, 235))
        for c, frame in enumerate(frames):
            cell = Image.fromarray(np.ascontiguousarray(frame)).resize((cw, ch), Image.NEAREST)
            sheet.paste(cell, (c * (cw + gap), y + label_h))
    png.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(png)


def side_by_side(alpha_mp4: Path, video: Path) -> None:
    """Alpha | Bravo per frame (a 2-pixel white separator), 20 fps mp4v; the shorter side holds its last frame."""
    import cv2
    import numpy as np

    from solaris_env.engine.recorder import VIDEO_FOURCC, VIDEO_FPS

    caps = [cv2.VideoCapture(str(p)) for p in (alpha_mp4, _bravo_of(alpha_mp4))]
    video.parent.mkdir(parents=True, exist_ok=True)
    writer, last = None, [None, None]
    try:
        while True:
            reads = [cap.read() for cap in caps]
            if not any(ok for ok, _ in reads):
                break
            for k, (ok, bgr) in enumerate(reads):
                if ok:
                    last[k] = bgr
            left, right = (f if f is not None else np.zeros_like(last[1 - k]) for k, f in enumerate(last))
            sep = np.full((left.shape[0], 2, 3), 255, np.uint8)
            frame = np.concatenate([left, sep, right], axis=1)
            if writer is None:
                writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*VIDEO_FOURCC), VIDEO_FPS,
                                         (frame.shape[1], frame.shape[0]))
            writer.write(frame)
    finally:
        for cap in caps:
            cap.release()
        if writer is not None:
            writer.release()


if __name__ == "__main__":
    sys.exit(main())
