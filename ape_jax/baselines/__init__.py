"""Baselines of the paper, one module each (method names as in `--methods` and results).

Weighting baselines (scores or weights for the weighted learner; they join the grid program):

- `bcpd` — Bayesian online changepoint detection on the expert's actions: a
  per-sample changepoint probability, ranked by the step function like APE;
- `actfreq` — inverse action-frequency weights over a grid of action bins;
- `kmeans` — inverse cluster-size weights over k-means clusters of the actions;
- `boosting` — AdaBoost.R2 reweighting by the previous round's loss, retrained in rounds.

Training baselines (learners of their own, vmapped over seeds):

- `history-dropout` — lives in `ape_jax.learner` as a traced knob (`Hparams.history_dropout`);
- `fca` — Fighting Copycat Agents: an adversary on the embedding predicts the previous action;
- `dagger` — online: rolls out the policy, labels visited states with the expert, aggregates.

Each module's docstring states how it reads the details the paper leaves open.
"""
