"""FCA: the adversary learns when unopposed, the encoder's adversarial term defeats it, the policy still learns,
one vmapped run equals per-seed runs, and the hparams refuse bad values.

The toy data makes `a_{t−1}` readable from the observation history but useless for `a_t`: the observation is
`[s_t, a_{t−1}]` with `s_t` i.i.d. normal and `a_t = tanh(s_t W)`, so `a_t` is independent of `a_{t−1}` (apart
from episode starts, where `a_{t−1} = a_t`), and an adversary can beat chance (`Var(a_{t−1})`, summed over
dimensions) only through what the embedding keeps of the history.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import tasks
from ape_jax.baselines.fca import FcaHparams, make_fca
from ape_jax.history import history_index
from ape_jax.learner import Data, LearnerConfig, stack_hparams
from ape_jax.models import ImagePolicy, StatePolicy
from _compare import UPDATE_RTOL, update_mismatch


def _copycat_dataset(n_episodes=8, length=32, seed=0) -> Data:
    rng = np.random.default_rng(seed)
    n = n_episodes * length
    s = rng.normal(size=(n, 2)).astype(np.float32)
    w = rng.normal(size=(2, 2)).astype(np.float32)
    action = np.tanh(s @ w).astype(np.float32)
    t = np.tile(np.arange(length, dtype=np.int32), n_episodes)
    previous = action[np.asarray(history_index(jnp.asarray(t), jnp.arange(n), 1, offset=1))[:, 0]]
    obs = np.concatenate([s, previous], axis=1)  # [N, 4]: the history reveals a_{t-1}
    return Data(obs=jnp.asarray(obs), action=jnp.asarray(action), t=jnp.asarray(t), ape=jnp.ones(n, jnp.float32))


CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=400, batch_size=32, lr_decay_every=100_000)
ALPHAS = (0.0, 1.0)  # unopposed adversary; a strong adversarial term (the paper's are 0.1-0.5)


@pytest.fixture(scope="module")
def data():
    return _copycat_dataset()


@pytest.fixture(scope="module")
def trained(data):
    """Both alphas, same seed, in one vmapped program: (policy params [2, ...], metrics [2, 400])."""
    learner = make_fca(CFG)
    hp = stack_hparams([FcaHparams.make(a, lr=1e-3) for a in ALPHAS])
    keys = jnp.stack([jax.random.PRNGKey(0)] * len(ALPHAS))
    return jax.jit(jax.vmap(learner.train, (0, 0, None)))(keys, hp, data)


def _chance(data):
    """The adversary's loss when it predicts the mean previous action: Σ_d Var(a_{t−1})_d."""
    previous = data.action[history_index(data.t, jnp.arange(len(data.t)), 1, offset=1)[:, 0]]
    return float(previous.var(axis=0).sum())


def test_the_adversary_learns_the_previous_action_when_unopposed(data, trained):
    _, metrics = trained
    adv = np.asarray(metrics["adversary_loss"][0])  # alpha = 0: E ignores D
    assert adv.shape == (CFG.iterations,) and np.all(np.isfinite(adv))
    first, last = adv[:10].mean(), adv[-50:].mean()
    assert last < 0.1 * first, (first, last)
    assert last < 0.05 * _chance(data), (last, _chance(data))  # far below chance: it reads a_{t-1} from e


def test_the_adversarial_term_keeps_the_adversary_at_chance(data, trained):
    _, metrics = trained
    adv = np.asarray(metrics["adversary_loss"][:, -50:].mean(axis=1))  # [alpha=0, alpha=1], same seed and batches
    assert adv[1] > 20 * adv[0], adv
    assert adv[1] > 0.5 * _chance(data), (adv, _chance(data))
    loss, bc = np.asarray(metrics["loss"][1]), np.asarray(metrics["unweighted_loss"][1])
    assert np.all(loss < bc)  # loss = BC - alpha * adversary loss
    np.testing.assert_allclose(metrics["loss"][0], metrics["unweighted_loss"][0])  # alpha = 0: plain BC


