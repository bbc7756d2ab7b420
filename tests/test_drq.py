"""The `drq` image encoder (`models.DrQPolicy`) and the policies' arithmetic dtype (`recipe.dtype`)."""

import dataclasses
import json
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import models
from ape_jax.learner import Data, Hparams, LearnerConfig, make_train
from ape_jax.models import IMAGE_ENCODERS, DrQPolicy, windows3x3
from ape_jax.pipeline import checkpoint, results as results_lib
from ape_jax.pipeline.hints import SettingsError
from ape_jax.pipeline.presets import RECIPES, Settings, resolve
from experiments import sweep


# -- the encoder ----------------------------------------------------------------------------------------------------

def test_drq_at_84x84_with_a_history_stacked_on_channels():
    # three frames of history: 9 channels in; DrQ's map: 84 -> 41 (stride 2) -> 39 -> 37 -> 35, 32 channels
    model = DrQPolicy(action_dim=6)
    frames = jax.random.uniform(jax.random.PRNGKey(0), (2, 5, 84, 84, 9))  # leading dims [2, 5]
    variables = model.init(jax.random.PRNGKey(1), frames)
    params = variables["params"]
    assert [params[f"conv_{i}"]["kernel"].shape for i in range(4)] == [(3, 3, 9, 32)] + [(3, 3, 32, 32)] * 3
    assert params["Head_0"]["embedding"]["kernel"].shape == (35 * 35 * 32, 100)
    action, embedding = model.apply(variables, frames, return_embedding=True)
    assert action.shape == (2, 5, 6) and embedding.shape == (2, 5, 100)
    assert action.dtype == embedding.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(action)))
    assert IMAGE_ENCODERS["drq"] is DrQPolicy and DrQPolicy.loop_friendly


def test_the_im2col_convolutions_are_xla_convolutions():
    # the same parameters through XLA's convolution (`matmul=False`) give the same actions; the windows are the
    # VALID convolution's: ⌊(h − 3) / s⌋ + 1 a side
    x = jax.random.uniform(jax.random.PRNGKey(0), (3, 20, 17, 6))
    assert windows3x3(x, 2).shape == (3, 9, 8, 54) and windows3x3(x, 1).shape == (3, 18, 15, 54)
    variables = DrQPolicy(2).init(jax.random.PRNGKey(1), x)
    np.testing.assert_allclose(DrQPolicy(2).apply(variables, x), DrQPolicy(2, matmul=False).apply(variables, x),
                               rtol=1e-4, atol=1e-5)


def test_a_frame_smaller_than_the_encoder_takes_is_refused_in_one_line(capsys):
    # 15 is the least side: three unstrided 3x3 convolutions need 7 pixels, the strided one gives 7 from 15
    assert DrQPolicy.min_side == 15
    DrQPolicy(2).init(jax.random.PRNGKey(0), jnp.zeros((1, 15, 15, 3)))  # the least side runs
    LearnerConfig(obs_shape=(15, 15, 3), action_dim=2, encoder="drq")
    with pytest.raises(ValueError, match=r"encoder 'drq' takes images of at least 15×15 pixels, got 14×20"):
        LearnerConfig(obs_shape=(14, 20, 3), action_dim=2, encoder="drq")
    item = ["recipe.encoder=drq", "protocol.image_size=14x14"]
    message = "recipe.encoder 'drq' takes images of at least 15×15 pixels, got protocol.image_size 14x14"
    with pytest.raises(SettingsError) as exc:
        resolve("hopper", "image", sets=item)
    assert message in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(SystemExit) as code:
        sweep.parse(["--obs", "image", "--set", item[0], "--set", item[1]], writes=False)
    err = capsys.readouterr().err
    assert code.value.code == 2 and message in err and err.count("\n") == 1
    assert resolve("hopper", "image", sets=["recipe.encoder=drq", "protocol.image_size=84x84"]).recipe.encoder == "drq"


# -- a tiny image dataset, trained in float32 and bfloat16 -----------------------------------------------------------

SEEDS, ITERATIONS = 3, 40


