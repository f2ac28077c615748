"""Record episodes on real Minecraft and write them in the voxel engine's Duet/eval layout.

One :class:`MinecraftSession` (Xvfb + a flying-squid server on 127.0.0.1) serves a whole collect, the
server restarted before each episode after the first (a fresh flat world, ~1 s); each episode runs
``record.js`` (both bots and both views in one Node process, choreographies from ``episodes.js``) into a scratch dir,
then the raw rows become Mineflayer records (:mod:`.records`), the RGBA frames become the requested
``H x W`` RGB video (rendered at the 16:9 display aspect and resampled, like the voxel engine's
frames), and :func:`solaris_env.engine.recorder.write_episode` writes everything atomically.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Self

import numpy as np

from solaris_env.engine.minecraft import MINECRAFT_VERSION, NODE_DIR
from solaris_env.engine.minecraft.install import setup_problem
from solaris_env.engine.minecraft.records import (
    MAX_BURST_FRACTION,
    build_records,
    catchup_ticks,
    edit_events,
    ground_truth,
)
from solaris_env.engine.minecraft.supervisor import ProcessError, Supervisor, start_xvfb

# Implemented in episodes.js (the voxel engine's buildHouse, collector, pve and towerBridge are not).
TRAINING_TYPES = ("buildStructure", "buildTower", "chase", "mine", "orbit", "placeAndMine", "pvp",
                  "straightLineWalk", "walkLook", "walkLookAway")
EVAL_TYPES = ("bothLookAwayEval", "oneLooksAwayEval", "rotationEval", "structureEval", "translationEval",
              "turnToLookEval", "turnToLookOppositeEval")
DISPLAY_ASPECT = 16 / 9
FOV_DEG = 70.0
SERVER_READY_S = 60.0
DEFAULT_SPAWN = (10.0, 15.0)  # the reference's MIN/MAX_BOTS_DISTANCE (docs/engine.md §5.1)
# Spawn distances where the spec's differ from the default (docs/engine.md §5.2, §6.2); placeAndMine and turnToLook*
# place the bots 4 blocks apart themselves (episodes.js planEpisode).
SPAWN = {"buildStructure": (8.0, 15.0), "buildTower": (8.0, 15.0), "pvp": (8.0, 15.0), "placeAndMine": (4.0, 4.0),
         "rotationEval": (10.0, 12.0), "translationEval": (10.0, 12.0), "oneLooksAwayEval": (10.0, 12.0),
         "bothLookAwayEval": (10.0, 12.0), "structureEval": (6.0, 6.0), "turnToLookEval": (4.0, 4.0),
         "turnToLookOppositeEval": (4.0, 4.0)}
EPISODE_TIMEOUT_S = 400.0
MAX_TICKS = 180 * 20


def render_size(height: int, width: int) -> tuple[int, int]:
    """(render height, render width): the requested height at the 16:9 display aspect (even width)."""
    return height, max(2, 2 * round(height * DISPLAY_ASPECT / 2))


def frames_from_rgba(raw: bytes | np.ndarray, rh: int, rw: int, height: int, width: int) -> np.ndarray:
    """(T, height, width, 3) uint8 RGB from gl.readPixels RGBA frames (bottom row first), resampled."""
    import cv2

    buf = np.frombuffer(raw, np.uint8) if isinstance(raw, (bytes, bytearray)) else np.asarray(raw, np.uint8)
    if buf.size % (rh * rw * 4):
        raise ValueError(f"frame file of {buf.size} bytes is not a whole number of {rw}x{rh} RGBA frames")
    rgba_THW4 = buf.reshape(-1, rh, rw, 4)
    out = np.empty((rgba_THW4.shape[0], height, width, 3), np.uint8)
    for t, f in enumerate(rgba_THW4):
        rgb = np.ascontiguousarray(f[::-1, :, :3])
        out[t] = rgb if (rh, rw) == (height, width) else cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA)
    return out


@dataclass
class _Trace:
    """The part of the voxel engine's Trace that the recorder reads."""

    player_names: list[str]
    records: list[list[dict]]

    @property
    def num_ticks(self) -> int:
        return len(self.records[0])


@dataclass
class McEpisodeOutput:
    """Duck-typed :class:`solaris_env.engine.bots.runner.EpisodeOutput` for ``recorder.write_episode``."""

    trace: _Trace
    episode_type: str
    infos: list[dict]
    start_ticks: list[int | None]
    aborted: bool = False
    abort_reason: str = ""
    extra: dict = field(default_factory=dict)


