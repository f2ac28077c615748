"""What the real and the dream env share: per-agent spaces built once, input checks that name the agent and
the key, the per-agent step outputs (tasks, terminations, truncation) and all players' frames side by side."""

from __future__ import annotations

import copy
import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

RENDER_MODES = ("rgb_array", "human")


# ---------------------------------------------------------------------------------------------
# Checks
# ---------------------------------------------------------------------------------------------


def check_render_mode(render_mode: str | None) -> None:
    """ValueError for an unknown mode; RuntimeError for ``"human"`` where no window can be opened."""
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode must be one of {list(RENDER_MODES)} or None, got {render_mode!r}")
    if render_mode == "human":
        reason = human_display_problem()
        if reason:
            raise RuntimeError(f"render_mode='human' cannot open a window: {reason}. Use render_mode='rgb_array' "
                               "(or `solaris-env play`, which serves a local web page)")


def available_render_modes() -> list[str]:
    """The render modes that work on this machine: ``rgb_array`` always, ``human`` where a window can open. An
    env's ``metadata["render_modes"]`` lists these, so checkers that try every listed mode (Gymnasium's
    ``check_env``) pass on a headless machine; asking for ``human`` there still raises a clear error."""
    return ["rgb_array"] + (["human"] if human_display_problem() is None else [])


def human_display_problem() -> str | None:
    """Why an OpenCV window cannot be shown here, or None when it can."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY and WAYLAND_DISPLAY are unset)"
    import cv2

    info = cv2.getBuildInformation()
    gui = next((line.split(":", 1)[1].strip() for line in info.splitlines() if line.strip().startswith("GUI:")), "")
    if gui.upper() == "NONE":
        return "this OpenCV build has no GUI support (opencv-python-headless); install opencv-python"
    return None


# ``reset`` option keys that are accepted and ignored: PettingZoo's ``parallel_api_test`` (and ``api_test``) call
# ``reset(seed=0, options={"options": 1})`` to check that reset takes the argument; its seed test passes none.
IGNORED_OPTION_KEYS = ("options",)


def check_options(options: Any, allowed: Sequence[str] = (), ignored: Sequence[str] = IGNORED_OPTION_KEYS) -> Mapping:
    """``reset``'s options: None or a dict whose keys are in ``allowed`` (used) or ``ignored`` (PettingZoo's API
    test probe, ``IGNORED_OPTION_KEYS``). Any other key raises ValueError naming it and the keys this env takes, so
    a typo (``"frame"`` for ``"frames"``) does not silently start the default scene."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise TypeError(f"options must be a dict or None, got {type(options).__name__}")
    unknown = [k for k in options if k not in allowed and k not in ignored]
    if unknown:
        raise ValueError(f"options: unknown key {unknown[0]!r}; this env's reset takes {list(allowed)} "
                         f"(and ignores {list(ignored)}, PettingZoo's API-test probe)")
    return {k: v for k, v in options.items() if k in allowed}


def check_seed(seed: Any) -> int | None:
    """``reset``'s seed: None or an int >= 0 (Python or numpy integer) -> None or a Python int. Bools and other
    types (float, str, ...) raise ValueError naming ``seed``."""
    if seed is None:
        return None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed must be None or an int >= 0 (a Python or numpy integer, not a bool), "
                         f"got {type(seed).__name__} {seed!r}")
    if seed < 0:
        raise ValueError(f"seed must be None or an int >= 0, got {seed!r}")
    return int(seed)


