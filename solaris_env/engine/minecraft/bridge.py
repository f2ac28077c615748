"""The Python end of ``env_bridge.js``: real-Minecraft players stepped in real time over 127.0.0.1.

:class:`MinecraftBridge` starts Xvfb, a flying-squid server and ``env_bridge.js`` (the players as
mineflayer bots, their views rendered by prismarine-viewer) under one :class:`Supervisor`, connects to
the bridge's TCP port and speaks its line-JSON protocol (see the head of ``env_bridge.js``): one JSON
request line, one JSON reply line followed by ``frameBytes`` raw RGBA bytes. ``close()`` stops every
process (no orphans, also on errors and Ctrl-C).
"""

from __future__ import annotations

import json
import os
import socket
from dataclasses import dataclass
from typing import Any, Self

import numpy as np

from solaris_env.engine.minecraft import MINECRAFT_VERSION, NODE_DIR
from solaris_env.engine.minecraft.install import setup_problem
from solaris_env.engine.minecraft.records import CONTROL_KEYS
from solaris_env.engine.minecraft.supervisor import ProcessError, Supervisor, start_xvfb

SERVER_READY_S = 60.0
BRIDGE_READY_S = 90.0  # both bots log in one after the other
RESET_TIMEOUT_S = 60.0  # the first reset includes ~3-13 s of chunk-meshing warm-up
STEP_TIMEOUT_S = 20.0  # plus 50 ms per tick
WARMUP_MS = 3000


@dataclass
class BridgeReply:
    """One reset or step: every bot's frames and per-frame poses, plus the step's tick accounting.

    ``rgba_PTHW4``: uint8 (P, T, rh, rw, 4), bottom row first (gl.readPixels); ``poses_PT``: P lists of T
    pose dicts (``env_bridge.js``); ``header``: the reply's JSON header (tick counters, lateness)."""

    rgba_PTHW4: np.ndarray
    poses_PT: list[list[dict]]
    header: dict


def tick_message(action: dict, camera_rad: tuple[float, float]) -> dict:
    """One validated env action (one tick) -> the bridge's action object.

    ``camera_rad``: (dyaw, dpitch) in Mineflayer radians (``spaces.minerl_camera_to_mineflayer``)."""
    pressed = [k for k in range(1, 10) if action[f"hotbar.{k}"]]
    return {"controls": {k: bool(action[k]) for k in CONTROL_KEYS}, "dyaw": float(camera_rad[0]),
            "dpitch": float(camera_rad[1]), "attack": int(action["attack"]), "use": int(action["use"]),
            "hotbar": pressed[0] if pressed else None}  # several keys in one tick: the lowest wins (as the engine)


