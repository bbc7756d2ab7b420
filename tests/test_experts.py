"""Experts: the SAC trainer learns a trivial task; shipped experts load and perform; bad files are refused."""

import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax import envs as brax_envs

import envs
from envs import experts
from envs.experts import ExpertError
import dataclasses

from ape_jax.experts.sac import Checkpoints, SACConfig, make_trainer, run_epoch
from experiments import train_expert


class Reach(brax_envs.Env):
    """A point on a line that should move to a target: obs `[x, target]`, reward `-|x - target|`."""

    def reset(self, rng):
        q = jax.random.uniform(rng, (2,), minval=-1.0, maxval=1.0)
        zero = jnp.zeros(())
        return brax_envs.State(pipeline_state=q, obs=q, reward=zero, done=zero, metrics={}, info={})

    def step(self, state, action):
        x, target = state.pipeline_state
        q = jnp.stack([jnp.clip(x + 0.2 * action[0], -1.5, 1.5), target])
        return state.replace(pipeline_state=q, obs=q, reward=-jnp.abs(q[0] - target))

    observation_size = property(lambda self: 2)
    action_size = property(lambda self: 1)
    backend = property(lambda self: "none")


@pytest.fixture(scope="module")
def tiny_run():
    cfg = SACConfig(num_timesteps=4096, num_envs=16, grad_updates_per_step=16, batch_size=64,
                    min_replay_size=256, hidden_layer_sizes=(32, 32), episode_length=20,
                    epoch_steps=1024, num_eval_envs=32, learning_rate=1e-3)
    trainer = make_trainer(Reach(), cfg)
    state = trainer.prefill(trainer.init(jax.random.PRNGKey(0)))
    before = trainer.evaluate(state.policy)[0]
    for _ in range(cfg.num_epochs):
        state, metrics = trainer.epoch(state)
    return trainer, state, before, trainer.evaluate(state.policy)[0]


def test_a_tiny_expert_learns_a_trivial_task(tiny_run):
    _, state, before, after = tiny_run
    # 20 steps of -|x - target|: a random start costs ~ -13 standing still; a good policy gets within 2
    assert after > before + 3 and after > -4, (before, after)
    assert int(state.env_steps) >= 4096 and int(state.grad_steps) == 4 * 64 * 16


def test_exported_policy_reproduces_the_trained_deterministic_policy(tiny_run, tmp_path):
    trainer, state, _, _ = tiny_run
    spec = trainer.policy_spec(state.policy)
    experts.save(tmp_path, spec, {"network": {"obs_size": 2, "action_size": 1, "hidden": [32, 32]}})
    policy = experts.load("reach", root=tmp_path)
    obs = jax.random.uniform(jax.random.PRNGKey(1), (64, 2), minval=-1, maxval=1)
    from brax.training.agents.sac import networks as sac_networks  # the trainer's own forward pass
    from brax.training.acme import running_statistics

    nets = sac_networks.make_sac_networks(2, 1, running_statistics.normalize, hidden_layer_sizes=(32, 32))
    want, _ = sac_networks.make_inference_fn(nets)((state.policy.normalizer, state.policy.network), True)(obs, None)
    np.testing.assert_allclose(np.asarray(jax.jit(policy)(obs)), np.asarray(want), atol=1e-6)


def test_missing_or_corrupt_experts_name_the_file_and_the_command(tiny_run, tmp_path):
    trainer, state, _, _ = tiny_run
    with pytest.raises(ExpertError, match=r"card.json does not exist.*train_expert --env walker9"):
        experts.load("walker9", root=tmp_path / "nothing")
    good = tmp_path / "good"
    experts.save(good, trainer.policy_spec(state.policy), {"network": {"obs_size": 2, "action_size": 1,
                                                                       "hidden": [32, 32]}})
    bad_card = tmp_path / "bad_card"
    shutil.copytree(good, bad_card)
    (bad_card / "card.json").write_text("{ not json")
    with pytest.raises(ExpertError, match=r"corrupt expert card .*bad_card/card.json"):
        experts.load("reach", root=bad_card)
    wrong = tmp_path / "wrong_shape"
    shutil.copytree(good, wrong)
    (wrong / "card.json").write_text(json.dumps({"network": {"obs_size": 3, "action_size": 1, "hidden": [32, 32]}}))
    with pytest.raises(ExpertError, match=r"corrupt expert checkpoint .*wrong_shape/policy"):
        experts.load("reach", root=wrong)
    damaged = tmp_path / "damaged"
    shutil.copytree(good, damaged)
    for f in (damaged / "policy").rglob("*"):
        if f.is_file() and f.stat().st_size > 0:
            f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    with pytest.raises(ExpertError, match=r"corrupt expert checkpoint .*damaged/policy.*train_expert --env reach"):
        experts.load("reach", root=damaged)


