"""PALR: the HSCIC estimator is PALR's formula and tells dependence from conditional independence; PALR at weight
0 is BC-OH bit for bit; at its default weight it empties the embedding of the previous action where BC-OH keeps
it; its knobs refuse bad values; PALR's protocol records."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import diagnostics as dg
from ape_jax import methods, tasks
from ape_jax.baselines.palr import DEFAULT_BANDWIDTH, DEFAULT_WEIGHT, PalrHparams, gaussian_gram, hscic, make_palr
from ape_jax.learner import Hparams, LearnerConfig, make_train, stack_hparams
from ape_jax.pipeline.presets import resolve
from _compare import update_mismatch
from _planted import planted

CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=500, batch_size=64, lr_boundaries=(),
                    beta1=0.5)


def _per_row_hscic(x, y, z, bandwidth, ridge):
    """PALR's estimator written per conditioning point, in float64: the mean over i of
    `w_iᵀ(K_X ⊙ K_Y)w_i − 2 w_iᵀ((K_X w_i) ⊙ (K_Y w_i)) + (w_iᵀ K_X w_i)(w_iᵀ K_Y w_i)`."""
    x, y, z = (np.asarray(v, np.float64) for v in (x, y, z))
    kx, ky, kz = (np.exp(-((v[:, None] - v[None]) ** 2).sum(-1) / bandwidth) for v in (x, y, z))
    n = len(x)
    total = 0.0
    for i in range(n):
        w = np.linalg.solve(kz + ridge * n * np.eye(n), kz[:, i])
        total += w @ (kx * ky) @ w - 2 * w @ ((kx @ w) * (ky @ w)) + (w @ kx @ w) * (w @ ky @ w)
    return total / n


@pytest.mark.parametrize("bandwidth", [0.5, 2.0])
def test_the_estimator_is_palr_s_formula(bandwidth):
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    x, y, z = (jax.random.normal(k, (24, d)) for k, d in zip(keys, (5, 2, 2)))
    got = float(hscic(x, y, z, bandwidth, ridge=1e-2))
    want = _per_row_hscic(x, y, z, bandwidth, 1e-2)
    assert want > 1e-3 and got == pytest.approx(want, rel=1e-3)
    gram = gaussian_gram(x, bandwidth)
    np.testing.assert_allclose(np.diag(gram), 1.0, rtol=1e-5)  # rounding in the distances
    np.testing.assert_allclose(gram, gram.T)


def test_the_estimator_tells_dependence_from_conditional_independence():
    """X a function of Z plus noise (independent of Y given Z) against X reading Y: the first's estimate is a
    finite-sample bias that shrinks as rows are added, the second's stays."""
    estimates = {}
    for n in (128, 512):
        keys = jax.random.split(jax.random.PRNGKey(1), 4)
        z, y = (jax.random.uniform(k, (n, 2), minval=-1, maxval=1) for k in keys[:2])
        noise, mix = 0.1 * jax.random.normal(keys[2], (n, 3)), jax.random.normal(keys[3], (4, 3))
        independent = jnp.concatenate([z, z**2], axis=1) @ mix + noise
        leaky = jnp.concatenate([z, y], axis=1) @ mix + noise
        estimates[n] = float(hscic(independent, y, z, 1.0)), float(hscic(leaky, y, z, 1.0))
    (small_128, large_128), (small_512, large_512) = estimates[128], estimates[512]
    assert 0.0 <= small_128 and 2.5 * small_128 < large_128 and 4 * small_512 < large_512, estimates
    assert small_512 < 0.5 * small_128 and large_512 > 0.5 * large_128, estimates
    # only the embedding's kernel carries a gradient: Y and Z are data
    grads = jax.grad(lambda x, y, z: hscic(x, y, z, 1.0), argnums=(0, 1, 2))(leaky, y, z)
    assert float(jnp.abs(grads[0]).max()) > 0 and not jnp.any(grads[1]) and not jnp.any(grads[2])


@pytest.mark.parametrize("network", ["mlp", "bn-mlp"])
def test_at_weight_0_palr_trains_bc_oh(network):
    """The same initialisation, batches, loss and updates as BC-OH: bit for bit where XLA compiles the two programs
    alike (the default compile here), up to float32 rounding under the tests' fast-compile flags; a weight
    moves far from it."""
    cfg = dataclasses.replace(CFG, iterations=20, network=network)
    data, key = planted(), jax.random.PRNGKey(3)
    palr, metrics = jax.jit(make_palr(cfg).train)(key, PalrHparams.make(0.0, lr=1e-3), data)
    bc_oh, _ = jax.jit(make_train(cfg).train)(key, Hparams.make(lr=1e-3), data)
    init = make_train(cfg).init_policy(jax.random.split(key)[0], data)
    assert jax.tree.structure(palr) == jax.tree.structure(bc_oh)
    assert update_mismatch(palr, bc_oh, init) < 1e-4
    np.testing.assert_array_equal(metrics["loss"], metrics["unweighted_loss"])
    # the default weight at σ² = 10: the BatchNorm network's embedding is ~10× the plain one's in squared
    # distance, where σ² = 1 leaves every pair of rows at kernel ~0 and the penalty without a gradient (docs)
    moved, _ = jax.jit(make_palr(cfg).train)(key, PalrHparams.make(DEFAULT_WEIGHT, 10.0, lr=1e-3), data)
    assert update_mismatch(moved, bc_oh, init) > 0.01  # a hundred times the rounding above


