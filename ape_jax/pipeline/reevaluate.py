"""Evaluating a finished sweep's saved policies again, to add what its results lack.

    new = reevaluate(results.load("OUT/results.json"), "OUT/params")

A sweep saves every trained policy (`OUT/params/<group>`, orbax, beside
`<group>.json`: its history, observation and runs in order; `checkpoint.save_policies`).
This rebuilds everything the evaluation needs from `results.json` alone: the
preset, the environment, the demonstrations (from the cache, collected again if
missing; each group in its own observation, `sweep.Prepared.view`), and ψ (fitted
again; key 0 makes it deterministic), with the sweep's own phases. It then runs the sweep's own
evaluation (`sweep.evaluate_group`, the same episodes) and adds the fields the file
lacks, such as the copycat diagnostics written by newer code (`imitation_error`
and `rollout_ape`; each run's `diagnostics`, the embedding probe, own-rollout
predictability and verdict of `ape_jax.diagnostics`, with `config.diagnostics`),
and the training APE's `quantiles`.

Nothing is overwritten that the file has: each run's return and every
metric it records must come out as recorded (they do on the same machine and
jax; they would not if the policies, the environment or the demonstrations
had changed), and otherwise `ReevaluationError` says which differ, and
nothing is returned.
"""

from __future__ import annotations

import pathlib
import time
from collections.abc import Callable

import numpy as np

from ape_jax import diagnostics as diagnostics_lib
from ape_jax.pipeline import checkpoint as ckpt_lib
from ape_jax.pipeline import results as results_lib
from ape_jax.pipeline import records as records_lib
from ape_jax.pipeline import sweep as sweep_lib
from ape_jax.pipeline.results import Results
from ape_jax.pipeline.spec import Run, SweepSpec


class ReevaluationError(ValueError):
    """The saved sweep cannot be evaluated again as recorded (one line, for the command line)."""


def _lacks(record: dict) -> bool:
    """Whether a run record lacks copycat diagnostics, or has a readable block without the later fields
    (`ape_jax.diagnostics.LATER_FIELDS`); an absent block (`{"absent": why}`) lacks nothing."""
    diag = record.get("diagnostics")
    if diag is None:
        return True
    return "absent" not in diag and any(k not in diag for k in diagnostics_lib.LATER_FIELDS)


def _same(a, b, rtol: float) -> bool:
    """Whether a recomputed diagnostics value is the recorded one (numbers within `rtol`; null and text equal)."""
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return bool(np.isclose(a, b, rtol=rtol, atol=1e-9))
    return a == b


def spec_of(results: Results, data_dir=None) -> SweepSpec:
    """The `SweepSpec` that produced `results` (its methods need not be registered: only evaluated here)."""
    settings = results.config["data"]["settings"]
    return SweepSpec(results.env, results.obs, results.records(), (), dataset=settings.get("dataset"),
                     data_dir=data_dir)


