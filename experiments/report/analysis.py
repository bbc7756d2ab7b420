"""The report's numbers: results files loaded and merged, the rows each table picks, the bootstrap, the weights.

Nothing here formats markdown or draws: `experiments.report.markdown` and
`experiments.report.figures` do, from what these functions return.

- `load` reads one results file (`ape_jax.pipeline.results.load`, the one
  validator) and `merge` joins them per `Key(env, obs, protocol)`: results of
  one task under two protocols (the paper's `fca`, Brax's own `brax`) are
  different experiments, on different scales, and never mix;
- `_rows`, `_best`, `headline`, `comparisons`, `extra_methods` pick the
  configurations the tables show; method labels come from what each file
  records of its methods (`label`), then the registry, then the name;
- `bootstrap_difference`, `verdict`, `bootstrap_rows`: Ours − BC-OH and
  BC-OH − BC-SO (does the history help?) over seeds, per group;
- `copycat_map`: BC-SO, BC-OH and Ours per frame skip of the fca family, and
  the history's benefit at each (where copycat appears);
- `choices`: the paper's settings against the best of the grid;
- `weight_shares`: how concentrated each weighting is within a batch, on the
  raw APE and on the APE divided by its mean.

Protocols: a file's `protocol["name"]`; schema 1 files record none and ran
Brax's own settings, so they are `brax`. The *fca family* is `fca` (the
paper's MuJoCo-State setting, frame skip 1) and every protocol named
`fca-...` (the same setting at another frame skip, e.g. `fca-fs4`), told
apart by the `frame_skip` they record.

Tasks are told apart by their record (`ape_jax.tasks`), never by name: a task
judged by a rate (its main metric is not the return) is shown in %.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from ape_jax import methods as methods_lib
from ape_jax import tasks
from ape_jax.pipeline import results as results_lib
from experiments.report.paper import (PAPER_SENSITIVITY_TAU, PAPER_SENSITIVITY_W, PAPER_STEP, PAPER_TABLE5,
                                      PAPER_TAU)

BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED = 10_000, 0
# The state tables' tasks: those with an expert that are judged by their return (the MuJoCo tasks).
MUJOCO = tuple(t for t in tasks.sweepable() if tasks.get(t).metric == "return")


class ReportError(results_lib.ResultsError):
    """A results file that cannot be read or merged (one line, naming the file)."""


@dataclasses.dataclass
class Source(results_lib.Results):
    """One results file as the report read it: its `Results`, and where it came from."""

    path: str = ""


def load(path: str | pathlib.Path) -> Source:
    """Reads and validates one results file (`ReportError`, one line naming it, if it cannot be used)."""
    try:
        res = results_lib.load(path)
    except results_lib.ResultsError as e:
        raise ReportError(str(e)) from None
    if res.config.get("smoke"):
        raise ReportError(f"{path}: a --smoke run (its amounts shrunk to seconds, its numbers mean nothing); "
                          f"the report takes real runs only")
    return Source(**{f.name: getattr(res, f.name) for f in dataclasses.fields(results_lib.Results)}, path=str(path))


def main_metric(res: results_lib.Results) -> str:
    """What a results file is judged by: the metric it records, else its task's (schema 1 records none)."""
    return res.main_metric if "metric" in res.config else tasks.get(res.env).metric


BRAX, FCA = "brax", "fca"  # the protocol of files that record none; the paper's MuJoCo-State protocol


class Key(NamedTuple):
    """A merged group of results: one task, one observation mode, one protocol (its name), one training budget.

    `budget` is None for files that trained their preset's iterations, else their iterations (a run with
    `--iterations`, e.g. the long runs that ask whether more training changes a verdict): results at another
    budget are another experiment, shown apart and compared in "Training longer" (`longer_runs`).
    """

    env: str
    obs: str
    protocol: str
    budget: int | None = None


def budget_of(res: results_lib.Results) -> int | None:
    """`res`'s iterations where they differ from its base preset's (None: the base's, or a preset this code lacks).

    The base is the file's own preset, except for `paper`, whose base is `default`: a `paper` run is the same
    experiment trained longer (300k iterations where `default` trains 30k), a group of its own beside the `default`
    group, never merged into it.
    """
    from ape_jax.pipeline.presets import BUDGETS, resolve

    iterations = res.config.get("iterations")
    if res.preset not in BUDGETS or not isinstance(iterations, int):
        return None
    base = "default" if res.preset == "paper" else res.preset
    return None if iterations == resolve(res.env, res.obs, preset=base).budget.iterations else iterations


def in_fca_family(name: str) -> bool:
    """Whether protocol `name` is the paper's setting or a variant of it at another frame skip (`fca-...`)."""
    return name == FCA or name.startswith(FCA + "-")


def protocol_of(res: results_lib.Results, where: str = "") -> dict:
    """The protocol `res` ran under, its `name` filled in: `brax` for a file that records none (schema 1).

    Raises:
      ReportError: a protocol whose name is not a non-empty string, or whose `frame_skip` is not a positive int.
    """
    p = {**(res.protocol or {})}
    name = p.setdefault("name", BRAX)
    if not isinstance(name, str) or not name:
        raise ReportError(f"{where}: protocol field 'name' must be a non-empty string, got {name!r:.80}")
    skip = p.get("frame_skip")
    if skip is not None and not (isinstance(skip, int) and not isinstance(skip, bool) and skip >= 1):
        raise ReportError(f"{where}: protocol field 'frame_skip' must be an int >= 1 or null, got {skip!r:.80}")
    return p


def variant_name(res: results_lib.Results, protocol: dict) -> str:
    """The group name of a file's setting: its protocol's name for files split by episode with the `mlp` recipe (every
    file before results schema 3), else `NAME.SPLIT.RECIPE` (e.g. `fca.rows.fca`), a group of its own: the recipe
    section (`recipe_groups`, `recipe_rows`) compares them, and they never join the copycat map or the whole-episode tables."""
    split, recipe = protocol.get("split") or "episodes", res.recipe_name
    history, expert = other_history(protocol), protocol.get("expert")
    if (split, recipe, history, expert) == ("episodes", "mlp", None, None):
        return protocol["name"]
    return (f"{protocol['name']}.{split}.{recipe}" + ("" if history is None else f".h{history}")
            + ("" if expert is None else f".{expert}"))


def other_setting(protocol: dict) -> bool:
    """Whether a variant changes more than the split and the recipe: another history or another expert (such
    groups stay out of the recipe table and the paper-budget table, and are settings of their own in the map)."""
    return other_history(protocol) is not None or protocol.get("expert") is not None


def other_history(protocol: dict) -> int | None:
    """The protocol's history where it differs from its named protocol's (`--set protocol.history=7`), else None
    (the named protocol's, or a protocol this code does not know)."""
    named = tasks.PROTOCOLS.get(protocol.get("variant_of") or protocol.get("name"))
    history = protocol.get("history")
    return history if named is not None and isinstance(history, int) and history != named.history else None


def protocol_words(p: dict) -> str:
    """How titles name a protocol: `"fca"`, `"fca, frame skip 2"`, `"fca, 80,000 training transitions"` (the rest
    of the fca family, by what differs from fca), `"fca, split by rows, recipe fca"` (a variant, `variant_name`),
    else its name."""
    name = p["name"]
    if p.get("variant_of"):
        history = other_history(p)
        return (f"{p['variant_of']}, split by {p.get('split')}, recipe {p.get('recipe')}"
                + ("" if history is None else f", history {history}")
                + ("" if p.get("expert") is None else f", expert {p['expert']}"))
    if not in_fca_family(name) or name == FCA:
        return name
    differs = ([f"frame skip {p['frame_skip']}"] if p.get("frame_skip") not in (None, 1) else []) + \
        ([f"{p['train_transitions']:,} training transitions"]
         if p.get("train_transitions") not in (None, FCA_TRAIN) else [])
    return ", ".join([FCA, *differs]) if differs else name


