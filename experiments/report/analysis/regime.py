"""Table 5 with FCA's expert: the paper's protocol and recipe with an expert of FCA's kind, beside the supplement.

- `regime_groups`: the groups whose demonstrations came from an imported expert (`experiments.import_expert`: FCA's
  own CS294 Hopper policy is the reference one) or stored the expert's labels raw (as FCA stored them: the rough
  experts' runs), under the mujoco-state protocol (split by rows) and the bn-mlp recipe, at any budget;
- `regime_table`: per such group, every configuration in % of expert and return over seeds (t-intervals),
  the supplement's Table 5 beside it, its difference against BC-OH (Welch t-interval, in points of % of expert),
  its copycat diagnostics (both verdicts' counts, the control and predictability ratios), and the history's share
  of the gap between BC-SO and BC-full.

Arrays in, intervals out: every number comes from `differences`' estimators (`experiments.stats`) over the runs'
per-seed values; the sentences are `experiments.report.sections.regime`'s.
"""

from __future__ import annotations

from typing import NamedTuple

from ape_jax import tasks
from experiments.report.analysis.differences import (Interval, RecipeCell, Share, mean_difference, history_share,
                                                   mean_cell)
from experiments.report.analysis.diagnostics import PolicyDiagnostics, policy_diagnostics
from experiments.report.analysis.groups import (STATE, MUJOCO, Group, Merged, ordered, other_history, raw_labels,
                                               trained_its_preset)
from experiments.report.analysis.selection import (CEILING, CEILING_LABEL, LATER, is_finite, label, method_rows,
                                                   ok_runs)
from experiments.report.paper import PAPER_STEP, PAPER_TABLE5

# The table's methods in order (each configuration that ran, in the order of its hyperparameters): the references and
# ours, FCA, the methods published after the paper (`LATER`), BC-full; others after.
REGIME_METHODS = ("bc-so", "bc-oh", "ours-step", "ours-softmax", "fca", "fca-ib", *LATER, CEILING)


class RegimeRow(NamedTuple):
    """One configuration of a regime group (`regime_table`).

    Attributes:
      method, hparams: the configuration.
      label: how the table names it (`"Ours (step), THR 10% W 5"`, `"FCA (TCA), α 2"`).
      normalized, returns: % of expert and mean return over its seeds, each with its 95% t-interval (None
        where no seed recorded it).
      paper: the supplement's Table 5 return of the same method (None: Table 5 has no such row); FCA's one number
        stands beside every α (Table 5 does not say which α gave it).
      versus: its % of expert − BC-OH's over seeds, in points, with its 95% Welch t-interval (None for BC-OH itself
        or where either arm has no seeds).
      diagnostics: its copycat diagnostics over seeds (`policy_diagnostics`).
    """

    method: str
    hparams: dict
    label: str
    normalized: RecipeCell | None
    returns: RecipeCell | None
    paper: float | None
    versus: Interval | None
    diagnostics: PolicyDiagnostics


class RegimeTable(NamedTuple):
    """One regime group's table: the group, its rows (`RegimeRow`, in `REGIME_METHODS` order), BC-OH's row (None
    where it did not run), Table 5's BC-OH for the ratios, and the history's share of the gap between BC-SO and
    BC-full over seeds (`history_share`; None where one of the three did not run)."""

    group: Group
    rows: tuple[RegimeRow, ...]
    bcoh: RegimeRow | None
    paper_bcoh: float | None
    share: Share | None


def is_regime(m: Group) -> bool:
    """Whether group `m` is one of Table 5 with FCA's expert: MuJoCo-State under the mujoco-state protocol split by rows
    with the bn-mlp recipe (the FCA code's), the protocol's own history and no previous action in view, and
    demonstrations from an imported expert (`Group.protocol["expert_sha256"]`) or with raw labels."""
    p = m.protocol
    return (m.env in MUJOCO and m.obs == "pos" and p.get("variant_of") == STATE and p.get("recipe") == "bn-mlp"
            and p.get("split") == "rows" and other_history(p) is None and not p.get("prev_action")
            and "preset" not in p and (bool(p.get("expert_sha256")) or raw_labels(p)))


def regime_groups(merged: Merged) -> list[Group]:
    """The groups of `is_regime`, by task (`MUJOCO` order), then imported experts before shipped ones, raw labels
    before clipped, then name and budget (the preset's first)."""
    rank = {e: i for i, e in enumerate(MUJOCO)}
    found = [m for _, m in ordered(merged) if is_regime(m)]
    return sorted(found, key=lambda m: (rank[m.env], not m.protocol.get("expert_sha256"),
                                        not raw_labels(m.protocol), m.protocol["name"], m.budget or 0))


