"""ChannelDropout: a dropped channel is zero in every frame of its sample and nothing else moves; dropping ToyTown's
speed turns a frame with the speed into the frame without it; at rate 0 it trains BC-OH; a grid of rates × seeds
trains in one call, each rate as it should; its knobs, learner and the sweep refuse a channel the observation does
not carry, in one line, before any work; a tiny sweep trains it and PTP end to end."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax import methods, tasks
from ape_jax.baselines.channel_dropout import (DEFAULT_RATE, ChannelDropoutHparams, ChannelDropoutKnobs,
                                               channel_masks, drop_channels, make_channel_dropout, refusal)
from ape_jax.learner import Hparams, LearnerConfig, make_train, stack_hparams
from ape_jax.models import PatchPolicy
from ape_jax.pipeline.presets import resolve
from envs.toytown_render import strip_rows
from experiments import sweep
from _compare import update_mismatch
from _planted import planted
from _refusal import assert_sweep_refuses

# the planted copycat's observation is [s_t, a_{t−1}]: the previous action in view, as protocol.prev_action has it
CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=20, batch_size=64, lr_boundaries=(),
                    beta1=0.5)
IMAGE_CFG = LearnerConfig(obs_shape=(32, 32, 3), action_dim=3, history=2, iterations=3, batch_size=8,
                          encoder="patch")


def test_a_dropped_channel_is_zero_in_every_frame_of_its_sample_and_nothing_else_moves():
    history = jnp.arange(1, 1 + 512 * 2 * 4, dtype=jnp.float32).reshape(512, 2, 4)
    masks = channel_masks(CFG, ("prev_action",))
    np.testing.assert_array_equal(masks, [[False, False, True, True]])   # the last action_dim entries
    out, dropped = drop_channels(jax.random.PRNGKey(0), history, masks, 0.5)
    out, history, hit = np.asarray(out), np.asarray(history), np.asarray(dropped[:, 0])
    assert dropped.shape == (512, 1) and 0.4 < hit.mean() < 0.6
    assert np.all(out[hit][:, :, 2:] == 0)                                 # every frame, the current one too
    np.testing.assert_array_equal(out[hit][:, :, :2], history[hit][:, :, :2])
    np.testing.assert_array_equal(out[~hit], history[~hit])
    for rate, share in ((0.0, 0.0), (1.0, 1.0)):
        out, dropped = drop_channels(jax.random.PRNGKey(1), jnp.asarray(history), masks, rate)
        assert float(jnp.mean(dropped)) == share
        np.testing.assert_array_equal(np.asarray(out)[:, :, :2], history[:, :, :2])
    np.testing.assert_array_equal(drop_channels(jax.random.PRNGKey(1), jnp.asarray(history), masks, 0.0)[0],
                                  history)


def test_dropping_the_speed_turns_toytown_s_frame_into_the_frame_without_the_speed():
    short = dict(traffic="empty", image_size=32, route_length=180.0, intersections=2, episode_length=700)
    sim = jax.jit(envs.make("toytown", **short).reset)(jax.random.PRNGKey(0)).pipeline_state
    sim = sim.replace(v=jnp.asarray(6.0, sim.v.dtype))   # one scene, seen by the camera with and without the speed
    with_speed, without = (np.asarray(envs.make("toytown", speed_input=s, **short).observe_sim(sim))
                           for s in (True, False))
    assert not np.array_equal(with_speed, without)   # the strip shows the speed
    masks = channel_masks(IMAGE_CFG, ("speed",))
    assert masks.shape == (1, 32, 32, 3) and masks[0, :strip_rows(32)].all() and not masks[0, strip_rows(32):].any()
    dropped, _ = drop_channels(jax.random.PRNGKey(0), jnp.asarray(with_speed)[None, None], masks, 1.0)
    np.testing.assert_array_equal(np.asarray(dropped)[0, 0], without)


def test_at_rate_0_channel_dropout_trains_bc_oh():
    """The same initialisation and run key from the same key, the same batches, loss and updates: BC-OH's policy
    (BatchNorm's running statistics too) up to float32 rounding between two compiled programs (`tests/_compare.py`).
    The FCA recipe's BatchNorm network here; the plain one in the grid below."""
    cfg, data, key = dataclasses.replace(CFG, network="bn-mlp"), planted(), jax.random.PRNGKey(3)
    params, metrics = jax.jit(make_channel_dropout(cfg).train)(key, ChannelDropoutHparams.make(0.0, lr=1e-3), data)
    bc_oh, _ = jax.jit(make_train(cfg).train)(key, Hparams.make(lr=1e-3), data)
    init = make_train(cfg).init_policy(jax.random.split(key)[0], data)
    assert jax.tree.structure(params) == jax.tree.structure(bc_oh)
    assert update_mismatch(params, bc_oh, init) < 1e-4
    assert not np.any(metrics["dropped"])
    np.testing.assert_array_equal(metrics["loss"], metrics["unweighted_loss"])


def test_a_grid_of_two_rates_by_two_seeds_trains_in_one_call_each_rate_as_it_should():
    """Rates 0 and 1 × seeds 0 and 1 in one `jit(vmap(train))`: rate 0 is BC-OH's policy for its seed; at rate 1
    the previous action is zero in every training input, so the first layer's weights that read it never move
    from their initial values while the others train."""
    data = planted()
    keys = jnp.stack([jax.random.PRNGKey(s) for s in (0, 1, 0, 1)])
    hp = stack_hparams([ChannelDropoutHparams.make(r, lr=1e-3) for r in (0.0, 0.0, 1.0, 1.0)])
    params, metrics = jax.jit(jax.vmap(make_channel_dropout(CFG).train, (0, 0, None)))(keys, hp, data)
    bc_oh, _ = jax.jit(jax.vmap(make_train(CFG).train, (0, 0, None)))(
        keys[:2], stack_hparams([Hparams.make(lr=1e-3)] * 2), data)
    np.testing.assert_array_equal(np.asarray(metrics["dropped"]).mean(axis=1), [0.0, 0.0, 1.0, 1.0])
    previous = np.array([2, 3, 6, 7])   # a_{t−1} and a_{t−2}: the last two entries of each of the two frames
    for i, seed in enumerate((0, 1, 0, 1)):
        run = jax.tree.map(lambda leaf: leaf[i], params)
        init = make_train(CFG).init_policy(jax.random.split(jax.random.PRNGKey(seed))[0], data)
        if i < 2:
            assert update_mismatch(run, jax.tree.map(lambda leaf: leaf[seed], bc_oh), init) < 1e-4
            continue
        kernel, start = (np.asarray(p["params"]["encoder_0"]["kernel"]) for p in (run, init))
        np.testing.assert_array_equal(kernel[previous], start[previous])
        assert np.abs(kernel[[0, 1, 4, 5]] - start[[0, 1, 4, 5]]).max() > 1e-3


def test_an_image_learner_drops_the_speed_and_trains_a_plain_patch_policy():
    rng = np.random.default_rng(0)
    data = dataclasses.replace(planted(episodes=4, length=8), obs=jnp.asarray(rng.integers(0, 256, (32, 32, 32, 3),
                                                                                           np.uint8)),
                               action=jnp.asarray(rng.uniform(-1, 1, (32, 3)), jnp.float32))
    learner = make_channel_dropout(IMAGE_CFG)   # auto: the speed on frames
    params, metrics = jax.jit(learner.train)(jax.random.PRNGKey(0), ChannelDropoutHparams.make(1.0), data)
    model = IMAGE_CFG.model()
    assert isinstance(model, PatchPolicy) and np.all(np.asarray(metrics["dropped"]) == 1.0)
    fresh = learner.init_policy(jax.random.PRNGKey(1), data)
    assert jax.tree.map(jnp.shape, params) == jax.tree.map(jnp.shape, fresh)
    assert np.all(np.isfinite(np.asarray(metrics["loss"])))


def test_the_knobs_and_the_learner_refuse_what_they_cannot_run():
    for kw, message in (({"channels": "velocity"}, "channel-dropout.channels must be 'auto' or prev_action, speed"),
                        ({"channels": "speed,speed"}, "channel-dropout.channels must be"),
                        ({"channels": "auto,speed"}, "channel-dropout.channels must be"),
                        ({"channels": ("speed",)}, "channel-dropout.channels must be a string"),
                        ({"rates": (1.5,)}, r"channel-dropout.rates must be <= 1"),
                        ({"rates": (-0.1,)}, "channel-dropout.rates must be >= 0"),
                        ({"rates": (float("nan"),)}, "channel-dropout.rates must be >= 0"),
                        ({"rates": ()}, "at least one"), ({"rates": (0.5, 0.5)}, "each rate once")):
        with pytest.raises(ValueError, match=message) as e:
            ChannelDropoutKnobs(**kw)
        assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="rate must be <= 1"):
        ChannelDropoutHparams.make(1.2)
    with pytest.raises(ValueError, match="learning rate"):
        ChannelDropoutHparams.make(0.5, lr=0.0)
    with pytest.raises(ValueError, match="are not frames"):
        make_channel_dropout(CFG, "speed")
    with pytest.raises(ValueError, match="have none"):
        make_channel_dropout(IMAGE_CFG, "prev_action")
    with pytest.raises(ValueError, match="have none"):
        make_channel_dropout(dataclasses.replace(CFG, obs_shape=(2,)))
    assert ChannelDropoutKnobs().names(images=True) == ("speed",)
    assert ChannelDropoutKnobs("prev_action, speed").names(images=False) == ("prev_action", "speed")
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=100)
    assert methods.get("channel-dropout").settings(ctx) == [{"rate": DEFAULT_RATE}]
    ctx = dataclasses.replace(ctx, knobs={"channel-dropout": ChannelDropoutKnobs(rates=(0.0, 0.5))})
    assert methods.get("channel-dropout").settings(ctx) == [{"rate": 0.0}, {"rate": 0.5}]