def merge(files: Sequence[results_lib.Results]) -> dict[Key, dict]:
    """Results per `Key(env, obs, protocol name)`: summary rows and runs of all files, with the files they came from.

    Each value has `env`, `obs`, `protocol` (the files' protocol settings,
    `name` always set: `brax` for schema 1 files), `title` (how tables name
    the group: the task, its observation mode unless a state task's `pos`,
    and its protocol where `shows_protocol`: unless it is `brax` and the
    only protocol of that task and mode), `expert`, `summary`, `runs`, `sources` (the files), `methods`
    (what the files record of their methods, the first file naming one
    wins), `metric` (the main metric) and `task_metrics`.

    Raises:
      ReportError: the same configuration in two files of one group, files of
        one group with different experts or different protocol settings, or a
        malformed protocol.
    """
    merged: dict[Key, dict] = {}
    for r in files:
        where = getattr(r, "path", "") or f"a {r.env} ({r.obs}) results file"
        protocol = protocol_of(r, where)
        name = variant_name(r, protocol)
        if name != protocol["name"]:
            protocol = {**protocol, "name": name, "variant_of": protocol["name"], "recipe": r.recipe_name}
        key = Key(r.env, r.obs, name, budget_of(r))
        m = merged.setdefault(key, {"env": r.env, "obs": r.obs, "protocol": protocol, "budget": key.budget,
                                    "expert": r.expert,
                                    "summary": [], "runs": [], "sources": [], "methods": {}, "metric": main_metric(r),
                                    "task_metrics": tuple(r.config.get("task_metrics", tasks.get(r.env).metrics))})
        group = f"{r.env} ({r.obs}, protocol {key.protocol}" + (f", {key.budget:,} iterations)" if key.budget else ")")
        if m["expert"] != r.expert:
            raise ReportError(f"{where}: its expert differs from another {group} results file's")
        differ = [k for k in protocol.keys() & m["protocol"].keys()
                  if protocol[k] is not None and m["protocol"][k] is not None and protocol[k] != m["protocol"][k]]
        if differ:
            raise ReportError(f"{where}: its protocol differs from another {group} results file's (" + ", ".join(
                f"{k} {protocol[k]!r} vs {m['protocol'][k]!r}" for k in sorted(differ)) + ")")
        seen = {_config_key(row) for row in m["summary"]}
        for row in r.summary:
            if _config_key(row) in seen:
                raise ReportError(f"{where}: {row['method']} {row['hparams']} is also in another results "
                                  f"file of {group}; pass one of them")
        m["summary"] += r.summary
        m["runs"] += r.runs
        m["sources"].append(r)
        m["methods"] = {**r.methods, **m["methods"]}
        m["protocol"] = {**protocol, **{k: v for k, v in m["protocol"].items() if v is not None}}
    for key, m in merged.items():
        shared = any(k[:2] == key[:2] and k.protocol != key.protocol for k in merged)
        m["shows_protocol"] = key.protocol != BRAX or shared
        m["title"] = _title(key, m["protocol"], m["shows_protocol"])
        if key.budget:
            m["title"] = m["title"][:-1] + f", {key.budget:,} iterations)" if m["title"].endswith(")") else \
                m["title"] + f" ({key.budget:,} iterations)"
    return merged


def _config_key(row: dict) -> tuple:
    return row["method"], tuple(sorted(row["hparams"].items()))


def is_rate(m: dict) -> bool:
    """Whether the merged results of `m` are judged by a rate in [0, 1] (reported in %), not by the return."""
    return m["metric"] != "return"


# -- methods: labels and which ones the tables list ----------------------------------------------------------------

def known_methods(merged: dict) -> dict[str, dict]:
    """What the results files record of each method (label, role, online), over every environment."""
    out: dict[str, dict] = {}
    for _, m in _ordered(merged):
        out = {**m["methods"], **out}
    return out


def _registered(name: str) -> methods_lib.Method | None:
    try:
        return methods_lib.get(name)
    except methods_lib.MethodError:
        return None


def label(known: Mapping[str, dict], name: str, online: bool = True) -> str:
    """How tables name method `name`: the label its results file records, else the registry's, else the name;
    with `online`, an online method (one that queries the expert while training, DAgger) says so."""
    info, registered = known.get(name) or {}, _registered(name)
    text = info.get("label") or (registered.label if registered else "") or name
    is_online = info["online"] if "online" in info else bool(registered and registered.online)
    return text + (" (online)" if online and is_online else "")


def extra_methods(merged: dict) -> list[str]:
    """The methods besides the references and ours that appear in the results: role baseline in registry
    order (baselines the registry does not know after them), then plugins, in order of appearance."""
    known = known_methods(merged)
    appear = list(dict.fromkeys(r["method"] for _, m in _ordered(merged) for r in m["summary"]))
    order = {name: i for i, name in enumerate(methods_lib.names())}

    def role(name):
        registered = _registered(name)
        return (known.get(name) or {}).get("role") or (registered.role if registered else "plugin")

    def key(name):
        if role(name) == "baseline":
            return 0, order.get(name, len(order)), appear.index(name)
        return 1, 0, appear.index(name)

    return sorted((n for n in appear if role(n) in ("baseline", "plugin")), key=key)


# -- selection -----------------------------------------------------------------------------------------------------

def _rows(m: dict, method: str) -> list[dict]:
    return [r for r in m["summary"] if r["method"] == method and r["n_seeds"]]


def _best(rows: list[dict]) -> dict | None:
    """The row with the highest % of expert (a task judged by a rate: that rate), or return where that is missing."""
    def score(r):
        return r["normalized_mean"] if r.get("normalized_mean") is not None else r["return_mean"]

    return max(rows, key=score, default=None)


def _paper_step(m: dict) -> dict | None:
    """The summary row of Ours at the paper's step setting (THR 10%, W 5), or None if not run."""
    return next((r for r in _rows(m, "ours-step") if r["hparams"] == PAPER_STEP), None)


def thousands(x: float) -> str:
    """`30000 -> "30k"`, `2500 -> "2.5k"`, `2 -> "2"`: iterations, sizes and frame skips in headings and ticks."""
    return f"{x / 1000:g}k" if x >= 1000 else f"{x:g}"


def _pct(thr: float) -> str:
    """A fraction as a percentage, `0.1 -> "10%"`."""
    return f"{100 * thr:g}%"


def _hp(row: dict | None) -> str:
    """A configuration's hyperparameters, `" (thr 0.2, w 3)"`; "" for None."""
    if row is None:
        return ""
    return " (" + ", ".join(f"{k} {v:g}" for k, v in row["hparams"].items()) + ")"


def headline(m: dict, extras: Sequence[str] = (), known: Mapping[str, dict] | None = None
             ) -> list[tuple[str, dict | None]]:
    """The state table's rows of one group (task, observation mode, protocol): (label, summary row or None).

    BC-SO, BC-OH, Ours at the paper's step setting and the best step and
    softmax settings, then each of `extras` (`extra_methods`), labelled from
    `known` (default: what `m`'s files record).
    """
    known = m["methods"] if known is None else known
    best_step, best_soft = _best(_rows(m, "ours-step")), _best(_rows(m, "ours-softmax"))
    out = [("BC-SO", _best(_rows(m, "bc-so"))), ("BC-OH", _best(_rows(m, "bc-oh"))),
           ("Ours, step THR 10% W 5", _paper_step(m)),
           (f"Ours, best step{_hp(best_step)}", best_step),
           (f"Ours, best softmax{_hp(best_soft)}", best_soft)]
    out += [(label(known, method), _best(_rows(m, method))) for method in extras]
    return out


def _seeds(m: dict, row: dict | None, key: str = "return_mean") -> list[float]:
    """Per-seed evaluation values (`eval[key]`) of the configuration of summary row `row`, in seed order."""
    if row is None:
        return []
    runs = [r for r in m["runs"] if r["method"] == row["method"] and r["hparams"] == row["hparams"]
            and r["status"] == "ok" and r["eval"].get(key) is not None]
    return [r["eval"][key] for r in sorted(runs, key=lambda r: r.get("seed", 0))]


def _ok_runs(m: dict, method: str, hparams: dict) -> list[dict]:
    return [r for r in m["runs"] if r["method"] == method and r["hparams"] == hparams and r["status"] == "ok"]


def comparisons(m: dict) -> list[tuple[str, dict | None]]:
    """Ours' configurations compared with BC-OH: the paper's step setting, then the best step and softmax."""
    best_step, best_soft = _best(_rows(m, "ours-step")), _best(_rows(m, "ours-softmax"))

    def after(row: dict | None) -> str:
        return "" if row is None else f" ({_hp(row)[2:-1]}; selected after the fact)"

    return [("Ours, step THR 10% W 5 (the paper's)", _paper_step(m)),
            (f"Ours, best step{after(best_step)}", best_step), (f"Ours, best softmax{after(best_soft)}", best_soft)]


