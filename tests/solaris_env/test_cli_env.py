"""``solaris-env``: fast --help, info, rollout (real and dream) to mp4 (+ rrd), play's argument errors."""

import subprocess
import sys
import time

import cv2
import pytest

from solaris_env import cli_env


def test_help_returns_in_under_half_a_second():
    code = "import sys; from solaris_env.cli_env import main; sys.argv[0] = 'solaris-env'; main(['--help'])"
    cmd = [sys.executable, "-c", code]
    times = []
    for _ in range(3):  # the best of 3: the machine is shared
        start = time.perf_counter()
        out = subprocess.run(cmd, capture_output=True, text=True, check=False)
        times.append(time.perf_counter() - start)
        assert out.returncode == 0 and "rollout" in out.stdout and "play" in out.stdout
    assert min(times) < 0.5, times
    check = "import sys, solaris_env.cli_env; print(sorted(m for m in ('jax', 'torch', 'gymnasium') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_gymnasium_ids_register_in_either_import_order():
    # the third order has our wrapper import gymnasium first: the registration must not need a circular import
    for code in ("import solaris_env, gymnasium", "import gymnasium, solaris_env",
                 "import solaris_env.wrappers.single_agent, gymnasium"):
        code += "; print(sorted(k for k in gymnasium.registry if k.startswith('solaris_env/')))"
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        assert out.stdout.strip() == "['solaris_env/Dream-v0', 'solaris_env/Real-v0']", code


def test_info(capsys):
    assert cli_env.main(["info"]) == 0
    out = capsys.readouterr().out
    assert "solaris_env/Dream-v0" in out and "start scenes  : 12" in out and "visual_novelty" in out


def frame_count(path):
    cap = cv2.VideoCapture(str(path))
    n, w, h = (int(cap.get(p)) for p in (cv2.CAP_PROP_FRAME_COUNT, cv2.CAP_PROP_FRAME_WIDTH,
                                          cv2.CAP_PROP_FRAME_HEIGHT))
    cap.release()
    return n, w, h


def test_rollout_real_with_bots_writes_mp4_and_rrd(tmp_path, capsys):
    out, rrd = tmp_path / "real.mp4", tmp_path / "real.rrd"
    assert cli_env.main(["rollout", "--kind", "real", "--resolution", "36", "--world", "flat", "--steps", "20",
                         "--policy", "bot", "--task", "visual_novelty", "--out", str(out), "--rrd", str(rrd)]) == 0
    assert frame_count(out) == (21, 72, 36) and rrd.stat().st_size > 0
    assert "20 steps" in capsys.readouterr().out


def test_rollout_dream_test_preset(tmp_path):
    out = tmp_path / "dream.mp4"
    assert cli_env.main(["rollout", "--kind", "dream", "--preset", "test", "--steps", "3", "--out", str(out)]) == 0
    assert frame_count(out) == (1 + 3 * 4, 64, 32)


def test_rollout_argument_errors(tmp_path, capsys):
    with pytest.raises(SystemExit):
        cli_env.main(["rollout", "--kind", "moon"])
    for bad in (["--steps", "0"], ["--steps", "2.5"], ["--players", "-1"], ["--seed", "-3"]):
        with pytest.raises(SystemExit) as err:
            cli_env.main(["rollout", *bad])
        assert err.value.code == 2 and f"argument {bad[0]}: expected an integer" in capsys.readouterr().err


def test_rollout_checks_the_output_path_before_building_the_model(tmp_path, monkeypatch):
    import solaris_env.dream_env

    def no_model(*args, **kwargs):
        raise AssertionError("the model was built before the output path was checked")

    monkeypatch.setattr(solaris_env.dream_env, "build_model", no_model)
    (tmp_path / "taken.mp4").mkdir()
    (tmp_path / "file").write_text("x")
    for out, says in [("noext", "ending in .mp4"), ("video.avi", "ending in .mp4"),
                      (tmp_path / "taken.mp4", "is a directory"), (tmp_path / "file" / "a.mp4", "not a directory")]:
        with pytest.raises(SystemExit, match=f"solaris-env: error: ValueError: --out: .*{says}"):
            cli_env.main(["rollout", "--kind", "dream", "--out", str(out)])
    with pytest.raises(SystemExit, match="--rrd: expected a file name ending in .rrd"):
        cli_env.main(["rollout", "--kind", "dream", "--out", str(tmp_path / "a.mp4"), "--rrd", str(tmp_path / "a")])


def test_cli_errors_are_one_line_and_debug_shows_the_traceback(tmp_path):
    missing = tmp_path / "no_such_checkpoint"
    args = ["rollout", "--kind", "dream", "--checkpoint", str(missing), "--out", str(tmp_path / "a.mp4")]
    code = "import sys; from solaris_env.cli_env import main; sys.exit(main(sys.argv[1:]))"
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, check=False)
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 1 and len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    assert lines[0].startswith("solaris-env: error: ") and str(missing) in lines[0] and "--debug" in lines[0]
    out = subprocess.run([sys.executable, "-c", code, "--debug", *args], capture_output=True, text=True, check=False)
    assert out.returncode == 1 and "Traceback" in out.stderr and str(missing) in out.stderr


def test_play_window_without_a_display_is_a_clear_error(monkeypatch):
    # the server and the page are tested in test_play.py
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    with pytest.raises(SystemExit, match="--window: no display .* drop --window"):
        cli_env.main(["play", "--window"])
