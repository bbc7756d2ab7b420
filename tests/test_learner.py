"""The weighted-BC learner: fits a tiny dataset; the vmapped grid equals per-configuration runs; no recompiles."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import weighting
from ape_jax.learner import Data, Hparams, LearnerConfig, drop_history, make_train, stack_hparams
from _compare import UPDATE_RTOL, update_mismatch


# A few training steps' losses are means over the batch: relative rounding ~1e-7..1e-6, far below what
# another minibatch or weighting gives (tens of percent).
LOSS_RTOL = 1e-4


def _dataset(n_episodes=6, length=40, obs_dim=4, action_dim=2, seed=0):
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n_episodes * length, obs_dim)).astype(np.float32)
    w = rng.normal(size=(obs_dim, action_dim)).astype(np.float32)
    action = np.tanh(obs @ w)  # a function of the current observation
    t = np.tile(np.arange(length, dtype=np.int32), n_episodes)
    ape = rng.exponential(size=len(obs)).astype(np.float32)
    return Data(obs=jnp.asarray(obs), action=jnp.asarray(action), t=jnp.asarray(t), ape=jnp.asarray(ape))


CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=300, batch_size=32, lr_boundaries=(200,))
GRID = [Hparams.make("uniform", lr=1e-3), Hparams.make("step", lr=1e-3, thr=0.2, w=5.0),
        Hparams.make("softmax", lr=1e-3, tau=0.5)]


@pytest.fixture(scope="module")
def data():
    return _dataset()


def test_the_learner_fits_a_tiny_dataset(data):
    learner = make_train(CFG)
    params, metrics = jax.jit(learner.train)(jax.random.PRNGKey(0), GRID[0], data)
    assert metrics["loss"].shape == (300,)
    first, last = float(metrics["unweighted_loss"][:10].mean()), float(metrics["unweighted_loss"][-20:].mean())
    assert last < 0.2 * first, (first, last)
    full = learner.per_sample_loss(params, data, jnp.arange(len(data.t))).mean()
    assert float(full) < 0.2 * first


def test_unrolled_chunks_of_any_length_train_exactly_like_the_plain_loop(data):
    import dataclasses

    plain, unrolled = make_train(CFG), make_train(dataclasses.replace(CFG, unroll=True))
    state = jax.jit(plain.init)(jax.random.PRNGKey(0), GRID[1], data)
    run_plain, run_unrolled = jax.jit(plain.run, static_argnums=3), jax.jit(unrolled.run, static_argnums=3)
    a, ma = run_plain(state, GRID[1], data, 3)
    b, mb = run_unrolled(state, GRID[1], data, 1)  # a chunk of one iteration takes its own path
    assert int(b.step) == 1
    b, mb2 = run_unrolled(b, GRID[1], data, 2)
    assert int(a.step) == int(b.step) == 3
    np.testing.assert_allclose(ma["loss"], np.concatenate([mb["loss"], mb2["loss"]]), rtol=LOSS_RTOL)
    assert update_mismatch(b.params, a.params, state.params) < UPDATE_RTOL


def test_the_weighted_loss_uses_the_weighting(data):
    learner = make_train(CFG)
    state = learner.init(jax.random.PRNGKey(0), GRID[1], data)
    np.testing.assert_array_equal(state.static_weights, weighting.step(data.ape, 0.2, 5.0))
    _, metrics = learner.run(state, GRID[1], data, 5)
    # upweighted samples make the weighted loss differ from the unweighted one
    assert not np.allclose(metrics["loss"], metrics["unweighted_loss"])
    _, uniform = learner.run(learner.init(jax.random.PRNGKey(0), GRID[0], data), GRID[0], data, 5)
    np.testing.assert_allclose(uniform["loss"], uniform["unweighted_loss"], rtol=1e-6)


def test_history_dropout_zeros_only_past_frames_at_the_configured_rate():
    history = jnp.ones((20_000, 3, 2))  # [B, H, D]
    out = np.asarray(drop_history(jax.random.PRNGKey(0), history, 0.3))
    np.testing.assert_array_equal(out[:, -1], 1.0)             # the current frame is never dropped
    frame_zero = (out[:, :-1] == 0).all(-1)
    assert ((out[:, :-1] == 0).any(-1) == frame_zero).all()     # whole frames, never parts
    assert abs(frame_zero.mean() - 0.3) < 0.01                 # the configured rate
    assert abs(frame_zero[:, 0].mean() - frame_zero[:, 1].mean()) < 0.02
    np.testing.assert_array_equal(drop_history(jax.random.PRNGKey(0), history, 0.0), history)


def test_history_dropout_hides_the_past_from_the_learner():
    # the label is the *previous* observation: learnable from the history, not with it dropped
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(400, 1)).astype(np.float32)
    t = np.tile(np.arange(40, dtype=np.int32), 10)
    prev = np.where(t[:, None] > 0, np.roll(obs, 1, axis=0), obs)
    data = Data(obs=jnp.asarray(obs), action=jnp.asarray(prev), t=jnp.asarray(t), ape=jnp.ones(400))
    cfg = LearnerConfig(obs_shape=(1,), action_dim=1, iterations=200, batch_size=64)  # full: loss ~1e-5 by then
    learner = jax.jit(make_train(cfg).train)
    _, full = learner(jax.random.PRNGKey(0), Hparams.make(lr=1e-3), data)
    _, dropped = learner(jax.random.PRNGKey(0), Hparams.make(lr=1e-3, history_dropout=0.9), data)
    assert float(full["loss"][-50:].mean()) < 0.1
    assert float(dropped["loss"][-50:].mean()) > 3 * float(full["loss"][-50:].mean())


def test_one_vmapped_grid_run_equals_per_configuration_runs(data):
    # a few iterations: enough for every row's weighting and key to show, too few for rounding to grow
    cfg = LearnerConfig(obs_shape=(4,), action_dim=2, iterations=4, batch_size=32)
    learner = make_train(cfg)
    keys = jax.random.split(jax.random.PRNGKey(1), 6)
    grid = stack_hparams(GRID + GRID)  # 3 configs x 2 seeds
    traces = []
    run_grid = jax.jit(jax.vmap(lambda k, hp, d: (traces.append(1), learner.train(k, hp, d))[1], (0, 0, None)))
    params, metrics = run_grid(keys, grid, data)
    single = jax.jit(learner.train)
    init = jax.jit(lambda k: learner.init(k, GRID[0], data).params)  # the parameters depend on the key only
    for i in range(6):
        p_i, m_i = single(keys[i], jax.tree.map(lambda x: x[i], grid), data)
        np.testing.assert_allclose(metrics["loss"][i], m_i["loss"], rtol=LOSS_RTOL)
        np.testing.assert_allclose(metrics["unweighted_loss"][i], m_i["unweighted_loss"], rtol=LOSS_RTOL)
        row = jax.tree.map(lambda x: x[i], params)
        assert update_mismatch(row, p_i, init(keys[i])) < UPDATE_RTOL, i
        # the tolerances tell configurations apart: this row's key with the next row's weighting is far off
        p_w, m_w = single(keys[i], jax.tree.map(lambda x: x[(i + 1) % 6], grid), data)
        assert update_mismatch(row, p_w, init(keys[i])) > 10 * UPDATE_RTOL, i
        assert not np.allclose(metrics["loss"][i], m_w["loss"], rtol=10 * LOSS_RTOL), i
    run_grid(jax.random.split(jax.random.PRNGKey(2), 6), grid, data)  # new seeds: no retrace
    assert len(traces) == 1


def test_image_histories_are_stacked_on_channels_and_scaled():
    cfg = LearnerConfig(obs_shape=(8, 8, 3), action_dim=2, history=2, iterations=3, batch_size=4)
    learner = make_train(cfg)
    frames = jnp.arange(2 * 8 * 8 * 3, dtype=jnp.uint8).reshape(2, 8, 8, 3)
    x = learner.policy_input(frames[None])  # [1, H=2, 8, 8, 3]
    assert x.shape == (1, 8, 8, 6) and float(x.max()) <= 1.0
    np.testing.assert_allclose(x[0, ..., 3:], frames[1] / 255.0)
    data = Data(obs=jnp.zeros((10, 8, 8, 3), jnp.uint8), action=jnp.zeros((10, 2)), t=jnp.arange(10),
                ape=jnp.ones(10))
    params, metrics = jax.jit(learner.train)(jax.random.PRNGKey(0), Hparams.make(), data)
    assert metrics["loss"].shape == (3,) and np.all(np.isfinite(metrics["loss"]))


def test_a_dataset_smaller_than_the_batch_is_refused(data):
    learner = make_train(LearnerConfig(obs_shape=(4,), action_dim=2, batch_size=1000))
    with pytest.raises(ValueError, match="fewer than the batch size 1000"):
        learner.init(jax.random.PRNGKey(0), GRID[0], data)


def test_invalid_static_settings_are_refused():
    with pytest.raises(ValueError, match="LearnerConfig.loss 'huber' is not one of l2, l1"):
        LearnerConfig(obs_shape=(4,), action_dim=2, loss="huber")
    with pytest.raises(ValueError, match="history must be >= 1"):
        LearnerConfig(obs_shape=(4,), action_dim=2, history=0)


SHARDED = """
import jax, jax.numpy as jnp, numpy as np, sys
sys.path.insert(0, {tests!r})
from test_learner import _dataset, GRID, LOSS_RTOL, UPDATE_RTOL, update_mismatch
from ape_jax.grid import grid_runner
from ape_jax.learner import LearnerConfig, make_train, stack_hparams
assert jax.device_count() == 4, jax.devices()
learner = make_train(LearnerConfig(obs_shape=(4,), action_dim=2, iterations=4, batch_size=32))
data = _dataset()
keys = jax.random.split(jax.random.PRNGKey(1), 6)
grid = stack_hparams(GRID + GRID)          # 6 runs over 4 devices: padded to 8, trimmed back
sharded = grid_runner(learner.train)(keys, grid, data)
single = grid_runner(learner.train, devices=jax.devices()[:1])(keys, grid, data)
assert sharded[1]["loss"].shape == (6, 4)
for name in sharded[1]:
    np.testing.assert_allclose(np.asarray(sharded[1][name]), np.asarray(single[1][name]), rtol=LOSS_RTOL)
