"""The controlled copycat verdict of a results file's runs (`ape_jax.diagnostics.controlled_verdict`).

A run's `diagnostics` hold its embedding probe and own-rollout predictability and the first verdict. The
controlled verdict also needs the no-history control's (`diagnostics.CONTROL`, BC-SO) probe error on the
same rows with the same probe: from the file itself where its sweep trained BC-SO, else from a sibling file
that shares everything the control's embedding depends on (`control_key`: task, demonstrations, protocol,
recipe, training length, probe).

    judged = judge.judge(res)                            # the file's own BC-SO (JudgeError where it has none)
    judged = judge.judge_own(res)                        # the same, or `res` as it is where it has none
    found = judge.find_control(res, [(name, other), ...])  # a sibling's: (name, Results) or None
    judged = judge.judge(res, found)

To every readable `diagnostics` (each run's, and each `at` snapshot's against the control at the same
iteration) it adds `control_ratio` (`diagnostics.control_ratio`: the policy's error ÷ the median of the
control's seeds') and `controlled_verdict`; to `config.diagnostics`, `thresholds.control_ratio` and `control`
(the method, the file it came from, per iteration its seeds and median error). The first verdict (`verdict`,
`embedding_ratio`) is left as it was. Pure: it returns a new `Results`, and judging a judged file again with
the same control gives the same file.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from ape_jax import diagnostics as diagnostics_lib
from ape_jax import methods as methods_lib
from ape_jax.pipeline.results import Results

CONTROL_FIELDS = ("control_ratio", "controlled_verdict")   # what judging adds to a run's `diagnostics`


class JudgeError(ValueError):
    """A file that cannot be judged (one line: the file and why)."""


def readable(record: dict) -> dict | None:
    """A record's (run's or snapshot's) `diagnostics` if they hold a probe to judge, else None."""
    d = record.get("diagnostics")
    return d if isinstance(d, dict) and "absent" not in d and "prev_from_embedding" in d else None


def sees_past(res: Results, method: str) -> bool:
    """Whether `method`'s policies in `res` see a past: a history longer than one observation (the method's own,
    `Method.history`, else the protocol's), or the previous action in the observation (`protocol.prev_action`).
    A method the registry does not know (a plugin) has the protocol's history."""
    protocol = res.settings.get("protocol") or {}
    try:
        history = methods_lib.get(method).history
    except methods_lib.MethodError:
        history = None
    if history is None:
        history = int(protocol.get("history") or res.config.get("history") or 1)
    return history > 1 or bool(protocol.get("prev_action"))


def control_errors(res: Results) -> dict[int, list[float]]:
    """The no-history control's `prev_from_embedding` in `res`, per iteration (the end: `config.iterations`; and
    each `at` snapshot's), one value per ok seed with a finite one; empty where `res` has no control (no BC-SO,
    or its BC-SO sees the previous action, `protocol.prev_action`)."""
    if (res.settings.get("protocol") or {}).get("prev_action"):
        return {}
    end = int(res.config["iterations"])
    out: dict[int, list[float]] = {}
    for run in res.runs:
        if run["method"] != diagnostics_lib.CONTROL or run["status"] != "ok":
            continue
        for iteration, record in [(end, run), *((int(a["iteration"]), a) for a in run.get("at") or ())]:
            value = (readable(record) or {}).get("prev_from_embedding")
            if isinstance(value, (int, float)) and math.isfinite(value):
                out.setdefault(iteration, []).append(float(value))
    return out


def control_key(res: Results) -> dict:
    """What must agree for one file's control to stand for another's: the task and observation mode, the demonstrations
    (`config.data` but their path), the protocol's fields (but `prev_action`: the control sees no previous
    action; and `history_stride`: it sees one frame, at any stride), the recipe's fields (the learner's: the
    methods' knobs are their own records, `Settings.knobs`), the training length and the probe (fit steps and
    rows). The records as resolved (`Results.records`), so a file from before a field was recorded matches one
    with its default."""
    records = res.records()
    protocol = {k: v for k, v in dataclasses.asdict(records.protocol).items()
                if k not in ("name", "doc", "prev_action", "history_stride")}
    recipe = {k: v for k, v in dataclasses.asdict(records.recipe).items() if k != "name"}
    diag = res.config.get("diagnostics") or {}
    return {"env": res.env, "obs": res.obs,
            "data": {k: v for k, v in (res.config.get("data") or {}).items() if k not in ("path", "sha256")},
            "protocol": protocol, "recipe": recipe, "iterations": res.config.get("iterations"),
            "probe": {"steps": diag.get("probe_steps"), "rows": diag.get("probe_rows")}}


def same_demonstrations(a: Results, b: Results) -> bool:
    """Whether two files' demonstrations can be the same: equal SHA-256 where both record one."""
    sha = [(r.config.get("data") or {}).get("sha256") for r in (a, b)]
    return None in sha or sha[0] == sha[1]


