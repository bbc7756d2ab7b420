"""Priming (PrimeNet): at weight 0 the history policy trains as BC-OH and the composite acts as BC-OH, with the prime
read from a trained BC-SO (`bc-so`, kept as it is) or trained beside it (`joint`); a 2 × 2 grid (weights × seeds)
trains in one vmapped program; the trained composite is the prime network on the current state feeding the history
policy, probed through the history policy's embedding; each run reads its own seed's BC-SO; its knobs and the sweep
refuse what it cannot run, in one line."""

import dataclasses
import json
import types

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
from experiments import sweep

CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=30, batch_size=16, lr_boundaries=())


def _policy_part(variables):
    """The history policy's variables inside the composite's (a plain `StatePolicy`'s)."""
    return {k: v["policy"] for k, v in variables.items()}


def _bc_so(cfg: LearnerConfig, data, key=jax.random.PRNGKey(9)):
    """A BC-SO policy of `cfg`'s recipe, trained: the prime the `bc-so` source reads."""
    return jax.jit(make_train(dataclasses.replace(cfg, history=1)).train)(key, Hparams.make(lr=1e-3), data)[0]


def _prime_part(variables):
    return {k: v["prime"] for k, v in variables.items()}


@pytest.mark.parametrize("source", ["bc-so", "joint"])
@pytest.mark.parametrize("network", ["mlp", "bn-mlp"])
def test_at_weight_0_the_history_policy_trains_as_bc_oh(network, source):
    cfg, key, data = dataclasses.replace(CFG, network=network), jax.random.PRNGKey(3), planted(rho=0.7)
    hp = PrimingHparams.make(0.0, lr=1e-3)
    bc_so = _bc_so(cfg, data)
    primed, metrics = jax.jit(make_priming(cfg, source).train)(key, hp.read(bc_so) if source == "bc-so" else hp, data)
    bc_oh, bc_metrics = jax.jit(make_train(cfg).train)(jax.random.split(key)[0], Hparams.make(lr=1e-3), data)
    init = make_train(cfg).init_policy(jax.random.split(jax.random.split(key)[0])[0], data)
    assert jax.tree.structure(_policy_part(primed)) == jax.tree.structure(bc_oh)
    assert update_mismatch(_policy_part(primed), bc_oh, init) < 1e-4
    np.testing.assert_allclose(metrics["unweighted_loss"], bc_metrics["unweighted_loss"], rtol=1e-4)
    assert not np.any(primed["params"]["prime_input"]["kernel"])    # the prime's block, scaled by 0
    if source == "joint":   # BC-SO trained beside
        assert float(metrics["prime_loss"][-5:].mean()) < float(metrics["prime_loss"][:5].mean())
        np.testing.assert_allclose(metrics["loss"], metrics["unweighted_loss"] + metrics["prime_loss"], rtol=1e-5)
    else:   # BC-SO read as it is: its parameters and running statistics untouched, its loss not trained
        jax.tree.map(np.testing.assert_array_equal, _prime_part(primed), bc_so)
        np.testing.assert_array_equal(metrics["loss"], metrics["unweighted_loss"])


def test_the_bc_so_source_primes_with_the_policy_it_reads_and_refuses_to_run_without_one():
    data = planted(rho=0.7)
    bc_so = _bc_so(CFG, data)
    primed, metrics = jax.jit(make_priming(CFG, "bc-so").train)(
        jax.random.PRNGKey(3), PrimingHparams.make(1.0, lr=1e-3).read(bc_so), data)
    x = make_train(CFG).policy_input(data.obs[jnp.stack([jnp.maximum(jnp.arange(64) - 1, 0), jnp.arange(64)], 1)])
    np.testing.assert_allclose(primed_model(CFG).apply(primed, x, method="prime_of"),
                               StatePolicy(2).apply(bc_so, x[:, -4:]), rtol=1e-6, atol=1e-6)   # BC-SO's actions
    loss = metrics["unweighted_loss"]
    assert float(loss[-5:].mean()) < float(loss[:5].mean())   # the history policy learns beside the fixed prime
    with pytest.raises(ValueError, match="reads BC-SO's trained policies, and none were given"):
        make_priming(CFG, "bc-so").init(jax.random.PRNGKey(0), PrimingHparams.make(1.0), data)


def test_each_run_reads_the_policy_of_its_own_seed():
    runs = [types.SimpleNamespace(method="priming", seed=s) for s in (4, 3, 4)]
    source = [types.SimpleNamespace(method="bc-so", seed=s) for s in (3, 4)]
    params = {"w": jnp.asarray([30.0, 40.0])}
    hp = methods.read_trained(stack_hparams([PrimingHparams.make(1.0)] * 3), runs, "bc-so", source, params)
    np.testing.assert_array_equal(hp.prime["w"], [40.0, 30.0, 40.0])
    with pytest.raises(methods.MethodError, match=r"bc-so's policies, which has no run of seed\(s\) \[7\]"):
        methods.read_trained(hp, [types.SimpleNamespace(method="priming", seed=7)], "bc-so", source, params)