def _brightness_data(n: int = 64, side: int = 16) -> Data:
    """The action is the current frame's brightness: learnable only by looking at it."""
    rng = np.random.default_rng(0)
    level = rng.random(n).astype(np.float32)
    frames = np.clip(level[:, None, None, None] + 0.1 * rng.normal(size=(n, side, side, 3)), 0, 1)
    return Data(obs=jnp.asarray((255 * frames).astype(np.uint8)), action=jnp.asarray(2 * level[:, None] - 1),
                t=jnp.tile(jnp.arange(8, dtype=jnp.int32), n // 8), ape=jnp.ones(n))


@pytest.fixture(scope="module")
def trained():
    """{dtype: (params of 3 seeds, losses [3, ITERATIONS])}: drq at 16×16, batch 16, the seeds vmapped."""
    data = _brightness_data()
    out = {}
    for dtype in models.DTYPES:
        cfg = LearnerConfig(obs_shape=(16, 16, 3), action_dim=1, history=2, batch_size=16, encoder="drq",
                            iterations=ITERATIONS, lr_boundaries=(), dtype=dtype)
        learner = make_train(cfg)
        hp = Hparams.make(lr=1e-3)
        params, metrics = jax.jit(jax.vmap(learner.train, (0, None, None)))(
            jax.random.split(jax.random.PRNGKey(0), SEEDS), hp, data)
        out[dtype] = params, np.asarray(metrics["unweighted_loss"])
    return data, out


def test_the_drq_learner_fits_a_tiny_image_dataset(trained):
    data, out = trained
    losses = out["float32"][1]  # [seeds, iterations], each on a fresh minibatch before that step's update
    assert np.all(np.isfinite(losses))
    variance = float(data.action.var())  # the loss of the best blind (constant) prediction
    assert np.all(losses[:, -10:].mean(1) < 0.3 * losses[:, :3].mean(1)), losses
    assert np.all(losses[:, -10:].mean(1) < 0.3 * variance), (losses, variance)


def test_bfloat16_trains_as_float32_within_seed_noise_and_keeps_float32_parameters(trained):
    data, out = trained
    params, bf16 = out["bfloat16"]
    # mixed precision: parameters (and so Adam's moments, made like them) stay float32
    assert {leaf.dtype for leaf in jax.tree.leaves(params)} == {jnp.dtype(jnp.float32)}
    fp32 = out["float32"][1]
    assert np.all(np.isfinite(bf16))
    # the final loss (mean of the last 10 minibatches) of each seed: bfloat16's mean within two of float32's
    # seed-to-seed standard deviations of float32's mean, about 2.4 standard errors of a difference of two
    # 3-seed means (a 3% false alarm under the same distribution); and bf16 learns as float32 does
    end32, end16 = fp32[:, -10:].mean(1), bf16[:, -10:].mean(1)
    assert abs(end16.mean() - end32.mean()) <= 2 * end32.std(ddof=1), (end32, end16)
    assert np.all(end16 < 0.3 * bf16[:, :3].mean(1)), bf16
    # the same seed starts from the same parameters and minibatches: the first loss differs by rounding alone
    np.testing.assert_allclose(bf16[:, 0], fp32[:, 0], rtol=0.05)


def test_bfloat16_computes_in_bfloat16_and_answers_in_float32():
    cfg = LearnerConfig(obs_shape=(16, 16, 3), action_dim=2, encoder="drq", dtype="bfloat16")
    model = cfg.model()
    x = jax.random.uniform(jax.random.PRNGKey(0), (4, 16, 16, 6))
    variables = model.init(jax.random.PRNGKey(1), x)
    assert {leaf.dtype for leaf in jax.tree.leaves(variables)} == {jnp.dtype(jnp.float32)}
    hlo = jax.jit(model.apply).lower(variables, x).as_text()
    assert "bf16" in hlo
    action = model.apply(variables, x)
    assert action.dtype == jnp.float32
    full = LearnerConfig(obs_shape=(16, 16, 3), action_dim=2, encoder="drq").model().apply(variables, x)
    assert float(jnp.abs(action - full).max()) < 0.05 * float(jnp.abs(full).max()) + 1e-2
    # the state MLP and the patch encoder take the knob too
    for cfg in (LearnerConfig(obs_shape=(5,), action_dim=2, dtype="bfloat16", network="bn-mlp"),
                LearnerConfig(obs_shape=(16, 16, 3), action_dim=2, encoder="patch", dtype="bfloat16")):
        z = jnp.ones((3, 5 * 2) if len(cfg.obs_shape) == 1 else (3, 16, 16, 6))
        variables = cfg.model().init(jax.random.PRNGKey(0), z)
        assert cfg.model().apply(variables, z).dtype == jnp.float32
        assert {leaf.dtype for leaf in jax.tree.leaves(variables)} == {jnp.dtype(jnp.float32)}


# -- the dtype knob's refusals ----------------------------------------------------------------------------------------

def test_a_dtype_not_float32_or_bfloat16_is_refused_in_one_line(capsys):
    message = "recipe.dtype 'float16' is not one of float32, bfloat16"
    with pytest.raises(SettingsError) as exc:
        resolve("hopper", "pos", sets=["recipe.dtype=float16"])
    assert str(exc.value) == message
    with pytest.raises(SystemExit) as code:
        sweep.parse(["--set", "recipe.dtype=float16"], writes=False)
    err = capsys.readouterr().err
    assert code.value.code == 2 and message in err and err.count("\n") == 1
    with pytest.raises(ValueError, match="LearnerConfig.dtype 'float16' is not one of float32, bfloat16"):
        LearnerConfig(obs_shape=(5,), action_dim=2, dtype="float16")


def test_bfloat16_where_the_backend_has_none_is_refused_in_one_line(monkeypatch, capsys):
    assert models.bf16_problem() is None  # XLA:CPU, where the suite runs, takes it
    monkeypatch.setattr(models, "bf16_problem", lambda: "the GPU Tesla V100 (compute capability 7.0) has no "
                                                        "bfloat16 arithmetic (Ampere, 8.0, or later)")
    with pytest.raises(SystemExit) as code:
        sweep.parse(["--obs", "image", "--set", "recipe.dtype=bfloat16"], writes=False)
    err = capsys.readouterr().err
    assert code.value.code == 2 and err.count("\n") == 1
    assert "recipe.dtype 'bfloat16': the GPU Tesla V100 (compute capability 7.0) has no bfloat16" in err
    with pytest.raises(ValueError, match="LearnerConfig.dtype 'bfloat16': the GPU Tesla V100"):
        LearnerConfig(obs_shape=(5,), action_dim=2, dtype="bfloat16")
    resolve("hopper", "image", sets=["recipe.dtype=float32"])  # float32 needs nothing


@pytest.mark.parametrize("platform, capability, refused", [
    ("cpu", None, False), ("tpu", None, False), ("gpu", "9.0", False), ("gpu", "8.0", False),
    ("gpu", "7.5", True), ("gpu", None, True), ("METAL", None, True)])
def test_which_backends_have_bfloat16(monkeypatch, platform, capability, refused):
    device = types.SimpleNamespace(platform=platform, device_kind="a device", compute_capability=capability)
    monkeypatch.setattr(jax, "devices", lambda: [device])
    problem = models.bf16_problem()
    assert (problem is not None) == refused
    assert problem is None or "\n" not in problem


# -- settings recorded before the knob ------------------------------------------------------------------------------

def test_settings_and_checkpoints_recorded_before_dtype_are_float32(tmp_path):
    # a sweep's fingerprint (its checkpoint's sweep.json) and a results file's settings without recipe.dtype: the
    # sweep they ran was float32, so a float32 sweep resumes them and a bfloat16 one does not
    settings = resolve("hopper", "pos")
    assert settings.recipe.dtype == "float32"
    blocks = settings.to_json()
    del blocks["recipe"]["dtype"]
    assert Settings.from_json(blocks).recipe.dtype == "float32"
    protocol = {"name": settings.protocol.name}
    old = results_lib.fingerprint("hopper", "pos", "quick", blocks, ["bc"], None, protocol)
    now = results_lib.fingerprint("hopper", "pos", "quick", settings.to_json(), ["bc"], None, protocol)
    assert "dtype" not in json.dumps(old["settings"]["recipe"]) and checkpoint.differences(old, now) == []
    bf16 = dataclasses.replace(settings, recipe=dataclasses.replace(settings.recipe, dtype="bfloat16"))
    later = results_lib.fingerprint("hopper", "pos", "quick", bf16.to_json(), ["bc"], None, protocol)
    assert checkpoint.differences(old, later) == ["settings.recipe.dtype ('float32' there, 'bfloat16' now)"]
    # a checkpoint directory written before the knob opens (resumes) under today's float32 fingerprint
    directory = tmp_path / "checkpoints"
    checkpoint.SweepCheckpoint(directory, old, every=10).open()
    (directory / "state").mkdir()
    assert checkpoint.SweepCheckpoint(directory, now, every=10).open()
    with pytest.raises(checkpoint.CheckpointError, match="settings.recipe.dtype"):
        checkpoint.SweepCheckpoint(directory, later, every=10).open()
    assert RECIPES["mlp"].dtype == "float32"


def test_a_shipped_results_file_without_dtype_loads_as_float32():
    res = results_lib.load("results/halfcheetah-image-default.json")
    assert "dtype" not in res.settings["recipe"]
    settings = Settings.from_json(res.settings, preset=res.preset)
    assert settings.recipe.dtype == "float32"
    # its fingerprint against the same sweep's today (every recipe field written): no difference
    today = {**res.fingerprint(), "settings": settings.to_json()}
    assert "dtype" in today["settings"]["recipe"] and checkpoint.differences(res.fingerprint(), today) == []


# -- experiments.bench_images ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("args, message", [
    (["--dtype", "float16"], "--dtype: unknown ['float16']; valid: float32, bfloat16"),
    (["--encoders", "patch@64,drq@12"], "--encoders: drq@12 at 12x12: smaller than the encoder takes (drq: 15)"),
    (["--encoders", "drq@big"], "--encoders: a size after @ must be an integer"),
    (["--chunk", "0"], "must be >= 1"),
])
def test_bench_images_refuses_bad_input_before_timing(capsys, args, message):
    from experiments import bench_images

    with pytest.raises(SystemExit) as code:
        bench_images.main(args)
    err = capsys.readouterr().err
    assert code.value.code == 2 and message in err and err.strip().count("\n") == 0, err


