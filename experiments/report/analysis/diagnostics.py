"""Copycat diagnostics per policy (`ape_jax.diagnostics`, each run's `diagnostics`), at the end and over training.

- `policy_diagnostics`: one configuration's seeds, medians and ranges of the ratios and the verdict count;
- `diagnostics_rows`, `recipe_diagnostics`, `diagnostics_thresholds`: the diagnostics tables' rows and criteria;
- `run_at`, `training_points`: the policies at each iteration they were evaluated at (`Budget.eval_at`).
"""

from __future__ import annotations

from typing import NamedTuple
from collections.abc import Sequence

import numpy as np

from ape_jax import tasks
from ape_jax.pipeline import results as results_lib
from experiments.report.analysis.differences import RecipeCell, mean_cell
from experiments.report.analysis.groups import Group
from experiments.report.analysis.selection import is_finite, label, ok_runs, seed_values


class Spread(NamedTuple):
    """A ratio over a configuration's seeds: the median and the seeds' range, over the `n` seeds that recorded it."""

    median: float
    low: float
    high: float
    n: int


class PolicyDiagnostics(NamedTuple):
    """The copycat diagnostics of one configuration's seeds (`policy_diagnostics`).

    `read` counts the seeds whose diagnostics could be read (`copycats` of them judged copycat by the first
    verdict); `judged` those of them with the controlled verdict (`ape_jax.pipeline.judge`; 0 in a file without a
    control), `controlled` of them judged copycat by it; `embedding`, `velocity`, `predictability` and `control`
    are the ratios over those seeds (None where no seed recorded one: e.g. velocity on data without `qvel`);
    `absent` the distinct reasons of the seeds the diagnostics could not read, with how many seeds gave each.
    """

    read: int
    copycats: int
    embedding: Spread | None
    velocity: Spread | None
    predictability: Spread | None
    absent: tuple[tuple[str, int], ...]
    state: Spread | None = None  # embedding ÷ the true state's probe (`state_ratio`; files before it: None)
    control: Spread | None = None  # embedding ÷ the no-history control's (`control_ratio`; files without: None)
    judged: int = 0
    controlled: int = 0


