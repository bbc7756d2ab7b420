"""The shipped reference beside a short sweep's table: what `results/` holds for the same task and setting at
longer budgets, so a first table at the `quick` budget is read against the answer, not as one.

A quick sweep trains 1% of the paper's iterations with one seed. Its ordering can be the opposite of the published
one (Hopper: BC-OH below BC-SO at 3k, far above it at 30k and 300k), and a 1-seed row has no interval.
`reference_lines` finds the committed files of the same task, observation, protocol, expert, labels and recipe
(its own budget or longer, any seeds or weighting grid: `experiments.compare`'s comparable fields with the budget
left free), and prints their BC-SO, BC-OH and Ours (step, THR 10% W 5) per budget, in % of expert with 95%
t-intervals, beside this run's, with one line on what this budget can and cannot show. A task judged by a rate
(ToyTown's success) gets `rate_lines`: what the rate means, and the shipped tables of its protocol per observation
mode and task version, with BC-full and a plain word where their policies crash or stand still. `next_steps` are
the commands that end a sweep's output: the report of its folder, and `experiments.compare` where a shipped file
lets it rank the sweep.
"""

from __future__ import annotations

import functools
import pathlib
import shlex
import sys

ARMS = (("bc-so", "BC-SO"), ("bc-oh", "BC-OH"), ("ours-step", "Ours (step, THR 10% W 5)"))


def reference_lines(results_path: str | pathlib.Path, shipped: pathlib.Path | None = None) -> list[str]:
    """The printed block: the shipped files' rows per budget above this run's, and the reading; [] where no
    shipped file shares this run's setting at its budget or a longer one, or this run is a smoke run. A run that
    trained none of the references gets the shipped rows and a line naming its own methods (no row of dashes).

    Args:
      results_path: the sweep's `results.json`.
      shipped: the folder of committed results files; None: the repository's `results/` (`compare.SHIPPED`).
    """
    from experiments.compare import SHIPPED, comparable_fields
    from experiments.report import analysis

    if _smoke(results_path):
        return []
    mine = analysis.load(results_path)
    if analysis.main_metric(mine) != "return":   # a rate (ToyTown's success): its own block
        return rate_lines(mine, _shipped(shipped or SHIPPED))
    want = _setting(comparable_fields(mine))
    iterations = mine.config["iterations"]
    by_budget: dict[int, list] = {}
    for other in _shipped(shipped or SHIPPED):
        if (other.config["iterations"] >= iterations and _setting(comparable_fields(other)) == want
                and not _same_file(other, mine)
                and {"bc-so", "bc-oh"} & {r["method"] for r in other.summary}):
            by_budget.setdefault(other.config["iterations"], []).append(other)
    if not by_budget:
        return []
    rows = [(n, _arms(analysis, files)) for n, files in sorted(by_budget.items())]
    here = _arms(analysis, [mine])
    width = 22
    lines = [f"shipped reference: {_describe(mine)} in results/ (% of expert, mean [95% t-interval] over seeds)",
             f"  {'iterations':>10} {'seeds':>5}  " + "  ".join(f"{label:<{width}}" for _, label in ARMS)]
    for n, arms in rows:
        lines.append(f"  {n:>10,} {_seeds(arms):>5}  " + "  ".join(f"{_cell(arms.get(m)):<{width}}" for m, _ in ARMS))
    if here:
        lines.append(f"  {iterations:>10,} {_seeds(here):>5}  " + "  ".join(f"{_cell(here.get(m)):<{width}}"
                                                                           for m, _ in ARMS) + "  <- this run")
    else:
        ran = ", ".join(dict.fromkeys(row["method"] for row in mine.summary))
        lines.append(f"  this run trained none of these ({ran}): `python -m experiments.compare` ranks it against "
                     "them where its budget is a shipped one")
    files = sorted({pathlib.Path(f.path).name for f in by_budget[rows[-1][0]]})
    lines.append(_reading(iterations, here, rows) + f" ({', '.join('results/' + f for f in files)})")
    return [line.rstrip() for line in lines]


RATE_ARMS = (*ARMS, ("bc-full", "BC-full"))
WORDS = {"success": "the route completed in time without a collision"}   # what a rate metric means, where known


