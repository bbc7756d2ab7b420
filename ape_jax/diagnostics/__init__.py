"""Copycat diagnostics: does a trained policy read the previous action from its history and lean on it?

`docs/design.md`, "The copycat verdict". Two measures per trained policy, from the
FCA paper (Wen et al., "Fighting Copycat Agents in Behavioral Cloning from
Observation Histories", NeurIPS 2020), and verdicts that need both (`Thresholds`):

- **embedding probe** (its Table 3): a small MLP on the frozen policy's
  embedding predicts the expert's previous action `a_{t−1}`; its held-out MSE
  against the same probe fed `a_t` alone. A policy must encode `a_t` to act, so
  a ratio well below 1 says the embedding carries `a_{t−1}` beyond what the
  current action explains (BC-OH there: 0.38e-3 against 5.0e-3);
- **own-rollout predictability** (its Table 1): ψ's architecture
  (`ape_jax.ape`) fitted on half of the policy's own rollout episodes and
  scored on the other half, against the same for the expert's rollouts. A
  copycat repeats itself, so its actions are more predictable from its past
  actions than the expert's (BC-OH on Hopper there: 8×). Both sides are
  executed actions: the policy's clipped rollout actions against the actions
  the expert's environment ran (`Demonstrations.executed`), not its labels,
  which may be unbounded (`protocol.labels = "raw"`).

The first verdict (`verdict`) reads the embedding against `a_t`, the expert's own
autocorrelation, so it moves with the expert even for a policy without a
history. The controlled verdict (`controlled_verdict`) reads it against a
no-history control, `CONTROL` (BC-SO) trained on the same rows and probed the
same way (`control_ratio`), and never calls a policy that sees no past a
copycat. Results files keep both (`ape_jax.pipeline.judge`).

    tr, va = probe_inputs(cfg, params, train), probe_inputs(cfg, params, val)
    probe = embedding_probe(key_probe, tr.embedding, va.embedding, tr.previous_action, va.previous_action,
                            tr.action, va.action)
    pred = rollout_predictability(key_psi, traj.action, expert_traj.action,
                                  policy_valid=traj.valid, expert_valid=expert_traj.valid)
    v = verdict(probe, pred)          # v.label: "copycat" | "not copycat"; v.reasons
    c = controlled_verdict(control_ratio(probe.prev_from_embedding, bc_so_prev_from_embedding), pred.ratio,
                           sees_past=True)

The package: `records` (the results' records, constants and `Thresholds`), `probes` (the embeddings,
the probe, and both probes of every policy of a batch), `predictability` (own-rollout
predictability), `verdicts` (both verdicts) and, here, `diagnose` (every diagnostic of a batch of
policies); every name is importable from `ape_jax.diagnostics`. The probe (`fit_probe`, `probe_mse`,
`probe_target`, `embedding_probe`) is pure and jit-able (leaves are `jax.Array`s, so it vmaps over
policies); `rollout_predictability` is host code around a jitted fit, because validity masks decide
how many steps each side keeps; the verdicts are host code.
"""

from __future__ import annotations

from typing import Any
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax.diagnostics.predictability import (demonstration_rollouts, rollout_predictability,
                                                rollout_predictability_batch)
from ape_jax.diagnostics.probes import (embedding_probe, fit_probe, policy_embeddings, previous_action_rows,
                                        probe_apply, probe_inputs, probe_mse, probe_policies, probe_target)
from ape_jax.diagnostics.records import (CONTROL, COPYCAT, NOT_COPYCAT, PROBE_BATCH, PROBE_HIDDEN, PROBE_LR,
                                         PROBE_STEPS, THRESHOLDS, EmbeddingProbe, Predictability, ProbeInputs,
                                         ProbeParams, TargetProbe, Thresholds, Verdict)
from ape_jax.diagnostics.verdicts import control_ratio, controlled_verdict, verdict
from ape_jax.learner import Data, LearnerConfig

