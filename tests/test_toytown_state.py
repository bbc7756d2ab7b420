"""ToyTown's task versions and its one-frame state: brake lights in the frame, a measurement strip that hides nothing
the expert reacts to, the one-frame observation (`obs="pos"`) and what it leaves out, the version recorded where
demonstrations and results are named, histories at a stride, and the refusals."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax import tasks
from ape_jax.learner import LearnerConfig, make_train
from ape_jax.pipeline import presets
from ape_jax.pipeline.setup import Setup
from envs import toytown_render as render_lib
from envs import toytown_traffic as traffic
from envs import toytown_world as world
from envs.toytown import step_sim
from envs.toytown_expert import FEATURES, HIDDEN, LEAD_BRAKES, features, one_frame, one_frame_names, perception
from experiments import sweep
from test_cli_guards import refused

SHORT = dict(route_length=180.0, intersections=2, episode_length=700)
GREEN_FOREVER = dict(green_range=(1000.0, 1000.0))
EGO_S = 40.0


def _scene(version=2, lead_gap=12.0, lead_v=0.0, lead_brake=1.0, obs="image", **settings):
    """An environment and a simulator state: the ego at `EGO_S` m, one route car in its lane `lead_gap` m
    (bumper to bumper) ahead at speed `lead_v` with brake lights `lead_brake`, nobody else, lights green."""
    env = envs.make("toytown", obs=obs, traffic="regular", task_version=version, **SHORT, **GREEN_FOREVER, **settings)
    sim = env.reset(jax.random.PRNGKey(0)).pipeline_state
    x, y, h, _ = world.pose_at(sim.route, jnp.float32(EGO_S))
    d = -0.5 * env.config.lane_width
    n = sim.car_s.shape[0]
    place = lambda first, rest: jnp.asarray([first] + [rest] * (n - 1), jnp.float32)  # noqa: E731
    sim = sim.replace(x=x - d * jnp.sin(h), y=y + d * jnp.cos(h), yaw=h, s=jnp.float32(EGO_S), d=jnp.float32(d),
                      car_s=place(EGO_S + traffic.CAR_LENGTH + lead_gap, traffic.NOWHERE), car_lane=place(0, 0),
                      car_active=place(1, 0), car_v=place(lead_v, 0), car_brake=place(lead_brake, 0),
                      car_stop=place(0, 0), ped_active=jnp.zeros_like(sim.ped_active),
                      ped_s=jnp.full_like(sim.ped_s, traffic.NOWHERE),
                      cross_wait=jnp.full_like(sim.cross_wait, traffic.NEVER),
                      cross_u=jnp.full_like(sim.cross_u, -traffic.CROSS_REACH))  # out of sight
    return env, sim


def _mask(img, cls):
    return np.all(np.asarray(img) == render_lib.PALETTES["train"][cls], axis=-1)


# -- brake lights ----------------------------------------------------------------------------------------------------

def test_braking_and_standing_cars_light_their_brake_lights_and_a_cruising_car_does_not():
    env, sim = _scene(lead_gap=20.0, lead_v=6.0, lead_brake=0.0)
    cruising = step_sim(sim, jnp.zeros(3), env.config)
    assert float(cruising.car_brake[0]) == 0.0   # free road at its own speed
    stopping = step_sim(sim.replace(car_stop=sim.car_stop.at[0].set(3.0)), jnp.zeros(3), env.config)
    assert float(stopping.car_v[0]) < 6.0 and float(stopping.car_brake[0]) == 1.0   # a random stop: it brakes
    standing = step_sim(sim.replace(car_v=sim.car_v.at[0].set(0.0), car_stop=sim.car_stop.at[0].set(3.0)),
                        jnp.zeros(3), env.config)
    assert float(standing.car_v[0]) == 0.0 and float(standing.car_brake[0]) == 1.0


def test_a_braking_car_shows_its_lights_at_its_rear_and_version_1_draws_none():
    env, lit = _scene(lead_brake=1.0)
    img = np.asarray(env.observe_sim(lit))
    light, car = _mask(img, render_lib.BRAKE_LIGHT), _mask(img, render_lib.CAR)
    assert light.sum() >= 4 and car.sum() >= 8
    rows = lambda m: np.nonzero(m)[0]  # noqa: E731
    assert rows(light).min() > rows(car).min() and rows(light).max() >= rows(car).max()  # the rear faces the ego
    dark = lit.replace(car_brake=lit.car_brake * 0)
    assert not _mask(np.asarray(env.observe_sim(dark)), render_lib.BRAKE_LIGHT).any()
    old, lit_v1 = _scene(version=1, lead_brake=1.0)
    assert not _mask(np.asarray(old.observe_sim(lit_v1)), render_lib.BRAKE_LIGHT).any()


# -- the measurement strip -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("size", [32, 64, 128])
def test_from_version_2_the_strip_sits_above_everything_the_expert_perceives(size):
    cfg = envs.make("toytown", image_size=size).config
    top = render_lib.scene_top(cfg)
    mpp, _, _, _, _ = render_lib.camera(cfg)
    # the scene's first row starts exactly at view_ahead: every metre the expert reacts to lies below the strip
    assert top == render_lib.strip_rows(size)
    np.testing.assert_allclose(mpp * (size - top), cfg.view_ahead + cfg.view_behind, rtol=1e-6)
    assert perception(cfg) + traffic.CAR_LENGTH / 2 <= cfg.view_ahead


@pytest.mark.parametrize("version,shown", [(1, False), (2, True)])
def test_a_car_at_the_edge_of_what_the_expert_perceives_is_in_the_frame_from_version_2(version, shown):
    gap = perception(envs.make("toytown").config) - 0.5
    env, sim = _scene(version=version, lead_gap=gap, lead_brake=0.0)
    full = np.asarray(features(sim, env.config))
    assert full[FEATURES.index("lead_gap")] == pytest.approx(gap, abs=1e-3)  # the expert reacts to it
    img = np.asarray(env.observe_sim(sim))
    scene = img[render_lib.strip_rows(img.shape[0]):]
    assert _mask(scene, render_lib.CAR).any() == shown


# -- the one-frame state ---------------------------------------------------------------------------------------------

def test_the_one_frame_state_names_what_a_frame_shows_by_version_and_speed_input():
    names = lambda **kw: one_frame_names(envs.make("toytown", **kw).config)  # noqa: E731
    v2, v1, blind = names(), names(task_version=1), names(speed_input=False)
    assert v2 == v1 + (LEAD_BRAKES,) and blind == tuple(n for n in v2 if n != "speed")
    assert v2[0] == "speed" and not set(HIDDEN) & set(v2)
    assert names(reveal=("lead_speed",)) == v2 + ("lead_speed",)
    env = envs.make("toytown", obs="pos")
    assert env.observation_shape == (len(v2),) and "pos" in envs.obs_modes("toytown")


def test_the_one_frame_state_does_not_change_with_what_no_frame_shows():
    env, sim = _scene(obs="pos", lead_v=3.0)
    moved = sim.replace(car_v=sim.car_v.at[0].set(7.0), t=sim.t + 37)  # the lead's speed, the light's time left
    a, b = (np.asarray(one_frame(s, env.config)) for s in (sim, moved))
    np.testing.assert_array_equal(a, b)
    full_a, full_b = (np.asarray(features(s, env.config)) for s in (sim, moved))
    assert full_a[FEATURES.index("lead_speed")] != full_b[FEATURES.index("lead_speed")]


@pytest.mark.parametrize("brake", [0.0, 1.0])
def test_lead_brakes_is_what_the_frame_shows(brake):
    env, sim = _scene(obs="pos", lead_brake=brake)
    state = np.asarray(env.observe_sim(sim))
    assert state[one_frame_names(env.config).index(LEAD_BRAKES)] == brake
    camera = envs.registry.same_task(env, "image")
    assert _mask(np.asarray(camera.observe_sim(sim)), render_lib.BRAKE_LIGHT).any() == bool(brake)
    # nothing ahead within sight: no brake lights to report, whatever the far car shows
    _, far = _scene(obs="pos", lead_gap=perception(env.config) + 5.0, lead_brake=1.0)
    assert np.asarray(env.observe_sim(far))[one_frame_names(env.config).index(LEAD_BRAKES)] == 0.0


@pytest.mark.parametrize("settings,match", [
    (dict(task_version=3), "task_version must be one of 1, 2, got 3"),
    (dict(reveal=("speed",)), r"reveal takes full-state features the one-frame state leaves out.*valid: light_left"),
    (dict(reveal=("lead_speed", "lead_speed")), "each once"),
])
def test_bad_versions_and_reveals_are_refused_in_one_line(settings, match):
    with pytest.raises(ValueError, match=match) as err:
        envs.make("toytown", obs="pos", **settings)
    assert "\n" not in str(err.value)


# -- the version, recorded -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("sets,version", [((), 2), (("protocol.task_version=1",), 1)])
def test_the_task_version_is_recorded_in_the_settings_the_protocol_and_the_data_key(sets, version):
    settings = presets.resolve("toytown", "pos", preset="quick", sets=sets)
    assert settings.protocol.task_version == version
    setup = Setup.resolve("toytown", "pos", settings.protocol)
    assert setup.applied.settings["task_version"] == version
    assert setup.data_key["env_overrides"]["task_version"] == version
    assert setup.data_key["expert"]["config"]["task_version"] == version
    bare = Setup.resolve("toytown", "pos", tasks.get("toytown").protocol("nocrash", "pos"))  # no version named
    assert bare.applied.settings["task_version"] == envs.make("toytown").config.task_version
    assert presets.resolve("hopper", "pos").protocol.task_version is None  # a task without versions


# -- histories at a stride -------------------------------------------------------------------------------------------

def test_a_history_at_stride_k_spans_k_steps_and_the_policy_sees_its_ends():
    settings = presets.resolve("toytown", "pos", sets=["protocol.history_stride=5"])
    cfg = settings.learner_config((4,), 3, 2, "l1")
    assert (cfg.history, cfg.history_stride, cfg.frames) == (6, 5, 2)
    assert settings.learner_config((4,), 3, 1, "l1").history == 1  # BC-SO: no past to space
    window = jnp.arange(6 * 4, dtype=jnp.float32).reshape(1, 6, 4)  # steps t-5 ... t
    seen = make_train(cfg).policy_input(window)
    np.testing.assert_array_equal(seen, jnp.concatenate([window[0, 0], window[0, 5]])[None])
    with pytest.raises(ValueError, match="must be a multiple of history_stride"):
        LearnerConfig(obs_shape=(4,), action_dim=3, history=5, history_stride=5)


@pytest.mark.parametrize("argv,message", [
    (["--env", "toycar", "--obs", "pos"], "--obs 'pos' is not supported by toycar; valid: full, image"),
    (["--env", "toytown", "--obs", "pos", "--set", "protocol.history_stride=0"],
     "protocol.history_stride must be a whole number of steps >= 1, got 0"),
    (["--env", "toytown", "--obs", "pos", "--set", "protocol.history_stride=1.5"], "protocol.history_stride takes"),
    (["--env", "toytown", "--obs", "pos", "--set", "protocol.history_stride=2000"],
     "protocol.history 2 at stride 2000 (2,001 steps) is longer than an episode (2,000 steps)"),
])
def test_a_one_frame_state_or_a_stride_the_task_cannot_take_is_refused_and_nothing_is_written(capsys, tmp_path,
                                                                                               argv, message):
    out = tmp_path / "run"
    assert message in refused(capsys, lambda: sweep.main([*argv, "--yes", "--out", str(out)]))
    assert not out.exists() or not any(out.iterdir())


# -- versions never merge --------------------------------------------------------------------------------------------

def _with_protocol(tmp_path, name: str, **fields):
    """Committed results file `name` and a copy of it whose protocol (and settings' protocol) sets `fields`."""
    import json
    import pathlib

    first = pathlib.Path(__file__).resolve().parents[1] / "results" / name
    obj = json.loads(first.read_text())
    for holder in (obj, obj["settings"]):
        holder["protocol"].update(fields)
    second = tmp_path / "changed.json"
    second.write_text(json.dumps(obj))
    return first, second


def _as_version_2(tmp_path):
    """The committed Table 1 seed-0 file (the first version: it records none) and a copy that says version 2."""
    return _with_protocol(tmp_path, "toytown-image-nocrash-default-seeds0.json", task_version=2)


def test_results_of_two_task_versions_are_grouped_apart_and_the_first_is_labelled(tmp_path):
    from experiments import report
    from experiments.report.analysis import Key

    first, second = _as_version_2(tmp_path)
    merged = report.merge([report.load(first), report.load(second)])
    assert set(merged) == {Key("toytown", "image", "nocrash", version=1), Key("toytown", "image", "nocrash", version=2)}
    titles = {k.version: m.title for k, m in merged.items()}
    assert titles == {1: "ToyTown (image, nocrash, version 1)", 2: "ToyTown (image, nocrash)"}


def test_compare_runs_refuses_two_task_versions_in_one_line(tmp_path, capsys):
    from experiments import compare_runs

    first, second = _as_version_2(tmp_path)
    assert "ran task version 1" in refused(capsys, lambda: compare_runs.main([str(first), str(second)]))


def test_a_history_at_another_stride_is_a_group_of_its_own_titled_by_it(tmp_path):
    from experiments import report

    table, strided = _with_protocol(tmp_path, "toytown-pos-nocrash-default.json", history_stride=5)
    merged = report.merge([report.load(table), report.load(strided)])   # the same runs: merged, it would refuse
    assert sorted(k.protocol for k in merged) == ["nocrash", "nocrash.episodes.mlp.stride5"]
    (m,) = [m for k, m in merged.items() if k.protocol != "nocrash"]
    assert "frames 5 steps apart" in m.title and m.protocol["variant_of"] == "nocrash"


def test_the_ceiling_tool_reads_one_frame_sweeps_and_refuses_other_files(tmp_path, capsys):
    import json
    import pathlib

    from experiments import toytown_ceiling

    results = pathlib.Path(__file__).resolve().parents[1] / "results"
    files = sorted(str(p) for p in (results / "exploratory").glob("toytown-ceiling-v*.json"))
    out = tmp_path / "ceiling.json"
    assert len(files) == 4 and toytown_ceiling.main([*files, "--out", str(out)]) == 0
    rows = json.loads(out.read_text())["rows"]
    assert [(r["task_version"], r["revealed"]) for r in rows] == [(1, []), (1, ["lead_speed"]), (2, []),
                                                                  (2, ["lead_speed"])]
    assert "| 2 | - | 5 | 87.4 |" in capsys.readouterr().out
    assert toytown_ceiling.main([str(results / "hopper-pos-default.json")]) == 2
    assert "not a ToyTown one-frame sweep" in capsys.readouterr().err
    assert "no such results file" in refused(capsys, lambda: toytown_ceiling.main([str(tmp_path / "none.json")]))