def reevaluate(results: Results, params_dir: str | pathlib.Path, data_dir=None, log: Callable[[str], None] = print,
               rtol: float = 1e-4, system: dict | None = None) -> Results:
    """A copy of `results` with the evaluation fields it lacks added from its saved policies.

    Runs the sweep's own phases (`sweep.prepare`, `sweep.fit_ape`,
    `sweep.evaluate_group`) on the demonstrations it names (from the cache,
    collected again if missing).

    Args:
      results: a sweep's results (`results.load`).
      params_dir: the sweep's `params/`.
      data_dir: the demonstration cache (default: `ape_jax.pipeline.data.cache_dir()`).
      rtol: how closely each run's mean return must come out as recorded.
      system: provenance of this evaluation (`ape_jax.pipeline.provenance.system()`), recorded beside the fields added.

    Raises:
      ReevaluationError: the policies are missing, the demonstrations or ψ
        are not those of the sweep, or recorded returns or metrics differ
        from the recomputed ones.
    """
    config = results.config
    spec = spec_of(results, data_dir)
    episodes = spec.budget.eval_episodes
    try:
        policies = ckpt_lib.load_policies(params_dir)
    except ckpt_lib.PolicyError as e:
        raise ReevaluationError(str(e)) from None
    prepared = sweep_lib.prepare(spec, sweep_lib.Hooks(log=log))
    recorded = config["data"].get("sha256")   # None in files written before it was; the checks below still hold
    if recorded is not None and prepared.data_sha256 is not None and prepared.data_sha256 != recorded:
        raise ReevaluationError(f"the demonstrations at {prepared.data_path} are not the sweep's (their SHA-256 "
                                "differs from the one it recorded: collected again since?)")
    if len(prepared.train) != config["data"]["train_transitions"]:
        raise ReevaluationError(f"the demonstrations have {len(prepared.train)} training transitions, the sweep had "
                                f"{config['data']['train_transitions']}: they are not the sweep's")
    ape = sweep_lib.fit_ape(prepared, spec.settings)
    recorded_scale = config["ape"]["scale"]
    if not np.isclose(ape.scale, recorded_scale, rtol=1e-4):
        raise ReevaluationError(f"ψ fitted again gives a mean APE of {ape.scale:.6g}, the sweep recorded "
                                f"{recorded_scale:.6g}: the demonstrations or the APE code changed")
    records = {results_lib.run_key(r): r for r in results.runs}
    new = Results.from_json(results.to_json())  # a deep copy: `results` is left as it was
    new_records = {results_lib.run_key(r): r for r in new.runs}
    metrics = (*prepared.task.metrics, *records_lib.COPYCAT_METRICS)
    added, differ, diag_config, diag_s = set(), [], None, 0.0
    t0 = time.perf_counter()
    for name, saved in policies.items():
        history, observation = saved["history"], saved["observation"]
        try:
            view = prepared.view(observation)   # the group's own observation (`bc-full`: the full state)
        except ValueError as e:
            raise ReevaluationError(str(e)) from None
        mean = view.normalizer.mean
        if saved["obs_mean"] is not None and mean is not None and not np.allclose(saved["obs_mean"], mean, rtol=1e-5):
            raise ReevaluationError(f"the saved policies' observation statistics ({name}) are not those of the "
                                    "demonstrations: they were trained on other data")
        runs = tuple(Run(r["method"], r["hparams"], r["seed"]) for r in saved["runs"])
        group = sweep_lib.PolicyGroup(history, view.learner_config(spec.settings, history), runs, saved["params"],
                                      prepared.observing(observation), view)
        seen = "" if group.observation is None else f", reading the {group.observation} observation"
        log(f"evaluating {len(runs)} saved policies with history {history}{seen} ({episodes} episodes each)")
        lacking = any(_lacks(records.get(results_lib.run_key(r), {})) for r in saved["runs"])
        # the steps the file's diagnostics ran (so the fields added beside them are of the same fit), else the
        # budget's, else (a file that ran none) the default's
        steps = ((config.get("diagnostics") or {}).get("probe_steps") or spec.budget.probe_steps
                 or diagnostics_lib.PROBE_STEPS)
        out, _, seconds = sweep_lib.evaluate_group(ape, episodes, group, steps if lacking else 0, spec.budget.width)
        diag_s += seconds
        diag_config = diag_config or records_lib.diagnostics_config(prepared.train.demos, [out])
        for j, run in enumerate(saved["runs"]):
            key = results_lib.run_key(run)
            if key not in records:
                raise ReevaluationError(f"a saved policy ({run['method']} {run['hparams']} seed {run['seed']}) "
                                        "has no run in results.json: the params and the results are of different "
                                        "sweeps")
            was, ev = records[key].get("eval") or {}, new_records[key].setdefault("eval", {})
            diag = records_lib.diagnostics_record(out, j) if lacking else None
            if diag is not None and "diagnostics" not in records[key]:
                new_records[key]["diagnostics"] = diag
                added.add("diagnostics")
            elif diag is not None and _lacks(records[key]):   # diagnostics from before the later fields
                had = records[key]["diagnostics"]
                differ += [f"{run['method']} {run['hparams']} seed {run['seed']} diagnostics {k}: {diag[k]!r} vs "
                           f"{had[k]!r}" for k in had if k in diag and not _same(diag[k], had[k], rtol)]
                for k in diagnostics_lib.LATER_FIELDS:
                    if k in diag and k not in had:
                        new_records[key]["diagnostics"][k] = diag[k]
                        added.add(f"diagnostics.{k}")
            now = {"return_mean": out["return"][j], **{k: out[k][j] for k in metrics if k in out}}
            for k, values in now.items():
                value = float(np.mean(values))
                if was.get(k) is None:
                    if k != "return_mean":
                        ev[k] = value
                        added.add(k)
                elif not np.isclose(value, was[k], rtol=rtol, atol=1e-3):  # what is recorded must come out again
                    differ.append(f"{run['method']} {run['hparams']} seed {run['seed']} {k}: {value:.6g} vs "
                                  f"{was[k]:.6g}")
    if differ:
        raise ReevaluationError(f"{len(differ)} recorded evaluation numbers (returns, metrics) differ from the "
                                f"recomputed ones (e.g. {differ[0]}): the policies, the environment or the "
                                "evaluation changed")
    if "diagnostics" not in new.config and diag_config is not None:
        new.config["diagnostics"] = diag_config
        added.add("config.diagnostics")
    elif diag_config is not None and "state" not in new.config["diagnostics"]:
        new.config["diagnostics"]["state"] = diag_config.get("state")
        added.add("config.diagnostics.state")
    ape_record = new.config.setdefault("ape", {})
    if "val_mean" not in ape_record:
        ape_record["val_mean"] = float(np.mean(ape.val))
        added.add("config.ape.val_mean")
    if "raw_mean" not in ape_record:
        ape_record["raw_mean"] = ape.raw_mean
        added.add("config.ape.raw_mean")
    if "quantiles" not in ape_record:
        ape_record["quantiles"] = np.quantile(np.asarray(ape.train), np.linspace(0, 1, 101)).tolist()
        added.add("config.ape.quantiles")
    new.reevaluated = {"fields": sorted(added), "eval_s": time.perf_counter() - t0,
                       "diagnostics_s": diag_s, "system": system}  # the diagnostics' time is in eval_s
    if results.reevaluated:  # an earlier evaluation's record is kept, not replaced
        new.reevaluated["previous"] = results.reevaluated
    return new
