"""RAP: the two branches stay apart inside a plain StatePolicy, and on images inside a plain PatchPolicy (GroupNorm's
groups on one side each); at weight 0 its gradient is BC-OH's on that network,
at weight 1 the memory learns from the residual alone; the memory predicts the action's change far better than
no change; its knobs and the sweep refuse what it cannot run (also PALR's and MINE's knobs), before anything
compiles; a sweep of the three methods killed mid-training resumes bit for bit."""

import dataclasses
import json
import os
import pathlib
import signal
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import methods, tasks
from ape_jax.baselines._batch import sample_batch
from ape_jax.baselines.rap import (ENCODERS, PATCH, RapHparams, apply_masks, branch_masks, make_rap, memory_units,
                                   predict_residual, rap_loss, refusal)
from ape_jax.history import history_index
from ape_jax.learner import Data, LearnerConfig, make_train, stack_hparams, trainable
from ape_jax.models import PatchPolicy, StatePolicy
from ape_jax.pipeline.presets import resolve
from experiments import sweep
from _planted import planted
from _refusal import assert_sweep_refuses

ROOT = pathlib.Path(__file__).resolve().parents[1]
CFG = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=400, batch_size=64, lr_boundaries=(),
                    beta1=0.5)
WIDTH = 150


def _state_and_batch(weight, width=WIDTH, network="mlp"):
    cfg = dataclasses.replace(CFG, network=network)
    data = planted(rho=0.7)
    state = make_rap(cfg).init(jax.random.PRNGKey(0), RapHparams.make(weight, width), data)
    return cfg, state, sample_batch(cfg, make_train(cfg), data, jax.random.PRNGKey(1))


def _grads(cfg, state, batch, weight, width=WIDTH):
    return jax.grad(lambda p, r: rap_loss(cfg, {**state.params, **p}, r, batch, jnp.float32(weight),
                                          jnp.float32(width))[0], argnums=(0, 1))(trainable(state.params),
                                                                                 state.residual)


def _memory_entries(params, width=WIDTH):
    """1 where a parameter belongs to the memory branch: its units' kernel columns and biases in the encoder and
    the embedding; the head and the action layer are the policy's."""
    out = {name: jax.tree.map(lambda v: jnp.broadcast_to(memory_units(width, v.shape[-1]), v.shape), params[name])
           for name in params if name != "Head_0"}
    head = params["Head_0"]
    out["Head_0"] = {"embedding": jax.tree.map(lambda v: jnp.broadcast_to(memory_units(width, v.shape[-1]), v.shape),
                                               head["embedding"]),
                     **{k: jax.tree.map(lambda v: jnp.zeros(v.shape, bool), head[k]) for k in ("head", "action")}}
    return out


def test_the_branches_stay_apart_in_a_plain_state_policy():
    data = planted(rho=0.7)
    hp = RapHparams.make(1.0, 100, lr=1e-3)
    params, _ = jax.jit(make_rap(dataclasses.replace(CFG, iterations=50)).train)(jax.random.PRNGKey(0), hp, data)
    x = jnp.ones((1, 8))
    assert jax.tree.structure(params) == jax.tree.structure(StatePolicy(2).init(jax.random.PRNGKey(0), x))
    masks = branch_masks(params["params"], CFG.history, 100)
    for name in ENCODERS:
        kernel = params["params"][name]["kernel"]
        assert not np.any(np.asarray(kernel)[np.asarray(masks[name]) == 0]) and np.any(kernel)  # zero where held
    # the policy branch reads the current frame only: changing the past moves the memory's units, not its own
    model, past = StatePolicy(2), jnp.array([[0.3, -1.0, 0.5, 0.2]])
    _, a = model.apply(params, jnp.concatenate([past, jnp.ones((1, 4))], -1), return_embedding=True)
    _, b = model.apply(params, jnp.concatenate([-past, jnp.ones((1, 4))], -1), return_embedding=True)
    memory = np.asarray(memory_units(100, 100))
    assert memory.sum() == 33 and np.array_equal(np.asarray(a)[0, ~memory], np.asarray(b)[0, ~memory])
    assert not np.allclose(np.asarray(a)[0, memory], np.asarray(b)[0, memory])


@pytest.mark.parametrize("network", ["mlp", "bn-mlp"])
def test_at_weight_0_the_gradient_is_bc_oh_s_on_the_split_network(network):
    cfg, state, batch = _state_and_batch(0.0, network=network)
    grads, residual = _grads(cfg, state, batch, 0.0)
    masks = branch_masks(state.params["params"], cfg.history, WIDTH)

    def bc_oh(p):  # BC-OH's loss on the masked network, nothing intercepted
        variables = {**state.params, "params": apply_masks(p["params"], masks)}
        kw = {"train": True, "mutable": ["batch_stats"]} if network == "bn-mlp" else {}
        out = cfg.model().apply(variables, batch.x, **kw)
        predicted = out[0] if network == "bn-mlp" else out
        return jnp.mean(jnp.sum((predicted - batch.action) ** 2, -1))

    want = jax.grad(bc_oh)(trainable(state.params))
    for g, w in zip(jax.tree.leaves(grads), jax.tree.leaves(want)):
        np.testing.assert_allclose(g, w, rtol=1e-5, atol=1e-8)
    assert not any(np.any(leaf) for leaf in jax.tree.leaves(residual))  # the residual head idles


