"""The image path end to end on tiny frames: the default encoder learns, and the jitted evaluation renders inside
the rollout (no host callback) with the returns of a step-by-step reference rollout of the same policy."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax import evaluate
from ape_jax.learner import Data, Hparams, LearnerConfig, make_train

SIZE = (16, 16)
ENV_KW = dict(episode_length=30, road_length=30.0, light_range=(12.0, 20.0))


def _image_cfg(**kw):
    return LearnerConfig(obs_shape=(*SIZE, 3), action_dim=2, history=2, batch_size=16, loss="l1", **kw)


def _tiny_image_data(n: int = 64) -> Data:
    """`n` random frames whose action (two dims) is a function of them: their red and blue means."""
    rng = np.random.default_rng(0)
    obs = rng.integers(0, 256, (n, *SIZE, 3), np.uint8)
    action = np.stack([obs[..., 0].mean((1, 2)), obs[..., 2].mean((1, 2))], -1) / 128.0 - 1.0
    return Data(obs=jnp.asarray(obs), action=jnp.asarray(action, jnp.float32), t=jnp.arange(n) % 16,
                ape=jnp.ones(n))


def test_the_small_cnn_learner_loss_falls_on_a_tiny_image_dataset():
    """64 random frames whose action is a function of the frames: the CNN fits them."""
    data = _tiny_image_data()
    # trained as the sweep trains images on a CPU: unrolled chunks of 10 iterations (convolution gradients
    # inside a scan are ~50x slower on XLA:CPU); the loss falls to ~15% of its start within 80 iterations
    cfg = _image_cfg(iterations=80, lr_boundaries=(10_000,), unroll=True)
    assert cfg.encoder == "small"
    learner, hp = make_train(cfg), Hparams.make(lr=1e-3)
    state = jax.jit(learner.init)(jax.random.PRNGKey(0), hp, data)
    run = jax.jit(lambda s: learner.run(s, hp, data, 10))
    losses = []
    for _ in range(cfg.iterations // 10):
        state, metrics = run(state)
        losses.append(np.asarray(metrics["loss"]))
    loss = np.concatenate(losses)
    assert np.isfinite(loss).all()
    assert loss[-20:].mean() < 0.5 * loss[:20].mean(), (loss[:20].mean(), loss[-20:].mean())


def test_the_image_evaluator_renders_inside_jit_and_matches_a_step_by_step_rollout():
    env = envs.make("toycar", obs="image", image_size=SIZE, **ENV_KW)
    cfg = _image_cfg()
    learner, model = make_train(cfg), cfg.model()
    x = learner.policy_input(jnp.zeros((1, 2, *SIZE, 3), jnp.uint8))
    params = jax.vmap(lambda k: model.init(k, x))(jax.random.split(jax.random.PRNGKey(1), 2))
    run = evaluate.make_evaluator(env, cfg, None, None, episodes=2)
    key = jax.random.PRNGKey(7)
    jaxpr = str(jax.make_jaxpr(run)(params, key))
    assert "callback" not in jaxpr                    # no host round trip: frames are rendered in the program
    out = run(params, key)
    assert out["return"].shape == (2, 2)

    # the reference: the same policy and episodes, one jitted env.step per call, the history kept by hand
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    act = jax.jit(lambda p, history: model.apply(p, learner.policy_input(history[None]))[0])
    low, high = env.action_bounds
    reset_keys = jax.random.split(jax.random.split(key)[0], 2)
    for p in range(2):
        policy = jax.tree.map(lambda v: v[p], params)
        for e in range(2):
            state = reset(reset_keys[e])
            assert state.obs.dtype == jnp.uint8 and state.obs.shape == (*SIZE, 3)
            history, total = jnp.stack([state.obs] * 2), 0.0
            for _ in range(env.episode_length):
                if float(state.done) > 0:
                    break
                action = jnp.clip(act(policy, history), low, high)
                state = step(state, action)
                total += float(state.reward)
                history = jnp.stack([history[1], state.obs])
            np.testing.assert_allclose(out["return"][p, e], total, rtol=1e-4, atol=1e-4)


def test_the_patch_learner_trains_in_a_scan_and_vmapped_as_the_sweep_trains_it():
    """The same tiny dataset: the patch encoder's grid, vmapped over two learning rates and scanned (not unrolled),
    fits it, and each configuration equals the same configuration trained alone."""
    from ape_jax.learner import stack_hparams

    data = _tiny_image_data()
    cfg = _image_cfg(iterations=80, lr_boundaries=(10_000,), encoder="patch")
    assert not cfg.unroll
    learner, grid = make_train(cfg), stack_hparams([Hparams.make(lr=1e-3), Hparams.make(lr=5e-4)])
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    params, metrics = jax.jit(jax.vmap(learner.train, (0, 0, None)))(keys, grid, data)
    loss = np.asarray(metrics["loss"])
    assert loss.shape == (2, 80) and np.isfinite(loss).all()
    assert (loss[:, -20:].mean(1) < 0.5 * loss[:, :20].mean(1)).all(), loss
    alone, alone_metrics = jax.jit(learner.train)(keys[1], jax.tree.map(lambda x: x[1], grid), data)
    np.testing.assert_allclose(alone_metrics["loss"], loss[1], rtol=1e-4, atol=1e-6)


@pytest.mark.integration
def test_a_sweep_with_the_patch_encoder_trains_its_grid_vmapped_and_diagnoses_it(tmp_path, capsys):
    """`--set recipe.encoder=patch` end to end on tiny ToyCar frames, with GroupNorm and random shifts: the grid
    trains vmapped in scanned chunks (no one-at-a-time message), FCA-IB's bottleneck noise and the diagnostics'
    embedding go through it, and results.json records the recipe."""
    import json

    from experiments import sweep

    argv = ["--env", "toycar", "--obs", "image", "--set", "protocol.image_size=16,16", "--iterations", "20",
            "--eval-episodes", "2", "--seeds", "1", "--methods", "bc-oh,ours-step,fca-ib", "--step-grid", "0.1:5",
            "--set", "recipe.encoder=patch", "--set", "recipe.encoder_norm=group", "--set", "recipe.augment_shift=2",
            "--set", "budget.probe_steps=20", "--quiet",
            "--out", str(tmp_path / "run"), "--data-dir", str(tmp_path / "data")]
    assert sweep.main(argv) == 0
    printed = capsys.readouterr()
    assert "one after another" not in printed.out + printed.err
    assert "recipe mlp (patch encoder, group norm, shift 2 px," in printed.out
    r = json.loads((tmp_path / "run" / "results.json").read_text())
    recipe = r["settings"]["recipe"]
    assert (recipe["encoder"], recipe["encoder_norm"], recipe["augment_shift"]) == ("patch", "group", 2)
    assert r["settings"]["protocol"]["image_size"] == [16, 16]
    assert {run["method"] for run in r["runs"]} == {"bc-oh", "ours-step", "fca-ib"}
    for run in r["runs"]:
        assert run["status"] == "ok", run["error"]
        assert np.isfinite(run["losses"]["val"]["unweighted"])
        assert "absent" not in run["diagnostics"] and np.isfinite(run["diagnostics"]["embedding_ratio"])


@pytest.mark.slow
def test_the_paper_image_preset_runs_end_to_end_as_a_smoke_run(tmp_path, capsys):
    """`--preset paper --obs image --smoke` (ResNet-18, here on 128×128 frames) on a CPU: every method of the
    preset's table trains, is evaluated mid-run and at the end, and is diagnosed; the report refuses the file.
    About 5 minutes on two cores, most of it compiling ResNet-18 and the renderer."""
    import json

    from experiments import report, sweep

    out = tmp_path / "run"
    argv = ["--env", "hopper", "--obs", "image", "--preset", "paper", "--smoke", "--quiet",
            "--set", "protocol.image_size=128x128", "--methods", "bc-so,bc-oh,ours-step,ours-softmax,fca",
            "--out", str(out), "--data-dir", str(tmp_path / "data")]
    assert sweep.main(argv) == 0
    assert "smoke run: preset paper's settings" in capsys.readouterr().out
    r = json.loads((out / "results.json").read_text())
    assert r["config"]["smoke"] is True and r["preset"] == "paper"
    assert r["settings"]["recipe"]["encoder"] == "resnet18" and r["settings"]["protocol"]["image_size"] == [128, 128]
    assert {run["method"] for run in r["runs"]} == {"bc-so", "bc-oh", "ours-step", "ours-softmax", "fca"}
    for run in r["runs"]:
        assert run["status"] == "ok", run["error"]
        assert [a["iteration"] for a in run["at"]] == [2]
        assert np.isfinite(run["eval"]["return_mean"]) and np.isfinite(run["diagnostics"]["embedding_ratio"])
    with pytest.raises(SystemExit) as exc:
        report.main([str(out / "results.json")])
    assert exc.value.code == 2
