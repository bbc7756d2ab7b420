"""The policies' networks: ResNet-18's shapes, size, per-sample normalisation, embedding, and that it trains; the
patch encoder's convolution, shapes, embedding and bottleneck noise."""

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax.learner import Data, Hparams, LearnerConfig, make_train
from ape_jax.models import IMAGE_ENCODERS, Head, ImagePolicy, PatchPolicy, ResNet18Policy, StatePolicy, patchify

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
    assert isinstance(LearnerConfig(**image, encoder="patch").model(), PatchPolicy)
    assert isinstance(LearnerConfig(obs_shape=(5,), action_dim=2).model(), StatePolicy)
    with pytest.raises(ValueError, match="LearnerConfig.encoder 'bogus' is not one of small, resnet18, patch"):
        LearnerConfig(**image, encoder="bogus")
    for encoder in ("resnet18", "patch"):
        with pytest.raises(ValueError, match="for image observations"):
            LearnerConfig(obs_shape=(5,), action_dim=2, encoder=encoder)


@pytest.mark.integration
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


# -- the patch encoder --------------------------------------------------------------------------------------------

def test_the_patch_layer_is_a_convolution_with_kernel_equal_to_stride_on_zero_padded_frames():
    # a Dense on `patchify`'s patches is the convolution of kernel = stride = 8; a side 8 does not divide is
    # zero-padded at its end (20 -> 24, 12 -> 16), like a SAME convolution of stride 8
    model = PatchPolicy(action_dim=2)
    for shape in ((2, 16, 16, 6), (2, 20, 12, 6)):
        x = jax.random.uniform(jax.random.PRNGKey(0), shape)
        params = model.init(jax.random.PRNGKey(1), x)["params"]
        layer = params["patch_0"]
        dense = nn.leaky_relu(patchify(x, 8) @ layer["kernel"] + layer["bias"], 0.2)
        padded = jnp.pad(x, ((0, 0), (0, -shape[1] % 8), (0, -shape[2] % 8), (0, 0)))
        conv = jax.lax.conv_general_dilated(padded, layer["kernel"].reshape(8, 8, 6, 64), (8, 8), "VALID",
                                            dimension_numbers=("NHWC", "HWIO", "NHWC"))
        assert dense.shape == (2, -(-shape[1] // 8), -(-shape[2] // 8), 64)
        np.testing.assert_allclose(dense, nn.leaky_relu(conv + layer["bias"], 0.2), rtol=1e-5, atol=1e-5)
        # and the head reads that grid flattened
        assert params["Head_0"]["embedding"]["kernel"].shape == (dense.shape[1] * dense.shape[2] * 64, 100)


def test_the_patch_encoder_is_sized_like_the_small_one():
    def count(model):
        params = jax.eval_shape(model.init, jax.random.PRNGKey(0), jnp.zeros((1, 32, 32, 6)))
        return _count(params)

    head = (4 * 4 * 64 + 1) * 100 + (100 + 1) * 300 + (300 + 1) * 3  # embedding, hidden, action
    assert count(PatchPolicy(3)) == (8 * 8 * 6 + 1) * 64 + head == 158_343
    assert 0.7 < count(PatchPolicy(3)) / count(ImagePolicy(3)) < 1.0  # 194k


@pytest.mark.parametrize("lead", [(5,), (2, 3)])
def test_the_patch_policy_takes_any_leading_dims_returns_the_embedding_and_adds_the_noise_to_it(lead):
    model = PatchPolicy(action_dim=3)
    x = jax.random.uniform(jax.random.PRNGKey(2), lead + (16, 16, 6))
    params = model.init(jax.random.PRNGKey(3), x)
    apply = jax.jit(model.apply, static_argnames="return_embedding")
    action = apply(params, x)
    assert action.shape == lead + (3,) and bool(jnp.all(jnp.isfinite(action)))
    np.testing.assert_allclose(apply(params, x.reshape((-1, 16, 16, 6))), action.reshape(-1, 3), rtol=1e-5,
                               atol=1e-6)
    same, z = apply(params, x, return_embedding=True)
    assert z.shape == lead + (100,)
    np.testing.assert_allclose(same, action, rtol=1e-5, atol=1e-6)
    assert set(params["params"]["Head_0"]) == {"embedding", "head", "action"}  # the layers FCA reads
    # FCA-IB's bottleneck: the head reads embedding + noise; the embedding returned is the layer's own output
    noise = jax.random.normal(jax.random.PRNGKey(4), z.shape)
    noisy, z_noisy = apply(params, x, return_embedding=True, embedding_noise=noise)
    np.testing.assert_allclose(z_noisy, z, rtol=1e-6, atol=1e-6)
    assert float(jnp.abs(noisy - action).max()) > 1e-3
    layer = params["params"]["patch_0"]
    features = nn.leaky_relu(patchify(x, 8) @ layer["kernel"] + layer["bias"], 0.2).reshape(lead + (-1,))
    head = Head(3).apply({"params": params["params"]["Head_0"]}, features, embedding_noise=noise)
    np.testing.assert_allclose(noisy, head, rtol=1e-5, atol=1e-5)
    zero, _ = apply(params, x, return_embedding=True, embedding_noise=jnp.zeros_like(z))
    np.testing.assert_allclose(zero, action, rtol=1e-5, atol=1e-6)


def test_only_the_loop_friendly_encoder_leaves_the_one_at_a_time_cpu_path():
    from ape_jax.pipeline.sweep import trains_sequentially

    assert jax.default_backend() == "cpu"
    assert {name: cls.loop_friendly for name, cls in IMAGE_ENCODERS.items()} == {
        "small": False, "resnet18": False, "patch": True, "drq": True, "perception": True}
    assert trains_sequentially((32, 32, 3), "small") and trains_sequentially((32, 32, 3), "resnet18")
    assert not trains_sequentially((32, 32, 3), "patch")
    assert not trains_sequentially((5,), "small")  # state policies: always the vmapped grid


# -- what image imitation needs: normalisation and augmentation ---------------------------------------------------

def test_random_shift_moves_every_frame_of_a_sample_by_one_offset_within_the_pad_repeating_the_edge():
    from ape_jax.learner import random_shift

    b, h, w, pad = 64, 12, 10, 2
    frames = jax.random.randint(jax.random.PRNGKey(0), (b, 2, h, w, 3), 0, 256).astype(jnp.uint8)
    frames = frames.at[:, 1].set(255 - frames[:, 0])  # the two frames of a history differ
    out = np.asarray(random_shift(jax.random.PRNGKey(1), frames, pad))
    assert out.shape == frames.shape and out.dtype == np.uint8
    padded = np.pad(np.asarray(frames), ((0, 0), (0, 0), (pad, pad), (pad, pad), (0, 0)), mode="edge")
    seen = set()
    for i in range(b):  # each sample is the padded history cut at one offset, the same for both frames
        hits = [(dy, dx) for dy in range(2 * pad + 1) for dx in range(2 * pad + 1)
                if np.array_equal(out[i], padded[i, :, dy:dy + h, dx:dx + w])]
        assert hits, i
        seen.update(hits)
    assert len(seen) > 10  # offsets drawn over the whole range (25 of them), not one
    np.testing.assert_array_equal(random_shift(jax.random.PRNGKey(1), frames, 0), frames)


def test_augmentation_is_training_only_and_absent_by_default():
    from ape_jax.learner import augment

    frames = jax.random.randint(jax.random.PRNGKey(0), (4, 2, 16, 16, 3), 0, 256).astype(jnp.uint8)
    cfg = LearnerConfig(obs_shape=(16, 16, 3), action_dim=2, encoder="patch")
    assert augment(cfg, jax.random.PRNGKey(1), frames) is frames
    shifted = LearnerConfig(obs_shape=(16, 16, 3), action_dim=2, encoder="patch", augment_shift=4)
    assert not np.array_equal(augment(shifted, jax.random.PRNGKey(1), frames), frames)
    with pytest.raises(ValueError, match=r"augment_shift must be an integer in \[0, 4\]"):
        LearnerConfig(obs_shape=(16, 16, 3), action_dim=2, augment_shift=5)
    with pytest.raises(ValueError, match="augment_shift is for image observations"):
        LearnerConfig(obs_shape=(5,), action_dim=2, augment_shift=1)


@pytest.mark.parametrize("encoder", ["small", "patch"])
def test_group_norm_normalises_each_sample_alone_after_every_encoder_layer(encoder):
    cfg = LearnerConfig(obs_shape=(16, 16, 3), action_dim=2, encoder=encoder, encoder_norm="group")
    model = cfg.model()
    x = jax.random.uniform(jax.random.PRNGKey(0), (3, 2, 16, 16, 6))
    params = model.init(jax.random.PRNGKey(1), x)["params"]
    layers = [k for k in params if k.startswith(("conv_", "patch_"))]
    assert sorted(k for k in params if k.startswith("norm_")) == [f"norm_{i}" for i in range(len(layers))]
    out = model.apply({"params": params}, x)
    # per sample: a sample's action does not depend on the others in its batch, nor on its leading dims
    np.testing.assert_allclose(model.apply({"params": params}, x[1:2, 0]), out[1:2, 0], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(model.apply({"params": params}, x.reshape(6, 16, 16, 6)), out.reshape(6, 2),
                               rtol=1e-5, atol=1e-6)
    # and the first layer's features are normalised: at initialisation (biases zero) scaling the frames leaves the
    # action as it was
    np.testing.assert_allclose(model.apply({"params": params}, 3.0 * x), out, rtol=1e-3, atol=1e-4)
    with pytest.raises(ValueError, match=r"encoder_norm 'group' is for the encoders 'small', 'patch' and 'drq' "
                                         r"\(resnet18"):
        LearnerConfig(obs_shape=(16, 16, 3), action_dim=2, encoder="resnet18", encoder_norm="group")


@pytest.mark.parametrize("encoder", ["small", "patch"])
@pytest.mark.parametrize("size", [(5, 5), (12, 20)])
def test_the_cpu_encoders_take_any_frame_size(encoder, size):
    """Every frame size `--set protocol.image_size` accepts (>= 1 px) is one the encoders run on (the patch
    embedding pads to whole patches, the convolutions pad their edges), so there is no size to refuse."""
    cfg = LearnerConfig(obs_shape=(*size, 3), action_dim=3, history=2, encoder=encoder)
    x = jnp.linspace(0.0, 1.0, 2 * size[0] * size[1] * 6).reshape(2, *size, 6)
    variables = cfg.model().init(jax.random.PRNGKey(0), x)
    out = cfg.model().apply(variables, x)
    assert out.shape == (2, 3) and bool(jnp.all(jnp.isfinite(out)))