def find_control(res: Results, candidates: Sequence[tuple[str, Results]],
                 resampled: bool = False) -> tuple[str, Results] | None:
    """The sibling among `candidates` (`(name, Results)`) whose control stands for `res`'s: the same
    `control_key`, the same demonstrations (with `resampled`, also ones collected with the same settings that
    differ in their bytes), a control at `res`'s end; of several, the one with the most control seeds there, then
    the first name. None where there is none."""
    key, end = control_key(res), int(res.config["iterations"])
    found = [(name, c) for name, c in candidates
             if control_errors(c).get(end) and control_key(c) == key and (resampled or same_demonstrations(res, c))]
    if not found:
        return None
    return min(found, key=lambda nc: (-len(control_errors(nc[1])[end]), nc[0]))


def judge(res: Results, control: tuple[str, Results] | None = None,
          thresholds: diagnostics_lib.Thresholds = diagnostics_lib.THRESHOLDS, resampled: bool = False) -> Results:
    """`res` with the controlled verdict of every readable `diagnostics` (module docstring).

    Args:
      res: a results file.
      control: `(file name, Results)` of a sibling whose control stands for `res`'s (`find_control`); None: `res`'s
        own.
      thresholds: the criteria (default `diagnostics.THRESHOLDS`).
      resampled: accept a `control` whose demonstrations were collected with the same settings (`control_key`) but
        differ in their bytes: one deterministic expert's long rollouts diverge in float rounding from one CPU to
        another, so the data is another sample of the same distribution. Recorded in `config.diagnostics.control`
        (`demonstrations`: both SHA-256).

    Returns:
      A new `Results`; a record without a control at its iteration keeps no control fields.

    Raises:
      JudgeError: no control at `res`'s end, or a `control` that does not stand for `res`'s.
    """
    end = int(res.config["iterations"])
    name, source = (None, res) if control is None else control
    if control is not None and (control_key(source) != control_key(res)
                                or not (resampled or same_demonstrations(res, source))):
        raise JudgeError(f"{name} does not share the demonstrations, protocol, recipe, training length and probe "
                         "of the file it would control")
    errors = control_errors(source)
    if not errors.get(end):
        raise JudgeError(f"{name or 'the file'} has no {diagnostics_lib.CONTROL} policy with diagnostics at "
                         f"{end:,} iterations to control the verdict"
                         + (" (its policies see the previous action)"
                            if (source.settings.get("protocol") or {}).get("prev_action") else ""))
    runs = copy.deepcopy(res.runs)
    for run in runs:
        past = sees_past(res, run["method"])
        for iteration, record in [(end, run), *((int(a["iteration"]), a) for a in run.get("at") or ())]:
            d = readable(record)
            if d is None:
                continue
            for k in CONTROL_FIELDS:
                d.pop(k, None)
            if not errors.get(iteration):
                continue
            ratio = float(diagnostics_lib.control_ratio(_number(d.get("prev_from_embedding")), errors[iteration]))
            v = diagnostics_lib.controlled_verdict(ratio, _number(d.get("predictability_ratio")), past, thresholds)
            d["control_ratio"] = ratio if math.isfinite(ratio) else None
            d["controlled_verdict"] = v.label
    config = copy.deepcopy(res.config)
    diag = config.setdefault("diagnostics", {})
    diag["thresholds"] = {**(diag.get("thresholds") or {}), "control_ratio": thresholds.control_ratio}
    diag["control"] = {
        "method": diagnostics_lib.CONTROL, "file": name,
        "at": [{"iteration": i, "seeds": len(v), "prev_from_embedding": float(np.median(v))}
               for i, v in sorted(errors.items())],
        "rule": "control_ratio = the policy's prev_from_embedding / the median of the control's seeds' at the "
                "same iteration; controlled_verdict: copycat when a policy that sees a past has control_ratio <= "
                "thresholds.control_ratio and predictability_ratio <= thresholds.predictability_ratio"}
    if control is not None and not same_demonstrations(res, source):
        diag["control"]["demonstrations"] = {
            "file": (res.config.get("data") or {}).get("sha256"), "control": source.config["data"]["sha256"],
            "note": "collected with the same settings, other bytes (float rounding on another CPU): another sample"}
    return dataclasses.replace(res, runs=runs, config=config)


def judge_own(res: Results) -> Results:
    """`res` judged against its own control (`judge`) where it has one at its end, else `res` unchanged (a sweep
    without BC-SO: its controlled verdict comes later, from a sibling file, `experiments.evaluate --rejudge`)."""
    return judge(res) if control_errors(res).get(int(res.config["iterations"])) else res


def _number(value) -> float:
    return float(value) if isinstance(value, (int, float)) else math.nan