def test_at_weight_1_the_memory_learns_from_the_residual_alone():
    cfg, state, batch = _state_and_batch(1.0)
    grads, residual = _grads(cfg, state, batch, 1.0)
    only = {}  # the two losses' gradients apart, nothing split (weight 0)
    for part in ("bc", "res"):
        def loss(p, r, part=part):
            _, ((bc, res, _), _) = rap_loss(cfg, {**state.params, **p}, r, batch, jnp.float32(0.0), jnp.float32(WIDTH))
            return bc if part == "bc" else res
        only[part] = jax.grad(loss)(trainable(state.params), state.residual)
    memory = _memory_entries(state.params["params"])
    for g, bc, res, m in zip(jax.tree.leaves(grads), jax.tree.leaves(only["bc"]), jax.tree.leaves(only["res"]),
                             jax.tree.leaves({"params": memory})):
        np.testing.assert_allclose(g, np.where(m, res, bc), rtol=1e-5, atol=1e-8)
    assert any(np.any(v) for v in jax.tree.leaves(only["res"])) and any(np.any(v) for v in jax.tree.leaves(residual))


def test_the_memory_predicts_the_action_s_change_far_better_than_no_change():
    train, val = planted(rho=0.7), planted(seed=1, rho=0.7)
    learner = make_rap(CFG)
    hp = stack_hparams([RapHparams.make(w, WIDTH, lr=1e-3) for w in (1.0, 0.0)])
    keys = jnp.stack([jax.random.PRNGKey(0)] * 2)
    start = jax.vmap(learner.init, (0, 0, None))(keys, hp, train)
    state, metrics = jax.jit(jax.vmap(lambda s, h, d: learner.run(s, h, d, CFG.iterations), (0, 0, None)))(
        start, hp, train)
    idx = jnp.arange(val.t.shape[0])
    x = learner.policy_input(val.obs[history_index(val.t, idx, CFG.history)])
    change = val.action - val.action[history_index(val.t, idx, 1, offset=1)[:, 0]]
    rap = jax.tree.map(lambda leaf: leaf[0], state)
    held_out = float(jnp.mean(jnp.sum((predict_residual(CFG, rap, WIDTH, x) - change) ** 2, -1)))
    no_change = float(jnp.mean(jnp.sum(change**2, -1)))
    assert held_out < 0.1 * no_change, (held_out, no_change)
    assert float(metrics["residual_loss"][0, -50:].mean()) < 0.1 * float(metrics["zero_residual_loss"][0, -50:].mean())
    bc = np.asarray(metrics["unweighted_loss"][:, -50:].mean(axis=1))
    assert np.all(bc < 0.05), bc                                    # both policies imitate a_t
    idle = jax.tree.map(lambda leaf: leaf[1], (state.residual, start.residual))
    assert all(np.array_equal(a, b) for a, b in zip(*map(jax.tree.leaves, idle)))  # weight 0: R never moves


# images: 16×16 frames (a 2×2 grid of 8×8 patches), the default image recipe's patch encoder with GroupNorm
IMAGE_CFG = dataclasses.replace(CFG, obs_shape=(16, 16, 3), encoder="patch", encoder_norm="group", iterations=300,
                                batch_size=32)


def _frames(data: Data) -> Data:
    """`planted`'s observations drawn as 16×16 frames: each 8×8 patch shows one entry of `[s_t, a_{t−1}]` as a
    grey level (`128 + 40 v`, uint8), so the current frame holds what the action and its change depend on."""
    level = np.clip(np.round(128 + 40 * np.asarray(data.obs)), 0, 255).astype(np.uint8)   # [N, 4]
    frames = np.repeat(np.repeat(level.reshape(-1, 2, 2), 8, axis=1), 8, axis=2)           # [N, 16, 16]
    return data.replace(obs=jnp.asarray(np.repeat(frames[..., None], 3, axis=-1)))


@pytest.fixture(scope="module")
def trained_image():
    """A RAP image learner trained `IMAGE_CFG.iterations` on the planted frames (width 100): `(params, metrics,
    data)`."""
    data = _frames(planted(rho=0.7))
    params, metrics = jax.jit(make_rap(IMAGE_CFG).train)(jax.random.PRNGKey(0), RapHparams.make(1.0, 100, lr=1e-3),
                                                         data)
    return params, metrics, data