def task_metric_rows(m: dict) -> list[tuple[str, str, list[dict]]]:
    """The task-metrics table's policies (the supplement's Table 4 protocol): `(label, method, ok runs)` of
    BC-SO, BC-OH and Ours at THR 10%, W 5, those that ran."""
    wanted = (("BC-SO", "bc-so", {}), ("BC-OH", "bc-oh", {}), ("Ours, step THR 10% W 5", "ours-step", PAPER_STEP))
    return [(lab, method, runs) for lab, method, hp in wanted if (runs := _ok_runs(m, method, hp))]


def loss_rows(m: dict) -> list[tuple[str, list[dict]]]:
    """The loss analysis' policies: BC-SO, BC-OH, Ours at the paper's step setting and the best step
    (where it differs), each with its ok runs; those without runs left out."""
    wanted = [("BC-SO", "bc-so", {}), ("BC-OH", "bc-oh", {}), ("Ours, step THR 10% W 5", "ours-step", PAPER_STEP)]
    best = _best(_rows(m, "ours-step"))
    if best is not None and best["hparams"] != PAPER_STEP:
        wanted.append((f"Ours, best step{_hp(best)}", "ours-step", best["hparams"]))
    return [(lab, runs) for lab, method, hp in wanted if (runs := _ok_runs(m, method, hp))]


def copycat_groups(m: dict) -> dict[tuple, list[dict]]:
    """The ok runs that record the copycat diagnostics (`rollout_ape`, `imitation_error`), per configuration."""
    groups: dict[tuple, list[dict]] = {}
    for r in m["runs"]:
        if r["status"] == "ok" and "rollout_ape" in r["eval"] and "imitation_error" in r["eval"]:
            groups.setdefault(_config_key(r), []).append(r)
    return groups


def expert_ape(m: dict) -> float | None:
    """The validation demonstrations' mean APE ÷ the raw training mean (the scale of the policies' `rollout_ape`),
    from the first of `m`'s files that records enough to put it on that scale.

    `config["ape"]["val_mean"]` is the mean of the APE the file trained on. Times `scale` ÷ `raw_mean` (the raw
    training mean, recorded since the raw-APE default, or added by `experiments.evaluate`) it is on
    `rollout_ape`'s scale; a file without `raw_mean` trained with `normalization: "mean"` (or none recorded: those
    predate `"none"`) is already on it. A `"none"` file without `raw_mean` gives none.
    """
    for src in m["sources"]:
        ape = src.config.get("ape")
        if not isinstance(ape, dict) or "val_mean" not in ape:
            continue
        if ape.get("raw_mean"):
            return ape["val_mean"] * ape.get("scale", 1.0) / ape["raw_mean"]
        if ape.get("normalization", "mean") == "mean":
            return ape["val_mean"]
    return None


def sensitivity(m: dict) -> tuple[list[tuple[float, dict | None]], list[tuple[float, dict | None]]]:
    """The sensitivity study's rows: per τ of the paper's and per W (at THR 10%) of the paper's, our summary row."""
    rows = {_config_key(r): r for r in m["summary"] if r["n_seeds"]}
    tau = [(t, rows.get(("ours-softmax", (("tau", t),)))) for t in PAPER_SENSITIVITY_TAU]
    w = [(x, rows.get(("ours-step", (("thr", 0.1), ("w", x))))) for x in PAPER_SENSITIVITY_W]
    return tau, w


# -- Ours − BC-OH: bootstrap over seeds ----------------------------------------------------------------------------

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
    low, high = _percentiles(_resampled_means(a, rng, resamples) - _resampled_means(b, rng, resamples), level)
    return Interval(float(a.mean() - b.mean()), float(low), float(high), int(a.size), int(b.size))


def bootstrap_mean(values: Sequence[float], resamples: int = BOOTSTRAP_RESAMPLES, level: float = 0.95,
                   seed: int = BOOTSTRAP_SEED) -> tuple[float, float, float]:
    """`(mean, low, high)`: the mean of per-seed `values` with its percentile bootstrap interval (seeds resampled
    with replacement; the same inputs always give the same interval)."""
    x = np.asarray(values, np.float64)
    if x.ndim != 1 or not x.size:
        raise ValueError(f"bootstrap_mean needs a non-empty 1-d array, got shape {x.shape}")
    low, high = _percentiles(_resampled_means(x, np.random.default_rng(seed), resamples), level)
    return float(x.mean()), float(low), float(high)


def _resampled_means(x: np.ndarray, rng: np.random.Generator, resamples: int) -> np.ndarray:
    return x[rng.integers(0, x.size, size=(resamples, x.size))].mean(1)


def _percentiles(replicates: np.ndarray, level: float) -> tuple[float, float]:
    tail = 100 * (1 - level) / 2
    low, high = np.percentile(replicates, [tail, 100 - tail])
    return float(low), float(high)


def verdict(ci: Interval, a: str = "Ours", b: str = "BC-OH") -> str:
    """Plain words: `a` better / `b` better when the interval excludes 0, else not significant."""
    if min(ci.n_a, ci.n_b) < 2:
        return "no verdict (needs ≥ 2 seeds per arm)"
    if ci.low > 0:
        return f"{a} better"
    if ci.high < 0:
        return f"{b} better"
    return "not significant (CI contains 0)"


def _unit(m: dict) -> tuple[str, str, float]:
    """What the bootstrap compares in a group: `(eval key, unit, factor)`: the mean return, or for a task judged by a
    rate (whose reward is not its measure) that rate in % points."""
    return (m["metric"], f"{m['metric']}, % points", 100.0) if is_rate(m) else ("return_mean", "return", 1.0)


class Difference(NamedTuple):
    """One comparison over seeds in one group: `a − b` with its bootstrap interval (`bootstrap_rows`).

    `kind` is `"history"` (BC-OH − BC-SO: does the history help?) or `"ours"` (a configuration of Ours −
    BC-OH); `label` says what is compared, `a` and `b` name the arms for `verdict`, `unit` the numbers'.
    """

    key: Key
    title: str
    kind: str
    label: str
    a: str
    b: str
    ci: Interval
    unit: str


def _unit_seeds(m: dict, row: dict | None, key: str | None = None, factor: float | None = None) -> list[float]:
    """`_seeds` of summary row `row` in `_unit(m)` (or of `eval[key] × factor`), what the bootstrap compares."""
    default_key, _, default_factor = _unit(m)
    factor = default_factor if factor is None else factor
    return [factor * v for v in _seeds(m, row, key or default_key)]


def history_difference(m: dict, key: str | None = None, factor: float | None = None) -> Interval | None:
    """BC-OH − BC-SO over seeds in group `m` (each the best of its rows), by default in `_unit(m)`; None if either
    has no seeds. With `key`/`factor`, of `eval[key] × factor` instead (`"normalized"`, 1: % of expert points)."""
    bcoh = _unit_seeds(m, _best(_rows(m, "bc-oh")), key, factor)
    bcso = _unit_seeds(m, _best(_rows(m, "bc-so")), key, factor)
    return bootstrap_difference(bcoh, bcso) if bcoh and bcso else None


def ours_differences(m: dict) -> list[tuple[str, dict, Interval]]:
    """Ours − BC-OH over seeds in group `m`, in `_unit(m)`: `(label, Ours' summary row, interval)` per configuration
    of `comparisons` that has seeds (none if BC-OH has none)."""
    bcoh = _unit_seeds(m, _best(_rows(m, "bc-oh")))
    out = []
    for lab, row in comparisons(m) if bcoh else []:
        ours = _unit_seeds(m, row)
        if ours:
            out.append((lab, row, bootstrap_difference(ours, bcoh)))
    return out


