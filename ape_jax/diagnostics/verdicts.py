"""The copycat verdicts: the first (embedding against `a_t`) and the controlled (against the no-history control),
each needing both its criteria. Host code."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from ape_jax.diagnostics.records import (CONTROL, COPYCAT, NOT_COPYCAT, THRESHOLDS, EmbeddingProbe, Predictability,
                                        Thresholds, Verdict)


# -- the verdict -----------------------------------------------------------------------------------------------------

def verdict(probe: EmbeddingProbe, predictability: Predictability,
            thresholds: Thresholds = THRESHOLDS) -> Verdict:
    """The first verdict: `"copycat"` when both its criteria (`embedding_ratio`, `predictability_ratio` of
    `thresholds`) hold, else `"not copycat"`, with the reasons. Kept beside `controlled_verdict`.

    An undefined ratio (NaN or infinite: a reference error of zero) never holds.

    Args:
      probe: the policy's `EmbeddingProbe`.
      predictability: its `Predictability`.
      thresholds: the criteria (default `THRESHOLDS`, fixed before any result).

    Returns:
      A `Verdict`.
    """
    e_held, e_reason = _criterion("embedding probe, MSE(a_t-1 | embedding) / MSE(a_t-1 | a_t)",
                                  float(probe.ratio), thresholds.embedding_ratio)
    p_held, p_reason = _criterion(_PREDICTABILITY, float(predictability.ratio), thresholds.predictability_ratio)
    return Verdict(label=COPYCAT if e_held and p_held else NOT_COPYCAT, embedding_held=e_held,
                   predictability_held=p_held, reasons=(e_reason, p_reason))


_PREDICTABILITY = "own-rollout predictability, psi's MSE on the policy / on the expert's executed actions"


def _criterion(what: str, ratio: float, threshold: float) -> tuple[bool, str]:
    held = math.isfinite(ratio) and ratio <= threshold
    sign = "<=" if held else (">" if math.isfinite(ratio) else "undefined, not <=")
    return held, f"{what}: ratio {ratio:.3g} {sign} {threshold} ({'held' if held else 'did not hold'})"


def control_ratio(prev_from_embedding: Any, control_prev_from_embedding: Any) -> np.ndarray:
    """How much more about `a_{t−1}` a policy's embedding holds than the no-history control's (`CONTROL`).

    Args:
      prev_from_embedding: `[P]` (or scalar) float, each policy's `EmbeddingProbe.prev_from_embedding`.
      control_prev_from_embedding: `[C]` float, the control's seeds' `prev_from_embedding` on the same rows with
        the same probe (non-finite ones left out).

    Returns:
      `[P] float64` (a scalar's shape kept): each policy's error ÷ the median of the control's seeds'; NaN where
      the control has no finite value. The median, not the same seed's: a run's key folds in its method
      (`ape_jax.methods.run_key`), so a BC-SO and a BC-OH of one seed share no initialisation or minibatch, and
      pairing them would only add one control seed's noise to every ratio.
    """
    control = np.asarray(control_prev_from_embedding, np.float64).reshape(-1)
    control = control[np.isfinite(control)]
    reference = float(np.median(control)) if control.size else math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(prev_from_embedding, np.float64) / reference


def controlled_verdict(control: float, predictability: float, sees_past: bool,
                       thresholds: Thresholds = THRESHOLDS) -> Verdict:
    """The controlled verdict (`Thresholds`): `"copycat"` when a policy that sees a past has both its
    `control_ratio` and its `predictability_ratio` at or below their thresholds; a policy that sees no past
    (history 1, no previous action in its observation) is never a copycat.

    An undefined ratio (NaN or infinite) never holds.

    Args:
      control: the policy's `control_ratio` (float).
      predictability: its `Predictability.ratio` (float; the expert's side its executed actions).
      sees_past: whether the policy sees a past (a history longer than 1, or the previous action).
      thresholds: the criteria (default `THRESHOLDS`).

    Returns:
      A `Verdict` (`embedding_held`: the control criterion).
    """
    if not sees_past:
        return Verdict(NOT_COPYCAT, False, False, ("no past in view (history 1, no previous action): nothing to "
                                                   "copy from, never a copycat",))
    c_held, c_reason = _criterion("embedding against the no-history control, MSE(a_t-1 | embedding) / "
                                  f"MSE(a_t-1 | {CONTROL}'s embedding)", float(control), thresholds.control_ratio)
    p_held, p_reason = _criterion(_PREDICTABILITY, float(predictability), thresholds.predictability_ratio)
    return Verdict(label=COPYCAT if c_held and p_held else NOT_COPYCAT, embedding_held=c_held,
                   predictability_held=p_held, reasons=(c_reason, p_reason))
