"""``solaris-env play``: a person drives one player with keyboard and mouse; the others follow a policy.

Two front ends share one :class:`PlaySession` (the env and its scripted players) and one :class:`PlayControls`
(held keys and mouse movement -> one MineRL env action per step):

* a local web page (the default; needs no display, so it works over an SSH port forward): ``make_play_server``
  serves the page at ``http://127.0.0.1:PORT/`` and drives the env over a WebSocket at ``/ws``. The server steps
  the env ``fps`` times a second with the newest input and sends each step's frame back.
* an OpenCV window (``run_window``), where a display and a GUI build of OpenCV exist (``window_problem``).

WebSocket protocol. One connection drives at a time; a newer one (a reloaded page) takes over.

* page -> server: text, a JSON object with any of
  ``"keys"``: the keys held now, a list of MineRL binary keys (``spaces.BINARY_KEYS``) and look keys
  (``LOOK_KEYS``), replacing the previous set; ``"mouse"``: ``[dx, dy]`` pointer-lock movement in CSS pixels
  since the last message (+x right, +y down); ``"reset": true``: start a new episode.
* server -> page, each env step: one binary message, the driven player's newest frame as PNG, then one text
  message, the JSON status of ``PlaySession.status`` plus ``"turn_pending_deg"``. A bad message is answered with
  ``{"error": ...}`` in the status and changes nothing; the connection carries on.

Camera units. The env camera is [dpitch, dyaw] in degrees per step, +pitch looks down, +yaw turns right
(``spaces.make_action_space``). Mouse pixels become degrees at ``DEG_PER_PIXEL`` = 0.15 deg/px
(``spaces.VPT_CAMERA_DEG_PER_PIXEL``, the mouse sensitivity of the VPT recordings), so a sweep turns as far as it
did for the people in the training data. One step turns at most what the env turns in one step,
``PlaySession.max_turn_deg`` = k x ``spaces.CAMERA_TICK_LIMIT_DEG`` (8.59 deg per engine tick, the training data's
look speed; k = the env's ticks per step: 8.59 deg in the real env at 20 steps/s, 34.4 in the dream at 5 steps/s,
172 deg/s in both; ``PlayControls`` alone defaults to ``MAX_TURN_DEG`` = 20). Nothing is clipped: movement beyond
that is carried over and turned in the next steps (the status shows what is pending).
"""

from __future__ import annotations

import json
import math
import os
import sys
import threading
import time
from collections.abc import Iterable
from typing import Any

import numpy as np

from solaris_env.spaces import (
    BINARY_KEYS,
    CAMERA_CLIP_DEG,
    CAMERA_KEY,
    CAMERA_TICK_LIMIT_DEG,
    VPT_CAMERA_DEG_PER_PIXEL,
    noop,
)
from solaris_env.wrappers.opponents import make_opponents

DEG_PER_PIXEL = VPT_CAMERA_DEG_PER_PIXEL  # 360 / 2400 = 0.15 deg per pixel of mouse movement
MAX_TURN_DEG = CAMERA_CLIP_DEG  # PlayControls' default per step and axis; the rest waits for the next steps
LOOK_DEG_PER_STEP = 5.0  # what a held arrow key turns per step
# look key -> its unit turn [dpitch, dyaw] (MineRL signs: +down, +right)
LOOK_KEYS = {"lookUp": (-1.0, 0.0), "lookDown": (1.0, 0.0), "turnLeft": (0.0, -1.0), "turnRight": (0.0, 1.0)}

# ---------------------------------------------------------------------------------------------
# Input -> env action
# ---------------------------------------------------------------------------------------------


