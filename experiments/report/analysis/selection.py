"""Which configurations each table shows: method labels, the rows picked per group, the paper's settings.

- `method_rows`, `best_of`, `paper_step_row`, `headline`, `comparisons`, `extra_methods` pick the configurations
  the tables show; method labels come from what each file records of its methods (`label`), then the registry,
  then the name;
- `driving_table`, `driving_rows`: a group of the suite's driving protocols (`ape_jax.tasks.DRIVING_FAMILIES`) as
  the supplement's Table 1 or 2, with every configuration that ran, in a fixed order;
- `seed_values`, `ok_runs`: a configuration's per-seed numbers and runs;
- `choices`: the paper's settings against the best of the grid;
- `first_training`, `retrained_shift`: a file trained again, against the first training it replaced;
- `longer_runs`: configurations trained longer, beside the same configuration at its preset's budget.

Tasks are told apart by their record (`ape_jax.tasks`), never by name: a task judged by a rate (its main metric is
not the return) is shown in %.
"""

from __future__ import annotations

import math
import statistics
from collections import Counter
from typing import NamedTuple
from collections.abc import Mapping, Sequence

from ape_jax import methods as methods_lib
from ape_jax import tasks
from experiments.report.analysis.groups import Group, Merged, config_key, is_rate, ordered
from experiments.report.paper import (PAPER_DRIVING_TABLES, PAPER_SENSITIVITY_TAU, PAPER_SENSITIVITY_W, PAPER_STEP,
                                      PAPER_STEP_LABEL, PAPER_TAU)


# -- methods: labels and which ones the tables list ----------------------------------------------------------------

# The methods published after the paper against the copycat problem, in the order the tables list them: RAP, PALR,
# MINE, then the remedies added after them (ChannelDropout: ChauffeurNet's and PlanTF's dropout of the leaking
# channel; PTP: past-token prediction; ActionChunks: ACT's history-free chunks; Priming: PrimeNet).
LATER = ("rap", "palr", "mine", "channel-dropout", "ptp", "action-chunks", "priming")


def known_methods(merged: Merged) -> dict[str, dict]:
    """What the results files record of each method (label, role, online), over every environment."""
    out: dict[str, dict] = {}
    for _, m in ordered(merged):
        out = {**m.methods, **out}
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


def extra_methods(merged: Merged) -> list[str]:
    """The methods besides the references and ours that appear in the results: role baseline in registry
    order (baselines the registry does not know after them), then plugins, in order of appearance."""
    known = known_methods(merged)
    appear = list(dict.fromkeys(r["method"] for _, m in ordered(merged) for r in m.summary))
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

def method_rows(m: Group, method: str) -> list[dict]:
    """Group `m`'s summary rows of `method` that have seeds (a configuration whose every run failed has none)."""
    return [r for r in m.summary if r["method"] == method and r["n_seeds"]]


def best_of(rows: list[dict]) -> dict | None:
    """The row with the highest % of expert (a task judged by a rate: that rate), or return where that is missing."""
    def score(r):
        return r["normalized_mean"] if r.get("normalized_mean") is not None else r["return_mean"]

    return max(rows, key=score, default=None)


def paper_step_row(m: Group) -> dict | None:
    """The summary row of Ours at the paper's step setting (THR 10%, W 5), or None if not run."""
    return next((r for r in method_rows(m, "ours-step") if r["hparams"] == PAPER_STEP), None)


def thousands(x: float) -> str:
    """`30000 -> "30k"`, `2500 -> "2.5k"`, `2 -> "2"`: iterations, sizes and frame skips in headings and ticks."""
    return f"{x / 1000:g}k" if x >= 1000 else f"{x:g}"


def percent(thr: float) -> str:
    """A fraction as a percentage, `0.1 -> "10%"`."""
    return f"{100 * thr:g}%"


def hparams_suffix(row: dict | None) -> str:
    """A configuration's hyperparameters, `" (thr 0.2, w 3)"`; "" for None."""
    if row is None:
        return ""
    return " (" + ", ".join(f"{k} {v:g}" for k, v in row["hparams"].items()) + ")"


CEILING = "bc-full"  # BC on the full state (velocities included): the ceiling of the state tables
CEILING_LABEL = "BC-full (full state: the ceiling)"


