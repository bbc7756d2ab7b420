"""ToyCar: the rule-based expert, the driving metrics, the rollout conventions."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs import toycar
from envs.toycar import ToyCarConfig, ToyCarSim

CFG = ToyCarConfig()


def _sims(x, v, green, light_x=50.0):
    x, v, green = (jnp.asarray(a, jnp.float32) for a in (x, v, green))
    n = x.shape[0]
    return ToyCarSim(x=x, v=v, light_x=jnp.full(n, light_x), green=green, remaining=jnp.ones(n),
                     t=jnp.arange(n, dtype=jnp.int32), key=jnp.zeros((n, 2), jnp.uint32))


def _initial(x0, green0, light_x=50.0):
    return jax.tree.map(lambda a: a[0], _sims([x0], [0.0], [green0], light_x))


def _metrics(x, v, green, x0=0.0, green0=1.0, valid=None):
    traj = _sims(x, v, green)
    valid = jnp.ones(len(x)) if valid is None else jnp.asarray(valid, jnp.float32)
    return {k: float(v) for k, v in toycar.episode_metrics(_initial(x0, green0), traj, valid, CFG).items()}


def test_a_car_standing_still_on_green_is_stuck():
    m = _metrics(x=[30.0] * 100, v=[0.0] * 100, green=[1.0] * 100, x0=30.0)
    assert m["stuck"] == 1.0 and m["success"] == 0.0 and m["red_light_violations"] == 0.0
    assert m["progress"] == pytest.approx(0.0) and m["avg_speed"] == pytest.approx(0.0)


def test_waiting_at_a_red_light_is_not_stuck():
    m = _metrics(x=[48.0] * 100, v=[0.0] * 100, green=[0.0] * 100, x0=48.0, green0=0.0)
    assert m["stuck"] == 0.0


def test_crossing_on_red_is_a_violation_and_not_a_success():
    x = np.linspace(10.0, 100.0, 10)  # 10 m per step: reaches the goal
    m = _metrics(x=x, v=[10.0] * 10, green=[0.0] * 10, x0=0.0, green0=0.0)
    assert m["red_light_violations"] == 1.0
    assert m["success"] == 0.0 and m["progress"] == pytest.approx(1.0)
    assert m["avg_speed"] == pytest.approx(100.0 / (10 * CFG.dt))


def test_crossing_on_green_reaching_the_goal_is_a_success():
    x = np.linspace(10.0, 100.0, 10)
    m = _metrics(x=x, v=[10.0] * 10, green=[1.0] * 10, x0=0.0)
    assert m == {"success": 1.0, "red_light_violations": 0.0, "progress": pytest.approx(1.0),
                 "avg_speed": pytest.approx(100.0), "stuck": 0.0}


def test_steps_after_the_episode_end_do_not_count():
    x = np.r_[np.linspace(10.0, 40.0, 4), [60.0, 100.0]]  # would cross on red, but invalid
    m = _metrics(x=x, v=[10.0] * 6, green=[0.0] * 6, x0=0.0, green0=0.0, valid=[1, 1, 1, 1, 0, 0])
    assert m["red_light_violations"] == 0.0 and m["progress"] == pytest.approx(0.4)


def test_expert_succeeds_in_99_percent_of_1000_random_episodes_without_violations():
    env = envs.make("toycar", obs="full")
    policy = envs.from_observation(env.expert, expert=True, env=env)

    @jax.jit
    def run(key):
        traj = envs.rollout(env, policy, None, key, num_episodes=1000, record=lambda s: s.pipeline_state)
        initial = jax.tree.map(lambda a: a[:, 0], traj.extra)
        after = jax.tree.map(lambda a, f: jnp.concatenate([a[:, 1:], f[:, None]], axis=1),
                             traj.extra, traj.final.pipeline_state)
        return traj, jax.vmap(lambda i, a, v: toycar.episode_metrics(i, a, v, env.config))(initial, after, traj.valid)

    traj, m = run(jax.random.PRNGKey(0))
    assert float(m["success"].mean()) >= 0.99
    assert float(m["red_light_violations"].sum()) == 0.0
    assert float(m["stuck"].sum()) == 0.0
    # the env's own per-step violation flag never fired either
    assert float(traj.final.metrics["red_light_violation"].sum()) == 0.0
    # the expert actually meets red lights: it brakes in a good share of episodes
    braked = np.asarray((traj.action[..., 1] * traj.valid).max(axis=1))
    assert braked.mean() > 0.2
    # episodes that reach the goal end there: frozen state, invalid steps, zero reward
    lengths = np.asarray(traj.lengths)
    assert lengths.min() > 50 and (lengths < env.episode_length).mean() >= 0.99
    i = int(np.argmin(lengths))
    assert float(traj.valid[i, lengths[i]:].sum()) == 0.0
    assert float(traj.final.done[i]) == 1.0


def test_step_flags_a_red_light_crossing():
    env = envs.make("toycar", obs="full", light_range=(10.0, 10.0), start_range=(0.0, 0.0),
                    red_range=(300.0, 300.0), green_range=(300.0, 300.0))

    @jax.jit
    def run(key):
        always_throttle = envs.from_observation(lambda o: jnp.array([1.0, 0.0]))
        return envs.rollout(env, always_throttle, None, key, num_episodes=64, num_steps=60)

    traj = run(jax.random.PRNGKey(0))
    # green at reset stays green for the whole rollout (at least 5% of 300 s), red stays red
    green0 = np.asarray(traj.obs[:, 0, 3])
    assert 0 < green0.sum() < 64
    crossed_on_red = np.asarray(
        jax.vmap(lambda o: jnp.any((o[:-1, 0] < 10.0) & (o[1:, 0] >= 10.0) & (o[:-1, 3] == 0)))(traj.obs)
    )
    np.testing.assert_array_equal(crossed_on_red, green0 == 0)


def test_image_observation_shows_the_light_colour():
    red_env = envs.make("toycar", image_size=32, light_range=(20.0, 20.0), start_range=(5.0, 5.0),
                        red_range=(300.0, 300.0), green_range=(300.0, 300.0))

    @jax.jit
    def frames(key):
        keys = jax.random.split(key, 32)
        return jax.vmap(red_env.reset)(keys)

    states = frames(jax.random.PRNGKey(0))
    green = np.asarray(states.pipeline_state.green) > 0
    img = np.asarray(states.obs).astype(int)
    redness = ((img[..., 0] > 200) & (img[..., 1] < 80)).sum(axis=(1, 2))
    greenness = ((img[..., 1] > 200) & (img[..., 0] < 80)).sum(axis=(1, 2))
    assert np.all(redness[~green] > 0) and np.all(redness[green] == 0)
    assert np.all(greenness[green] > 0) and np.all(greenness[~green] == 0)
    assert img.shape[1:] == (32, 32, 3) and states.obs.dtype == jnp.uint8
    # in the last `amber_seconds` of green the lamp is amber: neither green nor red
    for seconds, want in ((1.5, "amber"), (2.5, "green")):
        img = np.asarray(_held(red_env, 5.0, 0.0, 20.0, 1.0, seconds).obs).astype(int)
        amber = ((img[..., 0] > 200) & (img[..., 1] > 150) & (img[..., 1] < 220) & (img[..., 2] < 80)).sum()
        greenish = ((img[..., 1] > 200) & (img[..., 0] < 80)).sum()
        assert (amber > 0, greenish > 0) == ((True, False) if want == "amber" else (False, True)), seconds


def _held(env, x, v, light_x, green, seconds=60.0):
    """A reset state moved to position `x`, speed `v`, a light at `light_x` held green or red for `seconds`."""
    state = env.reset(jax.random.PRNGKey(0))
    sim = state.pipeline_state.replace(x=jnp.float32(x), v=jnp.float32(v), light_x=jnp.float32(light_x),
                                       green=jnp.float32(green), remaining=jnp.float32(seconds))
    return state.replace(pipeline_state=sim, obs=env.observe_sim(sim))


def _drive(env, act, state, steps):
    """`steps` steps of `act(obs) -> action` from `state`: the simulator states after each step and the actions."""
    def step(s, _):
        a = act(s.obs)
        s = env.step(s, a)
        return s, (s.pipeline_state, a)

    return jax.lax.scan(step, state, None, length=steps)[1]


@pytest.mark.integration
def test_a_small_bc_so_trained_on_a_few_hundred_samples_stops_for_a_red_light_and_goes_on_green():
    """Behaviour, not a falling loss: BC-SO (one frame of the full state, the project's learner, ToyCar's L1 loss)
    trained on 720 expert steps stops before a red light at a place it never saw in training, never crosses it in 15 s,
    and drives through a green one."""
    from ape_jax import methods
    from ape_jax.learner import Data, LearnerConfig, make_train

    env, STEPS, ITERS = envs.make("toycar", obs="full"), 80, 4_000
    drive = jax.jit(_drive, static_argnums=(0, 1, 3))
    # (x, v, light_x, green), each light held for the whole 8 s episode
    scenes = [(0.0, 6.0, 40.0, 0.0), (5.0, 2.0, 45.0, 0.0), (2.0, 9.0, 50.0, 0.0), (0.0, 4.0, 55.0, 0.0),
              (8.0, 1.0, 60.0, 0.0), (3.0, 7.0, 65.0, 0.0), (0.0, 0.0, 70.0, 0.0), (0.0, 4.0, 50.0, 1.0),
              (2.0, 8.0, 60.0, 1.0)]
    demos = [drive(env, env.expert, _held(env, *scene), STEPS) for scene in scenes]
    # the observation before each step: the scene's start, then the states after all but the last step
    obs = jnp.concatenate([jnp.concatenate([env.observe_sim(_held(env, *sc).pipeline_state)[None],
                                            jax.vmap(toycar.full_observation)(sims)[:-1]])
                           for sc, (sims, _) in zip(scenes, demos)])
    actions = jnp.concatenate([a for _, a in demos])
    mean, std = obs.mean(0), obs.std(0) + 1e-6
    data = Data(obs=(obs - mean) / std, action=actions, t=jnp.tile(jnp.arange(STEPS), len(scenes)),
                ape=jnp.ones(len(obs)))
    cfg = LearnerConfig(obs_shape=(5,), action_dim=2, history=1, iterations=ITERS, batch_size=64,
                        lr_boundaries=(ITERS // 2,), loss="l1")
    learner = make_train(cfg)
    params, _ = jax.jit(learner.train)(jax.random.PRNGKey(0), methods.get("bc-so").hparams({}, 1e-3, 0), data)
    model = cfg.model()

    def policy(o):
        return jnp.clip(model.apply(params, learner.policy_input(((o - mean) / std)[None, None]))[0], 0.0, 1.0)

    red, _ = drive(env, policy, _held(env, 3.0, 7.0, 52.0, 0.0), 150)   # a red light at 52 m for 15 s
    assert float(red.x.max()) < 52.0, "the policy ran the red light"
    # stops near it
    assert float(red.v.min()) < 0.05 and float(red.x[-1]) > 45.0, (float(red.v.min()), float(red.x[-1]))
    green, _ = drive(env, policy, _held(env, 3.0, 7.0, 52.0, 1.0), 100)  # the same light held green
    assert float(green.x[-1]) > 80.0, float(green.x[-1])
