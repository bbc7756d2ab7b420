"""What policies observe beside the sweep's observation: `bc-full`'s full state and `protocol.prev_action`."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ape_jax import evaluate as evaluate_lib
from ape_jax import methods, observations
from ape_jax.learner import Hparams, LearnerConfig, make_train
from ape_jax.pipeline import checkpoint as ckpt_lib
from ape_jax.pipeline import collect
from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline import reevaluate as reevaluate_lib
from ape_jax.pipeline import results as results_lib
from ape_jax.pipeline import sweep as S
from experiments import sweep as sweep_cli

TINY = ["budget.iterations=40", "budget.eval_episodes=2", "budget.seeds=1", "budget.probe_steps=0",
        "protocol.episodes=4"]


def _sim(env):
    """`state -> env.sim_state(state)` as a dict of arrays (what demonstrations store)."""
    def record(state):
        sim = env.sim_state(state)
        return sim if isinstance(sim, dict) else {f.name: getattr(sim, f.name) for f in dataclasses.fields(sim)}
    return record


def _demos(traj: envs.Trajectory, label) -> data_lib.Demonstrations:
    """A rollout's valid steps as demonstrations (episodes in order), as `collect` stores them."""
    valid = np.asarray(traj.valid) > 0
    rows = lambda x: np.asarray(x)[valid]  # noqa: E731
    n, t = valid.shape
    return data_lib.Demonstrations(
        obs=rows(traj.obs), action=rows(label).astype(np.float32), executed=rows(traj.action).astype(np.float32),
        episode=np.broadcast_to(np.arange(n, dtype=np.int32)[:, None], valid.shape)[valid],
        t=np.broadcast_to(np.arange(t, dtype=np.int32)[None], valid.shape)[valid],
        done=rows(traj.done), reward=rows(traj.reward), sim={k: rows(v) for k, v in traj.extra["sim"].items()})


def _toycar_demos(env, episodes: int, steps: int, key: int = 0) -> tuple[data_lib.Demonstrations, envs.Trajectory]:
    """ToyCar's expert driving in `env` (any observation mode), with the simulator state."""
    policy = envs.from_observation(env.expert, expert=True, env=env)
    traj = jax.device_get(jax.jit(lambda k: envs.rollout(env, policy, None, k, episodes, steps,
                                                         record=lambda s: {"sim": _sim(env)(s)}))(
        jax.random.PRNGKey(key)))
    return _demos(traj, traj.action), traj


def _exit_code(argv) -> int:
    try:
        return sweep_cli.main(argv)
    except SystemExit as e:
        return e.code


# -- bc-full: the full state ----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def hopper_rollout():
    """Hopper (positions only) driven by its expert, with the simulator state and Brax's full observation."""
    env = envs.make("hopper", obs="pos", episode_length=60)
    expert, _ = collect.expert_for(env)
    policy = envs.from_observation(expert, expert=True, env=env)
    record = lambda s: {"sim": env.sim_state(s), "full": s.info["brax_obs"],  # noqa: E731
                        "label": expert(env.expert_observation(s))}
    traj = jax.device_get(jax.jit(lambda k: envs.rollout(env, policy, None, k, 3, record=record))(
        jax.random.PRNGKey(0)))
    return env, _demos(traj, traj.extra["label"]), np.asarray(traj.extra["full"])[np.asarray(traj.valid) > 0]


