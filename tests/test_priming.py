"""Priming (PrimeNet): at weight 0 the history policy trains as BC-OH and the composite acts as BC-OH; a 2 × 2 grid
(weights × seeds) trains in one vmapped program; the trained composite is the prime network on the current state
feeding the history policy, probed through the history policy's embedding; its knobs and the sweep refuse what it
cannot run, in one line."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax import evaluate, methods, tasks
from ape_jax.baselines.priming import (PrimingHparams, PrimingKnobs, make_priming, policy_runtime, primed_model,
                                       refusal)
from ape_jax.diagnostics import policy_embeddings
from ape_jax.learner import Hparams, LearnerConfig, make_train, stack_hparams
from ape_jax.models import StatePolicy
from ape_jax.pipeline.presets import resolve
from _compare import UPDATE_RTOL, update_mismatch
from _planted import planted
from _refusal import assert_sweep_refuses

CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=30, batch_size=16, lr_boundaries=())


def _policy_part(variables):
    """The history policy's variables inside the composite's (a plain `StatePolicy`'s)."""
    return {k: v["policy"] for k, v in variables.items()}


@pytest.mark.parametrize("network", ["mlp", "bn-mlp"])
def test_at_weight_0_the_history_policy_trains_as_bc_oh(network):
    cfg, key, data = dataclasses.replace(CFG, network=network), jax.random.PRNGKey(3), planted(rho=0.7)
    primed, metrics = jax.jit(make_priming(cfg).train)(key, PrimingHparams.make(0.0, lr=1e-3), data)
    bc_oh, bc_metrics = jax.jit(make_train(cfg).train)(jax.random.split(key)[0], Hparams.make(lr=1e-3), data)
    init = make_train(cfg).init_policy(jax.random.split(jax.random.split(key)[0])[0], data)
    assert jax.tree.structure(_policy_part(primed)) == jax.tree.structure(bc_oh)
    assert update_mismatch(_policy_part(primed), bc_oh, init) < 1e-4
    np.testing.assert_allclose(metrics["unweighted_loss"], bc_metrics["unweighted_loss"], rtol=1e-4)
    assert not np.any(primed["params"]["prime_input"]["kernel"])    # the prime's block, scaled by 0
    assert float(metrics["prime_loss"][-5:].mean()) < float(metrics["prime_loss"][:5].mean())   # BC-SO trained beside


@pytest.fixture(scope="module")
def grid():
    """Weights 0 and 1 × two seeds in one vmapped program, and weight 1's first seed alone."""
    keys = jax.random.split(jax.random.PRNGKey(5), 2)
    keys = jnp.concatenate([keys, keys])
    hp = stack_hparams([PrimingHparams.make(w, lr=1e-3) for w in (1.0, 0.0) for _ in range(2)])
    params, metrics = jax.jit(jax.vmap(make_priming(CFG).train, (0, 0, None)))(keys, hp, planted(rho=0.7))
    alone, _ = jax.jit(make_priming(CFG).train)(keys[0], PrimingHparams.make(1.0, lr=1e-3), planted(rho=0.7))
    return params, metrics, alone, keys


def test_a_grid_of_two_weights_by_two_seeds_trains_in_one_vmapped_program(grid):
    params, metrics, alone, keys = grid
    row = lambda j: jax.tree.map(lambda x: x[j], params)   # noqa: E731
    init = make_priming(CFG).init(keys[0], PrimingHparams.make(1.0), planted()).params
    assert update_mismatch(row(0), alone, init) < UPDATE_RTOL
    assert all(update_mismatch(row(j), alone, init) > 0.1 for j in (1, 2, 3))   # another seed or weight
    assert metrics["loss"].shape == (4, CFG.iterations)
    np.testing.assert_allclose(metrics["loss"], metrics["unweighted_loss"] + metrics["prime_loss"], rtol=1e-5)
    # the same seed's prime network trains alike at either weight (nothing flows back from the policy into it)
    prime = lambda j: jax.tree.map(lambda x: x[j], params["params"]["prime"])   # noqa: E731
    assert update_mismatch(prime(0), prime(2), init["params"]["prime"]) < UPDATE_RTOL


def test_the_composite_is_the_prime_network_feeding_the_history_policy(grid):
    params, _, _, _ = grid
    p = jax.tree.map(lambda x: x[0], params)
    data = planted(rho=0.7)
    x = make_train(CFG).policy_input(data.obs[jnp.stack([jnp.maximum(jnp.arange(64) - 1, 0), jnp.arange(64)], 1)])
    net = StatePolicy(2)
    prime = net.apply({"params": p["params"]["prime"]}, x[:, -4:])                     # BC-SO on o_t
    block = prime @ p["params"]["prime_input"]["kernel"]
    want, want_embedding = net.apply({"params": p["params"]["policy"]}, x, return_embedding=True,
                                     first_layer_input=block)
    runtime = policy_runtime(CFG, [{"weight": 1.0}])
    got, embedding = runtime.apply(p, x, return_embedding=True)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(embedding, want_embedding, rtol=1e-5, atol=1e-6)
    probed = policy_embeddings(CFG, p, data, jnp.arange(1, 9), apply=runtime.apply)   # what the probes read
    np.testing.assert_allclose(probed, embedding[1:9], rtol=1e-5, atol=1e-6)
    alone = net.apply({"params": p["params"]["policy"]}, x)
    assert float(jnp.abs(got - alone).max()) > 1e-3   # the prime moves the action
    losses = evaluate.loss_analysis(CFG, params, data, runtime=runtime)
    assert losses["unweighted"].shape == (4,) and np.all(np.isfinite(losses["unweighted"]))


def test_at_weight_0_the_composite_acts_as_bc_oh():
    env = envs.make("toycar", obs="full", episode_length=40)
    cfg = dataclasses.replace(CFG, obs_shape=(5,))
    data = planted()
    states = jax.vmap(lambda key: make_priming(cfg).init(key, PrimingHparams.make(0.0), data))(
        jax.random.split(jax.random.PRNGKey(2), 2))
    params = jax.tree_util.tree_map_with_path(   # untrained; actions moved inside ToyCar's bounds [0, 1]
        lambda path, v: v + 0.5 if jax.tree_util.keystr(path).endswith("['action']['bias']") else v, states.params)
    params = {**params, "params": {**params["params"], "prime_input": {"kernel": jnp.zeros_like(
        params["params"]["prime_input"]["kernel"])}}}   # weight 0, as `policy_params` leaves it
    mean, std = jnp.full(5, 2.0), jnp.full(5, 3.0)
    runtime = policy_runtime(cfg, [{"weight": 0.0}] * 2)
    primed = evaluate.make_evaluator(env, cfg, mean, std, 2, keep_actions=True, runtime=runtime)
    bc_oh = evaluate.make_evaluator(env, cfg, mean, std, 2, keep_actions=True)
    got, want = primed(params, jax.random.PRNGKey(4)), bc_oh(_policy_part(params), jax.random.PRNGKey(4))
    assert float(jnp.abs(want["actions"]).max()) > 0.1   # a real comparison
    np.testing.assert_allclose(got["actions"], want["actions"], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(got["return"], want["return"], rtol=1e-5, atol=1e-5)


def test_the_knobs_and_the_learner_refuse_what_priming_cannot_run_in_one_line():
    assert (PrimingKnobs().source, PrimingKnobs().weights) == ("joint", (1.0,))
    for bad, words in (({"source": "staged"}, "priming.source must be one of joint"),
                       ({"weights": (1.0, -0.5)}, "priming.weights must be >= 0"),
                       ({"weights": ()}, "priming.weights must list each weight once"),
                       ({"weights": (1.0, 1.0)}, "priming.weights must list each weight once")):
        with pytest.raises(ValueError, match=words) as e:
            PrimingKnobs(**bad)
        assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="needs a history of at least 2"):
        make_priming(dataclasses.replace(CFG, history=1))
    with pytest.raises(ValueError, match="runs on state observations"):
        make_priming(LearnerConfig(obs_shape=(16, 16, 3), action_dim=2, encoder="patch"))
    with pytest.raises(ValueError, match="priming weight must be >= 0"):
        PrimingHparams.make(-1.0)
    assert "state observations" in refusal(resolve("hopper", "image"), "image")
    assert "primes a history policy" in refusal(resolve("hopper", "pos", sets=["protocol.history=1"]), "pos")
    assert refusal(resolve("hopper", "pos"), "pos") is None


def test_the_method_s_grid_is_its_weights_knob():
    method = methods.get("priming")
    assert (method.program, method.history, method.knobs, method.label) == ("priming", None, PrimingKnobs, "Priming")
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=100)
    assert method.settings(ctx) == [{"weight": 1.0}]
    ctx = dataclasses.replace(ctx, knobs={"priming": PrimingKnobs(weights=(0.0, 0.5))})
    assert method.settings(ctx) == [{"weight": 0.0}, {"weight": 0.5}]
    assert primed_model(dataclasses.replace(CFG, network="bn-mlp")).batchnorm


@pytest.mark.parametrize("args, message", [
    (["--set", "priming.source=staged"], "priming.source must be one of joint"),
    (["--set", "priming.weights=1,-1"], "priming.weights must be >= 0"),
    (["--set", "protocol.history=1"], "priming primes a history policy"),
    (["--obs", "image"], "priming runs on state observations"),
])
def test_the_sweep_refuses_what_priming_cannot_run_in_one_line_before_any_work(tmp_path, capsys, args, message):
    argv = ["--env", "toycar", "--obs", "full", "--quiet", "--methods", "priming", *args]
    assert_sweep_refuses(tmp_path, capsys, argv, message)