def has_ceiling(groups: Sequence[Group]) -> bool:
    """Whether any of `groups` ran the ceiling (`CEILING`): a table of them shows its row (files without it lack
    it: "—")."""
    return any(method_rows(m, CEILING) for m in groups)


def headline(m: Group, extras: Sequence[str] = (), known: Mapping[str, dict] | None = None,
             ceiling: bool = False) -> list[tuple[str, dict | None]]:
    """The state table's rows of one group (task, observation mode, protocol): (label, summary row or None).

    BC-SO, BC-OH, Ours at the paper's step setting and the best step and
    softmax settings, then each of `extras` (`extra_methods`), labelled from
    `known` (default: what `m`'s files record); with `ceiling` (`has_ceiling` of
    the table's groups), BC-full last.
    """
    known = m.methods if known is None else known
    best_step, best_soft = best_of(method_rows(m, "ours-step")), best_of(method_rows(m, "ours-softmax"))
    out = [("BC-SO", best_of(method_rows(m, "bc-so"))), ("BC-OH", best_of(method_rows(m, "bc-oh"))),
           (PAPER_STEP_LABEL, paper_step_row(m)),
           (f"Ours, best step{hparams_suffix(best_step)}", best_step),
           (f"Ours, best softmax{hparams_suffix(best_soft)}", best_soft)]
    out += [(label(known, method), best_of(method_rows(m, method))) for method in extras]
    if ceiling:
        out.append((CEILING_LABEL, best_of(method_rows(m, CEILING))))
    return out


def seed_values(m: Group, row: dict | None, key: str = "return_mean") -> list[float]:
    """Per-seed evaluation values (`eval[key]`) of the configuration of summary row `row`, in seed order."""
    if row is None:
        return []
    runs = [r for r in m.runs if r["method"] == row["method"] and r["hparams"] == row["hparams"]
            and r["status"] == "ok" and r["eval"].get(key) is not None]
    return [r["eval"][key] for r in sorted(runs, key=lambda r: r.get("seed", 0))]


def ok_runs(m: Group, method: str, hparams: dict) -> list[dict]:
    """Group `m`'s runs of one configuration (`method`, `hparams`) that finished (`status` ok), in file order."""
    return [r for r in m.runs if r["method"] == method and r["hparams"] == hparams and r["status"] == "ok"]


def comparisons(m: Group) -> list[tuple[str, dict | None]]:
    """Ours' configurations compared with BC-OH: the paper's step setting, then the best step and softmax."""
    best_step, best_soft = best_of(method_rows(m, "ours-step")), best_of(method_rows(m, "ours-softmax"))

    def after(row: dict | None) -> str:
        return "" if row is None else f" ({hparams_suffix(row)[2:-1]}; selected after the fact)"

    return [(f"{PAPER_STEP_LABEL} (the paper's)", paper_step_row(m)),
            (f"Ours, best step{after(best_step)}", best_step), (f"Ours, best softmax{after(best_soft)}", best_soft)]


def task_metric_rows(m: Group) -> list[tuple[str, str, list[dict]]]:
    """The task-metrics table's policies (the supplement's Table 4 protocol): `(label, method, ok runs)` of
    BC-SO, BC-OH and Ours at THR 10%, W 5, those that ran."""
    wanted = (("BC-SO", "bc-so", {}), ("BC-OH", "bc-oh", {}), (PAPER_STEP_LABEL, "ours-step", PAPER_STEP))
    return [(lab, method, runs) for lab, method, hp in wanted if (runs := ok_runs(m, method, hp))]


def loss_rows(m: Group) -> list[tuple[str, list[dict]]]:
    """The loss analysis' policies: BC-SO, BC-OH, Ours at the paper's step setting and the best step
    (where it differs), each with its ok runs; those without runs left out. A driving group (`driving_table`):
    every configuration of its table (`driving_rows`), as the supplement's Table 3 lists them."""
    if driving_table(m) is not None:
        return [(r.label, r.runs) for r in driving_rows(m)]
    wanted = [("BC-SO", "bc-so", {}), ("BC-OH", "bc-oh", {}), (PAPER_STEP_LABEL, "ours-step", PAPER_STEP)]
    best = best_of(method_rows(m, "ours-step"))
    if best is not None and best["hparams"] != PAPER_STEP:
        wanted.append((f"Ours, best step{hparams_suffix(best)}", "ours-step", best["hparams"]))
    return [(lab, runs) for lab, method, hp in wanted if (runs := ok_runs(m, method, hp))]


