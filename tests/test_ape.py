"""APE: near zero on predictable actions, peaks at a planted change of action."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import ape


def _episodes(actions_per_episode):
    actions = np.concatenate(actions_per_episode).astype(np.float32)
    t = np.concatenate([np.arange(len(a)) for a in actions_per_episode]).astype(np.int32)
    return jnp.asarray(actions), jnp.asarray(t)


def test_past_actions_are_oldest_first_and_padded_with_the_episode_start():
    actions, t = _episodes([np.arange(4.0)[:, None], 10 + np.arange(3.0)[:, None]])
    x = ape.past_actions(actions, t, jnp.array([0, 2, 5, 6]), k=3)
    np.testing.assert_array_equal(x, [[0, 0, 0], [0, 0, 1], [10, 10, 10], [10, 10, 11]])


@pytest.fixture(scope="module")
def planted():
    # 8 episodes of 100 steps: action (0.5, -0.5) until a random step in [30, 70), then (-0.5, 0.5)
    rng = np.random.default_rng(0)
    eps, changes = [], []
    for _ in range(8):
        c = int(rng.integers(30, 70))
        a = np.where(np.arange(100)[:, None] < c, [0.5, -0.5], [-0.5, 0.5])
        eps.append(a)
        changes.append(c)
    actions, t = _episodes(eps)
    params, losses = jax.jit(lambda k: ape.fit(k, actions, t, steps=400, batch=128))(jax.random.PRNGKey(0))
    return actions, t, changes, ape.errors(params, actions, t), losses


def test_fit_reduces_the_prediction_loss(planted):
    *_, losses = planted
    assert float(losses[-50:].mean()) < 0.2 * float(losses[:10].mean())


def test_ape_peaks_exactly_at_the_planted_change_and_is_near_zero_elsewhere(planted):
    _, t, changes, errors, _ = planted
    errors = np.asarray(errors).reshape(8, 100)
    for episode, c in enumerate(changes):
        assert int(np.argmax(errors[episode])) == c
        assert errors[episode, c] > 1.0  # the squared distance between the two actions is 2
        quiet = np.delete(errors[episode], np.arange(c, c + 9))  # ψ has seen the change within 9 steps
        assert quiet.max() < 0.05


def test_ape_is_near_zero_on_a_constant_action_demonstration():
    actions, t = _episodes([np.tile([0.3, -0.2, 0.9], (60, 1))] * 4)
    params, _ = ape.fit(jax.random.PRNGKey(1), actions, t, steps=300, batch=64)
    assert float(ape.errors(params, actions, t).max()) < 1e-3


def test_normalize_divides_by_the_training_mean():
    tr, va, scale = ape.normalize(jnp.array([1.0, 3.0]), jnp.array([4.0]), "mean")
    assert scale == 2.0 and tr.tolist() == [0.5, 1.5] and va.tolist() == [2.0]
    assert ape.normalize(jnp.array([1.0, 3.0]), jnp.array([4.0]), "none")[2] == 1.0
    with pytest.raises(ValueError, match="unknown APE normalization"):
        ape.normalize(jnp.ones(2), jnp.ones(1), "max")
    with pytest.raises(ValueError, match="perfectly predictable"):
        ape.normalize(jnp.zeros(2), jnp.ones(1), "mean")
