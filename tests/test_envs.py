"""Environments: every registered env and observation mode runs under jit, deterministically."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs

PAPER_TASKS = envs.MUJOCO_TASKS
SMALL = {"image_size": 16}
# The paper's tasks and ToyCar are tested per mode, as users call them: separately
# jitted reset and step. Every other Brax env is tested in one program for all of
# its modes (compiling MJX costs ~10 s a program on 2 cores).
# The default run keeps Hopper's `full` and `image` and HalfCheetah's `full`; the rest is the
# full matrix (`pytest -m slow`):
# - `pos` is the same physics and Brax observation as `full`, cut to `positional_dims`
#   (a gather): `test_pos_keeps_the_positions` checks the dimensions of every task, and
#   `tests/test_data.py` collects Hopper's `pos` demonstrations under jit;
# - the renderer is one program for every task (`envs/render.py`), tested on Hopper here
#   and in `tests/test_render.py`; Walker2d's physics runs in the shipped expert's test.
DEFAULT_RUN = {("hopper", "full"), ("hopper", "image"), ("halfcheetah", "full")}
PER_MODE = [
    (n, m) if n == "toycar" or (n, m) in DEFAULT_RUN else pytest.param(n, m, marks=pytest.mark.slow)
    for n in (*PAPER_TASKS, "toycar")
    for m in envs.obs_modes(n)
]
# Every other Brax env compiles for 20-90 s on 2 cores and goes through the wrapper the paper's tasks
# use: they run in the full matrix (`pytest -m slow`).
OTHER = [pytest.param(n, marks=pytest.mark.slow) for n in envs.names() if n not in (*PAPER_TASKS, "toycar")]


def _action(env, key):
    low, high = env.action_bounds
    low, high = jnp.maximum(low, -1.0), jnp.minimum(high, 1.0)
    return jax.random.uniform(key, (env.action_size,), minval=low, maxval=high)


def _assert_finite(tree):
    for leaf in jax.tree.leaves(tree):
        leaf = np.asarray(leaf)
        if np.issubdtype(leaf.dtype, np.floating):
            assert np.all(np.isfinite(leaf))


@functools.cache
def _jitted(name, obs):
    """`(env, jit(env.reset), jit(env.step))` for `envs.make(name, obs=obs, **SMALL)`.

    Made once per test process: the tests of one environment share its compiled
    reset and step (MJX takes ~10-30 s to trace and compile each on 2 cores).
    """
    env = envs.make(name, obs=obs, **SMALL)
    return env, jax.jit(env.reset), jax.jit(env.step)


def _avals(tree):
    return jax.tree.structure(tree), [(x.shape, x.dtype, x.weak_type) for x in jax.tree.leaves(tree)]


def _check_state(env, state):
    assert state.obs.shape == env.observation_shape
    assert state.obs.dtype == env.observation_dtype
    assert state.reward.shape == () and state.done.shape == ()
    assert state.reward.dtype == jnp.float32 and state.done.dtype == jnp.float32
    _assert_finite(state)


@pytest.mark.parametrize("name,obs", PER_MODE)
def test_reset_and_step_jit_shapes_and_determinism(name, obs):
    env, reset, step = _jitted(name, obs)
    k_reset, k_act = jax.random.split(jax.random.PRNGKey(0))
    s0 = reset(k_reset)
    s1 = step(s0, _action(env, k_act))
    s2 = step(s1, _action(env, jax.random.fold_in(k_act, 1)))
    for s in (s0, s1, s2):
        _check_state(env, s)
    # reset and step give identical abstract types (Brax's weak types are removed), so a state
    # from step goes back into step without a retrace
    assert _avals(s0) == _avals(s1) == _avals(s2)
    assert step._cache_size() == 1
    # the same key gives the same trajectory, bit for bit
    r1 = step(reset(k_reset), _action(env, k_act))
    jax.tree.map(lambda a, b: np.testing.assert_array_equal(np.asarray(a), np.asarray(b)), s1, r1)
    moved = jax.tree.map(lambda a, b: bool(np.any(np.asarray(a) != np.asarray(b))), s0.pipeline_state,
                         s2.pipeline_state)
    assert any(jax.tree.leaves(moved)), "two steps changed nothing"


@pytest.mark.parametrize("name", OTHER)
def test_other_brax_envs_every_mode(name):
    modes = envs.obs_modes(name)
    assert {"full", "pos"} <= set(modes)
    made = {m: envs.make(name, obs=m, **SMALL) for m in modes}

    @jax.jit
    def run(key):
        out = {}
        for m, env in made.items():
            s0 = env.reset(key)
            out[m] = (s0, env.step(s0, _action(env, key)))
        return out

    out = run(jax.random.PRNGKey(1))
    for m, (s0, s1) in out.items():
        _check_state(made[m], s0)
        _check_state(made[m], s1)
    # pos is a strict subset of the full observation
    assert made["pos"].observation_shape[0] < made["full"].observation_shape[0]
    again = run(jax.random.PRNGKey(1))
    jax.tree.map(lambda a, b: np.testing.assert_array_equal(np.asarray(a), np.asarray(b)), out, again)


@pytest.mark.parametrize("name,dims", [("hopper", 5), ("halfcheetah", 8), ("walker2d", 8)])
def test_pos_keeps_the_positions(name, dims):
    """`pos` is Brax's qpos[1:] part: the first nq-1 observation dims, no velocities."""
    env = _jitted(name, "pos")[0]
    assert env.observation_shape == (dims,)
    assert env.brax_env.sys.q_size() - 1 == dims
    assert envs.brax_env.positional_dims(name, "mjx", ()) == tuple(range(dims))


