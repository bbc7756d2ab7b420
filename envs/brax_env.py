"""Brax environments on the MJX backend, with `full`, `pos` and `image` observations.

`pos` is the paper's partially observed "MuJoCo-State" setting: velocities and
forces are removed from Brax's observation. Which observation dimensions are
positional is *derived*, not tabulated: the environment's observation function
is evaluated at one configuration `q` with two different velocities `qd` and
actions; the dimensions that do not change are functions of the positions
alone. For Hopper, HalfCheetah and Walker2d this keeps Brax's `qpos[1:]` part
(5, 8 and 8 dims); for any other Brax model it keeps whatever that model's
observation derives from `q` alone (e.g. Humanoid's body inertias, Reacher's
target offset), so new environments need no table entry. (No Brax 0.14
environment puts external contact forces, `cfrc_ext`, in its observation; the
rule removes velocity- and action-dependent force terms such as Humanoid's
actuator forces.)
"""

from __future__ import annotations

import dataclasses
import functools
import inspect

import jax
import jax.numpy as jnp
import numpy as np

from envs import render as render_lib
from envs._quiet import brax_envs
from brax.envs.base import State as BraxState
from envs.base import OBS_MODES, Env, State

# Brax's `fast` is a test double without physics; it is not offered.
_EXCLUDED = {"fast"}


def brax_names() -> tuple[str, ...]:
    """Names of the Brax environments that `envs.make` accepts."""
    return tuple(sorted(n for n in brax_envs._envs if n not in _EXCLUDED))


@dataclasses.dataclass(frozen=True)
class BraxConfig:
    """Static settings of a Brax environment (hashable, never mutated).

    Attributes:
      backend: Brax physics pipeline; `mjx` unless the model supports only
        another (Brax's Swimmer runs on `generalized` only).
      episode_length: control steps per episode (the time limit; Brax uses 1000).
      image_size: (height, width) of `image` observations.
      camera: the `render.Camera`; `None` frames the model automatically.
      reward_scale: every reward is multiplied by this (e.g. 1/4 at a quarter of the
        frame skip, so returns stay on the scale of the standard control step).
      brax_kwargs: keyword arguments for the Brax environment's constructor,
        as a tuple of (name, value) pairs so the config stays hashable.
    """

    backend: str = "mjx"
    episode_length: int = 1000
    image_size: tuple[int, int] = (64, 64)
    camera: render_lib.Camera | None = None
    reward_scale: float = 1.0
    brax_kwargs: tuple[tuple[str, object], ...] = ()


# What Brax's own environments of the paper's tasks take by default (`n_frames`; all run on mjx), known without
# building them, so resolving a sweep's settings builds nothing (`tests/test_setup.py` checks them against Brax)
KNOWN_FRAME_SKIPS = {"hopper": 4, "walker2d": 4, "halfcheetah": 5}


@functools.cache
def _supports_mjx(name: str) -> bool:
    if name in KNOWN_FRAME_SKIPS:
        return True
    try:
        _build_brax(name, "mjx", ())
    except ValueError:  # e.g. Brax's Swimmer: "Unsupported backend: mjx."
        return False
    return True


@functools.cache
def default_frame_skip(name: str) -> int:
    """Simulator steps per control step that Brax's `name` takes by default (its `n_frames`: 4 for Hopper)."""
    if name in KNOWN_FRAME_SKIPS:
        return KNOWN_FRAME_SKIPS[name]
    return int(_build_brax(name, default_config(name).backend, ())._n_frames)


def default_config(name: str) -> BraxConfig:
    """A fresh default config for Brax environment `name` (mjx unless it is unsupported)."""
    if _supports_mjx(name):
        return BraxConfig(backend="mjx")
    backend = inspect.signature(brax_envs._envs[name].__init__).parameters["backend"].default
    return BraxConfig(backend=backend)


@functools.cache
def constructor_params(name: str) -> tuple[str, ...]:
    """Keyword arguments the Brax environment `name`'s constructor accepts."""
    cls = brax_envs._envs[name]
    params = []
    for klass in cls.__mro__:
        if "__init__" in vars(klass):
            for p in inspect.signature(klass.__init__).parameters.values():
                if p.name != "self" and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL):
                    params.append(p.name)
    return tuple(sorted(set(params) - {"sys", "backend"}))


def split_overrides(name: str, overrides: dict) -> BraxConfig:
    """Applies `overrides` to the default config: our fields, then Brax's keyword arguments.

    Raises:
      ValueError: an override that is neither a config field nor a keyword of
        the Brax environment's constructor (the message lists both).
    """
    config = default_config(name)
    ours = {f.name for f in dataclasses.fields(BraxConfig)} - {"brax_kwargs"}
    brax_params = list(constructor_params(name))
    mine, theirs = {}, {}
    for key, value in overrides.items():
        if key in ours:
            mine[key] = value
        elif key in brax_params:
            theirs[key] = value
        else:
            raise ValueError(
                f"unknown setting {key!r} for env {name!r}; valid: {sorted(ours)} "
                f"or the Brax constructor's {brax_params}"
            )
    if "image_size" in mine:
        mine["image_size"] = parse_image_size(mine["image_size"])
    return dataclasses.replace(config, **mine, brax_kwargs=tuple(sorted(theirs.items())))


