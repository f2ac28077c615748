"""Runs one episode: world, spawn, setup, then all bots tick by tick until they finish.

Lifecycle (docs/engine.md §5.1): a fresh seeded world; players spread ``spawn_min..spawn_max`` apart on
the surface; setup (64 stone and diamond tools, an empty hand, facing each other, type-specific
items); recording starts with 1 s of idle; the choreographies run with phase barriers; the episode
ends when every bot has finished (or aborts for both when one fails, or at ``max_s``).
"""

from __future__ import annotations

import datetime as dt
import math
import zlib
from dataclasses import dataclass, field, replace

import numpy as np

from solaris_env.engine import constants as C
from solaris_env.engine.blocks import Block, Item, item_name
from solaris_env.engine.bots import registry
from solaris_env.engine.bots.controller import Barrier, Bot, EpisodeAbort
from solaris_env.engine.bots.spec import EpisodeSpec
from solaris_env.engine.game import Game
from solaris_env.engine.physics import Player, face
from solaris_env.engine.trace import Trace
from solaris_env.engine.world import World
from solaris_env.engine.worldgen import WorldConfig, generate
from solaris_env.spaces import noop

PLAYER_NAMES = ("Alpha", "Bravo", "Charlie", "Delta", "Echo", "Foxtrot", "Golf", "Hotel")
PRE_ROLL_TICKS = C.TICKS_PER_SECOND  # the reference sleeps 1 s after recording starts
EPOCH_BASE_MS = 1_765_000_000_000  # renderTime of tick 0 of episode 0 (deterministic, not the wall clock)
EPISODE_EPOCH_STRIDE_MS = 3_600_000
GROUND_BLOCKS = frozenset(int(b) for b in (Block.GRASS, Block.DIRT, Block.STONE, Block.SAND, Block.SNOW,
                                           Block.RED_SAND, Block.GRAVEL, Block.COBBLESTONE))


TIMES_OF_DAY = ("cycle", "day")
NOON_TICKS = 6000  # world age at noon: daylight 1.0 (``Game.daylight``)


@dataclass(frozen=True)
class EpisodeConfig:
    """Which episode to run. ``episode_type=None`` samples a training type with the shared RNG."""

    seed: int
    instance: int = 0
    episode: int = 0
    world_kind: str = "flat"
    episode_type: str | None = None
    num_players: int = 2
    world: WorldConfig = WorldConfig()
    # training episodes: "cycle" starts at a random time of day (the reference's natural cycle), "day" at noon
    # like the eval episodes and the envs (docs/engine.md, "Time of day"); eval episodes always start at noon
    time_of_day: str = "cycle"

    def __post_init__(self):
        if not 2 <= self.num_players <= len(PLAYER_NAMES):
            raise ValueError(f"num_players must be in [2, {len(PLAYER_NAMES)}], got {self.num_players}")
        if self.world_kind not in ("flat", "normal"):
            raise ValueError(f"world_kind must be 'flat' or 'normal', got {self.world_kind!r}")
        if self.time_of_day not in TIMES_OF_DAY:
            raise ValueError(f"time_of_day must be one of {TIMES_OF_DAY}, got {self.time_of_day!r}")


@dataclass
class EpisodeOutput:
    trace: Trace
    episode_type: str
    world: World
    infos: list[dict]  # per player: the *_episode_info.json content
    start_ticks: list[int | None]  # per player: eval start tick (after the sneak signal)
    aborted: bool = False
    abort_reason: str = ""
    tick_events: list[list] = field(default_factory=list)  # [tick][player] TickEvents


def episode_seeds(cfg: EpisodeConfig) -> tuple[int, int]:
    """(shared seed, world seed): the reference's ``seedrandom("<12345+instance>_<N>")``, as integers."""
    shared = zlib.crc32(f"{cfg.seed + 12345 + cfg.instance}_{cfg.episode}".encode())
    world = zlib.crc32(f"world_{cfg.seed}_{cfg.instance}_{cfg.episode}".encode())
    return shared, world


def _standable(world: World, x: int, z: int) -> tuple[bool, int]:
    y = world.surface_y(x, z)
    below = world.get(x, y - 1, z)
    free = not world.is_solid(x, y, z) and not world.is_solid(x, y + 1, z)
    wet = world.get(x, y, z) == Block.WATER
    return (below in GROUND_BLOCKS and free and not wet), y