def test_palr_empties_the_embedding_of_the_previous_action_where_bc_oh_keeps_it():
    """Same keys, batches and updates; weight 0 (BC-OH) and PALR's default in one vmapped program. A fresh probe
    on the frozen embeddings of held-out episodes reads a_{t−1} from BC-OH's (~2% of what a_t alone leaves) and
    little from PALR's, whose policy still learns a_t."""
    train, val = planted(), planted(seed=1)
    hp = stack_hparams([PalrHparams.make(w, DEFAULT_BANDWIDTH, lr=1e-3) for w in (0.0, DEFAULT_WEIGHT)])
    params, metrics = jax.jit(jax.vmap(make_palr(CFG).train, (0, 0, None)))(
        jnp.stack([jax.random.PRNGKey(0)] * 2), hp, train)
    probes, losses = [], []
    for i in range(2):
        p = jax.tree.map(lambda leaf: leaf[i], params)
        tr, va = dg.probe_inputs(CFG, p, train), dg.probe_inputs(CFG, p, val)
        probes.append(dg.embedding_probe(jax.random.PRNGKey(5), tr.embedding, va.embedding, tr.previous_action,
                                         va.previous_action, tr.action, va.action, steps=800))
        losses.append(float(jnp.mean(make_train(CFG).per_sample_loss(p, val, jnp.arange(val.t.shape[0])))))
    bc_oh, palr = probes
    assert float(bc_oh.ratio) < 0.1, bc_oh                                   # BC-OH keeps a_{t−1}
    assert float(palr.prev_from_embedding) > 5 * float(bc_oh.prev_from_embedding), (bc_oh, palr)
    hscic_trace = np.asarray(metrics["hscic"][1])
    assert hscic_trace[-50:].mean() < 0.1 * hscic_trace[:10].mean()        # the penalty it was trained on fell
    assert losses[1] < 0.05 and losses[1] < 3 * losses[0], losses          # and it still imitates a_t


def test_the_knobs_refuse_bad_values():
    for kw, message in (({"weight": -1.0}, "weight must be >= 0"), ({"weight": float("inf")}, "weight must be"),
                        ({"bandwidth": 0.0}, "bandwidth must be > 0"), ({"bandwidth": -2.0}, "bandwidth must be > 0"),
                        ({"lr": 0.0}, "learning rate")):
        with pytest.raises(ValueError, match=message):
            PalrHparams.make(**kw)
    with pytest.raises(ValueError, match="rows must be >= 0"):
        make_palr(CFG, rows=-1)
    with pytest.raises(ValueError, match="bandwidth must be > 0"):
        methods.get("palr").hparams({"weight": 1.0, "bandwidth": 0.0}, 1e-3, 0)


def test_the_grid_is_the_recipe_s_weights_by_bandwidths_or_the_authors_defaults():
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=100)
    assert methods.get("palr").settings(ctx) == [{"weight": 10.0, "bandwidth": 1.0}]
    knobs = resolve("hopper", "pos", sets=["palr.weights=1,10", "palr.bandwidths=0.5"]).knobs
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=100, knobs=knobs)
    assert methods.get("palr").settings(ctx) == [{"weight": 1.0, "bandwidth": 0.5}, {"weight": 10.0, "bandwidth": 0.5}]


@pytest.mark.parametrize("history", [2, 4])
def test_palr_s_protocol_is_a_record_with_its_recipe(history):
    settings = resolve("halfcheetah", "pos", protocol=f"palr-h{history}")
    p, r = settings.protocol, settings.recipe
    assert (p.history, p.train_transitions, p.val_transitions, p.split) == (history, 30_000, 2_000, "episodes")
    assert p.frame_skip is None and p.horizon is None and p.reference == "brax"   # gym's frame skip, 1,000 steps
    assert "positions only" in p.doc and "velocities" in p.doc                       # the HalfCheetah mask, declined
    assert (r.name, r.batch_size, r.lr, r.lr_decay_at) == ("mlp-b1024", 1024, 3e-4, ())
    assert settings.learner_config((8,), 6, history, "l2").lr_boundaries == ()
