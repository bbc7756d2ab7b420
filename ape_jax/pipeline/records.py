"""The records of a run, as the sweep's assemble phase (and `experiments.evaluate`) writes them into results.json:
a run's `eval` block, its `diagnostics`, its whole record and its snapshots at `budget.eval_at`, and what the
diagnostics mean (`config.diagnostics`). Each builder takes what it reads (the evaluation outputs, the task, the
expert's card, the demonstrations), never the sweep's state; reading and validating files is `results`'."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from ape_jax import diagnostics as diagnostics_lib
from ape_jax import methods as methods_lib
from ape_jax.tasks import Task

COPYCAT_METRICS = ("imitation_error", "rollout_ape")  # the copycat diagnostics (`ape_jax.evaluate`)
DIAG = "diag_"  # the prefix of the diagnostics' arrays among a group's evaluation outputs
CURVE_POINTS = 100  # points of each run's training curve in results.json (the full curves: OUT/curves/)


def diagnostics_record(out: dict, j: int) -> dict | None:
    """Run `j`'s `diagnostics` in results.json from its group's outputs, None where the group has none (outputs
    saved before them, or a sweep that is not `sweep.diagnosable`)."""
    if f"{DIAG}absent" in out:
        return {"absent": "the policy's network gives no embedding (it takes no return_embedding)"}
    if f"{DIAG}copycat" not in out:
        return None
    value = {k: float(out[DIAG + k][j]) for k in diagnostics_lib.FIELDS if k != "copycat" and DIAG + k in out}
    value = {k: v if np.isfinite(v) else None for k, v in value.items()}  # e.g. no velocity: null, never 0
    value["predictability_steps"] = int(value["predictability_steps"])
    value["verdict"] = diagnostics_lib.COPYCAT if bool(out[f"{DIAG}copycat"][j]) else diagnostics_lib.NOT_COPYCAT
    return value


def eval_record(out: dict, j: int, task: Task, card: dict | None) -> dict:
    """Row `j`'s `eval` block in results.json from its group's evaluation outputs `out`: returns, % of expert by
    the expert `card`'s references (none without a card), the task's metrics and the copycat metrics."""
    returns = np.asarray(out["return"][j], np.float64)
    ev = {"episodes": int(len(returns)), "return_mean": float(returns.mean()), "return_std": float(returns.std())}
    if card is not None:
        from ape_jax import evaluate as evaluate_lib  # here: it imports the environments, which reading does not need

        ev["normalized"] = float(evaluate_lib.normalized(returns.mean(), card["return_mean"],
                                                         card["random_return_mean"]))
    for k in (*task.metrics, *COPYCAT_METRICS):
        if k in out:
            ev[k] = float(np.mean(out[k][j]))
    if task.metric != "return":
        ev.setdefault("normalized", 100.0 * ev[task.metric])  # a rate, in % (no return to normalise)
    return ev


def run_record(run: Any, j: int, out: dict, losses: dict, curves: dict, task: Task, card: dict | None) -> dict:
    """Run `run`'s record in results.json (`run`: its `method`, `hparams` and `seed`, a `spec.Run`); `j` is its row
    in the evaluation outputs `out` and `losses`; `curves` its per-iteration training metrics (`"loss"` and the
    learner's others, e.g. FCA's `adversary_loss`)."""
    returns = np.asarray(out["return"][j], np.float64)
    record = {"method": run.method, "hparams": run.hparams, "seed": run.seed, "status": "ok", "error": None,
              "online": methods_lib.get(run.method).online}
    loss_curve = np.asarray(curves["loss"])
    bad = np.flatnonzero(~np.isfinite(loss_curve))
    if len(bad):
        record.update(status="failed", error=f"training loss became non-finite at iteration {int(bad[0])}")
    elif not np.all(np.isfinite(returns)):
        record.update(status="failed", error="evaluation returns are non-finite")
    record["eval"] = eval_record(out, j, task, card)
    if (diag := diagnostics_record(out, j)) is not None:
        record["diagnostics"] = diag
    record["losses"] = {split: {k: float(v[j]) for k, v in losses[split].items()} for split in losses}
    record["train_loss_final"] = float(np.mean(loss_curve[-100:]))
    # every training metric over the last 1% of the run (at least 100 minibatches): e.g. FCA's adversary against
    # its reference predictor of a_{t-1} from a_t alone
    tail = max(100, len(loss_curve) // 100)
    record["train_final"] = {k: float(np.mean(np.asarray(v)[-tail:])) for k, v in curves.items()}
    record["train_curve"] = window_means(loss_curve, CURVE_POINTS)
    return record


def snapshot_record(iteration: int, j: int, out: dict, losses: dict, curves: dict, task: Task,
                    card: dict | None) -> dict:
    """One entry of a run's `at` list in results.json: its policy at `iteration` (`Budget.eval_at`) evaluated as
    at the end (`eval`, `diagnostics`, `losses`), and its training loss over the 100 minibatches before."""
    loss = np.asarray(curves["loss"])[max(0, iteration - 100):iteration]
    record = {"iteration": iteration, "eval": eval_record(out, j, task, card),
              "losses": {split: {k: float(v[j]) for k, v in losses[split].items()} for split in losses},
              "train_loss": float(np.mean(loss)) if len(loss) else None}
    if (diag := diagnostics_record(out, j)) is not None:
        record["diagnostics"] = diag
    return record


def window_means(values: np.ndarray, points: int) -> list[float]:
    """`values` cut into `points` consecutive windows of equal length (the last takes the rest), each window's mean."""
    values = np.asarray(values, np.float64)
    width = max(1, len(values) // points)
    ends = [*range(width, len(values), width)][: points - 1] + [len(values)]
    return [float(values[a:b].mean()) for a, b in zip([0, *ends[:-1]], ends)]


def diagnostics_config(demos: Any, outputs: Sequence[dict]) -> dict | None:
    """What the runs' `diagnostics` mean (results.json's `config.diagnostics`) for a sweep on the training
    demonstrations `demos` (`Demonstrations`), None where no group's evaluation `outputs` have them."""
    out = next((o for o in outputs if f"{DIAG}probe_rows_train" in o), None)
    if out is None:
        return None
    return {"thresholds": dataclasses.asdict(diagnostics_lib.THRESHOLDS),
            "probe_steps": int(out[f"{DIAG}probe_steps"][0]),
            "probe_rows": {"train": int(out[f"{DIAG}probe_rows_train"][0]),
                           "val": int(out[f"{DIAG}probe_rows_val"][0])},
            "expert_rollouts": f"the demonstrations' {demos.num_episodes} training episodes, their executed actions, "
                               "cut to each policy's step count",
            "velocity": "qvel" if "qvel" in demos.sim else None,
            "state": "qpos[1:], qvel (the expert's observation)" if {"qpos", "qvel"} <= set(demos.sim) else None}
