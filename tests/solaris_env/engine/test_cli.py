"""``solaris-engine`` (``engine.cli``) end to end (collect, resume, crash safety, eval layout, preview) with
the real renderer at 64x36 (16:9 like the reference's 1280x720, so a 40 deg turn stays on screen).

One renderer is shared by every in-process collect (``cli.get_renderer``), so the jit compiles once.
"""

import json
import re
import subprocess
import sys
import time

import numpy as np
import pytest

from solaris_env.engine import cli
from solaris_env.engine import recorder as rec
from solaris_env.engine.bots.runner import EpisodeConfig, run_episode
from solaris_env.engine.capture import ground_truth, render_episode
from solaris_env.engine.eval_protocol import sneak_end

RES = ["--resolution", "64x36"]
HEIGHT, WIDTH = 36, 64
TRAIN_RE = re.compile(r"batch_3_(\d{6})_(Alpha|Bravo)_instance_(\d{3})(\.mp4|\.json|_episode_info\.json)")
EVAL_RE = re.compile(r"(\d{6})_(Alpha|Bravo)_instance_(\d{3})(_camera\.mp4|\.json)")
SIDECAR_RE = re.compile(r"(batch_3_)?\d{6}_instance_\d{3}_groundtruth\.json")
ACTION_KEYS = {"forward", "back", "left", "right", "jump", "sprint", "sneak", "camera", "attack", "use", "mount",
               "dismount", "place_block", "place_entity", "mine"} | {f"hotbar.{k}" for k in range(1, 10)}
RECORD_FIELDS = {"x", "y", "z", "yaw", "pitch", "action", "inventory", "renderTime", "physicsTime", "worldAgeTicks",
                 "isInWater", "frame_count", "episode_id", "relativeTimeMs", "epochTime", "extra_info"}
INFO_FIELDS = {"timestamp", "bot_name", "world_type", "episode_number", "episode_type", "instance_id",
               "encountered_error", "peer_encountered_error", "bot_died", "episode_recording_started", "eval_metadata"}


def _collect_args(out, *extra):
    return ["collect", "--out", str(out), *RES, "--seed", "3", "--world", "flat", "--types", "walkLook", *extra]


def _decode(path):
    import cv2

    cap = cv2.VideoCapture(str(path))
    reported = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    frames = []
    while True:
        ok, bgr = cap.read()
        if not ok:
            break
        frames.append(bgr)
    cap.release()
    return reported, frames


def _bot_files(out):
    return sorted(p for p in (out / "duet").rglob("*") if p.is_file())


@pytest.fixture(scope="module")
def train_out(tmp_path_factory):
    out = tmp_path_factory.mktemp("collect")
    assert cli.main(_collect_args(out, "--episodes", "2")) == 0
    return out


@pytest.fixture(scope="module")
def eval_out(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval")
    assert cli.main(["collect", "--out", str(out), *RES, "--eval", "--eval-types", "rotationEval", "--episodes", "1"]) == 0
    return out


# ---------------------------------------------------------------------------------------------
# Training collect
# ---------------------------------------------------------------------------------------------


def test_help_is_fast():
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "solaris_env.engine.cli", "--help"], capture_output=True, text=True)
    assert res.returncode == 0 and "collect" in res.stdout
    assert time.perf_counter() - t0 < 2.0


def test_training_layout(train_out):
    files = _bot_files(train_out)
    sidecars = [p for p in files if SIDECAR_RE.fullmatch(p.name)]
    bot_files = [p for p in files if p not in sidecars]
    assert len(sidecars) == 2 and len(bot_files) == 12
    assert all(TRAIN_RE.fullmatch(p.name) and p.parent.name in ("train", "test") for p in bot_files)
    assert {TRAIN_RE.fullmatch(p.name)[3] for p in bot_files} == {"000", "001"}  # episode e on instance e mod 2
    assert not (train_out / rec.STAGING_DIR).exists()