def rate_lines(mine, shipped: tuple) -> list[str]:
    """The block for a task judged by a rate (ToyTown's success): what the rate means, then the shipped tables of
    this task and protocol, each observation mode and task version apart (the camera's, the one-frame state's),
    BC-SO, BC-OH, Ours (step, THR 10% W 5) and BC-full (the ceiling) in % of episodes with 95% t-intervals, this
    run beside them, and a reading that says plainly where the shipped policies crash or stand still. [] where
    nothing shipped shares the task and protocol."""
    from experiments.report import analysis

    metric, name = analysis.main_metric(mine), (mine.protocol or {}).get("name")
    tables: dict[tuple, list] = {}
    for other in shipped:
        p = other.protocol or {}
        if (other.env == mine.env and p.get("name") == name and (p.get("history_stride") or 1) == 1
                and {"bc-so", "bc-oh"} & {r["method"] for r in other.summary} and not _same_file(other, mine)):
            tables.setdefault((_seen(other), p.get("task_version"), other.config["iterations"]), []).append(other)
    if not tables:
        return []
    width = 20
    lines = [f"shipped reference: {mine.env}, protocol {name}, in results/ ({metric}"
             + (f": {WORDS[metric]}" if metric in WORDS else "") + "; % of episodes, mean [95% t-interval] over seeds)",
             f"  {'observations':<13} {'version':>7} {'iterations':>10} {'seeds':>5}  "
             + "  ".join(f"{label:<{width}}" for _, label in RATE_ARMS)]
    crashing = []
    for (obs, version, iterations), files in sorted(tables.items(), key=lambda kv: (kv[0][0] != _seen(mine), kv[0])):
        arms, crash = _rate_arms(analysis, files, metric)
        lines.append(f"  {obs:<13} {version or '-':>7} {iterations:>10,} {_seeds(arms):>5}  "
                     + "  ".join(f"{_cell(arms.get(m)):<{width}}" for m, _ in RATE_ARMS))
        if crash:
            crashing.append(f"the shipped {obs} policies (version {version}) {crash}")
    here, _ = _rate_arms(analysis, [mine], metric)
    version = (mine.protocol or {}).get("task_version")
    lines.append(f"  {_seen(mine):<13} {version or '-':>7} {mine.config['iterations']:>10,} {_seeds(here):>5}  "
                 + "  ".join(f"{_cell(here.get(m)):<{width}}" for m, _ in RATE_ARMS) + "  <- this run")
    budget = max(it for _, _, it in tables)
    words = (f"  reading: {mine.config['iterations']:,} of the {budget:,} iterations the tables were read at"
             if mine.config["iterations"] < budget else "  reading: the tables' budget")
    if _seeds(here) == "1":
        words += ", one seed: it checks that the pipeline runs end to end and cannot rank methods"
    lines.append(words + "".join(f"; {c}" for c in crashing))
    return [line.rstrip() for line in lines]


def _seen(res) -> str:
    """What a file's policies observed, as the block names it: its observation mode, `image+encoder` for frames seen
    through a perception encoder (`recipe.perception_sha256`)."""
    recipe = (res.settings or {}).get("recipe") or {}
    if not recipe.get("perception_sha256"):
        return res.obs
    return f"{res.obs}+encoder" + ("" if recipe.get("perception_output", "embedding") == "embedding" else "-r")


def _rate_arms(analysis, files, metric: str) -> tuple[dict[str, list[float]], str | None]:
    """Per-seed rates (%) of `RATE_ARMS` in `files` (one table), and how BC-SO, BC-OH and Ours fail where every seed
    of theirs ends most episodes so (`"crash in 90-100% of episodes"`, `"stand still in ..."`), else None."""
    out, crashes, stuck = {}, [], []
    for m in analysis.merge(files).values():
        for method, _ in RATE_ARMS:
            row = (analysis.paper_step_row(m) if method == "ours-step"
                   else analysis.best_of(analysis.method_rows(m, method)))
            values = analysis.seed_values(m, row, metric)
            if values:
                out[method] = [100 * float(v) for v in values]
            if method != "bc-full" and row is not None:
                crashes += analysis.seed_values(m, row, "collisions")
                stuck += analysis.seed_values(m, row, "stuck")
    either = [c + s for c, s in zip(crashes, stuck)]
    for values, verb in ((crashes, "crash in"), (stuck, "stand still in"), (either, "crash or stand still in")):
        if values and min(values) >= 0.5:
            return out, f"{verb} {100 * min(values):.0f}-{100 * min(max(values), 1.0):.0f}% of episodes"
    return out, None


def _same_file(a, b) -> bool:
    """Whether two loaded results are one file (a shipped file given as the run itself)."""
    pa, pb = getattr(a, "path", None), getattr(b, "path", None)
    return pa is not None and pb is not None and pathlib.Path(pa).resolve() == pathlib.Path(pb).resolve()


def comparable(results_path: str | pathlib.Path, shipped: pathlib.Path | None = None) -> bool:
    """Whether `python -m experiments.compare` can rank the sweep of `results_path` against `shipped`: a file there
    shares its task, setting and budget, and it holds a method that is not a reference (`compare.match`)."""
    from experiments.compare import REFERENCES, SHIPPED, CompareError, match
    from experiments.report import analysis

    if _smoke(results_path):
        return False
    mine = analysis.load(results_path)
    if not [r for r in mine.summary if r["method"] not in REFERENCES]:
        return False
    try:
        match(mine, _shipped(shipped or SHIPPED))
    except CompareError:
        return False
    return True


