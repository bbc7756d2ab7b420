"""PTP: the past targets are the previous actions, the first repeated at an episode's start; at weight 0 the policy
trains as BC-OH's; a grid of weights × seeds trains in one call, a weight making the embedding hold the past that
BC-OH's lets go; on images it trains a plain image policy; its knobs are refused in one line, through the sweep too,
before any work. (`tests/test_channel_dropout.py` runs it through a tiny sweep beside ChannelDropout.)"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import methods, tasks
from ape_jax.baselines.ptp import DEFAULT_WEIGHT, PastHead, PtpHparams, PtpKnobs, make_ptp, past_actions
from ape_jax.learner import Hparams, LearnerConfig, make_train, stack_hparams
from ape_jax.models import PatchPolicy
from _compare import update_mismatch
from _planted import planted
from _refusal import assert_sweep_refuses

CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=100, batch_size=64, lr_boundaries=(),
                    beta1=0.5)


def test_the_past_targets_are_the_previous_actions_repeating_the_first_at_an_episode_start():
    data = planted(episodes=2, length=5)
    a = np.asarray(data.action)
    got = np.asarray(past_actions(data, jnp.array([0, 1, 4, 5, 7]), 3))
    want = a[[[0, 0, 0], [0, 0, 0], [1, 2, 3], [5, 5, 5], [5, 5, 6]]]   # oldest first; rows 5.. are episode 2
    np.testing.assert_array_equal(got, want)
    head = PastHead(action_dim=2, past=3)
    out = head.apply(head.init(jax.random.PRNGKey(0), jnp.zeros((1, 100))), jnp.zeros((7, 100)))
    assert out.shape == (7, 3, 2)


def test_at_weight_0_ptp_trains_bc_oh():
    """BC-OH's initialisation and run key from the key's first half (MINE's convention), its batches, loss and
    updates: its policy (BatchNorm's statistics too) up to float32 rounding (`tests/_compare.py`); the past head
    learns beside it all the same."""
    cfg, data, key = dataclasses.replace(CFG, iterations=20, network="bn-mlp"), planted(), jax.random.PRNGKey(3)
    params, metrics = jax.jit(make_ptp(cfg).train)(key, PtpHparams.make(0.0, lr=1e-3), data)
    policy_key = jax.random.split(key)[0]
    bc_oh, _ = jax.jit(make_train(cfg).train)(policy_key, Hparams.make(lr=1e-3), data)
    init = make_train(cfg).init_policy(jax.random.split(policy_key)[0], data)
    assert jax.tree.structure(params) == jax.tree.structure(bc_oh)
    assert update_mismatch(params, bc_oh, init) < 1e-4
    np.testing.assert_array_equal(metrics["loss"], metrics["unweighted_loss"])
    past = np.asarray(metrics["past_loss"])
    assert past[-5:].mean() < 0.5 * past[:5].mean()


def test_a_grid_of_two_weights_by_two_seeds_trains_in_one_call_each_weight_as_it_should():
    """Weights 0 and 1 × seeds 0 and 1 in one `jit(vmap(train))`, predicting a_{t−2} and a_{t−1}. The planted
    expert's a_t reads neither, so BC-OH's embedding (weight 0: BC-OH's policy for its seed) lets the past go and
    the head reads it back poorly; at weight 1 the embedding keeps it (measured: the head's error about a third of
    weight 0's after 100 updates)."""
    data = planted()
    keys = jnp.stack([jax.random.PRNGKey(s) for s in (0, 1, 0, 1)])
    hp = stack_hparams([PtpHparams.make(w, lr=1e-3) for w in (0.0, 0.0, 1.0, 1.0)])
    params, metrics = jax.jit(jax.vmap(make_ptp(CFG, past=2).train, (0, 0, None)))(keys, hp, data)
    policy_keys = jnp.stack([jax.random.split(k)[0] for k in keys[:2]])
    bc_oh, _ = jax.jit(jax.vmap(make_train(CFG).train, (0, 0, None)))(
        policy_keys, stack_hparams([Hparams.make(lr=1e-3)] * 2), data)
    past = np.asarray(metrics["past_loss"])[:, -20:].mean(axis=1)
    for seed in (0, 1):
        init = make_train(CFG).init_policy(jax.random.split(policy_keys[seed])[0], data)
        reference = jax.tree.map(lambda leaf: leaf[seed], bc_oh)
        assert update_mismatch(jax.tree.map(lambda leaf: leaf[seed], params), reference, init) < 1e-4
        assert update_mismatch(jax.tree.map(lambda leaf: leaf[2 + seed], params), reference, init) > 0.01
        assert past[2 + seed] < 0.7 * past[seed], past
    loss, bc = np.asarray(metrics["loss"]), np.asarray(metrics["unweighted_loss"])
    np.testing.assert_allclose(loss[2:], bc[2:] + np.asarray(metrics["past_loss"])[2:], rtol=1e-6)


def test_on_images_ptp_trains_a_plain_patch_policy():
    cfg = LearnerConfig(obs_shape=(32, 32, 3), action_dim=3, history=2, iterations=3, batch_size=8, encoder="patch")
    rng = np.random.default_rng(0)
    data = dataclasses.replace(planted(episodes=4, length=8), obs=jnp.asarray(rng.integers(0, 256, (32, 32, 32, 3),
                                                                                           np.uint8)),
                               action=jnp.asarray(rng.uniform(-1, 1, (32, 3)), jnp.float32))
    learner = make_ptp(cfg, past=2)
    params, metrics = jax.jit(learner.train)(jax.random.PRNGKey(0), PtpHparams.make(1.0), data)
    assert isinstance(cfg.model(), PatchPolicy)
    fresh = learner.init_policy(jax.random.PRNGKey(1), data)
    assert jax.tree.map(jnp.shape, params) == jax.tree.map(jnp.shape, fresh)   # the policy alone, no head
    assert np.all(np.isfinite(np.asarray(metrics["past_loss"])))


def test_the_knobs_refuse_bad_values_in_one_line():
    for kw, message in (({"past": 0}, "ptp.past must be an integer >= 1"), ({"past": True}, "ptp.past must be"),
                        ({"past": 1.5}, "ptp.past must be"), ({"weights": (-1.0,)}, "ptp.weights must be >= 0"),
                        ({"weights": (float("inf"),)}, "ptp.weights must be >= 0 and finite"),
                        ({"weights": ()}, "at least one"), ({"weights": (1.0, 1.0)}, "each weight once")):
        with pytest.raises(ValueError, match=message) as e:
            PtpKnobs(**kw)
        assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="ptp weight must be >= 0"):
        PtpHparams.make(-0.5)
    with pytest.raises(ValueError, match="learning rate"):
        PtpHparams.make(1.0, lr=-1.0)
    with pytest.raises(ValueError, match="ptp.past must be an integer >= 1"):
        make_ptp(CFG, past=0)
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=100)
    assert methods.get("ptp").settings(ctx) == [{"weight": DEFAULT_WEIGHT}]
    ctx = dataclasses.replace(ctx, knobs={"ptp": PtpKnobs(weights=(0.0, 0.5))})
    assert methods.get("ptp").settings(ctx) == [{"weight": 0.0}, {"weight": 0.5}]


@pytest.mark.parametrize("args, message", [
    (["--set", "ptp.weights=-1"], "ptp.weights must be >= 0 and finite"),
    (["--set", "ptp.past=0"], "ptp.past must be an integer >= 1"),
    (["--set", "ptp.past=two"], "ptp.past takes int"),
    (["--set", "ptp.future=3"], "ptp has no setting 'future'; valid: ptp.past, ptp.weights"),
])
def test_the_sweep_refuses_bad_knobs_in_one_line_before_any_work(tmp_path, capsys, args, message):
    assert_sweep_refuses(tmp_path, capsys, ["--env", "toycar", "--obs", "full", "--quiet", "--methods", "ptp", *args],
                         message)
