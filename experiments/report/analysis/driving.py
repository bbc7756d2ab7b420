"""A driving task's verdict across its driving groups (`driving_verdicts`): the numbers the results page's driving
section states, from the tables `driving_table` picks (the supplement's Tables 1 and 2 and their variants).

The state's groups (every observation mode but the camera's) give the headline: BC-SO and BC-OH in the state's
first table (Table 1 where it ran) with their difference, and the copycat counts over every state table. The camera's
give the best a policy learned from pixels reached, and apart from it the best through a pretrained encoder
(`Key.perception`)."""

from __future__ import annotations

from typing import NamedTuple

from experiments.report.analysis.diagnostics import policy_diagnostics
from experiments.report.analysis.differences import Comparison, driving_comparisons, mean_estimate
from experiments.report.analysis.groups import Group, Key, Merged, is_rate, ordered
from experiments.report.analysis.rates import per_seed
from experiments.report.analysis.selection import driving_rows, driving_table

# The observation mode of a task's camera; its other modes are states.
CAMERA = "image"


class DrivingVerdict(NamedTuple):
    """One driving task's verdict (`driving_verdicts`).

    Attributes:
      env: the task.
      headline: the state's group the verdict quotes: its first table without a variant (`Key`), else its first.
      means: in `headline`, BC-SO's and BC-OH's main metric (`{method: mean over seeds}`, a rate in %), those that ran.
      history: BC-OH − BC-SO in `headline` (`analysis.driving_comparisons`), None where an arm did not run.
      policies: seeds diagnosed over every state group's configurations (the first verdict's), `copycats` of them
        judged copycat by the first verdict; `judged` of them with the controlled verdict, `controlled` of those
        judged copycat by it.
      states: every state group, in report order.
      camera: the highest mean main metric (a rate in %) of a camera policy learned from pixels, over every camera
        group's configurations but the ceiling (BC-full); None where no such group ran.
      perceived: the same through a pretrained encoder; None where none ran.
      cameras: every camera group, in report order.
    """

    env: str
    headline: Key
    means: dict[str, float]
    history: Comparison | None
    policies: int
    copycats: int
    judged: int
    controlled: int
    states: tuple[Key, ...]
    camera: float | None
    perceived: float | None
    cameras: tuple[Key, ...]


def _scale(m: Group) -> float:
    return 100.0 if is_rate(m) else 1.0


def _best(groups: list[Group]) -> float | None:
    """The highest mean over seeds of the main metric among `groups`' configurations but the ceiling."""
    means = [mean_estimate(v)[0] for m in groups for r in driving_rows(m) if not r.ceiling
             and len(v := per_seed(r.runs, m.metric, _scale(m)))]
    return max(means, default=None)


def driving_verdicts(merged: Merged) -> list[DrivingVerdict]:
    """Per task with a driving group of a state (`driving_table`, an observation mode other than `CAMERA`), in report
    order, its verdict across its driving groups; tasks whose driving groups are all the camera's give none."""
    found: dict[str, list[tuple[Key, Group]]] = {}
    for k, m in ordered(merged):
        if driving_table(m) is not None and driving_rows(m):
            found.setdefault(k.env, []).append((k, m))
    out = []
    for env, groups in found.items():
        states = [(k, m) for k, m in groups if k.obs != CAMERA]
        if not states:
            continue
        plain = [(k, m) for k, m in states if not m.protocol.get("variant_of")] or states
        key, head = min(plain, key=lambda km: (driving_table(km[1]).number or 99, plain.index(km)))
        means = {r.method: mean_estimate(v)[0] for r in driving_rows(head) if r.method in ("bc-so", "bc-oh")
                 and len(v := per_seed(r.runs, head.metric, _scale(head)))}
        history = next((c for c in driving_comparisons(head)
                        if (c.a, c.b, c.metric) == ("BC-OH", "BC-SO", head.metric)), None)
        diagnosed = [policy_diagnostics(r.runs) for _, m in states for r in driving_rows(m)]
        cameras = [(k, m) for k, m in groups if k.obs == CAMERA]
        out.append(DrivingVerdict(
            env, key, means, history, sum(d.read for d in diagnosed), sum(d.copycats for d in diagnosed),
            sum(d.judged for d in diagnosed), sum(d.controlled for d in diagnosed), tuple(k for k, _ in states),
            _best([m for k, m in cameras if k.perception is None]), _best([m for k, m in cameras if k.perception]),
            tuple(k for k, _ in cameras)))
    return out