init = jax.jit(jax.vmap(lambda k: learner.init(k, GRID[0], data).params))(keys)
for i in range(6):
    row = lambda tree: jax.tree.map(lambda x: np.asarray(x[i]), tree)
    assert update_mismatch(row(sharded[0]), row(single[0]), row(init)) < UPDATE_RTOL, i
print("devices", len(sharded[0]["params"]["Head_0"]["action"]["kernel"].sharding.device_set))
"""


@pytest.mark.integration
def test_the_grid_sharded_over_four_cpu_devices_equals_the_unsharded_run():
    import os
    import pathlib
    import subprocess
    import sys

    env = dict(os.environ, JAX_PLATFORMS="cpu",
               XLA_FLAGS=os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4")
    code = SHARDED.format(tests=str(pathlib.Path(__file__).parent))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "devices 4" in out.stdout


def test_the_sequential_grid_runner_equals_the_vmapped_one_and_compiles_once():
    from ape_jax.grid import grid_runner

    # image policies on CPU train configuration by configuration, unrolled: same numbers as vmap
    data = Data(obs=jnp.asarray(np.random.default_rng(0).integers(0, 255, (64, 8, 8, 3)), jnp.uint8),
                action=jnp.asarray(np.random.default_rng(1).normal(size=(64, 2)), jnp.float32),
                t=jnp.tile(jnp.arange(16, dtype=jnp.int32), 4), ape=jnp.asarray(np.random.default_rng(2).random(64)))
    cfg = LearnerConfig(obs_shape=(8, 8, 3), action_dim=2, iterations=4, batch_size=16, unroll=True)
    learner = make_train(cfg)
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    grid = stack_hparams(GRID)
    traces = []
    sequential = grid_runner(lambda k, hp, d: (traces.append(1), learner.train(k, hp, d))[1], vectorize=False)
    seq_params, seq_metrics = sequential(keys, grid, data)
    vm_params, vm_metrics = grid_runner(learner.train)(keys, grid, data)
    assert len(traces) == 1 and seq_metrics["loss"].shape == (3, 4)
    # vmapped convolutions are grouped ones, summed in another order: equal up to rounding
    np.testing.assert_allclose(seq_metrics["loss"], vm_metrics["loss"], rtol=LOSS_RTOL)
    init = jax.jit(jax.vmap(lambda k: learner.init(k, GRID[0], data).params))(keys)
    for i in range(3):
        row = lambda tree: jax.tree.map(lambda x: x[i], tree)  # noqa: E731
        assert update_mismatch(row(seq_params), row(vm_params), row(init)) < UPDATE_RTOL, i


def test_the_learning_rate_schedules_are_optax_schedules_and_the_papers_is_unchanged():
    import dataclasses

    from ape_jax.learner import lr_schedule
    from ape_jax.pipeline.presets import SettingsError, resolve

    steps = jnp.arange(300)
    paper = jax.vmap(lr_schedule(dataclasses.replace(CFG, lr_boundaries=(100, 200))))(steps)
    passed = (steps >= 100).astype(jnp.float32) + (steps >= 200).astype(jnp.float32)
    np.testing.assert_array_equal(paper, 0.1 ** jnp.asarray(passed, jnp.float32))   # the formula before schedules
    assert (paper[0], paper[150]) == (1.0, np.float32(0.1)) and paper[250] == pytest.approx(0.01)
    constant = jax.vmap(lr_schedule(dataclasses.replace(CFG, lr_schedule="constant")))(steps)
    np.testing.assert_array_equal(constant, np.ones(300))
    cosine = np.asarray(jax.vmap(lr_schedule(dataclasses.replace(CFG, lr_schedule="cosine", warmup_steps=30)))(steps))
    assert cosine[0] == 0.0 and cosine[30] == pytest.approx(1.0) and cosine[165] == pytest.approx(0.5, abs=0.01)
    assert np.all(np.diff(cosine[:31]) > 0) and np.all(np.diff(cosine[30:]) <= 0) and cosine[-1] < 1e-3

    s = resolve("hopper", "pos", sets=["recipe.lr_schedule=cosine", "recipe.warmup=0.1"])
    cfg = s.learner_config((5,), 3, 2, "l2")
    assert (cfg.lr_schedule, cfg.warmup_steps, cfg.lr_boundaries) == ("cosine", s.budget.iterations // 10, ())
    assert resolve("hopper", "pos").learner_config((5,), 3, 2, "l2").lr_boundaries == (1000, 2000)   # quick: 3k
    for sets, message in ((["recipe.warmup=0.1"], "cosine schedule's"), (["recipe.lr_schedule=linear"], "lr_schedule"),
                          (["recipe.lr_decay=0"], "lr_decay must be in")):
        with pytest.raises(SettingsError, match=message):
            resolve("hopper", "pos", sets=sets)