class MinecraftSession:
    """Xvfb + server for a collect; :meth:`record` runs one episode. Use as a context manager."""

    def __init__(self, seed: int = 0, view_distance: int = 4):
        problem = setup_problem()
        if problem:
            raise RuntimeError(f"the Minecraft backend is not set up: {problem}")
        self.sup = Supervisor()
        self.seed, self.view_distance = seed, view_distance
        self.server = None
        self.world_used = False  # an episode ran on this server's world (blocks may be placed or dug)
        try:
            self.xvfb, self.display = start_xvfb(self.sup)
            self._start_server()
        except BaseException:
            self.sup.close()
            raise

    def _start_server(self) -> None:
        cfg = {"port": 0, "version": MINECRAFT_VERSION, "viewDistance": self.view_distance, "seed": self.seed}
        self.server = self.sup.start("server", ["node", "server.js", json.dumps(cfg)], cwd=str(NODE_DIR))
        line = self.sup.read_line(self.server, SERVER_READY_S, lambda s: s.startswith("{"))
        self.port = int(json.loads(line)["port"])
        self.world_used = False

    def fresh_world(self) -> None:
        """Restart the server (~1 s) so the next episode starts on an untouched flat world: far teleports
        strand bots in unloaded chunks, so every episode plays near the origin."""
        if self.server is not None:
            self.sup.stop(self.server)
            self.sup.children.remove(self.server)
        self._start_server()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.sup.close()

    def run_recorder(self, scratch: Path, episode_type: str, episode: int, seed: int, height: int,
                     instance: int = 0, timeout_s: float = EPISODE_TIMEOUT_S, max_ticks: int = MAX_TICKS) -> dict:
        """Run record.js into ``scratch``; returns episode.json's content."""
        if self.world_used or not self.server.alive():
            self.fresh_world()
        self.world_used = True
        rh, rw = render_size(height, height)
        lo, hi = SPAWN.get(episode_type, DEFAULT_SPAWN)
        cfg = {"host": "127.0.0.1", "port": self.port, "version": MINECRAFT_VERSION, "names": ["Alpha", "Bravo"],
               "episodeType": episode_type, "episode": episode, "instance": instance, "seed": seed,
               "renderWidth": rw, "renderHeight": rh,
               "viewDistance": self.view_distance, "spawnMin": lo, "spawnMax": hi, "maxTicks": max_ticks,
               "fovDeg": FOV_DEG, "outDir": str(scratch)}
        env = dict(os.environ, DISPLAY=self.display)
        child = self.sup.start(f"record[{episode_type} {episode}]", ["node", "record.js", json.dumps(cfg)],
                               cwd=str(NODE_DIR), env=env)
        try:
            rc = self.sup.wait(child, timeout_s)
        finally:
            self.sup.stop(child)
            self.sup.children.remove(child)
        if rc != 0:
            raise ProcessError(f"record.js exited with status {rc}; stderr:\n{child.tail()}")
        return json.loads((scratch / "episode.json").read_text())

    def record(self, out: str | Path, key, episode_type: str, seed: int, height: int, width: int,
               split: str = "train", world_kind: str = "flat", max_ticks: int = MAX_TICKS) -> dict:
        """Record one episode and write it with the voxel engine's recorder; returns a summary."""
        from solaris_env.engine.recorder import write_episode

        staging = Path(out) / ".staging"  # recorder.clean_staging removes leftovers of a crash
        staging.mkdir(parents=True, exist_ok=True)
        scratch = Path(tempfile.mkdtemp(prefix="mc-episode-", dir=staging))
        try:
            info = self.run_recorder(scratch, episode_type, key.episode, seed, height, key.instance,
                                     max_ticks=max_ticks)
            names = list(info["names"])
            rows = {n: [json.loads(line) for line in (scratch / f"{n}.jsonl").read_text().splitlines()] for n in names}
            records = {n: build_records(rows[n], key.episode) for n in names}
            rh, rw = info["renderHeight"], info["renderWidth"]
            frames = [frames_from_rgba(np.fromfile(scratch / f"{n}.rgba", np.uint8), rh, rw, height, width)
                      for n in names]
            for n, f in zip(names, frames):
                if len(f) != len(records[n]):
                    raise RuntimeError(f"{n}: {len(f)} frames for {len(records[n])} action records")
            T = min(len(r) for r in records.values())  # record.js stops both bots at the same count
            bursts = {n: catchup_ticks(rows[n]) for n in names}
            aborted, reason = bool(info["aborted"]), info["abortReason"]
            worst = max(bursts[n] / max(1, len(rows[n])) for n in names)
            if worst > MAX_BURST_FRACTION and not aborted:
                aborted, reason = True, f"physics catch-up ticks: {bursts} (> {MAX_BURST_FRACTION:.0%} of ticks)"
            now = dt.datetime.now(dt.UTC).isoformat()
            infos = [{"timestamp": now, "bot_name": n, "world_type": world_kind, "episode_number": key.episode,
                      "episode_type": episode_type, "instance_id": key.instance, "encountered_error": aborted,
                      "peer_encountered_error": False, "bot_died": False, "episode_recording_started": True,
                      "eval_metadata": info["bots"][n]["evalMetadata"] if info["isEval"] else {}}
                     for n in names]
            output = McEpisodeOutput(_Trace(names, [records[n][:T] for n in names]), episode_type, infos,
                                     [info["bots"][n]["startTick"] for n in names], aborted, reason)
            gt = ground_truth({n: records[n][:T] for n in names}, (height, width), info["fovDeg"], DISPLAY_ASPECT)
            gt["blocks"], gt["hits"] = edit_events(rows, T)
            gt["backend"] = {"name": "minecraft", "version": MINECRAFT_VERSION, "catchup_ticks": bursts,
                             "render_size": [rh, rw], "summary": info.get("summary", {}),
                             "look_resets": {n: info["bots"][n].get("lookResets", 0) for n in names},
                             "skipped_ticks": info.get("skippedTicks", 0)}
            frames_PTHW3 = np.stack([f[:T] for f in frames])
            write_episode(out, key, output, frames_PTHW3, gt, split)
            return {"ticks": T, "aborted": aborted, "abort_reason": reason, "catchup_ticks": bursts,
                    "type": episode_type}
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
