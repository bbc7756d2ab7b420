"""Tables for `BENCHMARKS.md` from sweep results: `python -m experiments.report RESULTS... [--out BENCHMARKS.md]`.

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
  seeds, commit, machine).

No number in these tables is typed by hand; regenerate them after every sweep.

A results file that cannot be read, is not JSON, or lacks a field the tables
use (or has it with the wrong type), and an `--out` that cannot be written, are
refused with one line on stderr and exit status 2; `--out` is then left as it was.
"""

from __future__ import annotations

import json
import math
import pathlib
import sys

from experiments._cli import Parser, fail, unwritable_file

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
            _row(f"{path}: runs[{i}]", run, {"losses": (lambda v: isinstance(v, dict), "an object")})
            _row(f"{path}: runs[{i}] losses", run["losses"], _LOSSES)


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
    return max(rows, key=lambda r: r["return_mean"], default=None)


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


def state_table(merged: dict) -> str:
    envs = [e for e in MUJOCO if (e, "pos") in merged]
    if not envs:
        return ""
    heads = {e: headline(merged[(e, "pos")]) for e in envs}
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
    experts = [merged[(e, "pos")]["expert"] for e in envs]
    lines.append("| expert (ours) | " + " | ".join("—" if x["return_mean"] is None else
                                                   f"{x['return_mean']:,.0f} ± {x['return_std'] or 0:,.0f}"
                                                   for x in experts) + " |")
    lines.append("| random policy | " + " | ".join("—" if x["random_return_mean"] is None else
                                                   f"{x['random_return_mean']:,.0f}" for x in experts) + " |")
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
    rows = [r for r in m["summary"]]
    best = _best([r for r in rows if r["n_seeds"]])
    lines = ["| method | hparams | seeds | return | % of expert |", "|---|---|---:|---:|---:|"]
    for r in rows:
        hp = ", ".join(f"{k} {v:g}" for k, v in r["hparams"].items()) or "—"
        label = LABELS.get(r["method"], r["method"])
        if not r["n_seeds"]:
            lines.append(f"| {label} | {hp} | 0 | failed | |")
            continue
        mark = "**" if r is best else ""
        norm = f"{r['normalized_mean']:.1f}" if r.get("normalized_mean") is not None else "—"
        lines.append(f"| {mark}{label}{mark} | {hp} | {r['n_seeds']} | "
                     f"{mark}{r['return_mean']:,.1f} ± {r['return_std']:,.1f}{mark} | {norm} |")
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


def provenance(r: dict) -> str:
    """The command and setting one results file came from."""
    cfg = r["config"]
    from ape_jax.sweep import PRESETS

    cmd = f"python -m experiments.sweep --env {r['env']} --obs {r['obs']} --preset {r['preset']}"
    default_methods = ["bc-so", "bc-oh", "ours-step", "ours-softmax"]
    if cfg.get("methods") != default_methods:
        cmd += f" --methods {','.join(cfg['methods'])}"
    preset = PRESETS.get(r["preset"])
    for key, flag in (("iterations", "--iterations"), ("seeds", "--seeds"), ("eval_episodes", "--eval-episodes")):
        if preset is not None and cfg.get(key) != getattr(preset, key):
            cmd += f" {flag} {cfg[key]}"
    s, t = r["system"], r.get("timing", {})
    machine = s.get("machine") or "machine not recorded in the file"
    commit = f"`{s.get('commit')}`" + (" with uncommitted changes" if s.get("dirty") else "")
    return (f"`{cmd}` — {cfg['iterations']:,} iterations, {cfg['seeds']} seeds, {cfg['eval_episodes']} evaluation "
            f"episodes; commit {commit}, jax {s.get('jax')} ({s.get('backend')}, {s.get('devices')} "
            f"device(s)), {machine}; {t.get('total_s', 0):,.0f} s in all")


def report(files: list[dict]) -> str:
    merged = merge(files)
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
    order = {e: i for i, e in enumerate((*MUJOCO, "toycar"))}
    for (env, obs), m in sorted(merged.items(), key=lambda kv: (order.get(kv[0][0], len(order)), kv[0])):
        out += [f"### {TITLES.get(env, env)}, `{obs}` observations: every configuration", ""]
        out += [f"- {provenance(r)}" for r in m["sources"]]
        out += ["", grid_table(m), "Loss analysis (the paper's Table 3; mean over seeds of the per-sample "
                "loss; changepoints = top 10% APE of each split):", "", loss_table(m)]
    return "\n".join(out)


def main(argv=None) -> int:
    p = Parser(prog="python -m experiments.report", description=__doc__.splitlines()[0])
    p.add_argument("results", nargs="+", type=pathlib.Path, help="results.json files of experiments.sweep")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="write into this file's `report` section (BENCHMARKS.md) instead of printing")
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
    try:
        text = report([load(path) for path in args.results])
    except ReportError as e:
        return fail(None, str(e))
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