def copycat_groups(m: Group) -> dict[tuple, list[dict]]:
    """The ok runs that record the copycat diagnostics (`rollout_ape`, `imitation_error`), per configuration."""
    groups: dict[tuple, list[dict]] = {}
    for r in m.runs:
        if r["status"] == "ok" and "rollout_ape" in r["eval"] and "imitation_error" in r["eval"]:
            groups.setdefault(config_key(r), []).append(r)
    return groups


def expert_ape(m: Group) -> float | None:
    """The validation demonstrations' mean APE ÷ the raw training mean (the scale of the policies' `rollout_ape`),
    from the first of `m`'s files that records enough to put it on that scale.

    `config["ape"]["val_mean"]` is the mean of the APE the file trained on. Times `scale` ÷ `raw_mean` (the raw
    training mean, recorded since the raw-APE default, or added by `experiments.evaluate`) it is on
    `rollout_ape`'s scale; a file without `raw_mean` trained with `normalization: "mean"` (or none recorded: those
    predate `"none"`) is already on it. A `"none"` file without `raw_mean` gives none.
    """
    for src in m.sources:
        ape = src.config.get("ape")
        if not isinstance(ape, dict) or "val_mean" not in ape:
            continue
        if ape.get("raw_mean"):
            return ape["val_mean"] * ape.get("scale", 1.0) / ape["raw_mean"]
        if ape.get("normalization", "mean") == "mean":
            return ape["val_mean"]
    return None


# -- the driving tables: the supplement's Tables 1 and 2 ---------------------------------------------------------

# The driving tables' methods, in order: the references and ours, the paper's baselines (FCA, HistoryDropout, DAgger,
# Boosting, then the other baselines of its issue), the methods published after it (`LATER`); any other baseline
# after them in registry order, then plugins in order of appearance, and BC-full (`CEILING`) last.
DRIVING_ORDER = ("bc-so", "bc-oh", "ours-step", "ours-softmax", "fca", "fca-ib", "history-dropout", "dagger",
                 "boosting", "bcpd", "actfreq", "kmeans", *LATER)


class DrivingTable(NamedTuple):
    """Which of the supplement's driving tables a group stands for (`driving_table`).

    `number` is the table's (1: the speed in view, 2: without it; `PAPER_DRIVING_TABLES`), None for a driving
    protocol the supplement has no table for or one whose recorded traffic or speed input differs from its named
    protocol's; `words` say what sets the table apart (`"NoCrash-Dense, speed in view"`)."""

    number: int | None
    words: str


def driving_table(m: Group) -> DrivingTable | None:
    """The supplement's driving table group `m` stands for: a group whose protocol (a variant's: the protocol it
    varies) is of a driving family (`ape_jax.tasks.DRIVING_FAMILIES`, `nocrash`); None for every other group."""
    name = m.protocol.get("variant_of") or m.protocol["name"]
    if tasks.protocol_family(name) not in tasks.DRIVING_FAMILIES:
        return None
    found, named = PAPER_DRIVING_TABLES.get(name), tasks.PROTOCOLS.get(name)
    same = named is not None and all(m.protocol.get(k) is None or m.protocol[k] == getattr(named, k)
                                     for k in ("traffic", "speed_input"))
    if found is None or not same:
        return DrivingTable(None, f"protocol {name}" + ("" if same else ", its traffic or speed input changed"))
    return DrivingTable(*found)


class DrivingRow(NamedTuple):
    """One configuration of a driving table (`driving_rows`): how the table names it, its method and hparams, its ok
    runs (seeds), and whether it is the full state's ceiling (`CEILING`)."""

    label: str
    method: str
    hparams: dict
    runs: list[dict]
    ceiling: bool


def _is_paper_step(row: dict) -> bool:
    return row["method"] == "ours-step" and row["hparams"] == PAPER_STEP