def test_video_frames_equal_actions(train_out):
    for mp4 in (train_out / "duet").rglob("*.mp4"):
        records = json.loads(mp4.with_suffix(".json").read_text())
        reported, frames = _decode(mp4)
        assert reported == len(frames) == len(records) > 100
        assert frames[0].shape == (HEIGHT, WIDTH, 3)


def test_records_and_episode_info(train_out):
    for alpha in (train_out / "duet").rglob("*_Alpha_*.json"):
        if alpha.name.endswith("_episode_info.json"):
            continue
        bravo = alpha.with_name(alpha.name.replace("_Alpha_", "_Bravo_"))
        ra, rb = json.loads(alpha.read_text()), json.loads(bravo.read_text())
        for r in ra + rb:
            assert set(r) == RECORD_FIELDS and set(r["action"]) == ACTION_KEYS
            assert len(r["action"]["camera"]) == 2
        times = [r["renderTime"] for r in ra]
        assert all(b > a for a, b in zip(times, times[1:]))
        assert times == [r["renderTime"] for r in rb]
        assert [r["frame_count"] for r in ra] == list(range(len(ra)))
        info = json.loads(alpha.with_name(alpha.stem + "_episode_info.json").read_text())
        assert set(info) == INFO_FIELDS and info["bot_name"] == "Alpha" and info["episode_type"] == "walkLook"


def test_groundtruth_walklook_players_see_each_other_at_start(train_out):
    for sc in (train_out / "duet").rglob("*_groundtruth.json"):
        gt = json.loads(sc.read_text())
        assert gt["episode_type"] == "walkLook" and gt["frame_size"] == [HEIGHT, WIDTH]
        for viewer, other in (("Alpha", "Bravo"), ("Bravo", "Alpha")):
            sight = gt["sight"][viewer][other]
            assert sight["visible"][0] and sight["region"][0] == "center"
            assert all(len(v) == gt["num_frames"] for v in sight.values())


def test_resume_skips_finished_and_cleans_stale_staging(train_out):
    before = {p: p.stat().st_mtime_ns for p in _bot_files(train_out)}
    stale = train_out / rec.STAGING_DIR / "batch_3_000001_001-999-dead"
    stale.mkdir(parents=True)
    (stale / "batch_3_000001_Alpha_instance_001.mp4").write_bytes(b"half")
    assert cli.main(_collect_args(train_out, "--episodes", "2")) == 0
    assert {p: p.stat().st_mtime_ns for p in _bot_files(train_out)} == before
    assert not (train_out / rec.STAGING_DIR).exists()


def test_crash_mid_write_leaves_no_episode_files(tmp_path, monkeypatch):
    def boom(path, frames):
        path.write_bytes(b"truncated")
        raise OSError("simulated crash in the mp4 writer")

    monkeypatch.setattr(rec, "write_mp4", boom)
    assert cli.main(_collect_args(tmp_path, "--episodes", "1")) == 1
    assert list(tmp_path.rglob("*.mp4")) == [] and list(tmp_path.rglob("*.json")) == []


# ---------------------------------------------------------------------------------------------
# Eval collect
# ---------------------------------------------------------------------------------------------


def test_eval_layout_and_eval_ids(eval_out):
    test_dir = eval_out / "eval" / "rotationEval" / "test"
    names = sorted(p.name for p in test_dir.iterdir())
    assert names == ["000000_Alpha_instance_000.json", "000000_Alpha_instance_000_camera.mp4",
                     "000000_Bravo_instance_000.json", "000000_Bravo_instance_000_camera.mp4",
                     "000000_instance_000_groundtruth.json"]
    assert all(EVAL_RE.fullmatch(n) for n in names[:4])
    alpha = json.loads((test_dir / names[0]).read_text())
    assert _decode(test_dir / names[1])[0] == len(alpha)
    start = sneak_end(alpha)  # episode 0: Alpha turns +40 deg (case 0)
    rows = json.loads((eval_out / "eval" / "eval_ids_rotationEval.json").read_text())
    assert rows == [[0, start, start + 257, start, start + 257]]


