"""Environments of ape_jax: Brax/MJX locomotion and the registered tasks (ToyCar, ToyTown), behind one `make`.

    env = envs.make("hopper", obs="pos")          # velocities removed: 5 dims
    env = envs.make("walker2d", obs="image", image_size=32)
    env = envs.make("toycar")                      # images by default
    env = envs.make("toytown", traffic="dense", speed_input=False)
    traj = jax.jit(lambda k: envs.rollout(env, policy, params, k, num_episodes=8))(key)

Every environment has pure `reset(key) -> State` and `step(state, action) ->
State` (see `envs.base`); step them with `envs.rollout`. A task is one module
that registers itself (`envs.registry`); Brax's names are the fallback.
"""

from __future__ import annotations

from envs import _quiet  # noqa: F401  (silences MJX/Brax import noise first)
from envs import brax_env, registry
from envs import toycar, toytown  # noqa: F401  (task modules: each registers itself on import)
from envs.base import OBS_MODES, ConfiguredEnv, Env, State
from envs.render import Camera
from envs.rollout import Policy, Trajectory, from_observation, rollout, stateless
from envs.toycar import ToyCar, ToyCarConfig
from envs.toytown import ToyTown, ToyTownConfig

MUJOCO_TASKS = ("hopper", "halfcheetah", "walker2d")  # the paper's three tasks


def names() -> tuple[str, ...]:
    """Every name `make` accepts: Brax's environments and the registered tasks (`envs.registry`)."""
    return tuple(sorted((*brax_env.brax_names(), *registry.names())))


def obs_modes(name: str) -> tuple[str, ...]:
    """Observation modes environment `name` supports."""
    _check_name(name)
    spec = registry.get(name)
    if spec is not None:
        return spec.obs_modes
    if brax_env.default_config(name).backend != "mjx":
        return ("full", "pos")  # rendering needs MJX
    return OBS_MODES


def default_obs(name: str) -> str:
    """The observation mode `make` uses when `obs` is not given."""
    spec = registry.get(name)
    return spec.default_obs if spec is not None else "full"


def _check_name(name: str) -> None:
    if name not in names():
        raise ValueError(f"unknown env {name!r}; valid: {list(names())}")


def default_episode_length(name: str) -> int:
    """Control steps per episode of environment `name` at its defaults (Brax's 1000, a registered task's own),
    read from its config without building it."""
    _check_name(name)
    spec = registry.get(name)
    return (spec.default_config() if spec is not None else brax_env.default_config(name)).episode_length


def make(name: str, obs: str | None = None, **overrides) -> Env:
    """Builds environment `name` with observation mode `obs`.

    Args:
      name: one of `names()`: a registered task (`toycar`, `toytown`, or one of yours: `envs.registry`),
        `hopper`, `halfcheetah`, `walker2d` or any other Brax environment.
      obs: `full`, `pos` or `image` (see `obs_modes(name)`); default `full`
        for Brax environments, the task's own for a registered task (`image` for ToyCar and ToyTown).
      **overrides: settings replacing the environment's defaults. Brax
        environments take the fields of `brax_env.BraxConfig` (e.g.
        `image_size=32`, `episode_length=500`, `camera=Camera(...)`) and any
        keyword of the Brax environment's constructor (e.g.
        `terminate_when_unhealthy=False`); a registered task takes the fields of its config
        (`ToyCarConfig`, `ToyTownConfig`).

    Returns:
      A fresh `Env`; each call builds its own config.

    Raises:
      ValueError: unknown name, observation mode or setting, or an invalid
        value (the message lists the valid choices).
    """
    _check_name(name)
    spec = registry.get(name)
    if spec is not None:
        return spec.make(obs, **overrides)
    obs = default_obs(name) if obs is None else obs
    if obs not in obs_modes(name):
        why = " (obs='image' needs the mjx backend)" if obs == "image" else ""
        raise ValueError(f"unknown obs mode {obs!r} for env {name!r}; valid: {list(obs_modes(name))}{why}")
    return brax_env.BraxEnv(name, obs, brax_env.split_overrides(name, overrides))


__all__ = [
    "MUJOCO_TASKS",
    "OBS_MODES",
    "Camera",
    "ConfiguredEnv",
    "Env",
    "Policy",
    "State",
    "ToyCar",
    "ToyCarConfig",
    "ToyTown",
    "ToyTownConfig",
    "Trajectory",
    "default_episode_length",
    "default_obs",
    "from_observation",
    "make",
    "names",
    "obs_modes",
    "registry",
    "rollout",
    "stateless",
    "toycar",
    "toytown",
]
