"""ToyTown: shapes, determinism, the expert per traffic condition, the metrics' counters on scripted episodes,
what the camera shows, and the refusals.

The default run shrinks the route (180 m, two intersections) so an expert episode is a few hundred steps; the
task's own defaults are measured by the integration test at the end, with `experiments.toytown_soundness` (the
soundness table of docs/tasks.md):

    python -m experiments.toytown_soundness --episodes 100 --out results/exploratory/toytown-soundness.json
"""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs import toytown_render as render_lib
from envs import toytown_world as world
from envs.toytown import ToyTownConfig
from envs.toytown_expert import FEATURES
from experiments import toytown_soundness
from experiments.toytown_soundness import expert_metrics as _expert_metrics, soundness

SHORT = dict(route_length=180.0, intersections=2, episode_length=700)  # three 60 m blocks: ~300 expert steps
GREEN_FOREVER = dict(green_range=(1000.0, 1000.0))
PALETTE = render_lib.PALETTES["train"]


def _colour_mask(img, cls):
    return np.all(np.asarray(img) == PALETTE[cls], axis=-1)


# -- shapes, determinism -------------------------------------------------------------------------------------

@pytest.mark.parametrize("obs,traffic", [("full", "regular"), ("image", "dense"), ("image", "empty")])
def test_reset_and_step_under_jit_give_finite_observations_of_the_declared_shape(obs, traffic):
    env = envs.make("toytown", obs=obs, traffic=traffic, image_size=32, **SHORT)
    assert env.action_size == 3 and env.action_names == ("steer", "throttle", "brake")
    low, high = env.action_bounds
    np.testing.assert_array_equal(low, [-1, 0, 0]) and np.testing.assert_array_equal(high, [1, 1, 1])
    reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    states = reset(jax.random.split(jax.random.PRNGKey(0), 4))
    for _ in range(3):
        states = step(states, jnp.tile(jnp.array([0.1, 0.6, 0.0]), (4, 1)))
    assert states.obs.shape == (4, *env.observation_shape) and states.obs.dtype == env.observation_dtype
    assert env.observation_shape == ((32, 32, 3) if obs == "image" else (len(FEATURES),))
    assert np.all(np.isfinite(np.asarray(states.obs, np.float32)))
    assert np.all(np.isfinite(np.asarray(states.pipeline_state.x))) and float(states.done.max()) == 0.0
    # the same key gives the same episode; another key another one
    again = reset(jax.random.split(jax.random.PRNGKey(0), 4))
    np.testing.assert_array_equal(again.obs, reset(jax.random.split(jax.random.PRNGKey(0), 4)).obs)
    other = reset(jax.random.split(jax.random.PRNGKey(1), 4))
    offsets = [np.asarray(s.pipeline_state.light_offset) for s in (other, again)]
    assert not np.array_equal(*offsets)


def test_the_registry_knows_toytown_and_its_defaults():
    assert "toytown" in envs.names() and envs.obs_modes("toytown") == ("full", "pos", "image")
    assert envs.default_obs("toytown") == "image"
    assert envs.default_episode_length("toytown") == ToyTownConfig().episode_length
    env = envs.make("toytown")
    assert env.observation_shape == (64, 64, 3) and env.config.traffic == "dense" and env.config.speed_input


def test_the_task_record_reads_the_environment_s_metrics_and_the_supplement_s_carla_settings():
    from ape_jax import tasks

    task = tasks.get("toytown")
    assert task.metrics == envs.make("toytown", obs="full").episode_metric_names and task.metric == "success"
    assert (task.loss, task.fca_alpha, task.expert, task.default_obs) == ("l1", 0.2, "rule-based", "image")
    assert "toytown" in tasks.sweepable()


def test_routes_bend_keep_straight_road_round_each_intersection_and_end_at_the_goal():
    for layout in (0, 7, 1003):
        route, inter_s = world.make_route(jnp.int32(layout), 400.0, 4)
        np.testing.assert_allclose(inter_s, [80, 160, 240, 320])
        s = jnp.linspace(0.0, 400.0, 801)
        _, _, heading, kappa = world.pose_at(route, s)
        assert float(jnp.max(jnp.abs(kappa))) > 1 / 60  # it bends
        assert float(jnp.max(jnp.abs(heading))) <= world.MAX_HEADING + 1e-4
        for j in np.asarray(inter_s):  # straight road on both sides of every intersection
            near = jnp.abs(s - j) <= world.STRAIGHT
            assert float(jnp.max(jnp.abs(kappa[near]))) == 0.0
        # the pieces join: a point's projection onto the route gives back its arc length and offset
        x, y, h, _ = world.pose_at(route, jnp.array([37.0, 151.0, 333.0]))
        project = jax.vmap(lambda px, py, guess: world.project(route, px, py, guess, 5.0, 5.0, 0.5))
        ps, pd = project(x - 1.5 * jnp.sin(h), y + 1.5 * jnp.cos(h), jnp.array([36.0, 150.0, 331.0]))
        np.testing.assert_allclose(ps, [37.0, 151.0, 333.0], atol=0.02)
        np.testing.assert_allclose(pd, 1.5, atol=0.02)