@pytest.mark.slow
def test_the_full_observation_is_the_full_environments_bit_for_bit_and_holds_what_the_positions_lack(hopper_rollout):
    env, demos, brax_full = hopper_rollout
    env_full, full = observations.full_state(env, demos)
    assert env_full.obs_mode == "full" and env_full.observation_shape == (11,)
    np.testing.assert_array_equal(full.obs, brax_full)   # the torso height as the environment gave it, too
    assert observations.full_env(env_full) is env_full
    # with the previous action in view, it stays in view on the full state
    env_prev, demos_prev = observations.with_previous_action(env, demos)
    env_full_prev, full_prev = observations.full_state(env_prev, demos_prev)
    assert isinstance(env_full_prev, observations.PreviousAction) and env_full_prev.observation_shape == (14,)
    np.testing.assert_array_equal(full_prev.obs, np.concatenate([brax_full, observations.previous_actions(demos)], 1))
    # planted: the expert acts on velocities; BC on the positions cannot fit what BC on the full state fits
    losses = {}
    for name, obs in (("pos", demos.obs), ("full", full.obs)):
        obs = (obs - obs.mean(0)) / (obs.std(0) + 1e-6)
        cfg = LearnerConfig(obs_shape=(obs.shape[1],), action_dim=3, history=1, iterations=600, batch_size=64,
                            lr_boundaries=())
        data = S.Data(obs=jnp.asarray(obs), action=jnp.asarray(demos.action), t=jnp.asarray(demos.t),
                      ape=jnp.zeros(len(demos)))
        learner = make_train(cfg)
        params, _ = jax.jit(learner.train)(jax.random.PRNGKey(0), Hparams.make(lr=1e-3), data)
        losses[name] = float(jnp.mean(jax.vmap(lambda i: learner.per_sample_loss(params, data, i[None])[0])(
            jnp.arange(len(demos)))))
    assert losses["full"] < 0.5 * losses["pos"], losses


def test_the_full_observation_of_frames_is_the_full_environments_and_is_refused_without_simulator_state():
    image = envs.make("toycar", obs="image", image_size=(8, 8))
    demos, _ = _toycar_demos(image, 1, 5)
    truth, _ = _toycar_demos(envs.make("toycar", obs="full"), 1, 5)
    np.testing.assert_array_equal(observations.full_observations(image, demos), truth.obs)
    with pytest.raises(observations.FullStateError, match="no simulator state of 'toycar'") as e:
        observations.full_observations(image, demos.replace(sim={}), "my.npz")
    assert "\n" not in str(e.value) and "my.npz" in str(e.value)


def test_bc_full_is_registered_as_a_reference_reading_the_full_state_at_history_one():
    m = methods.get("bc-full")
    assert (m.role, m.history, m.observation, m.program) == ("reference", 1, "full", "bc-full")
    with methods.scratch():
        with pytest.raises(methods.MethodError, match="unknown observation"):
            methods.register(methods.Method("x-velocity", "x", grid=m.grid, hparams=m.hparams, program="x",
                                            observation="velocity"))
        with pytest.raises(methods.MethodError, match="another history, observation or learner"):
            methods.register(methods.Method("x-full", "x", grid=m.grid, hparams=m.hparams, program="bc-so",
                                            history=1, observation="full"))


@pytest.fixture(scope="module")
def image_sweep(tmp_path_factory):
    """A tiny ToyCar sweep on 8×8 frames with BC-SO and bc-full (which reads the car's full state)."""
    tmp = tmp_path_factory.mktemp("bcfull")
    spec = S.SweepSpec.make("toycar", "image", ("bc-so", "bc-full"), recipe="mlp",
                            sets=[*TINY, "protocol.image_size=8,8", "recipe.encoder=patch", "budget.probe_steps=20"],
                            data_dir=tmp / "data")
    res, policies = S.run_sweep(spec, S.Hooks(log=lambda m: None))
    ckpt_lib.save_policies(tmp / "params", policies)
    results_lib.save(tmp / "results.json", res)
    return tmp, spec, res, policies


