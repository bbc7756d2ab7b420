"""The score table the weighted learner reads: per-sample scores of the training rows, one row per source.

    rows = score_rows(spec.methods)                    # ("ape", then each method with scores of its own)
    table = score_table(ape_train, method_scores(spec.methods, train))   # [len(rows), N] float32

Row 0 is the APE (`ape_jax.ape`); every registered method with a `score`
function (`ape_jax.methods`: the weighting baselines, a weighting plugin) adds
its own row, in registry order. A method's traced `ape_jax.weighting.Weighting`
names its row (`Weighting.source`, set by `Method.hparams` from `score_rows`), so
a new row never changes how the other rows train.
"""

from __future__ import annotations

from typing import Any
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import methods as methods_lib


def score_rows(names: Sequence[str]) -> tuple[str, ...]:
    """Rows of the score table the weighted learner reads: `"ape"`, then each method with scores of its own."""
    return ("ape", *(m for m in methods_lib.names() if m in names and methods_lib.get(m).score is not None))


def method_scores(names: Sequence[str], train: Any) -> jax.Array:
    """`[len(score_rows(names)) - 1, N] float32`: each weighting method's scores of the training rows (the rows
    after the APE). A method scores the whole episodes (its `t` and actions in order), read at the part's rows.

    `train` is the training part of a split, the pipeline's `data.Part`: whole episodes `train.demos` (`action`
    `[M, A]`, `t` `[M]`), `train.own(x)` a per-row array of them at the part's `N` rows, `len(train) == N`.

    Raises `methods.PluginError` for scores that are not `[M]` finite float32.
    """
    action, t = jnp.asarray(train.demos.action), jnp.asarray(train.demos.t)
    rows = [train.own(methods_lib.get(m).score(methods_lib.score_key(m), action, t)) for m in score_rows(names)[1:]]
    return jnp.asarray(np.stack(rows)) if rows else jnp.zeros((0, len(train)), jnp.float32)


def score_table(ape: jax.Array, scores: jax.Array) -> jax.Array:
    """The table the weighted learner reads: the APE (row 0) above the methods' scores (`method_scores`)."""
    return jnp.concatenate([jnp.asarray(ape, jnp.float32)[None], scores])