def test_held_out_towns_draw_other_layouts_and_a_fixed_layout_stays():
    from envs.toytown import draw_layout

    keys = jax.random.split(jax.random.PRNGKey(0), 200)
    layouts = {town: set(np.asarray(jax.vmap(lambda k: draw_layout(k, ToyTownConfig(town=town)))(keys)))
               for town in ("train", "test")}
    assert layouts["train"] == set(range(*ToyTownConfig().train_layouts))
    assert layouts["test"] == set(range(*ToyTownConfig().test_layouts))
    assert int(draw_layout(keys[0], ToyTownConfig(town="test", layout=7))) == 7


# -- the expert ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("traffic", ["empty", "regular", "dense"])
def test_the_expert_completes_short_routes_in_every_condition_without_collisions(traffic):
    env = envs.make("toytown", obs="full", traffic=traffic, **SHORT)
    traj, m = _expert_metrics(env, 12, key=3)
    assert m["success"].mean() == 1.0, m
    assert m["collisions"].sum() == 0 and m["red_light_violations"].sum() == 0 and m["stuck"].sum() == 0
    assert np.all(m["route_completion"] == 1.0)
    actions = np.asarray(traj.action)[np.asarray(traj.valid) > 0]
    # smooth control: the previous action predicts the next far better than ToyCar's bang-bang expert (0.66)
    follows = np.asarray(traj.valid)[:, 1:] > 0
    step_change = np.sum(np.diff(np.asarray(traj.action), axis=1) ** 2, -1)[follows].mean()
    assert step_change / np.sum(actions.var(0)) < 0.15
    if traffic != "empty":  # it meets other road users and stops for them or for lights
        assert (actions[:, 2] > 0.05).mean() > 0.02


# -- scripted episodes: the counters ---------------------------------------------------------------------------

def _placed(env, key=0, s=None, **fields):
    """A reset state with the ego moved to arc length `s` (in its lane, along the road) and `fields` of the
    simulator replaced; observed again."""
    state = env.reset(jax.random.PRNGKey(key))
    sim = state.pipeline_state
    if s is not None:
        x, y, h, _ = world.pose_at(sim.route, jnp.float32(s))
        d = -0.5 * env.config.lane_width
        sim = sim.replace(x=x - d * jnp.sin(h), y=y + d * jnp.cos(h), yaw=h, s=jnp.float32(s))
    sim = sim.replace(**{k: jnp.asarray(v, getattr(sim, k).dtype) for k, v in fields.items()})
    return state.replace(pipeline_state=sim, obs=env.observe_sim(sim))


def _drive(env, state, act, steps):
    """`steps` steps of `act(full_obs) -> action` from `state` (on past `done`: the rollout, not the environment,
    ends episodes); the simulator states after each step, the final state, and the per-step metrics."""
    from envs.toytown_expert import features

    def step(s, _):
        s = env.step(s, act(features(s.pipeline_state, env.config)))
        return s, (s.pipeline_state, s.metrics)

    final, (sims, metrics) = jax.lax.scan(step, state, None, length=steps)
    return sims, final, metrics


def _metrics(env, start, sims, final):
    valid = jnp.ones(sims.t.shape[0])
    both = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), start.pipeline_state, sims)
    return {k: float(v) for k, v in env.episode_metrics(both, final, valid).items()}


def _lane_keeping(obs, throttle, brake=0.0):
    """Steer as the expert does, with given pedals."""
    from envs.toytown_expert import expert_action

    return jnp.array([expert_action(obs, ToyTownConfig())[0], throttle, brake])