def spread(values: Sequence) -> Spread | None:
    """Median, smallest and largest of the finite numbers among `values` (None and non-finite ones skipped);
    None if there are none."""
    x = np.asarray([v for v in values if is_finite(v)], np.float64)
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
    velocity, predictability and control ratios, and how many seeds were judged copycat out of those that were
    read (the first verdict) and out of those with the controlled verdict.

    An absent block (`{"absent": reason}`: a policy the diagnostics cannot read) counts in `absent`, never as
    zero; a null ratio (non-finite when measured) is left out of that ratio's median and range, while its seed's
    verdict still counts.
    """
    ok = [r for r in runs if r["status"] == "ok"]
    read = [d for r in ok if (d := diagnostics_block(r)) is not None]
    reasons = [str(r["diagnostics"]["absent"]) for r in ok
               if isinstance(r.get("diagnostics"), dict) and "absent" in r["diagnostics"]]
    judged = [d["controlled_verdict"] for d in read if "controlled_verdict" in d]
    return PolicyDiagnostics(len(read), sum(d.get("verdict") == "copycat" for d in read),
                             spread([d.get("embedding_ratio") for d in read]),
                             spread([d.get("velocity_ratio") for d in read]),
                             spread([d.get("predictability_ratio") for d in read]),
                             tuple((why, reasons.count(why)) for why in dict.fromkeys(reasons)),
                             spread([d.get("state_ratio") for d in read]),
                             spread([d.get("control_ratio") for d in read]),
                             len(judged), judged.count("copycat"))


class DiagnosticsRow(NamedTuple):
    """One configuration of a group in the diagnostics table: its label and hyperparameters, its ok seeds, its
    mean over them of % of expert (a task judged by a rate: that rate in %; None where not recorded), and its
    `PolicyDiagnostics`."""

    label: str
    hparams: dict
    seeds: int
    normalized: float | None
    diagnostics: PolicyDiagnostics


def diagnostics_rows(m: Group) -> list[DiagnosticsRow]:
    """Every configuration of group `m` whose ok runs record copycat diagnostics (read or absent), in summary
    order; none for a group whose files predate them."""
    out = []
    for row in m.summary:
        runs = ok_runs(m, row["method"], row["hparams"])
        if not has_diagnostics(runs):
            continue
        values = seed_values(m, row, "normalized")
        out.append(DiagnosticsRow(label(m.methods, row["method"]), row["hparams"], len(runs),
                                  float(np.mean(values)) if values else None, policy_diagnostics(runs)))
    return out


def diagnostics_thresholds(sources: Sequence[results_lib.Results]) -> list[dict]:
    """The copycat thresholds (`config["diagnostics"]["thresholds"]`: `{"embedding_ratio": …,
    "predictability_ratio": …}`, and `"control_ratio"` where the file was judged against its control) the files
    record, each distinct one once, in file order."""
    out: list[dict] = []
    for src in sources:
        t = (src.config.get("diagnostics") or {}).get("thresholds")
        if isinstance(t, dict) and t not in out:
            out.append(t)
    return out


def recipe_diagnostics(groups: dict[tuple[str, str, str], dict[str, Group]]
                       ) -> list[tuple[str, str, DiagnosticsRow]]:
    """The recipe section's diagnostics (`recipe_groups`' groups): `(task title, recipe, row)` per configuration
    with diagnostics, by task, then recipe (mlp, bn-mlp, others), then summary order."""
    out = []
    for (env, obs, _), recipes in groups.items():
        title = tasks.get(env).title + ("" if obs == "pos" else f" ({obs})")
        names = [r for r in ("mlp", "bn-mlp") if r in recipes] + [r for r in recipes if r not in ("mlp", "bn-mlp")]
        out += [(title, n, row) for n in names for row in diagnostics_rows(recipes[n])]
    return out


# -- the policies over training (`Budget.eval_at`: each run's `at` list) -------------------------------------------

class TrainingPoint(NamedTuple):
    """One configuration at one iteration of its runs (an `eval_at` point, or the end): % of expert over its
    seeds with a 95% t-interval, its training loss (mean over seeds of the 100 minibatches before; None
    where not recorded) and its `PolicyDiagnostics` there."""

    label: str
    hparams: dict
    iteration: int
    normalized: RecipeCell | None
    train_loss: float | None
    diagnostics: PolicyDiagnostics


def run_at(run: dict, iteration: int, end: int) -> dict | None:
    """A run's record at `iteration`: its `at` entry, or the run itself at the end (`end`); None if neither."""
    if iteration == end:
        return {"eval": run["eval"], "diagnostics": run.get("diagnostics"), "train_loss": run.get("train_loss_final"),
                "losses": run.get("losses"), "status": run["status"]}
    snap = next((a for a in run.get("at") or () if a["iteration"] == iteration), None)
    return None if snap is None else {**snap, "status": run["status"]}


def training_points(m: Group) -> list[TrainingPoint]:
    """Every configuration of group `m` whose runs were also evaluated before the end (`Budget.eval_at`), at each
    of those iterations and at the end, in summary order then iteration order; none for other groups."""
    end = int(m.sources[0].config["iterations"])  # a group's files share their budget
    out = []
    for row in m.summary:
        runs = ok_runs(m, row["method"], row["hparams"])
        points = sorted({a["iteration"] for r in runs for a in r.get("at") or ()})
        if not points:
            continue
        for iteration in [*points, end]:
            at = [a for r in sorted(runs, key=lambda r: r.get("seed", 0)) if (a := run_at(r, iteration, end))]
            seeds = [a["eval"]["normalized"] for a in at if a["eval"].get("normalized") is not None]
            losses = [a["train_loss"] for a in at if is_finite(a.get("train_loss"))]
            out.append(TrainingPoint(label(m.methods, row["method"]), row["hparams"], iteration, mean_cell(seeds),
                                     float(np.mean(losses)) if losses else None, policy_diagnostics(at)))
    return out