@pytest.mark.integration
def test_bc_full_trains_on_and_is_evaluated_with_the_full_observation(image_sweep):
    tmp, spec, res, policies = image_sweep
    assert set(policies) == {"h1", "full-h1"}
    full, own = policies["full-h1"], policies["h1"]
    assert [r["method"] for r in full["runs"]] == ["bc-full"] and (full["history"], full["observation"]) == (1, "full")
    assert full["obs_mean"].shape == (5,) and own["obs_mean"] is None   # its own statistics; frames have none
    prepared = S.prepare(spec)
    view = prepared.view("full")
    assert view.env.obs_mode == "full" and view is prepared.view("full") and prepared.view(None) is prepared
    assert prepared.observing("full") == "full" and view.train.obs.shape == (len(prepared.train), 5)
    np.testing.assert_allclose(full["obs_mean"], view.train.obs.mean(0), rtol=1e-5)
    cfg = view.learner_config(spec.settings, 1)      # one 5-d full state in, history 1: the saved network's shapes
    fresh = make_train(cfg).init_policy(jax.random.PRNGKey(0), view.data(view.train, np.zeros(len(view.train))))
    assert jax.tree.map(lambda a: a.shape[1:], full["params"]) == jax.tree.map(np.shape, fresh)
    records = {r["method"]: r for r in res.runs}
    assert records["bc-full"]["status"] == "ok" and records["bc-full"]["eval"]["episodes"] == 2
    assert set(records["bc-full"]["losses"]["train"]) == {"unweighted", "changepoint", "copycat"}
    assert res.methods["bc-full"]["role"] == "reference"


@pytest.mark.integration
def test_bc_full_policies_reload_and_reevaluate_to_the_same_returns(image_sweep):
    tmp, spec, res, _ = image_sweep
    saved = ckpt_lib.load_policies(tmp / "params")
    assert json.loads((tmp / "params" / "full-h1.json").read_text())["observation"] == "full"
    assert (saved["full-h1"]["history"], saved["full-h1"]["observation"]) == (1, "full")
    was = results_lib.load(tmp / "results.json")
    for run in was.runs:   # lacking a field, so the evaluation runs again and must reproduce the returns
        run["eval"].pop("imitation_error")
    # it raises if a recorded return or metric does not come out again; the field it adds must equal the sweep's
    new = reevaluate_lib.reevaluate(was, tmp / "params", data_dir=spec.data_dir, log=lambda m: None)
    assert "imitation_error" in new.reevaluated["fields"]
    again = {r["method"]: r["eval"] for r in new.runs}
    for run in res.runs:
        assert again[run["method"]]["imitation_error"] == pytest.approx(run["eval"]["imitation_error"], rel=1e-5)


def test_policies_saved_before_groups_had_an_observation_still_load(tmp_path):
    ckpt_lib.save_policies(tmp_path, {"h2": {"runs": [{"method": "bc-oh", "hparams": {}, "seed": 0}],
                                            "params": {"w": np.zeros((1, 3))}, "obs_mean": None}})
    assert isinstance(json.loads((tmp_path / "h2.json").read_text()), list)   # the old layout: the runs alone
    saved = ckpt_lib.load_policies(tmp_path)["h2"]
    assert (saved["history"], saved["observation"]) == (2, None)