def test_eval_rotation_plus_40_leaves_other_on_the_right(eval_out):
    gt = json.loads((eval_out / "eval/rotationEval/test/000000_instance_000_groundtruth.json").read_text())
    assert gt["episode_info"]["Alpha"]["eval_metadata"]["rotation_degrees"] == 40.0
    sight = gt["sight"]["Alpha"]["Bravo"]
    assert sight["region"][gt["start_ticks"]["Alpha"] - 1] == "center"
    assert sight["region"][-1] == "right"  # turned left by 40 deg -> the judge's answer "right"


def test_rotation_180_hides_the_other_player():
    out = run_episode(EpisodeConfig(seed=0, instance=0, episode=2, world_kind="flat", episode_type="rotationEval"))
    assert out.infos[0]["eval_metadata"]["rotation_degrees"] == 180.0  # case 2: Alpha turns around
    renderer = cli.get_renderer(HEIGHT, WIDTH)
    frames, avatar_ids = render_episode(out.trace, renderer, cli.auto_chunk_ticks(HEIGHT, WIDTH))
    assert frames.shape == (2, out.trace.num_ticks, HEIGHT, WIDTH, 3)
    gt = ground_truth(out.trace, avatar_ids, out.tick_events)
    start = out.start_ticks[0]
    assert gt["sight"]["Alpha"]["Bravo"]["visible"][start - 1]
    assert not gt["sight"]["Alpha"]["Bravo"]["visible"][-1]
    assert gt["sight"]["Alpha"]["Bravo"]["region"][-1] == "none"
    assert gt["sight"]["Bravo"]["Alpha"]["visible"][-1]  # the observer still sees the rotator


# ---------------------------------------------------------------------------------------------
# Preview
# ---------------------------------------------------------------------------------------------


def test_preview_png_and_side_by_side(train_out, tmp_path):
    from PIL import Image

    png = tmp_path / "sheet.png"
    assert cli.main(["preview", str(train_out), "--out", str(png), "--columns", "5"]) == 0
    with Image.open(png) as im:
        assert im.width >= 5 * WIDTH and im.height >= 4 * HEIGHT  # 2 episodes x 2 bots
        assert np.asarray(im).std() > 5
    first_alpha = sorted((train_out / "duet").rglob("*_Alpha_*.mp4"))[0]
    reported, frames = _decode(tmp_path / "sheet.mp4")
    assert reported == len(frames) == len(json.loads(first_alpha.with_suffix(".json").read_text()))
    assert frames[0].shape == (HEIGHT, 2 * WIDTH + 2, 3)


@pytest.mark.slow
def test_spawn_workers_write_the_same_data(train_out, tmp_path):
    """2 'spawn' workers (each with its own renderer) produce the in-process collect's records and sidecars."""
    assert cli.main(_collect_args(tmp_path, "--episodes", "2", "--workers", "2")) == 0
    mine = sorted(p.relative_to(tmp_path) for p in _bot_files(tmp_path))
    assert mine == sorted(p.relative_to(train_out) for p in _bot_files(train_out))
    for rel in mine:
        if rel.suffix == ".json":
            assert (tmp_path / rel).read_text() == (train_out / rel).read_text(), rel


# ---------------------------------------------------------------------------------------------
# Argument errors and Ctrl-C
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("flag,value", [("--episodes", "-3"), ("--episodes", "0"), ("--workers", "0"),
                                        ("--instances", "0"), ("--chunk-ticks", "-1"), ("--instance-offset", "-2")])
def test_collect_refuses_nonsense_counts_naming_the_argument(tmp_path, capsys, flag, value):
    args = ["collect", "--out", str(tmp_path / "out"), "--episodes", "1", flag, value]
    with pytest.raises(SystemExit) as err:
        cli.main(args)
    assert err.value.code == 2 and f"argument {flag}: expected an integer >= " in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("extra", [["--eval"], ["--backend", "minecraft"]])
def test_collect_refuses_the_day_cycle_where_every_episode_starts_at_noon(tmp_path, extra):
    with pytest.raises(SystemExit, match="--time-of-day cycle is for the voxel backend's training data"):
        cli.main(["collect", "--out", str(tmp_path / "out"), "--episodes", "1", "--time-of-day", "cycle", *extra])
    assert not (tmp_path / "out").exists()


