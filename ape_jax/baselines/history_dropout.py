"""HistoryDropout (Bansal et al., 2018): each past observation of a training history is dropped.

The learner does the work (`ape_jax.learner`, `Hparams.history_dropout`): with
probability p each *past* frame of a training history (never the current one)
is replaced by zeros, independently per sample and frame; evaluation sees the
full history. It is a traced knob, so the method trains in the grid program
beside BC-OH. p = 0.5, our reading of the paper's unstated setting.
"""

from __future__ import annotations

from ape_jax import methods
from ape_jax.learner import Hparams

P = 0.5

methods.register(methods.Method(
    "history-dropout", "HistoryDropout", grid=lambda ctx: [{"p": P}],
    hparams=lambda settings, lr, row: Hparams.make("uniform", lr=lr, history_dropout=settings["p"]),
    module=__name__))
