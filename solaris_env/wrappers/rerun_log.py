"""``RerunRecorder``: every player's frames, actions and rewards of a ParallelEnv on one Rerun timeline.

Entities: ``players/<agent>/view`` (the frame), ``players/<agent>/reward``, ``players/<agent>/return``,
``players/<agent>/action/<key>`` (each binary key 0/1, ``camera/pitch`` and ``camera/yaw`` in degrees).
Timelines: ``tick`` (20 Hz: the dream env's k frames per step each get their tick), ``step`` (env steps)
and ``episode``. Time is set with ``RecordingStream.set_time`` (rerun >= 0.23 API).

Output: ``path=...`` writes an ``.rrd`` file (open it with ``rerun file.rrd``); ``spawn=True`` streams to a
live viewer instead.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pettingzoo.utils.wrappers import BaseParallelWrapper

from solaris_env.spaces import BINARY_KEYS, CAMERA_KEY


class RerunRecorder(BaseParallelWrapper):
    """Args:
        env: a ParallelEnv of ours (it must have ``step_frames()``).
        path: the ``.rrd`` file to write (atomically at ``close``); None with ``spawn=True``.
        spawn: stream to a newly spawned Rerun viewer.
        application_id: the recording's application id.
        jpeg_quality: frames are logged JPEG-compressed at this quality (None: raw RGB).
    """

    def __init__(self, env: Any, path: str | Path | None = None, spawn: bool = False,
                 application_id: str = "solaris_env", jpeg_quality: int | None = 90):
        import rerun as rr

        super().__init__(env)
        if (path is None) == (not spawn):
            raise ValueError("give exactly one of path (an .rrd file) or spawn=True")
        self.rec = rr.RecordingStream(application_id)
        self.path = None if path is None else Path(path)
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._tmp = self.path.with_name(f".{self.path.stem}.tmp{self.path.suffix}")
            self.rec.save(self._tmp)
        else:
            self.rec.spawn()
        self.jpeg_quality = jpeg_quality
        self.tick = self.step_count = 0
        self.episode = -1
        self._returns: dict[str, float] = {}

    def reset(self, seed: int | None = None, options: dict | None = None):
        out = self.env.reset(seed=seed, options=options)
        self.episode += 1
        self._returns = {a: 0.0 for a in self.env.possible_agents}
        self._log_frames()
        return out

    def step(self, actions: dict):
        out = self.env.step(actions)
        _, rewards, *_ = out
        self.step_count += 1
        self._set_time(self.tick + 1)
        for agent, action in actions.items():
            self._log_action(agent, action)
        for agent, r in rewards.items():
            self._returns[agent] += float(r)
            self._log_scalar(f"players/{agent}/reward", float(r))
            self._log_scalar(f"players/{agent}/return", self._returns[agent])
        self._log_frames()
        return out

    def close(self) -> None:
        self.rec.flush()
        if self.path is not None:
            self.rec.disconnect()
            self._tmp.replace(self.path)
            self.path_written = self.path
        self.env.close()

    # -- logging ----------------------------------------------------------------------------------
    def _set_time(self, tick: int) -> None:
        self.rec.set_time("tick", sequence=tick)
        self.rec.set_time("step", sequence=self.step_count)
        self.rec.set_time("episode", sequence=self.episode)

    def _log_frames(self) -> None:
        import rerun as rr

        frames_PkHW3 = self.env.unwrapped.step_frames()
        for t in range(frames_PkHW3.shape[1]):
            self.tick += 1
            self._set_time(self.tick)
            for agent, frame in zip(self.env.possible_agents, frames_PkHW3[:, t]):
                image = rr.Image(frame)
                self.rec.log(f"players/{agent}/view", image.compress(self.jpeg_quality) if self.jpeg_quality else image)

    def _log_action(self, agent: str, action: dict) -> None:
        for key in BINARY_KEYS:
            self._log_scalar(f"players/{agent}/action/{key}", float(action[key]))
        pitch, yaw = np.asarray(action[CAMERA_KEY], np.float64)
        self._log_scalar(f"players/{agent}/action/camera/pitch", pitch)
        self._log_scalar(f"players/{agent}/action/camera/yaw", yaw)

    def _log_scalar(self, entity: str, value: float) -> None:
        import rerun as rr

        self.rec.log(entity, rr.Scalars(value))