def cell_title(m: Group) -> str:
    """A cell's short name in the tables: the task and what sets it apart (`"Hopper (FCA's expert, raw labels)"`,
    `"Hopper (FCA's expert, clipped labels)"`, `"Walker2d (rough expert, raw labels)"`, `"Hopper"`). Labels are named
    where they matter: raw ones always, clipped ones beside an expert of FCA's kind (the shipped experts' actions
    are in range either way)."""
    p = m.protocol
    why = ("FCA's expert" if p.get("expert_sha256") else f"{p['expert']} expert" if p.get("expert") else "")
    labels = "raw labels" if raw_labels(p) else "clipped labels" if why else ""
    why = ", ".join(w for w in (why, labels, "previous action in view" if p.get("prev_action") else "") if w)
    title = tasks.get(m.env).title
    return f"{title} ({why})" if why else title


def regime_budget_groups(merged: Merged) -> list[Group]:
    """The groups of `regime_groups` trained for the `paper` preset's iterations (Table 5 with FCA's expert at the
    paper's budget, evaluated over training), in its order."""
    return [m for m in regime_groups(merged)
            if all(src.preset == "paper" and trained_its_preset(src) for src in m.sources)]


# How labels name the paper's hyperparameters; any other is named only where it varies (FCA's adversary lr).
_WORDS = {"thr": lambda v: f"THR {100 * v:g}%", "w": lambda v: f"W {v:g}", "tau": lambda v: f"τ {v:g}",
          "alpha": lambda v: f"α {v:g}"}


def _row_label(m: Group, row: dict) -> str:
    """`"Ours (step), THR 10% W 5"`, `"FCA (TCA), α 2"`, `"BC-OH"`: the method's label and the hyperparameters of the
    paper's words, then any other that differs between the method's configurations in `m`."""
    name = CEILING_LABEL if row["method"] == CEILING else label(m.methods, row["method"])
    siblings = method_rows(m, row["method"])
    words = [_WORDS[k](v) if k in _WORDS else f"{k} {v:g}" for k, v in row["hparams"].items()
             if k in _WORDS or len({r["hparams"].get(k) for r in siblings}) > 1]
    return f"{name}, {' '.join(words)}" if words else name


def _values(runs: list[dict], key: str) -> list[float]:
    return [r["eval"][key] for r in sorted(runs, key=lambda r: r.get("seed", 0)) if is_finite(r["eval"].get(key))]


def _paper(m: Group, row: dict) -> float | None:
    """Table 5's return beside a configuration: BC-SO's, BC-OH's, Ours' at the paper's step setting, FCA's (either
    variant, every α); None for the rest."""
    method = row["method"]
    key = ("ours" if method == "ours-step" and row["hparams"] == PAPER_STEP else
           "fca" if method in ("fca", "fca-ib") else method if method in ("bc-so", "bc-oh") else None)
    return None if key is None else float(PAPER_TABLE5[key][m.env])


def regime_table(m: Group) -> RegimeTable:
    """Group `m`'s `RegimeTable`: every configuration with seeds, `REGIME_METHODS` first (each method's
    configurations in hyperparameter order), then any other method in summary order."""
    order = {name: i for i, name in enumerate(REGIME_METHODS)}
    chosen = sorted((r for r in m.summary if r["n_seeds"]),
                    key=lambda r: (order.get(r["method"], len(order)), r["method"] if r["method"] not in order else "",
                                   tuple(sorted(r["hparams"].items()))))
    bcoh_row = next(iter(method_rows(m, "bc-oh")), None)
    bcoh = None if bcoh_row is None else mean_cell(
        _values(ok_runs(m, "bc-oh", bcoh_row["hparams"]), "normalized"))
    rows = []
    for row in chosen:
        runs = ok_runs(m, row["method"], row["hparams"])
        normalized = mean_cell(_values(runs, "normalized"))
        versus = (mean_difference(normalized.seeds, bcoh.seeds)
                  if normalized is not None and bcoh is not None and row["method"] != "bc-oh" else None)
        rows.append(RegimeRow(row["method"], dict(row["hparams"]), _row_label(m, row), normalized,
                              mean_cell(_values(runs, "return_mean")), _paper(m, row), versus,
                              policy_diagnostics(runs)))
    paper_bcoh = float(PAPER_TABLE5["bc-oh"][m.env]) if m.env in PAPER_TABLE5["bc-oh"] else None
    return RegimeTable(m, tuple(rows), next((r for r in rows if r.method == "bc-oh"), None), paper_bcoh,
                       history_share(m))

