"""The 14 training episode types and our opt-in lookAround, approach and roam (docs/engine.md §5.3), as per-bot
choreographies, one module per family: ``movement``, ``combat``, ``building``, ``mining`` (their shared constants
and helpers: ``common``).

Each type is a generator ``behaviour(bot)`` run by both bots, plus an optional ``setup(bot)`` that hands
out items (and, for placeAndMine, re-teleports) before recording starts. Decisions both bots must agree
on are drawn from ``bot.shared_rng`` at the same points on both; private choices use ``bot.rng``.

Adaptations to our engine (it has no Mineflayer pathfinder and no mobs): pathfinder goals become
:meth:`Bot.goto` (steering, step jumps, ``dig=True`` for ``canDig``), :meth:`Bot.tunnel_to` (digging
goals), :meth:`Bot.bridge` (scaffolding) and :meth:`Bot.place_below` (1x1 towers); timeouts are the spec's.
The family modules describe their own adaptations.
"""

from solaris_env.engine.bots.training_episodes import building, combat, mining, movement

EPISODE_TYPES = movement.EPISODE_TYPES + combat.EPISODE_TYPES + building.EPISODE_TYPES + mining.EPISODE_TYPES