class PlayControls:
    """The driven player's input between env steps: the held keys and the turn not yet made.

    Args:
        deg_per_pixel: degrees of camera turn per pixel of mouse movement.
        max_turn_deg: the largest turn per step and axis; more is carried over to later steps, never dropped.
        look_deg_per_step: the turn per step of a held look key (``LOOK_KEYS``).
    """

    def __init__(self, deg_per_pixel: float = DEG_PER_PIXEL, max_turn_deg: float = MAX_TURN_DEG,
                 look_deg_per_step: float = LOOK_DEG_PER_STEP):
        if not (deg_per_pixel > 0 and max_turn_deg > 0 and look_deg_per_step >= 0):
            raise ValueError(f"PlayControls: need deg_per_pixel > 0, max_turn_deg > 0, look_deg_per_step >= 0; got "
                             f"{deg_per_pixel}, {max_turn_deg}, {look_deg_per_step}")
        self.deg_per_pixel, self.max_turn_deg, self.look_deg_per_step = deg_per_pixel, max_turn_deg, look_deg_per_step
        self.held: frozenset[str] = frozenset()
        self.pending_deg_2 = np.zeros(2)  # [dpitch, dyaw] still to turn

    def hold(self, keys: Iterable[str]) -> None:
        """Set the held keys (MineRL binary keys and ``LOOK_KEYS``); raises ValueError naming an unknown one."""
        if isinstance(keys, (str, bytes)) or not isinstance(keys, Iterable):
            raise ValueError(f"'keys' must be a list of key names, got {keys!r}")
        keys = list(keys)
        if not all(isinstance(k, str) for k in keys):
            raise ValueError(f"'keys' must be a list of key names (strings), got {keys!r}")
        keys = frozenset(keys)
        unknown = sorted(str(k) for k in keys if k not in BINARY_KEYS and k not in LOOK_KEYS)
        if unknown:
            raise ValueError(f"unknown key {unknown[0]!r}; expected MineRL keys {list(BINARY_KEYS)} "
                             f"or look keys {list(LOOK_KEYS)}")
        self.held = keys

    def move_mouse(self, dx_px: float, dy_px: float) -> None:
        """Add mouse movement in pixels (+x right, +y down) to the turn still to make."""
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                   for v in (dx_px, dy_px)):
            raise ValueError(f"'mouse' must be two finite numbers [dx, dy] in pixels, got {[dx_px, dy_px]!r}")
        self.pending_deg_2 += (dy_px * self.deg_per_pixel, dx_px * self.deg_per_pixel)  # down = +pitch

    def apply(self, message: Any) -> bool:
        """Apply one page message (see the module docstring); returns whether it asks for a new episode.

        Raises ValueError on a malformed message, before changing anything.
        """
        if not isinstance(message, dict):
            raise ValueError(f"a message must be a JSON object, got {type(message).__name__}")
        unknown = sorted(set(message) - {"keys", "mouse", "reset"})
        if unknown:
            raise ValueError(f"unknown message field {unknown[0]!r}; expected 'keys', 'mouse', 'reset'")
        if not isinstance(message.get("reset", False), bool):
            raise ValueError(f"'reset' must be true or false, got {message['reset']!r}")
        mouse = message.get("mouse", [0, 0])
        if not isinstance(mouse, list) or len(mouse) != 2:
            raise ValueError(f"'mouse' must be two finite numbers [dx, dy] in pixels, got {mouse!r}")
        previous = self.held
        if "keys" in message:
            self.hold(message["keys"])
        try:
            self.move_mouse(*mouse)
        except ValueError:
            self.held = previous
            raise
        return message.get("reset") is True

    def next_action(self) -> dict[str, Any]:
        """The env action for one step: the held keys, and up to ``max_turn_deg`` per axis of the pending turn."""
        for key in self.held & LOOK_KEYS.keys():
            self.pending_deg_2 += np.multiply(LOOK_KEYS[key], self.look_deg_per_step)
        turn_deg_2 = np.clip(self.pending_deg_2, -self.max_turn_deg, self.max_turn_deg)
        self.pending_deg_2 -= turn_deg_2  # carried over, not dropped
        action = noop()
        action.update({key: 1 for key in self.held if key in BINARY_KEYS})
        action[CAMERA_KEY] = turn_deg_2.astype(np.float32)
        return action


