"""``solaris-env play``: input -> actions, the WebSocket server on the real env, the OpenCV window's pure parts, and
an end-to-end run in headless Chromium (pointer lock, mouse, keys) driven over the DevTools protocol."""

import base64
import itertools
import json
import math
import shutil
import subprocess
import threading
import time
import urllib.error
import urllib.request
from contextlib import contextmanager

import cv2
import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from solaris_env import play
from solaris_env.spaces import BINARY_KEYS, CAMERA_TICK_LIMIT_DEG, validate_action

# ---------------------------------------------------------------------------------------------
# PlayControls
# ---------------------------------------------------------------------------------------------


def test_mouse_pixels_become_degrees_and_a_large_turn_is_carried_over_not_clipped():
    controls = play.PlayControls()
    controls.move_mouse(200, -40)  # 200 px right, 40 px up at 0.15 deg/px: yaw +30, pitch -6
    turns = [controls.next_action()["camera"].tolist() for _ in range(3)]
    assert turns == [[-6.0, 20.0], [0.0, 10.0], [0.0, 0.0]]  # 20 deg per step at most; the rest comes next step
    assert play.DEG_PER_PIXEL == 0.15 and play.MAX_TURN_DEG == 20.0


def test_held_keys_and_look_keys_make_valid_actions():
    controls = play.PlayControls()
    assert controls.apply({"keys": ["forward", "jump", "turnRight", "lookUp"], "mouse": [10, 0]}) is False
    for yaw_deg in (5.0 + 1.5, 5.0):  # held keys act every step; the mouse once
        action = validate_action(controls.next_action())
        assert {k for k in BINARY_KEYS if action[k]} == {"forward", "jump"}
        assert action["camera"].tolist() == pytest.approx([-5.0, yaw_deg])
    assert controls.apply({"keys": [], "reset": True}) is True
    assert validate_action(controls.next_action())["forward"] == 0


@pytest.mark.parametrize("message, error", [
    ([1], "JSON object"), ({"fly": 1}, "'fly'"), ({"keys": ["fly"]}, "'fly'"), ({"keys": "forward"}, "list"),
    ({"mouse": [1]}, "mouse"), ({"mouse": [float("nan"), 0]}, "finite"), ({"mouse": ["a", 0]}, "finite"),
    ({"keys": ["forward"], "mouse": [True, 0]}, "finite"), ({"keys": [["forward"]]}, "strings"),
    ({"reset": "yes"}, "'reset'"),
])
def test_bad_messages_raise_and_change_nothing(message, error):
    controls = play.PlayControls()
    controls.apply({"keys": ["back"]})
    with pytest.raises(ValueError, match=error):
        controls.apply(message)
    assert controls.held == {"back"} and controls.pending_deg_2.tolist() == [0.0, 0.0]


# ---------------------------------------------------------------------------------------------
# The WebSocket server on the real env
# ---------------------------------------------------------------------------------------------


@contextmanager
def serving(session, fps=40.0):
    server = play.make_play_server(session, port=0, fps=fps)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"127.0.0.1:{server.socket.getsockname()[1]}"
    finally:
        server.shutdown()
        thread.join(timeout=10)


def player(session):
    """(position (3,), yaw, pitch) of the driven player in the engine, radians in Mineflayer signs (+left, +up)."""
    with session.lock:
        p = session.env.game.players[session.index]
        return p.pos.copy(), p.yaw, p.pitch


def turned(after, before):
    """The signed angle after - before in (-pi, pi]."""
    return -math.remainder(before - after, 2 * math.pi)


