"""``solaris-env``: look at and drive the envs from the command line.

    solaris-env info                                   # envs, models, start scenes, tasks
    solaris-env rollout --kind real --steps 200 --policy bot --out rollout.mp4
    solaris-env rollout --kind dream --preset tiny --steps 50 --out dream.mp4 --rrd dream.rrd
    solaris-env play --kind real                       # a local web page: drive Alpha with the keyboard

Heavy frameworks (jax, torch) are imported only inside the commands, so ``--help`` is instant.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

# ---------------------------------------------------------------------------------------------
# Building envs from arguments
# ---------------------------------------------------------------------------------------------


def _add_env_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--kind", choices=("dream", "real"), default="real", help="world model or engine")
    p.add_argument("--checkpoint", type=Path, help="dream: a world-model checkpoint (default: the shipped one)")
    p.add_argument("--preset", choices=("tiny", "test", "solaris"), help="dream: a RANDOM-INIT preset instead")
    p.add_argument("--players", type=int, default=2, help="number of players")
    p.add_argument("--resolution", type=int, default=64, help="real: frame size (square)")
    p.add_argument("--world", choices=("flat", "normal", "mixed"), default="mixed", help="real: world kind")
    p.add_argument("--task", default=None, help="task name (solaris_env.tasks.TASKS); default: zero reward")
    p.add_argument("--seed", type=int, default=0, help="reset seed")


def _make_env(args, max_steps: int, render_mode: str | None = None):
    if args.kind == "dream":
        from solaris_env.dream_env import DreamParallelEnv

        return DreamParallelEnv(checkpoint=args.checkpoint, preset=args.preset, num_players=args.players,
                                max_steps=max_steps, task=args.task, render_mode=render_mode)
    from solaris_env.real_env import RealParallelEnv

    return RealParallelEnv(num_players=args.players, world=args.world, resolution=args.resolution,
                           max_steps=max_steps, task=args.task, render_mode=render_mode)


def _opponents(env, policy: str, seed: int) -> dict:
    import numpy as np

    from solaris_env.wrappers.opponents import make_opponent

    out = {a: make_opponent(policy) for a in env.possible_agents}
    for a, s in zip(env.possible_agents, np.random.default_rng(seed).integers(2**31 - 1, size=len(out))):
        out[a].reset(env, a, int(s))
    return out


# ---------------------------------------------------------------------------------------------
# Commands
# ---------------------------------------------------------------------------------------------


def cmd_info(args) -> int:
    import solaris_env
    from solaris_env.dream_env import DEFAULT_CHECKPOINT
    from solaris_env.start_scenes import SCENES_PATH, _bundle
    from solaris_env.tasks import TASKS
    from solaris_env.world_model.config import PRESETS
    from solaris_env.wrappers.opponents import OPPONENTS
    from solaris_env.wrappers.single_agent import ENV_IDS

    print(f"solaris_env {solaris_env.__version__}")
    print("parallel envs : solaris_env.parallel_env('dream' | 'real'), DreamVectorEnv (N worlds, one model call)")
    print(f"gymnasium ids : {', '.join(ENV_IDS)}")
    shipped = "present" if DEFAULT_CHECKPOINT.exists() else "NOT shipped yet (use --preset for random-init weights)"
    print(f"default model : {DEFAULT_CHECKPOINT} ({shipped})")
    print(f"presets       : {', '.join(sorted(PRESETS))} (random-init)")
    if SCENES_PATH.exists():
        b = _bundle(str(SCENES_PATH))
        print(f"start scenes  : {len(b['seeds'])} per player count {b['player_counts'].tolist()} at "
              f"{b['resolutions'].tolist()} px ({SCENES_PATH.stat().st_size / 1e6:.2f} MB)")
    else:
        print(f"start scenes  : missing ({SCENES_PATH}); build with python -m solaris_env.start_scenes")
    print(f"tasks         : {', '.join(TASKS)}")
    print(f"policies      : {', '.join(OPPONENTS)}")
    return 0


def cmd_rollout(args) -> int:
    """Run one episode of ``--steps`` steps with every player on ``--policy``; write all views to an mp4."""
    import numpy as np

    from solaris_env.env_common import side_by_side
    from solaris_env.wrappers.video import Mp4Writer

    env = _make_env(args, max_steps=args.steps)
    if args.rrd is not None:
        from solaris_env.wrappers.rerun_log import RerunRecorder

        env = RerunRecorder(env, path=args.rrd)
    writer = Mp4Writer(args.out)
    start = time.perf_counter()
    obs, _ = env.reset(seed=args.seed)
    policies = _opponents(env.unwrapped, args.policy, args.seed)
    returns = dict.fromkeys(env.possible_agents, 0.0)

    def write():
        frames_PkHW3 = env.unwrapped.step_frames()
        for t in range(frames_PkHW3.shape[1]):
            writer.write(side_by_side(frames_PkHW3[:, t]))

    write()
    steps = 0
    while env.agents:
        obs, rewards, *_ = env.step({a: policies[a].act(obs[a]) for a in env.agents})
        for a, r in rewards.items():
            returns[a] += r
        steps += 1
        write()
    seconds = time.perf_counter() - start
    env.close()
    path = writer.close()
    print(f"{args.kind}: {steps} steps in {seconds:.1f} s ({steps / seconds:.1f} steps/s incl. compile), "
          f"{writer.frames} frames -> {path}")
    print("returns: " + ", ".join(f"{a} {r:.3f}" for a, r in returns.items()))
    if args.rrd is not None:
        print(f"rerun: {args.rrd} (open with `rerun {args.rrd}`)")
    return 0 if np.isfinite(list(returns.values())).all() else 1


def cmd_play(args) -> int:
    """Serve a local page that drives one player with the keyboard; the others follow ``--policy``."""
    session = PlaySession(_make_env(args, max_steps=args.max_steps), args.agent, args.policy, args.seed)
    server = make_play_server(session, args.host, args.port)
    host, port = server.server_address[:2]
    print(f"playing {args.kind} as {args.agent}: open http://{host}:{port}/ (Ctrl-C to stop)")
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0


# ---------------------------------------------------------------------------------------------
# play: a local web page (works without a display or a GUI build of OpenCV)
# ---------------------------------------------------------------------------------------------

PLAY_PAGE = """<!doctype html><html><head><title>solaris-env play</title><style>
body{background:#222;color:#ddd;font:14px sans-serif;text-align:center}
img{image-rendering:pixelated;width:90vw;max-width:1400px;cursor:crosshair}</style></head><body>
<p>Click the view to capture the mouse (camera). WASD move, Space jump, Shift sneak, R sprint, left/right click
attack/use, 1-9 hotbar, Q drop, E inventory, F swap hands, arrow keys turn, Backspace new episode.</p>
<img id="view" src="/frame.png"><p id="status"></p><script>
const KEYS={KeyW:"forward",KeyS:"back",KeyA:"left",KeyD:"right",Space:"jump",ShiftLeft:"sneak",KeyR:"sprint",
 KeyQ:"drop",KeyE:"inventory",KeyF:"swapHands",Escape:"ESC"};
for(let i=1;i<=9;i++)KEYS["Digit"+i]="hotbar."+i;
const held={},cam=[0,0],view=document.getElementById("view"),status=document.getElementById("status");
let reset=false;
document.addEventListener("keydown",e=>{if(e.code==="Backspace")reset=true;
 if(e.code==="ArrowLeft")cam[1]-=5;if(e.code==="ArrowRight")cam[1]+=5;if(e.code==="ArrowUp")cam[0]-=5;
 if(e.code==="ArrowDown")cam[0]+=5;if(KEYS[e.code]){held[KEYS[e.code]]=1;e.preventDefault();}});
document.addEventListener("keyup",e=>{if(KEYS[e.code])held[KEYS[e.code]]=0;});
view.addEventListener("click",()=>view.requestPointerLock());
document.addEventListener("mousemove",e=>{if(document.pointerLockElement===view){cam[1]+=e.movementX*0.15;
 cam[0]+=e.movementY*0.15;}});
document.addEventListener("mousedown",e=>{if(e.button===0)held.attack=1;if(e.button===2)held.use=1;});
document.addEventListener("mouseup",e=>{if(e.button===0)held.attack=0;if(e.button===2)held.use=0;});
document.addEventListener("contextmenu",e=>e.preventDefault());
async function loop(){
 const action=Object.assign({},held,{camera:[Math.max(-180,Math.min(180,cam[0])),Math.max(-180,Math.min(180,cam[1]))]});
 cam[0]=0;cam[1]=0;
 const r=await fetch(reset?"/reset":"/step",{method:"POST",body:JSON.stringify(action)});reset=false;
 if(r.ok){view.src=URL.createObjectURL(await r.blob());status.textContent=r.headers.get("X-Status");}
 else status.textContent=await r.text();
 setTimeout(loop,50);}
loop();
</script></body></html>"""


class PlaySession:
    """One env driven by a keyboard player (``agent``) and ``policy`` for the others; thread-safe."""

    def __init__(self, env, agent: str, policy: str, seed: int):
        import threading

        if agent not in env.possible_agents:
            raise ValueError(f"--agent must be one of {env.possible_agents}, got {agent!r}")
        self.env, self.agent, self.policy, self.seed = env, agent, policy, seed
        self.lock = threading.Lock()
        self.episode, self.returns = -1, 0.0
        self.reset()

    def reset(self) -> bytes:
        with self.lock:
            self.episode += 1
            self.obs, _ = self.env.reset(seed=self.seed + self.episode)
            self.others = _opponents(self.env.unwrapped, self.policy, self.seed + self.episode)
            self.returns = 0.0
            return self.frame_png()

    def step(self, action: dict) -> bytes:
        """One env step with the player's action (a MineRL dict; missing keys count as not pressed)."""
        from solaris_env.spaces import ACTION_KEYS, noop, validate_action

        unknown = sorted(set(action) - set(ACTION_KEYS))
        if unknown:
            raise ValueError(f"unknown action key {unknown[0]!r}; expected keys {list(ACTION_KEYS)}")
        full = validate_action({**noop(), **action}, agent=self.agent)
        with self.lock:
            if self.agent not in self.env.agents:
                raise ValueError("the episode has ended: press Backspace (POST /reset) for a new one")
            actions = {a: self.others[a].act(self.obs[a]) for a in self.env.agents if a != self.agent}
            actions[self.agent] = full
            self.obs, rewards, *_ = self.env.step(actions)
            self.returns += rewards.get(self.agent, 0.0)
            return self.frame_png()

    def frame_png(self) -> bytes:
        import cv2

        from solaris_env.env_common import side_by_side

        sheet = side_by_side(self.env.unwrapped.step_frames()[:, -1])
        ok, png = cv2.imencode(".png", sheet[..., ::-1])
        if not ok:
            raise RuntimeError("PNG encoding failed")
        return png.tobytes()

    def status(self) -> str:
        return f"episode {self.episode}, {self.agent} return {self.returns:.3f}, live {self.env.agents}"


def make_play_server(session: PlaySession, host: str = "127.0.0.1", port: int = 8765):
    """A ``ThreadingHTTPServer``: GET / (the page), GET /frame.png, POST /step and /reset (JSON action -> PNG)."""
    import json
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args):  # quiet
            pass

        def _send(self, code: int, body: bytes, kind: str) -> None:
            self.send_response(code)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("X-Status", session.status())
            self.end_headers()
            self.wfile.write(body)

        def do_GET(self):
            if self.path == "/":
                self._send(200, PLAY_PAGE.encode(), "text/html; charset=utf-8")
            elif self.path.startswith("/frame.png"):
                with session.lock:
                    png = session.frame_png()
                self._send(200, png, "image/png")
            else:
                self._send(404, b"not found", "text/plain")

        def do_POST(self):
            if self.path not in ("/step", "/reset"):
                self._send(404, b"not found", "text/plain")
                return
            try:
                if self.path == "/reset":
                    png = session.reset()
                else:
                    body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                    action = json.loads(body or b"{}")
                    if not isinstance(action, dict):
                        raise ValueError(f"the body must be a JSON object (an action), got {type(action).__name__}")
                    png = session.step(action)
            except (ValueError, TypeError) as err:  # bad input: say why, keep serving
                self._send(400, str(err).encode(), "text/plain; charset=utf-8")
                return
            self._send(200, png, "image/png")

    return ThreadingHTTPServer((host, port), Handler)