def check_int(value: Any, name: str, minimum: int = 1) -> int:
    """``value`` as a Python int >= ``minimum`` (numpy integers are fine); bools, floats (2.5, nan), strings and
    None raise ValueError naming ``name``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an int >= {minimum}, got {type(value).__name__} {value!r}")
    return int(value)


def episode_rng(current: np.random.Generator | None, seed: int | None) -> np.random.Generator:
    """The generator a ``reset`` draws from: a fresh one for ``seed`` (or when there is none yet), else a COPY of
    ``current`` (Gymnasium's rule: an unseeded reset continues the stream). The env assigns it only once the reset
    has succeeded, so a failed reset leaves the stream where it was."""
    if seed is not None or current is None:
        from gymnasium.utils import seeding

        return seeding.np_random(seed)[0]
    return copy.deepcopy(current)


def check_agent_actions(actions: Any, agents: Sequence[str]) -> None:
    """``actions`` must be a dict with exactly one entry per live agent (values are checked by the env)."""
    if not isinstance(actions, Mapping):
        raise TypeError(f"actions must be a dict keyed by agent {list(agents)}, got {type(actions).__name__}")
    missing = [a for a in agents if a not in actions]
    unknown = [a for a in actions if a not in agents]
    if missing or unknown:
        raise ValueError(f"actions must have exactly one entry per live agent {list(agents)}; "
                         f"missing {missing}, unknown {unknown}")


def check_agent_frames(frames: Any, agents: Sequence[str], shape: tuple[int, int, int],
                       where: str = "options['frames']") -> np.ndarray:
    """``{agent: (H, W, 3) uint8}`` for every agent -> (P, H, W, 3) uint8 in agent order.

    Raises ValueError naming the agent, the expected shape and what was given.
    """
    if not isinstance(frames, Mapping):
        raise TypeError(f"{where} must be a dict {{agent: {shape} uint8 array}}, got {type(frames).__name__}")
    missing = [a for a in agents if a not in frames]
    unknown = [a for a in frames if a not in agents]
    if missing or unknown:
        raise ValueError(f"{where} must have one frame per agent {list(agents)}; missing {missing}, unknown {unknown}")
    for a in agents:
        frame = frames[a]
        dtype, got = getattr(frame, "dtype", None), getattr(frame, "shape", None)
        if dtype is None or np.dtype(dtype) != np.uint8 or tuple(got) != tuple(shape):
            raise ValueError(f"{where}[{a!r}]: expected a uint8 array of shape {tuple(shape)}, "
                             f"got dtype {dtype} shape {got}")
    return np.stack([np.asarray(frames[a]) for a in agents])


def side_by_side(frames_PHW3: np.ndarray) -> np.ndarray:
    """(P, H, W, 3) -> (H, P*W, 3): every player's view, left to right in agent order."""
    return np.concatenate(list(frames_PHW3), axis=1)


# ---------------------------------------------------------------------------------------------
# The mixin
# ---------------------------------------------------------------------------------------------


class PlayerViewsEnv:
    """Mixin for ParallelEnvs with one first-person view per player.

    The env builds ``self._observation_spaces`` / ``self._action_spaces`` (agent -> space) once in
    ``__init__``, keeps the players' current frames in ``self._frames`` (P, H, W, 3), all frames of the last step in
    ``self._step_frames`` (P, k, H, W, 3), and the agents that
    are still playing in ``self.agents``. ``render_mode="rgb_array"`` returns the (H, P*W, 3) sheet;
    ``"human"`` shows it in an OpenCV window.

    Terminations: an agent whose task says it terminated leaves ``agents``; its player stays in the world
    and is sent no-op actions until the episode ends (truncation at ``max_steps`` or every agent done).
    """

    render_mode: str | None
    possible_agents: list[str]
    agents: list[str]
    _frames: np.ndarray | None
    _step_frames: np.ndarray | None
    _observation_spaces: dict
    _action_spaces: dict

    def observation_space(self, agent: str):
        return self._observation_spaces[agent]

    def action_space(self, agent: str):
        return self._action_spaces[agent]

    def render(self) -> np.ndarray | None:
        if self.render_mode is None or self._frames is None:
            return None
        sheet = side_by_side(self._frames)  # (H, P*W, 3)
        if self.render_mode == "human":
            import cv2

            cv2.imshow(self.metadata["name"], cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
            cv2.waitKey(1)
            return None
        return sheet

    def close(self) -> None:
        if self.render_mode == "human":
            import cv2

            cv2.destroyAllWindows()

    def step_frames(self) -> np.ndarray:
        """uint8 (P, k, H, W, 3): every player's frames of the last step (k = 1 after reset; all players,
        including those whose agent has ended), a read-only view of the env's buffer (copy it to change it).
        Recorders use it."""
        if self._step_frames is None:
            raise RuntimeError("step_frames() called before reset(); call reset() first")
        view = self._step_frames.view()
        view.setflags(write=False)
        return view

    # -- per-agent outputs ------------------------------------------------------------------------
    def _observations(self) -> dict[str, np.ndarray]:
        """Each live agent's frame, a copy the caller owns (writing into it changes nothing in the env)."""
        return {a: self._frames[self.possible_agents.index(a)].copy() for a in self.agents}

    def _step_outputs(self, rewards_P: np.ndarray, terminations_P: np.ndarray, truncated: bool,
                      infos_P: list[dict]) -> tuple[dict, dict, dict, dict, dict]:
        """The five per-agent dicts of ``step`` for the agents live before it; ended agents then leave."""
        index = {a: self.possible_agents.index(a) for a in self.agents}
        obs = self._observations()
        rewards = {a: float(rewards_P[i]) for a, i in index.items()}
        terminations = {a: bool(terminations_P[i]) for a, i in index.items()}
        truncations = {a: truncated and not terminations[a] for a in index}
        infos = {a: infos_P[i] for a, i in index.items()}
        self.agents = [a for a in self.agents if not (terminations[a] or truncations[a])]
        return obs, rewards, terminations, truncations, infos

    def _live_mask(self) -> np.ndarray:
        """(P,) bool: which players are still agents."""
        return np.array([a in self.agents for a in self.possible_agents])
