"""Environments of ape_jax: Brax/MJX locomotion and ToyCar, behind one `make`.

    env = envs.make("hopper", obs="pos")          # velocities removed: 5 dims
    env = envs.make("walker2d", obs="image", image_size=32)
    env = envs.make("toycar")                      # images by default
    traj = jax.jit(lambda k: envs.rollout(env, policy, params, k, num_episodes=8))(key)

Every environment has pure `reset(key) -> State` and `step(state, action) ->
State` (see `envs.base`); step them with `envs.rollout`.
"""

from __future__ import annotations

import dataclasses

from envs import _quiet  # noqa: F401  (silences MJX/Brax import noise first)
from envs import brax_env, toycar
from envs.base import OBS_MODES, Env, State
from envs.render import Camera
from envs.rollout import Policy, Trajectory, from_observation, rollout, stateless
from envs.toycar import ToyCar, ToyCarConfig

MUJOCO_TASKS = ("hopper", "halfcheetah", "walker2d")  # the paper's three tasks


def names() -> tuple[str, ...]:
    """Every name `make` accepts: Brax's environments and `toycar`."""
    return tuple(sorted((*brax_env.brax_names(), "toycar")))


def obs_modes(name: str) -> tuple[str, ...]:
    """Observation modes environment `name` supports."""
    _check_name(name)
    if name == "toycar":
        return ("full", "image")
    if brax_env.default_config(name).backend != "mjx":
        return ("full", "pos")  # rendering needs MJX
    return OBS_MODES


def default_obs(name: str) -> str:
    """The observation mode `make` uses when `obs` is not given."""
    return "image" if name == "toycar" else "full"


def _check_name(name: str) -> None:
    if name not in names():
        raise ValueError(f"unknown env {name!r}; valid: {list(names())}")


def default_episode_length(name: str) -> int:
    """Control steps per episode of environment `name` at its defaults (Brax's 1000, ToyCar's own), read from its
    config without building it."""
    _check_name(name)
    return ToyCarConfig().episode_length if name == "toycar" else brax_env.default_config(name).episode_length


def make(name: str, obs: str | None = None, **overrides) -> Env:
    """Builds environment `name` with observation mode `obs`.

    Args:
      name: one of `names()`: `hopper`, `halfcheetah`, `walker2d`, any other
        Brax environment, or `toycar`.
      obs: `full`, `pos` or `image` (see `obs_modes(name)`); default `full`
        for Brax environments and `image` for ToyCar.
      **overrides: settings replacing the environment's defaults. Brax
        environments take the fields of `brax_env.BraxConfig` (e.g.
        `image_size=32`, `episode_length=500`, `camera=Camera(...)`) and any
        keyword of the Brax environment's constructor (e.g.
        `terminate_when_unhealthy=False`); ToyCar takes the fields of
        `ToyCarConfig`.

    Returns:
      A fresh `Env`; each call builds its own config.

    Raises:
      ValueError: unknown name, observation mode or setting, or an invalid
        value (the message lists the valid choices).
    """
    _check_name(name)
    obs = default_obs(name) if obs is None else obs
    if obs not in obs_modes(name):
        why = " (obs='image' needs the mjx backend)" if obs == "image" and name != "toycar" else ""
        raise ValueError(f"unknown obs mode {obs!r} for env {name!r}; valid: {list(obs_modes(name))}{why}")
    if name == "toycar":
        valid = {f.name for f in dataclasses.fields(ToyCarConfig)}
        unknown = sorted(set(overrides) - valid)
        if unknown:
            raise ValueError(f"unknown setting(s) {unknown} for env 'toycar'; valid: {sorted(valid)}")
        if "image_size" in overrides:
            overrides["image_size"] = brax_env.parse_image_size(overrides["image_size"])
        return ToyCar(obs, ToyCarConfig(**overrides))
    return brax_env.BraxEnv(name, obs, brax_env.split_overrides(name, overrides))


__all__ = [
    "MUJOCO_TASKS",
    "OBS_MODES",
    "Camera",
    "Env",
    "Policy",
    "State",
    "ToyCar",
    "ToyCarConfig",
    "Trajectory",
    "default_episode_length",
    "default_obs",
    "from_observation",
    "make",
    "names",
    "obs_modes",
    "rollout",
    "stateless",
    "toycar",
]
