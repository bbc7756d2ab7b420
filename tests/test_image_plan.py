"""The MuJoCo-Image plan's parts: frames rendered from state demonstrations (`protocol.frames=states`), the `drq`
recipe, and `experiments.device.images`' plan (the pretrained encoders fine-tuned, the frozen ones beside them),
estimate and refusals."""

import json

import jax
import numpy as np
import pytest

import envs
from ape_jax.pipeline import collect, data as data_lib, setup as setup_lib
from ape_jax.pipeline.hints import SettingsError
from ape_jax.pipeline.presets import resolve
from ape_jax.pipeline.setup import ExpertRef
from ape_jax.pipeline.spec import SweepSpec
from experiments.device import images


# -- frames from the simulator states ---------------------------------------------------------------------------------

def test_an_image_dataset_from_states_names_the_state_dataset_the_pos_sweep_collects():
    image = SweepSpec.make("hopper", "image", methods=["bc-oh"], preset="default", recipe="drq",
                           sets=["protocol.frames=states"])
    pos = SweepSpec.make("hopper", "pos", methods=["bc-oh"], protocol="brax",
                         sets=[f"protocol.episodes={image.episodes}"])
    key = image.setup.data_key
    assert key["frames"] == "states" and key["obs"] == "image" and key["env_overrides"]["image_size"] == [84, 84]
    assert setup_lib.state_source(key) == pos.setup.data_key
    # a rollout's frames keep the key they always had (no "frames" field): cached datasets stay valid
    rollout = SweepSpec.make("hopper", "image", methods=["bc-oh"], preset="default", recipe="drq").setup.data_key
    assert "frames" not in rollout and setup_lib.state_source(rollout) is rollout
    assert data_lib.cache_path("d", key) != data_lib.cache_path("d", rollout)


@pytest.mark.integration
def test_frames_from_states_render_the_rows_of_the_cached_state_dataset_and_save_no_frames(tmp_path):
    ref = ExpertRef.resolve("hopper", None)
    key = setup_lib.data_key("hopper", "image", 1, ref, frames="states", image_size=(16, 16), episode_length=12)
    demos, meta, path, cached = collect.collect_cached(key, tmp_path)
    assert not cached and path.name.startswith("hopper-pos-")
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".json", ".npz"]  # the state dataset only
    state, _ = data_lib.load(path)
    np.testing.assert_array_equal(demos.action, state.action)   # the same rows
    assert demos.obs.shape == (12, 16, 16, 3) and demos.obs.dtype == np.uint8
    env = envs.make("hopper", obs="image", image_size=(16, 16), episode_length=12)
    one = {k: np.asarray(v)[5] for k, v in state.sim.items()}
    np.testing.assert_array_equal(demos.obs[5], np.asarray(jax.jit(env.observe_sim)(one)))
    assert meta["frames"]["from"] == "states" and meta["frames"]["state_dataset"] == path.name
    assert meta["settings"] == json.loads(json.dumps(key)) and meta["frames"]["frames_per_s"] > 0
    again, _, _, cached = collect.collect_cached(key, tmp_path)
    assert cached and np.array_equal(again.obs, demos.obs)
    # the frames differ from the collecting rollout's only where the body moved in the step's last substep
    rollout = collect.collect(env, ref.policy(env), jax.random.PRNGKey(0), 1)
    np.testing.assert_allclose(rollout.action, demos.action, rtol=1e-4, atol=1e-5)
    assert np.mean(rollout.obs != demos.obs) < 0.05


@pytest.mark.parametrize("obs,sets,message", [
    ("pos", ["protocol.frames=states"], "protocol.frames=states: for image observations (--obs image) only"),
    ("image", ["protocol.frames=pixels"], "protocol.frames 'pixels' is not one of rollout, states"),
])
def test_frames_from_states_are_refused_where_they_cannot_be_made(obs, sets, message):
    with pytest.raises((ValueError, SettingsError), match=message.replace("(", r"\(").replace(")", r"\)")):
        SweepSpec.make("hopper", obs, methods=["bc-oh"], sets=sets)
    with pytest.raises(ValueError, match="toycar.*positions-only"):
        SweepSpec.make("toycar", "image", methods=["bc-oh"], sets=["protocol.frames=states"])


# -- the drq recipe ---------------------------------------------------------------------------------------------------

def test_the_drq_recipe_is_drq_at_84x84_with_shifts_whatever_the_image_preset():
    for preset in ("quick", "default", "paper"):
        s = resolve("hopper", "image", preset=preset, recipe="drq")
        assert (s.recipe.encoder, s.recipe.encoder_norm, s.recipe.augment_shift) == ("drq", "none", 4)
        assert s.protocol.image_size == (84, 84) and s.recipe.name == "drq"
    assert resolve("hopper", "image", recipe="drq", sets=["protocol.image_size=64x64"]).protocol.image_size == (64, 64)
    with pytest.raises(SettingsError, match=r"^recipe 'drq' is for image observations \(--obs image\)$"):
        resolve("hopper", "pos", recipe="drq")