def test_a_restored_checkpoint_trains_on_exactly_like_the_uninterrupted_run(tmp_path):
    cfg = SACConfig(num_timesteps=2048, num_envs=8, grad_updates_per_step=4, batch_size=32, min_replay_size=64,
                    hidden_layer_sizes=(16,), episode_length=10, epoch_steps=256, num_eval_envs=4)
    trainer = make_trainer(Reach(), cfg)
    ckpt = Checkpoints(tmp_path / "ckpt", trainer, cfg)
    state = trainer.prefill(trainer.init(jax.random.PRNGKey(0)))
    state, best, meta = run_epoch(trainer, state, jax.tree.map(jnp.copy, state.policy), ckpt.new_meta())
    ckpt.save(state, best, meta)
    state2, best2, meta2 = Checkpoints(tmp_path / "ckpt", trainer, cfg).restore()
    assert meta2 == meta and len(meta["history"]) == 1
    for a, b in zip(jax.tree.leaves((state, best)), jax.tree.leaves((state2, best2))):
        np.testing.assert_array_equal(a, b)  # replay buffer, optimisers, temperature, key: all of it
    uninterrupted, _ = trainer.epoch(jax.tree.map(jnp.copy, state))
    resumed, _ = trainer.epoch(state2)
    for a, b in zip(jax.tree.leaves(uninterrupted), jax.tree.leaves(resumed)):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="other settings"):
        Checkpoints(tmp_path / "ckpt", trainer, dataclasses.replace(cfg, learning_rate=1e-3)).restore()


def _truncate_arrays(step):
    for f in (step / "state").rglob("*"):
        if f.is_file() and f.parent.name == "d":
            f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])


@pytest.mark.parametrize("damage", [_truncate_arrays, lambda step: shutil.rmtree(step / "meta")])
def test_a_damaged_checkpoint_is_refused_in_one_line_and_left_in_place(tmp_path, damage):
    cfg = SACConfig(num_timesteps=256, num_envs=4, batch_size=8, min_replay_size=8, hidden_layer_sizes=(8,),
                    episode_length=4, epoch_steps=64, num_eval_envs=2)
    trainer = make_trainer(Reach(), cfg)
    ckpt = Checkpoints(tmp_path / "ckpt", trainer, cfg)
    state = trainer.init(jax.random.PRNGKey(0))  # no training: a checkpoint of the initial state will do
    ckpt.save(state, state.policy, ckpt.new_meta())
    ckpt.close()
    damage(tmp_path / "ckpt" / "0")
    files = {f: f.read_bytes() for f in tmp_path.rglob("*") if f.is_file()}
    with pytest.raises(ValueError, match=r"ckpt/0: corrupt or incomplete checkpoint \(") as err:
        Checkpoints(tmp_path / "ckpt", trainer, cfg).restore()
    assert "\n" not in str(err.value)
    assert {f: f.read_bytes() for f in tmp_path.rglob("*") if f.is_file()} == files


# Over 200 steps: a random policy falls within ~20 steps (Hopper, Walker2d) or
# drifts (HalfCheetah, returns near 0); a trained expert keeps collecting
# healthy and forward reward. Bounds are a third of the card's 1000-step return,
# scaled to 200 steps, and well above random.
@pytest.mark.parametrize("name", [*envs.MUJOCO_TASKS, "hopper-ppo",   # and the variants shipped beside them
                                  *(f"{task}-rough" for task in envs.MUJOCO_TASKS)])
@pytest.mark.integration
def test_shipped_experts_load_and_beat_a_random_policy(name):
    card = experts.card(name)
    policy = experts.load(name)
    env = envs.make(name.partition("-")[0], obs="full")
    run = jax.jit(lambda k: envs.rollout(env, envs.from_observation(policy, expert=True, env=env), None, k,
                                         num_episodes=4, num_steps=200).returns)
    # 800 MJX steps run ~20 s at the suite's XLA backend optimisation level 0 (conftest), under a
    # second at level 1, which compiles a few seconds longer: this program asks for level 1
    key = jax.random.PRNGKey(0)
    run = run.lower(key).compile(compiler_options={"xla_backend_optimization_level": 1})
    returns = np.asarray(run(key))
    bound = max(card["return_mean"] * 0.2 / 3, card["random_return_mean"] + 50)
    assert returns.mean() > bound, (returns, bound)


