"""The perception encoder fine-tuned end to end (`recipe.perception_training=finetune`, `ape_jax.perception.tuned`):
the policy starts from the file's weights, sees each frame's embedding, trains the encoder, and what cannot run is
refused in one line."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import perception
from ape_jax.perception import card as card_lib
from ape_jax.perception.tuned import PretrainedEncoder
from ape_jax.pipeline import presets
from ape_jax.pipeline.presets import SettingsError
from tests.test_perception import tiny_encoder

TUNE = "recipe.perception_training=finetune"


@pytest.fixture
def tuned(tmp_path):
    """`(path, sha256, settings)`: a user's encoder and a ToyTown camera sweep's settings that fine-tune it."""
    path = tmp_path / "mine.npz"
    sha = tiny_encoder(path)
    return path, sha, presets.resolve("toytown", "image", preset="default", sets=[f"recipe.perception={path}", TUNE])


def _frames(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, 64, 64, 3), np.uint8)


def test_the_recipe_builds_a_pixel_policy_that_starts_from_the_encoders_weights(tuned):
    path, sha, s = tuned
    assert (s.recipe.encoder, s.recipe.perception_sha256, s.recipe.perception_training) == ("perception", sha,
                                                                                            "finetune")
    cfg = s.learner_config((64, 64, 3), 3, 2, "l1")
    assert cfg.images and cfg.encoder == "perception" and cfg.perception_sha256 == sha
    params = cfg.model().init(jax.random.PRNGKey(1), jnp.zeros((1, 64, 64, 6)))
    start = params["params"]["perception"]["net"]
    saved = card_lib.load(path).params["params"]
    assert jax.tree.structure(start) == jax.tree.structure(saved)
    for a, b in zip(jax.tree.leaves(start), jax.tree.leaves(saved), strict=True):
        np.testing.assert_array_equal(a, b)   # the file's weights, not a fresh draw


def test_each_frame_of_the_history_is_embedded_as_the_frozen_stage_embeds_it(tuned):
    path, sha, _ = tuned
    enc = card_lib.load(path)
    first, second = _frames(2, seed=3)
    stacked = np.concatenate([first, second], axis=-1)[None].astype(np.float32) / 255.0   # [1, 64, 64, 6]
    module = PretrainedEncoder(sha)
    variables = module.init(jax.random.PRNGKey(0), stacked)
    got = np.asarray(module.apply(variables, stacked))
    want = perception.embed_frames(enc, np.stack([first, second])).reshape(1, -1)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_the_bc_loss_reaches_the_encoders_weights(tuned):
    _, _, s = tuned
    model = s.learner_config((64, 64, 3), 3, 2, "l1").model()
    frames = jnp.asarray(_frames(8, seed=5).reshape(4, 64, 64, 6), jnp.float32) / 255.0
    params = model.init(jax.random.PRNGKey(0), frames)
    grads = jax.grad(lambda p: jnp.sum(model.apply(p, frames) ** 2))(params)["params"]
    # fine-tuned: the patch layer's kernel learns (the frozen stage's `stop_gradient` would give zeros) ...
    assert float(jnp.abs(grads["perception"]["net"]["patch_0"]["kernel"]).max()) > 0
    # ... and the read-out, which nothing reads, does not
    assert float(jnp.abs(grads["perception"]["net"]["readout"]["kernel"]).max()) == 0


@pytest.mark.parametrize("sets, words", [
    ([TUNE], "name it with recipe.perception"),
    (["recipe.encoder=perception"], "is a pretrained encoder fine-tuned"),
    (["recipe.perception={path}", "recipe.perception_training=thaw"], "frozen or finetune, got 'thaw'"),
    (["recipe.perception={path}", TUNE, "recipe.perception_output=readout"], "is the frozen stage's"),
    (["recipe.perception={path}", TUNE, "recipe.encoder_norm=group"], "fine-tunes the encoder"),
])
def test_finetuning_settings_that_cannot_run_are_refused_in_one_line(tmp_path, sets, words):
    path = tmp_path / "mine.npz"
    tiny_encoder(path)
    with pytest.raises(SettingsError, match=words) as e:
        presets.resolve("toytown", "image", sets=[item.format(path=path) for item in sets])
    assert "\n" not in str(e.value)


def test_a_policy_of_an_encoder_this_process_never_loaded_is_refused():
    with pytest.raises(perception.PerceptionError, match="no perception encoder with SHA-256 abcdef"):
        perception.perceived.loaded("abcdef" + "0" * 58)


def test_a_finetuning_sweep_trains_pixel_policies(tuned):
    from ape_jax.pipeline.spec import SweepSpec

    path, _, _ = tuned
    spec = SweepSpec.make("toytown", "image", methods=("bc-so", "bc-oh", "ours-step", "fca"), preset="default",
                          sets=[f"recipe.perception={path}", TUNE])
    assert spec.policy_obs == "image"


def test_a_fine_tuned_encoders_results_never_merge_with_the_frozen_ones_in_the_report():
    import json
    import pathlib

    from ape_jax.pipeline import results as results_lib
    from experiments.report.analysis import groups

    root = pathlib.Path(__file__).resolve().parents[1]
    obj = json.loads((root / "results" / "toytown-image-nocrash-default-seeds0.json").read_text())
    files = []
    for training in ("frozen", "finetune"):
        o = json.loads(json.dumps(obj))
        o["settings"]["recipe"].update(perception="task", perception_sha256="a" * 64, perception_training=training)
        files.append(results_lib.Results.from_json(o))
    merged = groups.merge(files)
    assert {k.perception for k in merged} == {"a" * 12, "a" * 12 + ":finetune"}
    assert any(g.title.endswith("through the pretrained encoder aaaaaaaa, fine-tuned)") for g in merged.values())
    assert len({groups.file_stem(g) for g in merged.values()}) == 2


def test_the_mujoco_image_tables_put_the_encoders_groups_in_a_table_of_their_own():
    import json
    import pathlib

    from ape_jax.pipeline import results as results_lib
    from experiments.report.analysis import groups
    from experiments.report.sections.state import perceived_groups, state_table

    root = pathlib.Path(__file__).resolve().parents[1]
    files = [results_lib.Results.from_json(json.loads((root / "results" / "hopper-image-patch-bc.json").read_text()))]
    for task in ("hopper", "walker2d"):
        files.append(results_lib.Results.from_json(json.loads(
            (root / "results" / "exploratory" / f"{task}-image-perceived-gate.json").read_text())))
    merged = groups.merge(files)
    perceived = perceived_groups(merged, "brax")
    assert [m.env for m in perceived] == ["hopper", "walker2d"]
    assert all(m.protocol["perception"] for m in perceived)
    scratch, through = state_table(merged, "image", "brax"), state_table(merged, "image", "brax", perceived)
    assert "Hopper" in scratch and "Hopper" in through
    assert "Walker2d" in through and "Walker2d" not in scratch   # the gate's Walker2d sits only in its own table
    assert "(14%)" in through and "(14%)" not in scratch          # Hopper's BC-SO through the encoder: 14.1%


def test_the_image_sections_stand_with_the_encoders_groups_alone():
    import json
    import pathlib

    from ape_jax.pipeline import results as results_lib
    from experiments.report.analysis import groups
    from experiments.report.sections.common import Context
    from experiments.report.sections.state import image_sections

    root = pathlib.Path(__file__).resolve().parents[1]
    files = [results_lib.Results.from_json(json.loads(
        (root / "results" / "exploratory" / "hopper-image-perceived-gate.json").read_text()))]
    ctx = Context(groups.merge(files), None, root)
    assert [s.title for s in image_sections(ctx)] == ["MuJoCo-Image, through the pretrained encoders"]
