"""Boosting (AdaBoost.R2 reweighting of the weighted BC learner): the update, and rounds in one program."""

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax.baselines import boosting
from ape_jax.learner import Data, Hparams, LearnerConfig, dataset_losses


def test_reweight_is_adaboost_r2_and_upweights_the_largest_losses():
    losses = jnp.array([0.0, 1.0, 2.0, 4.0])
    w = np.asarray(boosting.reweight(jnp.ones(4), losses))
    # L = [0, .25, .5, 1], L̄ = 0.4375, β = 0.4375 / 0.5625; w ∝ β^(1 − L)
    beta = 0.4375 / 0.5625
    expected = beta ** (1 - np.array([0.0, 0.25, 0.5, 1.0]))
    np.testing.assert_allclose(w, expected / expected.mean(), rtol=1e-6)
    assert np.argmax(w) == 3 and (np.diff(w) > 0).all()
    np.testing.assert_allclose(w.mean(), 1.0, rtol=1e-6)
    # the previous round's weights carry over multiplicatively
    w2 = np.asarray(boosting.reweight(jnp.array([2.0, 1.0, 1.0, 0.0]), losses))
    assert w2[3] == 0.0 and w2[0] > 0


def test_equal_losses_leave_the_weights_unchanged():
    np.testing.assert_allclose(boosting.reweight(jnp.ones(5), jnp.full(5, 0.3)), np.ones(5), rtol=1e-6)


def _data():
    # one hard region (rows with |obs| > 1.5 have a label that flips sign): the policy fits it worst
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(512, 2)).astype(np.float32)
    action = np.where(np.abs(obs[:, :1]) > 1.5, -3 * obs[:, :1], obs[:, :1]).astype(np.float32)
    t = np.tile(np.arange(64, dtype=np.int32), 8)
    return Data(obs=jnp.asarray(obs), action=jnp.asarray(action), t=jnp.asarray(t), ape=jnp.ones(512))


def test_rounds_in_one_program_upweight_the_samples_with_the_largest_loss():
    data = _data()
    cfg = LearnerConfig(obs_shape=(2,), action_dim=1, history=1, iterations=60, batch_size=64)
    learner = boosting.make_boosting(cfg, rounds=2)
    hp = Hparams.make(lr=1e-3)
    state = learner.init(jax.random.PRNGKey(0), hp, data)
    state, _ = learner.run(state, hp, data, cfg.iterations)
    losses = dataset_losses(learner, learner.policy_params(state), data)
    nxt = learner.next_round(state, hp, data)
    w = np.asarray(nxt.train.static_weights)
    assert int(nxt.round) == 1 and int(nxt.train.step) == 0
    np.testing.assert_allclose(w.mean(), 1.0, rtol=1e-5)
    worst = np.argsort(np.asarray(losses))[-20:]
    assert w[worst].min() > np.median(w)   # the worst-fit samples are upweighted
    # the whole thing as one compiled program: rounds x iterations of metrics, weighted loss differs in round 2
    params, metrics = jax.jit(learner.train)(jax.random.PRNGKey(0), hp, data)
    assert metrics["loss"].shape == (2 * cfg.iterations,)
    np.testing.assert_allclose(metrics["loss"][:60], metrics["unweighted_loss"][:60], rtol=1e-6)
    assert not np.allclose(metrics["loss"][60:], metrics["unweighted_loss"][60:])
    assert jax.tree.structure(params) == jax.tree.structure(learner.policy_params(state))
