"""Evaluation: the policy's own history equals training's; vmapped over policies; loss analysis."""

import functools

import jax
import jax.numpy as jnp
import numpy as np

import envs
from ape_jax import evaluate
from ape_jax.history import history_index
from ape_jax.learner import Data, Hparams, LearnerConfig, make_train, stack_hparams

CFG = LearnerConfig(obs_shape=(5,), action_dim=2, history=3, iterations=5, batch_size=8, loss="l1")


def assert_close_in_ulps(actual, desired, ulps=512):
    """`|actual - desired| <= ulps · eps32 · max|desired|`: the same network applied in two programs.

    XLA:CPU blocks a matrix product by its shapes and the CPU, so a policy applied
    to one observation (inside the rollout) and to a batch of them sums in
    another order; they agree to rounding, tens of ulps of the values (18 on an
    Intel Xeon), and the bound is a few hundred.
    """
    actual, desired = np.asarray(actual, np.float64), np.asarray(desired, np.float64)
    assert actual.shape == desired.shape, (actual.shape, desired.shape)
    bound = ulps * np.finfo(np.float32).eps * np.abs(desired).max()
    assert np.abs(actual - desired).max() <= bound, (np.abs(actual - desired).max(), bound)


@functools.cache
def _policies():
    """Three briefly trained policies, stacked: trained once per test process, in one vmapped program."""
    learner = make_train(CFG)
    data = Data(obs=jnp.ones((16, 5)), action=jnp.zeros((16, 2)), t=jnp.arange(16), ape=jnp.ones(16))
    hps = stack_hparams([Hparams.make()] * 3)
    return jax.jit(jax.vmap(learner.train, (0, 0, None)))(jax.random.split(jax.random.PRNGKey(0), 3), hps, data)[0]


def _params(n):
    """The first `n` (<= 3) of `_policies()`, stacked."""
    return jax.tree.map(lambda x: x[:n], _policies())


def test_the_policy_acts_on_the_same_history_as_in_training():
    env = envs.make("toycar", obs="full", episode_length=40)
    mean, std = jnp.full(5, 2.0), jnp.full(5, 3.0)
    params = jax.tree.map(lambda x: x[0], _params(1))
    policy = evaluate.history_policy(CFG, mean, std, env)
    traj = jax.jit(lambda k: envs.rollout(env, policy, params, k, 2, 40))(jax.random.PRNGKey(1))
    learner = make_train(CFG)
    obs = (traj.obs[0] - mean) / std                       # one episode, [T, 5]
    t = jnp.arange(40)
    inputs = learner.policy_input(obs[history_index(t, t, CFG.history)])
    low, high = env.action_bounds
    expected = jnp.clip(CFG.model().apply(params, inputs), low, high)
    steps = int(traj.lengths[0])
    assert steps > 10 and float(jnp.abs(expected[:steps]).max()) > 0.1  # a real comparison
    assert_close_in_ulps(traj.action[0, :steps], expected[:steps])


def test_evaluator_is_vmapped_over_policies_and_episodes_with_toycar_metrics():
    env = envs.make("toycar", obs="full", episode_length=30)
    run = evaluate.make_evaluator(env, CFG, jnp.zeros(5), jnp.ones(5), episodes=4)
    out = run(_params(3), jax.random.PRNGKey(0))
    for k in ("return", "length", "success", "red_light_violations", "progress", "avg_speed", "stuck"):
        assert out[k].shape == (3, 4), k
    # the same episodes for every policy: identical policies give identical results (up to rounding: the
    # rows of one vmapped program may be computed by different GEMM kernel paths), and different ones do not
    same = run(jax.tree.map(lambda x: jnp.stack([x[0]] * 3), _params(3)), jax.random.PRNGKey(0))
    for k in ("progress", "avg_speed", "length"):
        for p in (1, 2):
            np.testing.assert_allclose(same[k][p], same[k][0], rtol=1e-5, atol=1e-9, err_msg=k)
    assert np.ptp(np.asarray(same["progress"][0])) > 0  # the 4 episodes differ from each other
    assert not np.allclose(out["progress"][2], out["progress"][0], rtol=1e-3)  # and so do the policies


def test_normalized_score():
    assert evaluate.normalized(60.0, expert=110.0, random=10.0) == 50.0
    np.testing.assert_allclose(evaluate.normalized(jnp.array([10.0, 110.0]), 110.0, 10.0), [0.0, 100.0])