def spawn_positions(world: World, rng: np.random.Generator, n: int, dmin: float, dmax: float,
                    cfg: WorldConfig) -> list[np.ndarray]:
    """``n`` feet positions on standable ground, the first two ``U(dmin, dmax)`` apart (spreadplayers)."""
    reach = cfg.playable_half_extent - dmax
    for _ in range(200):
        cx, cz = rng.uniform(-reach, reach, 2)
        ang, dist = rng.uniform(0, 2 * math.pi), rng.uniform(dmin, dmax)
        out = []
        for k in range(n):
            a = ang + 2 * math.pi * k / n
            x, z = math.floor(cx + dist / 2 * math.cos(a)), math.floor(cz + dist / 2 * math.sin(a))
            ok, y = _standable(world, x, z)
            if not ok:
                break
            out.append(np.array([x + 0.5, float(y), z + 0.5]))
        else:
            return out
    raise RuntimeError(f"no standable spawn for {n} players {dmin}-{dmax} apart in {world.kind} world {world.seed}")


def give(p: Player, item: int, count: int = 1) -> None:
    """Add items to the hotbar: stack onto the same block item, else the first empty slot (dropped if full)."""
    for slot in p.hotbar:
        if slot[0] == item and item < 256:
            slot[1] = min(C.STACK_SIZE, slot[1] + count)
            return
    for slot in p.hotbar:
        if slot[0] == 0:
            slot[0], slot[1] = int(item), count
            return


def make_players(feet: list[np.ndarray]) -> list[Player]:
    """Players at the given feet positions with the reference's start kit (64 stone, diamond
    pickaxe/shovel/axe, an empty hand), each facing the next one."""
    players = [Player(PLAYER_NAMES[k], skin=k % 2, pos=np.array(f, float), on_ground=True) for k, f in enumerate(feet)]
    for p in players:
        give(p, Block.STONE, 64)
        give(p, Item.DIAMOND_PICKAXE)
        give(p, Item.DIAMOND_SHOVEL)
        give(p, Item.DIAMOND_AXE)
        p.selected_slot = 4  # an empty hand
    for k, p in enumerate(players):
        face(p, players[(k + 1) % len(players)])
    return players


def inventory_record(p: Player) -> dict:
    def item(slot: int) -> dict | None:
        it, n = p.hotbar[slot]
        if it == 0:
            return None
        name = item_name(it)
        return {"type": int(it), "count": int(n), "name": name, "displayName": name.replace("_", " ").title(),
                "slot": 36 + slot}

    return {"quickBarSlot": p.selected_slot, "mainInventory": [], "hotbar": [item(s) for s in range(C.HOTBAR_SIZE)],
            "heldItem": item(p.selected_slot), "offHandItem": None}


def make_record(game: Game, i: int, action_record: dict, t: int, cfg: EpisodeConfig, pose: tuple) -> dict:
    """A per-tick record in the act_recorder layout (docs/data-format.md §3.2)."""
    p = game.players[i]
    x, y, z, yaw, pitch = pose
    render_ms = EPOCH_BASE_MS + cfg.episode * EPISODE_EPOCH_STRIDE_MS + t * C.TICK_MS
    return {
        "x": round(x, 3), "y": round(y, 3), "z": round(z, 3),
        "yaw": round(yaw % (2 * math.pi), 3), "pitch": round(pitch, 3),
        "action": action_record,
        "inventory": inventory_record(p),
        "renderTime": render_ms,
        "physicsTime": float(t * C.TICK_MS),
        "worldAgeTicks": game.world_age0 + t,
        "isInWater": bool(p.in_water),
        "frame_count": t,
        "episode_id": cfg.episode,
        "relativeTimeMs": float(t * C.TICK_MS),
        "epochTime": render_ms / 1000.0,
        "extra_info": {"seed": 42},
    }


def setup_episode(cfg: EpisodeConfig, spec: EpisodeSpec, world_seed: int, shared: int
                  ) -> tuple[Game, list[Bot]]:
    """The episode's world, players (spawned apart), game and bots, with the type's setup applied."""
    world = generate(cfg.world_kind, world_seed, variant=cfg.instance, cfg=cfg.world)
    spawn_rng = np.random.default_rng([world_seed, 1])
    pos = spawn_positions(world, spawn_rng, cfg.num_players, spec.spawn_min, spec.spawn_max, cfg.world)
    players = make_players(pos)
    # Eval episodes are recorded by day (EVAL_TIME_SET_DAY); training sees the natural cycle unless asked for day.
    cycle_age = int(np.random.default_rng([world_seed, 2]).integers(0, 24000))
    age = NOON_TICKS if spec.is_eval or cfg.time_of_day == "day" else cycle_age
    game = Game(world, players, world_age=age)
    bots = [Bot(game, k, np.random.default_rng(shared), np.random.default_rng([shared, k + 1]))
            for k in range(cfg.num_players)]
    for b in bots:
        b.episode = cfg.episode
    if spec.setup is not None:
        for b in bots:
            spec.setup(b)
    return game, bots


