"""DAgger on ToyCar: the aggregated dataset grows by the query budget, labels are the expert's, seeds vmap,
minibatches come from the split's rows and the appended ones."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax.pipeline import collect
from ape_jax.baselines import dagger
from ape_jax.history import history_index
from ape_jax.learner import Data, Hparams, LearnerConfig, make_train, stack_hparams
from _compare import UPDATE_RTOL, update_mismatch

# a short road, so episodes end both at the goal and at the time limit
ENV_KW = dict(episode_length=50, road_length=30.0, light_range=(12.0, 20.0))
CFG = LearnerConfig(obs_shape=(5,), action_dim=2, history=2, iterations=6, batch_size=16, loss="l1")
BUDGET, ROUNDS, NUM_ENVS = 97, 3, 4   # 48 rows before round 1, 49 before round 2; 2 iterations a round

# Two programs training the same model agree up to float32 rounding only (XLA fuses and blocks each
# program's reductions its own way; Adam can turn rounding into ±lr on a component whose gradient is
# within rounding of zero), so trained parameters are compared through their update as a whole, over
# a few steps (see `tests/test_learner.py`): another minibatch, key or configuration is far outside.
LOSS_RTOL = 1e-4


@pytest.fixture(scope="module")
def setup():
    env = envs.make("toycar", obs="full", **ENV_KW)
    demos = collect.collect(env, env.expert, jax.random.PRNGKey(0), num_episodes=4)
    obs = np.asarray(demos.obs)
    mean, std = obs.mean(0), obs.std(0) + 1e-6
    data = Data(obs=jnp.asarray((obs - mean) / std), action=jnp.asarray(demos.action), t=jnp.asarray(demos.t),
                ape=jnp.zeros(len(demos), jnp.float32))
    learner = dagger.make_dagger(CFG, env, env.expert, mean, std, BUDGET, rounds=ROUNDS, num_envs=NUM_ENVS)
    return env, data, jnp.asarray(mean), jnp.asarray(std), learner


def _rounds(learner, data, key=jax.random.PRNGKey(3)):
    """`(states, trained)`: each round's state after `next_round` (round 0: after `init`), and after its training."""
    hp = Hparams.make(lr=1e-3)
    run = jax.jit(learner.run, static_argnums=3)
    nxt = jax.jit(learner.next_round)
    states, trained = [jax.jit(learner.init)(key, hp, data)], []
    for r in range(learner.rounds):
        trained.append(run(states[-1], hp, data, learner.round_iterations))
        if r + 1 < learner.rounds:
            states.append(nxt(trained[-1][0], hp, data))
    return states, trained


@pytest.fixture(scope="module")
def rounds(setup):
    return _rounds(setup[-1], setup[1])


def test_the_aggregated_dataset_grows_by_the_budget_round_by_round(setup, rounds):
    env, data, mean, std, learner = setup
    n = data.obs.shape[0]
    assert dagger.round_sizes(BUDGET, ROUNDS) == (0, 48, 49)
    states, trained = rounds
    assert [int(s.buffer.count) for s in states] == [n, n + 48, n + 97]
    assert [int(s.round) for s in states] == [0, 1, 2]
    buf = states[-1].buffer
    assert buf.obs.shape == (n + BUDGET, 5) and buf.obs.dtype == data.obs.dtype
    np.testing.assert_array_equal(buf.obs[:n], data.obs)          # the demonstrations stay
    np.testing.assert_array_equal(buf.action[:n], data.action)
    np.testing.assert_array_equal(buf.rows, np.arange(n + BUDGET))  # every row: the sampling table is the identity
    # appended rows: every round's rollout starts an episode, and time runs on or restarts at 0
    t = np.asarray(buf.t[n:])
    assert t[0] == 0 and t[48] == 0
    assert np.all((t[1:] == t[:-1] + 1) | (t[1:] == 0))
    # another call past the last round adds nothing
    hp = Hparams.make(lr=1e-3)
    assert int(jax.jit(learner.next_round)(states[-1], hp, data).buffer.count) == n + BUDGET


