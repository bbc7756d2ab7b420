"""ActionChunks (ACT's action chunking and temporal ensemble): chunk targets repeat an episode's last action; the
ensemble weighs the oldest prediction most, as ACT's code does; at k = 1 it trains and acts as BC-SO; a 2 × 2 grid
trains in one vmapped program; the run-time policy executes the ensemble of the chunks it queried; the probes and the
loss analysis read the chunk's first action; its knobs refuse bad values; a smoke sweep beside BC-SO and Priming
keeps their policies in groups of their own, evaluates them again as recorded and films one."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax import evaluate, methods, tasks
from ape_jax.baselines.action_chunks import (ChunkHparams, ChunkKnobs, chunk_config, make_action_chunks,
                                             policy_runtime, temporal_ensemble)
from ape_jax.diagnostics import policy_embeddings
from ape_jax.history import future_index
from ape_jax.learner import Hparams, LearnerConfig, make_train, stack_hparams
from ape_jax.pipeline import checkpoint as ckpt_lib
from experiments import evaluate as evaluate_cli
from experiments import sweep
from _compare import UPDATE_RTOL, update_mismatch
from _planted import planted
from _refusal import assert_sweep_refuses

CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=1, iterations=30, batch_size=16, lr_boundaries=())


def _train(cfg, k, key, lr=1e-3):
    return jax.jit(make_action_chunks(cfg, k).train)(key, ChunkHparams.make(lr), planted(rho=0.7))


def test_chunk_targets_read_ahead_in_the_episode_and_repeat_its_last_action():
    t = jnp.array([0, 1, 2, 0, 1, 0, 1, 2, 3])   # episodes of 3, 2 and 4 steps
    got = future_index(t, jnp.array([0, 1, 2, 3, 4, 5, 8]), 3)
    np.testing.assert_array_equal(got, [[0, 1, 2], [1, 2, 2], [2, 2, 2], [3, 4, 4], [4, 4, 4], [5, 6, 7], [8, 8, 8]])


def _act_reference(buffer: list, m: float) -> np.ndarray:
    """ACT's `imitate_episodes.py`: `all_time_actions[s, s:s+k] = chunk`; at t the populated rows of column t, in
    query order, weighted `exp(-m * arange(n))` and normalised."""
    t, k = len(buffer) - 1, len(buffer[0])
    table = np.zeros((t + 1, t + k, buffer[0].shape[-1]))
    for s, chunk in enumerate(buffer):
        table[s, s:s + k] = chunk
    column = table[max(0, t - k + 1):t + 1, t]
    w = np.exp(-m * np.arange(len(column)))
    return (w[:, None] * column).sum(0) / w.sum()


@pytest.mark.parametrize("m", [0.0, 0.01, 0.7])
def test_the_ensemble_weighs_the_oldest_prediction_most_as_act_does(m):
    k, a = 4, 2
    rng = np.random.default_rng(0)
    queried = [rng.normal(size=(k, a)).astype(np.float32) for _ in range(7)]
    chunks, made = jnp.zeros((k, k, a)), jnp.zeros((k,), bool)
    for t, chunk in enumerate(queried):   # an episode's first steps have fewer predictions, then k of them
        chunks = jnp.concatenate([chunks[1:], jnp.asarray(chunk)[None]])
        made = jnp.concatenate([made[1:], jnp.ones((1,), bool)])
        np.testing.assert_allclose(temporal_ensemble(chunks, made, m), _act_reference(queried[:t + 1], m), rtol=1e-5)
    predictions = np.stack([queried[-1 - i][i] for i in range(k)][::-1])   # oldest first
    if m > 0:   # the oldest weighs exp(m · (k − 1)) times the newest
        w = np.exp(-m * np.arange(k))
        np.testing.assert_allclose(temporal_ensemble(chunks, made, m), (w[:, None] * predictions).sum(0) / w.sum(),
                                   rtol=1e-5)
    np.testing.assert_array_equal(temporal_ensemble(chunks[-1:], made[-1:], m), queried[-1][0])   # k = 1: itself


@pytest.mark.parametrize("network", ["mlp", "bn-mlp"])
def test_at_k_1_it_trains_bc_so(network):
    cfg, key = dataclasses.replace(CFG, network=network), jax.random.PRNGKey(3)
    chunks, metrics = _train(cfg, 1, key)
    bc_so, bc_metrics = jax.jit(make_train(cfg).train)(key, Hparams.make(lr=1e-3), planted(rho=0.7))
    init = make_train(cfg).init_policy(jax.random.split(key)[0], planted(rho=0.7))
    assert jax.tree.structure(chunks) == jax.tree.structure(bc_so)
    assert update_mismatch(chunks, bc_so, init) < 1e-4
    np.testing.assert_allclose(metrics["first_loss"], bc_metrics["unweighted_loss"], rtol=1e-4)
    np.testing.assert_array_equal(metrics["loss"], metrics["first_loss"])


@pytest.fixture(scope="module")
def grid():
    """k = 3: two learning rates × two seeds in one vmapped program, and the first configuration alone."""
    keys = jax.random.split(jax.random.PRNGKey(5), 2)
    keys = jnp.concatenate([keys, keys])
    hp = stack_hparams([ChunkHparams.make(lr) for lr in (1e-3, 3e-3) for _ in range(2)])
    params, metrics = jax.jit(jax.vmap(make_action_chunks(CFG, 3).train, (0, 0, None)))(keys, hp,
                                                                                          planted(rho=0.7))
    alone, _ = _train(CFG, 3, keys[0])
    return params, metrics, alone, keys


def test_a_grid_of_two_settings_by_two_seeds_trains_in_one_vmapped_program(grid):
    params, metrics, alone, keys = grid
    row = lambda j: jax.tree.map(lambda x: x[j], params)   # noqa: E731
    init = make_train(chunk_config(CFG, 3)).init_policy(jax.random.split(keys[0])[0], planted(rho=0.7))
    assert row(0)["params"]["Head_0"]["action"]["kernel"].shape == (300, 6)   # k · A outputs
    assert update_mismatch(row(0), alone, init) < UPDATE_RTOL
    assert all(update_mismatch(row(j), alone, init) > 0.1 for j in (1, 2, 3))   # another seed or rate
    assert metrics["loss"].shape == (4, CFG.iterations)
    assert float(metrics["loss"][:, -5:].mean()) < float(metrics["loss"][:, :5].mean())


def test_the_run_time_policy_executes_the_ensemble_of_the_chunks_it_queried():
    env = envs.make("toycar", obs="full", episode_length=30)
    mean, std = jnp.full(5, 2.0), jnp.full(5, 3.0)
    cfg = dataclasses.replace(CFG, obs_shape=(5,))   # toycar's 5 inputs; an untrained chunk network
    p = make_train(chunk_config(cfg, 3)).init_policy(jax.random.PRNGKey(0), planted())
    runtime = policy_runtime(cfg, [{"k": 3.0, "m": 0.5}])
    policy = evaluate.runtime_policy(cfg, mean, std, env, runtime)
    traj = jax.jit(lambda key: envs.rollout(env, policy, p, key, 1, 30))(jax.random.PRNGKey(1))
    steps = int(traj.lengths[0])
    queried = np.asarray(chunk_config(cfg, 3).model().apply(p, (traj.obs[0] - mean) / std)).reshape(-1, 3, 2)
    low, high = env.action_bounds
    expected = [np.clip(_act_reference(list(queried[:t + 1]), 0.5), low, high) for t in range(steps)]
    assert steps > 10
    np.testing.assert_allclose(traj.action[0, :steps], np.stack(expected), rtol=1e-4, atol=1e-5)
    first = np.clip(queried[:steps, 0], low, high)
    assert np.abs(np.asarray(traj.action[0, :steps]) - first).max() > 1e-3   # not merely each chunk's first action


def test_the_probe_and_the_loss_analysis_read_the_chunk_s_first_action(grid):
    params, _, _, _ = grid
    data = planted(rho=0.7)
    runtime = policy_runtime(CFG, [{"k": 3.0, "m": 0.01}] * 4)
    x = make_train(CFG).policy_input(data.obs[:, None])
    action, embedding = runtime.apply(jax.tree.map(lambda v: v[1], params), x, return_embedding=True)
    full, full_embedding = chunk_config(CFG, 3).model().apply(jax.tree.map(lambda v: v[1], params), x,
                                                              return_embedding=True)
    np.testing.assert_array_equal(action, full[:, :2])
    np.testing.assert_array_equal(embedding, full_embedding)
    probed = policy_embeddings(CFG, jax.tree.map(lambda v: v[1], params), data, jnp.arange(8), apply=runtime.apply)
    np.testing.assert_allclose(probed, embedding[:8], rtol=1e-5, atol=1e-6)
    losses = evaluate.loss_analysis(CFG, params, data, runtime=runtime)
    own = jax.vmap(lambda p: jnp.mean(jnp.sum((runtime.apply(p, x) - data.action) ** 2, axis=-1)))(params)
    np.testing.assert_allclose(losses["unweighted"], own, rtol=1e-5)


def test_at_k_1_it_acts_as_bc_so():
    env = envs.make("toycar", obs="full", episode_length=40)
    cfg = dataclasses.replace(CFG, obs_shape=(5,))
    keys = jax.random.split(jax.random.PRNGKey(2), 2)
    params = jax.vmap(lambda key: make_train(cfg).init_policy(key, planted()))(keys)   # two untrained BC-SO
    mean, std = jnp.full(5, 2.0), jnp.full(5, 3.0)
    runtime = policy_runtime(cfg, [{"k": 1.0, "m": 0.01}] * 2)
    chunks = evaluate.make_evaluator(env, cfg, mean, std, 2, keep_actions=True, runtime=runtime)
    bc_so = evaluate.make_evaluator(env, cfg, mean, std, 2, keep_actions=True)
    got, want = chunks(params, jax.random.PRNGKey(4)), bc_so(params, jax.random.PRNGKey(4))
    assert float(jnp.abs(want["actions"]).max()) > 0.1   # a real comparison
    np.testing.assert_array_equal(got["actions"], want["actions"])
    np.testing.assert_array_equal(got["return"], want["return"])


def test_the_knobs_refuse_bad_values_in_one_line():
    assert (ChunkKnobs().k, ChunkKnobs().m) == (100, 0.01)   # ACT's chunk size and ensemble weight
    for bad, word in (({"k": 0}, "action-chunks.k must be an integer >= 1"),
                      ({"k": 2.5}, "action-chunks.k must be an integer >= 1"),
                      ({"k": True}, "action-chunks.k must be an integer >= 1"),
                      ({"m": -0.1}, "action-chunks.m must be >= 0"),
                      ({"m": float("nan")}, "action-chunks.m must be >= 0")):
        with pytest.raises(ValueError, match=word) as e:
            ChunkKnobs(**bad)
        assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="action-chunks.k must be an integer >= 1"):
        make_action_chunks(CFG, 0)
    with pytest.raises(ValueError, match="one group's policies must share k and m"):
        policy_runtime(CFG, [{"k": 3.0, "m": 0.01}, {"k": 3.0, "m": 0.1}])


def test_the_method_reads_its_knobs_and_trains_without_a_history():
    method = methods.get("action-chunks")
    assert (method.history, method.program, method.knobs, method.label) == (1, "action-chunks", ChunkKnobs,
                                                                           "ActionChunks")
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=100)
    assert method.settings(ctx) == [{"k": 100.0, "m": 0.01}]
    ctx = dataclasses.replace(ctx, knobs={"action-chunks": ChunkKnobs(k=5, m=0.1)})
    assert method.settings(ctx) == [{"k": 5.0, "m": 0.1}]
    learner = method.learner(methods.LearnerContext(cfg=CFG, env=None, expert=None, obs_mean=None, obs_std=None,
                                                    n_train=100, knobs=ctx.knobs))
    state = learner.init(jax.random.PRNGKey(0), method.hparams({"k": 5.0, "m": 0.1}, 1e-3, 0), planted())
    assert learner.policy_params(state)["params"]["Head_0"]["action"]["kernel"].shape == (300, 10)


@pytest.mark.slow
def test_a_smoke_sweep_keeps_their_policies_apart_evaluates_them_again_and_films_one(tmp_path, capsys):
    """BC-SO, ActionChunks (both history 1) and Priming: one evaluation group each, probed, saved, evaluated again
    from the saved policies through their runtimes with every recorded number as recorded, and filmed."""
    data, out = tmp_path / "data", tmp_path / "out"
    # at the knobs' defaults: `experiments.evaluate` refuses a file that records `settings.knobs` (its `spec_of`
    # lists no methods, and the spec refuses knobs of methods it does not run)
    assert sweep.main(["--env", "toycar", "--obs", "full", "--quiet", "--methods", "bc-so,action-chunks,priming",
                       "--smoke", "--out", str(out), "--data-dir", str(data)]) == 0
    runs = {r["method"]: r for r in json.loads((out / "results.json").read_text())["runs"]}
    assert runs["action-chunks"]["hparams"] == {"k": 100.0, "m": 0.01} and runs["priming"]["hparams"] == {"weight": 1.0}
    for method in ("action-chunks", "priming"):
        assert runs[method]["status"] == "ok" and np.isfinite(runs[method]["diagnostics"]["prev_from_embedding"])
    saved = ckpt_lib.load_policies(out / "params")
    assert {name: [r["method"] for r in g["runs"]] for name, g in saved.items()} == {
        "h1": ["bc-so"], "h1-action-chunks": ["action-chunks"], "h2-priming": ["priming"]}
    # Priming's prime (its default source, `bc-so`) is the sweep's own BC-SO policy of the same seed, as trained
    jax.tree.map(np.testing.assert_array_equal, saved["h2-priming"]["params"]["params"]["prime"],
                 saved["h1"]["params"]["params"])
    capsys.readouterr()
    assert evaluate_cli.main([str(out), "--data-dir", str(data), "--out", str(tmp_path / "again.json")]) == 0
    assert "every recorded return and metric came out as recorded" in capsys.readouterr().out
    assert evaluate_cli.main([str(out), "--data-dir", str(data), "--video", "action-chunks",
                              "--video-out", str(tmp_path / "chunks.gif")]) == 0
    assert (tmp_path / "chunks.gif").stat().st_size > 0


@pytest.mark.parametrize("args, message", [
    (["--set", "action-chunks.k=0"], "action-chunks.k must be an integer >= 1"),
    (["--set", "action-chunks.m=-1"], "action-chunks.m must be >= 0"),
])
def test_the_sweep_refuses_bad_knobs_in_one_line_before_any_work(tmp_path, capsys, args, message):
    assert_sweep_refuses(tmp_path, capsys, ["--env", "toycar", "--obs", "full", "--quiet", "--methods", "action-chunks",
                                            *args], message)