def parse_image_size(value) -> tuple[int, int]:
    """`64` or `(64, 48)` -> `(height, width)`; `ValueError` for anything else."""
    size = (value, value) if isinstance(value, int) else tuple(value)
    if len(size) != 2 or not all(isinstance(s, (int, np.integer)) and s > 0 for s in size):
        raise ValueError(f"image_size must be a positive int or (height, width), got {value!r}")
    return int(size[0]), int(size[1])


@functools.cache
def _build_brax(name: str, backend: str, brax_kwargs: tuple):
    env = brax_envs.get_environment(name, backend=backend, **dict(brax_kwargs))
    if jax.process_count() > 1:
        env.sys = _on_this_process(env.sys)
    return env


def _on_this_process(sys):
    """`sys` with MJX's part of the model on this process's device.

    MJX places a model on `jax.devices()[0]`, the *global* first device: in every process
    but the first of a multi-process run (`jax.distributed`) another process's device, which
    this one can neither read nor close over in `jit`. Brax keeps the host model
    (`sys.mj_model`), so its MJX fields are put again, here.
    """
    from mujoco import mjx

    local = mjx.put_model(sys.mj_model, device=jax.local_devices()[0])
    return sys.replace(**{f.name: getattr(local, f.name) for f in dataclasses.fields(local)
                          if f.name in {g.name for g in dataclasses.fields(sys)}})


@functools.cache
def positional_dims(name: str, backend: str, brax_kwargs: tuple) -> tuple[int, ...]:
    """Indices of Brax's observation that depend on positions only.

    Evaluates the environment's observation at one random configuration with
    three random (velocity, action) pairs; a dimension that never changes is
    positional. Cached per environment configuration.
    """
    env = _build_brax(name, backend, brax_kwargs)
    takes_action = len(inspect.signature(env._get_obs).parameters) > 1
    nv, nu = env.sys.qd_size(), env.action_size

    def observe(q, qd, action):
        ps = env.pipeline_init(q, qd)
        return env._get_obs(ps, action) if takes_action else env._get_obs(ps)

    k_q, k_qd, k_a = jax.random.split(jax.random.PRNGKey(0), 3)
    q = env.sys.init_q + 0.1 * jax.random.uniform(k_q, (env.sys.q_size(),), minval=-1, maxval=1)
    qd = jax.random.uniform(k_qd, (3, nv), minval=-1, maxval=1)
    action = jax.random.uniform(k_a, (3, nu), minval=-1, maxval=1)
    obs = np.asarray(jax.jit(jax.vmap(observe, in_axes=(None, 0, 0)))(q, qd, action))
    static = np.all(np.isclose(obs, obs[0], rtol=0, atol=1e-7), axis=0)
    return tuple(int(i) for i in np.flatnonzero(static))


