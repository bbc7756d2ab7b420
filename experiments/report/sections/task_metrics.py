"""The task-metric tables: a task's own per-episode metrics per policy and the rate's Wilson interval over every
episode. A task's group under its default protocol reads as the supplement's Table 4 protocol (BC-SO, BC-OH and
Ours); a group of the suite's driving protocols (`analysis.driving_table`: ToyTown under `nocrash` or
`nocrash-nospeed`) as the supplement's Table 1 or 2, with every configuration that ran, its copycat verdicts, the
paper's comparisons in numbers and a figure of success and stuck."""

from __future__ import annotations

from ape_jax import tasks
from experiments import stats
from experiments.report import figures
from experiments.report.analysis import (Comparison, DrivingTable, Group, Key, driving_comparisons, driving_rows,
                                         driving_table, file_stem, group_title, is_rate, mean_estimate, ordered,
                                         per_seed, policy_diagnostics, task_metric_rows)
from experiments.report.sections.common import (WIDE, Context, Section, hparams_text, interval, plus_minus, seeds_cell,
                                                table)


# How the task-metrics table heads a task's own metrics, and the factor it shows them at (rates in %); a metric
# not listed is headed by its name, and a task's main metric (a rate) is shown in %.
METRIC_HEADINGS = {"red_light_violations": ("red-light violations", 1.0), "avg_speed": ("average speed", 1.0),
                   "stuck": ("stuck %", 100.0)}


def _metric_heading(m: Group, metric: str) -> tuple[str, float]:
    if metric in METRIC_HEADINGS:
        return METRIC_HEADINGS[metric]
    return (f"{metric} %", 100.0) if metric == m.metric and is_rate(m) else (metric.replace("_", " "), 1.0)


def _metric_cells(m: Group, runs: list[dict]) -> list[str]:
    """One policy's cells of the task's metrics (mean ± sd over seeds [95% t-interval], a share of episodes clipped
    to [0, 100]; the mean alone at one seed) and, for a rate, the rate over every episode [Wilson 95%]."""
    def cell(v, scale: float) -> str:
        if not len(v):
            return "—"
        _, low, high = mean_estimate(v)
        if scale == 100.0:  # a share of episodes, in %: its mean lies in [0, 100], and so may its interval
            low, high = max(low, 0.0), min(high, 100.0)
        # the seeds column says once that two seeds' intervals are wide (`seeds_cell`)
        return f"{plus_minus(v.mean(), stats.sample_sd(v), '.2f')} {interval(low, high, len(v), '.2f', False)}".rstrip()

    scales = [_metric_heading(m, k)[1] for k in m.task_metrics]
    return [*(cell(per_seed(runs, key, scale), scale) for key, scale in zip(m.task_metrics, scales)),
            *([wilson_cell(runs, m.metric)] if is_rate(m) else [])]


def _metric_heads(m: Group) -> list[str]:
    return [*(_metric_heading(m, k)[0] for k in m.task_metrics),
            *([f"{m.metric} % of all episodes [Wilson 95%]"] if is_rate(m) else [])]


def task_table(m: Group) -> str | None:
    """A task's own per-episode metrics (its `metrics`; the supplement's Table 4 protocol): BC-SO, BC-OH and Ours
    (THR 10%, W 5), every metric as mean ± sd over seeds (of each seed's episode mean) with the mean's 95%
    t-interval over seeds (a share of episodes' clipped to [0, 100]), and beside them the paper's main metric where
    the task records it (`Task.paper`). None for a task without metrics. A driving group: `driving_metric_table`."""
    if driving_table(m) is not None:
        return driving_metric_table(m)
    rows = task_metric_rows(m)
    if not m.task_metrics or not rows:
        return None
    paper = tasks.get(m.env).paper
    return table(["method", "seeds", *_metric_heads(m),
                  *([f"paper: {m.metric}" + (" %" if is_rate(m) else "")] if paper else [])],
                 [[lab, seeds_cell(len(runs)), *_metric_cells(m, runs),
                   *([f"{paper[method][0]} ± {paper[method][1]}" if method in paper else "—"] if paper else [])]
                  for lab, method, runs in rows])


def verdict_cells(runs: list[dict]) -> list[str]:
    """A policy's copycat verdicts over its seeds (`analysis.policy_diagnostics`, the one count): the first verdict's
    seeds judged copycat / seeds diagnosed, and the controlled verdict's likewise; "—" where no seed has it."""
    d = policy_diagnostics(runs)
    return [f"{d.copycats}/{d.read}" if d.read else "—", f"{d.controlled}/{d.judged}" if d.judged else "—"]


# A driving table's key columns, first after the method so that they stay in view where the page is narrower than
# the table (the rest scrolls): the task's main metric, then these of its metrics, then the copycat verdicts.
DRIVING_KEY_METRICS = ("collisions", "stuck")