def test_appended_labels_are_the_experts_actions_on_the_recorded_states(setup, rounds):
    env, data, mean, std, learner = setup
    n = data.obs.shape[0]
    states, trained = rounds
    trained = trained[0][0]  # round 0's state after training, before round 1's rollout
    steps = -(-49 // NUM_ENVS)
    rec = jax.jit(lambda p, k: dagger.label_rollout(CFG, env, env.expert, mean, std, p, k, 0.5, NUM_ENVS, steps))(
        trained.params, jax.random.fold_in(trained.rollout_key, 1))
    # the buffer holds exactly the first 48 records of round 1's rollout
    np.testing.assert_allclose(states[1].buffer.obs[n:n + 48], rec.obs[:48], atol=1e-5)
    np.testing.assert_array_equal(states[1].buffer.action[n:n + 48], rec.action[:48])
    np.testing.assert_array_equal(states[1].buffer.t[n:n + 48], rec.t[:48])
    # labels = the expert on the full state; observations standardised like the demonstrations
    np.testing.assert_array_equal(rec.action, jax.vmap(env.expert)(rec.expert_obs))
    np.testing.assert_allclose(rec.obs, (rec.expert_obs - mean) / std, rtol=1e-6, atol=1e-6)
    acted = np.asarray(rec.expert_acted)
    assert 0 < acted.sum() < len(acted)  # β = 0.5: both expert and learner act


def _next_speed(env, rec, actions):
    """ToyCar's speed after each recorded step had `actions` executed: `[M]`."""
    cfg, a = env.config, np.clip(np.asarray(actions), 0.0, 1.0)
    v = np.asarray(rec.expert_obs[:, 1])
    accel = cfg.throttle_accel * a[:, 0] - cfg.brake_accel * a[:, 1] - cfg.rolling_resistance
    return np.clip(v + accel * cfg.dt, 0.0, cfg.max_speed)


def _check_speed_updates(env, rec, actions, same_episode):
    """Within an episode (`same_episode[i]`: rows i and i+1), the next speed follows from the executed action."""
    v_next = np.asarray(rec.expert_obs[1:, 1])
    expected = _next_speed(env, rec, actions)[:-1]
    np.testing.assert_allclose(v_next[same_episode], expected[same_episode], atol=1e-5)


def test_with_beta_one_the_records_are_expert_trajectories(setup):
    env, data, mean, std, learner = setup
    params = learner.init(jax.random.PRNGKey(0), Hparams.make(), data).params
    streams, steps = 4, 100  # longer than episodes: streams reset at the goal and at the time limit
    rec = jax.jit(lambda k: dagger.label_rollout(CFG, env, env.expert, mean, std, params, k, 1.0, streams, steps))(
        jax.random.PRNGKey(5))
    assert bool(rec.expert_acted.all())
    t, x = np.asarray(rec.t), np.asarray(rec.expert_obs[:, 0])
    assert np.all(t[::steps] == 0)                                   # each stream starts an episode
    within = (np.arange(streams)[:, None] * steps + np.arange(steps - 1)).ravel()  # rows i, i+1 of one stream
    same = t[within + 1] != 0
    np.testing.assert_array_equal(t[within + 1][same], t[within][same] + 1)
    restarts = within[~same]
    # a reset follows the goal or the time limit, nothing else
    v_next = _next_speed(env, rec, rec.action)[restarts]
    reached = x[restarts] + v_next * env.config.dt >= env.config.road_length - 1e-4
    assert np.all(reached | (t[restarts] == env.config.episode_length - 1))
    assert reached.any() and (t[restarts] == env.config.episode_length - 1).any()
    # the executed action was the expert's: each step's speed follows from its label
    same_episode = np.zeros(streams * steps - 1, bool)
    same_episode[within] = same
    _check_speed_updates(env, rec, rec.action, same_episode)


def test_the_learner_acts_on_its_observation_history_as_at_evaluation(setup):
    env, data, mean, std, learner = setup
    params = learner.init(jax.random.PRNGKey(1), Hparams.make(), data).params
    steps = 45
    rec = jax.jit(lambda k: dagger.label_rollout(CFG, env, env.expert, mean, std, params, k, 0.0, 1, steps))(
        jax.random.PRNGKey(6))
    assert not bool(rec.expert_acted.any())
    idx = jnp.arange(steps)
    inputs = make_train(CFG).policy_input(rec.obs[history_index(rec.t, idx, CFG.history)])
    low, high = env.action_bounds
    own = jnp.clip(CFG.model().apply(params, inputs), low, high)
    t = np.asarray(rec.t)
    _check_speed_updates(env, rec, own, t[1:] != 0)


@pytest.mark.integration
def test_train_gives_model_params_and_vmaps_over_seeds(setup, rounds):
    env, data, mean, std, learner = setup
    keys = jnp.stack([jax.random.PRNGKey(3), jax.random.PRNGKey(4)])   # seed 0 is the `rounds` fixture's
    hps = stack_hparams([Hparams.make(lr=1e-3)] * 2)
    params, metrics = jax.jit(jax.vmap(learner.train, (0, 0, None)))(keys, hps, data)
    assert metrics["loss"].shape == (2, CFG.iterations)
    assert np.all(np.isfinite(metrics["loss"]))
    np.testing.assert_array_equal(metrics["loss"], metrics["unweighted_loss"])
    # per seed, round by round (`init`, `run`, `next_round`, ... as `ape_jax.pipeline.sweep` drives it)
    for i, (states, trained) in enumerate([rounds, _rounds(learner, data, keys[1])]):
        loss_i = np.concatenate([m["loss"] for _, m in trained])
        np.testing.assert_allclose(metrics["loss"][i], loss_i, rtol=LOSS_RTOL)
        row = jax.tree.map(lambda x: x[i], params)
        reference = learner.policy_params(trained[-1][0])
        assert update_mismatch(row, reference, learner.policy_params(states[0])) < UPDATE_RTOL, i
    x = make_train(CFG).policy_input(data.obs[history_index(data.t, jnp.arange(8), CFG.history)])
    out = CFG.model().apply(jax.tree.map(lambda p: p[0], params), x)
    assert out.shape == (8, 2) and np.all(np.isfinite(out))
    # the seeds differ, so their rollouts and policies do too
    assert not np.allclose(metrics["loss"][0], metrics["loss"][1])


def test_budget_zero_is_bc_in_rounds(setup):
    """With no expert query DAgger is `make_train`'s BC-OH (uniform weights), trained in warm-started rounds.

    Same key, same settings: DAgger's `init` splits its key into (network, minibatches, rollouts),
    `make_train`'s into (network, minibatches); with jax's partitionable threefry (the default since
    jax 0.5) `split(key, 3)[:2] == split(key, 2)`, so both draw the same initial parameters and the
    same minibatches, `fold_in(minibatch key, step)` with the step counter running on across rounds.
    The losses are the same per-sample loss averaged over the batch and the updates the same Adam
    step, so the two trainings are the same computation. The programs differ (BC multiplies by its
    weights, all exactly 1; DAgger reads its buffer) and XLA may fuse their reductions differently
    (BC's own weighted and unweighted losses, equal in exact arithmetic, can differ in the last bit):
    bit-equality is not guaranteed, equality up to rounding is.
    """
    env, data, mean, std, _ = setup
    # the learning rate decays within the run (after step 4, in the last round): the schedule must carry over
    cfg = dataclasses.replace(CFG, lr_boundaries=(4, 8))
    learner = dagger.make_dagger(cfg, env, env.expert, mean, std, budget=0, rounds=ROUNDS, num_envs=NUM_ENVS)
    key, hp = jax.random.PRNGKey(3), Hparams.make(lr=1e-3)  # `_rounds`'s key and learning rate
    states, trained = _rounds(learner, data, key)
    n = data.obs.shape[0]
    assert [int(s.buffer.count) for s in states] == [n] * ROUNDS       # no row is ever added
    final = trained[-1][0]
    assert int(final.step) == cfg.iterations == ROUNDS * learner.round_iterations
    np.testing.assert_array_equal(final.buffer.obs, data.obs)        # the buffer is the demonstrations
    np.testing.assert_array_equal(final.buffer.action, data.action)

    bc = make_train(cfg)
    assert np.array_equal(jax.random.split(key, 3)[:2], jax.random.split(key, 2)), \
        "jax_threefry_partitionable is off: DAgger's and BC's keys differ, so do their trainings"
    bc_start = jax.jit(bc.init)(key, hp, data)
    np.testing.assert_array_equal(states[0].key, bc_start.key)       # the same minibatch key
    for a, b in zip(jax.tree.leaves(states[0].params), jax.tree.leaves(bc_start.params)):
        np.testing.assert_allclose(a, b, rtol=1e-6)                  # the same initial network
    bc_end, bc_metrics = jax.jit(bc.run, static_argnums=3)(bc_start, hp, data, cfg.iterations)  # = bc.train
    loss = np.concatenate([m["loss"] for _, m in trained])
    np.testing.assert_allclose(loss, bc_metrics["unweighted_loss"], rtol=LOSS_RTOL)
    np.testing.assert_allclose(loss, bc_metrics["loss"], rtol=LOSS_RTOL)  # uniform weights
    assert update_mismatch(learner.policy_params(final), bc_end.params, bc_start.params) < UPDATE_RTOL
    # Adam's moments carried over the rounds too: the same step count, the same first and second moments
    adam, bc_adam = final.opt_state, bc_end.opt_state
    assert int(adam.count) == int(bc_adam.count) == cfg.iterations
    for moment in ("mu", "nu"):
        zeros = jax.tree.map(jnp.zeros_like, getattr(bc_adam, moment))
        assert update_mismatch(getattr(adam, moment), getattr(bc_adam, moment), zeros) < UPDATE_RTOL, moment


def test_minibatches_come_from_the_split_rows_and_the_appended_rows(setup):
    """Episodes 1 and 3 are outside the split, with actions of 1e3: one drawn row of them would blow the loss up."""
    env, data, mean, std, learner = setup
    n, t = data.obs.shape[0], np.asarray(data.t)
    episode = np.cumsum(t == 0) - 1
    assert episode[-1] == 3
    rows = np.random.default_rng(0).permutation(np.flatnonzero(np.isin(episode, [0, 2]))).astype(np.int32)
    action = np.where(np.isin(episode, [0, 2])[:, None], np.asarray(data.action), 1e3).astype(np.float32)
    split = Data(obs=data.obs, action=jnp.asarray(action), t=data.t, ape=jnp.zeros(len(rows), jnp.float32),
                 rows=jnp.asarray(rows))
    states, trained = _rounds(learner, split)
    k = len(rows)
    assert [int(s.buffer.count) for s in states] == [k, k + 48, k + 97]
    buf = states[-1].buffer
    np.testing.assert_array_equal(buf.obs[:n], data.obs)             # whole episodes: histories read them
    np.testing.assert_array_equal(buf.rows[:k], rows)                # the split's rows, then the appended ones
    np.testing.assert_array_equal(buf.rows[k:], n + np.arange(BUDGET))
    np.testing.assert_array_equal(states[1].buffer.rows[k:k + 48], n + np.arange(48))
    assert int(buf.t[n]) == 0 and int(buf.t[n + 48]) == 0            # each round's rollout starts an episode
    loss = np.concatenate([np.asarray(metrics["loss"]) for _, metrics in trained])
    assert loss.shape == (CFG.iterations,) and np.all(loss < 10.0), loss


def test_image_observations_are_recorded_raw():
    env = envs.make("toycar", obs="image", image_size=(16, 16), **ENV_KW)
    cfg = LearnerConfig(obs_shape=(16, 16, 3), action_dim=2, history=2, iterations=4, batch_size=4, loss="l1")
    learner = dagger.make_dagger(cfg, env, env.expert, None, None, budget=10, rounds=2, num_envs=2)
    data = Data(obs=jnp.zeros((8, 16, 16, 3), jnp.uint8), action=jnp.zeros((8, 2)), t=jnp.arange(8),
                ape=jnp.zeros(8))
    hp = Hparams.make()
    state = jax.jit(lambda k: learner.next_round(learner.init(k, hp, data), hp, data))(jax.random.PRNGKey(0))
    buf = state.buffer
    assert buf.obs.dtype == jnp.uint8 and int(buf.count) == 18
    assert int(buf.obs[8:].astype(jnp.int32).sum()) > 0
    rec = jax.jit(lambda p, k: dagger.label_rollout(cfg, env, env.expert, None, None, p, k, 0.5, 1, 5))(
        state.params, jax.random.PRNGKey(0))
    sims = envs.toycar.ToyCarSim(*[rec.expert_obs[:, i] for i in range(5)], t=jnp.zeros(5, jnp.int32),
                                 key=jnp.zeros((5, 2), jnp.uint32))
    frames = jax.jit(jax.vmap(env.observe_sim))(sims)
    np.testing.assert_array_equal(rec.obs, frames)


def test_bad_arguments_are_refused(setup):
    env, data, mean, std, _ = setup
    make = lambda **kw: dagger.make_dagger(CFG, env, env.expert, mean, std, **{"budget": 8, **kw})  # noqa: E731
    with pytest.raises(ValueError, match="budget >= 0"):
        make(budget=-1)
    with pytest.raises(ValueError, match="rounds >= 2"):
        make(rounds=1)
    with pytest.raises(ValueError, match="num_envs >= 1"):
        make(num_envs=0)
    with pytest.raises(ValueError, match="beta must be in"):
        make(beta=1.5)
    with pytest.raises(ValueError, match="iterations >= rounds"):
        dagger.make_dagger(LearnerConfig(obs_shape=(5,), action_dim=2, iterations=2), env, env.expert, mean, std,
                           budget=8, rounds=3)
    with pytest.raises(ValueError, match="the learner expects"):
        dagger.make_dagger(LearnerConfig(obs_shape=(4,), action_dim=2), env, env.expert, mean, std, budget=8)
