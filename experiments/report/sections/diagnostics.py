"""Copycat diagnostics as tables: per configuration (a group's, or the recipe section's per task and recipe), the
thresholds the files record, and the policies over training."""

from __future__ import annotations

from experiments.report.analysis import (DiagnosticsRow, Group, diagnostics_rows, diagnostics_thresholds,
                                         display_metric, training_points)
from experiments.report.sections.common import hparams_text, pct_cell, ratio_text, table, verdict_count


# Where the diagnostics tables' columns are explained: the hand-written notes beside the generated pages.
COLUMNS = "columns explained in [the notes](notes.md#the-copycat-diagnostics)"


def _diagnostics_cells(row: DiagnosticsRow, control: bool) -> list[str]:
    d = row.diagnostics
    return [hparams_text(row.hparams), str(row.seeds),
            "—" if row.normalized is None else f"{row.normalized:.1f}", ratio_text(d.embedding),
            *([ratio_text(d.control)] if control else []), ratio_text(d.velocity, with_range=False),
            ratio_text(d.predictability), verdict_count(d)]


def diagnostics_table(rows: list[tuple[tuple[str, ...], DiagnosticsRow]], heads: tuple[str, ...] = ("method",),
                      unit: str = "% of expert") -> str:
    """Copycat diagnostics per configuration: seeds, % of expert, embedding ratio (median and range over seeds),
    control ratio (where recorded), velocity 1 − R² (median), predictability ratio (median and range) and the
    verdict counts (the controlled verdict's and the first's).

    Args:
      rows: `(leading cells, row)`, the leading cells one per `heads` (`("Hopper", "bn-mlp", "BC-OH")`).
      heads: the leading columns' headings (the method, and in the recipe table the task and recipe first).
      unit: the heading of the % of expert column (a task judged by a rate: that rate in %).
    """
    state = any(row.diagnostics.state is not None for _, row in rows)   # files from before it: no column
    control = any(row.diagnostics.control is not None for _, row in rows)   # files without a control: none
    return table([*heads, "hparams", "seeds", unit, "embedding ratio", *(["control ratio"] if control else []),
                  "velocity 1 − R²", "predictability ratio", "verdict", *(["embedding ÷ state"] if state else [])],
                 [[*lead, *_diagnostics_cells(row, control), *([ratio_text(row.diagnostics.state)] if state else [])]
                  for lead, row in rows],
                 "l" * (len(heads) + 1) + "r" * (5 + control) + "l" + ("r" if state else ""))


def thresholds_line(thresholds: list[dict]) -> str:
    """The copycat verdicts' criteria as the files record them (`analysis.diagnostics_thresholds`), in one line:
    the controlled verdict's where files record its threshold, and the first verdict's."""
    def number(t: dict, key: str) -> str:
        return f"{t[key]:g}" if isinstance(t.get(key), (int, float)) else "?"

    def rule(t: dict, keys: tuple[tuple[str, str], ...]) -> str:
        return " and ".join(f"{name} ≤ {number(t, key)}" for name, key in keys)

    first_keys = (("embedding ratio", "embedding_ratio"), ("predictability ratio", "predictability_ratio"))
    controlled_keys = (("control ratio", "control_ratio"), ("predictability ratio", "predictability_ratio"))
    fixed = "thresholds fixed before any result, `ape_jax.diagnostics.THRESHOLDS`"
    if not thresholds:
        return "Copycat = both ratios at or below their thresholds, per seed; the files record no thresholds."
    firsts = list(dict.fromkeys(rule(t, first_keys) for t in thresholds))
    controls = list(dict.fromkeys(rule(t, controlled_keys) for t in thresholds if "control_ratio" in t))
    if len(firsts) == 1:
        first = f"{firsts[0]}, both, per seed ({fixed})"
    else:
        first = f"both ratios at or below their thresholds, per seed ({fixed}); the files record different ones: " \
                + "; ".join(firsts)
    if not controls:
        return f"Copycat = {first}."
    return (f"Copycat (the controlled verdict) = a policy that sees a past (a history of more than one observation, "
            f"or the previous action in view) with {' or '.join(controls)}, both, per seed; a policy without a past "
            f"never is. The first verdict, beside it: {first}.")


def _absent_lines(rows: list[tuple[tuple[str, ...], DiagnosticsRow]], heads: tuple[str, ...]) -> list[str]:
    """One bullet per configuration with seeds the diagnostics could not read (shown "—" in the table), with the
    recorded reason: `"- BC-SO (Hopper, recipe bn-mlp): no diagnostics for 1 of 5 seeds: …"`."""
    out = []
    for lead, row in rows:
        where = [f"recipe {v}" if h == "recipe" else v for h, v in zip(heads, lead) if h != "method"]
        where += [", ".join(f"{k} {v:g}" for k, v in row.hparams.items())] if row.hparams else []
        for why, n in row.diagnostics.absent:
            out.append(f"- {row.label}" + (f" ({', '.join(where)})" if where else "")
                       + f": no diagnostics for {n} of {row.seeds} seed{'s' * (row.seeds != 1)}: {why}")
    return out


def diagnostics_lines(rows: list[tuple[tuple[str, ...], DiagnosticsRow]], thresholds: list[dict], caption: str,
                      heads: tuple[str, ...] = ("method",), unit: str = "% of expert") -> list[str]:
    """A diagnostics table with its caption (and where its columns are explained), the thresholds under it and the
    seeds it could not read; nothing without rows."""
    if not rows:
        return []
    absent = _absent_lines(rows, heads)
    return [f"{caption.rstrip(':.')} ({COLUMNS}):", "", diagnostics_table(rows, heads, unit),
            thresholds_line(thresholds), "", *(absent + [""] if absent else [])]


def group_diagnostics(m: Group) -> list[str]:
    """Group `m`'s copycat diagnostics per configuration (`analysis.diagnostics_rows`); nothing for a group whose
    files predate them."""
    rows = [((r.label,), r) for r in diagnostics_rows(m)]
    unit = display_metric(m)[1] if display_metric(m)[0] == "normalized" else "% of expert"
    return diagnostics_lines(rows, diagnostics_thresholds(m.sources), "Copycat diagnostics per configuration",
                             unit=unit)


def training_table(m: Group) -> list[str]:
    """Group `m`'s configurations over training (`Budget.eval_at`): per configuration and iteration, % of expert
    with its 95% t-interval over seeds, the training loss, the copycat diagnostics' medians and the
    verdict count; nothing for a group evaluated at the end only."""
    points = training_points(m)
    if not points:
        return []
    unit = display_metric(m)[1] if display_metric(m)[0] == "normalized" else "% of expert"
    control = any(p.diagnostics.control is not None for p in points)
    return ["The same policies over training (evaluated at `budget.eval_at`'s iterations):", "",
            table(["method", "hparams", "iteration", f"{unit} [95% CI]", "training loss", "embedding ratio",
                   *(["control ratio"] if control else []), "predictability ratio", "verdict"],
                  [[p.label, hparams_text(p.hparams), f"{p.iteration:,}", pct_cell(p.normalized),
                    "—" if p.train_loss is None else f"{p.train_loss:.4g}", ratio_text(p.diagnostics.embedding),
                    *([ratio_text(p.diagnostics.control)] if control else []),
                    ratio_text(p.diagnostics.predictability), verdict_count(p.diagnostics)] for p in points],
                  "ll" + "r" * (5 + control) + "l")]