def receive_until(ws, done, timeout=30.0):
    """Read (frame, status) pairs until ``done(status)``; returns the last pair."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        png, status = ws.recv(timeout=timeout), json.loads(ws.recv(timeout=timeout))
        assert isinstance(png, bytes)
        if done(status):
            return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), status
    raise AssertionError(f"timed out; last status {status}")


def test_server_streams_frames_and_steps_the_env_from_keys_and_mouse(real):
    session = play.PlaySession(real(), agent="Bravo", policy="bot", seed=0)
    with serving(session) as address:
        page = urllib.request.urlopen(f"http://{address}/", timeout=30)
        assert page.headers["Content-Type"].startswith("text/html") and b"solaris-env play" in page.read()
        with pytest.raises(urllib.error.HTTPError, match="404"):
            urllib.request.urlopen(f"http://{address}/frame.png", timeout=30)
        with pytest.raises(InvalidStatus, match="403"):
            connect(f"ws://{address}/ws", origin="http://evil.example").close()
        with connect(f"ws://{address}/ws") as ws:
            first, status = receive_until(ws, lambda s: True)
            assert first.shape == (36, 36, 3) and status["agent"] == "Bravo" and status["episode"] == 0
            pos, yaw, pitch = player(session)
            ws.send(json.dumps({"keys": ["forward"], "mouse": [100, 40]}))  # 15 deg right, 6 deg down
            frame, status = receive_until(ws, lambda s: np.linalg.norm(player(session)[0] - pos) > 0.5)
            assert status["turn_pending_deg"] == [0.0, 0.0] and not np.array_equal(frame, first)
            assert turned(player(session)[1], yaw) == pytest.approx(math.radians(-15.0), abs=1e-4)
            assert player(session)[2] - pitch == pytest.approx(math.radians(-6.0), abs=1e-4)

            ws.send(json.dumps({"keys": ["fly"]}))
            _, status = receive_until(ws, lambda s: "error" in s)
            assert "'fly'" in status["error"]
            ws.send(json.dumps({"reset": True}))
            _, status = receive_until(ws, lambda s: s["episode"] == 1)
            assert status["step"] == 0

            with connect(f"ws://{address}/ws") as newer:  # a reloaded page takes over; the old one is closed
                receive_until(newer, lambda s: True)
                with pytest.raises(ConnectionClosed):
                    receive_until(ws, lambda s: False)


def test_session_drives_the_dream_env(dream):
    session = play.PlaySession(dream(), agent="Bravo", policy="random", seed=0)
    controls = play.PlayControls()
    controls.apply({"keys": ["forward"], "mouse": [300, 0]})  # 45 deg: three steps of 20, 20, 5
    for _ in range(3):
        session.step(controls.next_action())
    frame = cv2.imdecode(np.frombuffer(session.frame_png(), np.uint8), cv2.IMREAD_COLOR)
    assert frame.shape == session.env.step_frames().shape[2:] and np.array_equal(
        frame[..., ::-1], session.env.step_frames()[1, -1])  # Bravo's newest frame, lossless
    assert session.status()["step"] == 3 and controls.pending_deg_2.tolist() == [0.0, 0.0]


def test_a_session_turns_at_most_what_one_env_step_turns_and_the_status_shows_the_rest(real, dream):
    for env, k in ((real(), 1), (real(ticks_per_step=4), 4), (dream(), 4)):
        session = play.PlaySession(env, agent="Alpha", policy="noop", seed=0)
        assert session.max_turn_deg == pytest.approx(k * CAMERA_TICK_LIMIT_DEG)
        controls = play.PlayControls(max_turn_deg=session.max_turn_deg)
        controls.move_mouse(600, 0)  # 90 deg right: every step turns what it can, the rest waits in the controls
        steps = 0
        while controls.pending_deg_2.any():
            session.step(controls.next_action())
            steps += 1
            assert not env._camera_pending_P2.any()  # nothing hidden in the env
        assert steps == math.ceil(90.0 / (k * CAMERA_TICK_LIMIT_DEG))


# ---------------------------------------------------------------------------------------------
# OpenCV window: the parts that need no display
# ---------------------------------------------------------------------------------------------


def test_window_keys_and_hold():
    assert [play.window_key(c) for c in (ord("w"), ord("W"), ord(" "), ord("7"), 65361, 0x1000014, ord("x"), -1)] \
        == ["forward", "forward", "jump", "hotbar.7", "turnLeft", "turnRight", None, None]
    keys = play.HeldKeys(hold_s=0.5)
    keys.press("forward", now=10.0)
    assert keys.held(10.4) == {"forward"} and keys.held(10.5) == set()


def test_window_loop_with_scripted_opencv_walks_turns_and_quits_on_esc(real, monkeypatch):
    session = play.PlaySession(real(), agent="Alpha", policy="noop", seed=0)
    pos, yaw, pitch = player(session)
    codes = iter([ord("w")] * 10 + [play.ESC_CODE])
    shown, callbacks = [], []

    def imshow(name, image):
        if not shown:  # drag the mouse 100 px right and 40 px down: 15 deg right, 6 deg down
            for event, x, y in ((cv2.EVENT_LBUTTONDOWN, 0, 0), (cv2.EVENT_MOUSEMOVE, 100, 40),
                                (cv2.EVENT_LBUTTONUP, 100, 40)):
                callbacks[0](event, x, y, 0, None)
        shown.append(image)

    for name, fake in (("namedWindow", lambda *a: None), ("setMouseCallback", lambda name, f: callbacks.append(f)),
                       ("imshow", imshow), ("waitKeyEx", lambda delay: next(codes)),
                       ("getWindowProperty", lambda *a: 1.0), ("destroyAllWindows", lambda: None)):
        monkeypatch.setattr(cv2, name, fake)
    play.run_window(session, fps=200.0, scale=4)
    assert len(shown) == 11 and shown[0].shape == (144, 144, 3) and session.steps == 10  # Esc: no 11th step
    assert np.linalg.norm(player(session)[0] - pos) > 0.5
    assert turned(player(session)[1], yaw) == pytest.approx(math.radians(-15.0), abs=1e-4)
    assert player(session)[2] - pitch == pytest.approx(math.radians(-6.0), abs=1e-4)


def test_window_problem_names_the_missing_display(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(play.sys, "platform", "linux")
    assert play.window_problem() == "no display (DISPLAY is not set)"
    monkeypatch.setenv("DISPLAY", ":0")
    if "GUI:                           NONE" in cv2.getBuildInformation():  # opencv-python-headless
        assert "no GUI support" in play.window_problem()


# ---------------------------------------------------------------------------------------------
# End to end in headless Chromium (Debian `chromium`), over the DevTools protocol
# ---------------------------------------------------------------------------------------------


class DevTools:
    """A minimal Chrome DevTools Protocol client: one page target, commands sent and awaited one at a time."""

    def __init__(self, ws, session_id):
        self.ws, self.session_id, self.ids = ws, session_id, itertools.count(1)

    def call(self, method, **params):
        message_id = next(self.ids)
        message = {"id": message_id, "method": method, "params": params}
        if self.session_id is not None:  # None: the browser itself
            message["sessionId"] = self.session_id
        self.ws.send(json.dumps(message))
        while True:  # skip events and other replies
            reply = json.loads(self.ws.recv(timeout=30))
            if reply.get("id") == message_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def js(self, expression):
        return self.call("Runtime.evaluate", expression=expression, returnByValue=True)["result"].get("value")

    def mouse(self, kind, x, y, **params):
        self.call("Input.dispatchMouseEvent", type=kind, x=x, y=y, **params)

    def key(self, kind, code, key, key_code):
        self.call("Input.dispatchKeyEvent", type=kind, code=code, key=key, windowsVirtualKeyCode=key_code)

    def wait(self, expression, timeout=20.0):
        end = time.monotonic() + timeout
        while not self.js(expression):
            if time.monotonic() > end:
                raise AssertionError(f"timed out waiting for {expression}")
            time.sleep(0.05)


@pytest.fixture
def chromium(tmp_path):
    """A headless Chromium with an empty page, as a ``DevTools`` client."""
    # --no-sandbox: Chromium's sandbox refuses to run as root (containers, CI)
    proc = subprocess.Popen(["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                             "--remote-debugging-port=0", f"--user-data-dir={tmp_path}", "about:blank"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        port_file, end = tmp_path / "DevToolsActivePort", time.monotonic() + 20
        while not (port_file.exists() and len(port_file.read_text().splitlines()) == 2):
            assert proc.poll() is None and time.monotonic() < end, "chromium did not start"
            time.sleep(0.05)
        port, path = port_file.read_text().splitlines()
        with connect(f"ws://127.0.0.1:{port}{path}", max_size=None) as ws:
            browser = DevTools(ws, None)
            target = browser.call("Target.createTarget", url="about:blank")["targetId"]
            yield DevTools(ws, browser.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"])
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.mark.browser
@pytest.mark.skipif(shutil.which("chromium") is None,
                    reason="Debian chromium is not installed (apt-get install -y chromium)")
def test_page_in_headless_chromium_walks_and_turns_the_player(real, chromium):
    session = play.PlaySession(real(), agent="Alpha", policy="noop", seed=0)
    with serving(session, fps=20.0) as address:
        chromium.call("Page.navigate", url=f"http://{address}/")
        chromium.wait("window.play && window.play.frames > 0")
        first = chromium.js("document.getElementById('view').toDataURL()")
        pos, yaw, pitch = player(session)

        # click the view for pointer lock (a move first, so Chromium knows where the pointer is), then move it
        box = json.loads(chromium.js("JSON.stringify(document.getElementById('view').getBoundingClientRect())"))
        x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        chromium.mouse("mouseMoved", x, y)
        for kind in ("mousePressed", "mouseReleased"):
            chromium.mouse(kind, x, y, button="left", buttons=int(kind == "mousePressed"), clickCount=1)
        chromium.wait("document.pointerLockElement === document.getElementById('view')")
        for i in range(1, 5):  # 100 px right, 40 px down in four moves: 15 deg right, 6 deg down
            chromium.mouse("mouseMoved", x + 25 * i, y + 10 * i)
        end = time.monotonic() + 20
        while abs(turned(player(session)[1], yaw) - math.radians(-15.0)) > 1e-4 and time.monotonic() < end:
            time.sleep(0.05)

        chromium.key("keyDown", "KeyW", "w", 87)  # hold W until the player has walked a block (>= 5 steps at 20 Hz)
        end = time.monotonic() + 20
        while np.linalg.norm(player(session)[0] - pos) < 1.0 and time.monotonic() < end:
            time.sleep(0.05)
        chromium.key("keyUp", "KeyW", "w", 87)

        status = chromium.js("window.play.status")
        last = chromium.js("document.getElementById('view').toDataURL()")
        frame = cv2.imdecode(np.frombuffer(base64.b64decode(last.split(",", 1)[1]), np.uint8), cv2.IMREAD_COLOR)
        # walking 1 block takes >= 1 / (4.317 b/s / 20 steps/s) = 4.6 steps, each sending one frame
        assert frame.shape == (36, 36, 3) and last != first and chromium.js("window.play.frames") >= 5
        assert status["agent"] == "Alpha" and status["step"] >= 5 and "error" not in status
        assert np.linalg.norm(player(session)[0] - pos) >= 1.0  # walked forward
        assert turned(player(session)[1], yaw) == pytest.approx(math.radians(-15.0), abs=1e-4)  # turned right
        assert player(session)[2] - pitch == pytest.approx(math.radians(-6.0), abs=1e-4)  # looked down