class BraxEnv(Env):
    """A Brax environment with the project's observation modes and safety checks.

    `Env.step` adds the shared guarantees (identical abstract types from reset
    and step, non-finite actions and states end the episode); this class maps
    Brax's state to the project's `State` and computes the observation mode.
    """

    def __init__(self, name: str, obs_mode: str, config: BraxConfig):
        if obs_mode not in OBS_MODES:
            raise ValueError(f"unknown obs mode {obs_mode!r} for env {name!r}; valid: {list(OBS_MODES)}")
        self.name, self.obs_mode, self.config = name, obs_mode, config
        self._env = _build_brax(name, config.backend, config.brax_kwargs)
        self._pos_idx = None
        if obs_mode == "pos":
            self._pos_idx = jnp.asarray(positional_dims(name, config.backend, config.brax_kwargs))
        self._renderer = self._segmenter = self.camera = None
        if config.backend == "mjx":
            h, w = config.image_size
            camera = config.camera or render_lib.camera_for_model(self._env.sys.mj_model, h, w)
            camera = dataclasses.replace(camera, height=h, width=w)
            self.camera = camera
            self._renderer = render_lib.make_renderer(self._env.sys, camera)
            self._segmenter = render_lib.make_segmenter(self._env.sys, camera)
        elif obs_mode == "image":
            raise ValueError(
                f"obs='image' needs the mjx backend; Brax's {name!r} runs on {config.backend!r} only"
            )

    # -- shapes -------------------------------------------------------------------------
    @property
    def brax_env(self):
        """The wrapped Brax environment."""
        return self._env

    @property
    def observation_shape(self) -> tuple[int, ...]:
        if self.obs_mode == "image":
            return (*self.config.image_size, 3)
        if self.obs_mode == "pos":
            return (int(self._pos_idx.shape[0]),)
        return (self._full_obs_size,)

    @functools.cached_property
    def _full_obs_size(self) -> int:
        # Brax's `observation_size` runs an un-jitted reset (~10 s for MJX) on every
        # access; tracing one abstractly costs ~1 s, once per environment object.
        return int(jax.eval_shape(self._env.reset, jax.random.PRNGKey(0)).obs.shape[-1])

    @property
    def action_size(self) -> int:
        return int(self._env.action_size)

    @property
    def action_bounds(self) -> tuple[jax.Array, jax.Array]:
        sys = self._env.sys
        limited = np.asarray(sys.actuator_ctrllimited, bool)
        rng = np.asarray(sys.actuator_ctrlrange, np.float32)
        low = np.where(limited, rng[:, 0], -np.inf).astype(np.float32)
        high = np.where(limited, rng[:, 1], np.inf).astype(np.float32)
        return jnp.asarray(low), jnp.asarray(high)

    @property
    def dt(self) -> float:
        return float(self._env.dt)

    @property
    def episode_length(self) -> int:
        return self.config.episode_length

    @property
    def frame_skip(self) -> int:
        """Simulator steps per control step (Brax's `n_frames`)."""
        return int(self._env._n_frames)

    # -- dynamics -----------------------------------------------------------------------
    def _observe(self, brax_state) -> jax.Array:
        if self.obs_mode == "full":
            return brax_state.obs
        if self.obs_mode == "pos":
            return brax_state.obs[self._pos_idx]
        return self._renderer(brax_state.pipeline_state)

    def _wrap(self, brax_state) -> State:
        return State(
            pipeline_state=brax_state.pipeline_state,
            obs=self._observe(brax_state),
            reward=brax_state.reward * self.config.reward_scale,
            done=brax_state.done,
            metrics=dict(brax_state.metrics),
            # Brax's own observation is kept: experts act on it, and health checks read it.
            info={"brax_obs": brax_state.obs, **brax_state.info},
        )

    def _reset(self, key: jax.Array) -> State:
        return self._wrap(self._env.reset(key))

    def _step(self, state: State, action: jax.Array) -> State:
        info = dict(state.info)
        brax_obs = info.pop("brax_obs")
        metrics = {k: v for k, v in state.metrics.items() if k not in ("invalid_action", "nonfinite_state")}
        brax_state = BraxState(state.pipeline_state, brax_obs, state.reward, state.done, metrics, info)
        return self._wrap(self._env.step(brax_state, action))

    def _is_finite(self, state: State) -> jax.Array:
        return jnp.all(jnp.isfinite(state.info["brax_obs"]))

    def sim_state(self, state: State) -> dict[str, jax.Array]:
        """`{"qpos": [nq], "qvel": [nv]}`: MuJoCo's physical state, all the rest is derived from it."""
        return {"qpos": state.pipeline_state.q, "qvel": state.pipeline_state.qd}

    def observe_sim(self, sim: dict[str, jax.Array]) -> jax.Array:
        """Observation of `{"qpos", "qvel"}`, recomputing body poses with `mj_forward`.

        Exact for observations built from `qpos`/`qvel` (HalfCheetah, Walker2d).
        Brax's stepped states carry body poses from before the last physics
        substep, so quantities read from them (Hopper's torso height, and the
        rendered frame) differ from the recorded ones by that substep's motion.
        """
        ps = self._env.pipeline_init(sim["qpos"], sim["qvel"])
        get_obs = self._env._get_obs
        if len(inspect.signature(get_obs).parameters) == 1:
            brax_obs = get_obs(ps)
        else:  # e.g. Humanoid's observation also reads the last action
            brax_obs = get_obs(ps, jnp.zeros(self.action_size))
        return self._observe(BraxState(ps, brax_obs, jnp.zeros(()), jnp.zeros(()), {}, {}))

    # -- views --------------------------------------------------------------------------
    def _require_mjx(self) -> None:
        if self._renderer is None:
            raise ValueError(f"rendering needs the mjx backend; {self.name!r} runs on {self.config.backend!r}")

    def render(self, state: State) -> jax.Array:
        self._require_mjx()
        return self._renderer(state.pipeline_state)

    def segmentation(self, state: State) -> jax.Array:
        """`[H, W] int32` geom id seen at each pixel of `render(state)` (-1: sky)."""
        self._require_mjx()
        return self._segmenter(state.pipeline_state)

    def expert_observation(self, state: State) -> jax.Array:
        """Brax's full observation (positions and velocities), what RL experts are trained on."""
        return state.info["brax_obs"]
