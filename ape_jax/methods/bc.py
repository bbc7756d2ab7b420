"""Plain behavioural cloning, the two references every table starts from.

- `bc-so` — the current observation only (history 1): a program of its own,
  because its input is narrower;
- `bc-oh` — the observation history (the preset's, 2 by default), uniform
  weights: the copycat-prone baseline the weightings improve on;
- `bc-full` — BC-SO on the full state (velocities included: the environment's
  `obs="full"` observation, built from the demonstrations' simulator state,
  `ape_jax.observations`), whatever the sweep's `--obs`: the same recipe,
  budget and rows, its own standardisation, evaluated in the `obs="full"`
  environment under the same protocol. Nothing is hidden from it, so it is the
  ceiling of the state tables: how much of what the positions lack the
  history recovers is (BC-OH − BC-SO) / (BC-full − BC-SO).
"""

from __future__ import annotations

from ape_jax import methods
from ape_jax.learner import Hparams


def _one(ctx: methods.GridContext) -> list[dict]:
    return [{}]


def _uniform(settings, lr: float, row: int) -> Hparams:
    return Hparams.make("uniform", lr=lr)


methods.register(methods.Method("bc-so", "BC-SO", grid=_one, hparams=_uniform, program="bc-so", history=1,
                                role="reference", module=__name__))
methods.register(methods.Method("bc-oh", "BC-OH", grid=_one, hparams=_uniform, role="reference", module=__name__))
methods.register(methods.Method("bc-full", "BC-full", grid=_one, hparams=_uniform, program="bc-full", history=1,
                                observation="full", role="reference", module=__name__))