__all__ = [
    "CONTROL", "COPYCAT", "FIELDS", "LATER_FIELDS", "NOT_COPYCAT", "PROBE_BATCH", "PROBE_HIDDEN", "PROBE_LR",
    "PROBE_ROWS", "PROBE_STEPS", "THRESHOLDS", "EmbeddingProbe", "Predictability", "ProbeInputs", "ProbeParams",
    "TargetProbe", "Thresholds", "Verdict", "control_ratio", "controlled_verdict", "demonstration_rollouts",
    "diagnose", "embedding_probe", "fit_probe", "policy_embeddings", "previous_action_rows", "probe_apply",
    "probe_inputs", "probe_mse", "probe_policies", "probe_rows", "probe_target", "rollout_predictability",
    "rollout_predictability_batch", "verdict",
]

# -- every diagnostic of a batch of policies -------------------------------------------------------------------------

PROBE_ROWS = (20_000, 5_000)  # the embedding probes' training and held-out rows at most (FCA's 20k/4k split fits)
FIELDS = ("embedding_ratio", "prev_from_embedding", "prev_from_action", "velocity_ratio", "predictability_ratio",
          "policy_mse", "expert_mse", "predictability_steps", "copycat", "prev_from_state", "state_ratio")
# Added after the first results: a file's diagnostics may lack them (`experiments.evaluate` adds them).
LATER_FIELDS = ("prev_from_state", "state_ratio")


def probe_rows(data: Data, at_most: int, seed: int = 0) -> np.ndarray:
    """The split's rows with `t ≥ 1` (`previous_action_rows`), at most `at_most` of them drawn by a fixed
    permutation, in row order (`[N] int32`)."""
    rows = previous_action_rows(data)
    if len(rows) > at_most:
        rows = np.sort(np.random.default_rng(seed).permutation(rows)[:at_most])
    return rows