def test_bench_images_refuses_bfloat16_where_the_backend_has_none(monkeypatch, capsys):
    from experiments import bench_images

    monkeypatch.setattr(models, "bf16_problem", lambda: "the METAL backend has no bfloat16 arithmetic")
    with pytest.raises(SystemExit) as code:
        bench_images.main(["--dtype", "float32,bfloat16", "--no-eval"])
    err = capsys.readouterr().err
    assert code.value.code == 2 and "--dtype bfloat16: the METAL backend has no bfloat16 arithmetic" in err


# -- returns: a whole sweep in each dtype ----------------------------------------------------------------------------

@pytest.mark.integration
def test_bfloat16_policies_score_as_float32_ones_within_seed_noise(tmp_path):
    """Mixed precision end to end (training, then evaluation in the jitted rollout) on the driving sandbox's state
    (the state MLP takes `recipe.dtype` as the image encoders do; an image policy that a CPU test can train, or a
    MuJoCo policy at the quick budget, scores too little to tell anything apart): BC-SO, 4 seeds of the quick
    preset per dtype, ~1 min each."""
    from experiments.stats import welch_difference

    scores, losses = {}, {}
    for dtype in models.DTYPES:
        out = tmp_path / dtype
        assert sweep.main(["--env", "toycar", "--obs", "full", "--preset", "quick", "--methods", "bc-so", "--seeds",
                           "4", "--set", "budget.probe_steps=0", "--set", f"recipe.dtype={dtype}", "--quiet",
                           "--out", str(out)]) == 0
        runs = json.loads((out / "results.json").read_text())["runs"]
        scores[dtype] = np.array([r["eval"]["normalized"] for r in runs])  # success, % of episodes
        losses[dtype] = np.array([r["train_loss_final"] for r in runs])
    assert scores["float32"].mean() >= 30 and scores["bfloat16"].mean() >= 30, scores  # the comparison has power
    # Welch's 95% intervals of the differences of the 4-seed means contain 0 (`experiments.stats`): the success
    # rate, and the final training loss; bfloat16's loss is float32's within 5% for every seed
    for values in (scores, losses):
        diff = welch_difference(values["bfloat16"], values["float32"])
        assert diff.low <= 0 <= diff.high, (values, diff)
    np.testing.assert_allclose(losses["bfloat16"], losses["float32"], rtol=0.05)
