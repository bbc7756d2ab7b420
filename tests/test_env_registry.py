"""The task registry: a task is one module; `envs.make` and its companions find it by name, and nothing else
changes. The tiny task here is made and registered inside the test and leaves no trace in the registry."""

import dataclasses
import inspect

import jax
import jax.numpy as jnp
import pytest

import envs
from envs import registry
from envs.base import Env, State


@dataclasses.dataclass(frozen=True)
class LineConfig:
    """A point on a line that the action pushes; the episode ends past `goal`."""

    goal: float = 3.0
    episode_length: int = 20

    def __post_init__(self):
        if self.goal <= 0:
            raise ValueError(f"goal must be > 0, got {self.goal!r}")


class Line(Env):
    name = "line"

    def __init__(self, obs_mode: str, config: LineConfig):
        self.obs_mode, self.config = obs_mode, config

    observation_shape = property(lambda self: (2,))
    action_size = property(lambda self: 1)
    action_bounds = property(lambda self: (-jnp.ones(1), jnp.ones(1)))
    dt = property(lambda self: 1.0)
    episode_length = property(lambda self: self.config.episode_length)

    def _reset(self, key):
        x = jax.random.uniform(key, (), maxval=0.5)
        zero = jnp.zeros((), jnp.float32)
        return State(x, jnp.stack([x, zero]), zero, zero)

    def _step(self, state, action):
        x = state.pipeline_state + action[0]
        done = jnp.maximum(state.done, (x > self.config.goal).astype(jnp.float32))
        return State(x, jnp.stack([x, jnp.float32(self.config.goal)]), action[0], done)

    def render(self, state):
        return jnp.zeros((4, 4, 3), jnp.uint8)

    def expert_observation(self, state):
        return state.obs


@pytest.fixture
def line():
    with registry.registered("line", Line, LineConfig, obs_modes=("full",), default_obs="full") as spec:
        yield spec
    assert "line" not in envs.names()


def test_a_task_registered_in_one_place_is_made_and_stepped_through_envs_make(line):
    assert "line" in envs.names() and registry.get("line") is line
    assert envs.obs_modes("line") == ("full",) and envs.default_obs("line") == "full"
    assert envs.default_episode_length("line") == 20
    env = envs.make("line", goal=2.0)
    assert isinstance(env, Line) and env.config == LineConfig(goal=2.0)
    assert envs.make("line").config is not envs.make("line").config  # each call builds its own config
    push = envs.from_observation(lambda obs: jnp.ones(1))
    traj = jax.jit(lambda k: envs.rollout(env, push, None, k, num_episodes=3))(jax.random.PRNGKey(0))
    assert traj.obs.shape == (3, 20, 2)
    assert jnp.all(traj.lengths == 2)  # from below 0.5, two pushes of 1 pass the goal at 2
    assert registry.same_task(env, "full").config == env.config


def test_the_registry_refuses_mistakes_naming_the_valid_choices(line):
    with pytest.raises(ValueError, match=r"unknown setting\(s\) \['gaol'\] for env 'line'; "
                                         r"valid: \['episode_length', 'goal'\]"):
        envs.make("line", gaol=2.0)
    with pytest.raises(ValueError, match=r"unknown obs mode 'image' for env 'line'; valid: \['full'\]"):
        envs.make("line", obs="image")
    with pytest.raises(ValueError, match="goal must be > 0"):
        envs.make("line", goal=-1.0)
    with pytest.raises(ValueError, match="registered already"):
        registry.register("line", Line, LineConfig, obs_modes=("full",), default_obs="full")
    with pytest.raises(ValueError, match="registered already"):
        registry.register("hopper", Line, LineConfig, obs_modes=("full",), default_obs="full")
    with pytest.raises(ValueError, match="default_obs 'image' is not one of"):
        registry.register("line2", Line, LineConfig, obs_modes=("full",), default_obs="image")
    with pytest.raises(ValueError, match="needs an episode_length"):
        registry.register("line2", Line, dataclasses.make_dataclass("C", [("goal", float, 1.0)], frozen=True),
                          obs_modes=("full",), default_obs="full")
    assert "line2" not in envs.names()


def test_a_registration_is_undone_even_when_the_block_fails():
    with pytest.raises(RuntimeError):
        with registry.registered("line", Line, LineConfig, obs_modes=("full",), default_obs="full"):
            raise RuntimeError("boom")
    assert registry.get("line") is None
    with pytest.raises(ValueError, match="unknown env 'line'"):
        envs.make("line")


def test_the_suite_tasks_are_registered_and_envs_names_none_of_them():
    assert {"toycar", "toytown"} <= set(registry.names())
    assert envs.default_episode_length("toycar") == envs.ToyCarConfig().episode_length
    source = inspect.getsource(envs)
    for task in registry.names():
        assert f'"{task}"' not in source.split('__all__')[0].split('"""', 2)[2], task  # code, not the docstring
    # a setting a task does not have is refused with the valid ones listed (ToyCar has no speed input)
    with pytest.raises(ValueError, match=r"unknown setting\(s\) \['speed_input'\] for env 'toycar'; valid: .*"
                                         r"'road_length'"):
        envs.make("toycar", speed_input=True)
