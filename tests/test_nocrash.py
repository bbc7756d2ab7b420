"""The NoCrash protocols (`nocrash`, `nocrash-nospeed`): what they set in ToyTown for collection and for
evaluation, how they name the demonstrations, CILRS's weighted L1, and the refusals of a setting a task lacks."""

import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import tasks
from ape_jax.learner import LearnerConfig, action_errors
from ape_jax.pipeline.presets import resolve
from ape_jax.pipeline.setup import Setup


def _setup(protocol, sets=()):
    return Setup.resolve("toytown", "image", resolve("toytown", "image", protocol=protocol, sets=sets).protocol)


def test_nocrash_collects_in_the_training_layouts_and_evaluates_in_the_held_out_ones():
    setup = _setup(None)                                   # ToyTown's default protocol
    assert setup.protocol.name == "nocrash"
    collection = {k: v for k, v in setup.collection.items() if k != "image_size"}   # the preset's
    assert collection == {"traffic": "dense", "speed_input": True, "task_version": 2}  # the version recorded
    assert setup.evaluation == {**setup.collection, "town": "test"}
    key = setup.data_key
    assert (key["noise_frac"], key["noise_std"], key["noise_steps"]) == (0.1, 0.3, 10)
    assert {k: key["env_overrides"][k] for k in ("speed_input", "traffic")} == {"speed_input": True, "traffic": "dense"}
    settings = setup.applied.settings
    assert settings["eval_town"] == "test" and settings["traffic"] == "dense" and settings["noise_steps"] == 10


def test_without_speed_names_other_demonstrations_and_new_weather_is_one_set_away():
    with_speed, without = _setup("nocrash"), _setup("nocrash-nospeed")
    assert without.collection["speed_input"] is False
    assert with_speed.data_key != without.data_key
    weather = _setup("nocrash", ["protocol.eval_weather=test"])
    assert weather.evaluation["weather"] == "test" and weather.data_key == with_speed.data_key


def test_protocols_without_task_settings_name_their_data_as_before():
    setup = Setup.resolve("hopper", "pos", tasks.get("hopper").protocol("mujoco-state", "pos"))
    assert "noise_steps" not in setup.data_key and "traffic" not in setup.applied.settings
    assert setup.data_key["noise_frac"] == 0.0


@pytest.mark.parametrize("sets, needle", [
    (["protocol.speed_input=true"], "protocol.speed_input: hopper has no such setting"),
    (["protocol.eval_town=test"], "protocol.eval_town: hopper has no such setting"),
])
def test_a_setting_the_task_lacks_is_refused(sets, needle):
    with pytest.raises(ValueError, match=needle):
        Setup.resolve("hopper", "pos", resolve("hopper", "pos", protocol="mujoco-state", sets=sets).protocol)


def test_mujoco_tasks_do_not_list_the_driving_protocols():
    assert "nocrash" not in tasks.get("hopper").protocols
    with pytest.raises(ValueError, match="unknown protocol 'nocrash' for hopper"):
        tasks.get("hopper").protocol("nocrash", "pos")


@pytest.mark.parametrize("args, needle", [
    (["--env", "toytown", "--set", "protocol.traffic=jammed"], "unknown traffic 'jammed'"),
    (["--env", "toycar", "--set", "protocol.speed_input=false"], "toycar has no such setting"),
    (["--env", "toytown", "--set", "protocol.noise_frac=1.5"], "noise_frac must be in [0, 1)"),
])
def test_the_sweep_refuses_bad_driving_settings_in_one_line(tmp_path, capsys, args, needle):
    from experiments import sweep
    from tests.test_refusals import refused

    out = tmp_path / "out"
    err = refused(capsys, lambda: sweep.main([*args, "--smoke", "--out", str(out)]))
    assert needle in err, err
    assert not out.exists()


def test_cilrs_weighted_l1_weighs_each_action_dimension():
    cfg = LearnerConfig(obs_shape=(4,), action_dim=3, loss="l1", loss_weights=(0.5, 0.45, 0.05))
    err = action_errors(cfg, jnp.zeros((2, 3)), jnp.array([[1.0, 0.0, 0.0], [0.0, 2.0, -4.0]]))
    np.testing.assert_allclose(err, [0.5, 0.9 + 0.2], rtol=1e-6)
    plain = LearnerConfig(obs_shape=(4,), action_dim=3, loss="l1")
    np.testing.assert_allclose(action_errors(plain, jnp.zeros((1, 3)), jnp.ones((1, 3))), [3.0])
    with pytest.raises(ValueError, match="loss_weights must be 3 numbers"):
        LearnerConfig(obs_shape=(4,), action_dim=3, loss_weights=(1.0, 1.0))


def test_toytown_sweeps_train_on_cilrs_weights_unless_the_recipe_names_its_own():
    settings = resolve("toytown", "image", preset="quick")
    cfg = settings.learner_config((64, 64, 3), 3, 2, tasks.get("toytown").loss,
                                  task_loss_weights=tasks.get("toytown").loss_weights)
    assert cfg.loss == "l1" and cfg.loss_weights == (0.5, 0.45, 0.05)
    own = resolve("toytown", "image", preset="quick", sets=["recipe.loss_weights=1,1,1"])
    assert own.learner_config((64, 64, 3), 3, 2, "l1", task_loss_weights=(0.5, 0.45, 0.05)).loss_weights == (1, 1, 1)
