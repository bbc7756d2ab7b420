"""The sweep's printed table (`python -m experiments.sweep`): one row per configuration, the task's main metric
first, a configuration marked best only where its 95% interval over seeds says so, the copycat diagnostics
beside."""

from __future__ import annotations

import math
import statistics

from experiments import stats


def table(res) -> str:
    """The printed summary: one row per configuration, the task's main metric first, the best marked; where runs
    record copycat diagnostics (`ape_jax.diagnostics`), each configuration's median embedding and predictability
    ratios over seeds and its seeds judged copycat / seeds whose diagnostics could be read."""
    metric = res.main_metric
    shown = list(res.config.get("task_metrics", []))
    best, rule = best_configuration(res)

    def read(runs):  # the readable diagnostics of `runs`; `{"absent": why}` is not read (shown "-", never 0)
        return [d for x in runs if isinstance(d := x.get("diagnostics"), dict) and "absent" not in d]

    def median(blocks, key):
        v = [b[key] for b in blocks if isinstance(b.get(key), (int, float)) and math.isfinite(b[key])]
        return f"{statistics.median(v):.3g}" if v else "-"

    def spread(r, key):  # the sample sd over seeds of the per-seed means (the summary keeps the population sd)
        v = seed_values(res, r, key)
        return stats.sample_sd(v)

    diagnosed = bool(read(res.runs))
    controlled = any("controlled_verdict" in b for b in read(res.runs))   # judged against its BC-SO
    heads = list(shown) if shown else ["return"]   # each cell: mean ± sd over seeds (the footnote says so)
    width = [max(len(h), 15) for h in heads]
    lines = [f"{'':2}{'method':<17}{'hparams':<30}{'seeds':>5}  " + "  ".join(f"{h:>{w}}" for h, w in zip(heads, width))
             + ("" if metric != "return" else f"  {'normalized':>11}")
             + (f"  {'emb ratio':>9}  {'pred ratio':>10}  {'copycat':>7}" if diagnosed else "")
             + (f"  {'ctl ratio':>9}  {'controlled':>10}" if controlled else "")]
    absent = []
    for r in res.summary:
        hp = ", ".join(f"{k}={v:g}" for k, v in r["hparams"].items()) or "-"
        if res.online(r["method"]):
            hp = f"{hp} (online)"
        if not r["n_seeds"]:
            lines.append(f"{'':2}{r['method']:<17}{hp:<30}{0:>5}  {'failed':>{width[0]}}")
            continue
        mark = "* " if r is best else "  "
        if shown:
            scale = {m: 100.0 if m == metric else 1.0 for m in shown}
            cells = [_pm(r["metrics"][m]["mean"], spread(r, m), scale[m], "%" if m == metric else "")
                     for m in shown]
        else:
            sd = spread(r, "return_mean")
            cells = [f"{r['return_mean']:,.1f}" + (f" ± {sd:,.1f}" if sd is not None else " (1 seed)")]
        line = (f"{mark}{r['method']:<17}{hp:<30}{r['n_seeds']:>5}  "
                + "  ".join(f"{c:>{w}}" for c, w in zip(cells, width)))
        if metric == "return":
            line += f"  {r['normalized_mean']:>10.1f}%"
        if diagnosed:
            runs = [x for x in res.runs if x["method"] == r["method"] and x["hparams"] == r["hparams"]
                    and x["status"] == "ok"]
            blocks = read(runs)
            count = f"{sum(b.get('verdict') == 'copycat' for b in blocks)}/{len(blocks)}" if blocks else "-"
            line += (f"  {median(blocks, 'embedding_ratio'):>9}  {median(blocks, 'predictability_ratio'):>10}"
                     f"  {count:>7}")
            if controlled:
                judged = [b["controlled_verdict"] for b in blocks if "controlled_verdict" in b]
                count = f"{judged.count('copycat')}/{len(judged)}" if judged else "-"
                line += f"  {median(blocks, 'control_ratio'):>9}  {count:>10}"
            why = [d["absent"] for x in runs if isinstance(d := x.get("diagnostics"), dict) and "absent" in d]
            absent += [f"no copycat diagnostics: {r['method']}" + (f" {hp}" if r["hparams"] else "")
                       + f", {why.count(w)} of {len(runs)} seeds: {w}" for w in dict.fromkeys(why)]
        lines.append(line)
    e = res.expert
    sd = "mean ± sd over seeds; sd: the sample sd (ddof 1)"
    if e.get("return_mean") is not None:   # the expert's mean alone: its card's sd is over episodes, not seeds
        lines.append(f"expert {e['return_mean']:,.1f}, random policy {e['random_return_mean']:,.1f}; normalized = "
                     f"100 (R - R_random) / (R_expert - R_random); {sd}; {rule}")
    elif metric != "return":
        lines.append(f"{metric} in % of episodes; the other metrics are per-episode means; {sd}; {rule}")
    else:
        lines.append(f"{sd}; {rule}")
    if diagnosed:
        t = (res.config.get("diagnostics") or {}).get("thresholds") or {}
        rule = " and ".join(f"{name} ratio <= " + (f"{t[key]:g}" if isinstance(t.get(key), (int, float)) else
                                                   "(threshold not recorded)")
                            for name, key in (("embedding", "embedding_ratio"),
                                              ("predictability", "predictability_ratio")))
        lines += [f"copycat = {rule} (both, per seed; fixed before any result)",
                  "emb / pred ratio: medians over seeds; copycat: seeds judged copycat / seeds with diagnostics"]
        if controlled:
            c = t.get("control_ratio")
            lines.append("controlled = a policy that sees a past with ctl ratio <= "
                         + (f"{c:g}" if isinstance(c, (int, float)) else "(threshold not recorded)")
                         + " and pred ratio <= " + (f"{t['predictability_ratio']:g}" if isinstance(
                             t.get("predictability_ratio"), (int, float)) else "(threshold not recorded)")
                         + "; ctl ratio: the embedding's error on a_t-1 / the median of bc-so's (no history, the "
                         "same rows and probe)")
    lines += absent
    for r in res.runs:
        if r["status"] != "ok":
            lines.append(f"failed: {r['method']} {r['hparams']} seed {r['seed']}: {r['error']}")
    return "\n".join(lines)