# ---------------------------------------------------------------------------------------------
# The env with one driven player
# ---------------------------------------------------------------------------------------------


class PlaySession:
    """An env in which ``agent`` takes its actions from outside and the other players follow ``policy``.

    Thread-safe: every method takes ``lock``. ``driver`` counts the front ends that claimed the session; only the
    newest one steps it.

    Args:
        env: a parallel env (``RealParallelEnv``, ``DreamParallelEnv``, or a wrapper of one).
        agent: the driven player, one of ``env.possible_agents``.
        policy: what drives the others (``wrappers.opponents.OPPONENTS``: "noop", "random", "bot").
        seed: the first episode's reset seed; episode ``n`` uses ``seed + n``.
    """

    def __init__(self, env, agent: str, policy: str, seed: int):
        if agent not in env.possible_agents:
            raise ValueError(f"--agent must be one of {env.possible_agents}, got {agent!r}")
        self.env, self.agent, self.policy, self.seed = env, agent, policy, seed
        self.index = env.possible_agents.index(agent)
        base = env.unwrapped
        ticks = getattr(base, "ticks_per_step", None) or getattr(base, "frames_per_step", None) or 1
        self.max_turn_deg = CAMERA_TICK_LIMIT_DEG * ticks  # what one env step turns; more waits in PlayControls
        self.lock = threading.RLock()
        self.driver = 0
        self.episode = -1
        self.reset()

    def claim(self) -> int:
        """Make the caller the driver; returns its token (``driver`` stays equal to it until someone else claims)."""
        with self.lock:
            self.driver += 1
            return self.driver

    def reset(self) -> None:
        with self.lock:
            self.episode += 1
            self.obs, _ = self.env.reset(seed=self.seed + self.episode)
            self.others = make_opponents(self.env.unwrapped, self.policy, self.seed + self.episode)
            self.steps, self.returns = 0, 0.0

    @property
    def ended(self) -> bool:
        return self.agent not in self.env.agents

    def step(self, action: dict[str, Any]) -> None:
        """One env step: ``action`` (a full MineRL action) for the driven player, the policy for the others."""
        with self.lock:
            if self.ended:
                raise RuntimeError("the episode has ended: reset() for a new one")
            actions = {a: self.others[a].act(self.obs[a]) for a in self.env.agents if a != self.agent}
            actions[self.agent] = action
            self.obs, rewards, *_ = self.env.step(actions)
            self.steps += 1
            self.returns += float(rewards.get(self.agent, 0.0))

    def frame(self) -> np.ndarray:
        """uint8 (H, W, 3) RGB: the driven player's newest frame."""
        with self.lock:
            return self.env.unwrapped.step_frames()[self.index, -1]

    def frame_png(self) -> bytes:
        import cv2

        ok, png = cv2.imencode(".png", self.frame()[..., ::-1])
        if not ok:
            raise RuntimeError("PNG encoding failed")
        return png.tobytes()

    def status(self) -> dict[str, Any]:
        with self.lock:
            return {"agent": self.agent, "episode": self.episode, "step": self.steps, "return": self.returns,
                    "live": list(self.env.agents), "ended": self.ended}


def _paced(fps: float):
    """Yields once per tick at ``fps`` ticks/s; a late tick starts the next one at once (no catching up)."""
    period, next_t = 1.0 / fps, time.monotonic()
    while True:
        yield
        next_t = max(next_t + period, time.monotonic())
        time.sleep(max(0.0, next_t - time.monotonic()))


# ---------------------------------------------------------------------------------------------
# Web page: HTTP for the page, a WebSocket for frames and input
# ---------------------------------------------------------------------------------------------

