"""Start frames of the dream envs: the bundled start scenes, fresh engine worlds, engine states, given frames.

The world model starts every world from one frame per player. Where those frames come from:

* ``"bundled"`` (the default): start scenes rendered by our engine and shipped with the package in
  ``assets/start_scenes/start_scenes.npz``, sampled by the reset seed. Each scene is a
  ``RealParallelEnv(num_players=P, world=kind).reset(seed=s)``: a fresh flat or normal world at noon with
  the players spawned 6-10 blocks apart, each facing the next. Rendered at ``BUNDLED_RESOLUTIONS``; other
  frame sizes are resized on load (every engine frame shows the 16:9 game window, so resizing keeps the
  field of view; sizes above 64 are upsampled and blurry: use ``"engine"`` there). The scene's
  ``(world, seed)`` is stored too, so ``StartScenes.engine_state(i)`` rebuilds the exact engine state and
  the real env can start from the same scene, and so are the players' poses (what a partner-map model
  dead reckons from, docs/model.md §8.6).
* ``"engine"``: a fresh engine world rendered at the model's resolution on every reset (slower: world
  generation and a render per reset, and the renderer compiles once per resolution).
* a list of ``EngineState``: rendered at the model's resolution, sampled by the reset seed.
* a uint8 array (S, P, H, W, 3): S scenes given directly, sampled by the reset seed.

Build the bundle (deterministic, ~1 minute on 2 cores)::

    python -m solaris_env.start_scenes            # writes solaris_env/assets/start_scenes/start_scenes.npz
"""

from __future__ import annotations

import argparse
import functools
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

SCENES_PATH = Path(__file__).parent / "assets" / "start_scenes" / "start_scenes.npz"
BUNDLED_PLAYER_COUNTS = (1, 2, 3, 4)
BUNDLED_RESOLUTIONS = (64, 32)  # the tiny preset's frame size and the test preset's
SCENES_PER_SET = 12  # per player count: half flat, half normal worlds
SCENE_SEED_BASE = 1000  # scene i of a set uses reset seed SCENE_SEED_BASE + i
START_STATE_KINDS = ("bundled", "engine")


# ---------------------------------------------------------------------------------------------
# The bundle
# ---------------------------------------------------------------------------------------------


def scene_key(num_players: int, resolution: int) -> str:
    return f"p{num_players}_r{resolution}"


def poses_key(num_players: int) -> str:
    return f"poses_p{num_players}"


def scene_plan(scenes: int) -> list[tuple[str, int]]:
    """The (world kind, reset seed) of each scene of a set: alternating flat and normal worlds."""
    return [(("flat", "normal")[i % 2], SCENE_SEED_BASE + i) for i in range(scenes)]


def render_scene_set(num_players: int, resolution: int,
                     plan: Sequence[tuple[str, int]]) -> tuple[np.ndarray, np.ndarray]:
    """The first views of ``RealParallelEnv`` resets, one per planned scene: (S, P, R, R, 3) uint8 frames and the
    players' (S, P, 5) float32 poses (``EngineState.poses``)."""
    from solaris_env.real_env import RealParallelEnv

    frames, poses = [], []
    for kind, seed in plan:
        env = RealParallelEnv(num_players=num_players, world=kind, resolution=resolution)
        obs, _ = env.reset(seed=seed)
        frames.append(np.stack([obs[a] for a in env.possible_agents]))
        poses.append(env.engine_state().poses)
    return np.stack(frames), np.stack(poses)


def build(path: Path = SCENES_PATH, scenes: int = SCENES_PER_SET,
          player_counts: Sequence[int] = BUNDLED_PLAYER_COUNTS,
          resolutions: Sequence[int] = BUNDLED_RESOLUTIONS) -> Path:
    """Render every (player count, resolution) set and write them to one compressed ``.npz``, atomically."""
    plan = scene_plan(scenes)
    arrays: dict[str, np.ndarray] = {
        "worlds": np.array([kind for kind, _ in plan]), "seeds": np.array([seed for _, seed in plan], np.int64),
        "player_counts": np.array(player_counts, np.int64), "resolutions": np.array(resolutions, np.int64)}
    for p in player_counts:
        for r in resolutions:
            arrays[scene_key(p, r)], arrays[poses_key(p)] = render_scene_set(p, r, plan)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez_compressed(f, **arrays)
        os.chmod(tmp, 0o644)  # mkstemp's 0600 would keep the shipped file from other users
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


