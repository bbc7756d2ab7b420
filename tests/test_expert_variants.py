"""Expert variants shipped beside a task's own (`envs/experts/<env>-<variant>/`, `protocol.expert`): the tanh
network of a PPO expert, and a sweep's data, references and commands naming the variant."""

import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ape_jax import tasks
from ape_jax.pipeline import collect
from ape_jax.pipeline.presets import resolve
from envs import experts
from envs.experts import ExpertError


def _params(key, sizes=(4, 8, 8, 6)):
    keys = jax.random.split(key, len(sizes))
    return {"obs_mean": jnp.full((sizes[0],), 0.5), "obs_std": jnp.full((sizes[0],), 2.0),
            "kernels": [jax.random.normal(k, (a, b)) for k, a, b in zip(keys, sizes[:-1], sizes[1:])],
            "biases": [jnp.full((b,), 0.1) for b in sizes[1:]]}


def test_a_tanh_expert_applies_tanh_between_layers_and_an_unknown_activation_is_refused():
    p = _params(jax.random.PRNGKey(0))
    obs = jax.random.normal(jax.random.PRNGKey(1), (5, 4))
    x = (obs - 0.5) / 2.0
    for i, (k, b) in enumerate(zip(p["kernels"], p["biases"])):
        x = x @ k + b
        x = jnp.tanh(x) if i < 2 else x
    np.testing.assert_allclose(experts.policy_from_params(p, "tanh")(obs), jnp.tanh(x[:, :3]), rtol=1e-5)
    assert not np.allclose(experts.policy_from_params(p, "relu")(obs), jnp.tanh(x[:, :3]))
    with pytest.raises(ExpertError, match="unknown expert activation 'swish'"):
        experts.policy_from_params(p, "swish")


def test_a_variant_names_its_own_commands():
    assert experts.train_command("hopper-ppo") == "python -m experiments.train_expert --env hopper --algorithm ppo"
    assert experts.train_command("hopper") == "python -m experiments.train_expert --env hopper"
    assert experts.reference_command("hopper-ppo", "mujoco-state") == \
        "python -m experiments.expert_references --env hopper --expert ppo --protocol mujoco-state"


@pytest.fixture
def variant_root(tmp_path, monkeypatch):
    """The shipped experts plus `hopper-ppo`, a copy of Hopper's own under the variant's name."""
    for name in ("hopper", "hopper-ppo"):
        shutil.copytree(experts.directory("hopper"), tmp_path / name)
    monkeypatch.setattr(experts, "ROOT", tmp_path)
    return tmp_path


def test_the_protocols_expert_names_the_data_and_is_recorded_only_when_set(variant_root):
    own = resolve("hopper", "pos", "mujoco-state", "quick").protocol
    ppo = resolve("hopper", "pos", "mujoco-state", "quick", sets=["protocol.expert=ppo"]).protocol
    assert (own.expert_name("hopper"), ppo.expert_name("hopper")) == ("hopper", "hopper-ppo")
    assert "expert" not in own.settings(4) and ppo.settings(4)["expert"] == "ppo"   # old records stay valid
    setup = collect.protocol_setup("hopper", "pos", ppo)
    a = collect.data_key("hopper", "pos", 2, **collect.protocol_setup("hopper", "pos", own).env_overrides)
    b = collect.data_key("hopper", "pos", 2, expert=setup.expert, **setup.env_overrides)
    assert (a["expert"]["path"], b["expert"]["path"]) == ("envs/experts/hopper", "envs/experts/hopper-ppo")
    assert (collect.ExpertRef.of_key(a).variant, collect.ExpertRef.of_key(b).variant) == (None, "ppo")


def test_a_bad_or_missing_variant_is_refused_with_its_command(variant_root):
    with pytest.raises(ValueError, match="protocol.expert must be a variant name"):
        resolve("hopper", "pos", "mujoco-state", "quick", sets=["protocol.expert=PPO!"])
    with pytest.raises(ExpertError, match="--env hopper --algorithm sac2"):
        collect.data_key("hopper", "pos", 2, expert="sac2")
    with pytest.raises(ValueError, match="rule-based"):
        collect.data_key("toycar", "full", 2, expert="ppo")
    assert tasks.get("hopper").expert == "shipped"