PLAY_PAGE = """<!doctype html><html><head><meta charset="utf-8"><title>solaris-env play</title><style>
body{background:#222;color:#ddd;font:14px sans-serif;text-align:center;margin:0}
canvas{image-rendering:pixelated;height:80vh;max-width:95vw;cursor:crosshair;background:#000}</style></head><body>
<p>Click the view to capture the mouse (Esc releases it). Mouse: look; left/right button: attack/use. WASD move,
Space jump, Shift sneak, R sprint, Q drop, E inventory, F swap hands, 1-9 hotbar, arrow keys look,
Backspace new episode.</p><canvas id="view" width="64" height="64"></canvas><p id="status">connecting</p><script>
const KEYS={KeyW:"forward",KeyS:"back",KeyA:"left",KeyD:"right",Space:"jump",ShiftLeft:"sneak",ShiftRight:"sneak",
 KeyR:"sprint",KeyQ:"drop",KeyE:"inventory",KeyF:"swapHands",ArrowUp:"lookUp",ArrowDown:"lookDown",
 ArrowLeft:"turnLeft",ArrowRight:"turnRight"};
for(let i=1;i<=9;i++)KEYS["Digit"+i]="hotbar."+i;
const view=document.getElementById("view"),ctx=view.getContext("2d"),statusLine=document.getElementById("status");
const held=new Set(),mouse=[0,0];
window.play={frames:0,status:null};  // read by the end-to-end test
const ws=new WebSocket("ws://"+location.host+"/ws");ws.binaryType="blob";
function send(msg){if(ws.readyState===WebSocket.OPEN)ws.send(JSON.stringify(msg));}
function sendKeys(){send({keys:[...held]});}
const locked=()=>document.pointerLockElement===view;
document.addEventListener("keydown",e=>{if(e.code==="Backspace"){send({reset:true});e.preventDefault();return;}
 const k=KEYS[e.code];if(k){e.preventDefault();if(!held.has(k)){held.add(k);sendKeys();}}});
document.addEventListener("keyup",e=>{const k=KEYS[e.code];if(k&&held.delete(k))sendKeys();});
window.addEventListener("blur",()=>{held.clear();sendKeys();});
view.addEventListener("click",()=>{if(!locked())view.requestPointerLock();});
document.addEventListener("pointerlockchange",()=>{
 if(!locked()){held.delete("attack");held.delete("use");sendKeys();}});
document.addEventListener("mousemove",e=>{if(locked()){mouse[0]+=e.movementX;mouse[1]+=e.movementY;}});
const BUTTONS={0:"attack",2:"use"};
document.addEventListener("mousedown",e=>{if(locked()&&BUTTONS[e.button]){held.add(BUTTONS[e.button]);sendKeys();}});
document.addEventListener("mouseup",e=>{if(BUTTONS[e.button]&&held.delete(BUTTONS[e.button]))sendKeys();});
document.addEventListener("contextmenu",e=>e.preventDefault());
function flushMouse(){if(mouse[0]||mouse[1]){send({mouse:[mouse[0],mouse[1]]});mouse[0]=0;mouse[1]=0;}
 requestAnimationFrame(flushMouse);}
requestAnimationFrame(flushMouse);
ws.onmessage=async e=>{
 if(typeof e.data==="string"){const s=JSON.parse(e.data);window.play.status=s;
  statusLine.textContent=(s.error?"error: "+s.error+" | ":"")+"episode "+s.episode+", step "+s.step+", "+s.agent+
   " return "+s.return.toFixed(3)+", live "+s.live.join(" ")+(s.ended?" (ended: Backspace for a new episode)":"");
  return;}
 const img=await createImageBitmap(e.data);
 if(view.width!==img.width||view.height!==img.height){view.width=img.width;view.height=img.height;}
 ctx.drawImage(img,0,0);window.play.frames++;};
ws.onclose=()=>{statusLine.textContent="disconnected (server stopped, or another page took over)";};
</script></body></html>"""


