"""Copycat diagnostics: a planted copycat is called one, a state reader is not; the probe; the policy's embeddings.

The synthetic world: the expert's action is a point on the unit circle, `a_t = (sin θ_t, cos θ_t)`, its
hidden phase θ turning at a per-segment speed and jumping at noise-free changepoints the past actions
cannot foresee. The observation is a position, `x_{t+1} = x_t + a_t` from a random start: one observation
says nothing about `a_t`, a history of two gives `a_{t−1} = x_t − x_{t−1}` (the copycat's shortcut).
"""

import dataclasses
import math
from typing import NamedTuple
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import diagnostics as dg
from ape_jax.history import history_index
from ape_jax.learner import Data, LearnerConfig, make_train

EPISODES, LENGTH, TRAIN_EPISODES = 24, 100, 16   # demonstrations: 16 episodes train the probes, 8 score them
ROLLOUTS, ROLLOUT_LENGTH = 16, 150               # rollouts per side: ψ fits on 8, scores on 8
# The fits shrunk for a CPU test (the defaults: 2,000 steps, ψ's batch 512); on this world the ratios move by
# a few percent between 500 and 2,000 steps.
PROBE_STEPS, PSI_STEPS, PSI_BATCH = 800, 800, 256


SMOOTH, JERKY = (0.1, 0.4), (1.0, 2.0)   # the expert's turning speeds |ω| per step: a_t tells a_{t−1} well, or not


def _speed(rng, speeds: tuple[float, float] = SMOOTH) -> float:
    return float(rng.choice([-1.0, 1.0]) * rng.uniform(*speeds))


def _expert_phases(rng, episodes: int, length: int, mean_segment: float = 10.0,
                   speeds: tuple[float, float] = SMOOTH, with_speed: bool = False):
    """The expert's hidden phase `[E, T]`: it turns by ω per step; at a changepoint (probability
    1/mean_segment per step) it jumps by U(π/2, 3π/2) and ω is redrawn (|ω| in `speeds`, either sign).
    With `with_speed`, also each step's ω `[E, T]` (the speed it turned by to get there, but at a changepoint)."""
    theta, omega = np.empty((episodes, length)), np.empty((episodes, length))
    for e in range(episodes):
        th, w = rng.uniform(0.0, 2 * math.pi), _speed(rng, speeds)
        for t in range(length):
            if t > 0 and rng.random() < 1.0 / mean_segment:
                th, w = th + rng.uniform(0.5 * math.pi, 1.5 * math.pi), _speed(rng, speeds)
            elif t > 0:
                th += w
            theta[e, t], omega[e, t] = th, w
    return (theta, omega) if with_speed else theta


def _on_circle(theta: np.ndarray) -> np.ndarray:
    return np.stack([np.sin(theta), np.cos(theta)], axis=-1).astype(np.float32)


def _held_actions(rng, episodes: int, length: int, mean_hold: float = 40.0) -> np.ndarray:
    """A copycat's rollouts `[E, T, 2]`: an action held for geometric spells (mean `mean_hold` steps), then a
    fresh one anywhere on the circle: piecewise constant."""
    theta = np.empty((episodes, length))
    for e in range(episodes):
        th = rng.uniform(0.0, 2 * math.pi)
        for t in range(length):
            if t > 0 and rng.random() < 1.0 / mean_hold:
                th = rng.uniform(0.0, 2 * math.pi)
            theta[e, t] = th
    return _on_circle(theta)


class World(NamedTuple):
    data: Data              # the demonstrations, obs = positions [M, 2]
    theta: np.ndarray       # [M] the expert's hidden phase
    train: np.ndarray       # rows of the probes' training episodes
    val: np.ndarray         # rows of the held-out episodes
    expert_rollouts: np.ndarray  # [ROLLOUTS, ROLLOUT_LENGTH, 2], fresh expert episodes
    omega: np.ndarray | None = None  # [M] the expert's speed at each step