def versus_bcoh(m: dict, extras: Sequence[str] = (), known: Mapping[str, dict] | None = None
                ) -> list[tuple[str, dict | None, Interval | None]]:
    """Every row of the state table of group `m` (`headline`) but BC-OH, against BC-OH: `(label, summary row,
    row − BC-OH over seeds in `_unit(m)`, or None where either arm has no seeds)`."""
    bcoh = _unit_seeds(m, _best(_rows(m, "bc-oh")))
    out = []
    for lab, row in headline(m, extras, known):
        if lab == "BC-OH":
            continue
        values = _unit_seeds(m, row)
        out.append((lab, row, bootstrap_difference(values, bcoh) if values and bcoh else None))
    return out


def bootstrap_rows(merged: dict) -> list[Difference]:
    """Per group (task, observation mode, protocol), in report order: BC-OH − BC-SO ("does the history help?"),
    then Ours − BC-OH per configuration of `comparisons`, each with its 95% CI, in `_unit`."""
    out = []
    for key, m in _ordered(merged):
        unit = _unit(m)[1]
        history = history_difference(m)
        if history is not None:
            out.append(Difference(key, m["title"], "history", "BC-OH − BC-SO (does the history help?)", "BC-OH",
                                  "BC-SO", history, unit))
        out += [Difference(key, m["title"], "ours", f"{lab} − BC-OH", "Ours", "BC-OH", ci, unit)
                for lab, _, ci in ours_differences(m)]
    return out


# -- the copycat map: the history's benefit per frame skip ---------------------------------------------------------

# The map's methods, (label, method, hparams: None for the best of its rows).
MAP_METHODS = (("BC-SO", "bc-so", None), ("BC-OH", "bc-oh", None), ("Ours, step THR 10% W 5", "ours-step", PAPER_STEP))


class MapCell(NamedTuple):
    """One method at one frame skip: % of expert, mean and std over seeds, the seeds, and each seed's value."""

    mean: float
    std: float
    n: int
    seeds: tuple[float, ...]


class MapRow(NamedTuple):
    """One frame skip of the copycat map.

    `cells` are aligned with `MAP_METHODS` (None: not run there); `history` is
    BC-OH − BC-SO in points of % of expert (means from the summary) and
    `history_ci` its bootstrap interval over seeds; `ceiling` is BC-OH's gap to
    the expert, 100 − BC-OH's % of expert. Each is None where its methods did not run.
    """

    frame_skip: int
    protocol: str
    cells: tuple[MapCell | None, ...]
    history: float | None
    history_ci: Interval | None
    ceiling: float | None
    train_transitions: int | None = None


class CopycatMap(NamedTuple):
    """One task's copycat map: `rows`, one per frame skip of the fca family at fca's training-set size, in
    increasing order; `data_rows`, one per training-set size at frame skip 1 (fca's own size included) where the
    files hold other sizes (`fca-train5k`, `fca-train80k`), in increasing order, else empty."""

    env: str
    obs: str
    title: str
    rows: list[MapRow]
    data_rows: list[MapRow] = []

    def at(self, frame_skip: int) -> MapRow | None:
        return next((r for r in self.rows if r.frame_skip == frame_skip), None)


FCA_TRAIN = 20_000  # fca's training transitions: the frame-skip rows of the map all have it


def _map_cell(m: dict, method: str, hparams: dict | None) -> MapCell | None:
    row = _map_row_of(m, method, hparams)
    if row is None or row.get("normalized_mean") is None:
        return None
    seeds = tuple(_seeds(m, row, "normalized"))
    std = row.get("normalized_std")
    return MapCell(float(row["normalized_mean"]), math.nan if std is None else float(std), int(row["n_seeds"]), seeds)


def copycat_map(merged: dict) -> list[CopycatMap]:
    """Where copycat appears: per task with fca-family results at ≥ 2 frame skips, BC-SO, BC-OH and Ours (step THR 10%
    W 5) in % of expert per frame skip, with the history's benefit (BC-OH − BC-SO) and BC-OH's gap to the expert.

    The fca family is one protocol at several frame skips (the same simulated horizon and training-set size),
    so its rows differ only in how often the policy acts: copycat, a policy that repeats its last action
    because its history predicts it, should grow with the frame rate. A group that holds more methods
    or seeds than the map needs (the fca file's full grid) gives only the rows of those three methods.

    Raises:
      ReportError: two protocols of the fca family at one frame skip for one task.
    """
    by_task: dict[tuple[str, str], dict[tuple[int, int], dict]] = {}
    for key, m in _ordered(merged):
        skip, train = m["protocol"].get("frame_skip"), m["protocol"].get("train_transitions") or FCA_TRAIN
        if (not in_fca_family(key.protocol) or m["protocol"].get("variant_of") or skip is None
                or key.budget is not None):  # the map of the first recipe; the extended map has the variants
            continue
        cells = by_task.setdefault((key.env, key.obs), {})
        if (skip, train) in cells:
            raise ReportError(f"{key.env} ({key.obs}): protocols {cells[skip, train]['protocol']['name']} and "
                              f"{key.protocol} both ran at frame skip {skip} with {train:,} training transitions; "
                              "pass the files of one of them")
        cells[skip, train] = m
    out = []
    for (env, obs), cells in by_task.items():
        rows = [_map_row(cells[k], *k) for k in sorted(cells) if k[1] == FCA_TRAIN]
        data = [_map_row(cells[k], *k) for k in sorted(cells, key=lambda k: k[1]) if k[0] == 1]
        data = data if any(r.train_transitions != FCA_TRAIN for r in data) else []
        if len(rows) < 2 and not data:
            continue
        out.append(CopycatMap(env, obs, _title(Key(env, obs, FCA), {"name": FCA}, with_protocol=False), rows, data))
    return out


def _map_row(m: dict, skip: int, train: int) -> MapRow:
    cells = tuple(_map_cell(m, method, hp) for _, method, hp in MAP_METHODS)
    bcso, bcoh = cells[0], cells[1]
    history = None if bcso is None or bcoh is None else bcoh.mean - bcso.mean
    ci = (bootstrap_difference(bcoh.seeds, bcso.seeds)
          if bcso is not None and bcoh is not None and bcso.seeds and bcoh.seeds else None)
    return MapRow(skip, m["protocol"]["name"], cells, history, ci, None if bcoh is None else 100.0 - bcoh.mean,
                  train)


# -- grid search: the paper's choices ------------------------------------------------------------------------------

def _metric(m: dict) -> tuple[str, str]:
    """Which summary numbers the figures show: `(prefix, unit)`; % of expert where every row has it (a task
    judged by a rate: that rate, in %)."""
    if all(r.get("normalized_mean") is not None for r in m["summary"] if r["n_seeds"]):
        return "normalized", f"{m['metric']} %" if is_rate(m) else "% of expert"
    return "return", "return"


def _value(row: dict, prefix: str) -> tuple[float, float]:
    mean, std = row[f"{prefix}_mean"], row.get(f"{prefix}_std")
    return float(mean), float(std if std is not None else math.nan)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _ape_scale(m: dict) -> float | None:
    """The training-set mean APE our softmax τ divided by (`ape_normalization: "mean"`), or None."""
    for r in m["sources"]:
        ape = r.config.get("ape")
        if (any(row["method"] == "ours-softmax" for row in r.summary) and isinstance(ape, dict)
                and ape.get("normalization") == "mean" and _number(ape.get("scale")) and ape["scale"] > 0):
            return float(ape["scale"])
    return None


class Gap(NamedTuple):
    """A setting against the grid's best: `(mean, std)` of each, `best − chosen`, and the noise (larger std)."""

    chosen: tuple[float, float]
    best: tuple[float, float]
    gap: float
    noise: float
    is_best: bool

    @property
    def within(self) -> bool:
        """Within one std over seeds: the gap is at most the larger of the two settings' std."""
        return self.gap <= self.noise


def gap(chosen: dict, best: dict, prefix: str) -> Gap:
    (cm, cs), (bm, bs) = _value(chosen, prefix), _value(best, prefix)
    return Gap((cm, cs), (bm, bs), bm - cm, max(cs, bs), chosen is best)


class Choice(NamedTuple):
    """One weighting's paper setting against our grid (`choices`).

    `chosen` is the paper's setting's row (None: not run), `best` the grid's
    best, `rows` the grid; where our APE was divided by its training-set mean
    (`scale`), `equivalent` is the paper's τ on that scale and `closest` the
    grid's row nearest to it (else None).
    """

    kind: str
    paper: dict
    chosen: dict | None
    best: dict
    rows: list[dict]
    scale: float | None = None
    equivalent: float | None = None
    closest: dict | None = None