def _serve_page(connection, request):
    """``process_request`` hook: the page at ``/``, the WebSocket at ``/ws`` (same-origin only), 404 otherwise."""
    from http import HTTPStatus
    from urllib.parse import urlsplit

    if request.path == "/ws":
        origin = request.headers.get("Origin")
        if origin is not None and urlsplit(origin).netloc != request.headers.get("Host"):
            return connection.respond(HTTPStatus.FORBIDDEN, f"cross-origin WebSocket from {origin} refused\n")
        return None  # go on with the WebSocket handshake
    if request.path != "/":
        return connection.respond(HTTPStatus.NOT_FOUND, "not found\n")
    response = connection.respond(HTTPStatus.OK, PLAY_PAGE)
    del response.headers["Content-Type"]
    response.headers["Content-Type"] = "text/html; charset=utf-8"
    return response


def _read_input(ws, controls: PlayControls) -> tuple[bool, str | None]:
    """Apply every message waiting on ``ws``; returns (a reset was asked for, the last error or None)."""
    reset, error = False, None
    while True:
        try:
            text = ws.recv(timeout=0)
        except TimeoutError:
            return reset, error
        try:
            if not isinstance(text, str):
                raise ValueError("messages must be JSON text, got a binary message")
            reset |= controls.apply(json.loads(text))
        except ValueError as err:  # json.JSONDecodeError is a ValueError; say why, keep driving
            error = str(err)


def _drive(session: PlaySession, fps: float, ws) -> None:
    """One WebSocket connection: read input, step, send the frame and the status, ``fps`` times a second."""
    from websockets.exceptions import ConnectionClosed

    token, controls = session.claim(), PlayControls(max_turn_deg=session.max_turn_deg)
    try:
        for _ in _paced(fps):
            if session.driver != token:  # a newer page took over
                ws.close(1000, "another page took over")
                return
            reset, error = _read_input(ws, controls)
            with session.lock:
                if reset:
                    session.reset()
                elif not session.ended:
                    session.step(controls.next_action())
                png, status = session.frame_png(), session.status()
            status["turn_pending_deg"] = controls.pending_deg_2.round(3).tolist()
            if error is not None:
                status["error"] = error
            ws.send(png)
            ws.send(json.dumps(status))
    except ConnectionClosed:
        pass


def make_play_server(session: PlaySession, host: str = "127.0.0.1", port: int = 8765, fps: float = 20.0):
    """A ``websockets`` sync server: GET / is the page, /ws drives ``session`` at ``fps`` steps/s.

    Run it with ``serve_forever()`` and stop it with ``shutdown()`` (closes the connections, waits for their
    threads). ``port=0`` picks a free port: read it from ``server.socket.getsockname()``.
    """
    from websockets.sync.server import serve

    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    # compression off: PNG frames do not deflate further and it would cost CPU every step
    return serve(lambda ws: _drive(session, fps, ws), host, port, process_request=_serve_page, compression=None)


def serve_play(session: PlaySession, host: str, port: int, fps: float) -> None:
    """Serve the page until Ctrl-C, then close the connections and the env."""
    server = make_play_server(session, host, port, fps)
    bound_host, bound_port = server.socket.getsockname()[:2]
    print(f"playing as {session.agent} at {fps:g} steps/s: open http://{bound_host}:{bound_port}/ (Ctrl-C to stop)")
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        print("stopping")
    finally:
        server.shutdown()
        session.env.close()


# ---------------------------------------------------------------------------------------------
# OpenCV window
# ---------------------------------------------------------------------------------------------

# OpenCV reports key presses only (no releases; the OS repeats a held key after a delay of ~0.5 s), so a key
# counts as held for HOLD_S after its last press.
HOLD_S = 0.6
WINDOW_KEYS = {"w": "forward", "s": "back", "a": "left", "d": "right", " ": "jump", "c": "sneak", "r": "sprint",
               "j": "attack", "k": "use", "q": "drop", "e": "inventory", "f": "swapHands",
               **{str(i): f"hotbar.{i}" for i in range(1, 10)}}