# -- the plan ---------------------------------------------------------------------------------------------------------

def test_the_plan_fits_the_most_iterations_in_the_limit_and_runs_the_supplements_settings(monkeypatch):
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    p = images.plan(images.TASKS, 540.0, None, None, "bfloat16", False)
    assert p.models == 3 * 2 * 15 and p.seeds == 3 and p.iterations % p.chunk == 0 and p.iterations >= p.chunk
    assert p.total_s + images.MARGIN_S <= 540.0
    with pytest.raises(ValueError, match="exceeds the limit of 540 s"):
        images.plan(images.TASKS, 540.0, p.iterations + p.chunk, None, "bfloat16", False)
    # a fast enough device gets the paper's budget, and no more
    assert images.plan(images.TASKS, 10_000.0, None, 1e9, "bfloat16", False).iterations == images.PAPER_ITERATIONS
    assert sorted(p.argv) == sorted(f"{t}-{v}" for t in images.TASKS for v in ("finetune", "frozen"))
    hopper, frozen, cheetah = p.argv["hopper-finetune"], p.argv["hopper-frozen"], p.argv["halfcheetah-finetune"]
    for flag in ("protocol.frames=states", "recipe.perception=task", "ours-step.grid=0.1:5", "budget.seeds=3",
                 "recipe.dtype=bfloat16", "budget.width=15", f"budget.iterations={p.iterations}"):
        assert flag in hopper and flag in frozen   # the baseline at the same budget, in the same run
    assert "recipe.perception_training=finetune" in hopper and "recipe.perception_training=frozen" in frozen
    assert "ours-softmax.taus=0.2" in hopper and "fca.alphas=0.1" in hopper
    assert "ours-softmax.taus=0.1" in cheetah and "fca.alphas=0.5" in cheetah
    assert hopper[hopper.index("--obs") + 1] == "image" and "--recipe" not in hopper


def test_the_plan_fine_tunes_the_shipped_encoder_at_its_image_size():
    spec = images._spec("hopper", "finetune", "float32")
    assert spec.recipe.encoder == "perception" and spec.policy_obs == "image"
    assert spec.protocol.image_size == (32, 32) and len(spec.recipe.perception_sha256) == 64
    frozen = images._spec("hopper", "frozen", "float32")
    assert frozen.policy_obs == "embedding" and frozen.recipe.perception_sha256 == spec.recipe.perception_sha256


@pytest.mark.parametrize("argv,message", [
    (["--limit-s", "480", "--iterations", "300000"], "exceeds the limit of 480 s; give fewer --iterations"),
    (["--limit-s", "30"], "the plan does not fit in 30 s"),
    (["--tasks", "hopper,ant"], "--tasks: unknown ['ant']"),
    (["--limit-s", "0"], "must be numbers > 0"),
    (["--dtype", "float16"], "--dtype 'float16' is not one of float32, bfloat16"),
])
def test_a_plan_that_cannot_run_is_refused_in_one_line_before_anything_is_written(argv, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        images.main([*argv, "--out", str(tmp_path / "out"), "--work", str(tmp_path / "work")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists() and not (tmp_path / "work").exists()


def test_a_plan_without_its_state_demonstrations_names_the_commands_that_collect_them(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("APE_JAX_CACHE", str(tmp_path / "data"))
    with pytest.raises(SystemExit) as exc:
        images.main(["--limit-s", "100000", "--rate", "1e9", "--tasks", "hopper,walker2d", "--out",
                     str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1
    assert "no state demonstrations cached for 2 task(s)" in err
    assert "python -m experiments.collect --env walker2d --obs pos --protocol brax --episodes 100" in err
    assert not (tmp_path / "out").exists()


def test_the_dry_run_prints_the_plan_and_the_sweeps_it_would_run(capsys):
    assert images.main(["--limit-s", "100000", "--rate", "1e9", "--dry-run", "--tasks", "hopper"]) == 0
    out = capsys.readouterr().out
    assert "300,000 iterations (the paper's budget)" in out
    assert "hopper-finetune: python -m experiments.sweep --env hopper --obs image --preset default" in out
    assert "recipe.perception_training=finetune" in out and "hopper-frozen: " in out


def test_collect_refuses_frames_from_states_and_names_the_state_dataset_to_collect(capsys):
    from experiments import collect as collect_cli

    with pytest.raises(SystemExit) as exc:
        collect_cli.parse(["--env", "hopper", "--obs", "image", "--set", "protocol.frames=states"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.count("\n") == 1 and "collect that state dataset with --obs pos" in err
