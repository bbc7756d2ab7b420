"""The report's numbers: results files loaded and merged, the rows each table picks, the bootstrap, the weights.

Nothing here formats markdown or draws: `experiments.report.markdown` and
`experiments.report.figures` do, from what these functions return.

- `load` reads one results file (`ape_jax.pipeline.results.load`, the one
  validator) and `merge` joins them per `(env, obs)`;
- `_rows`, `_best`, `headline`, `comparisons`, `extra_methods` pick the
  configurations the tables show; method labels come from what each file
  records of its methods (`label`), then the registry, then the name;
- `bootstrap_difference`, `verdict`, `bootstrap_rows`: Ours − BC-OH over seeds;
- `choices`: the paper's settings against the best of the grid;
- `weight_shares`: how concentrated each weighting is within a batch.

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

# The supplement's Table 5 (MuJoCo-State; its own experts, 300k iterations): mean returns.
PAPER_TABLE5 = {
    "bc-so": {"hopper": 275, "halfcheetah": -38, "walker2d": 363},
    "bc-oh": {"hopper": 293, "halfcheetah": 820, "walker2d": 592},
    "fca": {"hopper": 1086, "halfcheetah": 1250, "walker2d": 1296},
    "ours": {"hopper": 641, "halfcheetah": 1023, "walker2d": 1460},
}
PAPER_STEP = {"thr": 0.1, "w": 5.0}  # the setting the paper reports for its step weighting
PAPER_TAU = {"hopper": 0.2, "walker2d": 0.2, "halfcheetah": 0.1}  # the paper's softmax τ per environment
# The supplement's §4 sensitivity study: Walker2d returns per softmax τ, and CARLA driving success per step W.
PAPER_SENSITIVITY_TAU = {0.1: (765, 103), 0.2: (769, 97), 0.5: (724, 61)}
PAPER_SENSITIVITY_W = {4.0: 41.9, 5.0: 43.4, 6.0: 41.3}
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
    return Source(**{f.name: getattr(res, f.name) for f in dataclasses.fields(results_lib.Results)}, path=str(path))


def main_metric(res: results_lib.Results) -> str:
    """What a results file is judged by: the metric it records, else its task's (schema 1 records none)."""
    return res.main_metric if "metric" in res.config else tasks.get(res.env).metric


def merge(files: Sequence[results_lib.Results]) -> dict[tuple[str, str], dict]:
    """Results per `(env, obs)`: summary rows and runs of all files, with the files they came from.

    Each value has `env`, `obs`, `expert`, `summary`, `runs`, `sources` (the
    files), `methods` (what the files record of their methods, the first file
    naming one wins), `metric` (the main metric) and `task_metrics`.

    Raises:
      ReportError: the same configuration in two files, or files of one
        environment with different experts.
    """
    merged: dict[tuple[str, str], dict] = {}
    for r in files:
        where = getattr(r, "path", "") or f"a {r.env} ({r.obs}) results file"
        key = (r.env, r.obs)
        m = merged.setdefault(key, {"env": r.env, "obs": r.obs, "expert": r.expert, "summary": [], "runs": [],
                                    "sources": [], "methods": {}, "metric": main_metric(r),
                                    "task_metrics": tuple(r.config.get("task_metrics", tasks.get(r.env).metrics))})
        if m["expert"] != r.expert:
            raise ReportError(f"{where}: its expert differs from another {r.env} results file's")
        seen = {_config_key(row) for row in m["summary"]}
        for row in r.summary:
            if _config_key(row) in seen:
                raise ReportError(f"{where}: {row['method']} {row['hparams']} is also in another results "
                                  f"file of {r.env} ({r.obs}); pass one of them")
        m["summary"] += r.summary
        m["runs"] += r.runs
        m["sources"].append(r)
        m["methods"] = {**r.methods, **m["methods"]}
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
    """The state table's rows of one environment: (label, summary row or None).

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
    """The validation demonstrations' mean APE (÷ the training mean) that the first of `m`'s files records."""
    return next((src.config["ape"]["val_mean"] for src in m["sources"]
                 if isinstance(src.config.get("ape"), dict) and "val_mean" in src.config["ape"]), None)


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


def bootstrap_rows(merged: dict) -> list[tuple[str, str, Interval, str]]:
    """Per environment and configuration of Ours (`comparisons`): Ours − BC-OH with its CI, and the unit:
    mean return, or for a task judged by a rate (whose reward is not its measure) that rate in % points."""
    out = []
    for (env, obs), m in _ordered(merged):
        key, unit, scale = (m["metric"], f"{m['metric']}, % points", 100.0) if is_rate(m) else \
            ("return_mean", "return", 1.0)
        bcoh = [scale * v for v in _seeds(m, _best(_rows(m, "bc-oh")), key)]
        for lab, row in comparisons(m) if bcoh else []:
            ours = [scale * v for v in _seeds(m, row, key)]
            if ours:
                out.append((_env_title(env, obs), lab, bootstrap_difference(ours, bcoh), unit))
    return out


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
        q = next((src.config["ape"].get("quantiles") for src in m["sources"]
                  if isinstance(src.config.get("ape"), dict) and src.config["ape"].get("quantiles")), None)
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


# -- environments: order and titles --------------------------------------------------------------------------------

def _ordered(merged: dict) -> list[tuple[tuple[str, str], dict]]:
    """`merged`'s items, the sweepable tasks first in their order (`ape_jax.tasks.sweepable`), then by name."""
    order = {e: i for i, e in enumerate(tasks.sweepable())}
    return sorted(merged.items(), key=lambda kv: (order.get(kv[0][0], len(order)), kv[0]))


def _env_title(env: str, obs: str) -> str:
    """The task's title, with its observation mode unless it is a state task's `pos`."""
    return tasks.get(env).title + ("" if obs == "pos" and env in MUJOCO else f" ({obs})")


def envs_of(merged: dict, obs: str) -> list[str]:
    """The state tasks (`MUJOCO`) `merged` has results of with observations `obs`, in order."""
    return [e for e in MUJOCO if (e, obs) in merged]
