"""The task registry: a name -> (environment class, its default config), as MuJoCo Playground keeps them.

A task is one module. It defines its environment (an `envs.base.Env` subclass built as `Env(obs, config)`),
its settings as a frozen dataclass whose defaults are the task's defaults, and registers both:

    @dataclasses.dataclass(frozen=True)
    class MyTaskConfig:
        episode_length: int = 200
        ...

    class MyTask(envs.Env):
        def __init__(self, obs_mode: str, config: MyTaskConfig): ...

    registry.register("mytask", MyTask, MyTaskConfig, obs_modes=("full", "image"), default_obs="image")

From then on `envs.make("mytask", obs=..., **settings)`, `envs.names()`, `envs.obs_modes`,
`envs.default_obs` and `envs.default_episode_length` know it; nothing else is edited. The suite's own
task modules (`envs.toycar`, `envs.toytown`) are imported by `envs/__init__.py`; a task of your own
registers when its module is imported (`registered(...)` does it for a `with` block, as the tests do).
Brax's environments are not registered: `envs.make` falls back to them for names the registry lacks.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator
from typing import Any

from envs.base import Env


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """One registered task.

    Attributes:
      name: the name `envs.make` takes.
      env_class: `env_class(obs_mode, config) -> Env`.
      config_class: a frozen dataclass; `config_class()` is the default config, and its `__post_init__`
        refuses out-of-range values with `ValueError`.
      obs_modes: the observation modes the task supports.
      default_obs: the mode `envs.make` uses when none is given.
    """

    name: str
    env_class: Callable[[str, Any], Env]
    config_class: type
    obs_modes: tuple[str, ...]
    default_obs: str

    def default_config(self) -> Any:
        """A fresh config holding the task's defaults."""
        return self.config_class()

    def settings(self) -> tuple[str, ...]:
        """The names of the config's fields (the settings `envs.make` takes), sorted."""
        return tuple(sorted(f.name for f in dataclasses.fields(self.config_class)))

    def make(self, obs: str | None = None, **overrides) -> Env:
        """The environment in mode `obs` (None: `default_obs`) with `overrides` replacing the defaults.

        Raises:
          ValueError: an unknown observation mode or setting (listing the valid ones), or a value the config
            refuses.
        """
        obs = self.default_obs if obs is None else obs
        if obs not in self.obs_modes:
            raise ValueError(f"unknown obs mode {obs!r} for env {self.name!r}; valid: {list(self.obs_modes)}")
        unknown = sorted(set(overrides) - set(self.settings()))
        if unknown:
            raise ValueError(f"unknown setting(s) {unknown} for env {self.name!r}; valid: {list(self.settings())}")
        return self.env_class(obs, self.config_class(**_coerced(overrides)))


def _coerced(overrides: dict) -> dict:
    """Settings as the configs hold them: `image_size` as (height, width) from an int or a pair, and lists (a
    data key's JSON) as tuples, so a config stays hashable."""
    from envs.brax_env import parse_image_size  # here: envs.brax_env imports Brax, the registry need not

    out = {k: (tuple(v) if isinstance(v, list) else v) for k, v in overrides.items()}
    if "image_size" in out:
        out["image_size"] = parse_image_size(out["image_size"])
    return out


_TASKS: dict[str, TaskSpec] = {}


def register(name: str, env_class: Callable[[str, Any], Env], config_class: type, obs_modes: tuple[str, ...],
             default_obs: str) -> TaskSpec:
    """Registers a task under `name` and returns its record.

    Raises:
      ValueError: `name` is taken (by a registered task or a Brax environment), the config is not a frozen
        dataclass whose defaults build, it has no `episode_length`, or `default_obs` is not one of `obs_modes`.
    """
    from envs import brax_env

    if name in _TASKS or name in brax_env.brax_names():
        raise ValueError(f"env {name!r} is registered already; registered: {sorted(_TASKS)}")
    if not dataclasses.is_dataclass(config_class) or not config_class.__dataclass_params__.frozen:
        raise ValueError(f"env {name!r}: the config must be a frozen dataclass, got {config_class!r}")
    if "episode_length" not in {f.name for f in dataclasses.fields(config_class)}:
        raise ValueError(f"env {name!r}: the config needs an episode_length field (the time limit)")
    if default_obs not in obs_modes:
        raise ValueError(f"env {name!r}: default_obs {default_obs!r} is not one of {list(obs_modes)}")
    config_class()  # the defaults must build: a bad default fails here, at import, not at the first make
    spec = TaskSpec(name, env_class, config_class, tuple(obs_modes), default_obs)
    _TASKS[name] = spec
    return spec


def unregister(name: str) -> None:
    """Removes task `name`; `KeyError` if it is not registered."""
    del _TASKS[name]


@contextlib.contextmanager
def registered(name: str, env_class: Callable[[str, Any], Env], config_class: type, obs_modes: tuple[str, ...],
               default_obs: str) -> Iterator[TaskSpec]:
    """Registers a task for the duration of a `with` block and removes it afterwards, even on an error."""
    spec = register(name, env_class, config_class, obs_modes, default_obs)
    try:
        yield spec
    finally:
        unregister(name)


def get(name: str) -> TaskSpec | None:
    """The record of registered task `name`, or None (a Brax environment, or no environment at all)."""
    return _TASKS.get(name)


def names() -> tuple[str, ...]:
    """The registered tasks' names, sorted."""
    return tuple(sorted(_TASKS))


def same_task(env: Env, obs: str) -> Env:
    """`env`'s task with the same settings, observing in mode `obs` (e.g. the full state for `bc-full`).

    Raises:
      ValueError: `env` is not a registered task's, or the task has no mode `obs`.
    """
    spec = get(env.name)
    if spec is None or not isinstance(env, spec.env_class):
        raise ValueError(f"{env.name!r} is not a registered task; registered: {list(names())}")
    if obs not in spec.obs_modes:
        raise ValueError(f"unknown obs mode {obs!r} for env {env.name!r}; valid: {list(spec.obs_modes)}")
    return spec.env_class(obs, env.config)