def choices(m: dict) -> list[Choice]:
    """Per weighting (step, softmax) that ran and has a paper setting: the paper's setting against the grid."""
    prefix, _ = _metric(m)
    tau = PAPER_TAU.get(m["env"])
    out = []
    for kind, method, paper in (("step", "ours-step", PAPER_STEP),
                                ("softmax", "ours-softmax", None if tau is None else {"tau": tau})):
        rows = _rows(m, method)
        if not rows or paper is None:
            continue
        best = max(rows, key=lambda r: _value(r, prefix)[0])
        chosen = next((r for r in rows if r["hparams"] == paper), None)
        choice = Choice(kind, paper, chosen, best, rows)
        scale = _ape_scale(m) if kind == "softmax" else None
        taus = [r for r in rows if r["hparams"].get("tau", 0) > 0]
        if scale is not None and taus:
            equivalent = tau / scale
            closest = min(taus, key=lambda r: abs(math.log(r["hparams"]["tau"] / equivalent)))
            choice = choice._replace(scale=scale, equivalent=equivalent, closest=closest)
        out.append(choice)
    return out


# -- weights within a batch ----------------------------------------------------------------------------------------

# The two APE scales a softmax weighting can act on (`config["ape"]["normalization"]`), as the report names them.
APE_SCALES = {"none": "raw APE (the official code, our default)", "mean": "APE ÷ its mean (the old default)"}


class WeightShares(NamedTuple):
    """How concentrated a group's weights are within a batch, on both APE scales (`weight_shares`).

    `trained` is the scale the group's softmax runs trained on (`"none"`: raw APE, `"mean"`: APE ÷ its training
    mean), `mean_ape` the raw training APE's mean (`ape_mean`: the recorded one where the file trained on APE ÷
    its mean, else estimated from its quantile function; `mean_recorded` says which), and `series`
    `[(label, raw, by_mean)]`, `raw[k-1]` / `by_mean[k-1]` (`[batch]` float64) the mean over batches of the share
    of the total weight the k heaviest samples carry with the weights computed on the raw APE / on the APE ÷
    `mean_ape` (`by_mean` None when the mean is 0: every sample's APE is 0).
    """

    title: str
    trained: str
    mean_ape: float
    mean_recorded: bool
    series: list[tuple[str, np.ndarray, np.ndarray | None]]


def _quantile_source(m: dict) -> results_lib.Results | None:
    """The file of group `m` whose APE quantiles the weights are drawn from: one that ran the softmax weighting
    (it trained on that file's APE), else the first that records them (with the scale they are on)."""
    def usable(ape) -> bool:  # quantiles, and what they are the quantiles of
        return (isinstance(ape, dict) and bool(ape.get("quantiles")) and ape.get("normalization") in APE_SCALES
                and (ape["normalization"] == "none" or (_number(ape.get("scale")) and ape["scale"] > 0)))

    recorded = [src for src in m["sources"] if usable(src.config.get("ape"))]
    return next((src for src in recorded if any(r["method"] == "ours-softmax" for r in src.summary)),
                recorded[0] if recorded else None)


def raw_quantiles(ape: Mapping) -> np.ndarray:
    """The raw training APE's quantiles `[Q]` from a file's `config["ape"]`: its `quantiles` are of the APE it
    trained on, raw (`"none"`) or divided by its training mean, the recorded `scale` (`"mean"`)."""
    q = np.asarray(ape["quantiles"], np.float64)
    return q * float(ape["scale"]) if ape["normalization"] == "mean" else q


def quantile_mean(q: np.ndarray) -> float:
    """The mean of a distribution from its quantiles `[Q]` at evenly spaced levels 0..1: ∫₀¹ F⁻¹(p) dp, trapezoid.

    Exactly the mean of the batches `weight_shares` draws (the quantile function interpolated linearly); of a
    heavy-tailed APE it overstates the true mean, the last interval being a straight line up to the maximum
    (on the committed files' APE, by 10-40%).
    """
    q = np.asarray(q, np.float64)
    return float(((q[1:] + q[:-1]) / 2).mean())


def ape_mean(ape: Mapping) -> tuple[float, bool]:
    """The raw training APE's mean from a file's `config["ape"]`, and whether it was recorded: a file that trained on
    APE ÷ its mean records that mean as its `scale`, and sweeps since the raw-APE default record it as `raw_mean`;
    otherwise it is estimated from the quantiles (`quantile_mean`)."""
    if _number(ape.get("raw_mean")) and ape["raw_mean"] > 0:   # recorded by sweeps since the raw-APE default
        return float(ape["raw_mean"]), True
    if ape["normalization"] == "mean" and _number(ape.get("scale")) and ape["scale"] > 0:
        return float(ape["scale"]), True
    return quantile_mean(raw_quantiles(ape)), False


def weight_shares(merged: dict, batch: int = 128, batches: int = 400) -> list[WeightShares]:
    """How concentrated the weights are within a batch, per group that records its APE quantiles and ran softmax.

    Batches of `batch` are drawn from the group's training APE distribution (its quantiles, `_quantile_source`)
    and weighted as the sweep does, `batch·softmax(APE/τ)` at every τ the group ran, the paper's step setting
    and uniform weights, once on the raw APE and once on the APE ÷ its mean (`ape_mean`). The step and
    uniform weights depend only on the APE's ranks, so they are the same on both scales; the softmax's are not:
    dividing the APE by a mean much below 1 multiplies it by much more than 1, and a τ ≤ 1 then gives one
    sample nearly all of a batch's weight. Each group draws its batches with numpy seed 0.

    Returns:
      `WeightShares` per group, in report order.
    """
    def share(w):  # [batches, batch] -> [batch]
        top = -np.sort(-w, axis=1)
        return (np.cumsum(top, axis=1) / top.sum(1, keepdims=True)).mean(0)

    def softmax(z):
        return np.exp(z - z.max(1, keepdims=True))

    out = []
    for _, m in _ordered(merged):
        src = _quantile_source(m)
        taus = sorted({r["hparams"]["tau"] for r in _rows(m, "ours-softmax") if r["hparams"].get("tau", 0) > 0})
        if src is None or not taus:
            continue
        q = raw_quantiles(src.config["ape"])
        mean, recorded = ape_mean(src.config["ape"])
        levels = np.linspace(0, 1, len(q))
        raw = np.interp(np.random.default_rng(0).uniform(size=(batches, batch)), levels, q)
        by_mean = raw / mean if mean > 0 else None
        step = np.interp(1 - PAPER_STEP["thr"], levels, q)
        series = [(f"softmax τ {tau:g}", share(softmax(raw / tau)),
                   None if by_mean is None else share(softmax(by_mean / tau))) for tau in taus]
        weighted = share(np.where(raw >= step, PAPER_STEP["w"], 1.0))
        series.append((f"step THR {_pct(PAPER_STEP['thr'])} W {PAPER_STEP['w']:g}", weighted,
                       None if by_mean is None else weighted))
        uniform = np.arange(1, batch + 1) / batch
        series.append(("uniform (BC-OH)", uniform, uniform))
        out.append(WeightShares(m["title"], src.config["ape"]["normalization"], mean, recorded, series))
    return out


# -- groups: order, titles, file names ----------------------------------------------------------------------------

def _protocol_rank(p: dict) -> tuple:
    """Protocols in report order: the fca family by frame skip (the paper's first), then `brax`, then others."""
    if in_fca_family(p["name"]):
        return 0, p.get("frame_skip") or 0, p["name"]
    return (1, 0, "") if p["name"] == BRAX else (2, 0, p["name"])


def _ordered(merged: dict) -> list[tuple[Key, dict]]:
    """`merged`'s items: the sweepable tasks first in their order (`ape_jax.tasks.sweepable`), then by name; within a
    task by observation mode, then protocol (`_protocol_rank`)."""
    order = {e: i for i, e in enumerate(tasks.sweepable())}
    return sorted(merged.items(), key=lambda kv: (order.get(kv[0][0], len(order)), kv[0][0], kv[0][1],
                                                  _protocol_rank(kv[1]["protocol"]), kv[0].budget or 0))


