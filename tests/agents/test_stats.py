"""agents.stats: bootstrap intervals, Pearson/Spearman (SciPy and the NumPy fallback agree), MMRV on hand-made
examples."""

import numpy as np
import pytest
from scipy import stats as scipy_stats

from agents import stats


def test_bootstrap_ci_contains_the_mean_and_narrows_with_more_samples():
    rng = np.random.default_rng(0)
    few, many = rng.normal(3.0, 1.0, 10), rng.normal(3.0, 1.0, 1000)
    for x in (few, many):
        low, high = stats.bootstrap_ci(x, resamples=2000, seed=1)
        assert low < x.mean() < high
    assert np.diff(stats.bootstrap_ci(many, resamples=2000)) < np.diff(stats.bootstrap_ci(few, resamples=2000))
    # the true mean is inside a 95 % interval of 1000 normal samples
    assert stats.bootstrap_ci(many)[0] < 3.0 < stats.bootstrap_ci(many)[1]
    assert stats.bootstrap_ci(few, seed=5) == stats.bootstrap_ci(few, seed=5)  # seeded


def test_bootstrap_ci_degenerate_cases_and_errors():
    assert stats.bootstrap_ci([2.0, 2.0, 2.0]) == (2.0, 2.0)
    assert stats.bootstrap_ci([7.0]) == (7.0, 7.0)
    s = stats.summarize([0.0, 1.0, 1.0, 0.0], resamples=500)
    assert s["mean"] == 0.5 and s["n"] == 4 and s["ci_low"] <= 0.5 <= s["ci_high"] and s["returns"] == [0, 1, 1, 0]
    with pytest.raises(ValueError, match="non-empty"):
        stats.bootstrap_ci([])
    with pytest.raises(ValueError, match="confidence"):
        stats.bootstrap_ci([1.0, 2.0], confidence=1.5)
    with pytest.raises(ValueError, match="finite"):
        stats.bootstrap_ci([1.0, float("nan")])


def test_rankdata_averages_ties_like_scipy():
    x = [3.0, 1.0, 3.0, 2.0, 3.0, 0.5]
    assert np.array_equal(stats.rankdata(x), scipy_stats.rankdata(x))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_correlations_match_scipy_and_the_numpy_fallback(seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=9)
    y = 0.5 * x + rng.normal(size=9)
    y[3] = y[5]  # a tie
    assert stats.pearson(x, y) == pytest.approx(scipy_stats.pearsonr(x, y).statistic)
    assert stats.spearman(x, y) == pytest.approx(scipy_stats.spearmanr(x, y).statistic)
    assert stats._pearson_numpy(x, y) == pytest.approx(scipy_stats.pearsonr(x, y).statistic)
    assert stats._pearson_numpy(stats.rankdata(x), stats.rankdata(y)) == pytest.approx(
        scipy_stats.spearmanr(x, y).statistic)


def test_correlation_edge_cases():
    assert stats.spearman([1, 2, 3], [10, 20, 30]) == pytest.approx(1.0)
    assert stats.spearman([1, 2, 3], [1, 4, 9]) == pytest.approx(1.0)  # monotone, not linear
    assert stats.pearson([1, 2, 3], [1, 4, 9]) < 1.0
    assert stats.spearman([1, 2, 3], [3, 2, 1]) == pytest.approx(-1.0)
    assert np.isnan(stats.spearman([1, 2, 3], [5, 5, 5]))  # a constant evaluator orders nothing
    assert np.isnan(stats.pearson([1.0], [2.0]))
    with pytest.raises(ValueError, match="same length"):
        stats.pearson([1, 2], [1, 2, 3])


def test_mmrv_hand_made_examples():
    real = [0.0, 1.0, 2.0, 3.0]
    assert stats.mmrv(real, [0.0, 1.0, 2.0, 3.0]) == 0.0  # same order
    assert stats.mmrv(real, [10.0, 20.0, 30.0, 40.0]) == 0.0  # same order, other scale: no violation
    # swap the two best: policies 2 and 3 each violate one pair worth |2 - 3| = 1 -> (0 + 0 + 1 + 1) / 4
    assert stats.mmrv(real, [0.0, 1.0, 3.0, 2.0]) == pytest.approx(0.5)
    # reversed: every pair violated; each policy's worst violation is its distance to the farthest one
    assert stats.mmrv(real, [3.0, 2.0, 1.0, 0.0]) == pytest.approx((3 + 2 + 2 + 3) / 4)
    # a proxy tie between different real scores loses their order: the worse policy's "less than" is not
    # reproduced (a violation worth 1); the better one's "not less than" is -> (1 + 0) / 2
    assert stats.mmrv([0.0, 1.0], [5.0, 5.0]) == pytest.approx(0.5)
    # real ties cost nothing whatever the proxy says
    assert stats.mmrv([1.0, 1.0, 1.0], [3.0, 1.0, 2.0]) == 0.0
    assert stats.mmrv([4.0], [0.0]) == 0.0


def test_mmrv_is_invariant_to_monotone_proxy_transforms_and_weighs_by_real_gaps():
    rng = np.random.default_rng(3)
    real, proxy = rng.normal(size=8), rng.normal(size=8)
    assert stats.mmrv(real, proxy) == pytest.approx(stats.mmrv(real, np.exp(proxy)))
    assert stats.mmrv(2.0 * real, proxy) == pytest.approx(2.0 * stats.mmrv(real, proxy))


def test_transfer_ratio_only_when_the_real_ppo_beats_random():
    from agents.transfer import transfer_ratio

    row = lambda mean, lo: {"mean": mean, "ci_low": lo}
    ratio, note = transfer_ratio({"dream_ppo": row(6.0, 5.0), "real_ppo": row(10.0, 8.0), "random": row(2.0, 1.0)})
    assert ratio == pytest.approx(0.5) and note.startswith("defined")
    ratio, note = transfer_ratio({"dream_ppo": row(4.1, 3.3), "real_ppo": row(4.9, 3.3), "random": row(5.8, 2.3)})
    assert ratio is None and "not better than random" in note  # the measured face_partner run: noise, not 1.9
    assert transfer_ratio({"dream_ppo": row(1, 0), "real_ppo": row(2, 1)}) == (None, "no random baseline")
