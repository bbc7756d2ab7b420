"""The policies' networks: ResNet-18's shapes, size, per-sample normalisation, embedding, and that it trains."""

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax.learner import Data, Hparams, LearnerConfig, make_train
from ape_jax.models import ImagePolicy, ResNet18Policy, StatePolicy

# Float32 rounding scale for comparing two programs that compute the same network (another batch
# shape, another set of outputs). XLA:CPU picks its GEMM/convolution blocking, and so the order of
# the additions, from the shapes and the CPU (Intel and AMD differ), so such results agree only to
# rounding, which through ResNet-18's ~20 layers reaches tens of ulps of the outputs' magnitude
# (measured: 21 ulps on an Intel Xeon, ~60 on an AMD EPYC). The bound is a few hundred.
ULPS = 512


def assert_close_in_ulps(actual, desired, ulps=ULPS):
    """`|actual - desired| <= ulps · eps32 · max|desired|`: equal up to float32 rounding of values of that size."""
    actual, desired = np.asarray(actual, np.float64), np.asarray(desired, np.float64)
    assert actual.shape == desired.shape, (actual.shape, desired.shape)
    bound = ulps * np.finfo(np.float32).eps * np.abs(desired).max()
    assert bound > 0, "all-zero reference: nothing to compare"
    worst = np.abs(actual - desired).max()
    assert worst <= bound, f"max |difference| {worst:.3g} > {bound:.3g} ({ulps} ulps of max |value|)"
    return worst, bound

# torchvision's resnet18: 11,689,512 parameters, of which the 1000-way classifier is 512·1000 + 1000.
TORCHVISION_RESNET18_WITHOUT_FC = 11_689_512 - 513_000


def _resnet18_encoder_size(in_channels: int) -> int:
    """Conv kernels plus normalisation scales and biases of ResNet-18, counted from the architecture."""
    n = 7 * 7 * in_channels * 64 + 2 * 64
    previous = 64
    for c in (64, 128, 256, 512):
        n += 9 * previous * c + 9 * c * c + 4 * c  # first block's two convs and norms
        if c != previous:
            n += previous * c + 2 * c              # its 1×1 projection shortcut and norm
        n += 2 * 9 * c * c + 4 * c                 # second block
        previous = c
    return n


@pytest.fixture(scope="module")
def resnet():
    """`(jitted apply, params)` of a ResNet18Policy for 16×16 frames, history 2, 3 actions."""
    model = ResNet18Policy(action_dim=3)
    params = jax.jit(model.init)(jax.random.PRNGKey(0), jnp.zeros((1, 16, 16, 6)))
    return jax.jit(model.apply, static_argnames="return_embedding"), params


def _count(tree) -> int:
    return sum(leaf.size for leaf in jax.tree.leaves(tree))


def test_the_encoder_is_resnet18_sized():
    assert _resnet18_encoder_size(3) == TORCHVISION_RESNET18_WITHOUT_FC  # the count itself is right
    for history in (1, 2):
        params = jax.eval_shape(ResNet18Policy(3).init, jax.random.PRNGKey(0), jnp.zeros((1, 32, 32, 3 * history)))
        encoder = _count(params["params"]["encoder"])
        assert encoder == _resnet18_encoder_size(3 * history), (history, encoder)
        assert 11.1e6 < encoder < 11.3e6
    # with 2 stacked frames only the 7×7 stem grows, by 7·7·3·64 weights
    assert _resnet18_encoder_size(6) - _resnet18_encoder_size(3) == 9408


@pytest.mark.parametrize("lead", [(6,), (2, 3)])
def test_any_leading_batch_dims(resnet, lead):
    apply, params = resnet
    x = jax.random.uniform(jax.random.PRNGKey(1), lead + (16, 16, 6))
    action = apply(params, x)
    assert action.shape == lead + (3,) and bool(jnp.all(jnp.isfinite(action)))
    flat = apply(params, x.reshape((-1, 16, 16, 6)))
    assert_close_in_ulps(action.reshape(-1, 3), flat)


def _pool_the_batch(next_fun, args, kwargs, context):
    """Interceptor: every GroupNorm normalises the batch as one sample (statistics across samples)."""
    if isinstance(context.module, nn.GroupNorm) and context.method_name == "__call__":
        x = args[0]  # [N, h, w, C] -> [1, N·h, w, C]: the group statistics then pool all N samples
        return next_fun(x.reshape((1, -1) + x.shape[2:]), *args[1:], **kwargs).reshape(x.shape)
    return next_fun(*args, **kwargs)


