"""The environment interface shared by every environment of the project.

Environments are Brax-style: pure `reset(key) -> State` and
`step(state, action) -> State`, both traceable, so they run inside `jit`,
`vmap` and `lax.scan`. One `State` class serves every environment, so the
rollout helper, the demonstration collector and the evaluation loops treat
MJX locomotion and ToyCar alike.
"""

from __future__ import annotations

import abc
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

OBS_MODES = ("full", "pos", "image")


@struct.dataclass
class State:
    """Environment state, a pytree.

    Attributes:
      pipeline_state: the simulator state (`mjx.Data` for MJX environments, a
        `ToyCarSim` for ToyCar). Holds everything needed to re-observe or
        re-render the step later.
      obs: observation in the environment's mode: `[obs_dim] float32` for
        `full`/`pos`, `[H, W, 3] uint8` for `image`.
      reward: `[] float32` reward of the transition that produced this state.
      done: `[] float32`, 1.0 when this state is terminal.
      metrics: `dict[str, [] float32]` per-step diagnostics.
      info: `dict[str, Any]` environment bookkeeping (e.g. a PRNG key).
    """

    pipeline_state: Any
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    metrics: dict[str, jax.Array] = struct.field(default_factory=dict)
    info: dict[str, Any] = struct.field(default_factory=dict)


class Env(abc.ABC):
    """Abstract environment: a name, an observation mode and pure reset/step.

    Subclasses are plain Python objects holding static configuration; all
    traced state lives in `State`. Properties describe shapes so callers can
    allocate buffers without running the environment.
    """

    name: str
    obs_mode: str

    def reset(self, key: jax.Array) -> State:
        """Samples an initial state.

        Args:
          key: a PRNG key; the whole initial state (and, for ToyCar, the light
            schedule) is a function of it.

        Returns:
          The initial `State`, with `metrics["invalid_action"]` and
          `metrics["nonfinite_state"]` set to 0.
        """
        state = self._reset(key)
        zero = jnp.zeros((), jnp.float32)
        return strong_types(state.replace(metrics={**state.metrics, **_flags(zero, zero)}))

    def step(self, state: State, action: jax.Array) -> State:
        """Advances one control step.

        A non-finite action is the caller's error, not physics: the step is not
        simulated, the previous state is kept, `done` becomes 1 and
        `metrics["invalid_action"]` is 1. If the simulation itself produces a
        non-finite state, the same happens with `metrics["nonfinite_state"]`.

        Args:
          state: the current `State` of one environment (vmap for batches).
          action: `[action_size] float32`.

        Returns:
          The next `State`, with the same abstract type as `reset`'s.

        Raises:
          ValueError: at trace time, if `action` is not of shape `[action_size]`.
        """
        self.check_action(action)
        action = jnp.asarray(action, jnp.float32)
        valid = jnp.all(jnp.isfinite(action))
        nxt = self._step(state, jnp.where(valid, action, 0.0))
        healthy = self._is_finite(nxt)
        flags = _flags(1.0 - valid.astype(jnp.float32), 1.0 - healthy.astype(jnp.float32))
        nxt = nxt.replace(metrics={**nxt.metrics, **flags})
        # the step's own metrics may be NaN when physics failed: keep the previous ones
        frozen = state.replace(
            reward=jnp.zeros_like(state.reward), done=jnp.ones_like(state.done), metrics={**state.metrics, **flags}
        )
        ok = valid & healthy
        return strong_types(jax.tree.map(lambda a, b: jnp.where(ok, a, b), nxt, frozen))

    @abc.abstractmethod
    def _reset(self, key: jax.Array) -> State:
        """Environment-specific reset."""

    @abc.abstractmethod
    def _step(self, state: State, action: jax.Array) -> State:
        """Environment-specific step; `action` is finite and of the right shape."""

    def _is_finite(self, state: State) -> jax.Array:
        """Whether the simulated state is usable: `[] bool`."""
        return jnp.all(jnp.isfinite(state.obs)) if state.obs.dtype != jnp.uint8 else jnp.array(True)

    @property
    @abc.abstractmethod
    def observation_shape(self) -> tuple[int, ...]:
        """Shape of `State.obs` for one environment."""

    @property
    def observation_dtype(self) -> jnp.dtype:
        """Dtype of `State.obs`: uint8 for images, float32 otherwise."""
        return jnp.dtype(jnp.uint8) if self.obs_mode == "image" else jnp.dtype(jnp.float32)

    @property
    @abc.abstractmethod
    def action_size(self) -> int:
        """Number of action dimensions."""

    @property
    @abc.abstractmethod
    def action_bounds(self) -> tuple[jax.Array, jax.Array]:
        """(low, high), each `[action_size] float32`: the valid action range."""

    @property
    @abc.abstractmethod
    def dt(self) -> float:
        """Seconds of simulated time per control step."""

    @property
    @abc.abstractmethod
    def episode_length(self) -> int:
        """Default number of control steps in an episode (the time limit)."""

    @abc.abstractmethod
    def render(self, state: State) -> jax.Array:
        """Renders `state` as `[H, W, 3] uint8` inside jit (for images and videos)."""

    @abc.abstractmethod
    def expert_observation(self, state: State) -> jax.Array:
        """The fully observed `[d] float32` vector an expert acts on."""

    def sim_state(self, state: State) -> Any:
        """The simulator's own state inside `state`: a small pytree of arrays.

        Stored per step in demonstrations; `observe_sim` turns it back into an
        observation in any mode, so a dataset can be re-observed or re-rendered.
        """
        raise NotImplementedError(f"{self.name}: sim_state is not available")

    def observe_sim(self, sim: Any) -> jax.Array:
        """The observation (in this env's mode) of simulator state `sim` from `sim_state`."""
        raise NotImplementedError(f"{self.name}: observe_sim is not available")

    # Names of the action dimensions where the environment defines them (else None: MuJoCo's actuators).
    action_names: tuple[str, ...] | None = None
    # Per-episode metrics beside the return (e.g. a driving task's success); none by default.
    episode_metric_names: tuple[str, ...] = ()

    def episode_metrics(self, sims: Any, final: State, valid: jax.Array) -> dict[str, jax.Array]:
        """This environment's own metrics of one episode (`episode_metric_names`), inside jit.

        Args:
          sims: `sim_state` before each step, stacked (fields `[T, ...]`).
          final: the state after the last step.
          valid: `[T] float32`, 1 for the steps inside the episode.

        Returns:
          `{name: [] float32}` for every name of `episode_metric_names` (none by default).
        """
        return {}

    def caption(self, sim: Any, metrics: dict[str, float] | None = None) -> dict[str, str]:
        """What a video's caption says of one step, in words (host side, not traced): `{label: text}`.

        Args:
          sim: one step's simulator state (`sim_state`, unbatched host arrays), e.g. a driving task's speed and
            the light ahead.
          metrics: the episode's own metrics (`episode_metrics`, as floats), given for its last frame: then the
            words include its outcome (e.g. `"outcome": "collision (vehicle)"`).

        Returns:
          The task's words, in the order shown; none by default (the caption then shows the method, the step and
          the return only).
        """
        return {}

    def check_action(self, action: jax.Array) -> None:
        """Raises `ValueError` at trace time when `action` has the wrong shape."""
        shape = tuple(jnp.shape(action))
        if shape != (self.action_size,):
            raise ValueError(
                f"{self.name}: step() takes one action of shape ({self.action_size},), got "
                f"shape {shape}; to step a batch of environments, vmap reset and step."
            )

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r} obs={self.obs_mode!r}>"


