"""The image path end to end on tiny frames: the default encoder learns, and the jitted evaluation renders inside
the rollout (no host callback) with the returns of a step-by-step reference rollout of the same policy."""

import jax
import jax.numpy as jnp
import numpy as np

import envs
from ape_jax import evaluate
from ape_jax.learner import Data, Hparams, LearnerConfig, make_train

SIZE = (16, 16)
ENV_KW = dict(episode_length=30, road_length=30.0, light_range=(12.0, 20.0))


def _image_cfg(**kw):
    return LearnerConfig(obs_shape=(*SIZE, 3), action_dim=2, history=2, batch_size=16, loss="l1", **kw)


def test_the_small_cnn_learner_loss_falls_on_a_tiny_image_dataset():
    """64 random frames whose action is a function of the frames: the CNN fits them."""
    n = 64
    rng = np.random.default_rng(0)
    obs = rng.integers(0, 256, (n, *SIZE, 3), np.uint8)
    action = np.stack([obs[..., 0].mean((1, 2)), obs[..., 2].mean((1, 2))], -1) / 128.0 - 1.0
    data = Data(obs=jnp.asarray(obs), action=jnp.asarray(action, jnp.float32), t=jnp.arange(n) % 16,
                ape=jnp.ones(n))
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