def _world(speeds: tuple[float, float] = SMOOTH) -> World:
    rng = np.random.default_rng(0)
    theta, omega = _expert_phases(rng, EPISODES, LENGTH, speeds=speeds, with_speed=True)
    action = _on_circle(theta)
    start = rng.normal(scale=3.0, size=(EPISODES, 1, 2))
    obs = start + np.concatenate([np.zeros((EPISODES, 1, 2)), np.cumsum(action, axis=1)[:, :-1]], axis=1)
    t = np.tile(np.arange(LENGTH, dtype=np.int32), EPISODES)
    data = Data(obs=jnp.asarray(obs.reshape(-1, 2), jnp.float32), action=jnp.asarray(action.reshape(-1, 2)),
                t=jnp.asarray(t), ape=jnp.zeros(EPISODES * LENGTH))
    rows = np.arange(EPISODES * LENGTH, dtype=np.int32)
    split = TRAIN_EPISODES * LENGTH
    expert_rollouts = _on_circle(_expert_phases(np.random.default_rng(1), ROLLOUTS, ROLLOUT_LENGTH, speeds=speeds))
    return World(data, theta.reshape(-1), rows[:split], rows[split:], expert_rollouts, omega.reshape(-1))


@pytest.fixture(scope="module")
def world() -> World:
    return _world()


def _history(data: Data, rows: np.ndarray) -> jax.Array:
    """`[B, 2, 2]`: the last two positions of each row, as the learner builds histories."""
    return data.obs[history_index(data.t, jnp.asarray(rows), 2)]


def _copycat_embedding(world: World, rows: np.ndarray) -> jax.Array:
    """A linear map of the history, `L (x_t − x_{t−1}) = L a_{t−1}`: the previous action, 16 units."""
    mix = jax.random.normal(jax.random.PRNGKey(10), (2, 16))
    h = _history(world.data, rows)
    return (h[:, 1] - h[:, 0]) @ mix


def _reader_embedding(world: World, rows: np.ndarray) -> jax.Array:
    """Features of the expert's state (its phase) and of the current observation, mixed to 16 units."""
    th = world.theta[rows]
    state = np.stack([np.sin(th), np.cos(th), np.sin(2 * th), np.cos(2 * th)], axis=-1)
    mix_state = jax.random.normal(jax.random.PRNGKey(11), (4, 16))
    mix_obs = 0.1 * jax.random.normal(jax.random.PRNGKey(12), (2, 16))
    return jnp.asarray(state, jnp.float32) @ mix_state + world.data.obs[rows] @ mix_obs


def _probe(world: World, embed: Callable[[World, np.ndarray], jax.Array], key: jax.Array) -> dg.EmbeddingProbe:
    """The embedding probe, its rows chosen as `probe_inputs` chooses them."""
    sides = []
    for rows in (world.train, world.val):
        rows = dg.previous_action_rows(world.data.replace(rows=jnp.asarray(rows)))
        sides.append((embed(world, rows), world.data.action[rows - 1], world.data.action[rows]))
    (e_tr, p_tr, c_tr), (e_va, p_va, c_va) = sides
    return dg.embedding_probe(key, e_tr, e_va, p_tr, p_va, c_tr, c_va, steps=PROBE_STEPS)


def test_the_copycat_embedding_is_the_previous_action_read_off_the_history(world):
    rows = dg.previous_action_rows(world.data)
    assert rows.min() >= 1 and np.all(np.asarray(world.data.t)[rows] >= 1)
    h = _history(world.data, rows)
    np.testing.assert_allclose(h[:, 1] - h[:, 0], world.data.action[rows - 1], atol=1e-4)