def test_driving_into_a_standing_car_is_a_vehicle_collision_that_ends_the_episode():
    env = envs.make("toytown", obs="full", traffic="empty", **SHORT, **GREEN_FOREVER)
    start = _placed(env, car_s=[25.0, -1e4], car_lane=[0, 1], car_active=[1, 0], car_v=[0, 0],
                    car_stop=[1e4, 0], light_offset=[0.0, 0.0])
    sims, final, per_step = jax.jit(lambda s: _drive(env, s, lambda o: _lane_keeping(o, 1.0), 60))(start)
    m = _metrics(env, start, sims, final)
    assert m["collisions_vehicle"] == 1.0 and m["collisions"] == 1.0 and m["success"] == 0.0
    assert m["collisions_pedestrian"] == 0.0 and m["timeout"] == 0.0
    assert float(final.done) == 1.0 and float(per_step["collision"].sum()) == 1.0
    hit = int(np.argmax(np.asarray(per_step["collision"])))
    assert 25.0 - 4.5 < float(sims.s[hit]) < 25.0  # bumper to bumper with the standing car


def test_walking_into_a_crossing_pedestrian_is_a_pedestrian_collision():
    env = envs.make("toytown", obs="full", traffic="empty", **SHORT, **GREEN_FOREVER)
    start = _placed(env, ped_s=[30.0], ped_d=[-1.75], ped_walking=[1.0], ped_speed=[0.0], ped_active=[1.0],
                    light_offset=[0.0, 0.0])
    sims, final, _ = jax.jit(lambda s: _drive(env, s, lambda o: _lane_keeping(o, 1.0), 60))(start)
    m = _metrics(env, start, sims, final)
    assert m["collisions_pedestrian"] == 1.0 and m["collisions_vehicle"] == 0.0 and m["success"] == 0.0


def test_running_a_red_light_is_counted_and_the_expert_stops_for_it_without_being_stuck():
    red = dict(light_green=[1.0, 1.0], light_red=[1000.0, 1000.0], light_offset=[10.0, 10.0])  # red for ~17 min
    env = envs.make("toytown", obs="full", traffic="empty", **SHORT)
    start = _placed(env, **red)
    run = jax.jit(lambda s: _drive(env, s, lambda o: _lane_keeping(o, 1.0), 120))
    sims, final, per_step = run(start)
    m = _metrics(env, start, sims, final)
    assert m["red_light_violations"] >= 1.0 and float(per_step["red_light_violation"].sum()) >= 1.0
    assert m["collisions"] == 0.0 and m["stuck"] == 0.0
    # the expert brakes to a stop before the line and waits there: not stuck, however long
    sims, final, _ = jax.jit(lambda s: _drive(env, s, env.expert, 300))(start)
    m = _metrics(env, start, sims, final)
    line = float(start.pipeline_state.inter_s[0]) - env.config.lane_width - 1.0
    assert m["red_light_violations"] == 0.0 and m["stuck"] == 0.0 and m["timeout"] == 1.0
    assert float(sims.v[-100:].max()) < 0.1 and line - 4.0 < float(sims.s[-1]) + 2.25 < line


def test_stopping_on_green_with_the_road_clear_is_stuck_after_stuck_seconds():
    env = envs.make("toytown", obs="full", traffic="empty", **SHORT, **GREEN_FOREVER)
    start = _placed(env, light_offset=[0.0, 0.0])

    def stop_at_30m(o):  # drive off, brake to a stop past 30 m, stay
        past = o[FEATURES.index("progress")] * env.config.route_length > 30.0
        return _lane_keeping(o, jnp.where(past, 0.0, 1.0), jnp.where(past, 1.0, 0.0))

    steps = 80 + env.config.stuck_steps
    sims, final, _ = jax.jit(lambda s: _drive(env, s, stop_at_30m, steps))(start)
    m = _metrics(env, start, sims, final)
    assert float(sims.v[-1]) == 0.0 and m["stuck"] == 1.0 and m["collisions"] == 0.0 and m["timeout"] == 1.0
    # one step fewer standing would not have been stuck
    first = int(np.argmax(np.asarray(sims.stuck) > 0))
    assert int(sims.still[first]) == env.config.stuck_steps


def test_leaving_the_road_is_an_off_road_collision():
    env = envs.make("toytown", obs="full", traffic="empty", **SHORT)
    start = _placed(env)
    sims, final, _ = jax.jit(lambda s: _drive(env, s, lambda o: jnp.array([1.0, 0.6, 0.0]), 80))(start)
    m = _metrics(env, start, sims, final)
    assert m["collisions_offroad"] == 1.0 and m["success"] == 0.0 and float(final.done) == 1.0