# arrow key codes of cv2.waitKeyEx: GTK (X11 keysyms) and Qt (the PyPI opencv-python build)
WINDOW_ARROWS = {65362: "lookUp", 65364: "lookDown", 65361: "turnLeft", 65363: "turnRight",
                 0x1000013: "lookUp", 0x1000015: "lookDown", 0x1000012: "turnLeft", 0x1000014: "turnRight"}
ESC_CODE, BACKSPACE_CODE = 27, 8


def window_key(code: int) -> str | None:
    """A ``cv2.waitKeyEx`` code -> the MineRL or look key it holds, or None."""
    if code in WINDOW_ARROWS:
        return WINDOW_ARROWS[code]
    return WINDOW_KEYS.get(chr(code).lower()) if 0 <= code < 256 else None


class HeldKeys:
    """Key presses -> the keys held at a time: each press holds its key for ``hold_s`` seconds."""

    def __init__(self, hold_s: float = HOLD_S):
        self.hold_s = hold_s
        self.last_press: dict[str, float] = {}

    def press(self, key: str, now: float) -> None:
        self.last_press[key] = now

    def held(self, now: float) -> set[str]:
        return {k for k, t in self.last_press.items() if now - t < self.hold_s}


def window_problem() -> str | None:
    """Why an OpenCV window cannot open here (no display, or a build without GUI), or None when it can."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY is not set)"
    import cv2

    gui = [line.split(":", 1)[1].strip() for line in cv2.getBuildInformation().splitlines()
           if line.strip().startswith("GUI:")]
    if gui and gui[0].upper() == "NONE":
        return (f"this OpenCV {cv2.__version__} has no GUI support (opencv-python-headless); "
                "`pip install opencv-python` gives one")
    return None


def run_window(session: PlaySession, fps: float, scale: int = 8) -> None:
    """Drive ``session`` from an OpenCV window until Esc, closing the window, or Ctrl-C.

    Keys (``WINDOW_KEYS``; OpenCV sees no Shift or mouse buttons as keys): WASD move, Space jump, C sneak,
    R sprint, J attack, K use, Q drop, E inventory, F swap hands, 1-9 hotbar, arrows look, Backspace new episode,
    Esc quit. Drag with the left mouse button to look (window pixels at ``DEG_PER_PIXEL``).
    """
    import cv2

    name = f"solaris-env play: {session.agent}"
    controls, keys, drag = PlayControls(max_turn_deg=session.max_turn_deg), HeldKeys(), {"at": None}

    def on_mouse(event, x, y, flags, _):
        if event == cv2.EVENT_LBUTTONDOWN:
            drag["at"] = (x, y)
        elif event == cv2.EVENT_LBUTTONUP:
            drag["at"] = None
        elif event == cv2.EVENT_MOUSEMOVE and drag["at"] is not None:
            controls.move_mouse(x - drag["at"][0], y - drag["at"][1])
            drag["at"] = (x, y)

    cv2.namedWindow(name, cv2.WINDOW_AUTOSIZE)
    cv2.setMouseCallback(name, on_mouse)
    print(f"playing as {session.agent} at {fps:g} steps/s in an OpenCV window (Esc to stop)")
    try:
        for _ in _paced(fps):
            frame = cv2.resize(session.frame(), None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
            cv2.imshow(name, np.ascontiguousarray(frame[..., ::-1]))
            code = cv2.waitKeyEx(1)
            if code == ESC_CODE or cv2.getWindowProperty(name, cv2.WND_PROP_VISIBLE) < 1:
                return
            if code == BACKSPACE_CODE:
                session.reset()
            elif (key := window_key(code)) is not None:
                keys.press(key, time.monotonic())
            controls.hold(keys.held(time.monotonic()))
            if not session.ended:
                session.step(controls.next_action())
    except KeyboardInterrupt:
        pass
    finally:
        cv2.destroyAllWindows()
        session.env.close()
