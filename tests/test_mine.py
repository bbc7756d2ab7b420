"""MINE-BC: the Donsker–Varadhan estimator finds dependence and no more; at weight 0 the policy trains as BC-OH's;
the penalty holds its co-trained estimator at chance; at a strong weight a fresh probe reads less of the previous
action than from BC-OH (but far more than from PALR: MINE hides the leak from its estimator more than it removes
it); its knobs refuse bad values."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from ape_jax import diagnostics as dg
from ape_jax import methods, tasks
from ape_jax.baselines.mine import MineHparams, StatisticsNetwork, draw_noise, dv_bound, make_mine
from ape_jax.learner import Hparams, LearnerConfig, make_train, stack_hparams
from ape_jax.pipeline.presets import resolve
from _compare import update_mismatch
from _planted import planted

CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=400, batch_size=64, lr_boundaries=(),
                    beta1=0.5, network="bn-mlp")


def _fit_bound(x, y, steps=400):
    """T fitted alone by ascent on the bound (Adam 1e-3, batches of 128); the bound on the last 50 batches."""
    net = StatisticsNetwork()
    width = x.shape[1] + y.shape[1]
    params = net.init(jax.random.PRNGKey(0), x[:1], y[:1], draw_noise(jax.random.PRNGKey(1), 1, width))
    opt = optax.adam(1e-3)

    def step(carry, i):
        p, s = carry
        key = jax.random.fold_in(jax.random.PRNGKey(2), i)
        rows = jax.random.randint(key, (128,), 0, x.shape[0])
        noise = draw_noise(jax.random.fold_in(key, 1), 128, width)
        bound, g = jax.value_and_grad(lambda p: dv_bound(net, p, x[rows], y[rows], jax.random.fold_in(key, 2),
                                                         noise))(p)
        updates, s = opt.update(jax.tree.map(jnp.negative, g), s)
        return (optax.apply_updates(p, updates), s), bound

    _, bounds = jax.lax.scan(step, (params, opt.init(params)), jnp.arange(steps))
    return bounds[-50:].mean()


def test_the_bound_finds_dependence_and_not_independence():
    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    x = jax.random.uniform(k1, (2048, 2), minval=-1, maxval=1)
    dependent = jnp.concatenate([x, x**2], axis=1)
    independent = jax.random.uniform(k2, (2048, 4), minval=-1, maxval=1)
    bounds = jax.jit(jax.vmap(_fit_bound, (None, 0)))(x, jnp.stack([dependent, independent]))
    assert bounds[0] > 0.5 and abs(float(bounds[1])) < 0.1, bounds


def test_at_weight_0_the_policy_trains_as_bc_oh_s():
    """BC-OH's initialisation (from the key's first half), batches, loss and updates: up to float32 rounding
    (`test_palr`), far from weight 1's."""
    cfg = dataclasses.replace(CFG, iterations=20)
    data, key = planted(), jax.random.PRNGKey(4)
    mine, metrics = jax.jit(make_mine(cfg).train)(key, MineHparams.make(0.0, lr=1e-3), data)
    bc_key = jax.random.split(key)[0]
    bc_oh, _ = jax.jit(make_train(cfg).train)(bc_key, Hparams.make(lr=1e-3), data)
    init = make_train(cfg).init_policy(jax.random.split(bc_key)[0], data)
    assert update_mismatch(mine, bc_oh, init) < 1e-4
    moved, _ = jax.jit(make_mine(cfg).train)(key, MineHparams.make(1.0, lr=1e-3), data)
    assert update_mismatch(moved, bc_oh, init) > 0.01  # a hundred times the rounding above
    assert set(metrics) == {"loss", "unweighted_loss", "mi", "estimator_mi"}
    np.testing.assert_array_equal(metrics["loss"], metrics["unweighted_loss"])


