"""The one validator of the training knobs that a sweep's `Recipe` (`ape_jax.pipeline.presets`) hands to a
`LearnerConfig` (`ape_jax.learner`): each knob's rule is written once, here, and both records call `check`.

The recipe checks what a user typed (`--recipe`, `--set recipe.FIELD=VALUE`), naming the field `recipe.FIELD`;
the learner config checks what a program is built from, naming it `LearnerConfig.FIELD`, so a config made in
code (a benchmark, a notebook) is refused by the same rule and in the same words. `nonnegative`, `positive` and
`integer` are the range rules of the methods' own hyperparameters (their `Hparams.make` and `Method.knobs` records:
weights, bandwidths, learning rates, chunk sizes).
"""

from __future__ import annotations

import math
from typing import Any
from collections.abc import Callable

from ape_jax.models import DTYPES, IMAGE_ENCODERS, INITS, NORMS

LOSSES = ("l2", "l1")
NETWORKS = ("mlp", "bn-mlp")
SCHEDULES = ("piecewise", "constant", "cosine")  # the learning rate over a run (`learner.lr_schedule`)


def _one_of(valid: tuple) -> Callable[[Any], str | None]:
    return lambda v: None if v in valid else f"{v!r} is not one of {', '.join(map(str, valid))}"


def _fraction(low_open: bool, high_open: bool) -> Callable[[Any], str | None]:
    low, high = "(" if low_open else "[", ")" if high_open else "]"

    def rule(v: Any) -> str | None:
        number = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        inside = number and (v > 0 if low_open else v >= 0) and (v < 1 if high_open else v <= 1)
        return None if inside else f"must be in {low}0, 1{high}, got {v!r}"
    return rule


def _integer(least: int) -> Callable[[Any], str | None]:
    return lambda v: (None if isinstance(v, int) and not isinstance(v, bool) and v >= least
                      else f"must be an integer >= {least}, got {v!r}")


RULES: dict[str, Callable[[Any], str | None]] = {
    "network": _one_of(NETWORKS),
    "init": _one_of(tuple(INITS)),
    "encoder": _one_of(tuple(IMAGE_ENCODERS)),
    "encoder_norm": _one_of(NORMS),
    "lr_schedule": _one_of(SCHEDULES),
    "loss": _one_of(LOSSES),
    "beta1": _fraction(False, True),
    "beta2": _fraction(False, True),
    "bn_momentum": _fraction(True, False),
    "lr_decay": _fraction(True, False),
    "batch_size": _integer(1),
    "augment_shift": _integer(0),
    "dtype": _one_of(DTYPES),
}


def nonnegative(name: str, value: float) -> None:
    """Refuses (`ValueError`, one line) a method's hyperparameter `name` below 0, infinite or NaN."""
    if not 0.0 <= value < math.inf:
        raise ValueError(f"{name} must be >= 0 and finite, got {value}")


def positive(name: str, value: float) -> None:
    """Refuses (`ValueError`, one line) a method's hyperparameter `name` at or below 0, infinite or NaN."""
    if not 0.0 < value < math.inf:
        raise ValueError(f"{name} must be > 0 and finite, got {value}")


def integer(name: str, value: Any, least: int) -> None:
    """Refuses (`ValueError`, one line) a method's integer setting `name` that is not an integer >= `least`."""
    if problem := _integer(least)(value):
        raise ValueError(f"{name} {problem}")


def axis(name: str, values: tuple, rule: Callable[[str, Any], None] | None = None, empty: bool = False) -> None:
    """Refuses (`ValueError`, one line) a grid axis of a method's settings, `name`, that lists a value twice, is
    empty (unless `empty`: an empty axis means the task's), or holds a value `rule(name, value)` refuses (`nonnegative`,
    `positive`)."""
    if not values and not empty:
        raise ValueError(f"{name} must list at least one value")
    if len(set(values)) != len(values):
        raise ValueError(f"{name} lists a value twice: {', '.join(map(str, values))}")
    for v in values:
        if rule is not None:
            rule(name, v)


def check(where: str, error: type[Exception] = ValueError, **knobs: Any) -> None:
    """Refuses, with `error("{where}{knob} ...")` (one line), the first of `knobs` whose value breaks its rule
    (`RULES`), then an encoder normalisation on ResNet-18, which normalises its own layers.

    Args:
      where: the record's prefix in the message: `"recipe."` or `"LearnerConfig."`.
      error: the exception to raise (the sweep's `SettingsError`; `ValueError` for a config made in code).
      knobs: knob names of `RULES` and their values; a knob passed as None is not checked (the recipe's `loss`
        None means the task's).
    """
    for name, value in knobs.items():
        if value is not None and (problem := RULES[name](value)):
            raise error(f"{where}{name} {problem}")
    if knobs.get("encoder") == "resnet18" and knobs.get("encoder_norm", "none") != "none":
        raise error(f"{where}encoder_norm {knobs['encoder_norm']!r} is for the encoders 'small', 'patch' and 'drq' "
                    f"(resnet18 normalises its own layers)")