def run_episode(cfg: EpisodeConfig) -> EpisodeOutput:
    """Simulate one episode and return its trace, records and episode_info dicts."""
    shared, world_seed = episode_seeds(cfg)
    etype = cfg.episode_type or registry.sample_type(np.random.default_rng(shared))
    spec = registry.get(etype)
    if spec.world is not None and spec.world != cfg.world_kind:
        cfg = replace(cfg, world_kind=spec.world, episode_type=etype)
    game, bots = setup_episode(cfg, spec, world_seed, shared)
    trace = Trace.start(game)

    def script(bot: Bot):
        yield from bot.idle(PRE_ROLL_TICKS)
        yield from spec.behaviour(bot)

    gens = [script(b) for b in bots]
    n = len(bots)
    done, waiting = [False] * n, [None] * n
    errors, reason = [False] * n, ""
    tick_events = []
    for t in range(round(spec.max_s * C.TICKS_PER_SECOND)):
        actions, abort = next_actions(gens, waiting, done, errors)
        if abort is not None:
            reason = f"{bots[abort[0]].name}: {abort[1]}"
        if any(errors):
            break
        if all(done):
            break
        try:
            release_barrier(bots, waiting, done)
        except EpisodeAbort as e:
            errors, reason = [True] * n, str(e)
            break
        poses = [(*p.pos, p.yaw, p.pitch) for p in game.players]
        trace.append_state(game)
        events = game.step(actions)
        tick_events.append(events)
        for i, ev in enumerate(events):
            trace.records[i].append(make_record(game, i, ev.record, t, cfg, poses[i]))
            trace.append_edits(t, ev.placed + [(x, y, z, int(Block.AIR)) for x, y, z, _ in ev.mined])
    else:
        errors = [True] * n
        reason = f"episode exceeded max_s={spec.max_s}"
    aborted = any(errors)
    infos = []
    for i, b in enumerate(bots):
        start_ms = EPOCH_BASE_MS + cfg.episode * EPISODE_EPOCH_STRIDE_MS
        infos.append({
            "timestamp": dt.datetime.fromtimestamp(start_ms / 1000, dt.timezone.utc).isoformat(),
            "bot_name": b.name, "world_type": cfg.world_kind, "episode_number": cfg.episode,
            "episode_type": etype, "instance_id": cfg.instance,
            "encountered_error": errors[i], "peer_encountered_error": aborted and not errors[i],
            "bot_died": False, "episode_recording_started": True,
            "eval_metadata": b.eval_metadata if spec.is_eval else {},
        })
    return EpisodeOutput(trace.finish(), etype, game.world, infos, [b.start_tick for b in bots], aborted, reason,
                         tick_events)


def next_actions(gens: list, waiting: list, done: list[bool], errors: list[bool] | None = None
                 ) -> tuple[list[dict], tuple[int, EpisodeAbort] | None]:
    """One tick of the bots' generators: each unfinished bot that does not wait at a barrier yields its next
    env action (a ``Barrier`` makes it wait, the end of its generator finishes it); the others act no-op.
    A bot's ``EpisodeAbort`` marks ``errors[i]`` and is returned as (i, error) -- raised when ``errors`` is None.
    Updates ``waiting`` / ``done`` in place."""
    actions, abort = [], None
    for i, gen in enumerate(gens):
        a = noop()
        if not done[i] and waiting[i] is None:
            try:
                item = next(gen)
                if isinstance(item, Barrier):
                    waiting[i] = item
                else:
                    a = item
            except StopIteration:
                done[i] = True
            except EpisodeAbort as e:
                if errors is None:
                    raise
                errors[i], abort = True, (i, e)
        actions.append(a)
    return actions, abort


def release_barrier(bots: list[Bot], waiting: list, done: list[bool]) -> None:
    """Release a barrier once every unfinished bot waits on the same name (abort on a mismatch)."""
    live = [i for i in range(len(bots)) if not done[i]]
    if not live or any(waiting[i] is None for i in live):
        return
    names = {waiting[i].name for i in live}
    if len(names) != 1 or len(live) != len(bots):
        raise EpisodeAbort(f"barrier mismatch: {[w and w.name for w in waiting]} with finished={done}")
    name = names.pop()
    payloads = {bots[i].name: waiting[i].payload for i in live}
    for i in live:
        bots[i].peer_payloads[name] = payloads
        waiting[i] = None