def test_the_memory_s_channels_are_whole_groups_of_group_norm():
    channels = lambda width, groups=None: int(memory_units(width, 64, groups).sum())  # noqa: E731
    assert [channels(w, 8) for w in (1, 60, 100, 150, 299)] == [8, 16, 24, 32, 56]   # one group each side at least
    assert [channels(w) for w in (1, 60, 100, 150, 299)] == [1, 13, 21, 32, 63]       # no GroupNorm: the share
    masks = branch_masks(PatchPolicy(2, norm="group").init(jax.random.PRNGKey(0), jnp.zeros((1, 16, 16, 6)))["params"],
                         2, 100)
    memory = np.asarray(masks[PATCH]).min(axis=0) == 1   # the channels that read every entry
    assert memory.sum() == 24 and memory[:24].all()
    assert masks["embedding"].shape == (4 * 64, 100) and np.asarray(masks["embedding"])[64:64 + 24, :33].all()


def test_the_image_branches_stay_apart_and_the_held_kernel_entries_stay_zero(trained_image):
    params, _, data = trained_image
    masks = branch_masks(params["params"], IMAGE_CFG.history, 100)
    for name, kernel in ((PATCH, params["params"][PATCH]["kernel"]),
                         ("embedding", params["params"]["Head_0"]["embedding"]["kernel"])):
        held = np.asarray(masks[name]) == 0
        assert held.any() and not np.any(np.asarray(kernel)[held]) and np.any(kernel)   # zero where held
    x = make_train(IMAGE_CFG).policy_input(data.obs[history_index(data.t, jnp.arange(20, 28), IMAGE_CFG.history)])
    model, memory = IMAGE_CFG.model(), np.asarray(memory_units(100, 100))

    def embedding_grad(units):   # d(sum of these embedding units) / d(frames): [B, 16, 16, 6]
        return np.asarray(jax.grad(lambda x: model.apply(params, x, return_embedding=True)[1][:, units].sum())(x))

    policy, past = embedding_grad(~memory), slice(0, 3)   # the oldest frame: the first 3 of each pixel's channels
    assert not np.any(policy[..., past]) and np.any(policy[..., 3:])
    assert np.any(embedding_grad(memory)[..., past])
    # the probe: another past frame moves the memory's units, not the policy branch's
    _, a = model.apply(params, x, return_embedding=True)
    _, b = model.apply(params, x.at[..., past].set(1.0 - x[..., past]), return_embedding=True)
    assert np.array_equal(np.asarray(a)[:, ~memory], np.asarray(b)[:, ~memory])
    assert not np.allclose(np.asarray(a)[:, memory], np.asarray(b)[:, memory])


def test_a_rap_image_learner_trains_and_loads_as_a_plain_patch_policy(trained_image):
    params, metrics, data = trained_image
    bc, res, zero = (np.asarray(metrics[k])[-50:].mean() for k in ("unweighted_loss", "residual_loss",
                                                                    "zero_residual_loss"))
    spread = float(jnp.mean(jnp.sum((data.action - data.action.mean(0)) ** 2, -1)))   # the mean action's loss
    assert bc < 0.25 * spread and bc < 0.25 * float(metrics["unweighted_loss"][0]), (bc, spread)
    assert res < 0.2 * zero, (res, zero)   # the memory predicts the change far better than no change
    model = IMAGE_CFG.model()
    x = make_train(IMAGE_CFG).policy_input(data.obs[history_index(data.t, jnp.arange(8), IMAGE_CFG.history)])
    fresh = model.init(jax.random.PRNGKey(1), x)
    assert isinstance(model, PatchPolicy)
    assert jax.tree.map(jnp.shape, params) == jax.tree.map(jnp.shape, fresh)
    action = model.apply(params, x)
    assert action.shape == (8, 2) and np.all(np.isfinite(action))


def test_the_knobs_and_the_learner_refuse_what_rap_cannot_run():
    for kw, message in (({"weight": 1.5}, r"weight must be in \[0, 1\]"), ({"weight": -0.1}, "weight must be"),
                        ({"memory_width": 0}, "memory_width must be an integer"),
                        ({"memory_width": 300}, "memory_width must be an integer"),
                        ({"memory_width": 10.5}, "memory_width must be an integer")):
        with pytest.raises(ValueError, match=message):
            RapHparams.make(**kw)
    with pytest.raises(ValueError, match="history of at least 2"):
        make_rap(dataclasses.replace(CFG, history=1))
    with pytest.raises(ValueError, match="image encoder 'small' is not supported"):
        make_rap(LearnerConfig(obs_shape=(8, 8, 3), action_dim=2))
    with pytest.raises(ValueError, match="history of at least 2"):
        make_rap(dataclasses.replace(IMAGE_CFG, history=1))
    image = resolve("hopper", "image", sets=["recipe.encoder=patch", "recipe.encoder_norm=group"])
    assert refusal(image, "image") is None
    ctx = methods.GridContext(task=tasks.get("hopper"), n_train=100)
    assert methods.get("rap").settings(ctx) == [{"weight": 1.0, "memory_width": 150.0}]
    knobs = resolve("hopper", "pos", sets=["rap.weights=0.5,1", "rap.widths=60"]).knobs
    assert methods.get("rap").settings(dataclasses.replace(ctx, knobs=knobs)) == [
        {"weight": 0.5, "memory_width": 60.0}, {"weight": 1.0, "memory_width": 60.0}]


