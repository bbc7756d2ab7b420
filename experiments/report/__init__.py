"""Tables and figures for BENCHMARKS.md: `python -m experiments.report RESULTS... [--out BENCHMARKS.md] [--figures DIR]`.

Reads `results.json` files written by `experiments.sweep` (several per
environment are merged, e.g. the main grid and a `--methods baselines` run),
and prints, or with `--out` writes into the file's `report` section:

- the MuJoCo-State table: every method per environment as return mean ± std
  over seeds and as a percentage of our expert (normalised against a random
  policy), with the supplement's Table 5 beside it, compared as each method's
  ratio to BC-OH within its own source (the paper does not give its experts'
  returns, so fractions of *its* expert cannot be computed);
- per environment, the full grid (every configuration), the loss analysis
  (the paper's Table 3) and where each number came from (command, preset,
  seeds, commit, machine);
- Ours − BC-OH per environment with a 95% bootstrap confidence interval over
  seeds (the paper's step setting, and the best step and softmax settings,
  which are selected after the fact and so optimistic), with a verdict;
- figures (PNG): per environment the grid search as heatmaps (step THR × W,
  softmax τ) with a sentence on whether the paper's choices are near the best,
  and one figure of every method's return per environment (`returns.png`).

Figures go to `--figures DIR`, by default the folder `figures/` next to `--out`
(`BENCHMARKS.md` → `figures/grid-hopper.png`), and are linked with paths
relative to `--out`; printed to stdout without `--figures`, the report draws
none and says so. PNGs are written atomically, before the report section.

No number in these tables is typed by hand; regenerate them after every sweep.

A results file that cannot be read, is not JSON, or lacks a field the tables
use (or has it with the wrong type), and an `--out` that cannot be written, are
refused with one line on stderr and exit status 2; `--out` is then left as it was
(so is `--figures`: a folder that cannot be written is refused before anything is drawn).
"""

from __future__ import annotations

import json
import math
import os
import pathlib
import sys
from typing import NamedTuple, Sequence

import numpy as np

from experiments._cli import Parser, fail, unwritable, unwritable_file

# The supplement's Table 5 (MuJoCo-State; its own experts, 300k iterations): mean returns.
PAPER_TABLE5 = {
    "bc-so": {"hopper": 275, "halfcheetah": -38, "walker2d": 363},
    "bc-oh": {"hopper": 293, "halfcheetah": 820, "walker2d": 592},
    "fca": {"hopper": 1086, "halfcheetah": 1250, "walker2d": 1296},
    "ours": {"hopper": 641, "halfcheetah": 1023, "walker2d": 1460},
}
MUJOCO = ("hopper", "halfcheetah", "walker2d")
TITLES = {"hopper": "Hopper", "halfcheetah": "HalfCheetah", "walker2d": "Walker2d", "toycar": "ToyCar"}
PAPER_STEP = {"thr": 0.1, "w": 5.0}  # the setting the paper reports for its step weighting
PAPER_TAU = {"hopper": 0.2, "walker2d": 0.2, "halfcheetah": 0.1}  # the paper's softmax τ per environment
BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED = 10_000, 0
LABELS = {"bc-so": "BC-SO", "bc-oh": "BC-OH", "bcpd": "BCPD", "actfreq": "ActFreq", "kmeans": "k-means",
          "boosting": "Boosting", "history-dropout": "HistoryDropout", "fca": "FCA", "dagger": "DAgger (online)"}
REQUIRED = ("schema", "env", "obs", "preset", "config", "expert", "runs", "summary", "system")


class ReportError(ValueError):
    """A results file that cannot be read or merged."""


