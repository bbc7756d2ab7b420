"""`results.json`: the one reader, writer and validator of a sweep's results, and the records it holds.

    res = results.load("runs/sweep/hopper-pos-quick/results.json")   # validated, schema 1 upgraded
    res.label("ours-step"), res.records(), res.fingerprint()
    results.save(path, res)                                           # atomic

What goes into it is built by `ape_jax.pipeline.records` (each run's record from a group's
evaluation outputs, which the sweep's `assemble` phase calls); here is `fingerprint`, the settings that identify
a sweep: `SweepSpec.fingerprint` (a checkpoint's `sweep.json`) and `Results.fingerprint`
(a finished file) both build it, so a rerun compares like with like. Where the file
lives in a sweep's output folder is `rundir.RunDir`'s.

The layout is `docs/design.md`'s. It writes schema 3
(`SCHEMA`) and reads every schema in `READS`. Beside the task, the resolved `config`, the runs and
the summary, a file holds:

- `command`: the exact command line the sweep ran with (`None` from Python);
- `protocol`: how demonstrations and evaluation were set up, as the environment resolves it
  (frame skip, episode length, reward scale, history, the split);
- `settings`: the sweep's three records as resolved (`ape_jax.pipeline.presets.Settings`):
  `protocol` (the record's own fields), `budget` and `recipe`;
- `methods`: per method its label, role, program and whether it is online,
  so a report reads a plugin's label without importing the plugin;
- summary rows' `metrics`: mean and std over seeds of the task's own
  per-episode metrics (ToyCar's success, violations, …);
- each run's `train_final`: the mean of every training metric over the run's last 1%;
- optionally `reevaluated` (what `experiments.evaluate` added later) and `replaces`
  (`replaced_record`: the file this sweep was trained again to replace, because that one's
  policies were not kept: its command, provenance, summary and per-run returns).

A file of an older schema is upgraded on load: `settings` is rebuilt from its flat `config`
(recipe `mlp`, a split by episode, which is what such sweeps ran), and a schema 1 file's
`methods` come from the registry (or the name), its `command` empty and its `protocol` `brax` (the only
one before protocols were recorded). Anything
else that is not a complete, well-typed results file is refused with a one-line `ResultsError`
naming the file and the field.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import pathlib
from typing import Any
from collections.abc import Sequence

import numpy as np

from ape_jax import methods as methods_lib
from ape_jax.pipeline import older_files as older
from ape_jax.pipeline.data import write_atomic
from ape_jax.pipeline.presets import SECTIONS, Settings


SCHEMA = 3
READS = (1, 2, 3)


class ResultsError(ValueError):
    """A results file that cannot be used (one line: the file and the problem)."""


@dataclasses.dataclass
class Results:
    """One sweep's results (its fields: the module docstring, and `docs/design.md`'s "Files")."""

    env: str
    obs: str
    preset: str
    config: dict
    expert: dict
    runs: list[dict]
    summary: list[dict]
    timing: dict = dataclasses.field(default_factory=dict)
    system: dict | None = None
    command: list[str] | None = None
    protocol: dict = dataclasses.field(default_factory=dict)
    settings: dict = dataclasses.field(default_factory=dict)
    methods: dict[str, dict] = dataclasses.field(default_factory=dict)
    reevaluated: dict | None = None
    replaces: dict | None = None
    schema: int = SCHEMA
    # the schema the file was written in, before `from_json` upgraded it (None: made in memory); never written
    written_schema: int | None = None

    # -- reading --------------------------------------------------------------------------------------------------
    @classmethod
    def from_json(cls, obj: Any, where: str = "results") -> Results:
        """Validates `obj` (a parsed results.json) and returns it, an older schema upgraded to `SCHEMA` (the one it
        was written in kept as `written_schema`)."""
        if not isinstance(obj, dict):
            raise ResultsError(f"{where}: not a sweep results file (a JSON object is expected)")
        missing = [k for k in _REQUIRED if k not in obj]
        if missing:
            raise ResultsError(f"{where}: not a sweep results file (missing {', '.join(missing)})")
        if obj["schema"] not in READS:
            raise ResultsError(f"{where}: results schema {obj['schema']!r}; this version reads schemas "
                               f"{', '.join(map(str, READS))}")
        validate(obj, where)
        obj = json.loads(json.dumps(obj))  # a copy: the caller's object is left as it was
        obj["written_schema"] = obj["schema"]
        if obj["schema"] == 1:  # before protocols: Brax's own frame skip and episodes, the protocol `brax`
            obj.update(command=None, protocol={"name": "brax"}, methods={})
        if obj["schema"] < 3:
            obj.update(schema=SCHEMA, settings=older.legacy_settings(obj))
            if obj["protocol"]:
                obj["protocol"].setdefault("split", "episodes")
        older.current_names(obj)
        older.task_versions(obj)
        names = dict.fromkeys([*obj["config"].get("methods", []), *(r["method"] for r in obj["runs"])])
        known = {**{m: method_info(m) for m in names if m not in obj.get("methods", {})}, **obj.get("methods", {})}
        fields = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in obj.items() if k in fields and k != "methods"}, methods=known)

    def to_json(self) -> dict:
        out = {"schema": self.schema, "env": self.env, "obs": self.obs, "preset": self.preset,
               "command": self.command, "protocol": self.protocol, "settings": self.settings, "methods": self.methods,
               "config": self.config, "expert": self.expert, "runs": self.runs, "summary": self.summary,
               "timing": self.timing, "system": self.system}
        if self.reevaluated is not None:
            out["reevaluated"] = self.reevaluated
        if self.replaces is not None:
            out["replaces"] = self.replaces
        return _finite_or_none(out)

    def label(self, method: str) -> str:
        return self.methods.get(method, {}).get("label") or method

    def online(self, method: str) -> bool:
        return bool(self.methods.get(method, {}).get("online"))

    def role(self, method: str) -> str:
        return self.methods.get(method, {}).get("role") or "plugin"

    def records(self) -> Settings:
        """The protocol, budget and recipe this sweep ran with, and the iterations its preset gave before overrides
        (`config.preset_iterations`; None in a file from before it), as `presets.resolve` built them."""
        return dataclasses.replace(Settings.from_json(self.settings, preset=self.preset),
                                   preset_iterations=self.config.get("preset_iterations"))

    @property
    def recipe_name(self) -> str:
        return (self.settings.get("recipe") or {}).get("name") or "mlp"

    @property
    def split(self) -> str:
        """How the demonstrations were split: `"rows"` or `"episodes"`."""
        return (self.settings.get("protocol") or {}).get("split") or "episodes"

    def fingerprint(self) -> dict:
        """The settings that identify the sweep (`fingerprint`; what its `SweepSpec.fingerprint` gave)."""
        return fingerprint(self.env, self.obs, self.preset, self.settings, self.config.get("methods"),
                           self.config.get("data", {}).get("settings"), self.protocol)

    @property
    def main_metric(self) -> str:
        """`"return"`, or the task metric the sweep is judged by (ToyCar: `"success"`)."""
        return self.config.get("metric", "return")


def fingerprint(env: str, obs: str, preset: str, settings: dict, methods: Sequence[str] | None, data: dict | None,
                protocol: dict) -> dict:
    """The settings that identify a sweep: what a checkpoint (`checkpoint.SweepCheckpoint`, its `sweep.json`) and
    a finished results.json (`Results.fingerprint`) are compared by before a sweep resumes or reruns.

    Args:
      env, obs, preset: the task, the observation mode and the budget's name.
      settings: the three records as JSON (`presets.Settings.to_json`, results.json's `settings`).
      methods: the method names asked for, in order (results.json's `config.methods`).
      data: what names the demonstrations (`SweepSpec.data_settings`, results.json's `config.data.settings`).
      protocol: the protocol as it applies to the environment (`SweepSpec.protocol_settings`, results.json's
        `protocol`).

    Returns:
      `{"env", "obs", "preset", "settings", "methods", "data", "protocol"}`, in that order (a checkpoint's
      `sweep.json` holds exactly this).
    """
    return {"env": env, "obs": obs, "preset": preset, "settings": settings,
            "methods": None if methods is None else list(methods), "data": data, "protocol": protocol}


_REQUIRED = ("schema", "env", "obs", "preset", "config", "expert", "runs", "summary", "system")

def method_info(name: str) -> dict:
    """What `results.json` records of a method: label, role, program, online (from the registry if it knows it)."""
    try:
        m = methods_lib.get(name)
    except methods_lib.MethodError:
        return {"label": name, "role": "plugin", "program": None, "online": False}
    return {"label": m.label, "role": m.role, "program": m.program, "online": m.online}


def load(path: str | pathlib.Path) -> Results:
    """Reads and validates a results.json (`ResultsError` naming the file if it cannot be used)."""
    try:
        obj = json.loads(pathlib.Path(path).read_text())
    except (OSError, UnicodeDecodeError) as e:
        raise ResultsError(f"{path}: cannot read ({e})") from None
    except json.JSONDecodeError as e:
        raise ResultsError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from None
    return Results.from_json(obj, str(path))


def save(path: str | pathlib.Path, results: Results) -> None:
    """Writes `results` to `path` atomically (a temporary file renamed into place)."""
    write_json(path, results.to_json())


def write_json(path: str | pathlib.Path, obj: Any) -> None:
    write_atomic(pathlib.Path(path),
                 lambda f: f.write((json.dumps(obj, indent=2, allow_nan=False) + "\n").encode()))


def write_csv(path: str | pathlib.Path, results: Results) -> None:
    """`results.csv`: one summary row per configuration, the task's own metrics first (ToyCar: success, …)."""
    metrics = list(results.config.get("task_metrics", []))
    rows = io.StringIO()
    w = csv.writer(rows)
    w.writerow(["method", "label", "hparams", "n_seeds", *(f"{m}_{s}" for m in metrics for s in ("mean", "std")),
                "return_mean", "return_std", "normalized_mean", "normalized_std"])
    for row in results.summary:
        ms = row.get("metrics", {})
        w.writerow([row["method"], results.label(row["method"]), json.dumps(row["hparams"], sort_keys=True),
                    row["n_seeds"], *(ms.get(m, {}).get(s) for m in metrics for s in ("mean", "std")),
                    row["return_mean"], row["return_std"], row["normalized_mean"], row["normalized_std"]])
    write_atomic(pathlib.Path(path), lambda f: f.write(rows.getvalue().encode()))


# -- a sweep trained again to replace a file whose policies were not kept ---------------------------------------------

# What must agree for one sweep to stand for another trained again: the `config` fields and the protocol's (those both
# files record: older ones record fewer).
_SAME_CONFIG = ("iterations", "seeds", "eval_episodes", "batch_size", "lr", "history", "methods", "step_grid",
                "softmax_grid", "image_size", "encoder", "loss", "metric")
_SAME_PROTOCOL = ("name", "frame_skip", "episode_length", "reward_scale", "collect_transitions", "train_transitions",
                  "val_transitions", "history", "split")


def retraining_differences(old: Results, new: Results) -> list[str]:
    """Why `new` is not `old`'s sweep trained again (empty when it is): the task, observation mode, preset, recipe,
    protocol, budget, grids and methods must agree wherever both files record them, and so must the runs (method,
    seed and hparams, `same_knobs`). The code, and so the numbers, may differ: that is what training again means."""
    out = [f"{k} {getattr(old, k)!r} against {getattr(new, k)!r}" for k in ("env", "obs", "preset")
           if getattr(old, k) != getattr(new, k)]
    if old.recipe_name != new.recipe_name:
        out.append(f"recipe {old.recipe_name!r} against {new.recipe_name!r}")
    if old.split != new.split:
        out.append(f"split {old.split!r} against {new.split!r}")
    out += [f"protocol {k} {old.protocol[k]!r} against {new.protocol[k]!r}" for k in _SAME_PROTOCOL
            if k in old.protocol and k in new.protocol and old.protocol[k] != new.protocol[k]]
    out += [f"{k} {old.config[k]!r} against {new.config[k]!r}" for k in _SAME_CONFIG
            if k in old.config and k in new.config and old.config[k] != new.config[k]]
    matched = retrained_hparams(old, new)
    gone = [r for r in old.runs if run_key(r) not in matched]
    extra = len(new.runs) - (len(old.runs) - len(gone))
    if gone or extra:
        first = (f"{gone[0]['method']} {gone[0]['hparams']} seed {gone[0]['seed']} has no run trained again" if gone
                 else "it has runs the first training did not")
        out.append(f"the runs differ ({len(gone)} missing, {extra} extra: {first})")
    return out


def same_knobs(method: str, a: dict, b: dict, lr: float) -> bool:
    """Whether hparams `a` and `b` configure `method` alike: equal, or made into the same traced knobs by the
    method's `hparams` (a knob one leaves out takes its default: FCA's `adversary_lr` is `lr` unless given)."""
    if a.keys() == b.keys() and all(float(a[k]) == float(b[k]) for k in a):
        return True
    try:
        knobs = [methods_lib.get(method).hparams(h, lr, 0) for h in (a, b)]
    except (methods_lib.MethodError, KeyError, TypeError, ValueError):
        return False
    import jax   # here: reading a results file does not need it

    leaves = [jax.tree.leaves(k) for k in knobs]
    return len(leaves[0]) == len(leaves[1]) and all(np.array_equal(np.asarray(x), np.asarray(y))
                                                    for x, y in zip(*leaves))


def run_key(run: dict) -> tuple:
    """A run's identity, hashable: `(method, hparams as JSON with sorted keys, seed)`."""
    return run["method"], json.dumps(run["hparams"], sort_keys=True), run["seed"]


def retrained_hparams(old: Results, new: Results) -> dict[tuple, dict]:
    """Per run of `old` (`(method, hparams as JSON, seed)`), the hparams of the run of `new` that trains it again
    (the same method and seed, `same_knobs`); runs without one are left out."""
    lr = float(old.config.get("lr") or (old.settings.get("recipe") or {}).get("lr") or 2e-4)
    free = list(new.runs)
    out = {}
    for run in old.runs:
        twin = next((r for r in free if r["method"] == run["method"] and r["seed"] == run["seed"]
                     and same_knobs(run["method"], run["hparams"], r["hparams"], lr)), None)
        if twin is not None:
            free.remove(twin)
            out[run_key(run)] = twin["hparams"]
    return out


def replaced_record(old: Results, file: str, new: Results | None = None) -> dict:
    """`replaces` of a sweep trained again to stand for `old` (read from `file`): what `old` recorded of where it came
    from (`command`, `system`, `timing`), its `summary`, and each run's mean return, so the first training's numbers
    stay readable beside the new ones; a record `old` had itself is nested under `replaces`. Given `new`, a row whose
    hparams `new` writes otherwise (`same_knobs`) takes `new`'s, its own kept as `hparams_recorded`, so the two
    files' rows match by configuration."""
    matched = retrained_hparams(old, new) if new is not None else {}
    by_config = {(k[0], k[1]): hp for k, hp in matched.items()}

    def rekeyed(row: dict) -> dict:
        hp = by_config.get((row["method"], json.dumps(row["hparams"], sort_keys=True)))
        if hp is None or hp == row["hparams"]:
            return row
        return {**row, "hparams": hp, "hparams_recorded": row["hparams"]}

    record = {"file": file, "command": old.command, "system": old.system, "timing": old.timing,
              "summary": [rekeyed(row) for row in old.summary],
              "runs": [{**rekeyed({"method": r["method"], "hparams": r["hparams"]}), "seed": r["seed"],
                        "status": r["status"], "return_mean": (r.get("eval") or {}).get("return_mean")}
                       for r in old.runs]}
    if old.replaces is not None:
        record["replaces"] = old.replaces
    return record


# -- the summary ----------------------------------------------------------------------------------------------------

def summarize(runs: Sequence[dict], metrics: Sequence[str] = (), ddof: int = 0) -> list[dict]:
    """Mean and std over seeds of the per-seed means, per (method, hparams); failed runs left out.

    `metrics` (the task's own per-episode metrics) are summarised the same way under each row's `metrics`. The std
    is the population one (`ddof` 0) in `results.json`, as every file has written it; the report asks for the
    sample sd (`ddof` 1). Either is None where fewer than 2 seeds leave no spread to estimate (a 1-seed row
    stores null, not 0.0).
    """
    groups: dict[tuple, list[dict]] = {}
    for r in runs:
        groups.setdefault((r["method"], tuple(sorted(r["hparams"].items()))), []).append(r)
    rows = []
    for (method, hp), rs in groups.items():
        ok = [r for r in rs if r["status"] == "ok"]

        def stats(key):
            values = np.array([np.nan if r["eval"].get(key) is None else r["eval"][key] for r in ok], np.float64)
            if not ok:
                return None, None
            return float(values.mean()), float(values.std(ddof=ddof)) if len(ok) > max(ddof, 1) else None

        row = {"method": method, "hparams": dict(hp), "n_seeds": len(ok)}
        row["return_mean"], row["return_std"] = stats("return_mean")
        row["normalized_mean"], row["normalized_std"] = stats("normalized")
        if metrics:
            row["metrics"] = {m: dict(zip(("mean", "std"), stats(m))) for m in metrics}
        rows.append(row)
    return _finite_or_none(rows)


def _finite_or_none(tree):
    """`tree` with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(tree, dict):
        return {k: _finite_or_none(v) for k, v in tree.items()}
    if isinstance(tree, list):
        return [_finite_or_none(v) for v in tree]
    if isinstance(tree, float) and not math.isfinite(tree):
        return None
    return tree


# -- validation -----------------------------------------------------------------------------------------------------

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
        raise ResultsError(f"{where} must be an object, got {type(row).__name__}")
    for key, (test, want) in fields.items():
        if key not in row:
            raise ResultsError(f"{where} has no field '{key}'")
        if not test(row[key]):
            raise ResultsError(f"{where} field '{key}' must be {want}, got {row[key]!r:.80}")


_TEXT = (lambda v: isinstance(v, str), "a string")
_OBJECT = (lambda v: isinstance(v, dict), "an object")
_SUMMARY = {"method": _TEXT, "hparams": (_hparams, "an object of numbers"),
            "n_seeds": (_count, "an int >= 0"),
            "return_mean": (_optional(_number), "a number or null"),
            "return_std": (_optional(_number), "a number or null")}
_RUN = {"method": _TEXT, "hparams": (_hparams, "an object of numbers"), "status": _TEXT}
_EVAL = {"return_mean": (lambda v: _number(v) and math.isfinite(v), "a finite number"),
         "normalized": (_optional(_number), "a number or null")}
_DIAGNOSTICS = {"verdict": (lambda v: v in ("copycat", "not copycat"), "'copycat' or 'not copycat'"),
                **{k: (_optional(_number), "a number or null")
                   for k in ("embedding_ratio", "prev_from_embedding", "prev_from_action", "velocity_ratio",
                             "predictability_ratio", "policy_mse", "expert_mse")}}
_LATER_DIAGNOSTICS = {**{k: (_optional(_number), "a number or null")
                         for k in ("prev_from_state", "state_ratio", "control_ratio")},  # optional
                      "controlled_verdict": (lambda v: v in ("copycat", "not copycat"), "'copycat' or 'not copycat'")}
_LOSSES = {s: (lambda v: isinstance(v, dict) and all(
    _number(v.get(k)) for k in ("unweighted", "changepoint", "copycat")), "an object with numbers unweighted, "
    "changepoint and copycat") for s in ("train", "val")}


def validate(obj: dict, where: str = "results") -> None:
    """Refuses (`ResultsError`, one line) a results object lacking a field the readers use, or with a wrong type."""
    _row(f"{where}:", obj, {"env": _TEXT, "obs": _TEXT, "preset": _TEXT, "config": _OBJECT, "expert": _OBJECT,
                            "runs": (lambda v: isinstance(v, list), "a list"),
                            "summary": (lambda v: isinstance(v, list), "a list"),
                            "system": (_optional(lambda v: isinstance(v, dict)), "an object or null")})
    if obj.get("schema") in (2, 3):
        _row(f"{where}:", obj, {"command": (_optional(lambda v: isinstance(v, list) and all(
            isinstance(x, str) for x in v)), "a list of strings or null"), "protocol": _OBJECT, "methods": _OBJECT})
    if obj.get("schema") == 3:
        _row(f"{where}:", obj, {"settings": _OBJECT})
        _row(f"{where}: settings", obj["settings"], {k: _OBJECT for k in SECTIONS})
    _row(f"{where}: config", obj["config"], {k: (_count, "an int >= 0")
                                             for k in ("iterations", "seeds", "eval_episodes")})
    _row(f"{where}: expert", obj["expert"], {k: (_optional(_number), "a number or null")
                                             for k in ("return_mean", "return_std", "random_return_mean")})
    if obj.get("replaces") is not None:
        _row(f"{where}: replaces", obj["replaces"], {"summary": (lambda v: isinstance(v, list), "a list")})
        for i, row in enumerate(obj["replaces"]["summary"]):
            _row(f"{where}: replaces.summary[{i}]", row, _SUMMARY)
    for i, row in enumerate(obj["summary"]):
        _row(f"{where}: summary[{i}]", row, _SUMMARY)
        spread = ("return_mean", "return_std") if row["n_seeds"] > 1 else ("return_mean",)   # 1 seed: no sd
        if row["n_seeds"] and not all(_number(row[k]) and math.isfinite(row[k]) for k in spread):
            raise ResultsError(f"{where}: summary[{i}] has {row['n_seeds']} seeds but return "
                               f"{row['return_mean']!r} ± {row['return_std']!r}; expected finite numbers")
    for i, run in enumerate(obj["runs"]):
        _row(f"{where}: runs[{i}]", run, _RUN)
        if run["status"] == "ok":
            _row(f"{where}: runs[{i}]", run, {"losses": _OBJECT, "eval": _OBJECT})
            _row(f"{where}: runs[{i}] losses", run["losses"], _LOSSES)
            _row(f"{where}: runs[{i}] eval", {"normalized": None, **run["eval"]}, _EVAL)
        _check_diagnostics(f"{where}: runs[{i}]", run)
        for n, snap in enumerate(run.get("at") or ()):  # optional: the policy at `Budget.eval_at`'s iterations
            _row(f"{where}: runs[{i}] at[{n}]", snap, {"iteration": (_count, "an int >= 0"), "eval": _OBJECT})
            _row(f"{where}: runs[{i}] at[{n}] eval", {"normalized": None, **snap["eval"]}, _EVAL)
            _check_diagnostics(f"{where}: runs[{i}] at[{n}]", snap)


def _check_diagnostics(where: str, record: dict) -> None:
    """A record's optional `diagnostics` (files before them have none; a policy without them: {"absent": why})."""
    if "diagnostics" in record:
        diag = record["diagnostics"]
        if not (isinstance(diag, dict) and isinstance(diag.get("absent"), str)):
            _row(f"{where} diagnostics", diag, _DIAGNOSTICS)
            _row(f"{where} diagnostics", diag, {k: v for k, v in _LATER_DIAGNOSTICS.items() if k in diag})