BASE = ["--env", "toycar", "--obs", "full", "--quiet"]


@pytest.mark.parametrize("args, message", [
    (["--methods", "rap", "--set", "protocol.history=1"], "rap needs a history"),
    (["--methods", "bc-oh,rap", "--obs", "image"], "rap on images needs the patch encoder"),
    (["--methods", "rap", "--obs", "image", "--set", "recipe.encoder=drq"], "use --set recipe.encoder=patch"),
    (["--methods", "rap", "--obs", "image", "--set", "recipe.encoder=patch", "--set", "protocol.history=1"],
     "rap needs a history"),
    (["--methods", "rap", "--set", "rap.weights=1.5"], "rap: weights: every value must be in [0, 1]"),
    (["--methods", "rap", "--set", "rap.widths=0"], "rap: widths: every value must be an integer"),
    (["--methods", "palr", "--set", "palr.bandwidths=0"], "palr: bandwidths must be > 0"),
    (["--methods", "palr", "--set", "palr.bandwidths=-1"], "palr: bandwidths must be > 0"),
    (["--methods", "palr", "--set", "palr.weights=-1"], "palr: weights must be >= 0"),
    (["--methods", "mine", "--set", "mine.weights=-0.5"], "mine: weights must be >= 0"),
    (["--methods", "mine", "--set", "mine.steps=0"], "mine: steps must be an integer >= 1"),
    (["--methods", "palr", "--set", "palr.rows=-1"], "palr: rows must be an integer >= 0"),
    (["--methods", "mine", "--set", "recipe.mine_rows=-1"], "mine: rows must be an integer >= 0"),   # the old name
])
def test_the_sweep_refuses_bad_knobs_and_rap_without_a_history_before_any_work(tmp_path, capsys, args, message):
    assert_sweep_refuses(tmp_path, capsys, [*BASE, *args], message)


# the three methods' programs, 40 iterations saved every 20; SIGKILL after the KILL_AT-th training save
RESUME = [*BASE, "--methods", "rap,palr,mine", "--iterations", "40", "--checkpoint-every", "20", "--seeds", "1",
          "--eval-episodes", "2", "--set", "budget.probe_steps=0", "--set", "recipe.batch_size=16"]
KILLER = """
import os, signal, sys
from ape_jax.pipeline import checkpoint
count, real = [0], checkpoint.ProgramCheckpoint.save
def save(self, *args, **kwargs):
    real(self, *args, **kwargs)
    count[0] += 1
    if count[0] == int(os.environ["KILL_AT"]):
        os.kill(os.getpid(), signal.SIGKILL)
checkpoint.ProgramCheckpoint.save = save
from experiments import sweep
sys.exit(sweep.main(sys.argv[1:]))
"""


def _numbers(path: pathlib.Path) -> dict:
    results = json.loads((path / "results.json").read_text())
    return {k: v for k, v in results.items() if k not in ("timing", "system", "command")}


@pytest.mark.slow
def test_a_sweep_of_the_three_killed_mid_training_resumes_bit_for_bit(tmp_path, capsys):
    data = tmp_path / "data"
    assert sweep.main([*RESUME, "--out", str(tmp_path / "reference"), "--data-dir", str(data)]) == 0
    env = {**os.environ, "KILL_AT": "3", "PYTHONPATH": str(ROOT)}   # mine done (20, 40), palr at 20 of 40
    out = tmp_path / "killed"
    proc = subprocess.run([sys.executable, "-c", KILLER, *RESUME, "--out", str(out), "--data-dir", str(data)],
                          env=env, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    assert not (out / "results.json").exists() and (out / "checkpoints" / "train-palr").is_dir()
    capsys.readouterr()
    assert sweep.main([*RESUME, "--out", str(out), "--data-dir", str(data)]) == 0
    assert "resuming from" in capsys.readouterr().out
    resumed, reference = _numbers(out), _numbers(tmp_path / "reference")
    assert resumed == reference
    assert {r["method"] for r in reference["runs"]} == {"rap", "palr", "mine"}
    assert len({r["train_loss_final"] for r in reference["runs"]}) == 3   # three different trainings