def test_normalisation_is_per_sample(resnet):
    # GroupNorm, no batch statistics: a sample's action does not depend on the rest of its batch
    apply, params = resnet
    x = jax.random.uniform(jax.random.PRNGKey(2), (6, 16, 16, 6))
    together = apply(params, x)
    alone = jnp.concatenate([apply(params, x[i:i + 1]) for i in range(6)])
    _, bound = assert_close_in_ulps(together, alone)  # batch 6 and batch 1 differ only by rounding
    assert "batch_stats" not in params
    assert float(jnp.std(together[:, 0])) > 0  # and it is not a constant function
    # The bound is tight enough to catch a normalisation across samples: the same network and
    # parameters with batch statistics (same result for a batch of one) is far outside it.
    with nn.intercept_methods(_pool_the_batch):
        pooled = jax.jit(lambda p, v: ResNet18Policy(action_dim=3).apply(p, v))(params, x)
    assert np.abs(np.asarray(pooled) - np.asarray(alone)).max() > 100 * bound


def test_return_embedding_gives_the_head_embedding_and_the_same_action(resnet):
    apply, params = resnet
    x = jax.random.uniform(jax.random.PRNGKey(3), (2, 3, 16, 16, 6))
    action, embedding = apply(params, x, return_embedding=True)
    assert_close_in_ulps(action, apply(params, x))  # two programs (one also returns the embedding)
    assert embedding.shape == (2, 3, 100)
    assert set(params["params"]["Head_0"]) == {"embedding", "head", "action"}  # the layers FCA reads
    assert params["params"]["mlp"]["kernel"].shape == (512, 300)


def test_the_config_selects_the_encoder():
    image = dict(obs_shape=(16, 16, 3), action_dim=2)
    assert isinstance(LearnerConfig(**image).model(), ImagePolicy)
    assert isinstance(LearnerConfig(**image, encoder="resnet18").model(), ResNet18Policy)
    assert isinstance(LearnerConfig(obs_shape=(5,), action_dim=2).model(), StatePolicy)
    with pytest.raises(ValueError, match="unknown encoder 'bogus'.*'small', 'resnet18'"):
        LearnerConfig(**image, encoder="bogus")
    with pytest.raises(ValueError, match="for image observations"):
        LearnerConfig(obs_shape=(5,), action_dim=2, encoder="resnet18")


def test_resnet18_learner_fits_a_tiny_image_dataset():
    # the action is the brightness of the current frame: learnable only by looking at it
    rng = np.random.default_rng(0)
    n = 32
    level = rng.random(n).astype(np.float32)
    frames = np.clip(level[:, None, None, None] + 0.1 * rng.normal(size=(n, 16, 16, 3)), 0, 1)
    data = Data(obs=jnp.asarray((255 * frames).astype(np.uint8)), action=jnp.asarray(2 * level[:, None] - 1),
                t=jnp.tile(jnp.arange(8, dtype=jnp.int32), n // 8), ape=jnp.ones(n))
    cfg = LearnerConfig(obs_shape=(16, 16, 3), action_dim=1, history=2, batch_size=8, encoder="resnet18")
    learner = make_train(cfg)
    hp = Hparams.make(lr=1e-4)  # the paper's 2e-4 is for batches of 128
    state = jax.jit(learner.init)(jax.random.PRNGKey(0), hp, data)
    # One iteration per call, compiled once (the smallest program: compiling dominates here). The
    # suite compiles at XLA backend optimisation level 0 (conftest), where ResNet-18's convolution
    # gradients run ~25x slower: this one program asks for level 2.
    step = (jax.jit(lambda s, d: learner.run(s, hp, d, 1)).lower(state, data)
            .compile(compiler_options={"xla_backend_optimization_level": 2}))
    losses = []
    for _ in range(30):
        state, metrics = step(state, data)
        losses.append(float(metrics["unweighted_loss"][0]))
    losses = np.array(losses)  # each on a fresh minibatch, before that step's update
    assert np.all(np.isfinite(losses))
    assert losses[-10:].mean() < 0.3 * losses[:5].mean(), losses
    variance = float(data.action.var())  # the loss of the best blind (constant) prediction
    assert losses[-10:].mean() < 0.5 * variance, (losses, variance)