def test_loss_analysis_splits_changepoint_and_copycat_samples():
    cfg = LearnerConfig(obs_shape=(1,), action_dim=1, history=1, batch_size=2)
    params = {"params": jax.tree.map(jnp.zeros_like,
                                     cfg.model().init(jax.random.PRNGKey(0), jnp.zeros((1, 1))))["params"]}
    # the zero network predicts 0: the loss of a sample is its squared action
    data = Data(obs=jnp.zeros((10, 1)), action=jnp.arange(10.0)[:, None], t=jnp.arange(10),
                ape=jnp.array([0, 0, 0, 0, 0, 0, 0, 0, 0, 9.0]))
    out = evaluate.loss_analysis(cfg, jax.tree.map(lambda x: x[None], params), data)
    sq = np.arange(10.0) ** 2
    np.testing.assert_allclose(out["unweighted"], [sq.mean()], rtol=1e-6)
    np.testing.assert_allclose(out["changepoint"], [81.0], rtol=1e-6)   # top 10%: the sample with APE 9
    np.testing.assert_allclose(out["copycat"], [sq[:9].mean()], rtol=1e-6)


def test_copycat_diagnostics_equal_a_step_by_step_reference():
    """imitation_error: the policy's action vs the expert's on the policy's own states; rollout_ape: ψ on its
    actions."""
    from ape_jax import ape as ape_lib

    env = envs.make("toycar", obs="full", episode_length=30)
    params = _params(2)
    psi = ape_lib.ActionPredictor(2).init(jax.random.PRNGKey(3), jnp.zeros((1, ape_lib.K * 2)))
    run = evaluate.make_evaluator(env, CFG, jnp.zeros(5), jnp.ones(5), episodes=3, expert=env.expert,
                                  ape_params=psi, ape_scale=2.0)
    out = run(params, jax.random.PRNGKey(0))
    assert out["imitation_error"].shape == out["rollout_ape"].shape == (2, 3)

    policy = evaluate.history_policy(CFG, jnp.zeros(5), jnp.ones(5), env)
    reference = jax.jit(lambda one: envs.rollout(env, policy, one, jax.random.PRNGKey(0), 3,
                                                 record=lambda s: env.expert(env.expert_observation(s))))
    for p in range(2):
        one = jax.tree.map(lambda x: x[p], params)
        traj = reference(one)
        for e in range(3):
            n = int(traj.lengths[e])
            a, a_star = np.asarray(traj.action[e, :n]), np.asarray(traj.extra[e, :n])
            np.testing.assert_allclose(out["imitation_error"][p, e], np.sum((a - a_star) ** 2, -1).mean(), rtol=1e-5)
            ape = np.asarray(ape_lib.errors(psi, traj.action[e], jnp.arange(traj.action.shape[1])))[:n]
            np.testing.assert_allclose(out["rollout_ape"][p, e], ape.mean() / 2.0, rtol=1e-5)
    assert np.all(out["imitation_error"] > 0)  # untrained policies do not act like the expert


def test_image_loss_analysis_goes_policy_by_policy_in_chunks_and_matches_all_at_once():
    """Image policies: one at a time over 256-row chunks (300 rows: a partial last chunk), same numbers."""
    cfg = LearnerConfig(obs_shape=(8, 8, 3), action_dim=2, history=2, batch_size=4)
    learner = make_train(cfg)
    n = 300
    k_obs, k_act, k_ape = jax.random.split(jax.random.PRNGKey(0), 3)
    data = Data(obs=jax.random.randint(k_obs, (n, 8, 8, 3), 0, 256).astype(jnp.uint8),
                action=jax.random.normal(k_act, (n, 2)), t=jnp.arange(n) % 50, ape=jax.random.uniform(k_ape, (n,)))
    x = learner.policy_input(jnp.zeros((1, 2, 8, 8, 3), jnp.uint8))
    params = jax.vmap(lambda k: cfg.model().init(k, x))(jax.random.split(jax.random.PRNGKey(1), 2))
    out = evaluate.loss_analysis(cfg, params, data)
    cp = np.asarray(data.ape) >= np.quantile(np.asarray(data.ape), 0.9)
    for p in range(2):
        losses = np.asarray(learner.per_sample_loss(jax.tree.map(lambda v: v[p], params), data, jnp.arange(n)))
        np.testing.assert_allclose(out["unweighted"][p], losses.mean(), rtol=1e-5)
        np.testing.assert_allclose(out["changepoint"][p], losses[cp].mean(), rtol=1e-5)
        np.testing.assert_allclose(out["copycat"][p], losses[~cp].mean(), rtol=1e-5)