def test_the_policy_params_are_the_model_s_and_the_policy_learns(data, trained):
    params, metrics = trained
    learner, model = make_fca(CFG), CFG.model()
    fresh = jax.jit(learner.init)(jax.random.PRNGKey(0), FcaHparams.make(1.0), data)
    idx = jnp.arange(len(data.t))
    x = learner.policy_input(data.obs[history_index(data.t, idx, CFG.history)])
    full_loss = jax.jit(lambda p: learner.per_sample_loss(p, data, idx).mean())
    for i in range(len(ALPHAS)):
        p = jax.tree.map(lambda leaf: leaf[i], params)
        assert jax.tree.structure(p) == jax.tree.structure(jax.eval_shape(model.init, jax.random.PRNGKey(1), x))
        assert jax.eval_shape(model.apply, p, x).shape == (len(idx), CFG.action_dim)
        before = float(full_loss(learner.policy_params(fresh)))
        after = float(full_loss(p))
        assert after < 0.3 * before, (ALPHAS[i], before, after)
        bc = np.asarray(metrics["unweighted_loss"][i])
        assert bc[-50:].mean() < 0.3 * bc[:10].mean(), (ALPHAS[i], bc[:10].mean(), bc[-50:].mean())


def test_the_embedding_comes_from_the_same_params():
    for model, x in ((StatePolicy(2), jnp.ones((3, 8))), (ImagePolicy(2, channels=(4, 4)), jnp.ones((3, 8, 8, 6)))):
        params = model.init(jax.random.PRNGKey(0), x)
        action, embedding = model.apply(params, x, return_embedding=True)
        np.testing.assert_array_equal(action, model.apply(params, x))
        assert embedding.shape == (3, 100)
        assert set(params["params"]["Head_0"]) == {"embedding", "head", "action"}


def test_one_vmapped_run_equals_per_seed_runs(data):
    # a few iterations (the learning rate decays after the second): rounding has no time to grow
    cfg = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=4, batch_size=32, lr_decay_every=2)
    learner = make_fca(cfg)
    keys = jax.random.split(jax.random.PRNGKey(1), 2)
    hp = stack_hparams([FcaHparams.make(tasks.get("hopper").fca_alpha, lr=1e-3),
                        FcaHparams.make(tasks.get("walker2d").fca_alpha, lr=5e-4)])
    traces = []
    run = jax.jit(jax.vmap(lambda k, h, d: (traces.append(1), learner.train(k, h, d))[1], (0, 0, None)))
    params, metrics = run(keys, hp, data)
    assert set(metrics) >= {"loss", "unweighted_loss", "adversary_loss"}
    assert metrics["loss"].shape == (2, 4)
    single = jax.jit(learner.train)
    init = jax.jit(lambda k: learner.init(k, FcaHparams.make(0.0), data).policy)  # depends on the key only
    for i in range(2):
        p_i, m_i = single(keys[i], jax.tree.map(lambda x: x[i], hp), data)
        for name in metrics:
            np.testing.assert_allclose(metrics[name][i], m_i[name], rtol=1e-4)
        assert update_mismatch(jax.tree.map(lambda x: x[i], params), p_i, init(keys[i])) < UPDATE_RTOL
        # the other row's alpha and learning rate with this row's key: far outside that tolerance
        p_w, m_w = single(keys[i], jax.tree.map(lambda x: x[1 - i], hp), data)
        assert update_mismatch(jax.tree.map(lambda x: x[i], params), p_w, init(keys[i])) > 0.1
    assert not np.allclose(metrics["loss"][0], metrics["loss"][1])
    run(jax.random.split(jax.random.PRNGKey(2), 2), hp, data)  # new seeds: no retrace
    assert len(traces) == 1


def test_the_hparams_refuse_bad_values():
    with pytest.raises(ValueError, match="alpha must be >= 0"):
        FcaHparams.make(-0.1)
    with pytest.raises(ValueError, match="alpha must be >= 0"):
        FcaHparams.make(float("nan"))
    with pytest.raises(ValueError, match="learning rate must be > 0"):
        FcaHparams.make(0.1, lr=0.0)
    hp = FcaHparams.make(0.2)
    assert hp.alpha.dtype == hp.lr.dtype == jnp.float32
    assert float(hp.alpha) == pytest.approx(0.2) and float(hp.lr) == pytest.approx(2e-4)
    # the paper's α per task: Hopper 0.1, HalfCheetah and Walker2d 0.5
    assert [tasks.get(t).fca_alpha for t in ("hopper", "halfcheetah", "walker2d")] == [0.1, 0.5, 0.5]


def test_a_dataset_smaller_than_the_batch_is_refused(data):
    learner = make_fca(LearnerConfig(obs_shape=(4,), action_dim=2, batch_size=1000))
    with pytest.raises(ValueError, match="fewer than the batch size 1000"):
        learner.init(jax.random.PRNGKey(0), FcaHparams.make(0.1), data)