def _interrupted(args, delay_s, cwd):
    """Run ``solaris-engine ARGS`` in a subprocess, send it SIGINT ``delay_s`` after the command started (its first
    line on stderr; before ``main`` runs, during the interpreter's start-up, Ctrl-C is Python's own): (status,
    stderr, seconds from the signal to the exit)."""
    import signal

    # Ctrl-C's default handler, as in a terminal: a test run started as a background job (`cmd &`) would
    # otherwise pass SIGINT-ignored on to the child, whose handling then (rightly) changes nothing
    code = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
            "from solaris_env.engine.cli import main; sys.exit(main(sys.argv[1:]))")
    proc = subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=cwd)
    first = proc.stderr.readline()
    time.sleep(delay_s)
    sent = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    return proc.returncode, first + err, time.perf_counter() - sent


def _assert_interrupted_cleanly(status, err, seconds):
    assert status == 130, err
    assert "Traceback" not in err and "Fatal" not in err and "Segmentation" not in err, err
    lines = [line for line in err.replace("\r", "\n").splitlines() if "interrupted" in line]
    assert lines == ["solaris-engine: interrupted"], err
    assert seconds < 10, seconds


@pytest.mark.parametrize("delay_s", [0.0, 1.5, 4.0])
def test_ctrl_c_during_collect_exits_130_with_one_line(tmp_path, delay_s):
    """Ctrl-C as the collect starts, while JAX compiles the renderer, or while rendering: status 130 and one line
    (never "Fatal Python error: Segmentation fault", which an interrupt that hits the compile can cause)."""
    args = ["collect", "--out", str(tmp_path / "out"), "--episodes", "2", "--resolution", "32", "--seed", "5"]
    _assert_interrupted_cleanly(*_interrupted(args, delay_s, tmp_path))


@pytest.mark.slow
def test_a_collect_interrupted_by_ctrl_c_resumes(tmp_path):
    args = ["collect", "--out", str(tmp_path / "out"), "--episodes", "2", "--resolution", "32", "--seed", "5",
            "--workers", "2"]
    _assert_interrupted_cleanly(*_interrupted(args, 6.0, tmp_path))
    assert cli.main(args[:-2]) == 0
    assert len(list((tmp_path / "out" / "duet").rglob("*.mp4"))) == 4


def test_a_main_thread_stuck_in_native_code_is_still_ended_by_ctrl_c(tmp_path):
    """The watcher thread ends the process after the grace period when the main thread cannot get the
    KeyboardInterrupt (simulated: a handler that swallows it)."""
    import signal

    code = ("import signal, sys, time\n"
            "signal.signal(signal.SIGINT, signal.default_int_handler)\n"  # as in a terminal (see _interrupted)
            "from solaris_env.cli_support import interrupts_exit_cleanly\n"
            "with interrupts_exit_cleanly('stuck', grace_s=0.5):\n"
            "    signal.signal(signal.SIGINT, lambda *a: None)\n"
            "    print('ready', flush=True)\n"
            "    time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    start = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130 and err.strip() == "stuck: interrupted" and time.perf_counter() - start < 5


def test_ctrl_c_swallowed_by_a_gc_callback_still_ends_the_process_at_once():
    """A KeyboardInterrupt raised where Python can only report it ("Exception ignored in ...": a garbage-collector
    callback such as JAX's, a ``__del__``) ends the process at once with the one line, no traceback."""
    code = ("import signal, sys, time\n"
            "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "from solaris_env.cli_support import interrupts_exit_cleanly\n"
            "class Bomb:\n"
            "    def __del__(self):\n"
            "        raise KeyboardInterrupt\n"
            "with interrupts_exit_cleanly('gc', grace_s=30):\n"
            "    Bomb()\n"
            "    print('survived', flush=True)\n"
            "    time.sleep(60)\n")
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert out.returncode == 130 and out.stderr.strip() == "gc: interrupted", out.stderr
    assert "survived" not in out.stdout and time.perf_counter() - start < 10
