"""Every interval and verdict of the suite, in one place: the sweep's printed table, `experiments.report` and
`experiments.compare` read them here. Pure numpy (scipy for Student's t quantile).

Per task, over seeds (`values` a 1-D array of per-seed scores):
- `mean_interval`: a mean with Student's t-interval (sd with ddof 1);
- `welch_difference`: `mean(a) − mean(b)` with Welch's t-interval (unequal variances, Satterthwaite's degrees of
  freedom). Why not a percentile bootstrap: at the 3–8 seeds of this project's files it under-covers (a nominal
  95% interval held the true difference 79% of the time at 3 seeds, 91% at 8), while Welch's held 95–98%, normal
  seeds or collapsing ones (`tools/coverage.py`, written up in docs/reliability.md);
- `gap_share`: `(mean(a) − mean(b)) / (mean(c) − mean(b))`, a ratio of differences (no t-interval exists for it),
  with a percentile bootstrap interval resampling each arm's seeds independently;
- `sample_sd`: the sample sd (ddof 1), None for fewer than 2 values.

Across tasks, as Agarwal et al. (2021, "Deep RL at the edge of the statistical precipice", the `rliable` library)
define them, with `{task: array of per-seed scores}` (normalised, e.g. % of expert), one entry per run (seed):
- `wilson`: the Wilson score interval for a success rate. Unlike the normal ("Wald") interval it stays inside
  [0, 1] and does not collapse to zero width at 0 or n successes out of n.
- `iqm`: the interquartile mean, the mean of the middle 50% of the scores (25% trimmed from each end). It is
  robust to a few outlying runs like the median, yet uses half of the data, so it varies less than the median.
- `stratified_bootstrap`: a percentile interval for any statistic of the score dictionary, resampling seeds with
  replacement within each task (stratified), so every resample keeps every task and its number of seeds.
- `iqm_across_tasks`: the IQM of all tasks' runs pooled, with its stratified-bootstrap interval.
- `probability_of_improvement`: P(X > Y), per task the chance that a random run of X beats a random run of Y
  (Mann-Whitney; ties count half), averaged over tasks. It says how often, not by how much.
- `performance_profile`: the run-score distribution, for each threshold τ the fraction of runs scoring above τ
  (each task weighing the same), with pointwise stratified-bootstrap bands.

Why pool tasks: with 3-5 seeds per task, a per-task percentile bootstrap under-covers badly (a resample of 3
values has at most 10 distinct means, and the interval is narrower than the true uncertainty). Aggregating over
tasks and resampling within each task, as rliable does, gives intervals from many more runs while respecting
that runs of different tasks are not exchangeable.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from scipy import stats as scipy_stats

Scores = Mapping[str, np.ndarray]


@dataclasses.dataclass(frozen=True)
class Estimate:
    """A point estimate with its confidence interval."""

    value: float  # the point estimate on the full data
    low: float  # lower end of the confidence interval
    high: float  # upper end


def _check_confidence(confidence: float) -> None:
    if not (isinstance(confidence, (int, float, np.floating)) and 0.0 < confidence < 1.0):
        raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")


def _check_reps(reps: int) -> None:
    if isinstance(reps, bool) or not isinstance(reps, (int, np.integer)) or reps < 1:
        raise ValueError(f"reps must be an integer >= 1, got {reps!r}")


def _as_int(value: int, name: str) -> int:
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    if not (number and float(value).is_integer()):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    return int(value)


def _check_scores(scores: Scores, name: str = "scores") -> dict[str, np.ndarray]:
    """`scores` as {task: 1-D float array}, with tasks sorted by name; ValueError on empty, seedless or NaN."""
    if not isinstance(scores, Mapping) or not scores:
        raise ValueError(f"{name} is empty: no tasks")
    checked = {}
    for task in sorted(scores):
        values = np.atleast_1d(np.asarray(scores[task], dtype=float))
        if values.ndim != 1:
            raise ValueError(f"{name}[{task!r}] must be a 1-D array of per-seed scores, got shape {values.shape}")
        if values.size == 0:
            raise ValueError(f"{name}[{task!r}] has no seeds")
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{name}[{task!r}] holds NaN or infinite scores")
        checked[task] = values
    return checked


def _percentiles(samples: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """The percentile interval's ends along axis 0 of the bootstrap `samples`."""
    alpha = 1.0 - confidence
    return np.quantile(samples, alpha / 2, axis=0), np.quantile(samples, 1 - alpha / 2, axis=0)


def _bootstrap(statistic: Callable[..., object], groups: Sequence[dict[str, np.ndarray]], reps: int,
               seed: int) -> np.ndarray:
    """`statistic(*resampled_groups)` for `reps` stratified resamples, stacked along axis 0.

    Each group (a checked score dictionary) is resampled independently, seeds with replacement within each task.
    All indices are drawn up front, group by group and task by task in sorted order, so the result depends only
    on the data and `seed`.
    """
    rng = np.random.default_rng(seed)
    indices = [{task: rng.integers(0, values.size, size=(reps, values.size)) for task, values in group.items()}
               for group in groups]
    samples = [statistic(*({task: values[idx[task][r]] for task, values in group.items()}
                           for group, idx in zip(groups, indices)))
               for r in range(reps)]
    return np.asarray(samples, dtype=float)


