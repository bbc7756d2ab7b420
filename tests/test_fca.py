"""FCA: the adversary learns when unopposed, the encoder's adversarial term defeats it, the policy still learns,
one vmapped run equals per-seed runs, BatchNorm's statistics move once an iteration, the bottleneck is off bit for
bit at β = 0 and on at β > 0, minibatches come from the split's rows, and the hparams refuse bad values.

The toy data makes `a_{t−1}` readable from the observation history but useless for `a_t`: the observation is
`[s_t, a_{t−1}]` with `s_t` i.i.d. normal and `a_t = tanh(s_t W)`, so `a_t` is independent of `a_{t−1}` (apart
from episode starts, where `a_{t−1} = a_t`), and an adversary can beat chance (`Var(a_{t−1})`, summed over
dimensions) only through what the embedding keeps of the history.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import methods, tasks
from ape_jax.baselines.fca import DEFAULT_IB_WEIGHT, LOG_VAR_INIT, FcaHparams, FcaIbKnobs, FcaKnobs, make_fca
from ape_jax.history import history_index
from ape_jax.learner import Data, LearnerConfig, stack_hparams
from ape_jax.models import ImagePolicy, StatePolicy
from ape_jax.pipeline.presets import resolve
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


# the FCA recipe's Adam (0.5, 0.999); a constant learning rate
CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=400, batch_size=32, lr_boundaries=(),
                    beta1=0.5)
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
    cfg = dataclasses.replace(CFG, iterations=4, lr_boundaries=(2,))
    learner = make_fca(cfg)
    keys = jax.random.split(jax.random.PRNGKey(1), 2)
    hp = stack_hparams([FcaHparams.make(tasks.get("hopper").fca_alpha, lr=1e-3, adversary_lr=4e-4),
                        FcaHparams.make(tasks.get("walker2d").fca_alpha, lr=5e-4, ib_weight=1e-2)])
    traces = []
    run = jax.jit(jax.vmap(lambda k, h, d: (traces.append(1), learner.train(k, h, d))[1], (0, 0, None)))
    params, metrics = run(keys, hp, data)
    assert set(metrics) == {"loss", "unweighted_loss", "adversary_loss", "reference_loss", "kl"}
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
    with pytest.raises(ValueError, match="^learning rate must be > 0 and finite, got inf$"):
        FcaHparams.make(0.1, lr=float("inf"), adversary_lr=1e-4)
    with pytest.raises(ValueError, match="adversary learning rate must be > 0"):
        FcaHparams.make(0.1, adversary_lr=-1e-4)
    with pytest.raises(ValueError, match="ib_weight must be >= 0"):
        FcaHparams.make(0.1, ib_weight=-1.0)
    with pytest.raises(ValueError, match="ib_weight must be >= 0"):
        FcaHparams.make(0.1, ib_weight=float("inf"))
    hp = FcaHparams.make(0.2)
    assert hp.alpha.dtype == hp.lr.dtype == hp.adversary_lr.dtype == hp.ib_weight.dtype == jnp.float32
    assert float(hp.alpha) == pytest.approx(0.2) and float(hp.lr) == float(hp.adversary_lr) == pytest.approx(2e-4)
    assert float(hp.ib_weight) == 0.0
    assert float(FcaHparams.make(0.2, lr=1e-3, adversary_lr=4e-4).adversary_lr) == pytest.approx(4e-4)
    # the FCA code's α per task (its README: Hopper 2.0; its default 1.0) and Hopper's adversary learning rate
    assert [tasks.get(t).fca_alpha for t in ("hopper", "halfcheetah", "walker2d")] == [2.0, 1.0, 1.0]
    assert [tasks.get(t).fca_adversary_lr for t in ("hopper", "halfcheetah", "walker2d")] == [4e-4, 2e-4, 2e-4]


def test_tca_and_tca_ib_are_registered_as_one_program():
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=100)
    tca, ib = methods.get("fca"), methods.get("fca-ib")
    assert (tca.label, ib.label) == ("FCA (TCA)", "FCA (TCA + IB)")
    assert tca.program == ib.program == "fca" and tca.learner is ib.learner
    assert tca.settings(ctx) == [{"alpha": 2.0, "adversary_lr": 4e-4}]
    assert ib.settings(ctx) == [{"alpha": 2.0, "adversary_lr": 4e-4, "ib_weight": DEFAULT_IB_WEIGHT}]
    ctx = methods.GridContext(task=tasks.get("walker2d"), n_train=100,
                              knobs={"fca": FcaKnobs(alphas=(0.5, 1.0)),
                                     "fca-ib": FcaIbKnobs(alphas=(0.5, 1.0), weights=(1e-5, 1e-3))})
    assert [s["alpha"] for s in tca.settings(ctx)] == [0.5, 1.0]
    grid = ib.settings(ctx)
    assert [(s["alpha"], s["ib_weight"]) for s in grid] == [(0.5, 1e-5), (0.5, 1e-3), (1.0, 1e-5), (1.0, 1e-3)]
    # both methods' settings stack into one FcaHparams: one vmapped program
    hp = stack_hparams([m.hparams(s, 3e-4, 0) for m in (tca, ib) for s in m.settings(ctx)])
    np.testing.assert_allclose(hp.ib_weight, [0.0, 0.0, 1e-5, 1e-3, 1e-5, 1e-3])
    np.testing.assert_allclose(hp.adversary_lr, [2e-4] * 6)
    np.testing.assert_allclose(hp.lr, [3e-4] * 6)
    # its settings may set the adversary's learning rate for every task (`--set fca.adversary_lr=X`); the old
    # recipe names set both methods' (`--set recipe.fca_alphas=0.1 --set recipe.fca_adversary_lr=X`)
    knobs = resolve("hopper", "pos", sets=["recipe.fca_alphas=0.1", "recipe.fca_adversary_lr=2e-4"]).knobs
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=100, knobs=knobs)
    assert tca.settings(ctx) == [{"alpha": 0.1, "adversary_lr": 2e-4}]
    assert {s["adversary_lr"] for s in ib.settings(ctx)} == {2e-4}


def test_a_dataset_smaller_than_the_batch_is_refused(data):
    learner = make_fca(LearnerConfig(obs_shape=(4,), action_dim=2, batch_size=1000))
    with pytest.raises(ValueError, match="fewer than the batch size 1000"):
        learner.init(jax.random.PRNGKey(0), FcaHparams.make(0.1), data)


def test_the_reference_predictor_shows_what_the_embedding_adds(data, trained):
    _, metrics = trained
    ref = np.asarray(metrics["reference_loss"][:, -50:].mean(axis=1))  # R reads a_t alone: chance on this data
    adv = np.asarray(metrics["adversary_loss"][:, -50:].mean(axis=1))
    assert np.all(ref > 0.7 * _chance(data)), (ref, _chance(data))
    assert adv[0] < 0.1 * ref[0], (adv, ref)          # α = 0: the embedding reveals a_{t-1} beyond a_t
    assert 0.7 * ref[1] < adv[1] < 1.5 * ref[1], (adv, ref)  # α = 1: D learns about as little as R
    np.testing.assert_array_equal(metrics["kl"], 0.0)  # TCA: no bottleneck


def test_batchnorm_trains_per_configuration_and_its_statistics_move_once_an_iteration(data):
    cfg = dataclasses.replace(CFG, network="bn-mlp", init="xavier", iterations=10)
    learner = make_fca(cfg)
    keys = jax.random.split(jax.random.PRNGKey(2), 2)
    hp = stack_hparams([FcaHparams.make(1.0, lr=1e-3), FcaHparams.make(0.5, lr=1e-3, ib_weight=1e-2)])
    params, metrics = jax.jit(jax.vmap(learner.train, (0, 0, None)))(keys, hp, data)
    assert all(np.all(np.isfinite(m)) for m in metrics.values())
    fresh = jax.vmap(lambda k: learner.init(k, FcaHparams.make(0.0), data).policy)(keys)
    assert set(params) == {"params", "batch_stats"}
    for name, stats in params["batch_stats"].items():
        for stat in ("mean", "var"):
            moved = np.abs(np.asarray(stats[stat]) - np.asarray(fresh["batch_stats"][name][stat])).max(axis=-1)
            assert np.all(moved > 1e-3), (name, stat, moved)                   # both rows moved
            assert not np.allclose(stats[stat][0], stats[stat][1]), (name, stat)  # each its own statistics
    # one iteration: the first layer's running mean is 0.9 · 0 + 0.1 · its batch mean, updated once
    state = jax.jit(learner.init)(keys[0], FcaHparams.make(1.0), data)
    after, _ = jax.jit(learner.run, static_argnums=3)(state, FcaHparams.make(1.0), data, 1)
    _, idx = data.sample(jax.random.fold_in(state.key, 0), cfg.batch_size)
    x = learner.policy_input(data.obs[history_index(data.t, idx, cfg.history)])
    batch_mean = (x @ state.policy["params"]["encoder_0"]["kernel"]).mean(axis=0)
    np.testing.assert_allclose(after.policy["batch_stats"]["norm_0"]["mean"], 0.1 * batch_mean, rtol=1e-4, atol=1e-7)


@pytest.fixture(scope="module")
def short_runs(data):
    """`(run, state)`: 30 jitted iterations (α = 0.5) from one initial state, and that state."""
    learner = make_fca(dataclasses.replace(CFG, iterations=30))
    state = jax.jit(learner.init)(jax.random.PRNGKey(4), FcaHparams.make(0.5), data)
    return jax.jit(lambda s, hp: learner.run(s, hp, data, 30)), state


def test_without_the_bottleneck_sigma_changes_nothing(short_runs):
    run, state = short_runs
    hp = FcaHparams.make(0.5, lr=1e-3)
    a, metrics_a = run(state, hp)
    b, metrics_b = run(state.replace(log_var=state.log_var + 8.0), hp)  # σ ≈ 2.7 instead of 0.05
    for x, y in zip(jax.tree.leaves((a.policy, a.adversary, a.reference)),
                    jax.tree.leaves((b.policy, b.adversary, b.reference))):
        np.testing.assert_array_equal(x, y)
    for name in metrics_a:
        np.testing.assert_array_equal(metrics_a[name], metrics_b[name])
    np.testing.assert_array_equal(metrics_a["kl"], 0.0)
    np.testing.assert_array_equal(a.log_var, state.log_var)  # no gradient reaches σ


def test_with_the_bottleneck_the_kl_is_paid_and_sigma_learns(data, short_runs):
    run, state = short_runs
    tca, tca_metrics = run(state, FcaHparams.make(0.5, lr=1e-3))
    ib, metrics = run(state, FcaHparams.make(0.5, lr=1e-3, ib_weight=1e-2))
    assert all(np.all(np.isfinite(m)) for m in metrics.values())
    kl = np.asarray(metrics["kl"])
    assert np.all(kl > 0), kl
    # σ starts at e^{-3}: the KL's −log σ² term alone is 0.5 · 100 · (6 − 1 + e^{-6}) nats at the start
    assert kl[0] > 0.5 * ib.log_var.size * (-LOG_VAR_INIT - 1.0), kl[0]
    assert np.all(np.asarray(ib.log_var) > LOG_VAR_INIT)  # the KL opens the bottleneck
    # the noise reaches F: the same key and batches train another policy
    assert not np.allclose(metrics["unweighted_loss"], tca_metrics["unweighted_loss"])
    # the first iteration's KL: of N(μ, σ²) against N(0, I), μ the embedding of its minibatch, summed over dims
    _, idx = data.sample(jax.random.fold_in(state.key, 0), CFG.batch_size)
    x = make_fca(CFG).policy_input(data.obs[history_index(data.t, idx, CFG.history)])
    _, mu = CFG.model().apply(state.policy, x, return_embedding=True)
    var = np.exp(np.asarray(state.log_var, np.float64))
    expected = 0.5 * np.mean(np.sum(np.asarray(mu, np.float64) ** 2 + var - np.log(var) - 1.0, axis=-1))
    np.testing.assert_allclose(kl[0], expected, rtol=1e-5)


def test_minibatches_come_from_the_split_rows_only(data):
    """Episodes 1, 3, 4 and 6 hold actions of 1e3: one drawn row of them would blow every loss up."""
    episodes, length = 8, 32
    kept = np.array([0, 2, 5, 7])
    rows = np.random.default_rng(1).permutation((kept[:, None] * length + np.arange(length)).ravel())
    outside = np.ones(episodes * length, bool)
    outside[rows] = False
    action = np.where(outside[:, None], 1e3, np.asarray(data.action)).astype(np.float32)
    split = Data(obs=data.obs, action=jnp.asarray(action), t=data.t, ape=jnp.ones(len(rows), jnp.float32),
                 rows=jnp.asarray(rows, jnp.int32))
    learner = make_fca(dataclasses.replace(CFG, iterations=30))
    _, metrics = jax.jit(learner.train)(jax.random.PRNGKey(5), FcaHparams.make(0.5, lr=1e-3), split)
    for name in ("unweighted_loss", "adversary_loss", "reference_loss"):
        assert float(np.max(metrics[name])) < 10.0, (name, float(np.max(metrics[name])))
    # the same data without `rows` draws the other episodes too
    _, everything = jax.jit(learner.train)(jax.random.PRNGKey(5), FcaHparams.make(0.5, lr=1e-3),
                                           split.replace(rows=None, ape=jnp.ones(len(action), jnp.float32)))
    assert float(np.min(everything["unweighted_loss"])) > 1e3