@pytest.mark.parametrize("argv, message", [
    (["--env", "toycar"], "rule-based"),
    (["--env", "nope"], "unknown env 'nope'"),
    (["--env", "hopper", "--steps", "0"], "must be >= 1"),
])
def test_train_expert_refuses_bad_input_with_exit_code_2(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        train_expert.main(argv)
    assert exit_.value.code == 2 and message in capsys.readouterr().err


def test_the_rough_export_is_brax_ppos_normal_mean_unbounded():
    """`export_params` + `policy_from_params(..., "tanh", "linear")` give Brax's own deterministic policy (the
    normal's mean, normaliser included), and nothing squashes it: with a scaled last layer it leaves [-1, 1]."""
    from brax.training.acme import running_statistics
    from brax.training.agents.ppo import networks as ppo_networks

    nets = ppo_networks.make_ppo_networks(5, 3, running_statistics.normalize, policy_hidden_layer_sizes=(16, 16),
                                          activation=jnp.tanh, distribution_type="normal", noise_std_type="log")
    policy_params = nets.policy_network.init(jax.random.PRNGKey(0))
    dense = policy_params["params"]["Dense_0"]
    policy_params["params"]["Dense_0"] = {**dense, "kernel": 20.0 * dense["kernel"]}   # a mean beyond the range
    obs = 3.0 * jax.random.normal(jax.random.PRNGKey(1), (256, 5)) + 1.0
    normalizer = running_statistics.update(running_statistics.init_state(jax.ShapeDtypeStruct((5,), jnp.float32)),
                                           obs)
    want, _ = ppo_networks.make_inference_fn(nets)((normalizer, policy_params), deterministic=True)(obs, None)
    params = train_expert.export_params(normalizer, policy_params, "normal")
    assert [k.shape for k in params["kernels"]] == [(5, 16), (16, 16), (16, 3)]
    got = np.asarray(jax.jit(experts.policy_from_params(params, "tanh", "linear"))(obs))
    np.testing.assert_allclose(got, np.asarray(want), atol=1e-5)
    assert np.abs(got).max() > 1.5


def test_the_rough_trainer_runs_and_exports_a_linear_head(tmp_path):
    """A few PPO steps of the rough settings on the point task: a normal policy with its learned std, exported with
    `network.head` "linear" and loadable with it."""
    cfg = train_expert.PpoSettings(**dict(train_expert.ROUGH, num_timesteps=640, num_envs=8, unroll_length=5,
                                          batch_size=8, num_minibatches=2, num_updates_per_batch=2,
                                          episode_length=20, num_evals=2, num_eval_envs=8, seed=0,
                                          hidden_layer_sizes=(16, 16), frame_skip=None))
    params, meta = train_expert.run_ppo(Reach(), cfg)
    assert [k.shape for k in params["kernels"]] == [(2, 16), (16, 16), (16, 1)]
    assert len(meta["history"]) == 2 and len(meta["policy_std"]) == 1 and meta["policy_std"][0] > 0
    card = {"network": {"obs_size": 2, "action_size": 1, "hidden": [16, 16], "activation": "tanh",
                        "head": "linear"}}
    experts.save(tmp_path, params, card)
    policy = experts.load("reach", root=tmp_path)
    obs = jax.random.uniform(jax.random.PRNGKey(1), (8, 2), minval=-1, maxval=1)
    np.testing.assert_allclose(np.asarray(policy(obs)),
                               np.asarray(experts.policy_from_params(params, "tanh", "linear")(obs)), atol=1e-6)


def test_train_expert_refuses_a_bad_set_with_exit_code_2(capsys):
    for argv, message in ((["--algorithm", "rough", "--set", "nope=1"], "expected NAME=VALUE"),
                          (["--algorithm", "rough", "--set", "entropy_cost=x"], "is not a number"),
                          (["--algorithm", "rough", "--set", "distribution_type=beta"], "distribution_type must be"),
                          (["--set", "entropy_cost=0.1"], "--set applies to --algorithm ppo or rough")):
        with pytest.raises(SystemExit) as exit_:
            train_expert.main(["--env", "hopper", *argv])
        assert exit_.value.code == 2 and message in capsys.readouterr().err, argv
