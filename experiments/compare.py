"""Your method against the shipped baselines: `python -m experiments.compare YOURS... [--against results/]`.

    python -m experiments.sweep --preset default --plugins my_weighting --methods action-norm --out runs/mine
    python -m experiments.compare runs/mine                 # against the shipped results/*.json

YOURS are sweep folders (their `results.json`) or results files; `--against` a folder of results files or of
sweep folders, or files. Every method they hold that is not a
reference (BC-SO, BC-OH, Ours at the paper's step setting THR 10% W 5, FCA) is compared with those
references as the comparable files of `--against` (default: the shipped `results/`) record them: the same
task, observation mode, expert, protocol, recipe (its weighting grids aside) and budget (iterations and
evaluation episodes). A file of YOURS with no comparable file there is refused (exit 2, one line naming the
nearest file and the fields in which it differs); so is one that holds nothing but references, and one (or a
matching reference file) that records no expert references to give % of expert by (a `--dataset` sweep whose
dataset gave none), with how to add them.

Printed, and written to `--out` (default: the first of YOURS that is a folder, else the current one) as
`compare.md` and `compare-profile.png`:

- per task, every method's return (mean ± sample sd over seeds, % of expert with its t-interval), and each
  of yours minus each reference with a 95% Welch t-interval over seeds and a verdict;
- across tasks (`experiments.stats`), each method's interquartile mean of % of expert with a stratified
  bootstrap interval, the probability that it improves on BC-OH, and the performance profile (the fraction of
  runs above each score) as a figure.

Your methods are your files' best setting of each (by % of expert, so optimistic, as the report's best rows
are); the references are the shipped files' (a method in both: the shipped one). Seeds are independent
runs, few per task: Welch's interval holds its 95% at 3–8 seeds in simulation (docs/reliability.md), but
with 3 seeds an interval is wide, and one that only just excludes 0 is a hint.
"""

from __future__ import annotations

import dataclasses
import pathlib
import sys
from collections.abc import Sequence

import numpy as np

from ape_jax.pipeline.rundir import RunDir
from experiments._cli import Parser, fail, unwritable
from experiments.report import analysis
from experiments import stats
from experiments.report.paper import PAPER_STEP_LABEL

SHIPPED = pathlib.Path(__file__).resolve().parent.parent / "results"   # the committed results files
REFERENCES = ("bc-so", "bc-oh", "ours-step", "fca")
REFERENCE_LABELS = {"bc-so": "BC-SO", "bc-oh": "BC-OH", "ours-step": PAPER_STEP_LABEL, "fca": "FCA"}
# the settings that may differ between comparable files: which configurations ran, how many seeds, and amounts
# that do not change what a configuration computes (chunking, the diagnostics, the width: statistically alike)
FREE = {"recipe": {"name"}, "knobs": None,   # None: the whole section (the methods' own settings)
        "budget": {"seeds", "chunk", "probe_steps", "eval_at", "width"},
        "protocol": {"doc"}}
PROFILE_TAUS = np.linspace(0.0, 1.25, 126)  # fractions of the expert's return (normalised scores)


class CompareError(ValueError):
    """Files that cannot be compared (one line)."""


@dataclasses.dataclass(frozen=True)
class Arm:
    """One method on one task: its label and per-seed % of expert (and returns)."""

    method: str
    label: str
    pct: np.ndarray
    returns: np.ndarray
    hparams: dict
    yours: bool


def comparable_fields(res: analysis.Source) -> dict[str, object]:
    """What must agree between your file and a reference file: `{"section.field": value}`."""
    out: dict[str, object] = {"env": res.env, "obs": res.obs, "expert": res.expert.get("return_mean")}
    for section, values in res.records().to_json().items():
        if section in FREE and FREE[section] is None:
            continue
        out.update({f"{section}.{k}": v for k, v in values.items() if k not in FREE.get(section, ())})
    return out


def differing(a: analysis.Source, b: analysis.Source) -> list[str]:
    """The fields in which `b` (a reference file) differs from `a` (yours), as `field (b's there, a's here)`."""
    fa, fb = comparable_fields(a), comparable_fields(b)
    return [f"{k} ({fb.get(k)!r} there, {fa.get(k)!r} here)" for k in fa if fa.get(k) != fb.get(k)]


def _load_all(paths: Sequence[str], what: str) -> list[analysis.Source]:
    files = []
    for p in map(pathlib.Path, paths):
        if p.is_dir():
            # a sweep folder; else a folder of results files (the shipped results/) or of sweep folders
            found = ([RunDir(p).results] if RunDir(p).results.exists()
                     else sorted(p.glob("*.json")) + sorted(p.glob(f"*/{RunDir.RESULTS}")))
            if not found:
                raise CompareError(f"{what} {p}: a folder with no results.json, *.json or */results.json")
        elif p.exists():
            found = [p]
        else:
            raise CompareError(f"{what} {p}: no such file or folder")
        files += [analysis.load(f) for f in found]
    return files