def test_the_bound_reads_a_batch_within_its_rows_whole_and_a_larger_one_on_its_first_rows():
    """`rows` 0 (all), the batch and more than the batch train alike, bit for bit (the `fca` and `mlp` recipes'
    trainings are as before the cap); fewer rows than the batch feed the bound a subsample: another training."""
    cfg = dataclasses.replace(CFG, iterations=10)
    data, key, hp = planted(), jax.random.PRNGKey(4), MineHparams.make(1.0, lr=1e-3)
    trained = {rows: jax.jit(make_mine(cfg, rows=rows).train)(key, hp, data)
               for rows in (0, cfg.batch_size, 256, cfg.batch_size // 4)}
    whole = jax.tree.leaves(trained[0])
    for rows in (cfg.batch_size, 256):
        assert all(np.array_equal(a, b) for a, b in zip(whole, jax.tree.leaves(trained[rows])))
    params, metrics = trained[cfg.batch_size // 4]
    assert np.all(np.isfinite(metrics["mi"])) and not np.array_equal(metrics["mi"], trained[0][1]["mi"])


def _trained(weights, seeds, iterations, inner_steps):
    cfg = dataclasses.replace(CFG, iterations=iterations)
    hp = stack_hparams([MineHparams.make(w, lr=1e-3, estimator_lr=1e-3) for w in weights for _ in seeds])
    keys = jnp.stack([jax.random.PRNGKey(s) for _ in weights for s in seeds])
    return cfg, jax.jit(jax.vmap(make_mine(cfg, inner_steps=inner_steps).train, (0, 0, None)))(keys, hp, planted())


def test_the_penalty_holds_its_estimator_at_chance():
    """The estimator co-trained with BC-OH finds the embedding's a_{t−1} (~0.9 nats); with the penalty on, the
    policy keeps it near 0 nats, and still learns a_t. (3 estimator steps per iteration: a short run.)"""
    _, (_, metrics) = _trained((0.0, 1.0), (0,), 300, 3)
    found = np.asarray(metrics["estimator_mi"][:, -50:].mean(axis=1))
    assert found[0] > 0.5 and abs(found[1]) < 0.1, found
    bc = np.asarray(metrics["unweighted_loss"][:, -50:].mean(axis=1))
    assert bc[1] < 0.1 and bc[1] < 0.3 * float(metrics["unweighted_loss"][1, :10].mean()), bc


@pytest.mark.slow
def test_at_a_strong_weight_a_fresh_probe_reads_less_of_the_previous_action():
    """Weight 10 and the authors' 5 estimator steps (`recipe.mine_steps=5`) against weight 0, two seeds each:
    every MINE embedding holds less of a_{t−1} than every BC-OH one (about a third to a half as much, at ~2.5×
    BC-OH's BC loss; PALR: ~30× less). With the default single step the probe reads as much as from BC-OH, at
    weight 0.1 or 10: MINE fools its noisy estimator (its input noise of std 0.3 hides small directions of the
    embedding) more than it empties the embedding."""
    seeds = (0, 1)
    cfg, (params, _) = _trained((0.0, 10.0), seeds, 1000, 5)
    train, val = planted(), planted(seed=1)
    error = []
    for i in range(2 * len(seeds)):
        p = jax.tree.map(lambda leaf: leaf[i], params)
        tr, va = dg.probe_inputs(cfg, p, train), dg.probe_inputs(cfg, p, val)
        error.append(float(dg.embedding_probe(jax.random.PRNGKey(5), tr.embedding, va.embedding, tr.previous_action,
                                              va.previous_action, tr.action, va.action, steps=800).prev_from_embedding))
    bc_oh, mine = error[:len(seeds)], error[len(seeds):]
    assert min(mine) > 1.3 * max(bc_oh), (bc_oh, mine)


def test_the_knobs_refuse_bad_values():
    for kw, message in (({"weight": -0.1}, "weight must be >= 0"), ({"weight": float("nan")}, "weight must be"),
                        ({"estimator_lr": 0.0}, "estimator learning rate"), ({"lr": -1.0}, "learning rate")):
        with pytest.raises(ValueError, match=message):
            MineHparams.make(**kw)
    with pytest.raises(ValueError, match="inner_steps must be >= 1"):
        make_mine(CFG, inner_steps=0)
    with pytest.raises(ValueError, match="rows must be >= 0"):
        make_mine(CFG, rows=-1)
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=100)
    assert methods.get("mine").settings(ctx) == [{"weight": 0.1}]
    knobs = resolve("hopper", "pos", sets=["mine.weights=0,1"]).knobs
    assert methods.get("mine").settings(dataclasses.replace(ctx, knobs=knobs)) == [{"weight": 0.0}, {"weight": 1.0}]
