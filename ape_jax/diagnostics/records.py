"""The copycat diagnostics' records, constants and thresholds (`Thresholds`, `Verdict`)."""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax


PROBE_STEPS = 2000
# The embedding probes' hidden units: ψ's shape (one hidden layer, LeakyReLU) at a third of its width, so the two
# probes per policy cost about as much as one ψ fit (the diagnostics must not double the evaluation's time)
PROBE_HIDDEN = 100
PROBE_LR = 1e-3
PROBE_BATCH = 256
COPYCAT, NOT_COPYCAT = "copycat", "not copycat"
# The no-history control of the controlled verdict: BC on the current observation alone (history 1), trained on the
# same rows as the policies it controls and probed the same way
CONTROL = "bc-so"

# -- results ---------------------------------------------------------------------------------------------------------

class ProbeParams(NamedTuple):
    """A fitted probe: the training inputs' standardisation and the MLP's variables.

    Attributes:
      x_mean: `[D] float32`, the training inputs' mean.
      x_std: `[D] float32`, their standard deviation (1 where a column is constant).
      net: the `ape_jax.ape.ActionPredictor` variables (one hidden layer, LeakyReLU(0.2)).
    """

    x_mean: jax.Array
    x_std: jax.Array
    net: Any


class TargetProbe(NamedTuple):
    """How well a probe predicts a target on held-out rows (every field `[] float32`).

    Attributes:
      mse: the probe's held-out MSE (squared error summed over target dims, mean over rows).
      baseline: the held-out MSE of predicting the training targets' mean (the target's spread).
      ratio: `mse / baseline`, i.e. 1 − R²: near 0 the input determines the target, near 1 (or above:
        overfitting) it says nothing about it.
    """

    mse: jax.Array
    baseline: jax.Array
    ratio: jax.Array


class EmbeddingProbe(NamedTuple):
    """The embedding probe (the FCA paper's Table 3); every field `[] float32`.

    Attributes:
      prev_from_embedding: held-out MSE of the probe predicting `a_{t−1}` from the policy's embedding.
      prev_from_action: held-out MSE of the same probe predicting `a_{t−1}` from `a_t` alone.
      ratio: `prev_from_embedding / prev_from_action`: below 1, the embedding holds more about the previous
        action than the current action does.
    """

    prev_from_embedding: jax.Array
    prev_from_action: jax.Array
    ratio: jax.Array


class Predictability(NamedTuple):
    """Own-rollout predictability (the FCA paper's Table 1); host values.

    Attributes:
      policy_mse: ψ's held-out MSE on the policy's rollout actions (float).
      expert_mse: the same on the expert's rollout actions (float).
      ratio: `policy_mse / expert_mse` (float): below 1, the policy's actions are more predictable from its
        own past actions than the expert's are from theirs.
      train_rows: steps ψ was fitted on, on each side (int).
      val_rows: held-out steps on each side (int); the episodes' first steps (`t = 0`) among them are not
        scored.
    """

    policy_mse: float
    expert_mse: float
    ratio: float
    train_rows: int
    val_rows: int


class ProbeInputs(NamedTuple):
    """One split's rows for the embedding probe: those with a previous step in their episode (`t ≥ 1`).

    Attributes:
      embedding: `[N, E] float32`, the policy's embedding of each row's observation history.
      previous_action: `[N, A] float32`, the expert's `a_{t−1}`.
      action: `[N, A] float32`, the expert's `a_t`.
    """

    embedding: jax.Array
    previous_action: jax.Array
    action: jax.Array