def seed_values(res, row: dict, key: str) -> list[float]:
    """The per-seed values of `key` (a field of each run's `eval`) of one summary row's finished runs."""
    return [x["eval"][key] for x in res.runs if x["method"] == row["method"] and x["hparams"] == row["hparams"]
            and x["status"] == "ok" and isinstance((x.get("eval") or {}).get(key), (int, float))
            and math.isfinite(x["eval"][key])]


def best_configuration(res) -> tuple[dict | None, str]:
    """The summary row the table marks best, or None, and the rule's words for the legend.

    The rule: the configuration with the highest mean of the task's main metric over seeds is best only where its
    95% interval over seeds (Student's t: mean ± t(0.975, n-1) sd / sqrt(n), sd with ddof 1) lies wholly above
    every other configuration's mean. One seed gives no interval, so nothing is marked.
    """
    key = "return_mean" if res.main_metric == "return" else res.main_metric  # normalized: the same order
    means = [(sum(v) / len(v), r, v) for r in res.summary if r["n_seeds"] and (v := seed_values(res, r, key))]
    if len(means) < 2:
        return None, "one configuration: none is marked best"
    means.sort(key=lambda m: m[0], reverse=True)
    top, row, values = means[0]
    if len(values) < 2:
        return None, "1 seed: no interval, so none is marked best (--seeds 3 or more for one)"
    if stats.mean_interval(values).low > means[1][0]:
        return row, "* = best: its 95% interval over seeds (Student's t) lies above every other configuration's mean"
    return None, ("no * (best): no configuration's 95% interval over seeds (Student's t) lies above every other's "
                  "mean")


def _pm(mean, sd, scale: float, unit: str) -> str:
    """`mean ± sd` as a cell (`sd` None: one seed, no spread to show)."""
    if mean is None:
        return "-"
    digits = 1 if scale != 1 else 2
    cell = f"{scale * mean:,.{digits}f}{unit}"
    return cell + (f" ± {scale * sd:,.{digits}f}{unit}" if sd is not None else " (1 seed)")