@functools.lru_cache(maxsize=4)
def load_bundle(path: str) -> dict[str, np.ndarray]:
    """The bundled start scenes file as arrays (cached per path)."""
    if not Path(path).exists():
        raise FileNotFoundError(f"the bundled start scenes {path} are missing; build them with "
                                "`python -m solaris_env.start_scenes`")
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def resize_frames(frames_NHW3: np.ndarray, height: int, width: int) -> np.ndarray:
    """Resize uint8 frames (area averaging down, bilinear up)."""
    import cv2

    h, w = frames_NHW3.shape[1:3]
    if (h, w) == (height, width):
        return frames_NHW3
    interp = cv2.INTER_AREA if height <= h and width <= w else cv2.INTER_LINEAR
    return np.stack([cv2.resize(f, (width, height), interpolation=interp) for f in frames_NHW3])


@dataclass(frozen=True)
class StartScenes:
    """The bundled scenes of one player count at one frame size.

    Attributes:
        frames_SPHW3: uint8 (S, P, H, W, 3) first views.
        worlds: per scene, the world kind (``"flat"`` or ``"normal"``).
        seeds: per scene, the ``RealParallelEnv.reset`` seed that made it.
        poses_SP5: float32 (S, P, 5) the players' poses in each scene (``EngineState.poses``).
    """

    frames_SPHW3: np.ndarray
    worlds: tuple[str, ...]
    seeds: tuple[int, ...]
    poses_SP5: np.ndarray

    def __len__(self) -> int:
        return len(self.frames_SPHW3)

    def engine_state(self, index: int):
        """The engine state of scene ``index`` (rebuilt with the engine, deterministic)."""
        from solaris_env.real_env import RealParallelEnv

        p = self.frames_SPHW3.shape[1]
        env = RealParallelEnv(num_players=p, world=self.worlds[index], resolution=8, hud=False)
        env.reset(seed=self.seeds[index])
        return env.engine_state()


def load_start_scenes(num_players: int, height: int, width: int, path: Path = SCENES_PATH) -> StartScenes:
    """The bundled scenes for ``num_players`` at (height, width); resized from the nearest larger bundled size."""
    bundle = load_bundle(str(path))
    counts = [int(p) for p in bundle["player_counts"]]
    if num_players not in counts:
        raise ValueError(f"no bundled start scenes for num_players={num_players} (bundled: {counts}); "
                         "use start_states='engine'")
    sizes = sorted(int(r) for r in bundle["resolutions"])
    exact = [r for r in sizes if (r, r) == (height, width)]
    larger = [r for r in sizes if r >= max(height, width)]
    source = exact[0] if exact else (larger[0] if larger else sizes[-1])
    if poses_key(num_players) not in bundle:
        raise ValueError(f"the bundled start scenes {path} carry no poses (an older bundle); rebuild them with "
                         "`python -m solaris_env.start_scenes`")
    frames = bundle[scene_key(num_players, source)]
    s, p = frames.shape[:2]
    resized = resize_frames(frames.reshape(s * p, source, source, 3), height, width).reshape(s, p, height, width, 3)
    return StartScenes(resized, tuple(str(w) for w in bundle["worlds"]), tuple(int(x) for x in bundle["seeds"]),
                       bundle[poses_key(num_players)])


# ---------------------------------------------------------------------------------------------
# Where a dream env's start frames come from
# ---------------------------------------------------------------------------------------------


# what a dream env raises when a partner-map model (docs/model.md §8.6) is started without the players' poses
POSES_NEEDED = ("this model reads the partner map (dit.partner_map), which needs the players' poses: start it from "
                "the bundled scenes or an engine game (start_states 'bundled', 'engine' or a list of EngineState, or "
                "reset options={'engine_state': ...}), not from given frames alone")