def driving_rows(m: Group) -> list[DrivingRow]:
    """Every configuration of group `m` with finished runs, one row each, in `DRIVING_ORDER` (a method's
    configurations in summary order), BC-full last; of Ours (step) only the paper's setting where it ran (the grid's
    other settings are the group's grid table's), as the paper's tables list it.

    Labels: the paper's step setting as `PAPER_STEP_LABEL`, BC-full as `CEILING_LABEL`, every other method by `label`
    (online ones say so), with its setting (`setting_words`) where the method has more than one configuration.
    """
    rows = [r for r in m.summary if r["n_seeds"]]
    if any(_is_paper_step(r) for r in rows):
        rows = [r for r in rows if r["method"] != "ours-step" or _is_paper_step(r)]
    appear = list(dict.fromkeys(r["method"] for r in rows))
    registry = {name: i for i, name in enumerate(methods_lib.names())}
    others = sorted((n for n in appear if n not in DRIVING_ORDER and n != CEILING),
                    key=lambda n: (n not in registry, registry.get(n, 0), appear.index(n)))
    order = [*(n for n in DRIVING_ORDER if n in appear), *others, *([CEILING] if CEILING in appear else [])]
    rows.sort(key=lambda r: order.index(r["method"]))
    count = Counter(r["method"] for r in rows)
    out = []
    for r in rows:
        method, hp = r["method"], r["hparams"]
        if _is_paper_step(r):
            name = PAPER_STEP_LABEL
        elif method == CEILING:
            name = CEILING_LABEL
        else:
            name = label(m.methods, method)
        if count[method] > 1 and (words := setting_words(hp)):
            name += f", {words}"
        out.append(DrivingRow(name, method, hp, ok_runs(m, method, hp), method == CEILING))
    return out


def sensitivity(m: Group) -> tuple[list[tuple[float, dict | None]], list[tuple[float, dict | None]]]:
    """The sensitivity study's rows: per τ of the paper's and per W (at THR 10%) of the paper's, our summary row."""
    rows = {config_key(r): r for r in m.summary if r["n_seeds"]}
    tau = [(t, rows.get(("ours-softmax", (("tau", t),)))) for t in PAPER_SENSITIVITY_TAU]
    w = [(x, rows.get(("ours-step", (("thr", PAPER_STEP["thr"]), ("w", x))))) for x in PAPER_SENSITIVITY_W]
    return tau, w


# -- grid search: the paper's choices ------------------------------------------------------------------------------

def display_metric(m: Group) -> tuple[str, str]:
    """Which summary numbers the figures show: `(prefix, unit)`; % of expert where every row has it (a task
    judged by a rate: that rate, in %)."""
    if all(r.get("normalized_mean") is not None for r in m.summary if r["n_seeds"]):
        return "normalized", f"{m.metric} %" if is_rate(m) else "% of expert"
    return "return", "return"


def metric_value(row: dict, prefix: str) -> tuple[float, float]:
    """A summary row's `(mean, std)` of `prefix` (`"normalized"` or `"return"`); std NaN where not recorded."""
    mean, std = row[f"{prefix}_mean"], row.get(f"{prefix}_std")
    return float(mean), float(std if std is not None else math.nan)


def is_number(v) -> bool:
    """Whether `v` is an int or float (not a bool)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def is_finite(v) -> bool:
    """Whether `v` is a finite number (`is_number`, not NaN or ±inf)."""
    return is_number(v) and math.isfinite(v)


def _ape_scale(m: Group) -> float | None:
    """The training-set mean APE our softmax τ divided by (`ape_normalization: "mean"`), or None."""
    for r in m.sources:
        ape = r.config.get("ape")
        if (any(row["method"] == "ours-softmax" for row in r.summary) and isinstance(ape, dict)
                and ape.get("normalization") == "mean" and is_number(ape.get("scale")) and ape["scale"] > 0):
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
    """Summary row `chosen` against the grid's `best`, in `prefix` (`display_metric`): their `Gap`."""
    (cm, cs), (bm, bs) = metric_value(chosen, prefix), metric_value(best, prefix)
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


def choices(m: Group) -> list[Choice]:
    """Per weighting (step, softmax) that ran and has a paper setting: the paper's setting against the grid."""
    prefix, _ = display_metric(m)
    tau = PAPER_TAU.get(m.env)
    out = []
    for kind, method, paper in (("step", "ours-step", PAPER_STEP),
                                ("softmax", "ours-softmax", None if tau is None else {"tau": tau})):
        rows = method_rows(m, method)
        if not rows or paper is None:
            continue
        best = max(rows, key=lambda r: metric_value(r, prefix)[0])
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


