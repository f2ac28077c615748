"""One collected 64x64 episode of each eval type a judge question needs (collected once per session)."""

import pytest

from solaris_env.judges.episodes import find_episodes

# One eval type per judge question (bothLookAway asks the same question as oneLooksAway); turnToLook
# twice: the same-scenery question needs both answers.
FIXTURE_TYPES = ("translationEval", "rotationEval", "oneLooksAwayEval", "structureEval", "turnToLookEval",
                 "turnToLookOppositeEval")
SIZE = 64  # the default model's resolution, the probes' input


@pytest.fixture(scope="session")
def collected(collect_eval):
    """Root of a ``solaris-engine collect --eval`` output with one episode per FIXTURE_TYPES."""
    return collect_eval(FIXTURE_TYPES, SIZE, seed=0)


@pytest.fixture(scope="session")
def episodes(collected):
    eps = find_episodes(collected)
    assert sorted(e.episode_type for e in eps) == sorted(FIXTURE_TYPES)
    return {e.episode_type: e for e in eps}