# -- the camera ------------------------------------------------------------------------------------------------

def test_the_camera_shows_each_light_colour_cars_pedestrians_and_the_ego_where_they_are():
    env = envs.make("toytown", traffic="empty", **SHORT)
    lights = {"green": 0.0, "amber": 1000.5, "red": 1010.0}  # offsets into a 1000 s green, 3 s amber
    seen = {}
    for name, offset in lights.items():
        # 15 m before the first stop line (intersection at 60 m), a car 12 m ahead, an oncoming one 6 m behind,
        # a pedestrian 8 m ahead in the ego's lane
        state = _placed(env, s=40.0, light_green=[1000.0, 1000.0], light_offset=[offset, offset],
                        car_s=[52.0, 34.0], car_lane=[0, 1], car_active=[1, 1],
                        ped_s=[48.0], ped_d=[-1.75], ped_active=[1.0])
        img = np.asarray(jax.jit(env.observe_sim)(state.pipeline_state))
        seen[name] = {c: _colour_mask(img, i) for i, c in enumerate(render_lib.CLASS_NAMES)}
    h = env.config.image_size[0]
    ego_row = round(env.config.view_ahead / (env.config.view_ahead + env.config.view_behind) * h)
    for name in lights:
        masks = seen[name]
        assert masks[name].any(), name
        assert not any(masks[other].any() for other in lights if other != name), name
        rows = lambda m: np.nonzero(m)[0]  # noqa: E731
        assert rows(masks["car"]).min() < ego_row - 8  # the car 12 m ahead is drawn ahead of the ego
        assert rows(masks["car"]).max() > ego_row  # the oncoming car 6 m behind, beside it
        assert masks["pedestrian"].any() and rows(masks["pedestrian"]).max() < ego_row
        assert masks["ego"].sum() >= 20 and masks["road"].any() and masks["marking"].any()


def test_the_measurement_strip_shows_the_speed_only_with_the_speed_input():
    for speed_input, want in ((True, round(255 * 6.0 / render_lib.SPEED_SCALE)), (False, 0)):
        env = envs.make("toytown", traffic="empty", speed_input=speed_input, **SHORT)
        img = np.asarray(env.observe_sim(_placed(env, v=6.0).pipeline_state))
        strip = img[: render_lib.strip_rows(img.shape[0])]
        assert np.all(strip == want), (speed_input, np.unique(strip))
        assert not np.all(img[render_lib.strip_rows(img.shape[0]):] == want)


def test_the_held_out_weather_changes_the_palette_not_the_scene():
    frames = {}
    for weather in ("train", "test"):
        env = envs.make("toytown", traffic="dense", weather=weather, image_size=32, **SHORT)
        frames[weather] = np.asarray(env.reset(jax.random.PRNGKey(2)).obs)
    train, test = (frames[w].reshape(-1, 3) for w in ("train", "test"))
    assert not np.array_equal(train, test)
    # the same pixels are each class in both: colours map one to one
    pairs = {tuple(a): tuple(b) for a, b in zip(train, test)}
    assert len(set(pairs.values())) == len(pairs)


# -- refusals --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("settings,match", [
    (dict(traffic="rush"), "unknown traffic 'rush'; valid: empty, regular, dense"),
    (dict(vehicle_density=-1.0), "vehicle_density must be a number >= 0"),
    (dict(pedestrian_density=-0.5), "pedestrian_density must be a number >= 0"),
    (dict(route_length=100.0, intersections=1), "route_length must be at least 120 m for 1 intersection"),
    (dict(intersections=0), "intersections must be an integer >= 1"),
    (dict(image_size=15), "image_size must be at least 16x16, got 15x15"),
    (dict(image_size=(64, 12)), "image_size must be at least 16x16"),
    (dict(town="val"), "unknown town 'val'; valid: train, test"),
    (dict(weather="rain"), "unknown weather 'rain'; valid: train, test"),
    (dict(speed_input="yes"), "speed_input must be True or False"),
    (dict(spead_input=True), r"unknown setting\(s\) \['spead_input'\] for env 'toytown'; valid: .*'speed_input'"),
])
def test_bad_settings_are_refused_in_one_line_naming_the_valid_ones(settings, match):
    with pytest.raises(ValueError, match=match) as err:
        envs.make("toytown", **settings)
    assert "\n" not in str(err.value)


