"""How often a 95% interval over seeds holds the true difference of means: `python tools/coverage.py`.

Simulates two arms of `n` seeds each (n = 3, 5, 8), draws their per-seed scores from a known distribution, and
counts how often each interval for the difference of means contains the true one:

- `percentile`: a percentile bootstrap, each arm's seeds resampled independently (2,000 resamples): what the
  report used before its intervals moved to Welch's;
- `welch`: `experiments.stats.welch_difference`, Welch's t-interval (unequal variances, Satterthwaite's degrees
  of freedom), what the report, `experiments.compare` and the verdicts use.

Two distributions: normal seeds (sd 5 points of % of expert), and seeds that collapse (each seed, with
probability 0.2, scores 40 points below its arm's usual level: the spread seen with FCA's expert). A 95% interval
should cover 95% of the time; at 3 seeds per arm the percentile bootstrap covers far less.
"""

from __future__ import annotations

import sys

import numpy as np

sys.path.insert(0, __file__.rsplit("/tools/", 1)[0])

from experiments import stats  # noqa: E402  (after the path: the repository's, not an installed copy)


def percentile(a: np.ndarray, b: np.ndarray, rng: np.random.Generator, resamples: int = 2000,
               level: float = 0.95) -> tuple[float, float]:
    """The percentile bootstrap interval of `mean(a) − mean(b)`, each arm resampled independently."""
    means = [x[rng.integers(0, x.size, size=(resamples, x.size))].mean(1) for x in (a, b)]
    tail = 100 * (1 - level) / 2
    low, high = np.percentile(means[0] - means[1], [tail, 100 - tail])
    return float(low), float(high)


def draw(rng: np.random.Generator, n: int, kind: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Two arms of `n` seeds and their true difference of means: arm a at 60, arm b at 50 (points of expert)."""
    if kind == "normal":
        return rng.normal(60, 5, n), rng.normal(50, 5, n), 10.0
    collapse = lambda: rng.random(n) < 0.2  # noqa: E731
    a = rng.normal(60, 5, n) - 40 * collapse()
    b = rng.normal(50, 5, n) - 40 * collapse()
    return a, b, (60 - 0.2 * 40) - (50 - 0.2 * 40)


def coverage(n: int, kind: str, trials: int = 2000, seed: int = 0) -> dict[str, float]:
    """The share of `trials` simulated pairs of arms whose interval holds the true difference, per interval."""
    rng = np.random.default_rng(seed)
    hits = {"percentile": 0, "welch": 0}
    for _ in range(trials):
        a, b, truth = draw(rng, n, kind)
        low, high = percentile(a, b, rng)
        hits["percentile"] += low <= truth <= high
        e = stats.welch_difference(a, b)
        hits["welch"] += e.low <= truth <= e.high
    return {k: v / trials for k, v in hits.items()}


def main() -> int:
    print("seeds per arm | distribution | percentile bootstrap | Welch t (experiments.stats)")
    for kind in ("normal", "collapsing"):
        for n in (3, 5, 8):
            c = coverage(n, kind)
            print(f"{n} | {kind} | {c['percentile']:.3f} | {c['welch']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