def match(yours: analysis.Source, against: Sequence[analysis.Source]) -> list[analysis.Source]:
    """The files of `against` comparable with `yours`; `CompareError` naming the nearest file's differences."""
    if not against:
        raise CompareError(f"{yours.path}: no reference results to compare with")
    diffs = [(r, differing(yours, r)) for r in against]
    same = [r for r, diff in diffs if not diff]
    if same:
        return same
    nearest, diff = min(diffs, key=lambda rd: len(rd[1]))
    raise CompareError(f"{yours.path}: no reference file matches its settings; the nearest, {nearest.path}, differs "
                       f"in {'; '.join(diff[:4])}{' …' if len(diff) > 4 else ''}")


def _arm(m: analysis.Group, row: dict | None, label: str, yours: bool) -> Arm | None:
    if row is None:
        return None
    pct = analysis.seed_values(m, row, "normalized")
    if not pct:
        return None
    return Arm(row["method"], label, np.asarray(pct, float), np.asarray(analysis.seed_values(m, row), float),
               row["hparams"], yours)


def task_arms(yours: Sequence[analysis.Source], references: Sequence[analysis.Source]) -> list[Arm]:
    """One task's arms: each method of `yours` that is not a reference (its best setting), then the references
    as `references` hold them."""
    mine = analysis.merge(yours)
    ref = analysis.merge(references)
    (m,), (r,) = mine.values(), ref.values()  # `match` made each one group
    known = {**r.methods, **m.methods}
    arms = []
    for method in dict.fromkeys(row["method"] for row in m.summary):
        if method in REFERENCES:  # the reference files' own stand
            continue
        arm = _arm(m, analysis.best_of(analysis.method_rows(m, method)), analysis.label(known, method), True)
        if arm is not None:
            arms.append(arm)
    for method in REFERENCES:
        row = (analysis.paper_step_row(r) if method == "ours-step"
               else analysis.best_of(analysis.method_rows(r, method)))
        arm = _arm(r, row, REFERENCE_LABELS[method], False)
        if arm is not None:
            arms.append(arm)
    return arms


def compare(yours: Sequence[analysis.Source], against: Sequence[analysis.Source]) -> dict[str, list[Arm]]:
    """`{task: arms}` for every task of `yours` (`CompareError` if a file has no comparable reference or no
    method of its own)."""
    by_task: dict[str, list[analysis.Source]] = {}
    refs: dict[str, list[analysis.Source]] = {}
    for y in yours:
        analysis.check_references(y)   # every table here is in % of expert: none silently without it
        if not [row for row in y.summary if row["method"] not in REFERENCES]:
            ran = ", ".join(dict.fromkeys(row["method"] for row in y.summary))   # its own, not every reference's
            raise CompareError(f"{y.path}: holds only reference methods ({ran}): nothing of yours to compare "
                               "(train a method of your own beside them)")
        matched = match(y, against)
        for r in matched:
            analysis.check_references(r)
        key = y.env
        if key in refs and {id(r) for r in refs[key]} != {id(r) for r in matched}:
            raise CompareError(f"{y.path}: another file of yours on {y.env} has other settings; compare one "
                               "setting per task")
        by_task.setdefault(key, []).append(y)
        refs[key] = matched
    return {task: task_arms(files, refs[task]) for task, files in by_task.items()}


def _fmt_pct(e: stats.Estimate) -> str:
    return f"{e.value:.1f} [{e.low:.1f}, {e.high:.1f}]"