def load(path: pathlib.Path) -> dict:
    try:
        results = json.loads(pathlib.Path(path).read_text())
    except (OSError, UnicodeDecodeError) as e:
        raise ReportError(f"{path}: cannot read ({e})") from None
    except json.JSONDecodeError as e:
        raise ReportError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from None
    missing = [k for k in REQUIRED if k not in results] if isinstance(results, dict) else list(REQUIRED)
    if missing:
        raise ReportError(f"{path}: not a sweep results file (missing {', '.join(missing)})")
    if results["schema"] != 1:
        raise ReportError(f"{path}: results schema {results['schema']!r}, this report reads schema 1")
    check(results, path)
    results["_path"] = str(path)
    return results


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _count(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def _hparams(v) -> bool:
    return isinstance(v, dict) and all(_number(x) for x in v.values())


def _optional(test):
    return lambda v: v is None or test(v)


def _row(where: str, row, fields: dict) -> None:
    if not isinstance(row, dict):
        raise ReportError(f"{where} must be an object, got {type(row).__name__}")
    for key, (test, want) in fields.items():
        if key not in row:
            raise ReportError(f"{where} has no field '{key}'")
        if not test(row[key]):
            raise ReportError(f"{where} field '{key}' must be {want}, got {row[key]!r:.80}")


_TEXT = (lambda v: isinstance(v, str), "a string")
_SUMMARY = {"method": _TEXT, "hparams": (_hparams, "an object of numbers"),
            "n_seeds": (_count, "an int >= 0"),
            "return_mean": (_optional(_number), "a number or null"), "return_std": (_optional(_number), "a number or null")}
_RUN = {"method": _TEXT, "hparams": (_hparams, "an object of numbers"), "status": _TEXT}
_EVAL = {"return_mean": (lambda v: _number(v) and math.isfinite(v), "a finite number"),
         "normalized": (_optional(_number), "a number or null")}
_LOSSES = {s: (lambda v: isinstance(v, dict) and all(
    _number(v.get(k)) for k in ("unweighted", "changepoint", "copycat")), "an object with numbers unweighted, "
    "changepoint and copycat") for s in ("train", "val")}


def check(results: dict, path) -> None:
    """Refuses (`ReportError`, one line) a results file lacking a field the tables use, or with a wrong type."""
    _row(f"{path}:", results, {"env": _TEXT, "obs": _TEXT, "preset": _TEXT,
                              "config": (lambda v: isinstance(v, dict), "an object"),
                              "expert": (lambda v: isinstance(v, dict), "an object"),
                              "runs": (lambda v: isinstance(v, list), "a list"),
                              "summary": (lambda v: isinstance(v, list), "a list"),
                              "system": (lambda v: isinstance(v, dict), "an object")})
    _row(f"{path}: config", results["config"], {k: (_count, "an int >= 0")
                                                 for k in ("iterations", "seeds", "eval_episodes")})
    _row(f"{path}: expert", results["expert"], {k: (_optional(_number), "a number or null")
                                                 for k in ("return_mean", "return_std", "random_return_mean")})
    for i, row in enumerate(results["summary"]):
        _row(f"{path}: summary[{i}]", row, _SUMMARY)
        if row["n_seeds"] and not all(_number(row[k]) and math.isfinite(row[k]) for k in ("return_mean", "return_std")):
            raise ReportError(f"{path}: summary[{i}] has {row['n_seeds']} seeds but return "
                              f"{row['return_mean']!r} ± {row['return_std']!r}; expected finite numbers")
    for i, run in enumerate(results["runs"]):
        _row(f"{path}: runs[{i}]", run, _RUN)
        if run["status"] == "ok":
            _row(f"{path}: runs[{i}]", run, {"losses": (lambda v: isinstance(v, dict), "an object"),
                                             "eval": (lambda v: isinstance(v, dict), "an object")})
            _row(f"{path}: runs[{i}] losses", run["losses"], _LOSSES)
            _row(f"{path}: runs[{i}] eval", {"normalized": None, **run["eval"]}, _EVAL)


def merge(files: list[dict]) -> dict[tuple[str, str], dict]:
    """Results per `(env, obs)`: summary rows and runs of all files, with the files they came from.

    Raises:
      ReportError: the same configuration in two files, or files of one
        environment with different experts.
    """
    merged: dict[tuple[str, str], dict] = {}
    for r in files:
        key = (r["env"], r["obs"])
        m = merged.setdefault(key, {"env": r["env"], "obs": r["obs"], "expert": r["expert"], "summary": [],
                                    "runs": [], "sources": []})
        if m["expert"] != r["expert"]:
            raise ReportError(f"{r['_path']}: its expert differs from another {r['env']} results file's")
        seen = {_config_key(row) for row in m["summary"]}
        for row in r["summary"]:
            if _config_key(row) in seen:
                raise ReportError(f"{r['_path']}: {row['method']} {row['hparams']} is also in another results "
                                  f"file of {r['env']} ({r['obs']}); pass one of them")
        m["summary"] += r["summary"]
        m["runs"] += r["runs"]
        m["sources"].append(r)
    return merged


def _config_key(row: dict) -> tuple:
    return row["method"], tuple(sorted(row["hparams"].items()))


def _rows(m: dict, method: str) -> list[dict]:
    return [r for r in m["summary"] if r["method"] == method and r["n_seeds"]]


def _best(rows: list[dict]) -> dict | None:
    """The row with the highest % of expert (ToyCar: success rate), or return where that is missing."""
    def score(r):
        return r["normalized_mean"] if r.get("normalized_mean") is not None else r["return_mean"]

    return max(rows, key=score, default=None)


def headline(m: dict) -> list[tuple[str, dict | None]]:
    """The MuJoCo-State table's rows of one environment: (label, summary row or None)."""
    step = _rows(m, "ours-step")
    paper_step = next((r for r in step if r["hparams"] == PAPER_STEP), None)
    best_step, best_soft = _best(step), _best(_rows(m, "ours-softmax"))
    out = [("BC-SO", _best(_rows(m, "bc-so"))), ("BC-OH", _best(_rows(m, "bc-oh"))),
           ("Ours, step THR 10% W 5", paper_step),
           (f"Ours, best step{_hp(best_step)}", best_step),
           (f"Ours, best softmax{_hp(best_soft)}", best_soft)]
    for method in ("fca", "history-dropout", "bcpd", "actfreq", "kmeans", "boosting", "dagger"):
        out.append((LABELS[method], _best(_rows(m, method))))
    return out


def _hp(row: dict | None) -> str:
    if row is None:
        return ""
    return " (" + ", ".join(f"{k} {v:g}" for k, v in row["hparams"].items()) + ")"


def _cell(row: dict | None) -> str:
    if row is None:
        return "—"
    norm = f" ({row['normalized_mean']:.0f}%)" if row.get("normalized_mean") is not None else ""
    return f"{row['return_mean']:,.0f} ± {row['return_std']:,.0f}{norm}"


def state_table(merged: dict, obs: str = "pos") -> str:
    """Every method per MuJoCo task with observations `obs` ("pos": MuJoCo-State, "image": MuJoCo-Image)."""
    envs = [e for e in MUJOCO if (e, obs) in merged]
    if not envs:
        return ""
    heads = {e: headline(merged[(e, obs)]) for e in envs}
    lines = ["| method | " + " | ".join(TITLES[e] for e in envs) + " |", "|---|" + "---:|" * len(envs)]
    for i, (label, _) in enumerate(heads[envs[0]]):
        generic = label.split(" (")[0] if label.startswith("Ours, best") else label
        cells = []
        for e in envs:
            lab, row = heads[e][i]
            cell = _cell(row)
            if lab.startswith("Ours, best") and row is not None:
                cell += f" <br>{lab[len(generic) + 1:]}"
            cells.append(cell)
        lines.append(f"| {generic} | " + " | ".join(cells) + " |")
    experts = [merged[(e, obs)]["expert"] for e in envs]
    lines.append("| expert (ours) | " + " | ".join("—" if x["return_mean"] is None else
                                                   f"{x['return_mean']:,.0f} ± {x['return_std'] or 0:,.0f}"
                                                   for x in experts) + " |")
    lines.append("| random policy | " + " | ".join("—" if x["random_return_mean"] is None else
                                                   f"{x['random_return_mean']:,.0f}" for x in experts) + " |")
    return "\n".join(lines) + "\n"


# The supplement's Table 4 (ToyCar): success rate (%), mean ± std over 5 trials.
PAPER_TABLE4 = {"bc-so": (97.2, 0.7), "bc-oh": (95.1, 4.5), "ours": (97.8, 0.5)}
TOYCAR_METRICS = (("success", "success %", 100.0), ("red_light_violations", "red-light violations", 1.0),
                  ("progress", "progress", 1.0), ("avg_speed", "average speed", 1.0), ("stuck", "stuck %", 100.0))


def toycar_table(merged: dict) -> str | None:
    """The supplement's Table 4 protocol: BC-SO, BC-OH and Ours (THR 10%, W 5) on ToyCar images, every
    driving metric as mean ± std over seeds (of each seed's episode mean), the paper's success beside."""
    m = merged.get(("toycar", "image"))
    if m is None:
        return None
    lines = ["| method | seeds | " + " | ".join(name for _, name, _ in TOYCAR_METRICS) + " | paper: success % |",
             "|---|---:|" + "---:|" * (len(TOYCAR_METRICS) + 1)]
    for label, method, hp, paper in (("BC-SO", "bc-so", {}, "bc-so"), ("BC-OH", "bc-oh", {}, "bc-oh"),
                                     ("Ours, step THR 10% W 5", "ours-step", PAPER_STEP, "ours")):
        runs = [r for r in m["runs"] if r["method"] == method and r["hparams"] == hp and r["status"] == "ok"]
        if not runs:
            continue
        cells = []
        for key, _, scale in TOYCAR_METRICS:
            v = np.array([r["eval"][key] for r in runs if key in r["eval"]], float) * scale
            cells.append(f"{v.mean():.2f} ± {v.std():.2f}" if len(v) else "—")
        p_mean, p_std = PAPER_TABLE4[paper]
        lines.append(f"| {label} | {len(runs)} | " + " | ".join(cells) + f" | {p_mean} ± {p_std} |")
    return "\n".join(lines) + "\n"


def paper_table(merged: dict) -> str:
    """Ours next to the supplement's Table 5, each method as a ratio to BC-OH within its own source."""
    envs = [e for e in MUJOCO if (e, "pos") in merged]
    if not envs:
        return ""
    lines = ["| method | " + " | ".join(f"{TITLES[e]}: paper | {TITLES[e]}: ours" for e in envs) + " |",
             "|---|" + "---:|" * (2 * len(envs))]
    ours_rows = {e: dict(headline(merged[(e, "pos")])) for e in envs}
    pick = {"bc-so": "BC-SO", "bc-oh": "BC-OH", "fca": "FCA", "ours": "Ours, step THR 10% W 5"}
    for method, label in pick.items():
        cells = []
        for e in envs:
            paper, paper_bcoh = PAPER_TABLE5[method][e], PAPER_TABLE5["bc-oh"][e]
            row, bcoh = ours_rows[e].get(label), ours_rows[e].get("BC-OH")
            cells.append(f"{paper:,} ({paper / paper_bcoh:.2f}×)")
            cells.append("—" if row is None or bcoh is None else
                         f"{row['return_mean']:,.0f} ({row['return_mean'] / bcoh['return_mean']:.2f}×)")
        lines.append(f"| {label.replace(', step THR 10% W 5', '')} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def grid_table(m: dict) -> str:
    """Every configuration: return and % of expert (ToyCar, whose reward is not its measure: success %)."""
    rows = [r for r in m["summary"]]
    best = _best([r for r in rows if r["n_seeds"]])
    toycar = m["sources"][0]["env"] == "toycar"
    heads = ["success %"] if toycar else ["return", "% of expert"]
    lines = ["| method | hparams | seeds | " + " | ".join(heads) + " |", "|---|---|---:|" + "---:|" * len(heads)]
    for r in rows:
        hp = ", ".join(f"{k} {v:g}" for k, v in r["hparams"].items()) or "—"
        label = LABELS.get(r["method"], r["method"])
        ok = r["n_seeds"] and (not toycar or r.get("normalized_mean") is not None)
        if not ok:
            lines.append(f"| {label} | {hp} | {r['n_seeds']} | failed |" + ("" if toycar else " |"))
            continue
        mark = "**" if r is best else ""
        if toycar:
            cells = [f"{mark}{r['normalized_mean']:.1f} ± {r['normalized_std']:.1f}{mark}"]
        else:
            cells = [f"{mark}{r['return_mean']:,.1f} ± {r['return_std']:,.1f}{mark}",
                     f"{r['normalized_mean']:.1f}" if r.get("normalized_mean") is not None else "—"]
        lines.append(f"| {mark}{label}{mark} | {hp} | {r['n_seeds']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def loss_table(m: dict) -> str:
    """The paper's Table 3: mean over seeds of the per-sample loss, all / changepoint / copycat, train / val."""
    wanted = [("BC-SO", "bc-so", {}), ("BC-OH", "bc-oh", {}), ("Ours, step THR 10% W 5", "ours-step", PAPER_STEP)]
    best = _best(_rows(m, "ours-step"))
    if best is not None and best["hparams"] != PAPER_STEP:
        wanted.append((f"Ours, best step{_hp(best)}", "ours-step", best["hparams"]))
    keys = [(s, k) for s in ("train", "val") for k in ("unweighted", "changepoint", "copycat")]
    lines = ["| method | " + " | ".join(f"{s}: {'all' if k == 'unweighted' else k}" for s, k in keys) + " |",
             "|---|" + "---:|" * len(keys)]
    for label, method, hp in wanted:
        runs = [r for r in m["runs"] if r["method"] == method and r["hparams"] == hp and r["status"] == "ok"]
        if not runs:
            continue
        vals = [sum(r["losses"][s][k] for r in runs) / len(runs) for s, k in keys]
        lines.append(f"| {label} | " + " | ".join(f"{v:.4f}" for v in vals) + " |")
    return "\n".join(lines) + "\n"


def copycat_table(m: dict) -> str | None:
    """The copycat diagnostics of every configuration that has them (None if no run does).

    Per configuration, the mean over seeds of each seed's mean over evaluation episodes of
    `rollout_ape` (the APE of the policy's own actions, ÷ the training set's mean APE) and
    `imitation_error` (Σ_d (a − a*)² against the expert's action on the policy's own states).
    """
    groups: dict[tuple, list[dict]] = {}
    for r in m["runs"]:
        if r["status"] == "ok" and "rollout_ape" in r["eval"] and "imitation_error" in r["eval"]:
            groups.setdefault(_config_key(r), []).append(r)
    if not groups:
        return None
    expert = [src["config"]["ape"]["val_mean"] for src in m["sources"]
              if isinstance(src["config"].get("ape"), dict) and "val_mean" in src["config"]["ape"]]
    lines = ["| method | hparams | seeds | rollout APE (÷ training mean) | imitation error on own states | "
             "% of expert |", "|---|---|---:|---:|---:|---:|"]
    if expert:
        lines.append(f"| expert (validation demonstrations) | — | — | {expert[0]:.2f} | 0 | 100 |")
    for (method, hp), runs in groups.items():
        mean = lambda k: sum(r["eval"][k] for r in runs) / len(runs)  # noqa: E731
        norm = f"{mean('normalized'):.1f}" if all("normalized" in r["eval"] for r in runs) else "—"
        hps = ", ".join(f"{k} {v:g}" for k, v in hp) or "—"
        lines.append(f"| {LABELS.get(method, method)} | {hps} | {len(runs)} | {mean('rollout_ape'):.3f} | "
                     f"{mean('imitation_error'):.4f} | {norm} |")
    return "\n".join(lines) + "\n"


# The supplement's §4 sensitivity study: Walker2d returns per softmax τ, and CARLA driving success per step W.
PAPER_SENSITIVITY_TAU = {0.1: (765, 103), 0.2: (769, 97), 0.5: (724, 61)}
PAPER_SENSITIVITY_W = {4.0: 41.9, 5.0: 43.4, 6.0: 41.3}


def _norm_cell(row: dict | None) -> str:
    return "—" if row is None or row.get("normalized_mean") is None else f"{row['normalized_mean']:.1f}"


def sensitivity_table(merged: dict) -> str | None:
    """The sensitivity study on Walker2d (states): τ ∈ {0.1, 0.2, 0.5} and W ∈ {4, 5, 6} at THR 10%, with the paper's."""
    m = merged.get(("walker2d", "pos"))
    if m is None:
        return None
    rows = {_config_key(r): r for r in m["summary"] if r["n_seeds"]}
    tau = [(t, rows.get(("ours-softmax", (("tau", t),)))) for t in PAPER_SENSITIVITY_TAU]
    w = [(x, rows.get(("ours-step", (("thr", 0.1), ("w", x))))) for x in PAPER_SENSITIVITY_W]
    if not any(r for _, r in tau + w):
        return None
    lines = ["| setting | ours: Walker2d return | ours: % of expert | paper |", "|---|---:|---:|---:|"]
    for t, r in tau:
        paper = f"Walker2d {PAPER_SENSITIVITY_TAU[t][0]} ± {PAPER_SENSITIVITY_TAU[t][1]}"
        lines.append(f"| softmax τ {t:g} | {_cell(r).split(' (')[0]} | {_norm_cell(r)} | {paper} |")
    for x, r in w:
        lines.append(f"| step THR 10%, W {x:g} | {_cell(r).split(' (')[0]} | {_norm_cell(r)} | "
                     f"driving {PAPER_SENSITIVITY_W[x]}% success |")
    for name, group in (("τ", tau), ("W", w)):
        got = [r for _, r in group if r is not None]
        if len(got) == len(group):
            spread = max(r["return_mean"] for r in got) - min(r["return_mean"] for r in got)
            std = max(r["return_std"] for r in got)
            word = "within" if spread <= std else "beyond"
            lines.append(f"\nOver {name}: the means span {spread:,.0f}, {word} the largest std over seeds ({std:,.0f}).")
    return "\n".join(lines) + "\n"


# -- Ours − BC-OH: bootstrap over seeds ---------------------------------------------------------------------------

class Interval(NamedTuple):
    """A difference of means `a − b` with its bootstrap confidence interval `[low, high]`."""

    diff: float
    low: float
    high: float
    n_a: int
    n_b: int


def bootstrap_difference(a: Sequence[float], b: Sequence[float], resamples: int = BOOTSTRAP_RESAMPLES,
                         level: float = 0.95, seed: int = BOOTSTRAP_SEED) -> Interval:
    """Percentile bootstrap interval of `mean(a) − mean(b)`, resampling each arm's seeds independently.

    Args:
      a, b: per-seed values of the two arms (e.g. each seed's mean return), `[n_a]` and `[n_b]`, n ≥ 1.
      resamples: bootstrap replicates.
      level: coverage of the interval (0.95: the 2.5th to 97.5th percentile of the replicates).
      seed: the numpy RNG seed; the same inputs always give the same interval.

    Returns:
      `Interval(diff, low, high, n_a, n_b)`, `diff` the observed difference of means.
    """
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.ndim != 1 or b.ndim != 1 or not a.size or not b.size:
        raise ValueError(f"bootstrap_difference needs two non-empty 1-d arms, got shapes {a.shape} and {b.shape}")
    rng = np.random.default_rng(seed)
    means_a = a[rng.integers(0, a.size, size=(resamples, a.size))].mean(1)
    means_b = b[rng.integers(0, b.size, size=(resamples, b.size))].mean(1)
    tail = 100 * (1 - level) / 2
    low, high = np.percentile(means_a - means_b, [tail, 100 - tail])
    return Interval(float(a.mean() - b.mean()), float(low), float(high), int(a.size), int(b.size))


def verdict(ci: Interval, a: str = "Ours", b: str = "BC-OH") -> str:
    """Plain words: `a` better / `b` better when the interval excludes 0, else not significant."""
    if min(ci.n_a, ci.n_b) < 2:
        return "no verdict (needs ≥ 2 seeds per arm)"
    if ci.low > 0:
        return f"{a} better"
    if ci.high < 0:
        return f"{b} better"
    return "not significant (CI contains 0)"


def _seeds(m: dict, row: dict | None, key: str = "return_mean") -> list[float]:
    """Per-seed evaluation values (`eval[key]`) of the configuration of summary row `row`, in seed order."""
    if row is None:
        return []
    runs = [r for r in m["runs"] if r["method"] == row["method"] and r["hparams"] == row["hparams"]
            and r["status"] == "ok" and r["eval"].get(key) is not None]
    return [r["eval"][key] for r in sorted(runs, key=lambda r: r.get("seed", 0))]


def comparisons(m: dict) -> list[tuple[str, dict | None]]:
    """Ours' configurations compared with BC-OH: the paper's step setting, then the best step and softmax."""
    step = _rows(m, "ours-step")
    best_step, best_soft = _best(step), _best(_rows(m, "ours-softmax"))
    def after(row: dict | None) -> str:
        return "" if row is None else f" ({_hp(row)[2:-1]}; selected after the fact)"

    return [("Ours, step THR 10% W 5 (the paper's)", next((r for r in step if r["hparams"] == PAPER_STEP), None)),
            (f"Ours, best step{after(best_step)}", best_step), (f"Ours, best softmax{after(best_soft)}", best_soft)]


def bootstrap_rows(merged: dict) -> list[tuple[str, str, Interval, str]]:
    """Per environment and configuration of Ours (`comparisons`): Ours − BC-OH with its CI, and the unit:
    mean return, or for ToyCar (whose reward is not its measure) the success rate in percentage points."""
    out = []
    for (env, obs), m in _ordered(merged):
        key, unit, scale = ("success", "success, % points", 100.0) if env == "toycar" else ("return_mean", "return", 1.0)
        bcoh = [scale * v for v in _seeds(m, _best(_rows(m, "bc-oh")), key)]
        for label, row in comparisons(m) if bcoh else []:
            ours = [scale * v for v in _seeds(m, row, key)]
            if ours:
                out.append((_env_title(env, obs), label, bootstrap_difference(ours, bcoh), unit))
    return out


def bootstrap_table(rows: list[tuple[str, str, Interval, str]]) -> str:
    """The rows of `bootstrap_rows` as a table: difference of means, 95% CI, verdict."""
    lines = ["| environment | Ours | seeds (Ours / BC-OH) | Ours − BC-OH | 95% CI | verdict |",
             "|---|---|---:|---:|---:|---|"]
    lines += [f"| {env} | {label} | {ci.n_a} / {ci.n_b} | {ci.diff:+,.0f} ({unit}) | [{ci.low:+,.0f}, {ci.high:+,.0f}] | "
              f"{verdict(ci)} |" for env, label, ci, unit in rows]
    return "\n".join(lines) + "\n"


# -- grid search: heatmaps and the paper's choices ----------------------------------------------------------------

def _metric(m: dict) -> tuple[str, str]:
    """Which summary numbers the figures show: `(prefix, unit)`; % of expert where every row has it."""
    if all(r.get("normalized_mean") is not None for r in m["summary"] if r["n_seeds"]):
        return "normalized", "% of expert"
    return "return", "return"


def _value(row: dict, prefix: str) -> tuple[float, float]:
    mean, std = row[f"{prefix}_mean"], row.get(f"{prefix}_std")
    return float(mean), float(std if std is not None else math.nan)


def _pct(thr: float) -> str:
    return f"{100 * thr:g}%"


def _fmt(mean: float, std: float, prefix: str) -> str:
    return f"{mean:.1f} ± {std:.1f}%" if prefix == "normalized" else f"{mean:,.0f} ± {std:,.0f}"


def _ape_scale(m: dict) -> float | None:
    """The training-set mean APE our softmax τ divided by (`ape_normalization: "mean"`), or None."""
    for r in m["sources"]:
        ape = r["config"].get("ape")
        if (any(row["method"] == "ours-softmax" for row in r["summary"]) and isinstance(ape, dict)
                and ape.get("normalization") == "mean" and _number(ape.get("scale")) and ape["scale"] > 0):
            return float(ape["scale"])
    return None


def paper_choices(m: dict) -> list[str]:
    """One sentence per weighting: is the paper's setting within one std over seeds of the grid's best?

    "Within one std" means the gap to the best is at most the larger of the two configurations' std over seeds.
    Where our APE was divided by its training-set mean, the softmax sentence also names the grid value
    nearest to the paper's τ carried over to that scale (the paper's τ acts on the raw APE).
    """
    prefix, _ = _metric(m)
    pts = " points" if prefix == "normalized" else ""
    tau = PAPER_TAU.get(m["env"])

    def near(chosen: dict, best: dict, rows: list[dict], kind: str, name) -> str:
        (cm, cs), (bm, bs) = _value(chosen, prefix), _value(best, prefix)
        if chosen is best:
            return f"{_fmt(cm, cs, prefix)}, the best of the {len(rows)} {kind} settings"
        gap, noise = bm - cm, max(cs, bs)
        where = (f"within one std over seeds ({noise:.1f}) of the best" if gap <= noise else
                 f"more than one std over seeds ({noise:.1f}) below the best: not near it")
        return (f"{_fmt(cm, cs, prefix)} vs the best, {name(best['hparams'])}, {_fmt(bm, bs, prefix)}: "
                f"{gap:.1f}{pts} lower, {where}")

    out = []
    for kind, method, paper, name in (
            ("step", "ours-step", PAPER_STEP, lambda hp: f"THR {_pct(hp['thr'])} W {hp['w']:g}"),
            ("softmax", "ours-softmax", None if tau is None else {"tau": tau}, lambda hp: f"τ {hp['tau']:g}")):
        rows = _rows(m, method)
        if not rows or paper is None:
            continue
        best = max(rows, key=lambda r: _value(r, prefix)[0])
        chosen = next((r for r in rows if r["hparams"] == paper), None)
        text = f"{kind.capitalize()}, the paper's {name(paper)}: " + (
            "not run" if chosen is None else near(chosen, best, rows, kind, name)) + "."
        scale = _ape_scale(m) if kind == "softmax" else None
        taus = [r for r in rows if r["hparams"].get("tau", 0) > 0]
        if scale is not None and taus:
            equivalent = tau / scale
            closest = min(taus, key=lambda r: abs(math.log(r["hparams"]["tau"] / equivalent)))
            text += (f" But our τ acts on the APE divided by its training-set mean ({scale:.4f}) and the paper's on "
                     f"the raw APE, so its τ {tau:g} is about τ {equivalent:.1f} here (roughly: the paper's APE "
                     f"scale is not ours); the nearest grid value, τ {closest['hparams']['tau']:g}: "
                     f"{near(closest, best, rows, kind, name)}.")
        out.append(text)
    return out


def grid_figure(m: dict):
    """The grid search of one environment as heatmaps (step THR × W, softmax τ), or None if neither was run."""
    from experiments.report import figures

    prefix, unit = _metric(m)
    panels = []
    step = {(r["hparams"]["thr"], r["hparams"]["w"]): r for r in _rows(m, "ours-step")
            if set(r["hparams"]) == {"thr", "w"}}
    if step:
        thrs, ws = sorted({k[0] for k in step}), sorted({k[1] for k in step})
        panels.append(_grid_panel("step weighting", "THR (top fraction of APE)", "W (weight)",
                                  [_pct(t) for t in thrs], [f"{w:g}" for w in ws],
                                  [[step.get((t, w)) for w in ws] for t in thrs], prefix,
                                  next(((i, j) for i, t in enumerate(thrs) for j, w in enumerate(ws)
                                        if {"thr": t, "w": w} == PAPER_STEP), None)))
    soft = {r["hparams"]["tau"]: r for r in _rows(m, "ours-softmax") if set(r["hparams"]) == {"tau"}}
    if soft:
        taus = sorted(soft)
        tau = PAPER_TAU.get(m["env"])
        panels.append(_grid_panel("softmax weighting", "", "τ (temperature)", [""], [f"{t:g}" for t in taus],
                                  [[soft[t] for t in taus]], prefix,
                                  (0, taus.index(tau)) if tau in taus else None))
    if not panels:
        return None
    bcoh = _best(_rows(m, "bc-oh"))
    seeds = max(r["n_seeds"] for r in (*step.values(), *soft.values()))
    ref, center = "", None
    if bcoh is not None:
        center, std = _value(bcoh, prefix)
        ref = f"; BC-OH {center:.1f} ± {std:.1f}"
    title = (f"{_env_title(m['env'], m['obs'])}: grid search, {unit} (mean ± std over {seeds} seeds){ref}")
    return figures.heatmap(title, panels, center, unit)


def _grid_panel(title, row_label, col_label, rows, cols, cells, prefix, marked):
    from experiments.report import figures

    mean = np.array([[_value(c, prefix)[0] if c else np.nan for c in line] for line in cells])
    std = np.array([[_value(c, prefix)[1] if c else np.nan for c in line] for line in cells])
    best = np.unravel_index(np.nanargmax(mean), mean.shape)
    return figures.Grid(title, row_label, col_label, rows, cols, mean, std, (int(best[0]), int(best[1])), marked)


# -- return per method ----------------------------------------------------------------------------------------------

BAR_BASELINES = ("fca", "dagger", "bcpd", "actfreq", "kmeans", "boosting", "history-dropout")


def returns_figure(merged: dict):
    """Every method's return per environment (bars: mean, error bars: std over seeds, dots: seeds), or None."""
    from experiments.report import figures

    envs = _ordered(merged)
    baselines = [b for b in BAR_BASELINES if any(_rows(m, b) for _, m in envs)]
    labels = ["BC-SO", "BC-OH", "Ours, step THR 10% W 5", "Ours, best softmax",
              *(LABELS[b].replace(" (online)", "") for b in baselines)]
    panels = []
    for (env, obs), m in envs:
        prefix, unit = _metric(m)
        step = next((r for r in _rows(m, "ours-step") if r["hparams"] == PAPER_STEP), None)
        soft = _best(_rows(m, "ours-softmax"))
        rows = [_best(_rows(m, "bc-so")), _best(_rows(m, "bc-oh")), step, soft,
                *(_best(_rows(m, b)) for b in baselines)]
        if not any(rows):
            continue
        key = "normalized" if prefix == "normalized" else "return_mean"
        notes = ["" for _ in rows]
        if soft is not None:
            notes[3] = f"τ {soft['hparams']['tau']:g}"
        panels.append(figures.Bars(
            _env_title(env, obs), unit, [None if r is None else _value(r, prefix)[0] for r in rows],
            [None if r is None else _value(r, prefix)[1] for r in rows], [_seeds(m, r, key) for r in rows], notes,
            100.0 if prefix == "normalized" else None, "expert"))
    if not panels:
        return None
    return figures.bars(labels, panels, "Return per method: bars = mean over seeds, error bars = std, dots = seeds; "
                                        "best softmax selected after the fact")


def curves_figure(merged: dict):
    """Training curves (the weighted loss of the sampled batches, mean ± std over seeds) of BC-OH, the paper's
    step setting and the best softmax, one panel per environment; None if no run records its curve."""
    from experiments.report import figures

    panels = []
    for (env, obs), m in _ordered(merged):
        series = []
        for label, row in (("BC-OH", _best(_rows(m, "bc-oh"))), ("Ours, step THR 10% W 5", next(
                (r for r in _rows(m, "ours-step") if r["hparams"] == PAPER_STEP), None)),
                           ("Ours, best softmax" + _hp(_best(_rows(m, "ours-softmax"))),
                            _best(_rows(m, "ours-softmax")))):
            runs = [r["train_curve"] for r in m["runs"] if row is not None and r["status"] == "ok"
                    and _config_key(r) == _config_key(row) and r.get("train_curve")]
            runs = [c for c in runs if None not in c and len(c) == len(runs[0])] if runs else []
            if runs:
                curve = np.asarray(runs, float)
                iters = m["sources"][0]["config"]["iterations"]
                x = (np.arange(curve.shape[1]) + 1) * iters / curve.shape[1]
                series.append((label, x, curve.mean(0), curve.std(0)))
        if series:
            panels.append(figures.Lines(_env_title(env, obs), "iteration", "weighted BC loss (window mean)",
                                        series, log_y=True))
    return figures.lines(panels, "Training curves (mean ± std over seeds)") if panels else None


def weight_shares(merged: dict, batch: int = 128, batches: int = 400) -> list[tuple[str, list[tuple]]]:
    """How concentrated the weights are within a batch, per environment that records its APE quantiles.

    Batches of `batch` are drawn from each environment's training APE distribution
    (its quantiles) and weighted as the sweep does: softmax at every τ it ran,
    the paper's step setting and uniform weights. Returns
    `[(panel title, [(label, share), ...])]`, `share[k-1]` the mean over batches
    of the share of the total weight the k heaviest samples carry.
    """
    rng = np.random.default_rng(0)

    def share(w):  # [batches, batch] -> [batch]
        top = -np.sort(-w, axis=1)
        return (np.cumsum(top, axis=1) / top.sum(1, keepdims=True)).mean(0)

    out = []
    for (env, obs), m in _ordered(merged):
        q = next((src["config"]["ape"].get("quantiles") for src in m["sources"]
                  if isinstance(src["config"].get("ape"), dict) and src["config"]["ape"].get("quantiles")), None)
        taus = sorted({r["hparams"]["tau"] for r in _rows(m, "ours-softmax")})
        if q is None or not taus:
            continue
        levels = np.linspace(0, 1, len(q))
        ape = np.interp(rng.uniform(size=(batches, batch)), levels, q)
        series = []
        for tau in taus:
            z = ape / tau
            series.append((f"softmax τ {tau:g}", share(np.exp(z - z.max(1, keepdims=True)))))
        series.append(("step THR 10% W 5", share(np.where(ape >= np.interp(0.9, levels, q), 5.0, 1.0))))
        series.append(("uniform (BC-OH)", np.arange(1, batch + 1) / batch))
        out.append((_env_title(env, obs), series))
    return out


def weights_figure(shares: list[tuple[str, list[tuple]]]):
    """The share of a batch's weight carried by its k heaviest samples, against k (`weight_shares`)."""
    from experiments.report import figures

    if not shares:
        return None
    batch = len(shares[0][1][0][1])
    k = np.arange(1, batch + 1)
    panels = [figures.Lines(title, f"k heaviest samples of the batch of {batch}", "share of the batch's total weight",
                            [(label, k, y, None) for label, y in series], log_x=True) for title, series in shares]
    return figures.lines(panels, "How much of a batch's weight its heaviest samples carry")


def weights_table(shares: list[tuple[str, list[tuple]]]) -> str:
    """The heaviest sample's and the heaviest 10%'s share of a batch's weight, per environment and setting."""
    lines = ["| environment | weighting | heaviest sample's share | heaviest 10%'s share |", "|---|---|---:|---:|"]
    for title, series in shares:
        for label, y in series:
            lines.append(f"| {title} | {label} | {100 * y[0]:.0f}% | {100 * y[max(1, round(0.1 * len(y))) - 1]:.0f}% |")
    return "\n".join(lines) + "\n"


def _ordered(merged: dict) -> list[tuple[tuple[str, str], dict]]:
    order = {e: i for i, e in enumerate((*MUJOCO, "toycar"))}
    return sorted(merged.items(), key=lambda kv: (order.get(kv[0][0], len(order)), kv[0]))


def _env_title(env: str, obs: str) -> str:
    return TITLES.get(env, env) + ("" if obs == "pos" and env in MUJOCO else f" ({obs})")


def _grid_name(env: str, obs: str) -> str:
    return f"grid-{env}.png" if obs == "pos" else f"grid-{env}-{obs}.png"


def provenance(r: dict) -> str:
    """The command and setting one results file came from."""
    cfg = r["config"]
    from ape_jax.pipeline.sweep import PRESETS, preset_for

    cmd = f"python -m experiments.sweep --env {r['env']} --obs {r['obs']} --preset {r['preset']}"
    default_methods = ["bc-so", "bc-oh", "ours-step", "ours-softmax"]
    if cfg.get("methods") != default_methods:
        cmd += f" --methods {','.join(cfg['methods'])}"
    preset = preset_for(r["preset"], r["env"], r["obs"]) if r["preset"] in PRESETS else None
    for key, flag in (("iterations", "--iterations"), ("seeds", "--seeds"), ("eval_episodes", "--eval-episodes")):
        if preset is not None and cfg.get(key) != getattr(preset, key):
            cmd += f" {flag} {cfg[key]}"
    if preset is not None and "step_grid" in cfg and [list(g) for g in preset.step_grid] != cfg["step_grid"]:
        cmd += " --step-grid " + ",".join(f"{thr:g}:{w:g}" for thr, w in cfg["step_grid"])
    if preset is not None and "softmax_grid" in cfg and list(preset.softmax_grid) != cfg["softmax_grid"]:
        cmd += " --softmax-grid " + ",".join(f"{tau:g}" for tau in cfg["softmax_grid"])
    s, t = r["system"], r.get("timing", {})
    machine = s.get("machine") or "machine not recorded in the file"
    commit = f"`{s.get('commit')}`" + (" with uncommitted changes" if s.get("dirty") else "")
    line = (f"`{cmd}` — {cfg['iterations']:,} iterations, {cfg['seeds']} seeds, {cfg['eval_episodes']} evaluation "
            f"episodes; commit {commit}, jax {s.get('jax')} ({s.get('backend')}, {s.get('devices')} "
            f"device(s)), {machine}; {t.get('total_s', 0):,.0f} s in all"
            + (" (resumed after an interruption: the last process's time only)" if t.get("resumed") else ""))
    if t.get("peak_rss_mb"):
        line += f", peak resident memory {t['peak_rss_mb'] / 1024:.1f} GB"
    again = r.get("reevaluated")
    if again and again.get("fields"):
        line += (f"; {', '.join(f'`{f}`' for f in again['fields'])} added later by `python -m experiments.evaluate` "
                 f"(commit `{again['system'].get('commit')}`, every recorded number reproduced)")
    return line


def build(files: list[dict], figure_dir: pathlib.Path | None = None,
          base: pathlib.Path | None = None) -> tuple[str, dict[pathlib.Path, object]]:
    """The report's markdown and its figures, nothing written.

    Args:
      files: loaded results files (`load`).
      figure_dir: where the figures will be written; None draws none (the text says so).
      base: the folder the markdown's links are relative to (the `--out` file's); default the working folder.

    Returns:
      `(text, figures)`: the markdown, and `{path: matplotlib Figure}` to write with `experiments.report.figures.save_png`.
    """
    merged = merge(files)
    drawn: dict[pathlib.Path, object] = {}
    base = pathlib.Path.cwd() if base is None else pathlib.Path(base)

    def figure(name: str, alt: str, draw) -> list[str]:
        fig = draw() if figure_dir is not None else None
        if fig is None:
            return []
        path = pathlib.Path(figure_dir) / name
        drawn[path] = fig
        return [f"![{alt}]({pathlib.Path(os.path.relpath(path.absolute(), base.absolute())).as_posix()})", ""]

    out = []
    if any((e, "pos") in merged for e in MUJOCO):
        out += ["### MuJoCo-State (velocities removed)", "",
                "Return mean ± std over seeds (each seed's mean over the evaluation episodes), and in "
                "brackets the percentage of our expert's return, normalised against a random policy. "
                "\"Best\" rows pick the configuration with the highest return on the evaluation episodes "
                "(selection on the test episodes, as the paper's grid search does; optimistic).", "",
                state_table(merged),
                "Next to the supplement's Table 5 (its own experts, whose returns it does not give): mean "
                "returns, and in brackets each method's ratio to BC-OH of the same source.", "",
                paper_table(merged)]
    if any((e, "image") in merged for e in MUJOCO):
        out += ["### MuJoCo-Image", "",
                "As MuJoCo-State, from rendered frames (the image presets: see each file's provenance below).", "",
                state_table(merged, "image")]
    toycar = toycar_table(merged)
    if toycar:
        out += ["### ToyCar (the supplement's Table 4 protocol)", "",
                "Driving metrics per policy, mean ± std over seeds of each seed's mean over evaluation episodes; "
                "the paper's success rates beside (its own ToyCar sandbox, not ours).", "", toycar]
    if figure_dir is None:
        out += ["_Figures not drawn: the report was printed without `--figures DIR` (with `--out` they go to "
                "`figures/` next to it)._", ""]
    boot = bootstrap_rows(merged)
    returns = figure("returns.png", "Return per method and environment", lambda: returns_figure(merged))
    if boot or returns:
        out += ["### Ours vs BC-OH over seeds", ""] + returns
    if boot:
        seeds = min(min(ci.n_a, ci.n_b) for _, _, ci, _ in boot)
        out += ["Ours − BC-OH in mean return over seeds (ToyCar: in success rate), with a 95% percentile "
                "bootstrap confidence interval "
                f"(each arm's seeds resampled with replacement, independently, {BOOTSTRAP_RESAMPLES:,} times; "
                f"numpy seed {BOOTSTRAP_SEED}). The best-step and best-softmax rows were selected after the fact "
                "on these same evaluation returns, so their differences are optimistic.", "", bootstrap_table(boot),
                f"Caveat: with {seeds} seed{'s' * (seeds != 1)} per arm each arm has only "
                f"{math.comb(2 * seeds - 1, seeds)} distinct resamples, so the interval is coarse, and at so few "
                "seeds the percentile bootstrap is too narrow (it under-covers): read \"better\" as a hint, and "
                "\"not significant\" as \"these seeds cannot tell\", not as evidence of no effect.", ""]
    sensitivity = sensitivity_table(merged)
    if sensitivity:
        out += ["### Sensitivity (the supplement's §4)", "",
                "Walker2d (states), softmax τ and the step weight W at THR 10%, next to the paper's numbers "
                "(its W study was on CARLA driving, so only the pattern compares).", "", sensitivity]
    shares = weight_shares(merged)
    extra = figure("curves.png", "Training curves", lambda: curves_figure(merged)) + \
        figure("weights.png", "Weight concentration within a batch", lambda: weights_figure(shares))
    if shares:
        extra += [weights_table(shares)]
    if extra:
        out += ["### Training curves and weights", "",
                "From the results files that record them (runs since the training curve and the APE quantiles "
                "were added to `results.json`). Weights: batches of 128 drawn from each task's training APE "
                "distribution and weighted as the sweep does, `B·softmax(APE/τ)` or the step function; each curve "
                "is the share of a batch's total weight its k heaviest samples carry (uniform weights: the "
                "diagonal). A curve near 1 at k = 1 is a batch whose loss is one sample's.", ""] + extra
    for (env, obs), m in _ordered(merged):
        out += [f"### {TITLES.get(env, env)}, `{obs}` observations: every configuration", ""]
        out += [f"- {provenance(r)}" for r in m["sources"]]
        out += ["", grid_table(m)]
        out += figure(_grid_name(env, obs), f"{_env_title(env, obs)} grid search", lambda: grid_figure(m))
        choices = paper_choices(m)
        if choices:
            unit = "% of expert" if _metric(m)[0] == "normalized" else "return"
            out += [f"Are the paper's settings near the best of our grid? (In {unit}; \"within one std\": "
                    "the gap to the best is at most the larger of the two settings' std over seeds.)", ""]
            out += [f"- {c}" for c in choices] + [""]
        out += ["Loss analysis (the paper's Table 3; mean over seeds of the per-sample "
                "loss; changepoints = top 10% APE of each split):", "", loss_table(m)]
        copycat = copycat_table(m)
        if copycat:
            out += ["Copycat diagnostics, from the evaluation rollouts: how predictable each policy's own "
                    "actions are from its previous 9 (ψ's APE, ÷ the training set's mean APE; a policy that "
                    "repeats its last action scores below the expert), and how far its actions are from the "
                    "expert's on the states it visits itself:", "", copycat]
    return "\n".join(out), drawn


def report(files: list[dict], figure_dir: pathlib.Path | None = None, base: pathlib.Path | None = None) -> str:
    """`build`, then writes its figures (atomically); returns the markdown."""
    from experiments.report.figures import save_png

    text, drawn = build(files, figure_dir, base)
    for path, fig in drawn.items():
        save_png(fig, path)
    return text


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.report", description=__doc__.splitlines()[0])
    p.add_argument("results", nargs="+", type=pathlib.Path, help="results.json files of experiments.sweep")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="write into this file's `report` section (BENCHMARKS.md) instead of printing")
    p.add_argument("--figures", type=pathlib.Path, default=None, metavar="DIR",
                   help="write the figures (PNG) here; default: `figures/` next to --out, none when printing")
    args = p.parse_args(argv)
    if args.out is not None:
        why = unwritable_file(args.out)
        if why is None and args.out.exists():
            try:
                args.out.read_text()
            except (OSError, UnicodeDecodeError) as e:
                why = f"it cannot be read as text ({e})"
        if why:
            fail(p, f"--out {args.out}: cannot write the report there: {why}")
    figure_dir = args.figures if args.figures is not None else (
        None if args.out is None else args.out.parent / "figures")
    if figure_dir is not None and (why := unwritable(figure_dir)):
        flag = f"--figures {args.figures}" if args.figures is not None else f"--out {args.out}"
        fail(p, f"{flag}: cannot write the figures to {figure_dir}: {why}")
    try:
        text, drawn = build([load(path) for path in args.results], figure_dir,
                            None if args.out is None else args.out.parent)
    except ReportError as e:
        return fail(None, str(e))
    from experiments.report.figures import save_png

    log = sys.stdout if args.out is not None else sys.stderr   # stdout carries the markdown when printing
    for path, fig in drawn.items():
        try:
            size = save_png(fig, path)
        except OSError as e:
            return fail(None, f"cannot write {path}: {e}")
        print(f"wrote {path} ({size / 1024:.0f} KB)", file=log)
    if args.out is None:
        print(text)
        return 0
    from experiments._timing import write_section

    try:
        write_section(str(args.out), text, "report")
    except (OSError, UnicodeDecodeError) as e:
        return fail(None, f"cannot write {args.out}: {e}")
    print(f"wrote the report section of {args.out} from {len(args.results)} results file(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
