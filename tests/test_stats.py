"""`experiments.stats`: the intervals over seeds and the cross-task statistics, checked against values worked out
by hand or by scipy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from experiments.stats import (Estimate, gap_share, iqm, iqm_across_tasks, mean_interval, performance_profile,
                               probability_of_improvement, sample_sd, stratified_bootstrap, t_quantile,
                               welch_difference, wilson)

Z95 = 1.959963984540054  # the standard normal's 0.975 quantile


def _mean_of_task_means(scores: dict[str, np.ndarray]) -> float:
    return float(np.mean([np.mean(v) for v in scores.values()]))


# --- per task, over seeds: Student's, Welch's, the gap's share -----------------------------------------------


def test_the_t_quantiles_are_students():
    assert t_quantile(1) == pytest.approx(12.7062047, abs=1e-6)      # the tables' t(0.975, 1)
    assert t_quantile(4) == pytest.approx(2.7764451, abs=1e-6)
    assert t_quantile(2, 0.90) == pytest.approx(2.9199856, abs=1e-6)
    assert t_quantile(1e9) == pytest.approx(Z95, abs=1e-6)           # many degrees of freedom: the normal's
    with pytest.raises(ValueError, match="degrees of freedom"):
        t_quantile(0)


def test_the_mean_interval_is_students_by_hand():
    # 1, 2, 3: mean 2, sd 1, half width t(0.975, 2) · 1 / √3 = 4.302652730 / 1.732050808 = 2.484137712
    e = mean_interval([1.0, 2.0, 3.0])
    assert (e.value, e.low, e.high) == pytest.approx((2.0, 2.0 - 2.484137712, 2.0 + 2.484137712))
    assert mean_interval([7.0]) == Estimate(7.0, 7.0, 7.0)            # one seed: no spread known
    assert sample_sd([1.0, 2.0, 3.0]) == pytest.approx(1.0) and sample_sd([7.0]) is None
    with pytest.raises(ValueError, match="non-empty"):
        mean_interval([])


def test_welchs_interval_matches_scipys_and_the_formula():
    scipy_stats = pytest.importorskip("scipy.stats")
    a, b = np.array([60.0, 55.0, 71.0, 64.0]), np.array([50.0, 30.0, 52.0])
    ci = scipy_stats.ttest_ind(a, b, equal_var=False).confidence_interval(0.95)
    e = welch_difference(a, b)
    assert (e.value, e.low, e.high) == pytest.approx((a.mean() - b.mean(), ci.low, ci.high))
    # by hand: s_a² = 137 / 3, s_b² = 296 / 2; v = s² / n; df = (v_a + v_b)² / (v_a²/3 + v_b²/2)
    va, vb = 137.0 / 3 / 4, 148.0 / 3
    df = (va + vb) ** 2 / (va ** 2 / 3 + vb ** 2 / 2)
    assert e.high - e.value == pytest.approx(t_quantile(df) * math.sqrt(va + vb))


def test_welch_with_one_seed_in_an_arm_uses_the_others_spread_and_none_gives_a_point():
    e = welch_difference([10.0], [1.0, 2.0, 3.0])               # the one seed adds no variance; df = 2
    assert e.value == pytest.approx(8.0) and e.high - e.value == pytest.approx(t_quantile(2) / math.sqrt(3))
    assert welch_difference([5.0], [1.0]) == Estimate(4.0, 4.0, 4.0)
    assert welch_difference([5.0, 5.0], [1.0, 1.0]) == Estimate(4.0, 4.0, 4.0)
    with pytest.raises(ValueError, match="NaN"):
        welch_difference([1.0, math.nan], [1.0, 2.0])


def test_the_gap_share_is_the_ratio_of_the_differences_with_a_seeded_interval():
    a, b, c = [5.0, 6.0, 7.0], [0.0, 1.0, 2.0], [10.0, 11.0, 12.0]
    e = gap_share(a, b, c)
    assert e.value == pytest.approx(0.5) and e.low < 0.5 < e.high
    assert gap_share(a, b, c) == e                                # seeded: the same inputs, the same interval
    assert gap_share(a, b, b) is None                             # no gap to share
    wide = gap_share(a, b, [0.5, 1.5, 1.0, 1.2])                  # a gap about as large as its noise: wide
    assert wide.high - wide.low > 10 * (e.high - e.low)


# --- wilson -----------------------------------------------------------------------------------------------------


def test_wilson_matches_the_formula_worked_by_hand():
    # n = 10, p = 0.8, z² = 3.8414588206941254
    # denominator = 1 + z²/n = 1.38414588206941254
    # center = (p + z²/2n) / denominator = (0.8 + 0.19207294103470627) / 1.3841458820694126 = 0.7167401600411333
    # half = z·sqrt(p(1-p)/n + z²/4n²) / denominator = 1.959963984540054 · sqrt(0.016 + 0.009603647051735314)
    #      / 1.3841458820694126 = 1.959963984540054 · 0.16001139663078787 / 1.3841458820694126 = 0.22657768850449148
    # low = 0.7167401600411333 - 0.22657768850449148 = 0.49016247153664183, high = 0.9433178485456247
    est = wilson(8, 10)
    assert est.value == 0.8
    assert est.low == pytest.approx(0.49016247153664183, rel=1e-12)
    assert est.high == pytest.approx(0.9433178485456247, rel=1e-12)
    # the same from the formula with the constant above, so the test states which z it means
    n, p = 10, 0.8
    center = (p + Z95**2 / (2 * n)) / (1 + Z95**2 / n)
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n * n)) / (1 + Z95**2 / n)
    assert (est.low, est.high) == pytest.approx((center - half, center + half), rel=1e-12)


def test_wilson_at_the_ends_stays_in_the_unit_interval_without_collapsing():
    # 0 of 5: p = 0, so center = half = (z²/2n) / (1 + z²/n), low = 0 and
    # high = (z²/n) / (1 + z²/n) = 0.768291764138825 / 1.768291764138825 = 0.43448246478317476
    est = wilson(0, 5)
    assert (est.value, est.low) == (0.0, 0.0)
    assert est.high == pytest.approx(0.43448246478317476, rel=1e-12)
    # 5 of 5 mirrors it: high = 1, low = 1 - 0.43448246478317476 = 0.5655175352168252
    est = wilson(5, 5)
    assert (est.value, est.high) == (1.0, 1.0)
    assert est.low == pytest.approx(1 - 0.43448246478317476, rel=1e-12)


def test_wilson_narrows_with_lower_confidence():
    wide, narrow = wilson(3, 10, 0.99), wilson(3, 10, 0.5)
    assert wide.low < narrow.low < 0.3 < narrow.high < wide.high


# --- iqm --------------------------------------------------------------------------------------------------------


def test_iqm_trims_a_quarter_from_each_end():
    # n = 8: int(0.25·8) = 2 dropped from each end -> mean(3, 4, 5, 6) = 18 / 4 = 4.5
    assert iqm(np.arange(1, 9)) == 4.5
    # the same with the extremes made outliers: they are among the trimmed entries
    assert iqm(np.array([-1000.0, 2, 3, 4, 5, 6, 7, 1e6])) == 4.5
    # flattened: a 2 x 4 array is the same 8 entries
    assert iqm(np.arange(1, 9).reshape(2, 4)) == 4.5


def test_iqm_fractional_trimming_is_trim_means():
    # n = 3: int(0.75) = 0 trimmed -> mean(1, 2, 10) = 13 / 3
    assert iqm(np.array([1.0, 2, 10])) == pytest.approx(13 / 3)
    # n = 5: int(1.25) = 1 trimmed each end -> mean(2, 3, 4) = 3
    assert iqm(np.array([100.0, 1, 3, 2, 4])) == 3.0
    # n = 6: int(1.5) = 1 trimmed each end -> mean(2, 3, 4, 5) = 3.5
    assert iqm(np.array([6.0, 5, 4, 3, 2, 1])) == 3.5
    # n = 1: nothing trimmed
    assert iqm(np.array([7.0])) == 7.0


def test_iqm_agrees_with_scipy_trim_mean_where_scipy_is_installed():
    scipy_stats = pytest.importorskip("scipy.stats")
    rng = np.random.default_rng(1)
    for n in range(1, 23):
        values = rng.normal(size=n)
        assert iqm(values) == pytest.approx(scipy_stats.trim_mean(values, 0.25), abs=1e-12)


# --- stratified_bootstrap ---------------------------------------------------------------------------------------


def test_stratified_bootstrap_interval_contains_the_point_estimate():
    rng = np.random.default_rng(3)
    scores = {"a": rng.normal(0, 1, 10), "b": rng.normal(2, 1, 7), "c": rng.normal(1, 1, 5)}
    est = stratified_bootstrap(_mean_of_task_means, scores, reps=500)
    assert est.value == pytest.approx(_mean_of_task_means(scores))
    assert est.low < est.value < est.high


def test_stratified_bootstrap_of_equal_seeds_has_zero_width():
    # every resample of [2, 2, 2] is [2, 2, 2]: the mean is always 2
    assert stratified_bootstrap(_mean_of_task_means, {"a": np.array([2.0, 2, 2])}, reps=200) == Estimate(2.0, 2.0, 2.0)


def test_stratified_bootstrap_resamples_within_tasks():
    # task a all 0 (3 seeds), task b all 1 (5 seeds): resampling within each task keeps a all 0 and b all 1, so the
    # mean over tasks' means is always (0 + 1) / 2 = 0.5. Resampling the 8 pooled runs across tasks would not: a
    # resample could draw, say, six 1s and two 0s, a mean of tasks' means other than 0.5.
    scores = {"a": np.zeros(3), "b": np.ones(5)}
    assert stratified_bootstrap(_mean_of_task_means, scores, reps=300) == Estimate(0.5, 0.5, 0.5)

    seen = []

    def record(sample: dict[str, np.ndarray]) -> float:
        seen.append({task: values.copy() for task, values in sample.items()})
        return 0.0

    tasks = {"b": np.array([10.0, 11, 12, 13, 14]), "a": np.array([1.0, 2])}
    stratified_bootstrap(record, tasks, reps=50)
    assert len(seen) == 51  # 50 resamples and the point estimate
    for sample in seen:
        assert sorted(sample) == ["a", "b"]
        for task, values in sample.items():
            assert values.shape == tasks[task].shape  # each task keeps its own number of seeds
            assert set(values) <= set(tasks[task])  # and draws only its own seeds


def test_stratified_bootstrap_is_deterministic_for_a_seed():
    rng = np.random.default_rng(4)
    scores = {"a": rng.normal(size=5), "b": rng.normal(size=3)}
    first = stratified_bootstrap(_mean_of_task_means, scores, reps=300, seed=7)
    assert stratified_bootstrap(_mean_of_task_means, scores, reps=300, seed=7) == first
    # the order the tasks are given in does not matter
    assert stratified_bootstrap(_mean_of_task_means, {"b": scores["b"], "a": scores["a"]}, reps=300, seed=7) == first
    assert stratified_bootstrap(_mean_of_task_means, scores, reps=300, seed=8) != first


# --- iqm_across_tasks -------------------------------------------------------------------------------------------


def test_iqm_across_tasks_pools_every_tasks_seeds():
    # pooled [1..8] -> 4.5 (as above)
    est = iqm_across_tasks({"a": np.array([1.0, 2, 3, 4]), "b": np.array([5.0, 6, 7, 8])}, reps=300)
    assert est.value == 4.5
    assert est.low <= 4.5 <= est.high
    # pooling weighs tasks by their seeds: [0, 0, 0, 0, 0, 0, 1, 1] drops 2 from each end -> mean(0, 0, 0, 0) = 0
    # (the mean of the two tasks' IQMs would be 0.5); every resample keeps six 0s and two 1s -> zero width
    assert iqm_across_tasks({"a": np.zeros(6), "b": np.ones(2)}, reps=100) == Estimate(0.0, 0.0, 0.0)


# --- probability_of_improvement ---------------------------------------------------------------------------------


def test_probability_of_improvement_counts_pairs_by_hand():
    x = {"a": np.array([1.0, 3]), "b": np.array([1.0, 2]), "c": np.array([0.0, 5, 5])}
    y = {"a": np.array([2.0, 2]), "b": np.array([2.0]), "c": np.array([4.0, 5])}
    # a: (1>2: 0) (1>2: 0) (3>2: 1) (3>2: 1) -> 2 / 4 = 0.5
    # b: (1 vs 2: 0) (2 vs 2: tie, 0.5) -> 0.5 / 2 = 0.25
    # c: (0 vs 4: 0) (0 vs 5: 0) (5 vs 4: 1) (5 vs 5: 0.5) (5 vs 4: 1) (5 vs 5: 0.5) -> 3 / 6 = 0.5
    # mean over tasks: (0.5 + 0.25 + 0.5) / 3 = 1.25 / 3 = 5 / 12
    est = probability_of_improvement(x, y, reps=300)
    assert est.value == pytest.approx(5 / 12)
    assert 0.0 <= est.low <= est.high <= 1.0
    # ties count half on both sides, so P(X > Y) + P(Y > X) = 1
    assert probability_of_improvement(y, x, reps=1).value == pytest.approx(1 - 5 / 12)


def test_probability_of_improvement_of_disjoint_runs_is_certain():
    # every run of x beats every run of y on every task, in every resample too -> 1 with zero width
    x, y = {"a": np.array([5.0, 6, 7]), "b": np.array([1.0])}, {"a": np.array([1.0, 2]), "b": np.array([0.0, 0.5])}
    assert probability_of_improvement(x, y, reps=200) == Estimate(1.0, 1.0, 1.0)


def test_probability_of_improvement_names_a_missing_task():
    with pytest.raises(ValueError, match="'c'"):
        probability_of_improvement({"a": [1.0], "c": [2.0]}, {"a": [0.0]}, reps=10)
    with pytest.raises(ValueError, match="'d'"):
        probability_of_improvement({"a": [1.0]}, {"a": [0.0], "d": [2.0]}, reps=10)


# --- performance_profile ----------------------------------------------------------------------------------------


def test_performance_profile_averages_tasks_fractions_by_hand():
    scores = {"a": np.array([0.0, 1, 2, 3]), "b": np.array([1.0, 3])}
    taus = np.array([-1.0, 0.5, 1.0, 2.5, 3.0])
    # fraction of runs with score > τ (strictly), per task, then the mean of the two tasks:
    # τ = -1:  a 4/4, b 2/2 -> (1 + 1) / 2       = 1
    # τ = 0.5: a 3/4, b 2/2 -> (0.75 + 1) / 2    = 0.875  (pooling the 6 runs would give 5/6)
    # τ = 1:   a 2/4, b 1/2 -> (0.5 + 0.5) / 2   = 0.5    (1 is not > 1)
    # τ = 2.5: a 1/4, b 1/2 -> (0.25 + 0.5) / 2  = 0.375
    # τ = 3:   a 0/4, b 0/2 -> 0
    values, lows, highs = performance_profile(scores, taus, reps=300)
    np.testing.assert_allclose(values, [1.0, 0.875, 0.5, 0.375, 0.0])
    assert values.shape == lows.shape == highs.shape == (5,)
    assert np.all((0 <= lows) & (lows <= values) & (values <= highs) & (highs <= 1))
    # below every score or at the top one, every resample agrees: zero-width bands
    assert (lows[0], highs[0], lows[-1], highs[-1]) == (1.0, 1.0, 0.0, 0.0)
    assert highs[1] > lows[1]


def test_performance_profile_is_deterministic_for_a_seed():
    rng = np.random.default_rng(5)
    scores, taus = {"a": rng.normal(size=4), "b": rng.normal(size=3)}, np.linspace(-2, 2, 9)
    first = performance_profile(scores, taus, reps=200, seed=3)
    for got, want in zip(performance_profile(scores, taus, reps=200, seed=3), first):
        np.testing.assert_array_equal(got, want)


# --- bad input --------------------------------------------------------------------------------------------------


def _mean(scores: dict[str, np.ndarray]) -> float:
    return float(np.mean(np.concatenate(list(scores.values()))))


@pytest.mark.parametrize("call", [
    lambda: wilson(1, 0),  # trials < 1
    lambda: wilson(-1, 5),  # successes below 0
    lambda: wilson(6, 5),  # successes above trials
    lambda: wilson(1.5, 5),  # not a count
    lambda: wilson(1, 5, confidence=0.0),
    lambda: wilson(1, 5, confidence=1.0),
    lambda: wilson(1, 5, confidence=float("nan")),
    lambda: iqm(np.array([])),
    lambda: iqm(np.array([1.0, np.nan])),
    lambda: stratified_bootstrap(_mean, {}),  # no tasks
    lambda: stratified_bootstrap(_mean, {"a": np.array([])}),  # a task with no seeds
    lambda: stratified_bootstrap(_mean, {"a": np.array([1.0, np.nan])}),
    lambda: stratified_bootstrap(_mean, {"a": np.array([1.0])}, reps=0),
    lambda: stratified_bootstrap(_mean, {"a": np.array([1.0])}, confidence=1.5),
    lambda: iqm_across_tasks({}),
    lambda: iqm_across_tasks({"a": [1.0], "b": []}),
    lambda: iqm_across_tasks({"a": [1.0]}, reps=0),
    lambda: probability_of_improvement({}, {}),
    lambda: probability_of_improvement({"a": [1.0]}, {"a": [np.nan]}),
    lambda: probability_of_improvement({"a": [1.0]}, {"a": []}),
    lambda: probability_of_improvement({"a": [1.0]}, {"a": [0.0]}, confidence=0),
    lambda: performance_profile({}, np.array([0.0])),
    lambda: performance_profile({"a": [np.nan]}, np.array([0.0])),
    lambda: performance_profile({"a": [1.0]}, np.array([0.0]), reps=0),
    lambda: performance_profile({"a": [1.0]}, np.array([np.nan])),
])
def test_bad_input_raises_a_one_line_value_error(call):
    with pytest.raises(ValueError) as error:
        call()
    assert str(error.value) and "\n" not in str(error.value)