def t_quantile(df: float, confidence: float = 0.95) -> float:
    """Student's t quantile for a two-sided `confidence` interval with `df` > 0 degrees of freedom (fractional for
    Welch's): t((1 + confidence) / 2, df)."""
    _check_confidence(confidence)
    if not df > 0:
        raise ValueError(f"degrees of freedom must be > 0, got {df!r}")
    return float(scipy_stats.t.ppf(0.5 + confidence / 2, df))


def _seeds(values: Sequence[float], name: str) -> np.ndarray:
    x = np.asarray(values, np.float64)
    if x.ndim != 1 or not x.size:
        raise ValueError(f"{name} must be a non-empty 1-d array of per-seed values, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} holds NaN or infinite values")
    return x


def sample_sd(values: Sequence[float]) -> float | None:
    """The sample standard deviation (ddof 1) of per-seed `values`; None for fewer than 2 (no spread is known)."""
    x = np.asarray(values, np.float64)
    return float(x.std(ddof=1)) if x.size >= 2 else None


def mean_interval(values: Sequence[float], confidence: float = 0.95) -> Estimate:
    """The mean of per-seed `values` with Student's t-interval, mean ± t(df = n − 1) · sd / √n (sd with ddof 1).

    One value gives the degenerate interval [x, x]: one seed shows no spread, and the callers' verdicts say so.
    """
    x = _seeds(values, "values")
    mean = float(x.mean())
    if x.size < 2:
        return Estimate(mean, mean, mean)
    half = t_quantile(x.size - 1, confidence) * float(x.std(ddof=1)) / math.sqrt(x.size)
    return Estimate(mean, mean - half, mean + half)


def welch_difference(a: Sequence[float], b: Sequence[float], confidence: float = 0.95) -> Estimate:
    """`mean(a) − mean(b)` over two arms' per-seed values with Welch's t-interval.

    The standard error is √(s_a²/n_a + s_b²/n_b) (sds with ddof 1) and the degrees of freedom Satterthwaite's,
    (v_a + v_b)² / (v_a²/(n_a − 1) + v_b²/(n_b − 1)) with v = s²/n. An arm of one seed has no variance estimate and
    adds none (its term is left out); where neither arm shows spread the interval is [d, d]. A verdict needs ≥ 2
    seeds per arm (`experiments.report.analysis.verdict`).
    """
    a, b = _seeds(a, "a"), _seeds(b, "b")
    diff = float(a.mean() - b.mean())
    parts = [(float(x.var(ddof=1)) / x.size, x.size - 1) for x in (a, b) if x.size >= 2]
    se2 = sum(v for v, _ in parts)
    if se2 <= 0:
        return Estimate(diff, diff, diff)
    df = se2 ** 2 / sum(v ** 2 / dof for v, dof in parts if v > 0)
    half = t_quantile(df, confidence) * math.sqrt(se2)
    return Estimate(diff, diff - half, diff + half)


def gap_share(a: Sequence[float], b: Sequence[float], c: Sequence[float], reps: int = 10_000,
              confidence: float = 0.95, seed: int = 0) -> Estimate | None:
    """How much of the gap from `b` to `c` `a` covers, `(mean(a) − mean(b)) / (mean(c) − mean(b))`, with a
    percentile bootstrap interval (each arm's seeds resampled with replacement, independently).

    None where `mean(c) = mean(b)` (no gap to share). Replicates whose own gap is 0 are left out; where the gap's
    interval holds 0 the share's is wide (or unbounded), as it should be.
    """
    _check_reps(reps)
    _check_confidence(confidence)
    arms = [_seeds(x, name) for x, name in ((a, "a"), (b, "b"), (c, "c"))]
    if arms[2].mean() == arms[1].mean():
        return None

    def share(x: dict, y: dict, z: dict) -> float:
        gap = z["arm"].mean() - y["arm"].mean()
        return (x["arm"].mean() - y["arm"].mean()) / gap if gap != 0 else math.nan

    samples = _bootstrap(share, [{"arm": x} for x in arms], reps, seed)
    low, high = _percentiles(samples[np.isfinite(samples)], confidence)
    return Estimate(float(share(*({"arm": x} for x in arms))), float(low), float(high))


def wilson(successes: int, trials: int, confidence: float = 0.95) -> Estimate:
    """Wilson score interval for a binomial proportion; value = successes / trials."""
    successes, trials = _as_int(successes, "successes"), _as_int(trials, "trials")
    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    if not 0 <= successes <= trials:
        raise ValueError(f"successes must lie in [0, trials={trials}], got {successes}")
    _check_confidence(confidence)
    z = statistics.NormalDist().inv_cdf(1 - (1 - confidence) / 2)
    p = successes / trials
    denominator = 1 + z * z / trials
    center = (p + z * z / (2 * trials)) / denominator
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denominator
    low = 0.0 if successes == 0 else max(0.0, center - half)
    high = 1.0 if successes == trials else min(1.0, center + half)
    return Estimate(p, low, high)


