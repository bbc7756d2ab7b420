"""Recipes and the three settings records: `resolve` and `--set`, BatchNorm per configuration in a vmapped grid,
the FCA code's split by rows, and what results.json records of them."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import methods, weighting
from ape_jax.history import history_index
from ape_jax.learner import Data, Hparams, LearnerConfig, learning_rate, lr_boundaries, make_train, stack_hparams
from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline import sweep as S
from ape_jax.pipeline.checkpoint import CheckpointError, SweepCheckpoint
from ape_jax.pipeline.presets import RECIPES, SettingsError, format_set, parse_set, resolve
from ape_jax.pipeline.replay import arguments
from experiments import sweep
from _compare import STATS_RTOL, UPDATE_RTOL, stats_mismatch, update_mismatch

LOSS_RTOL = 1e-4


# -- the records ----------------------------------------------------------------------------------------------------

def test_the_mujoco_state_protocols_default_to_the_fca_codes_recipe_and_the_others_to_mlp():
    s = resolve("hopper", "pos")
    assert (s.protocol.name, s.protocol.split, s.recipe.name, s.budget.iterations) == \
        ("mujoco-state", "rows", "bn-mlp", 3_000)
    assert (s.recipe.network, s.recipe.init, s.recipe.beta1, s.recipe.batch_size) == ("bn-mlp", "xavier", 0.5, 64)
    assert resolve("hopper", "pos", protocol="brax").recipe == RECIPES["mlp"]
    assert resolve("hopper", "image").recipe.name == "mlp" and resolve("toycar", "image").recipe.name == "mlp"
    cfg = s.learner_config((5,), 3, 2, "l2")
    assert (cfg.network, cfg.batch_size, cfg.beta1, cfg.lr_boundaries) == ("bn-mlp", 64, 0.5, (1_000, 2_000))
    image = resolve("hopper", "image", recipe="bn-mlp").learner_config((32, 32, 3), 3, 2, "l2")
    assert image.network == "mlp" and image.encoder == "small"   # BatchNorm is the state network's


def test_smoke_shrinks_the_amounts_and_keeps_what_a_step_computes():
    paper, smoke = resolve("hopper", "image", preset="paper"), resolve("hopper", "image", preset="paper", smoke=True)
    assert smoke.smoke and not paper.smoke and smoke.preset == "paper"
    for kept in ("encoder", "network", "beta1", "lr", "lr_decay_at", "encoder_norm", "augment_shift"):
        assert getattr(smoke.recipe, kept) == getattr(paper.recipe, kept)
    assert smoke.recipe.encoder == "resnet18"
    for kept in ("image_size", "history", "frame_skip", "split", "name"):
        assert getattr(smoke.protocol, kept) == getattr(paper.protocol, kept)
    b = smoke.budget
    assert (b.iterations, b.seeds, b.eval_episodes, b.chunk, b.eval_at, b.probe_steps) == (4, 1, 2, 2, (2,), 10)
    assert (smoke.recipe.batch_size, smoke.knob("ours-step").grid, smoke.knob("ours-softmax").taus) == \
        (4, ((0.1, 3.0),), (0.1,))
    assert smoke.knob("palr").weights == (10.0,) and "palr" not in smoke.knobs   # one setting already: its defaults
    assert (smoke.protocol.episodes, smoke.protocol.horizon) == (3, 20)
    rows = resolve("hopper", "pos", preset="paper", smoke=True).protocol   # the fca protocol splits by rows
    assert (rows.split, rows.collect_transitions, rows.train_transitions, rows.val_transitions) == \
        ("rows", 240, 144, 48)
    assert resolve("hopper", "pos", smoke=True, sets=["budget.iterations=8"]).budget.iterations == 8  # --set wins
    assert resolve("hopper", "pos", preset="default", smoke=True, sets=["budget.probe_steps=0"]).budget.probe_steps == 0


def test_set_changes_any_field_parsed_by_its_type():
    s = resolve("hopper", "pos", preset="default", sets=[
        "recipe.batch_size=32", "recipe.lr=1e-3", "ours-step.grid=0.1:4,0.2:6", "recipe.fca_alphas=0.1,2",
        "protocol.split=episodes", "protocol.eval_steps=1000", "protocol.image_size=16x24", "budget.seeds=7",
        "recipe.loss=l1", "recipe.loss=none"])
    assert (s.recipe.batch_size, s.recipe.lr, s.knob("ours-step").grid) == (32, 1e-3, ((0.1, 4.0), (0.2, 6.0)))
    assert s.recipe.loss is None   # the last --set of a field wins
    # an old recipe name of a method's knob sets what it means now: FCA's and FCA-IB's α
    assert s.knob("fca").alphas == s.knob("fca-ib").alphas == (0.1, 2.0)
    assert (s.protocol.split, s.protocol.eval_steps, s.protocol.image_size) == ("episodes", 1000, (16, 24))
    assert s.budget.seeds == 7 and s.budget.iterations == 30_000
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.recipe.lr = 1.0   # nothing rewrites a record after it is built
    assert parse_set("budget.chunk=100") == ("budget", "chunk", 100)


@pytest.mark.parametrize("env, obs, protocol, preset, recipe, sets, smoke", [
    ("hopper", "pos", None, "default", None, [], False),
    ("hopper", "pos", "mujoco-state-fs2", "paper", "mlp", ["recipe.batch_size=32", "recipe.lr=1e-3", "budget.seeds=4",
                                                  "recipe.step_grid=0.1:4,0.2:6", "recipe.fca_alphas=",
                                                  "recipe.fca_adversary_lr=0.0002",
                                                  "recipe.lr_decay_at=0.25", "recipe.loss=none",
                                                  "budget.iterations=50000", "budget.first_seed=4"], False),
    ("walker2d", "pos", "brax", "quick", "fca", ["protocol.history=3", "budget.eval_at=2"], True),
    ("halfcheetah", "image", None, "default", None, ["protocol.image_size=16x24", "recipe.encoder=small",
                                                     "recipe.encoder_norm=none", "recipe.augment_shift=2"], False),
])
def test_the_arguments_of_recorded_settings_resolve_to_them_again(env, obs, protocol, preset, recipe, sets, smoke):
    """`arguments` (a Python-run file's command, rebuilt by the report) is `resolve`'s inverse through the sweep's
    command line, and sets nothing the preset, protocol or recipe already gives."""
    target = resolve(env, obs, protocol, preset, recipe, sets=sets, smoke=smoke)
    args = arguments(env, obs, target)
    given = [a for prev, a in zip(args, args[1:]) if prev == "--set"]
    # the sweep refuses a method's setting for a method it does not run: run those whose settings are given
    owners = [m for m in dict.fromkeys(g.partition(".")[0] for g in given) if m in methods.names()]
    runs = ["--methods", ",".join(["bc-oh", *owners]), "--yes"] if owners else []
    again = sweep.parse(["--env", env, "--obs", obs, *args, *runs], writes=False).settings
    assert dataclasses.replace(again, preset_iterations=None) == dataclasses.replace(target, preset_iterations=None)
    for item in given:  # each one needed
        rest = [g for g in given if g != item]
        assert resolve(env, obs, protocol, preset, recipe, sets=rest, smoke=smoke) != target, item
    if not sets:
        assert args == ["--preset", preset]
    for section, field, value in [("recipe", "lr", 2e-4 / 3), ("protocol", "image_size", (16, 24)),
                                  ("recipe", "loss", None), ("budget", "chunk", 500)]:
        assert parse_set(format_set(section, field, value)) == (section, field, value)
    assert parse_set("ours-step.grid=0.1:4,0.2:6") == ("ours-step", "grid", ((0.1, 4.0), (0.2, 6.0)))
    assert parse_set("recipe.fca_alphas=") == ("recipe", "fca_alphas", ())   # an old name, parsed as fca.alphas


@pytest.mark.parametrize("item, message", [
    ("recipe.nope=1", "unknown field recipe.nope; valid: recipe.network, recipe.init"),
    ("nope.x=1", "unknown section 'nope'; valid: protocol, budget, recipe"),
    ("recipe.batch_size", "is not SECTION.FIELD=VALUE"),
    ("recipe.batch_size=1.5", "recipe.batch_size takes int"),
    ("recipe.beta1=1", "recipe.beta1 must be in [0, 1)"),
    ("recipe.network=cnn", "recipe.network 'cnn' is not one of mlp, bn-mlp"),
    ("recipe.step_grid=0.1", "is not THR:W"),
    ("recipe.softmax_grid=0,1", "every value must be a finite number > 0"),
    ("recipe.fca_adversary_lr=0", "fca: adversary_lr must be > 0 and finite, got 0.0"),
    ("fca.adversary_lr=-1", "fca: adversary_lr must be > 0 and finite, got -1.0"),
    ("ours-step.grid=0.1:0.5", "ours-step: grid: THR must be in (0, 1) and W a finite number >= 1, got 0.1:0.5"),
    ("budget.iterations=0", "budget.iterations must be an integer >= 1"),
    ("budget.seeds=none", "budget.seeds takes int"),
    ("protocol.split=halves", "protocol.split 'halves' is not one of rows, episodes"),
    ("protocol.train_transitions=none", "split 'rows' needs train_transitions"),
])
def test_a_bad_set_is_refused_in_one_line_before_anything_compiles(item, message, capsys):
    with pytest.raises(SettingsError, match=None) as exc:
        resolve("hopper", "pos", sets=[item])
    assert message in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(SystemExit) as code:
        sweep.parse(["--set", item], writes=False)
    err = capsys.readouterr().err
    assert code.value.code == 2 and message in err and err.count("\n") == 1


@pytest.mark.parametrize("field, value", [("network", "cnn"), ("init", "he"), ("encoder", "vit"),
                                          ("encoder_norm", "batch"), ("loss", "huber"), ("lr_schedule", "linear"),
                                          ("beta1", 1.0), ("beta2", -0.1), ("bn_momentum", 0.0), ("lr_decay", 1.5),
                                          ("batch_size", 0), ("augment_shift", -1)])
def test_a_knob_the_learner_takes_from_the_recipe_has_one_rule_for_both(field, value):
    """`ape_jax.knobs`: the recipe (what a user sets) and the LearnerConfig (what a program is built from) refuse a
    bad value by the same rule, in the same words but for the record's name."""
    with pytest.raises(SettingsError) as recipe:
        dataclasses.replace(RECIPES["mlp"], **{field: value})
    shape = (32, 32, 3) if field in ("encoder", "encoder_norm", "augment_shift") else (5,)
    with pytest.raises(ValueError) as config:
        LearnerConfig(obs_shape=shape, action_dim=2, **{field: value})
    assert str(recipe.value).startswith(f"recipe.{field} ")
    assert str(config.value) == str(recipe.value).replace("recipe.", "LearnerConfig.", 1)


@pytest.mark.parametrize("obs, history, length", [("image", 1_001, 1_000), ("pos", 2_001, 2_000)])
def test_a_history_longer_than_an_episode_is_refused_before_anything_compiles(obs, history, length, tmp_path,
                                                                            capsys):
    with pytest.raises(SystemExit) as code:
        sweep.main(["--obs", obs, "--set", f"protocol.history={history}", "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code.value.code == 2 and err.count("\n") == 1 and not (tmp_path / "run").exists()
    assert f"protocol.history {history} is longer than an episode ({length:,} steps)" in err
    S.SweepSpec.make("hopper", obs, sets=[f"protocol.history={length}"])  # one whole episode is fine


@pytest.mark.parametrize("obs, item, message", [
    ("image", "recipe.augment_shift=9", "recipe.augment_shift must be at most a quarter of the image's shorter side "
                                        "(32: 8), got 9"),
    ("image", "recipe.augment_shift=-1", "recipe.augment_shift must be an integer >= 0, got -1"),
    ("image", "recipe.encoder_norm=batch", "recipe.encoder_norm 'batch' is not one of none, group"),
    ("pos", "recipe.augment_shift=2", "recipe.augment_shift=2: for image observations (--obs image) only"),
    ("pos", "recipe.encoder_norm=group", "recipe.encoder_norm=group: for image observations (--obs image) only"),
])
def test_an_image_setting_the_observations_cannot_take_is_refused_before_anything_compiles(obs, item, message,
                                                                                           capsys):
    with pytest.raises(SettingsError) as exc:
        resolve("hopper", obs, sets=[item])
    assert message in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(SystemExit) as code:
        sweep.parse(["--obs", obs, "--set", item], writes=False)
    err = capsys.readouterr().err
    assert code.value.code == 2 and message in err and err.count("\n") == 1
    # the paper's image preset (ResNet-18) normalises its own layers
    with pytest.raises(SettingsError, match="is for the encoders 'small', 'patch' and 'drq'"):
        resolve("hopper", "image", preset="paper", sets=["recipe.encoder_norm=group"])


def test_an_unknown_recipe_is_refused_listing_the_valid_ones(capsys):
    with pytest.raises(SystemExit) as code:
        sweep.parse(["--recipe", "resnet"], writes=False)
    assert code.value.code == 2 and "unknown recipe 'resnet'; valid: mlp, bn-mlp" in capsys.readouterr().err


def test_a_resumed_sweep_with_another_recipe_is_refused_naming_the_fields(tmp_path):
    fca = S.SweepSpec.make("hopper", "pos", ("bc-oh",))
    other = S.SweepSpec.make("hopper", "pos", ("bc-oh",), recipe="bn-mlp", sets=["recipe.batch_size=32"])
    SweepCheckpoint(tmp_path / "ck", fca.fingerprint(), 100).open()
    with pytest.raises(CheckpointError, match="settings.recipe.batch_size \\(64 there, 32 now\\)"):
        SweepCheckpoint(tmp_path / "ck", other.fingerprint(), 100).open()


def test_a_checkpoint_from_before_a_recipe_field_existed_resumes_when_the_field_is_at_its_default(tmp_path):
    import json

    spec = S.SweepSpec.make("hopper", "pos", ("bc-oh",), recipe="bn-mlp")
    older = spec.fingerprint()
    for field in ("encoder_norm", "augment_shift"):  # fields added after such checkpoints were written
        del older["settings"]["recipe"][field]
    SweepCheckpoint(tmp_path / "ck", older, 100).open()
    assert "augment_shift" not in json.loads((tmp_path / "ck" / "sweep.json").read_text())["settings"]["recipe"]
    assert SweepCheckpoint(tmp_path / "ck", spec.fingerprint(), 100).open() is False  # accepted (nothing saved yet)
    image = S.SweepSpec.make("hopper", "image", ("bc-oh",), sets=["recipe.augment_shift=2"])
    older = image.fingerprint()
    del older["settings"]["recipe"]["augment_shift"]
    SweepCheckpoint(tmp_path / "img", older, 100).open()
    with pytest.raises(CheckpointError, match="settings.recipe.augment_shift \\(0 there, 2 now\\)"):
        SweepCheckpoint(tmp_path / "img", image.fingerprint(), 100).open()


def test_the_learning_rate_drops_at_the_recipes_fractions_of_the_run():
    assert lr_boundaries(300_000, (1 / 3, 2 / 3)) == (100_000, 200_000)
    assert lr_boundaries(30, (0.5, 0.99)) == (15,)   # a drop at the last step or after it is no drop
    cfg = LearnerConfig(obs_shape=(4,), action_dim=2, iterations=30, lr_boundaries=lr_boundaries(30, (1 / 3, 2 / 3)))
    lrs = [float(learning_rate(cfg, jnp.float32(1.0), jnp.int32(s))) for s in (0, 9, 10, 19, 20, 29)]
    np.testing.assert_allclose(lrs, [1.0, 1.0, 0.1, 0.1, 0.01, 0.01], rtol=1e-6)


# -- BatchNorm per configuration -------------------------------------------------------------------------------------

def _dataset(n_episodes=6, length=40, obs_dim=4, action_dim=2, seed=0, rows=None):
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n_episodes * length, obs_dim)).astype(np.float32) * 3 + 1
    action = np.tanh(obs @ rng.normal(size=(obs_dim, action_dim)).astype(np.float32) / 3)
    t = np.tile(np.arange(length, dtype=np.int32), n_episodes)
    n = len(obs) if rows is None else len(rows)
    return Data(obs=jnp.asarray(obs), action=jnp.asarray(action), t=jnp.asarray(t),
                ape=jnp.asarray(rng.exponential(size=n).astype(np.float32)),
                rows=None if rows is None else jnp.asarray(rows, jnp.int32))


BN = LearnerConfig(obs_shape=(4,), action_dim=2, history=2, iterations=4, batch_size=32, network="bn-mlp",
                   init="xavier", beta1=0.5)
GRID = [Hparams.make("uniform", lr=1e-3), Hparams.make("step", lr=1e-3, thr=0.2, w=5.0),
        Hparams.make("softmax", lr=1e-3, tau=0.5)]


def test_a_batchnorm_configuration_in_a_six_wide_grid_equals_it_trained_alone():
    data = _dataset()
    learner = make_train(BN)
    keys = jax.random.split(jax.random.PRNGKey(1), 6)
    grid = stack_hparams(GRID + GRID)   # 3 weightings x 2 seeds
    params, metrics = jax.jit(jax.vmap(learner.train, (0, 0, None)))(keys, grid, data)
    single = jax.jit(learner.train)
    init = jax.jit(lambda k: learner.init(k, GRID[0], data).params)
    stats = [jax.tree.map(lambda x: np.asarray(x[i]), params["batch_stats"]) for i in range(6)]
    for i in range(6):
        p_i, m_i = single(keys[i], jax.tree.map(lambda x: x[i], grid), data)
        row = jax.tree.map(lambda x: x[i], params)
        np.testing.assert_allclose(metrics["loss"][i], m_i["loss"], rtol=LOSS_RTOL)
        assert update_mismatch(row["params"], p_i["params"], init(keys[i])["params"]) < UPDATE_RTOL, i
        # its own running statistics, as trained alone, moved from their start (mean 0, variance 1)
        assert stats_mismatch(stats[i], p_i["batch_stats"]) < STATS_RTOL, i
        assert np.abs(stats[i]["norm_0"]["mean"]).max() > 1e-2
        assert stats_mismatch(stats[(i + 1) % 6], p_i["batch_stats"]) > 100 * STATS_RTOL, i   # not shared


def test_a_batchnorm_policy_is_evaluated_on_its_running_statistics():
    data = _dataset()
    params, _ = jax.jit(make_train(BN).train)(jax.random.PRNGKey(0), GRID[0], data)
    model = BN.model()
    x = jnp.asarray(np.random.default_rng(1).normal(size=(16, 8)), jnp.float32)
    alone = jnp.concatenate([model.apply(params, x[i:i + 1]) for i in range(16)])
    np.testing.assert_allclose(np.asarray(model.apply(params, x)), np.asarray(alone), rtol=1e-5, atol=1e-6)
    trained, _ = model.apply(params, x, train=True, mutable=["batch_stats"])   # batch statistics: another function
    assert not np.allclose(np.asarray(trained), np.asarray(alone), atol=1e-3)
    mean0 = params["batch_stats"]["norm_0"]["mean"]
    assert mean0.shape == (300,) and "bias" not in params["params"]["encoder_0"]   # bias-free before BatchNorm


# -- the split by rows -----------------------------------------------------------------------------------------------

def _demos(lengths):
    t = np.concatenate([np.arange(n) for n in lengths]).astype(np.int32)
    episode = np.concatenate([np.full(n, i) for i, n in enumerate(lengths)]).astype(np.int32)
    n = len(t)
    return data_lib.Demonstrations(obs=np.arange(n, dtype=np.float32)[:, None],
                                   action=np.arange(n, dtype=np.float32)[:, None],
                                   executed=np.zeros((n, 1), np.float32), episode=episode, t=t,
                                   done=np.zeros(n, np.float32), reward=np.zeros(n, np.float32), sim={})


def test_the_split_by_rows_draws_exact_disjoint_rows_from_all_episodes_by_a_fixed_permutation():
    demos = _demos([100] * 25)
    train, val = data_lib.split_parts(demos, "rows", 2_000, 400, seed=0)
    assert (len(train), len(val)) == (2_000, 400) and train.demos is demos and val.demos is demos
    assert not set(train.rows) & set(val.rows)
    perm = np.random.default_rng(0).permutation(len(demos))
    assert set(train.rows) == set(perm[:2_000]) and set(val.rows) == set(perm[2_000:2_400])
    assert train.num_episodes == 25 and val.num_episodes == 25   # rows from every episode, unlike whole episodes
    again, _ = data_lib.split_parts(demos, "rows", 2_000, 400, seed=0)
    np.testing.assert_array_equal(again.rows, train.rows)
    np.testing.assert_array_equal(train.obs[:, 0], train.rows)   # the part's own rows
    by_episode, _ = data_lib.split_parts(demos, "episodes", 2_000, 400)
    assert by_episode.rows is None and len(by_episode) == 2_000
    with pytest.raises(ValueError, match="fewer than the 2,400 \\+ 200"):
        data_lib.split_parts(demos, "rows", 2_400, 200)


def test_rows_are_trained_on_with_histories_from_whole_episodes_and_ranked_among_themselves():
    demos = _demos([50] * 4)
    train, _ = data_lib.split_parts(demos, "rows", 60, 20, seed=3)
    # the normaliser reads the training rows only
    norm = S.Normalizer.fit(train.obs)
    np.testing.assert_allclose(norm.mean, np.asarray(demos.obs)[train.rows].mean(0), rtol=1e-6)
    # every minibatch row is a training row; its history reads the rows before it in its episode
    data = Data(obs=jnp.asarray(demos.obs), action=jnp.asarray(demos.action), t=jnp.asarray(demos.t),
                ape=jnp.arange(60, dtype=jnp.float32), rows=jnp.asarray(train.rows, jnp.int32))
    pos, idx = data.sample(jax.random.PRNGKey(0), 4096)
    assert set(np.asarray(idx)) <= set(train.rows) and len(set(np.asarray(pos))) == 60
    cfg = LearnerConfig(obs_shape=(1,), action_dim=1, history=3, iterations=1, batch_size=8)
    x = make_train(cfg).policy_input(data.obs[history_index(data.t, idx, 3)])
    rows = np.asarray(idx)
    t = np.asarray(demos.t)[rows]
    want = np.stack([np.maximum(rows - 2, rows - t), np.maximum(rows - 1, rows - t), rows], 1).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(x), want)   # obs = row index: the previous rows, training or not
    # the step function ranks the split's rows only: THR 10% of 60 rows = the 6 with the largest APE
    w = weighting.dataset_weights(data.score_table(), Hparams.make("step", thr=0.1, w=5.0).weighting)
    assert w.shape == (60,) and set(np.flatnonzero(np.asarray(w) == 5.0)) == set(range(54, 60))


def test_the_learner_never_trains_on_rows_outside_the_split():
    rows = np.arange(0, 240, 2)   # every other row
    data = _dataset(rows=rows)
    poisoned = data.replace(action=data.action.at[1::2].set(1e3))   # only rows outside the split
    cfg = dataclasses.replace(BN, iterations=30)
    _, metrics = jax.jit(make_train(cfg).train)(jax.random.PRNGKey(0), GRID[0], poisoned)
    assert float(np.max(metrics["unweighted_loss"])) < 100.0   # one poisoned row in a batch would cost ~1e6 / 32