def test_a_speed_input_asked_of_toycar_is_refused_naming_its_settings():
    with pytest.raises(ValueError, match=r"unknown setting\(s\) \['speed_input'\] for env 'toycar'; valid: \[") as e:
        envs.make("toycar", speed_input=False)
    assert "\n" not in str(e.value)


# -- collection ------------------------------------------------------------------------------------------------

def test_noisy_collection_executes_perturbed_actions_and_labels_the_expert_s_own():
    from ape_jax.pipeline import collect

    env = envs.make("toytown", obs="full", traffic="regular", **{**SHORT, "episode_length": 200})
    demos = collect.collect(env, env.expert, jax.random.PRNGKey(0), num_episodes=2, noise_frac=0.1, noise_std=0.3)
    perturbed = np.any(np.abs(demos.executed - demos.action) > 1e-6, axis=1)
    assert 0.05 < perturbed.mean() < 0.15
    # the label is the expert's action on the state the noisy actions led to
    sims = jax.tree.map(jnp.asarray, demos.sim)
    clean = jax.vmap(lambda s: env.expert(env.observe_sim(s)))(sims)
    np.testing.assert_allclose(demos.action, np.clip(clean, *[np.asarray(b) for b in env.action_bounds]), atol=1e-5)


def test_burst_noise_perturbs_the_asked_share_in_whole_triangular_bursts():
    from ape_jax.pipeline import collect

    env = envs.make("toytown", obs="full", traffic="regular", **{**SHORT, "episode_length": 300})
    demos = collect.collect(env, env.expert, jax.random.PRNGKey(1), num_episodes=8, noise_frac=0.1, noise_std=0.3,
                            noise_steps=10)
    offset = demos.executed - np.clip(demos.action, *[np.asarray(b) for b in env.action_bounds])
    perturbed = np.any(np.abs(offset) > 1e-6, axis=1)
    assert 0.05 < perturbed.mean() < 0.17, perturbed.mean()
    # runs of perturbed steps within an episode: bursts of 10 (a clipped entry or an episode's end may cut one)
    runs, run = [], 0
    for i, p in enumerate(perturbed):
        new_episode = i > 0 and demos.episode[i] != demos.episode[i - 1]
        if (not p or new_episode) and run:
            runs.append(run)
            run = 0
        run += int(p)
    runs.append(run) if run else None
    assert np.median(runs) >= 8 and max(runs) <= 20, runs   # two bursts may touch
    assert collect.burst_start_probability(0.1, 1) == pytest.approx(0.1)
    assert collect.burst_start_probability(0.1, 10) == pytest.approx(0.1 / (0.1 + 9.0))


# -- soundness (the defaults, measured) ------------------------------------------------------------------------

@pytest.mark.integration
def test_the_defaults_are_sound_the_expert_succeeds_and_ape_finds_its_starts_and_stops():
    result = soundness(episodes=100)
    for traffic, r in result.items():
        assert r["success"] >= 0.95, (traffic, r)
        assert r["copy_previous_ratio"] < 0.2, (traffic, r)
        assert r["top10_at_events"] > 2 * r["all_at_events"], (traffic, r)


def test_the_soundness_tool_writes_its_table_with_provenance_and_refuses_bad_input(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(toytown_soundness, "soundness", lambda episodes, seed: {
        c: {k: 0.5 for k in toytown_soundness.COLUMNS} | {"episodes": episodes} for c in toytown_soundness.CONDITIONS})
    out = tmp_path / "sound.json"
    assert toytown_soundness.main(["--episodes", "3", "--out", str(out)]) == 0
    written = json.loads(out.read_text())
    assert written["episodes"] == 3 and set(written["conditions"]) == {"empty", "regular", "dense"}
    assert written["command"][:3] == ["python", "-m", "experiments.toytown_soundness"] and "commit" in written["system"]
    assert "| dense | 0.500 |" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        toytown_soundness.main(["--episodes", "0"])
    assert e.value.code == 2 and "--episodes must be >= 1" in capsys.readouterr().err


def test_soundness_on_a_short_route_gives_every_column_in_range():
    rows = soundness(episodes=2, ape_steps=20, **SHORT)
    assert list(rows) == ["empty", "regular", "dense"]
    for r in rows.values():
        assert set(toytown_soundness.COLUMNS) <= set(r) and 0 <= r["success"] <= 1 and r["episode_steps"] > 0
        assert 0 <= r["top10_at_events"] <= 1 and r["copy_previous_ratio"] > 0