def test_a_sweep_with_bc_full_on_a_dataset_without_simulator_state_is_refused_in_one_line(tmp_path, capsys):
    demos, _ = _toycar_demos(envs.make("toycar", obs="image", image_size=(8, 8)), 3, 200, key=1)
    data_lib.save(tmp_path / "mine.npz", demos.replace(sim={}))
    out = tmp_path / "run"
    code = _exit_code(["--env", "toycar", "--obs", "image", "--set", "protocol.image_size=8,8",
                       "--dataset", str(tmp_path / "mine.npz"), "--methods", "bc-so,bc-full",
                       "--iterations", "5", "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "bc-full" in err and "simulator state" in err
    assert not out.exists()


# -- the previous action in view ------------------------------------------------------------------------------------

def test_previous_actions_are_the_executed_ones_shifted_within_each_episode_zeros_at_its_start():
    executed = np.arange(12, dtype=np.float32).reshape(6, 2)
    demos = data_lib.Demonstrations(obs=np.ones((6, 3), np.float32), action=-executed, executed=executed,
                                    episode=np.array([0, 0, 0, 1, 1, 1]), t=np.array([0, 1, 2, 0, 1, 2]),
                                    done=np.zeros(6), reward=np.zeros(6))
    out = observations.carrying_previous_action(demos)
    np.testing.assert_array_equal(out.obs[:, :3], 1.0)
    np.testing.assert_array_equal(out.obs[:, 3:], [[0, 0], [0, 1], [2, 3], [0, 0], [6, 7], [8, 9]])
    with pytest.raises(ValueError, match="vector observations"):
        observations.carrying_previous_action(demos.replace(obs=np.zeros((6, 4, 4, 3), np.uint8)))


def test_in_a_rollout_the_observation_carries_the_policys_own_last_executed_action():
    inner = envs.make("toycar", obs="full", episode_length=40)
    env = observations.PreviousAction(inner)
    assert env.observation_shape == (7,) and env.episode_metric_names == inner.episode_metric_names
    cfg = LearnerConfig(obs_shape=(7,), action_dim=2, history=2, iterations=1, batch_size=1)
    params = make_train(cfg).init_policy(jax.random.PRNGKey(3), S.Data(
        obs=jnp.zeros((1, 7)), action=jnp.zeros((1, 2)), t=jnp.zeros(1, jnp.int32), ape=jnp.zeros(1)))
    mean, std = jnp.full(7, 0.3), jnp.full(7, 0.5)     # the carried action is standardised like the rest
    policy = evaluate_lib.history_policy(cfg, mean, std, env)
    traj = jax.device_get(jax.jit(lambda k: envs.rollout(env, policy, params, k, 2))(jax.random.PRNGKey(0)))
    valid = np.asarray(traj.valid) > 0
    assert valid[:, 5:].any()
    np.testing.assert_array_equal(traj.obs[:, 0, 5:], 0.0)                     # zeros at t = 0
    carried, last = traj.obs[:, 1:, 5:], traj.action[:, :-1]
    np.testing.assert_array_equal(carried[valid[:, 1:]], last[valid[:, 1:]])    # the last executed action
    assert np.abs(last[valid[:, 1:]]).max() > 0                                # and not zeros all along
    low, high = inner.action_bounds
    assert (last >= np.asarray(low)).all() and (last <= np.asarray(high)).all()   # as executed: clipped
    # everything else is the environment's: the same steps with the same actions observe the same
    replay = jnp.asarray(traj.action[0])
    alone = jax.device_get(jax.jit(lambda k: envs.rollout(
        inner, envs.stateless(lambda p, s, key: replay[s.pipeline_state.t]), None, k, 2))(jax.random.PRNGKey(0)))
    np.testing.assert_array_equal(alone.obs[0][valid[0]], traj.obs[0, :, :5][valid[0]])


def test_a_prev_action_sweep_trains_on_the_demonstrations_executed_previous_action(tmp_path):
    spec = S.SweepSpec.make("toycar", "full", ("bc-so", "bc-oh"), recipe="mlp",
                            sets=[*TINY, "protocol.prev_action=true"], data_dir=tmp_path)
    prepared = S.prepare(spec)
    assert isinstance(prepared.env, observations.PreviousAction) and prepared.env.observation_shape == (7,)
    d = prepared.train.demos
    np.testing.assert_array_equal(d.obs[:, 5:], observations.previous_actions(d))
    assert (d.obs[np.asarray(d.t) == 0, 5:] == 0).all() and (d.obs[:, 5:] != 0).any()
    programs = S.plan(spec, prepared)
    assert {p.cfg.obs_shape for p in programs} == {(7,)}
    assert prepared.normalizer.mean.shape == (7,)
    assert spec.protocol_settings()["prev_action"] is True


def test_prev_action_with_frames_is_refused_in_one_line_before_anything_runs(tmp_path, capsys):
    code = _exit_code(["--env", "toycar", "--obs", "image", "--set", "protocol.prev_action=true",
                       "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "prev_action needs vector observations" in err
    assert not (tmp_path / "run").exists()


def test_a_registered_driving_task_observes_the_full_state_with_its_own_settings():
    for name, settings in (("toycar", {"image_size": 32}), ("toytown", {"image_size": 32, "traffic": "regular"})):
        env = envs.make(name, obs="image", **settings)
        full = observations.full_env(env)
        assert full.obs_mode == "full" and full.config == env.config and type(full) is type(env)
        assert observations.full_env(full) is full