@pytest.fixture(scope="module")
def grid():
    """Weights 0 and 1 × two seeds in one vmapped program, and weight 1's first seed alone."""
    keys = jax.random.split(jax.random.PRNGKey(5), 2)
    keys = jnp.concatenate([keys, keys])
    hp = stack_hparams([PrimingHparams.make(w, lr=1e-3) for w in (1.0, 0.0) for _ in range(2)])
    joint = make_priming(CFG, "joint")
    params, metrics = jax.jit(jax.vmap(joint.train, (0, 0, None)))(keys, hp, planted(rho=0.7))
    alone, _ = jax.jit(joint.train)(keys[0], PrimingHparams.make(1.0, lr=1e-3), planted(rho=0.7))
    return params, metrics, alone, keys


def test_a_grid_of_two_weights_by_two_seeds_trains_in_one_vmapped_program(grid):
    params, metrics, alone, keys = grid
    row = lambda j: jax.tree.map(lambda x: x[j], params)   # noqa: E731
    init = make_priming(CFG, "joint").init(keys[0], PrimingHparams.make(1.0), planted()).params
    assert update_mismatch(row(0), alone, init) < UPDATE_RTOL
    assert all(update_mismatch(row(j), alone, init) > 0.1 for j in (1, 2, 3))   # another seed or weight
    assert metrics["loss"].shape == (4, CFG.iterations)
    np.testing.assert_allclose(metrics["loss"], metrics["unweighted_loss"] + metrics["prime_loss"], rtol=1e-5)
    # the same seed's prime network trains alike at either weight (nothing flows back from the policy into it)
    prime = lambda j: jax.tree.map(lambda x: x[j], params["params"]["prime"])   # noqa: E731
    assert update_mismatch(prime(0), prime(2), init["params"]["prime"]) < UPDATE_RTOL


def test_the_grid_s_stacked_state_gives_each_run_its_own_scaled_policy():
    """The sweep reads the trained policies from the grid's state stacked over runs (`train_program`): the weight
    `[R]` scales each run's own projection `[R, A, F]`, as one run's state alone gives it."""
    learner = make_priming(CFG, "joint")
    weights = (0.5, 2.0, 0.0)
    keys = jax.random.split(jax.random.PRNGKey(3), len(weights))
    hp = stack_hparams([PrimingHparams.make(w, lr=1e-3) for w in weights])
    state = jax.vmap(learner.init, (0, 0, None))(keys, hp, planted())
    stacked = learner.policy_params(state)
    for j, w in enumerate(weights):
        one = learner.policy_params(jax.tree.map(lambda x: x[j], state))
        got = stacked["params"]["prime_input"]["kernel"][j]
        np.testing.assert_array_equal(got, one["params"]["prime_input"]["kernel"])
        np.testing.assert_array_equal(got, w * state.params["params"]["prime_input"]["kernel"][j])


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
    states = jax.vmap(lambda key: make_priming(cfg, "joint").init(key, PrimingHparams.make(0.0), data))(
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
    assert (PrimingKnobs().source, PrimingKnobs().weights) == ("bc-so", (1.0,))
    for bad, words in (({"source": "staged"}, "priming.source must be one of bc-so, joint"),
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
    (["--set", "priming.source=staged"], "priming.source must be one of bc-so, joint"),
    (["--set", "priming.weights=1,-1"], "priming.weights must be >= 0"),
    (["--set", "protocol.history=1"], "priming primes a history policy"),
    (["--obs", "image"], "priming runs on state observations"),
    ([], "priming reads the trained policies of bc-so: add bc-so to --methods, or change priming's settings"),
])
def test_the_sweep_refuses_what_priming_cannot_run_in_one_line_before_any_work(tmp_path, capsys, args, message):
    argv = ["--env", "toycar", "--obs", "full", "--quiet", "--methods", "priming", *args]
    assert_sweep_refuses(tmp_path, capsys, argv, message)


@pytest.mark.integration
def test_a_tiny_sweep_trains_priming_on_its_bc_so_and_records_both(tmp_path):
    """ToyCar from the full state, 10 iterations: BC-SO first, then Priming at weights 0 and 1 reading it, through
    the sweep's own training path (the grid's stacked state: `policy_params`), evaluated and recorded."""
    out = tmp_path / "run"
    assert sweep.main(["--env", "toycar", "--obs", "full", "--quiet", "--methods", "bc-so,priming",
                       "--iterations", "10", "--eval-episodes", "1", "--set", "budget.probe_steps=0",
                       "--set", "priming.weights=0,1", "--out", str(out), "--data-dir", str(tmp_path / "data")]) == 0
    r = json.loads((out / "results.json").read_text())
    assert [(x["method"], x["hparams"], x["status"]) for x in r["runs"]] == [
        ("bc-so", {}, "ok"), ("priming", {"weight": 0.0}, "ok"), ("priming", {"weight": 1.0}, "ok")]
    assert all(np.isfinite(x["train_loss_final"]) for x in r["runs"])