def driving_metric_table(m: Group) -> str | None:
    """A driving group's table (the supplement's Table 1 or 2): every configuration that ran (`analysis.driving_rows`:
    BC-SO, BC-OH, Ours at the paper's step setting, the baselines in a fixed order, BC-full last). Its columns: the
    method; the key columns, the main metric and `DRIVING_KEY_METRICS` as `task_table` shows them and the copycat
    verdicts (`verdict_cells`); then the hparams, the seeds and the task's other metrics. None for a task without
    metrics or a group without rows."""
    rows = driving_rows(m)
    if not m.task_metrics or not rows:
        return None
    main = [i for i, k in enumerate(m.task_metrics) if k == m.metric]
    key = main + [i for i, k in enumerate(m.task_metrics) if k in DRIVING_KEY_METRICS and k != m.metric]
    heads = _metric_heads(m)
    rest = [i for i in range(len(heads)) if i not in key]
    cells = [_metric_cells(m, r.runs) for r in rows]
    return table(["method", *(heads[i] for i in key), "copycat: first verdict", "copycat: controlled verdict",
                  "hparams", "seeds", *(heads[i] for i in rest)],
                 [[r.label, *(c[i] for i in key), *verdict_cells(r.runs), hparams_text(r.hparams),
                   seeds_cell(len(r.runs)), *(c[i] for i in rest)] for r, c in zip(rows, cells)],
                 "l" + "r" * (len(key) + 2) + "lr" + "r" * len(rest))


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


def _signed(x: float, fmt: str) -> str:
    """`"+12.0"`, `"−3.1"` (a minus sign, not a hyphen)."""
    return f"{x:+{fmt}}".replace("-", "−")


def _plain(x: float, fmt: str) -> str:
    """`"27.1"`, `"−3.1"`."""
    return f"{x:{fmt}}".replace("-", "−")


def comparison_text(c: Comparison) -> str:
    """One comparison in words: `"BC-OH − BC-SO: +12.0 points [−3.1, 27.1]: no difference shown at 5 seeds"`; with
    fewer than 2 seeds in an arm the difference alone, and no verdict."""
    fmt = ".1f" if c.unit == "points" else ".2f"
    unit = " points" if c.unit == "points" else ""
    head = f"{c.a} − {c.b}: {_signed(c.ci.diff, fmt)}{unit}"
    if min(c.ci.n_a, c.ci.n_b) < 2:
        return f"{head}, no verdict (fewer than 2 seeds)"
    seeds = f"{c.ci.n_a} seeds" if c.ci.n_a == c.ci.n_b else f"{c.ci.n_a} and {c.ci.n_b} seeds"
    said = (f"{c.a} higher" if c.ci.low > 0 else f"{c.a} lower" if c.ci.high < 0
            else f"no difference shown at {seeds}")
    wide = WIDE if min(c.ci.n_a, c.ci.n_b) == 2 else ""
    return f"{head} [{_plain(c.ci.low, fmt)}, {_plain(c.ci.high, fmt)}]{wide}: {said}"


def comparisons_line(m: Group) -> list[str]:
    """The paper's comparisons in group `m` (`analysis.driving_comparisons`) as one paragraph, per metric; nothing
    where no comparison has both arms."""
    found = driving_comparisons(m)
    parts = []
    for metric in dict.fromkeys(c.metric for c in found):
        mine = [c for c in found if c.metric == metric]
        what = f"{metric.replace('_', ' ')} per episode" if mine[0].unit == "per episode" else metric
        parts.append(f"{what[0].upper()}{what[1:]}: " + "; ".join(comparison_text(c) for c in mine) + ".")
    if not parts:
        return []
    return ["The paper's comparisons, differences of means over seeds [Welch 95% t-interval]: " + " ".join(parts), ""]


def driving_name(driving: DrivingTable) -> str:
    """How a driving group's heading names its table: "the supplement's Table 1 (NoCrash-Dense, speed in view)"."""
    if driving.number is None:
        return f"the supplement's driving protocol family ({driving.words})"
    return f"the supplement's Table {driving.number} ({driving.words})"


def task_metric_sections(ctx: Context, key: Key | None = None) -> list[Section]:
    """Per group whose task records metrics of its own (`task_table`), in report order (only `key`'s, if given); a
    driving group's with the paper's comparisons and its figure under the table."""
    out = []
    for k, m in ordered(ctx.merged):
        if (key is not None and k != key) or not (found := task_table(m)):
            continue
        task = tasks.get(k.env)
        title = group_title(k, m.protocol, m.shows_protocol, with_obs=k.obs != task.default_obs)
        if (driving := driving_table(m)) is None:
            out.append(Section(f"{title} (the supplement's Table 4 protocol)",
                               f"{task.title}'s own metrics, mean ± sd over seeds [95% t-interval]"
                               + ("; the rate pooled over episodes [Wilson 95%]" if is_rate(m) else "")
                               + ("; the paper's beside (its own task)" if task.paper else "") + ".", [found]))
            continue
        name = driving_name(driving)
        caption = (f"{task.title}'s own metrics for every method that ran, mean ± sd over seeds [95% t-interval]"
                   + ("; the rate pooled over episodes [Wilson 95%]" if is_rate(m) else "")
                   + "; copycat: seeds judged copycat / seeds diagnosed, by the first verdict and by the controlled "
                     "one (their criteria under the group's diagnostics below); BC-full, on the full state, is the "
                     "ceiling.")
        body = [found, *comparisons_line(m),
                *ctx.figure(f"driving-{file_stem(m)}.png", f"{m.title}: {m.metric} and stuck per method",
                            lambda m=m: figures.driving_figure(m))]
        out.append(Section(f"{title}: {name}", caption, body))
    return out