def _iqm(values: np.ndarray) -> float:
    """IQM of a flat, checked array (scipy.stats.trim_mean(values, 0.25))."""
    cut = int(0.25 * values.size)
    return float(np.mean(np.sort(values)[cut:values.size - cut]))


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean of all entries (flattened): the mean of the middle 50%, trimming 25% from each end.

    Fractional trimming as rliable/scipy.stats.trim_mean(x, 0.25): int(0.25 * n) entries are dropped from each
    end (none for n < 4). ValueError on no entries or NaN.
    """
    values = np.asarray(scores, dtype=float).ravel()
    if values.size == 0:
        raise ValueError("iqm of no scores")
    if not np.all(np.isfinite(values)):
        raise ValueError("iqm of NaN or infinite scores")
    return _iqm(values)


def stratified_bootstrap(statistic: Callable[[dict[str, np.ndarray]], float], scores: Scores, reps: int = 2000,
                         confidence: float = 0.95, seed: int = 0) -> Estimate:
    """`statistic(scores_dict) -> float` on `scores` ({task: array of per-seed scores}), with a percentile interval.

    The interval comes from resampling seeds with replacement within each task (stratified), `reps` times, using
    np.random.default_rng(seed). Tasks may have different numbers of seeds. `statistic` gets the tasks in sorted
    order. As any percentile interval, it need not contain the point estimate for a strongly skewed statistic.
    """
    _check_reps(reps)
    _check_confidence(confidence)
    checked = _check_scores(scores)
    samples = _bootstrap(statistic, [checked], reps, seed)
    low, high = _percentiles(samples, confidence)
    return Estimate(float(statistic(checked)), float(low), float(high))


def _pooled_iqm(scores: dict[str, np.ndarray]) -> float:
    return _iqm(np.concatenate(list(scores.values())))


def iqm_across_tasks(scores: Scores, reps: int = 2000, confidence: float = 0.95, seed: int = 0) -> Estimate:
    """IQM of every task's seeds' (normalised) scores pooled, with its stratified-bootstrap interval.

    Pooling weighs a task by its number of seeds, as rliable's IQM of the [runs x tasks] score matrix does.
    """
    return stratified_bootstrap(_pooled_iqm, scores, reps, confidence, seed)


def _improvement(x: dict[str, np.ndarray], y: dict[str, np.ndarray]) -> float:
    """Mean over tasks of the Mann-Whitney P(a run of X beats a run of Y), ties counting half."""
    per_task = [np.mean((x[t][:, None] > y[t][None, :]) + 0.5 * (x[t][:, None] == y[t][None, :])) for t in x]
    return float(np.mean(per_task))


def probability_of_improvement(x: Scores, y: Scores, reps: int = 2000, confidence: float = 0.95,
                               seed: int = 0) -> Estimate:
    """P(X > Y): per task, the probability that a random run of X beats a random run of Y, averaged over tasks.

    Per task it is the Mann-Whitney statistic: the mean over all (x, y) pairs of 1[x > y] + 0.5 * 1[x == y].
    Both must hold the same tasks (ValueError naming any missing from either). The interval is a stratified
    bootstrap resampling X's and Y's seeds independently within each task.
    """
    _check_reps(reps)
    _check_confidence(confidence)
    xs, ys = _check_scores(x, "x"), _check_scores(y, "y")
    if xs.keys() != ys.keys():
        only_x, only_y = sorted(xs.keys() - ys.keys()), sorted(ys.keys() - xs.keys())
        raise ValueError(f"x and y must hold the same tasks: missing from y {only_x}, missing from x {only_y}")
    samples = _bootstrap(_improvement, [xs, ys], reps, seed)
    low, high = _percentiles(samples, confidence)
    return Estimate(_improvement(xs, ys), float(low), float(high))


def performance_profile(scores: Scores, taus: np.ndarray, reps: int = 2000, confidence: float = 0.95,
                        seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The run-score distribution: for each τ in `taus`, the fraction of runs with score > τ.

    Computed as the mean over tasks of each task's fraction, so every task weighs the same. Returns
    (values, lows, highs), each of shape [len(taus)], the bands pointwise from the stratified bootstrap.
    """
    _check_reps(reps)
    _check_confidence(confidence)
    checked = _check_scores(scores)
    thresholds = np.atleast_1d(np.asarray(taus, dtype=float))
    if thresholds.ndim != 1 or thresholds.size == 0 or np.any(np.isnan(thresholds)):
        raise ValueError(f"taus must be a non-empty 1-D array without NaN, got shape {thresholds.shape}")

    def profile(sample: dict[str, np.ndarray]) -> np.ndarray:
        return np.mean([np.mean(v[:, None] > thresholds[None, :], axis=0) for v in sample.values()], axis=0)

    samples = _bootstrap(profile, [checked], reps, seed)
    lows, highs = _percentiles(samples, confidence)
    return profile(checked), lows, highs