class StartFrames:
    """The start-frame source of a dream env (see the module docstring for ``start_states``).

    Args:
        start_states: ``"bundled"``, ``"engine"``, a list of ``EngineState`` or a uint8 array (S, P, H, W, 3).
        agents: the env's agent names (player order).
        height, width: the model's frame size.
    """

    def __init__(self, start_states: Any, agents: Sequence[str], height: int, width: int):
        self.agents, self.height, self.width = list(agents), height, width
        # _scene_poses: (S, P, 5) the bundled scenes' poses (None for given frames)
        self.kind, self._scenes, self._scene_poses, self._states, self._engine_env = self._parse(start_states)
        # the players' poses (P, 5) of the last start that ``sample`` / ``from_options`` gave (``EngineState.poses``;
        # the bundled scenes store theirs); None for given frames
        self.poses: np.ndarray | None = None

    def _parse(self, start_states):
        if isinstance(start_states, str):
            if start_states not in START_STATE_KINDS:
                raise ValueError(f"start_states must be one of {START_STATE_KINDS}, a list of EngineState or a "
                                 f"uint8 array (S, P, H, W, 3); got {start_states!r}")
            if start_states == "bundled":
                scenes = load_start_scenes(len(self.agents), self.height, self.width)
                return "bundled", scenes.frames_SPHW3, scenes.poses_SP5, None, None
            return "engine", None, None, None, None
        if isinstance(start_states, np.ndarray):
            shape = (len(self.agents), self.height, self.width, 3)
            if start_states.dtype != np.uint8 or start_states.ndim != 5 or start_states.shape[1:] != shape \
                    or len(start_states) == 0:
                raise ValueError(f"start_states array must be uint8 (S, {', '.join(map(str, shape))}) with S >= 1; "
                                 f"got {start_states.dtype} {start_states.shape}")
            return "frames", start_states, None, None, None
        if isinstance(start_states, (list, tuple)) and start_states:
            from solaris_env.real_env import check_engine_state

            states = [check_engine_state(s, self.agents) for s in start_states]
            return "engine_states", None, None, states, None
        raise TypeError(f"start_states must be 'bundled', 'engine', a non-empty list of EngineState or a uint8 "
                        f"array; got {type(start_states).__name__}")

    def sample(self, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
        """(P, H, W, 3) uint8 start frames and an info dict saying which start was used."""
        self.poses = None
        if self._scenes is not None:
            i = int(rng.integers(len(self._scenes)))
            self.poses = None if self._scene_poses is None else self._scene_poses[i]
            return self._scenes[i], {"start": self.kind, "scene": i}
        if self._states is not None:
            i = int(rng.integers(len(self._states)))
            self.poses = self._states[i].poses
            return self.render_state(self._states[i]), {"start": self.kind, "scene": i}
        seed = int(rng.integers(2**31 - 1))
        return self._fresh_engine_frames(seed), {"start": "engine", "engine_seed": seed}

    def from_options(self, options: dict) -> tuple[np.ndarray, dict] | None:
        """Start frames given in ``reset`` options (``"frames"`` or ``"engine_state"``), else None."""
        from solaris_env.env_common import check_agent_frames

        self.poses = None
        if "frames" in options and "engine_state" in options:
            raise ValueError("options may give 'frames' or 'engine_state', not both")
        if "frames" in options:
            return check_agent_frames(options["frames"], self.agents, (self.height, self.width, 3)), {"start": "frames"}
        if "engine_state" in options:
            from solaris_env.real_env import check_engine_state

            state = check_engine_state(options["engine_state"], self.agents)
            self.poses = state.poses
            return self.render_state(state), {"start": "engine_state"}
        return None

    def render_state(self, state) -> np.ndarray:
        """The players' views of an engine state at the model's resolution (P, H, W, 3)."""
        from solaris_env.real_env import render_game_views

        return render_game_views(state.game(), self.height, self.width)[0]

    def _fresh_engine_frames(self, seed: int) -> np.ndarray:
        if self._engine_env is None:
            from solaris_env.real_env import RealParallelEnv

            self._engine_env = RealParallelEnv(num_players=len(self.agents), resolution=(self.height, self.width))
        obs, _ = self._engine_env.reset(seed=seed)
        self.poses = self._engine_env.engine_state().poses
        return np.stack([obs[a] for a in self.agents])


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Render the bundled start scenes of the dream envs.")
    parser.add_argument("--out", type=Path, default=SCENES_PATH, help="output .npz")
    parser.add_argument("--scenes", type=int, default=SCENES_PER_SET, help="scenes per player count")
    args = parser.parse_args(argv)
    path = build(args.out, args.scenes)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