@pytest.mark.parametrize("env, obs, sets, needle", [
    ("hopper", "pos", ["protocol.prev_action=true"], None),
    ("toytown", "image", [], None),                                   # nocrash: the speed in view
    ("toytown", "image", ["channel-dropout.channels=speed"], None),
    ("hopper", "pos", [], "--set protocol.prev_action=true"),
    ("toytown", "full", ["channel-dropout.channels=speed"], "--obs image (--obs full has no strip)"),
    ("toytown", "image", ["channel-dropout.channels=prev_action"], "frames do not carry"),
    ("toytown", "image", ["protocol.speed_input=false"], "protocol.speed_input=true (ToyTown's nocrash protocol), "
                                                         "got false"),
    ("hopper", "image", [], "got none"),                              # no strip: no speed to drop
])
def test_the_refusal_reads_the_channel_from_the_sweep_s_observation_and_protocol(env, obs, sets, needle):
    why = refusal(resolve(env, obs, sets=sets), obs)
    assert why is None if needle is None else (needle in why and "\n" not in why), why


BASE = ["--env", "toycar", "--obs", "full", "--quiet", "--methods", "channel-dropout"]


@pytest.mark.parametrize("args, message", [
    ([], "channel-dropout drops prev_action, which --obs full carries only with the previous action in view"),
    (["--obs", "image"], "channel-dropout drops speed, which the frames show only where the protocol says so"),
    (["--set", "protocol.prev_action=true", "--set", "channel-dropout.rates=1.5"],
     "channel-dropout.rates must be <= 1"),
    (["--set", "protocol.prev_action=true", "--set", "channel-dropout.channels=velocity"],
     "channel-dropout.channels must be 'auto' or prev_action, speed"),
])
def test_the_sweep_refuses_in_one_line_before_any_work(tmp_path, capsys, args, message):
    assert_sweep_refuses(tmp_path, capsys, [*BASE, *args], message)