def test_a_planted_copycat_is_called_a_copycat(world):
    key_probe, key_psi = jax.random.split(jax.random.PRNGKey(0))
    probe = _probe(world, _copycat_embedding, key_probe)
    copycat_rollouts = _held_actions(np.random.default_rng(3), ROLLOUTS, ROLLOUT_LENGTH)
    pred = dg.rollout_predictability(key_psi, copycat_rollouts, world.expert_rollouts, steps=PSI_STEPS,
                                     batch=PSI_BATCH)
    v = dg.verdict(probe, pred)
    assert v.label == "copycat", (probe, pred, v.reasons)
    assert v.embedding_held and v.predictability_held
    assert float(probe.ratio) < 0.1, probe            # a_{t−1} is in the embedding exactly
    assert float(probe.prev_from_action) > 0.05, probe  # and a_t alone does not give it
    assert pred.ratio < 0.4, pred
    assert pred.train_rows == pred.val_rows == (ROLLOUTS // 2) * ROLLOUT_LENGTH


def test_a_state_reader_that_acts_like_the_expert_is_not_a_copycat(world):
    key_probe, key_psi = jax.random.split(jax.random.PRNGKey(1))
    probe = _probe(world, _reader_embedding, key_probe)
    reader_rollouts = _on_circle(_expert_phases(np.random.default_rng(2), ROLLOUTS, ROLLOUT_LENGTH))
    pred = dg.rollout_predictability(key_psi, reader_rollouts, world.expert_rollouts, steps=PSI_STEPS,
                                     batch=PSI_BATCH)
    v = dg.verdict(probe, pred)
    assert v.label == "not copycat", (probe, pred, v.reasons)
    assert not v.embedding_held and not v.predictability_held
    assert float(probe.ratio) > 0.8, probe
    assert 0.7 < pred.ratio < 1.5, pred


def _no_history_embedding(mix_seed: int):
    """A policy without a history that reads the expert's state well (BC-SO at its best): features of the phase
    and of where the phase came from (`θ_t − ω_t`, as a velocity tells the previous state), mixed to 16 units.
    It knows `a_{t−1}` but at changepoints, whatever the expert; `mix_seed` makes another seed of it."""
    def embed(world: World, rows: np.ndarray) -> jax.Array:
        th, before = world.theta[rows], world.theta[rows] - world.omega[rows]
        state = np.stack([np.sin(th), np.cos(th), np.sin(before), np.cos(before)], axis=-1)
        mix = jax.random.normal(jax.random.PRNGKey(mix_seed), (4, 16))
        return jnp.asarray(state, jnp.float32) @ mix + 0.1 * world.data.obs[rows] @ mix[:2]
    return embed


@pytest.mark.parametrize("speeds", [SMOOTH, JERKY], ids=["smooth expert", "jerky expert"])
def test_a_no_history_policy_is_never_a_copycat_and_a_planted_one_is_whatever_the_expert(speeds):
    """The controlled verdict does not move with the expert. Against `a_t` alone (the first verdict) the same
    no-history policy's embedding ratio crosses 0.5 when only the expert's autocorrelation changes; against the
    no-history control (two other seeds of it) it stays near 1, and the planted copycat stays far below 0.25."""
    world = _world(speeds)
    rows = [dg.previous_action_rows(world.data.replace(rows=jnp.asarray(r))) for r in (world.train, world.val)]
    prev = [world.data.action[r - 1] for r in rows]
    key = jax.random.PRNGKey(6)

    def prev_from(x) -> float:   # the probe's held-out MSE of a_{t−1} (`prev_from_embedding`), one fit
        return float(dg.probe_target(key, x(rows[0]), x(rows[1]), *prev, steps=400).mse)

    from_action = prev_from(lambda r: world.data.action[r])      # the first verdict's reference: a_t alone
    control = [prev_from(lambda r, s=s: _no_history_embedding(20 + s)(world, r)) for s in range(2)]
    bc_so = prev_from(lambda r: _no_history_embedding(30)(world, r))
    copycat = prev_from(lambda r: _copycat_embedding(world, r))
    first = bc_so / from_action
    assert (first > 0.6) if speeds == SMOOTH else (first < 0.4), (bc_so, from_action)
    ratios = dg.control_ratio(np.array([bc_so, copycat]), control)
    assert 0.7 < ratios[0] < 1.4 and ratios[1] < 0.05, ratios
    rollouts = _held_actions(np.random.default_rng(3), ROLLOUTS, ROLLOUT_LENGTH)   # the copycat's: piecewise held
    pred = dg.rollout_predictability(jax.random.PRNGKey(7), rollouts, world.expert_rollouts, steps=PSI_STEPS,
                                     batch=PSI_BATCH)
    assert dg.controlled_verdict(ratios[1], pred.ratio, sees_past=True).label == "copycat", pred
    # the no-history policy acting as smoothly as the copycat: never a copycat, and its ratio would not say so
    v = dg.controlled_verdict(ratios[0], pred.ratio, sees_past=False)
    assert v.label == "not copycat" and not v.embedding_held and "never a copycat" in v.reasons[0]
    assert dg.controlled_verdict(ratios[0], pred.ratio, sees_past=True).label == "not copycat"


def test_the_control_ratio_divides_by_the_median_of_the_controls_seeds():
    np.testing.assert_allclose(dg.control_ratio([0.2, 0.4], [0.5, 0.4, 100.0, np.nan]), [0.4, 0.8])
    assert dg.control_ratio(0.2, [0.1]).shape == ()
    assert np.isnan(dg.control_ratio([0.2], [np.nan])).all() and np.isnan(dg.control_ratio([0.2], [])).all()


@pytest.mark.parametrize("control, predictability, sees_past, label, held", [
    (0.1, 0.2, True, "copycat", (True, True)),
    (0.25, 0.5, True, "copycat", (True, True)),          # at the thresholds counts
    (0.3, 0.2, True, "not copycat", (False, True)),      # reads its past for the state, no more
    (0.1, 0.9, True, "not copycat", (True, False)),      # holds a_{t−1}, acts like the expert
    (0.1, 0.2, False, "not copycat", (False, False)),    # no past in view: never
    (float("nan"), 0.2, True, "not copycat", (False, True)),
])
def test_the_controlled_verdict_needs_both_criteria_and_a_past(control, predictability, sees_past, label, held):
    v = dg.controlled_verdict(control, predictability, sees_past)
    assert (v.label, (v.embedding_held, v.predictability_held)) == (label, held)
    assert len(v.reasons) == (2 if sees_past else 1)


def test_the_state_reference_separates_reading_the_state_from_copying(world):
    """`diagnose`'s state reference: `a_{t−1}` from the true state at t (here the phase's features). The copycat's
    embedding holds `a_{t−1}` far beyond what the state tells; the state reader's holds what the state does."""
    def state(rows):
        th = world.theta[rows]
        return jnp.asarray(np.stack([np.sin(th), np.cos(th), np.sin(2 * th), np.cos(2 * th)], -1), jnp.float32)

    rows = [dg.previous_action_rows(world.data.replace(rows=jnp.asarray(r))) for r in (world.train, world.val)]
    key = jax.random.PRNGKey(5)
    prev = [world.data.action[r - 1] for r in rows]
    from_state = dg.probe_target(key, state(rows[0]), state(rows[1]), *prev, steps=PROBE_STEPS).mse
    ratios = {}
    for name, embed in (("copycat", _copycat_embedding), ("reader", _reader_embedding)):
        from_embedding = dg.probe_target(key, embed(world, rows[0]), embed(world, rows[1]), *prev,
                                         steps=PROBE_STEPS).mse
        ratios[name] = float(from_embedding / from_state)
    assert ratios["copycat"] < 0.2 and 0.7 < ratios["reader"] < 1.4, ratios


def test_steps_after_an_episode_ended_are_masked_out(world):
    rng = np.random.default_rng(4)
    actions = _on_circle(_expert_phases(rng, ROLLOUTS, ROLLOUT_LENGTH))
    ends = rng.integers(60, ROLLOUT_LENGTH, size=ROLLOUTS)
    valid = (np.arange(ROLLOUT_LENGTH)[None] < ends[:, None]).astype(np.float32)  # as `Trajectory.valid`
    actions = np.where(valid[..., None] > 0, actions, 3.0 * rng.normal(size=actions.shape)).astype(np.float32)
    key = jax.random.PRNGKey(2)
    fit = dict(steps=PSI_STEPS, batch=PSI_BATCH)
    masked = dg.rollout_predictability(key, actions, world.expert_rollouts, policy_valid=valid, **fit)
    unmasked = dg.rollout_predictability(key, actions, world.expert_rollouts, **fit)
    half = ROLLOUTS // 2
    assert masked.train_rows == int(valid[:half].sum()) and masked.val_rows == int(valid[half:].sum())
    assert unmasked.train_rows == half * ROLLOUT_LENGTH
    assert 0.6 < masked.ratio < 1.6, masked
    assert unmasked.ratio > 3.0 * masked.ratio, (masked, unmasked)


def test_rollout_predictability_refuses_mismatched_rollouts():
    a = np.zeros((4, 10, 2), np.float32)
    with pytest.raises(ValueError, match="E >= 2"):
        dg.rollout_predictability(jax.random.PRNGKey(0), a[:1], a, steps=1)
    with pytest.raises(ValueError, match="action dims differ"):
        dg.rollout_predictability(jax.random.PRNGKey(0), a, np.zeros((4, 10, 3), np.float32), steps=1)
    with pytest.raises(ValueError, match="valid mask"):
        dg.rollout_predictability(jax.random.PRNGKey(0), a, a, steps=1, policy_valid=np.ones((4, 9)))


# -- the probe -------------------------------------------------------------------------------------------------------

def test_the_probe_recovers_a_linear_map_whatever_the_input_scale():
    rng = np.random.default_rng(5)
    x = rng.normal(size=(1500, 6))
    y = (0.3 * x @ rng.normal(size=(6, 3))).astype(np.float32)
    x = (1000.0 * x + 50.0).astype(np.float32)  # standardised inside the probe
    params = dg.fit_probe(jax.random.PRNGKey(3), x[:1000], y[:1000])
    assert params.x_mean.shape == params.x_std.shape == (6,)
    spread = float(np.mean(np.sum((y[1000:] - y[:1000].mean(0)) ** 2, -1)))
    assert float(dg.probe_mse(params, x[1000:], y[1000:])) < 0.01 * spread


def test_the_probe_learns_nothing_from_noise_and_does_not_retrace():
    rng = np.random.default_rng(6)
    x = rng.normal(size=(1500, 6)).astype(np.float32)
    y = (0.5 * rng.normal(size=(1500, 2))).astype(np.float32)
    res = dg.probe_target(jax.random.PRNGKey(4), x[:1000], x[1000:], y[:1000], y[1000:], steps=500)
    np.testing.assert_allclose(float(res.baseline), float(np.mean(np.sum((y[1000:] - y[:1000].mean(0)) ** 2, -1))),
                               rtol=1e-4)
    assert 0.4 < float(res.baseline) < 0.6, res  # E|y|² = 2 · 0.25
    assert float(res.ratio) > 0.9, res
    compiled = dg.fit_probe._cache_size()
    again = dg.probe_target(jax.random.PRNGKey(5), x[500:1500], x[:500], y[500:1500], y[:500], steps=500)
    assert dg.fit_probe._cache_size() == compiled
    assert float(again.ratio) > 0.9, again


def test_the_probe_refuses_mismatched_rows():
    with pytest.raises(ValueError, match="same N"):
        dg.fit_probe(jax.random.PRNGKey(0), jnp.zeros((10, 3)), jnp.zeros((9, 2)), steps=1)
    with pytest.raises(ValueError, match="rows disagree"):
        z = jnp.zeros((10, 2))
        dg.embedding_probe(jax.random.PRNGKey(0), jnp.zeros((10, 4)), jnp.zeros((5, 4)), z, z[:5], z[:9], z[:5],
                           steps=1)


# -- the verdict -----------------------------------------------------------------------------------------------------

def _records(embedding_ratio: float, predictability_ratio: float) -> tuple[dg.EmbeddingProbe, dg.Predictability]:
    probe = dg.EmbeddingProbe(jnp.float32(embedding_ratio), jnp.float32(1.0), jnp.float32(embedding_ratio))
    return probe, dg.Predictability(predictability_ratio, 1.0, predictability_ratio, 100, 100)


@pytest.mark.parametrize("embedding_ratio, predictability_ratio, label, held", [
    (0.1, 0.2, "copycat", (True, True)),
    (0.5, 0.5, "copycat", (True, True)),           # at the threshold counts
    (0.1, 0.9, "not copycat", (True, False)),      # a state reader's embedding, the expert's rhythm
    (0.9, 0.2, "not copycat", (False, True)),      # smooth, but not from reading a_{t−1}
    (float("nan"), 0.2, "not copycat", (False, True)),
    (0.1, float("inf"), "not copycat", (True, False)),
])
def test_the_verdict_needs_both_criteria(embedding_ratio, predictability_ratio, label, held):
    v = dg.verdict(*_records(embedding_ratio, predictability_ratio))
    assert (v.label, (v.embedding_held, v.predictability_held)) == (label, held)
    assert len(v.reasons) == 2
    assert all(("(held)" in r) == h for r, h in zip(v.reasons, held))


def test_the_thresholds_are_fixed_and_checked():
    assert (dg.THRESHOLDS.embedding_ratio, dg.THRESHOLDS.predictability_ratio) == (0.5, 0.5)
    assert dg.THRESHOLDS.control_ratio == 0.25
    with pytest.raises(ValueError, match="control_ratio"):
        dg.Thresholds(control_ratio=0.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        dg.THRESHOLDS.embedding_ratio = 0.9
    with pytest.raises(ValueError, match="embedding_ratio"):
        dg.Thresholds(embedding_ratio=1.0)
    strict = dg.Thresholds(embedding_ratio=0.05, predictability_ratio=0.5)
    assert dg.verdict(*_records(0.1, 0.2), thresholds=strict).label == "not copycat"


# -- a real policy's embeddings --------------------------------------------------------------------------------------

def test_policy_embeddings_of_a_batchnorm_policy_use_learner_histories_and_running_statistics():
    cfg = LearnerConfig(obs_shape=(3,), action_dim=2, history=2, network="bn-mlp", iterations=1, batch_size=4,
                        lr_boundaries=())
    rng = np.random.default_rng(7)
    obs = rng.normal(size=(3 * 20, 3)).astype(np.float32)
    t = np.tile(np.arange(20, dtype=np.int32), 3)
    data = Data(obs=jnp.asarray(obs), action=jnp.asarray(rng.normal(size=(60, 2)), jnp.float32), t=jnp.asarray(t),
                ape=jnp.zeros(30), rows=jnp.arange(20, 50, dtype=jnp.int32))  # a split: rows 20..49
    model = cfg.model()
    params = model.init(jax.random.PRNGKey(0), jnp.zeros((1, 6)))
    # running statistics far from any batch's, so evaluation mode and training mode disagree
    keys = iter(jax.random.split(jax.random.PRNGKey(1), 16))
    params = {**params, "batch_stats": jax.tree.map(
        lambda s: jax.random.uniform(next(keys), s.shape, minval=0.5, maxval=2.0), params["batch_stats"])}

    idx = np.array([20, 21, 33, 40, 41, 49, 0, 59], np.int32)  # episode starts (t = 0) and later steps
    emb = dg.policy_embeddings(cfg, params, data, jnp.asarray(idx))
    assert emb.shape == (8, 100) and emb.dtype == jnp.float32
    assert bool(jnp.all(jnp.isfinite(emb)))
    prev = np.where(t[idx] == 0, idx, idx - 1)
    x = np.concatenate([obs[prev], obs[idx]], axis=-1)  # [o_{t−1}, o_t], oldest first; [o_0, o_0] at t = 0
    np.testing.assert_allclose(emb, model.apply(params, jnp.asarray(x), return_embedding=True)[1], atol=1e-5)
    np.testing.assert_allclose(emb, model.apply(params, make_train(cfg).policy_input(jnp.asarray(obs[np.stack(
        [prev, idx], -1)])), return_embedding=True)[1], atol=1e-5)
    one_by_one = jnp.concatenate([dg.policy_embeddings(cfg, params, data, jnp.asarray(idx[i:i + 1]))
                                  for i in range(len(idx))])
    np.testing.assert_allclose(one_by_one, emb, atol=1e-5)  # a row does not see the batch: running statistics
    np.testing.assert_allclose(dg.policy_embeddings(cfg, params, data, jnp.asarray(idx), chunk=3), emb, atol=1e-5)
    trained_mode = model.apply(params, jnp.asarray(x), return_embedding=True, train=True,
                               mutable=["batch_stats"])[0][1]
    assert float(jnp.max(jnp.abs(trained_mode - emb))) > 1e-2  # so the check above can tell the modes apart

    inputs = dg.probe_inputs(cfg, params, data, chunk=7)
    rows = np.r_[21:40, 41:50]  # the split's rows but the episode starts (rows 20 and 40 have t = 0)
    assert inputs.embedding.shape == (len(rows), 100)
    np.testing.assert_allclose(inputs.previous_action, data.action[rows - 1])
    np.testing.assert_allclose(inputs.action, data.action[rows])
    np.testing.assert_allclose(inputs.embedding, dg.policy_embeddings(cfg, params, data, jnp.asarray(rows)),
                               atol=1e-5)