class MinecraftBridge:
    """Xvfb + server + the bridge process for ``names`` players; a context manager.

    Args:
        names: the players' (bots') names, in agent order.
        render_size: (height, width) of the rendered views (the 16:9 game window).
        view_distance: server and viewer view distance in chunks.
        fov_deg: vertical field of view.
        seed: the server's world seed (its superflat world).
    """

    def __init__(self, names: list[str], render_size: tuple[int, int], view_distance: int = 4,
                 fov_deg: float = 70.0, seed: int = 42):
        problem = setup_problem()
        if problem:
            raise RuntimeError(f"the Minecraft backend is not set up: {problem} "
                               "(run `solaris-engine setup-minecraft`)")
        self.names = list(names)
        self.render_height, self.render_width = render_size
        self.sup = Supervisor()
        self.sock: socket.socket | None = None
        try:
            self.xvfb, display = start_xvfb(self.sup)
            server_cfg = {"port": 0, "version": MINECRAFT_VERSION, "viewDistance": view_distance, "seed": seed}
            self.server = self.sup.start("server", ["node", "server.js", json.dumps(server_cfg)], cwd=str(NODE_DIR))
            line = self.sup.read_line(self.server, SERVER_READY_S, lambda s: s.startswith("{"))
            port = int(json.loads(line)["port"])
            bridge_cfg = {"host": "127.0.0.1", "port": port, "version": MINECRAFT_VERSION, "names": self.names,
                          "renderWidth": self.render_width, "renderHeight": self.render_height,
                          "viewDistance": view_distance, "fovDeg": fov_deg, "warmupMs": WARMUP_MS}
            self.bridge = self.sup.start("env_bridge", ["node", "env_bridge.js", json.dumps(bridge_cfg)],
                                         cwd=str(NODE_DIR), env=dict(os.environ, DISPLAY=display))
            line = self.sup.read_line(self.bridge, BRIDGE_READY_S, lambda s: s.startswith("{"))
            self.sock = socket.create_connection(("127.0.0.1", int(json.loads(line)["port"])), timeout=10.0)
            self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._reader = self.sock.makefile("rb")
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- requests ---------------------------------------------------------------------------------
    def reset(self, spots: list[dict]) -> BridgeReply:
        """Teleport each bot to its block ``{x, y, z}`` facing ``{yaw, pitch}`` (radians); one frame each."""
        return self._request({"op": "reset", "spots": spots}, RESET_TIMEOUT_S)

    def step(self, ticks: list[list[dict]]) -> BridgeReply:
        """Play ``len(ticks)`` ticks; ``ticks[j][i]`` is bot i's action object (``tick_message``) of tick j."""
        return self._request({"op": "step", "ticks": ticks}, STEP_TIMEOUT_S + 0.05 * len(ticks))

    def _request(self, msg: dict, timeout_s: float) -> BridgeReply:
        if self.sock is None:
            raise RuntimeError("the Minecraft bridge is closed")
        self.sock.settimeout(timeout_s)
        try:
            self.sock.sendall((json.dumps(msg) + "\n").encode())
            line = self._reader.readline()
            if not line:
                raise ProcessError(f"env_bridge.js closed the connection; {self._tails()}")
            header = json.loads(line)
            if header.get("op") == "error":
                raise RuntimeError(f"env_bridge.js refused {msg['op']}: {header['message']}")
            raw = self._reader.read(int(header.get("frameBytes", 0)))
        except TimeoutError:
            raise ProcessError(f"env_bridge.js did not answer {msg['op']} within {timeout_s:.0f} s; "
                               f"{self._tails()}") from None
        poses_PT = [b["poses"] for b in header["bots"]]
        T = len(poses_PT[0])
        frame_bytes = self.render_height * self.render_width * 4
        if len(raw) != len(self.names) * T * frame_bytes:
            raise ProcessError(f"env_bridge.js sent {len(raw)} frame bytes, expected {len(self.names)} x {T} frames "
                               f"of {frame_bytes}; {self._tails()}")
        rgba = np.frombuffer(raw, np.uint8).reshape(len(self.names), T, self.render_height, self.render_width, 4)
        return BridgeReply(rgba, poses_PT, header)

    def _tails(self) -> str:
        return "; ".join(f"{c.name} {'running' if c.alive() else f'exited {c.popen.returncode}'}, stderr:\n{c.tail()}"
                         for c in self.sup.children)

    # -- accounting and shutdown ------------------------------------------------------------------
    def cpu_seconds(self) -> dict[str, float]:
        """User + system CPU seconds used so far by each process (Xvfb, server, env_bridge), threads included."""
        return {c.name: _proc_cpu_s(c.pid) for c in self.sup.children if c.alive()}

    def pids(self) -> list[int]:
        return [c.pid for c in self.sup.children]

    def close(self) -> None:
        """Ask the bridge to quit, then stop every process (idempotent)."""
        if self.sock is not None:
            try:
                self.sock.settimeout(2.0)
                self.sock.sendall(b'{"op":"close"}\n')
                self._reader.readline()
            except (OSError, ValueError):
                pass
            try:
                self._reader.close()
                self.sock.close()
            except OSError:
                pass
            self.sock = None
        self.sup.close()


def _proc_cpu_s(pid: int) -> float:
    """utime + stime of a process (all its threads) from /proc, in seconds."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def mineflayer_pose(p: dict) -> dict[str, Any]:
    """A bridge pose as numpy position + yaw in [0, 2pi) (the voxel engine's Player convention)."""
    return {"pos": np.array([p["x"], p["y"], p["z"]]), "yaw": float(p["yaw"]) % (2 * np.pi), "pitch": float(p["pitch"])}