def _title(key: Key, protocol: dict, with_protocol: bool, with_obs: bool | None = None) -> str:
    """A group's title: `"Hopper"`, `"Hopper (image)"`, `"Hopper (fca, frame skip 2)"`, `"Hopper (image, brax)"`;
    the observation mode unless `with_obs` is False (default: unless a state task's `pos`)."""
    with_obs = not (key.obs == "pos" and key.env in MUJOCO) if with_obs is None else with_obs
    parts = [key.obs] if with_obs else []
    parts += [protocol_words(protocol)] if with_protocol else []
    return tasks.get(key.env).title + (f" ({', '.join(parts)})" if parts else "")


def file_stem(m: dict) -> str:
    """A group's part of figure file names, unique per group: `hopper`, `hopper-image`, `hopper-fca-fs2`.

    `brax` groups keep the names they had before protocols existed; other protocols append their name.
    """
    parts = [m["env"]] + ([] if m["obs"] == "pos" else [m["obs"]])
    parts += [] if m["protocol"]["name"] == BRAX else [m["protocol"]["name"]]
    parts += [f"{m['budget']}it"] if m.get("budget") else []
    return "-".join(parts)


def groups_of(merged: dict, obs: str, protocol: str) -> list[dict]:
    """The state tasks' (`MUJOCO`) groups with observations `obs` under `protocol`, in task order."""
    return [merged[k] for e in MUJOCO if (k := Key(e, obs, protocol)) in merged]


def protocols_of(merged: dict, obs: str) -> list[str]:
    """The protocols of the state tasks' groups with observations `obs`, in report order (`_protocol_rank`)."""
    found = {m["protocol"]["name"]: m["protocol"] for k, m in _ordered(merged) if k.env in MUJOCO and k.obs == obs}
    return sorted(found, key=lambda n: _protocol_rank(found[n]))


def envs_of(merged: dict, obs: str, protocol: str = BRAX) -> list[str]:
    """The state tasks (`MUJOCO`) `merged` has results of with observations `obs` under `protocol`, in order."""
    return [m["env"] for m in groups_of(merged, obs, protocol)]


# -- training longer -----------------------------------------------------------------------------------------------

class LongerRow(NamedTuple):
    """One configuration at its preset's budget and at a longer one: `base`, `longer` summary rows."""

    label: str
    base: dict
    longer: dict


def longer_runs(merged: dict) -> list[tuple[dict, dict, list[LongerRow]]]:
    """Groups trained at another budget than their preset's (`Key.budget`), each beside its preset-budget group
    (same task, observation mode and protocol): `[(longer group, base group, rows)]`, one row per configuration
    both ran, in the longer group's order. Groups without a base group, or with no configuration in common,
    are left out."""
    out = []
    for key, m in _ordered(merged):
        base = merged.get(Key(key.env, key.obs, key.protocol)) if key.budget else None
        if base is None:
            continue
        rows = {_config_key(r): r for r in base["summary"] if r["n_seeds"]}
        pairs = [LongerRow(_row_label(m, r), rows[_config_key(r)], r) for r in m["summary"]
                 if r["n_seeds"] and _config_key(r) in rows]
        if pairs:
            out.append((m, base, pairs))
    return out


def _row_label(m: dict, row: dict) -> str:
    """`"BC-OH"`, `"Ours (step), THR 10% W 5"`, `"Ours (softmax), τ 0.2"`, `"FCA, alpha 0.1"`."""
    hp = dict(row["hparams"])
    words = ([f"THR {_pct(hp.pop('thr'))} W {hp.pop('w'):g}"] if {"thr", "w"} <= hp.keys() else []) + \
        ([f"τ {hp.pop('tau'):g}"] if "tau" in hp else []) + [f"{k} {v:g}" for k, v in hp.items()]
    return ", ".join([label(m["methods"], row["method"]), *words])


# -- the paper's recipe: mlp against fca under one protocol ------------------------------------------------------

# The recipe table's methods, (label, method, hparams: None for the task's default FCA setting).
RECIPE_METHODS = (("BC-SO", "bc-so", {}), ("BC-OH", "bc-oh", {}), ("Ours, step THR 10% W 5", "ours-step", PAPER_STEP),
                  ("FCA (TCA)", "fca", None), ("FCA (TCA + IB)", "fca-ib", None))


class RecipeCell(NamedTuple):
    """One method under one recipe: % of expert, the mean over seeds with its 95% bootstrap interval, the seeds."""

    mean: float
    low: float
    high: float
    seeds: tuple[float, ...]


class RecipeRow(NamedTuple):
    """One task and method: a cell per recipe (None: not run), and fca − mlp with its interval (None: not both)."""

    env: str
    label: str
    cells: dict[str, RecipeCell | None]
    difference: Interval | None


def _recipe_row(m: dict, method: str, hparams: dict | None) -> dict | None:
    rows = _rows(m, method)
    if hparams is None:  # FCA: the task's own α (the FCA code's), the first setting otherwise
        alpha = tasks.get(m["env"]).fca_alpha
        rows = [r for r in rows if r["hparams"].get("alpha") == alpha] or rows[:1]
    else:
        rows = [r for r in rows if r["hparams"] == hparams]
    return rows[0] if rows else None


def recipe_groups(merged: dict) -> dict[tuple[str, str, str], dict[str, dict]]:
    """`{(env, obs, "PROTOCOL, split by SPLIT"): {recipe: group}}` for the groups of `variant_name`s that ran at
    their preset's budget; only settings with more than one recipe."""
    out: dict = {}
    for key, m in _ordered(merged):
        p = m["protocol"]
        if p.get("variant_of") and key.budget is None and not other_setting(p):
            out.setdefault((key.env, key.obs, f"{p['variant_of']}, split by {p.get('split')}"), {})[p["recipe"]] = m
    return {k: v for k, v in out.items() if len(v) > 1}


def recipe_rows(recipes: dict[str, dict], order: Sequence[str] = ("mlp", "fca")) -> list[RecipeRow]:
    """Per method of `RECIPE_METHODS` that ran under some recipe: its % of expert per recipe (bootstrap mean) and
    fca − mlp (bootstrap difference of means over seeds, in points of % of expert)."""
    names = [r for r in order if r in recipes] + [r for r in recipes if r not in order]
    out = []
    for lab, method, hparams in RECIPE_METHODS:
        cells = {}
        for name in names:
            seeds = _seeds(recipes[name], _recipe_row(recipes[name], method, hparams), "normalized")
            cells[name] = RecipeCell(*bootstrap_mean(seeds), tuple(seeds)) if seeds else None
        if not any(cells.values()):
            continue
        env = next(iter(recipes.values()))["env"]
        both = len(names) >= 2 and cells[names[0]] is not None and cells[names[1]] is not None
        diff = bootstrap_difference(cells[names[1]].seeds, cells[names[0]].seeds) if both else None
        out.append(RecipeRow(env, lab, cells, diff))
    return out


class AlphaRow(NamedTuple):
    """FCA at one α: % of expert over seeds (bootstrap mean), and its adversary's final loss against the reference
    predictor of a_{t−1} from a_t alone (means over seeds; None where the files predate them)."""

    method: str
    hparams: dict
    cell: RecipeCell
    adversary: float | None
    reference: float | None


def alpha_rows(m: dict) -> list[AlphaRow]:
    """Every FCA configuration of group `m` (both variants), in α order: the α sensitivity."""
    out = []
    for method in ("fca", "fca-ib"):
        for row in sorted(_rows(m, method), key=lambda r: tuple(sorted(r["hparams"].items()))):
            seeds = _seeds(m, row, "normalized")
            if not seeds:
                continue
            runs = [r for r in m["runs"] if r["method"] == method and r["hparams"] == row["hparams"]
                    and r["status"] == "ok"]
            finals = [r.get("train_final") or {} for r in runs]

            def mean_of(k, finals=finals):
                values = [f[k] for f in finals if f.get(k) is not None]
                return float(np.mean(values)) if values else None

            out.append(AlphaRow(method, row["hparams"], RecipeCell(*bootstrap_mean(seeds), tuple(seeds)),
                                mean_of("adversary_loss"), mean_of("reference_loss")))
    return out


# -- copycat diagnostics per policy (`ape_jax.diagnostics`, each run's `diagnostics`) -------------------------------

class Spread(NamedTuple):
    """A ratio over a configuration's seeds: the median and the seeds' range, over the `n` seeds that recorded it."""

    median: float
    low: float
    high: float
    n: int