# ---------------------------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="solaris-env", description=__doc__.split("\n\n")[0].strip("` "),
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("info", help="what is installed: envs, models, start scenes, tasks").set_defaults(run=cmd_info)
    p = sub.add_parser("rollout", help="run an episode with a scripted/random policy and write an mp4")
    _add_env_args(p)
    p.add_argument("--steps", type=int, default=100, help="episode length in env steps")
    p.add_argument("--policy", choices=("random", "noop", "bot"), default="random",
                   help="what drives every player ('bot': real only)")
    p.add_argument("--out", type=Path, default=Path("rollout.mp4"), help="the mp4 (all players side by side)")
    p.add_argument("--rrd", type=Path, default=None, help="also write a Rerun recording here")
    p.set_defaults(run=cmd_rollout)
    p = sub.add_parser("play", help="drive one player with the keyboard in a local web page")
    _add_env_args(p)
    p.add_argument("--agent", default="Alpha", help="the player you drive")
    p.add_argument("--policy", choices=("random", "noop", "bot"), default="noop", help="what drives the others")
    p.add_argument("--max-steps", type=int, default=100_000, help="episode length")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8765)
    p.set_defaults(run=cmd_play)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "steps", 1) < 1:
        raise SystemExit("solaris-env: --steps must be >= 1")
    return args.run(args)


if __name__ == "__main__":
    sys.exit(main())