class ConfiguredEnv(Env):
    """A pure-JAX task whose settings are one frozen config dataclass: the observation mode is checked against
    `obs_modes`, and the control step and episode length are the config's `dt` and `episode_length` fields.

    A subclass sets `name`, `config_class` (and `obs_modes` if not full and image) and implements the rest of
    `Env`; `cls(obs_mode, config)` is how the task registry builds it in another mode with the same settings.
    """

    obs_modes: tuple[str, ...] = ("full", "image")
    config_class: type

    def __init__(self, obs_mode: str = "image", config: Any = None):
        if obs_mode not in self.obs_modes:
            raise ValueError(f"unknown obs mode {obs_mode!r} for env {self.name!r}; valid: {list(self.obs_modes)}")
        self.obs_mode = obs_mode
        self.config = self.config_class() if config is None else config

    @property
    def dt(self) -> float:
        return self.config.dt

    @property
    def episode_length(self) -> int:
        return self.config.episode_length


class Wrapper(Env):
    """An environment that changes what `inner` observes and nothing else: the simulator, actions, rewards, `done`,
    metrics, the expert's observation and rendering are `inner`'s. A subclass defines `reset`, `step` (which call
    `inner`'s) and `observation_shape`; whatever else it does not define is read from `inner`."""

    def __init__(self, inner: Env):
        self.inner = inner
        self.name, self.obs_mode = inner.name, inner.obs_mode

    def __getattr__(self, name: str):  # what the wrapper does not define is the environment's
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    def _reset(self, key: jax.Array) -> State:  # a subclass's `reset` and `step` are its whole dynamics
        return self.reset(key)

    def _step(self, state: State, action: jax.Array) -> State:
        return self.step(state, action)

    @property
    def action_size(self) -> int:
        return self.inner.action_size

    @property
    def action_bounds(self) -> tuple[jax.Array, jax.Array]:
        return self.inner.action_bounds

    @property
    def dt(self) -> float:
        return self.inner.dt

    @property
    def episode_length(self) -> int:
        return self.inner.episode_length

    @property
    def episode_metric_names(self) -> tuple[str, ...]:
        return self.inner.episode_metric_names

    @property
    def action_names(self) -> tuple[str, ...] | None:
        return self.inner.action_names

    def episode_metrics(self, sims: Any, final: State, valid: jax.Array) -> dict[str, jax.Array]:
        return self.inner.episode_metrics(sims, final, valid)

    def render(self, state: State) -> jax.Array:
        return self.inner.render(state)

    def caption(self, sim: Any, metrics: dict[str, float] | None = None) -> dict[str, str]:
        return self.inner.caption(sim, metrics)

    def expert_observation(self, state: State) -> jax.Array:
        return self.inner.expert_observation(state)

    def sim_state(self, state: State) -> Any:
        return self.inner.sim_state(state)


def _flags(invalid_action: jax.Array, nonfinite_state: jax.Array) -> dict[str, jax.Array]:
    return {"invalid_action": jnp.asarray(invalid_action, jnp.float32),
            "nonfinite_state": jnp.asarray(nonfinite_state, jnp.float32)}


def strong_types(tree: Any) -> Any:
    """Returns `tree` with every weakly-typed array made strongly typed.

    Brax's Hopper and Walker2d return weak-typed `done` and metrics from `step`
    but not from `reset`; a state passed between separately jitted calls then
    changes its abstract type and forces a recompile. Canonicalising both
    outputs keeps `reset` and `step` type-identical.
    """
    return jax.tree.map(lambda x: jnp.asarray(x, dtype=x.dtype) if isinstance(x, jax.Array) else x, tree)