def markdown(result: dict[str, list[Arm]], reps: int = 2000) -> str:
    """The comparison as markdown: a table per task, then the across-task statistics."""
    out = ["# Your methods against the references", ""]
    for task, arms in result.items():
        out += [f"## {task}", "", "| method | setting | seeds | return | % of expert [95% CI] |",
                "|---|---|---:|---:|---:|"]
        for a in arms:
            mean, low, high = analysis.mean_estimate(a.pct)
            sd = stats.sample_sd(a.returns)
            setting = ", ".join(f"{k} {v:g}" for k, v in a.hparams.items()) or "–"
            out.append(f"| {a.label}{' (yours)' if a.yours else ''} | {setting} | {len(a.pct)} | "
                       f"{a.returns.mean():,.0f}{' (1 seed)' if sd is None else f' ± {sd:,.0f}'} | "
                       f"{mean:.1f} [{low:.1f}, {high:.1f}] |")
        out += ["", "| yours − reference (% of expert points) | difference [95% CI] | verdict |", "|---|---:|---|"]
        for a in (a for a in arms if a.yours):
            for b in (b for b in arms if not b.yours):
                ci = analysis.mean_difference(a.pct, b.pct)
                out.append(f"| {a.label} − {b.label} | {ci.diff:+.1f} [{ci.low:+.1f}, {ci.high:+.1f}] | "
                           f"{analysis.verdict(ci, a.label, b.label)} |")
        out.append("")
    methods = _methods(result)
    out += ["## Across tasks", "",
            f"Tasks: {', '.join(result)}. Scores are % of expert; the intervals resample seeds within each task "
            f"(stratified bootstrap, {reps:,} resamples). IQM: the mean of the middle half of all runs' scores. "
            "P(improves on BC-OH): the chance that a random run of the method beats a random run of BC-OH on the "
            "same task, averaged over tasks.", "",
            "| method | tasks | IQM % of expert [95% CI] | P(improves on BC-OH) [95% CI] |", "|---|---:|---:|---:|"]
    for label, scores in methods.items():
        iqm = stats.iqm_across_tasks(scores, reps=reps)
        bcoh = methods.get("BC-OH")
        shared = {t: v for t, v in scores.items() if bcoh and t in bcoh}
        if label == "BC-OH" or not shared:
            poi = "–"
        else:
            p = stats.probability_of_improvement(shared, {t: bcoh[t] for t in shared}, reps=reps)
            poi = f"{p.value:.2f} [{p.low:.2f}, {p.high:.2f}]"
        out.append(f"| {label} | {len(scores)} | {_fmt_pct(iqm)} | {poi} |")
    return "\n".join(out) + "\n"


def _methods(result: dict[str, list[Arm]]) -> dict[str, dict[str, np.ndarray]]:
    """`{label: {task: per-seed % of expert}}`, yours first."""
    out: dict[str, dict[str, np.ndarray]] = {}
    for yours in (True, False):
        for task, arms in result.items():
            for a in arms:
                if a.yours == yours:
                    out.setdefault(a.label + (" (yours)" if yours else ""), {})[task] = a.pct
    return out


def profile_figure(result: dict[str, list[Arm]], reps: int = 2000):
    """The performance profile: per method, the fraction of runs above each % of expert, with its band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for label, scores in _methods(result).items():
        values, lows, highs = stats.performance_profile({t: v / 100.0 for t, v in scores.items()}, PROFILE_TAUS,
                                                        reps=reps)
        line, = ax.plot(100 * PROFILE_TAUS, values, label=label, lw=2 if "(yours)" in label else 1.2)
        ax.fill_between(100 * PROFILE_TAUS, lows, highs, color=line.get_color(), alpha=0.15)
    ax.set_xlabel("% of expert (τ)")
    ax.set_ylabel("fraction of runs with score > τ")
    ax.set_title(f"Performance profile over {', '.join(result)}")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def main(argv: Sequence[str] | None = None) -> int:
    p = Parser(prog="python -m experiments.compare", description=__doc__.splitlines()[0])
    p.add_argument("yours", nargs="+", help="your sweep folders (their results.json) or results files")
    p.add_argument("--against", default=str(SHIPPED),
                   help="folder or files of reference results (default: the shipped results/, from any folder)")
    p.add_argument("--out", default=None, help="folder for compare.md and compare-profile.png (default: the first "
                                               "of YOURS that is a folder, else the current folder)")
    p.add_argument("--resamples", type=int, default=2000, help="bootstrap resamples (default 2000)")
    args = p.parse_args(argv)
    if args.resamples < 1:
        fail(p, f"--resamples must be >= 1, got {args.resamples}")
    out = pathlib.Path(args.out) if args.out else next((pathlib.Path(y) for y in args.yours
                                                         if pathlib.Path(y).is_dir()), pathlib.Path("."))
    problem = unwritable(out)
    if problem:
        fail(p, f"--out {out}: {problem}")
    try:
        yours = _load_all(args.yours, "YOURS")
        against = [r for r in _load_all([args.against], "--against")
                   if not any(pathlib.Path(r.path).resolve() == pathlib.Path(y.path).resolve() for y in yours)]
        result = compare(yours, against)
    except (CompareError, analysis.ReportError) as e:
        fail(p, str(e))
    text = markdown(result, args.resamples)
    out.mkdir(parents=True, exist_ok=True)
    from experiments.report.figures import save_png

    save_png(profile_figure(result, args.resamples), out / "compare-profile.png")
    tmp = out / ".compare.md.tmp"
    tmp.write_text(text + "\n![performance profile](compare-profile.png)\n")
    tmp.replace(out / "compare.md")
    print(text)
    print(f"wrote {out / 'compare.md'} and {out / 'compare-profile.png'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
