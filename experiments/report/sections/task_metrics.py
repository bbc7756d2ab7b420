"""The task-metric tables (the supplement's Table 4 protocol): a task's own per-episode metrics per policy and the
rate's Wilson interval over every episode."""

from __future__ import annotations

from ape_jax import tasks
from experiments import stats
from experiments.report.analysis import (Group, Key, mean_estimate, group_title, is_rate, ordered, per_seed,
                                         task_metric_rows)
from experiments.report.sections.common import Context, Section, plus_minus, table


# How the task-metrics table heads a task's own metrics, and the factor it shows them at (rates in %); a metric
# not listed is headed by its name, and a task's main metric (a rate) is shown in %.
METRIC_HEADINGS = {"red_light_violations": ("red-light violations", 1.0), "avg_speed": ("average speed", 1.0),
                   "stuck": ("stuck %", 100.0)}


def _metric_heading(m: Group, metric: str) -> tuple[str, float]:
    if metric in METRIC_HEADINGS:
        return METRIC_HEADINGS[metric]
    return (f"{metric} %", 100.0) if metric == m.metric and is_rate(m) else (metric.replace("_", " "), 1.0)


def task_table(m: Group) -> str | None:
    """A task's own per-episode metrics (its `metrics`; the supplement's Table 4 protocol): BC-SO, BC-OH and Ours
    (THR 10%, W 5), every metric as mean ± sd over seeds (of each seed's episode mean) with the mean's 95%
    t-interval over seeds (a share of episodes' clipped to [0, 100]), and beside them the paper's main metric where
    the task records it (`Task.paper`). None for a task without metrics."""
    metrics = m.task_metrics
    rows = task_metric_rows(m)
    if not metrics or not rows:
        return None
    paper = tasks.get(m.env).paper
    heads = [_metric_heading(m, k) for k in metrics]

    def cell(v, scale: float) -> str:
        if not len(v):
            return "—"
        _, low, high = mean_estimate(v)
        if scale == 100.0:  # a share of episodes, in %: its mean lies in [0, 100], and so may its interval
            low, high = max(low, 0.0), min(high, 100.0)
        return f"{plus_minus(v.mean(), stats.sample_sd(v), '.2f')} [{low:.2f}, {high:.2f}]"

    return table(["method", "seeds", *(name for name, _ in heads),
                  *([f"{m.metric} % of all episodes [Wilson 95%]"] if is_rate(m) else []),
                  *([f"paper: {m.metric}" + (" %" if is_rate(m) else "")] if paper else [])],
                 [[lab, str(len(runs)),
                   *(cell(per_seed(runs, key, scale), scale) for key, (_, scale) in zip(metrics, heads)),
                   *([wilson_cell(runs, m.metric)] if is_rate(m) else []),
                   *([f"{paper[method][0]} ± {paper[method][1]}" if method in paper else "—"] if paper else [])]
                  for lab, method, runs in rows])


def wilson_cell(runs: list[dict], metric: str) -> str:
    """A rate over every evaluation episode of `runs` pooled, with Wilson's binomial interval (episodes as
    independent trials: it says how precisely the episodes measure the rate, the t-interval over seeds how much
    it varies between trained policies)."""
    counted = [(r["eval"][metric], int(r["eval"]["episodes"])) for r in runs
               if metric in r["eval"] and r["eval"].get("episodes")]
    if not counted:
        return "—"
    e = stats.wilson(sum(round(rate * n) for rate, n in counted), sum(n for _, n in counted))
    return f"{100 * e.value:.2f} [{100 * e.low:.2f}, {100 * e.high:.2f}]"


def task_metric_sections(ctx: Context, key: Key | None = None) -> list[Section]:
    """Per group whose task records metrics of its own (`task_table`), in report order (only `key`'s, if given)."""
    out = []
    for k, m in ordered(ctx.merged):
        if (key is not None and k != key) or not (found := task_table(m)):
            continue
        task = tasks.get(k.env)
        title = group_title(k, m.protocol, m.shows_protocol, with_obs=k.obs != task.default_obs)
        out.append(Section(f"{title} (the supplement's Table 4 protocol)",
                           f"{task.title}'s own metrics, mean ± sd over seeds [95% t-interval]"
                           + ("; the rate pooled over episodes [Wilson 95%]" if is_rate(m) else "")
                           + ("; the paper's beside (its own task)" if task.paper else "") + ".", [found]))
    return out