class PolicyDiagnostics(NamedTuple):
    """The copycat diagnostics of one configuration's seeds (`policy_diagnostics`).

    `read` counts the seeds whose diagnostics could be read (`copycats` of them judged copycat); `embedding`,
    `velocity` and `predictability` are the ratios over those seeds (None where no seed recorded one: e.g.
    velocity on data without `qvel`); `absent` the distinct reasons of the seeds the diagnostics could not read,
    with how many seeds gave each.
    """

    read: int
    copycats: int
    embedding: Spread | None
    velocity: Spread | None
    predictability: Spread | None
    absent: tuple[tuple[str, int], ...]
    state: Spread | None = None  # embedding ÷ the true state's probe (`state_ratio`; files before it: None)


def _finite(v) -> bool:
    return _number(v) and math.isfinite(v)


def spread(values: Sequence) -> Spread | None:
    """Median, smallest and largest of the finite numbers among `values` (None and non-finite ones skipped);
    None if there are none."""
    x = np.asarray([v for v in values if _finite(v)], np.float64)
    return Spread(float(np.median(x)), float(x.min()), float(x.max()), int(x.size)) if x.size else None


def diagnostics_block(run: dict) -> dict | None:
    """A run's readable `diagnostics` (the ratios and the verdict); None where it has none or they are absent."""
    d = run.get("diagnostics")
    return d if isinstance(d, dict) and "absent" not in d else None


def has_diagnostics(runs: Sequence[dict]) -> bool:
    """Whether any ok run of `runs` records copycat diagnostics (read or absent): files written before them do not."""
    return any(r["status"] == "ok" and isinstance(r.get("diagnostics"), dict) for r in runs)


def policy_diagnostics(runs: Sequence[dict]) -> PolicyDiagnostics:
    """The copycat diagnostics over the ok runs (seeds) of one configuration: medians and ranges of the embedding,
    velocity and predictability ratios, and how many seeds were judged copycat out of those that were read.

    An absent block (`{"absent": reason}`: a policy the diagnostics cannot read) counts in `absent`, never as
    zero; a null ratio (non-finite when measured) is left out of that ratio's median and range, while its seed's
    verdict still counts.
    """
    ok = [r for r in runs if r["status"] == "ok"]
    read = [d for r in ok if (d := diagnostics_block(r)) is not None]
    reasons = [str(r["diagnostics"]["absent"]) for r in ok
               if isinstance(r.get("diagnostics"), dict) and "absent" in r["diagnostics"]]
    return PolicyDiagnostics(len(read), sum(d.get("verdict") == "copycat" for d in read),
                             spread([d.get("embedding_ratio") for d in read]),
                             spread([d.get("velocity_ratio") for d in read]),
                             spread([d.get("predictability_ratio") for d in read]),
                             tuple((why, reasons.count(why)) for why in dict.fromkeys(reasons)),
                             spread([d.get("state_ratio") for d in read]))


class DiagnosticsRow(NamedTuple):
    """One configuration of a group in the diagnostics table: its label and hyperparameters, its ok seeds, its
    mean over them of % of expert (a task judged by a rate: that rate in %; None where not recorded), and its
    `PolicyDiagnostics`."""

    label: str
    hparams: dict
    seeds: int
    normalized: float | None
    diagnostics: PolicyDiagnostics


def diagnostics_rows(m: dict) -> list[DiagnosticsRow]:
    """Every configuration of group `m` whose ok runs record copycat diagnostics (read or absent), in summary
    order; none for a group whose files predate them."""
    out = []
    for row in m["summary"]:
        runs = _ok_runs(m, row["method"], row["hparams"])
        if not has_diagnostics(runs):
            continue
        values = _seeds(m, row, "normalized")
        out.append(DiagnosticsRow(label(m["methods"], row["method"]), row["hparams"], len(runs),
                                  float(np.mean(values)) if values else None, policy_diagnostics(runs)))
    return out


def diagnostics_thresholds(sources: Sequence[results_lib.Results]) -> list[dict]:
    """The copycat thresholds (`config["diagnostics"]["thresholds"]`: `{"embedding_ratio": …,
    "predictability_ratio": …}`) the files record, each distinct one once, in file order."""
    out: list[dict] = []
    for src in sources:
        t = (src.config.get("diagnostics") or {}).get("thresholds")
        if isinstance(t, dict) and t not in out:
            out.append(t)
    return out


def recipe_diagnostics(groups: dict[tuple[str, str, str], dict[str, dict]]
                       ) -> list[tuple[str, str, DiagnosticsRow]]:
    """The recipe section's diagnostics (`recipe_groups`' groups): `(task title, recipe, row)` per configuration
    with diagnostics, by task, then recipe (mlp, fca, others), then summary order."""
    out = []
    for (env, obs, _), recipes in groups.items():
        title = tasks.get(env).title + ("" if obs == "pos" else f" ({obs})")
        names = [r for r in ("mlp", "fca") if r in recipes] + [r for r in recipes if r not in ("mlp", "fca")]
        out += [(title, n, row) for n in names for row in diagnostics_rows(recipes[n])]
    return out


# -- the policies over training (`Budget.eval_at`: each run's `at` list) ---------------------------------------------

class TrainingPoint(NamedTuple):
    """One configuration at one iteration of its runs (an `eval_at` point, or the end): % of expert over its
    seeds with a 95% bootstrap interval, its training loss (mean over seeds of the 100 minibatches before; None
    where not recorded) and its `PolicyDiagnostics` there."""

    label: str
    hparams: dict
    iteration: int
    normalized: RecipeCell | None
    train_loss: float | None
    diagnostics: PolicyDiagnostics


def _at(run: dict, iteration: int, end: int) -> dict | None:
    """A run's record at `iteration`: its `at` entry, or the run itself at the end (`end`); None if neither."""
    if iteration == end:
        return {"eval": run["eval"], "diagnostics": run.get("diagnostics"), "train_loss": run.get("train_loss_final"),
                "status": run["status"]}
    snap = next((a for a in run.get("at") or () if a["iteration"] == iteration), None)
    return None if snap is None else {**snap, "status": run["status"]}


def training_points(m: dict) -> list[TrainingPoint]:
    """Every configuration of group `m` whose runs were also evaluated before the end (`Budget.eval_at`), at each
    of those iterations and at the end, in summary order then iteration order; none for other groups."""
    end = int(m["sources"][0].config["iterations"])  # a group's files share their budget
    out = []
    for row in m["summary"]:
        runs = _ok_runs(m, row["method"], row["hparams"])
        points = sorted({a["iteration"] for r in runs for a in r.get("at") or ()})
        if not points:
            continue
        for iteration in [*points, end]:
            at = [a for r in sorted(runs, key=lambda r: r.get("seed", 0)) if (a := _at(r, iteration, end))]
            seeds = [a["eval"]["normalized"] for a in at if a["eval"].get("normalized") is not None]
            losses = [a["train_loss"] for a in at if _finite(a.get("train_loss"))]
            out.append(TrainingPoint(label(m["methods"], row["method"]), row["hparams"], iteration, _cell(seeds),
                                     float(np.mean(losses)) if losses else None, policy_diagnostics(at)))
    return out


# -- the paper's budget with the paper's recipe: the same policies over training, beside Table 5 ------------------

# The methods of the issue's 300k table, (label, method, hparams): None for FCA's task default (`_recipe_row`),
# "tau" for the softmax at the paper's τ of the task (`PAPER_TAU`).
BUDGET_METHODS = (("BC-SO", "bc-so", {}), ("BC-OH", "bc-oh", {}), ("Ours, step THR 10% W 5", "ours-step", PAPER_STEP),
                  ("Ours, softmax at the paper's τ", "ours-softmax", "tau"), ("FCA (TCA)", "fca", None),
                  ("FCA (TCA + IB)", "fca-ib", None))


class BudgetPoint(NamedTuple):
    """One configuration at one iteration of its runs (an `eval_at` point or the end): % of expert and mean return
    over seeds, each with its 95% bootstrap interval (None where no seed recorded it), and the diagnostics there."""

    iteration: int
    normalized: RecipeCell | None
    returns: RecipeCell | None
    diagnostics: PolicyDiagnostics