def test_unknown_names_list_the_valid_ones():
    with pytest.raises(ValueError, match="unknown env 'hoper'.*hopper"):
        envs.make("hoper")
    with pytest.raises(ValueError, match="unknown obs mode 'rgb'.*'pos'"):
        envs.make("hopper", obs="rgb")
    with pytest.raises(ValueError, match="unknown obs mode 'pos'.*'image'"):
        envs.make("toycar", obs="pos")
    with pytest.raises(ValueError, match="'image' for env 'swimmer'.*needs the mjx backend"):
        envs.make("swimmer", obs="image")
    with pytest.raises(ValueError, match="unknown setting 'imagesize'.*image_size"):
        envs.make("hopper", imagesize=32)
    with pytest.raises(ValueError, match="unknown setting.*'speed'"):
        envs.make("toycar", speed=3)
    with pytest.raises(ValueError, match="image_size"):
        envs.make("hopper", obs="image", image_size=(0, 4))
    with pytest.raises(ValueError, match="light_range"):
        envs.make("toycar", light_range=(90.0, 120.0))


def test_brax_constructor_settings_pass_through():
    env = envs.make("hopper", obs="full", terminate_when_unhealthy=False, episode_length=50)
    assert env.brax_env._terminate_when_unhealthy is False
    assert env.episode_length == 50


@pytest.mark.parametrize("name", ["hopper", "toycar"])
def test_wrong_action_shape_is_a_trace_time_error(name):
    env, reset, _ = _jitted(name, "full")
    s0 = jax.eval_shape(reset, jax.random.PRNGKey(0))  # traced once, shared with the tests that run it
    with pytest.raises(ValueError, match=rf"shape \({env.action_size},\)"):
        jax.eval_shape(env.step, s0, jnp.zeros(env.action_size + 1))
    with pytest.raises(ValueError, match="vmap"):
        jax.eval_shape(env.step, s0, jnp.zeros((4, env.action_size)))


@pytest.mark.parametrize("name", ["hopper", "toycar"])
def test_non_finite_action_ends_the_episode_without_simulating(name):
    # one compiled step (the one the determinism test uses) for every case: the states have one type
    env, reset, step = _jitted(name, "full")
    full = lambda value: jnp.full(env.action_size, value, jnp.float32)  # noqa: E731  strong type, as _action's
    s0 = reset(jax.random.PRNGKey(2))
    good = step(s0, full(0.5))
    bad = step(good, full(0.5).at[0].set(jnp.nan))
    inf = step(good, full(jnp.inf))
    # a simulator state that cannot be integrated (every velocity-like field huge)
    if name == "toycar":
        poisoned = good.replace(pipeline_state=good.pipeline_state.replace(x=jnp.float32(jnp.nan)))
    else:
        poisoned = good.replace(pipeline_state=good.pipeline_state.replace(qvel=good.pipeline_state.qvel + 3e38))
    blown = step(poisoned, full(0.5))
    assert step._cache_size() == 1
    assert float(blown.metrics["nonfinite_state"]) == 1.0 and float(blown.metrics["invalid_action"]) == 0.0
    assert float(blown.done) == 1.0 and float(blown.reward) == 0.0
    np.testing.assert_array_equal(np.asarray(blown.obs), np.asarray(poisoned.obs))
    _assert_finite(blown.metrics)
    assert float(good.metrics["invalid_action"]) == 0 and float(good.done) == 0
    for s in (bad, inf):
        assert float(s.done) == 1.0
        assert float(s.metrics["invalid_action"]) == 1.0
        assert float(s.reward) == 0.0
        _assert_finite(s)
        # the simulator state is the one before the bad action
        jax.tree.map(
            lambda a, b: np.testing.assert_array_equal(np.asarray(a), np.asarray(b)),
            s.pipeline_state,
            good.pipeline_state,
        )