def diagnose(key: jax.Array, cfg: LearnerConfig, params: Any, train: Data, val: Data, rollouts: Any,
             rollouts_valid: Any, expert: tuple[Any, Any], velocity: tuple[Any, Any] | None = None,
             steps: int = PROBE_STEPS, max_rows: tuple[int, int] = PROBE_ROWS,
             thresholds: Thresholds = THRESHOLDS, state: tuple[Any, Any] | None = None,
             apply: Callable[..., Any] | None = None) -> dict[str, np.ndarray]:
    """Both diagnostics and the verdict of every policy of a batch (one network, stacked parameters).

    - the embedding probe on the demonstrations: fitted on (at most `max_rows[0]`) training rows, scored on
      (at most `max_rows[1]`) validation rows, `a_{t−1}` from each policy's embedding; the reference (from
      `a_t` alone) once, as it does not depend on the policy; every probe starts from the same key;
    - with `velocity`, the same probe on the true velocity (`qvel_t`): its `1 − R²` says whether the policy
      extracts what its history is for;
    - with `state`, the same probe of `a_{t−1}` from the true state at `t` (the expert's own observation:
      `qpos_t` without the root's x, `qvel_t`), once: the `state_ratio`, embedding ÷ state, says whether the
      embedding carries `a_{t−1}` beyond what the current state itself tells (the expert's previous action is
      a function of the previous state, which the current one nearly determines, so a policy that reads the
      state well carries `a_{t−1}` without copying it). The probe reads a trained embedding more easily than
      the raw state, so the ratio is below 1 even for a policy without a history: read it against one;
    - own-rollout predictability of each policy's evaluation rollouts against the expert's
      (`rollout_predictability_batch`);
    - the verdict (`verdict`, `thresholds`).

    Host code around jitted programs. Args:
      key: PRNG key (the probes' and ψ's).
      cfg: the policies' learner config; params: their variables, leaves `[P, ...]`.
      train, val: the splits the policies trained and validated on (`Data`, observations as they trained).
      rollouts: `[P, E, T, A]`, the policies' evaluation actions; rollouts_valid: `[P, E, T]`.
      expert: `(actions [E', T', A], valid [E', T'])`, the expert's rollouts (`demonstration_rollouts` of its
        executed actions: like with like, as the policies' rollout actions are the clipped ones the env ran).
      velocity: `(train [M, V], val [M', V])`, the true velocity of every row of `train.obs` / `val.obs`; None:
        no velocity probe.
      state: `(train [M, S], val [M', S])`, the true state of every row (e.g. `qpos` and `qvel`); None: no state
        reference (`prev_from_state`, `state_ratio` NaN).
      steps: each probe's and ψ's Adam steps.
      max_rows: the embedding probes' training and held-out rows at most.
      thresholds: the verdict's.
      apply: the policies' network as `cfg.model().apply` reads them (None: that); a method whose trained policy
        is another network gives its own (`ape_jax.evaluate.Runtime.apply`), the embedding it returns probed.

    Returns:
      `{field: [P] array}` for every field of `FIELDS` (`velocity_ratio` NaN without `velocity`, `prev_from_state`
      and `state_ratio` without `state`; `copycat` bool, the first verdict, from the two ratios of `verdict`
      alone: the controlled verdict needs the no-history control's policies, which are another batch, and is
      given when a results file is assembled, `ape_jax.pipeline.judge`), and `"probe_rows": (training rows,
      held-out rows)`.
    """
    rows_train, rows_val = probe_rows(train, max_rows[0]), probe_rows(val, max_rows[1])
    if len(rows_train) == 0 or len(rows_val) == 0:
        raise ValueError("diagnose: a split has no row with t >= 1 (no previous action to predict)")
    action_train, action_val = jnp.asarray(train.action, jnp.float32), jnp.asarray(val.action, jnp.float32)
    prev_train, prev_val = action_train[rows_train - 1], action_val[rows_val - 1]
    key_probe, key_psi = jax.random.split(key)
    reference = float(probe_target(jax.random.split(key_probe)[0], action_train[rows_train], action_val[rows_val],
                                   prev_train, prev_val, steps=steps).mse)
    from_state = np.nan
    if state is not None:  # the true state at t: what a_{t−1} is predictable from without any history
        s_train, s_val = (jnp.asarray(np.asarray(v)[r], jnp.float32) for v, r in zip(state, (rows_train, rows_val)))
        from_state = float(probe_target(jax.random.split(key_probe)[0], s_train, s_val, prev_train, prev_val,
                                        steps=steps).mse)
    vel = (None, None) if velocity is None else tuple(
        jnp.asarray(np.asarray(v)[r], jnp.float32) for v, r in zip(velocity, (rows_train, rows_val)))
    prev, vel_ratio = jax.device_get(probe_policies(
        key_probe, cfg, params, train, val, (jnp.asarray(rows_train), jnp.asarray(rows_val)),
        (prev_train, prev_val, *vel), steps=steps, apply=apply))
    rollouts, rollouts_valid = np.asarray(rollouts), np.asarray(rollouts_valid)
    pred = rollout_predictability_batch(key_psi, [(a, v) for a, v in zip(rollouts, rollouts_valid)], *expert,
                                        steps=steps)
    out = {"prev_from_embedding": np.asarray(prev, np.float64),
           "prev_from_action": np.full(len(pred), reference),
           "velocity_ratio": np.asarray(vel_ratio, np.float64),
           "predictability_ratio": np.array([p.ratio for p in pred]),
           "policy_mse": np.array([p.policy_mse for p in pred]),
           "expert_mse": np.array([p.expert_mse for p in pred]),
           "predictability_steps": np.array([p.train_rows + p.val_rows for p in pred])}
    out["prev_from_state"] = np.full(len(pred), from_state)
    with np.errstate(divide="ignore", invalid="ignore"):
        out["embedding_ratio"] = out["prev_from_embedding"] / reference
        out["state_ratio"] = out["prev_from_embedding"] / from_state
    out["copycat"] = np.array([verdict(EmbeddingProbe(e, reference, r), p, thresholds).label == COPYCAT
                               for e, r, p in zip(out["prev_from_embedding"], out["embedding_ratio"], pred)])
    out["probe_rows"] = (len(rows_train), len(rows_val))
    return out