class BudgetRow(NamedTuple):
    """One method of one task's paper-budget group: its points in iteration order, the supplement's Table 5 return
    for it (None: Table 5 has no such row), and which hyperparameters ran."""

    env: str
    label: str
    method: str
    hparams: dict
    points: tuple[BudgetPoint, ...]
    paper: float | None

    def at(self, iteration: int) -> BudgetPoint | None:
        return next((p for p in self.points if p.iteration == iteration), None)


def paper_budget_groups(merged: dict) -> list[dict]:
    """The groups of the paper's protocol (fca, any split) under the `fca` recipe trained for the `paper` preset's
    iterations: the issue's 300k table, one group per state task, in task order."""
    from ape_jax.pipeline.presets import BUDGETS

    return [m for key, m in _ordered(merged) if key.env in MUJOCO and key.obs == "pos"
            and key.budget == BUDGETS["paper"].iterations and m["protocol"].get("variant_of") == FCA
            and m["protocol"].get("recipe") == "fca" and not other_setting(m["protocol"])]


def _cell(values: Sequence[float]) -> RecipeCell | None:
    return RecipeCell(*bootstrap_mean(values), tuple(values)) if values else None


def budget_rows(m: dict) -> list[BudgetRow]:
    """`BUDGET_METHODS` that ran in group `m`, each at every iteration its runs were evaluated at (`Budget.eval_at`,
    then the end), with Table 5's return beside BC-SO, BC-OH, Ours (step THR 10% W 5) and FCA (the paper's FCA
    has the information bottleneck: beside TCA + IB, or beside TCA where IB did not run)."""
    end = int(m["sources"][0].config["iterations"])
    ib = bool(_rows(m, "fca-ib"))
    table5 = {"bc-so": "bc-so", "bc-oh": "bc-oh", "fca-ib": "fca", **({} if ib else {"fca": "fca"})}
    out = []
    for lab, method, hparams in BUDGET_METHODS:
        if hparams == "tau":
            if m["env"] not in PAPER_TAU:
                continue
            hparams = {"tau": PAPER_TAU[m["env"]]}
            lab = f"Ours, softmax τ {hparams['tau']:g}"
        row = _recipe_row(m, method, hparams)
        if row is None:
            continue
        runs = sorted(_ok_runs(m, row["method"], row["hparams"]), key=lambda r: r.get("seed", 0))
        points = []
        for iteration in sorted({a["iteration"] for r in runs for a in r.get("at") or ()} | {end}):
            at = [a for r in runs if (a := _at(r, iteration, end))]
            points.append(BudgetPoint(iteration,
                                      _cell([a["eval"]["normalized"] for a in at
                                             if _finite(a["eval"].get("normalized"))]),
                                      _cell([a["eval"]["return_mean"] for a in at
                                             if _finite(a["eval"].get("return_mean"))]),
                                      policy_diagnostics(at)))
        key = "ours" if method == "ours-step" and row["hparams"] == PAPER_STEP else table5.get(method)
        out.append(BudgetRow(m["env"], lab, method, dict(row["hparams"]), tuple(points),
                             None if key is None else float(PAPER_TABLE5[key][m["env"]])))
    return out


def budget_differences(rows: Sequence[BudgetRow]) -> list[tuple[str, dict[int, Interval]]]:
    """One task's differences over seeds, in points of % of expert, at each iteration both arms were evaluated:
    BC-OH − BC-SO (what the history adds), then every other method − BC-OH (does it beat the copycat?).
    `[(label, {iteration: Interval})]`, pairs without a common point left out."""
    by = {r.method: r for r in rows}
    pairs = [("BC-OH − BC-SO", by.get("bc-oh"), by.get("bc-so"))]
    pairs += [(f"{r.label} − BC-OH", r, by.get("bc-oh")) for r in rows if r.method not in ("bc-so", "bc-oh")]
    out = []
    for lab, a, b in pairs:
        if a is None or b is None:
            continue
        diffs = {}
        for p in a.points:
            q = b.at(p.iteration)
            if p.normalized is not None and q is not None and q.normalized is not None:
                diffs[p.iteration] = bootstrap_difference(p.normalized.seeds, q.normalized.seeds)
        if diffs:
            out.append((lab, diffs))
    return out


# -- the copycat map, extended: recipe and budget axes, diagnostics as well as returns -----------------------------

class MapPoint(NamedTuple):
    """One cell of the extended copycat map (`extended_map`): one task under one setting (recipe, split), frame skip
    and training-set size, for runs of `run` iterations evaluated at `iteration`.

    `cells` align with `MAP_METHODS` (None: not run); `history` is BC-OH − BC-SO over seeds in points of % of expert
    (None where either did not run); `diagnostics` are BC-OH's there (None where BC-OH did not run)."""

    env: str
    recipe: str
    split: str
    frame_skip: int
    train_transitions: int
    run: int
    iteration: int
    cells: tuple[MapCell | None, ...]
    history: Interval | None
    diagnostics: PolicyDiagnostics | None
    observations: int | None = None  # the policies' history where it is not the protocol's (`other_history`)
    expert: str | None = None        # the expert variant where it is not the task's own (`Protocol.expert`)

    @property
    def setting(self) -> str:
        """`"recipe fca, split by rows"` (`", history 7"` where the history is not the protocol's, `", expert ppo"`
        for another expert): what the recipe axis varies."""
        return f"recipe {self.recipe}, split by {self.split}" + (
            "" if self.observations is None else f", history {self.observations}") + (
            "" if self.expert is None else f", expert {self.expert}")


def _seed_cell(values: Sequence[float]) -> MapCell | None:
    if not values:
        return None
    x = np.asarray(values, np.float64)
    return MapCell(float(x.mean()), float(x.std(ddof=1)) if x.size > 1 else math.nan, int(x.size), tuple(values))


def extended_map(merged: dict) -> list[MapPoint]:
    """Every state group of the fca family (the paper's protocol at each frame skip and training-set size, under
    every recipe, split and budget) as map points: one per iteration its runs were evaluated at (`Budget.eval_at`,
    then the end), with BC-SO, BC-OH and Ours (step THR 10% W 5) in % of expert, BC-OH − BC-SO with its 95%
    bootstrap interval over seeds, and BC-OH's copycat diagnostics. In task, setting (recipe mlp before fca,
    whole episodes before rows), frame skip, size, run length and iteration order."""
    out = []
    for key, m in _ordered(merged):
        p = m["protocol"]
        base = p.get("variant_of") or key.protocol
        if key.obs != "pos" or key.env not in MUJOCO or not in_fca_family(base) or p.get("frame_skip") is None:
            continue
        end = int(m["sources"][0].config["iterations"])
        chosen = [_map_row_of(m, method, hp) for _, method, hp in MAP_METHODS]
        runs = [sorted(_ok_runs(m, r["method"], r["hparams"]), key=lambda r: r.get("seed", 0)) if r else []
                for r in chosen]
        points = sorted({a["iteration"] for rs in runs for r in rs for a in r.get("at") or ()} | {end})
        for iteration in points:
            at = [[a for r in rs if (a := _at(r, iteration, end))] for rs in runs]
            cells = tuple(_seed_cell([a["eval"]["normalized"] for a in xs if _finite(a["eval"].get("normalized"))])
                          for xs in at)
            bcso, bcoh = cells[0], cells[1]
            history = bootstrap_difference(bcoh.seeds, bcso.seeds) if bcso and bcoh else None
            out.append(MapPoint(key.env, p.get("recipe") or "mlp", p.get("split") or "episodes", int(p["frame_skip"]),
                                int(p.get("train_transitions") or FCA_TRAIN), end, iteration, cells, history,
                                policy_diagnostics(at[1]) if at[1] else None, other_history(p), p.get("expert")))
    rank = {"mlp": 0, "fca": 1}
    return sorted(out, key=lambda q: (MUJOCO.index(q.env), rank.get(q.recipe, 2), q.recipe, q.split != "episodes",
                                      q.observations or 0, q.expert or "", q.frame_skip, q.train_transitions, q.run,
                                      q.iteration))


def _map_row_of(m: dict, method: str, hparams: dict | None) -> dict | None:
    rows = _rows(m, method)
    return _best(rows) if hparams is None else next((r for r in rows if r["hparams"] == hparams), None)