def _smoke(results_path: str | pathlib.Path) -> bool:
    """Whether the file is a `--smoke` run's (which the report's loader refuses: nothing to set beside it)."""
    from ape_jax.pipeline import results

    return bool(results.load(results_path).config.get("smoke"))


@functools.lru_cache(maxsize=2)
def _shipped(folder: pathlib.Path) -> tuple:
    """The readable results files of `folder`, loaded once per process (an unreadable one is the report's to
    refuse, not a sweep's end)."""
    from experiments.report import analysis

    out = []
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else ():
        try:
            out.append(analysis.load(path))
        except (analysis.ReportError, ValueError, OSError):
            continue
    return tuple(out)


def _setting(fields: dict) -> dict:
    """The comparable fields without the budget's: the same experiment at any length, seeds or evaluation size."""
    return {k: v for k, v in fields.items() if not k.startswith("budget.")}


def _arms(analysis, files) -> dict[str, list[float]]:
    """Per-seed % of expert of BC-SO, BC-OH and Ours at the paper's step setting in `files` (one setting)."""
    out = {}
    for m in analysis.merge(files).values():
        for method, _ in ARMS:
            row = (analysis.paper_step_row(m) if method == "ours-step"
                   else analysis.best_of(analysis.method_rows(m, method)))
            values = analysis.seed_values(m, row, "normalized")
            if values:
                out[method] = [float(v) for v in values]
    return out


def _cell(values: list[float] | None) -> str:
    from experiments.report.analysis import mean_estimate

    if not values:
        return "-"
    mean, low, high = mean_estimate(values)
    return f"{mean:.1f}" + (f" [{low:.1f}, {high:.1f}]" if len(values) > 1 else " (1 seed)")


def _seeds(arms: dict[str, list[float]]) -> str:
    counts = sorted({len(v) for v in arms.values()})
    return "-" if not counts else "/".join(map(str, counts))


def _describe(res) -> str:
    p = res.protocol or {}
    expert = p.get("expert") or "the shipped expert"
    return (f"{res.env} ({res.obs}), protocol {p.get('name', 'brax')}, recipe {res.records().recipe.name}, "
            f"{expert}, {p.get('labels', 'clipped')} labels")


def _reading(iterations: int, here: dict, rows: list[tuple[int, dict]]) -> str:
    """One line: what this budget can show, and whether its BC-OH-vs-BC-SO order is the longest budget's."""
    longest, arms = rows[-1]
    words = (f"  reading: {iterations:,} of the {longest:,} iterations the answer is read at" if iterations < longest
             else f"  reading: the budget the shipped answer is read at ({longest:,} iterations)")
    if _seeds(here) == "1":
        words += ", one seed: it checks that the pipeline runs end to end and cannot rank methods"
    if "bc-so" in here and "bc-oh" in here and "bc-so" in arms and "bc-oh" in arms:
        mean = {k: sum(v) / len(v) for k, v in (("so", here["bc-so"]), ("oh", here["bc-oh"]),
                                                   ("so_ref", arms["bc-so"]), ("oh_ref", arms["bc-oh"]))}
        if (mean["oh"] > mean["so"]) != (mean["oh_ref"] > mean["so_ref"]):
            return (words + f"; here BC-OH is {'above' if mean['oh'] > mean['so'] else 'below'} BC-SO, at "
                    f"{longest:,} iterations it is {'above' if mean['oh_ref'] > mean['so_ref'] else 'below'}")
        return words + f"; BC-OH against BC-SO goes the same way as at {longest:,} iterations"
    return words


def typed_python() -> str:
    """The interpreter as a user types it from here: this one's path relative to the working directory where it
    lies inside it (the README's `.venv/bin/python`: a bare `python` in a fresh shell has no jax), else `python`
    (an activated or system environment)."""
    try:
        rel = pathlib.Path(sys.executable).relative_to(pathlib.Path.cwd())
    except ValueError:
        return "python"
    return shlex.quote(str(rel))


def next_steps(out: pathlib.Path, smoke: bool = False) -> list[str]:
    """The lines that end a sweep: the commands that report what it wrote in `out`, and compare it where a shipped
    file of the same setting and budget lets `experiments.compare` rank it (else why not, as a comment)."""
    if smoke:
        return ["next: the same command without --smoke (a smoke run's numbers mean nothing, and the report and "
                "compare refuse them)"]
    from ape_jax.pipeline.rundir import RunDir

    q, py = shlex.quote, typed_python()
    report = (f"  {py} -m experiments.report {q(str(RunDir(out).results))} --out {q(str(out / 'report.md'))}"
              f"   # tables and figures ({out / 'figures'}/)")
    if comparable(RunDir(out).results):
        return ["next:", report, f"  {py} -m experiments.compare {q(str(out))}   # against the shipped results/ "
                                 "of the same task, protocol, recipe and budget"]
    return ["next:", report, "  # experiments.compare ranks a sweep against a shipped file of its setting and budget "
                             "(e.g. --preset default) with a method of its own beside the references; none here"]
