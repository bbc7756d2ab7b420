"""Boosting: reweight the training set towards the samples the previous policy fits worst, retrain.

The paper lists boosting as a baseline without details; this is the project's
reading, AdaBoost.R2 (Drucker, 1997), the standard boosting reweighting for
regression, with the weighted BC learner as the weak learner:

1. round 0 trains BC-OH (all weights 1);
2. after each round, every training sample's unweighted loss `ℓ_i` under the
   round's policy is normalised by the largest, `L_i = ℓ_i / max_j ℓ_j ∈ [0, 1]`;
   with the weighted average loss `L̄ = Σ w_i L_i / Σ w_i` and
   `β = L̄ / (1 − L̄)` the weights become `w_i ← w_i · β^(1 − L_i)`, i.e.
   exponential in the normalised loss (`∝ w_i · exp(−ln β · L_i)`), then are
   rescaled to average 1;
3. the next round retrains from a fresh initialisation (new key, optimizer and
   learning-rate schedule restarted) on the reweighted samples.

After `rounds` rounds (default 3) the **final round's policy** is reported (not
the AdaBoost ensemble, whose history-dependent members would all have to run
at evaluation). All rounds run inside one compiled program (`train`), or round
by round with `next_round` between (`ape_jax.pipeline.training`, for progress bars).
"""

from __future__ import annotations


import jax
import jax.numpy as jnp
from flax import struct

from ape_jax.learner import (Data, Hparams, Learner, LearnerConfig, TrainState, dataset_losses, make_train,
                             train_in_rounds)
from ape_jax import methods

ROUNDS = 3


def reweight(weights: jax.Array, losses: jax.Array) -> jax.Array:
    """One AdaBoost.R2 update (module docstring).

    Args:
      weights: the current sample weights, `[N]`, positive.
      losses: each sample's loss under the round's policy, `[N]`, >= 0.

    Returns:
      `[N] float32` new weights averaging 1; larger losses get larger weights.
    """
    weights, losses = jnp.asarray(weights, jnp.float32), jnp.asarray(losses, jnp.float32)
    norm = losses / jnp.maximum(losses.max(), 1e-30)
    avg = jnp.sum(weights * norm) / jnp.sum(weights)
    beta = jnp.clip(avg / (1.0 - avg), 1e-6, 1.0)  # AdaBoost.R2 stops at L̄ ≥ 0.5; here: no change then
    new = weights * beta ** (1.0 - norm)
    return new / new.mean()


@struct.dataclass
class BoostState:
    train: TrainState
    round: jax.Array  # [] int32


def make_boosting(cfg: LearnerConfig, rounds: int = ROUNDS) -> Learner:
    """Boosting as a round-based `Learner` over `make_train(cfg)`; `hp` is an `Hparams` (uniform weighting).

    Each round trains `cfg.iterations` iterations, so the whole costs `rounds`
    BC-OH runs.
    """
    if rounds < 1:
        raise ValueError(f"boosting needs rounds >= 1, got {rounds}")
    base = make_train(cfg)

    def init(key: jax.Array, hp: Hparams, data: Data) -> BoostState:
        return BoostState(train=base.init(key, hp, data), round=jnp.zeros((), jnp.int32))

    def run(state: BoostState, hp: Hparams, data: Data, n: int):
        train, metrics = base.run(state.train, hp, data, n)
        return state.replace(train=train), metrics

    def next_round(state: BoostState, hp: Hparams, data: Data) -> BoostState:
        losses = dataset_losses(base, state.train.params, data)
        weights = reweight(state.train.static_weights, losses)
        fresh = base.init(jax.random.fold_in(state.train.key, state.round + 1), hp, data)
        return BoostState(train=fresh.replace(static_weights=weights), round=state.round + 1)

    learner = Learner(init=init, run=run, train=None, policy_input=base.policy_input,
                      per_sample_loss=base.per_sample_loss, policy_params=lambda s: s.train.params,
                      rounds=rounds, round_iterations=cfg.iterations, next_round=next_round)
    return learner._replace(train=lambda key, hp, data: train_in_rounds(learner, key, hp, data))


def _learner(ctx) -> Learner:
    return make_boosting(ctx.cfg)


methods.register(methods.Method(
    "boosting", "Boosting", grid=lambda ctx: [{"rounds": ROUNDS}],
    hparams=lambda settings, lr, row: Hparams.make("uniform", lr=lr), program="boosting", learner=_learner,
    module=__name__))