@dataclasses.dataclass(frozen=True)
class Thresholds:
    """When a policy is called a copycat. Two verdicts, each needing BOTH its criteria; every threshold fixed
    before the results it judges.

    **The controlled verdict** (`controlled_verdict`; the report's). A policy that sees a past (a history of more
    than one observation, or the previous action in its observation) is a copycat when

    - `control_ratio = 0.25`: its embedding's probe error on `a_{t−1}` at most a quarter of the no-history
      control's (`CONTROL`, BC-SO on the same rows, the same probe; `control_ratio`), i.e. the history removes
      at least three quarters of what an embedding of the current observation leaves unknown about the
      previous action; and
    - `predictability_ratio = 0.5`: ψ's held-out error on its own rollouts at most half of ψ's error on the
      expert's executed actions (like with like: both sides clipped to the action range).

    A policy that sees no past (history 1 without the previous action: BC-SO itself, `bc-full`) is never a
    copycat: it has nothing to copy from. The reference is BC-SO, not `a_t`, because `a_t → a_{t−1}` measures
    the expert's own autocorrelation: BC-SO's embedding ratio moves from about 2.4 (a smooth SAC expert) to
    about 0.7 (FCA's Gaussian expert) with the expert alone, and to 0.35 at frame skip 4, where the expert's
    actions change more per step; a verdict that moves for a policy without a history does not measure
    copying. Against BC-SO the expert's autocorrelation cancels: both embeddings are probed for the same
    `a_{t−1}` on the same rows.

    Why 0.25 and not 0.5. A history does carry `a_{t−1}` without copying it: the frame difference gives the
    velocity, hence the previous state, and under deterministic dynamics the previous state and the previous
    action carry the same information. The committed files' history policies sit at 0.35–1.17 of BC-SO
    (median about 0.6), the lowest (0.35–0.37) HalfCheetah's BC-OH and ours at 92–98% of the expert; those
    ratios were known when this threshold was set, so they are not evidence for it, only the reason it is not
    0.5. A copycat holds `a_{t−1}` itself: the FCA paper's BC-OH held it to 0.38e-3 against 5.0e-3 from `a_t`
    (0.08), and a no-history embedding holds what the current observation tells (the committed BC-SO: 0.35 to
    15 times `a_t`'s error), so a copycat of the paper's strength sits at 0.08 of BC-SO where BC-SO is at
    `a_t`'s level and at 0.23 in the worst case measured (BC-SO at 0.35 of `a_t`'s error, frame skip 4); the
    planted copycats of the tests sit below 0.05. BC-SO's own seeds spread over 0.85–1.13 of their median, so
    noise does not come near a factor of four.

    **The first verdict** (`verdict`; kept beside the controlled one, so files show both):
    `embedding_ratio = 0.5` and `predictability_ratio = 0.5`.

    - `embedding_ratio = 0.5`: the embedding probe's error on `a_{t−1}` at most half the error of the same
      probe fed `a_t` alone. The FCA paper's Table 3 has BC-OH's embedding at 0.38e-3 against 5.0e-3 from
      `a_t`, a ratio of about 0.08; an embedding that holds no more about `a_{t−1}` than the action it must
      produce sits near 1. 0.5 is six times the paper's copycat (a real one is caught with room to spare)
      and a factor of two from 1 (probe noise, a few tens of percent, does not cross it).
    - `predictability_ratio = 0.5`: ψ's held-out error on the policy's own rollouts at most half of its
      error on the expert's, i.e. the policy's actions at least 2× more predictable. The paper's Table 1
      has BC-OH's actions 8× more predictable than the expert's on Hopper (ratio 0.125); a policy that
      acts like the expert sits near 1. Again 4× short of the paper's copycat, 2× from 1.

    Why both, in either verdict: each alone has an innocent explanation. A policy that reads the full state
    can carry `a_{t−1}` in its embedding through the dynamics (the state at t reveals the step before it)
    without leaning on it; a sluggish, underfitted policy can be smoother, so more predictable, than the
    expert without reading its past actions. A copycat does both: it encodes the previous action and its
    rollouts repeat it.
    """

    embedding_ratio: float = 0.5
    predictability_ratio: float = 0.5
    control_ratio: float = 0.25

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not 0.0 < value < 1.0:
                raise ValueError(f"Thresholds.{f.name} must be in (0, 1) (a ratio below 'no different from "
                                 f"the reference'), got {value}")


THRESHOLDS = Thresholds()


class Verdict(NamedTuple):
    """The copycat verdict and why.

    Attributes:
      label: `"copycat"` when both criteria held, else `"not copycat"`.
      embedding_held: the embedding criterion held: the embedding probe's ratio (the first verdict's
        `embedding_ratio`, the controlled verdict's `control_ratio`) was at or below its threshold (False when
        undefined, or for a policy that sees no past).
      predictability_held: the rollout predictability ratio was at or below its threshold (False when
        undefined).
      reasons: one line per criterion: the measured ratio, the threshold, whether it held.
    """

    label: str
    embedding_held: bool
    predictability_held: bool
    reasons: tuple[str, ...]