@pytest.mark.slow
def test_a_tiny_sweep_trains_channel_dropout_and_ptp_from_their_knobs(tmp_path):
    """ToyCar with the previous action in view, 10 iterations: both methods' grids from `--set`, trained, evaluated
    and recorded (about 25 s on the 2-core CPU: the sweep's compiles)."""
    out = tmp_path / "run"
    assert sweep.main(["--env", "toycar", "--obs", "full", "--quiet", "--methods", "channel-dropout,ptp",
                       "--iterations", "10", "--eval-episodes", "1", "--set", "budget.probe_steps=0",
                       "--set", "protocol.prev_action=true", "--set", "channel-dropout.rates=0,0.5",
                       "--set", "ptp.past=2", "--out", str(out), "--data-dir", str(tmp_path / "data")]) == 0
    r = json.loads((out / "results.json").read_text())
    assert [(x["method"], x["hparams"], x["status"]) for x in r["runs"]] == [
        ("channel-dropout", {"rate": 0.0}, "ok"), ("channel-dropout", {"rate": 0.5}, "ok"),
        ("ptp", {"weight": 1.0}, "ok")]
    assert r["settings"]["knobs"] == {"channel-dropout": {"channels": "auto", "rates": [0.0, 0.5]},
                                      "ptp": {"past": 2, "weights": [1.0]}}
    assert all(np.isfinite(x["train_loss_final"]) for x in r["runs"])