# -- trained again -------------------------------------------------------------------------------------------------

def first_training(m: Group) -> dict[tuple, dict]:
    """The summary rows of the files `m`'s files were trained again to replace (`replaces`), by configuration, their
    std the sample sd over seeds as the group's rows have it (`merge`; the file records the population one)."""
    return {config_key(row): {**row, **{k: _sample_sd(row[k], row["n_seeds"]) for k in ("return_std", "normalized_std")
                                        if k in row}}
            for s in m.sources if s.replaces for row in s.replaces["summary"]}


def _sample_sd(population: float | None, n: int) -> float | None:
    return population * math.sqrt(n / (n - 1)) if population is not None and n > 1 else None


class Shift(NamedTuple):
    """How far the configurations trained again moved from their first training (`retrained_shift`): the number of
    configurations, the smallest and largest move of the mean return, the median |move| in standard errors of the
    difference, and how many moved by more than two of them (new seeds would put ~5% there, with a median ~0.67)."""

    n: int
    low: float
    high: float
    median_se: float
    beyond: int


def retrained_shift(m: Group) -> Shift | None:
    """The `Shift` of group `m`'s configurations trained again (`replaces`), each move against the standard error from
    the two trainings' std over seeds; None where no file of `m` replaced one."""
    first = first_training(m)
    pairs = [(row, first[config_key(row)]) for row in m.summary
             if config_key(row) in first and row["n_seeds"] > 1 and first[config_key(row)]["n_seeds"] > 1]
    moved = [(a["return_mean"] - b["return_mean"],
              math.sqrt(a["return_std"] ** 2 / a["n_seeds"] + b["return_std"] ** 2 / b["n_seeds"])) for a, b in pairs]
    ratio = [abs(d) / se for d, se in moved if se > 0]
    if not ratio:
        return None
    return Shift(len(pairs), min(d for d, _ in moved), max(d for d, _ in moved), statistics.median(ratio),
                 sum(r > 2 for r in ratio))


# -- training longer -----------------------------------------------------------------------------------------------

class LongerRow(NamedTuple):
    """One configuration at its preset's budget and at a longer one: `base`, `longer` summary rows."""

    label: str
    base: dict
    longer: dict


def longer_runs(merged: Merged) -> list[tuple[Group, Group, list[LongerRow]]]:
    """Groups trained at another budget than their preset's (`Key.budget`), each beside its preset-budget group
    (same task, observation mode and protocol): `[(longer group, base group, rows)]`, one row per configuration
    both ran, in the longer group's order. Groups without a base group, or with no configuration in common,
    are left out."""
    out = []
    for key, m in ordered(merged):
        base = merged.get(key._replace(budget=None)) if key.budget else None
        if base is None:
            continue
        rows = {config_key(r): r for r in base.summary if r["n_seeds"]}
        pairs = [LongerRow(_row_label(m, r), rows[config_key(r)], r) for r in m.summary
                 if r["n_seeds"] and config_key(r) in rows]
        if pairs:
            out.append((m, base, pairs))
    return out


def _row_label(m: Group, row: dict) -> str:
    """`"BC-OH"`, `"Ours (step), THR 10% W 5"`, `"Ours (softmax), τ 0.2"`, `"FCA, alpha 0.1"`."""
    words = setting_words(row["hparams"])
    return ", ".join([label(m.methods, row["method"]), *([words] if words else [])])


def setting_words(hparams: Mapping[str, float]) -> str:
    """A configuration's hyperparameters in words: `"THR 10% W 5"`, `"τ 0.2"`, `"alpha 0.1, adversary_lr 0.0004"`;
    "" for none."""
    hp = dict(hparams)
    words = ([f"THR {percent(hp.pop('thr'))} W {hp.pop('w'):g}"] if {"thr", "w"} <= hp.keys() else []) + \
        ([f"τ {hp.pop('tau'):g}"] if "tau" in hp else []) + [f"{k} {v:g}" for k, v in hp.items()]
    return ", ".join(words)
