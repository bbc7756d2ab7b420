"""What a policy observes besides the sweep's own observation: the full state, and the previous action.

    env_full, demos_full = observations.full_state(env, demos)   # the same task and rows, `obs="full"`
    env, demos = observations.with_previous_action(env, demos)   # the observation carries a_{t-1}

**The full state** (the `bc-full` method: BC on the full state, the ceiling every state table
shows). A sweep's demonstrations hold its own observation (`pos`: positions only, or frames) and,
for every shipped task, the simulator state before each step (`Demonstrations.sim`, the
environment's `sim_state`: MuJoCo's `qpos`/`qvel`, ToyCar's car and light). The full observation
is the environment's own, `envs.make(env, obs="full")`'s: its `observe_sim` applied to each row's
simulator state. One correction keeps it exact: Brax's Hopper and Walker2d read the torso height
from body poses computed before the last physics substep, which `observe_sim` recomputes (a
difference of up to ~0.003 m on Hopper); the `pos` observation holds those dimensions as the
environment gave them, so for a `pos` sweep they are taken from it and the full observation is
bit-identical to the one a rollout in `obs="full"` sees. (For frames, the recomputed height
stands: the substep's difference is all that remains.) Demonstrations without the simulator
state (a `--dataset` that stores none) cannot give it: `FullStateError`, one line.

**The previous action** (`protocol.prev_action`; the copycat trap of de Haan et al. 2019, PALR's
"POA"): each observation is followed by the action executed one step before it, zeros at an
episode's start, so a history of `H` frames carries the `H` previous actions. In training that is
the demonstration's *executed* action (`Demonstrations.executed`): what the expert did, which is
what a policy can observe of its own past in a rollout; it equals the label under clipped labels
and noise-free collection, and differs where labels are raw (unbounded; the environment executes
them clipped) or where DART noise was injected. In rollouts `PreviousAction` wraps the environment
so its observation carries the policy's own previous action as the environment executed it (the
policy's clipped output). Standardisation treats the carried action as more dimensions of the
observation (training statistics). Vector observations only: a frame has no place for it.
"""

from __future__ import annotations

import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import envs
from envs.base import Env, State, Wrapper

FULL = "full"      # `Method.observation` of a method that reads the full state
CHUNK = 8192       # rows per call when observing the simulator states (one compile, bounded memory)


class FullStateError(ValueError):
    """The full observation cannot be built here (one line): no simulator state, or an environment without one."""


def full_env(env: Env) -> Env:
    """The same environment and settings observing the full state (`obs="full"`); `env` itself if it does.

    A `PreviousAction` wrapper stays around the full environment. Raises `FullStateError` for an environment
    with no full observation mode."""
    if isinstance(env, PreviousAction):
        return PreviousAction(full_env(env.inner))
    from ape_jax.perception.perceived import Perceived

    if isinstance(env, Perceived):  # frames through an encoder (`ape_jax.perception`): the camera's task observes it
        return full_env(env.inner)
    if env.obs_mode == FULL:
        return env
    if isinstance(env, envs.brax_env.BraxEnv):
        return envs.brax_env.BraxEnv(env.name, FULL, env.config)
    try:   # a registered task (ToyCar, ToyTown, ...) rebuilds itself in another mode
        return envs.registry.same_task(env, FULL)
    except ValueError:
        raise FullStateError(f"{env.name!r} has no full observation to build (bc-full reads the full state)") from None


def _sim_layout(env: Env) -> dict[str, tuple[int, ...]]:
    """`{field: per-step shape}` of `env.sim_state`, abstractly (nothing runs)."""
    sim = jax.eval_shape(lambda k: env.sim_state(env.reset(k)), jax.random.PRNGKey(0))
    fields = sim if isinstance(sim, dict) else vars(sim)
    return {k: tuple(v.shape) for k, v in fields.items()}


def full_observations(env: Env, demos: Any, where: str = "the demonstrations") -> np.ndarray:
    """`[N, D_full] float32`: each row's full observation, as `full_env(env)` observes it (module docstring).

    Args:
      env: the environment the demonstrations were observed in (any observation mode; not a `PreviousAction`).
      demos: `Demonstrations` whose `obs` are `env`'s and whose `sim` holds `env.sim_state` per row.
      where: how a refusal names the demonstrations (e.g. the dataset's path).

    Raises:
      FullStateError: the demonstrations hold no simulator state of `env`'s layout.
    """
    if env.obs_mode == FULL:
        return np.asarray(demos.obs, np.float32)
    full = full_env(env)
    layout, sim = _sim_layout(env), dict(demos.sim or {})
    have = {k: tuple(np.shape(v)[1:]) for k, v in sim.items()}
    if any(have.get(k) != shape for k, shape in layout.items()):
        missing = ", ".join(f"sim/{k}" for k in layout if have.get(k) != layout[k])
        raise FullStateError(f"{where} hold no simulator state of {env.name!r} ({missing} missing or of another "
                             "shape): bc-full builds the full observation from it; collect the demonstrations "
                             "with this suite, or leave bc-full out")
    obs = observe_rows(full, {k: sim[k] for k in layout})[0].astype(np.float32)
    if isinstance(env, envs.brax_env.BraxEnv) and env.obs_mode == "pos":
        # the positional dimensions exactly as the environment gave them (the torso height's substep, above)
        dims = envs.brax_env.positional_dims(env.name, env.config.backend, env.config.brax_kwargs)
        obs[:, list(dims)] = np.asarray(demos.obs, np.float32)
    return obs


def observe_rows(env: Env, sim: dict, chunk: int = CHUNK) -> tuple[np.ndarray, float, float]:
    """`(observations [N, ...], compile_s, run_s)`: `env.observe_sim` of each row of `sim` (`{field: [N, ...]}`,
    `Demonstrations.sim`), `chunk` rows per jitted, vmapped call (the last chunk padded to the same size: one
    compiled program, bounded memory), and the seconds its compilation and the calls took."""
    n = len(next(iter(sim.values())))
    rows = lambda idx: {k: np.asarray(v)[idx] for k, v in sim.items()}  # noqa: E731
    t0 = time.perf_counter()
    observe = jax.jit(jax.vmap(env.observe_sim)).lower(rows(np.arange(chunk) % n)).compile()
    t1 = time.perf_counter()
    out = None
    for start in range(0, n, chunk):
        part = np.asarray(observe(rows(np.minimum(np.arange(start, start + chunk), n - 1))))[: n - start]
        if out is None:
            out = np.empty((n, *part.shape[1:]), part.dtype)
        out[start:start + len(part)] = part
    return out, t1 - t0, time.perf_counter() - t1


def full_state(env: Env, demos: Any, where: str = "the demonstrations") -> tuple[Env, Any]:
    """`(full_env(env), demos observed in it)`: the environment and demonstrations a policy reading the full state
    sees (`full_observations`); with the previous action in view (`PreviousAction`), it stays in view."""
    if isinstance(env, PreviousAction):
        own = demos.replace(obs=np.asarray(demos.obs)[:, : env.inner.observation_shape[0]])
        return with_previous_action(*full_state(env.inner, own, where))
    return full_env(env), demos.replace(obs=full_observations(env, demos, where))


# -- the previous action in view ------------------------------------------------------------------------------------

def previous_actions(demos: Any) -> np.ndarray:
    """`[N, A] float32`: each row's previous executed action in its episode (`executed[i − 1]`), zeros where
    `t = 0`. Rows are episodes concatenated in order (`Demonstrations`)."""
    executed = np.asarray(demos.executed, np.float32)
    prev = np.zeros_like(executed)
    prev[1:] = executed[:-1]
    prev[np.asarray(demos.t) == 0] = 0.0
    return prev


def carrying_previous_action(demos: Any) -> Any:
    """`demos` with each observation followed by its previous executed action (`previous_actions`):
    `obs [N, D + A]`."""
    obs = np.asarray(demos.obs)
    if obs.ndim != 2:
        raise ValueError(f"protocol.prev_action needs vector observations, got observations of shape "
                         f"{list(obs.shape[1:])}: a frame has no place for the previous action")
    return demos.replace(obs=np.concatenate([obs.astype(np.float32), previous_actions(demos)], axis=-1))


def with_previous_action(env: Env, demos: Any) -> tuple[Env, Any]:
    """`(PreviousAction(env), carrying_previous_action(demos))`: the environment and its demonstrations with the
    previous action in view (`protocol.prev_action`). `ValueError` (one line) for image observations."""
    return PreviousAction(env), carrying_previous_action(demos)


class PreviousAction(Wrapper):
    """`env` whose observation is followed by the action it executed one step before (zeros after a reset).

    `obs` is `[D + A] float32`: `env`'s observation, then the previous action as `env.step` executed it (the
    policy's action; zeros where it was not finite and the step was refused). Everything else (the simulator,
    rewards, `done`, metrics, the expert's observation, rendering) is `env`'s (`envs.base.Wrapper`).
    """

    def __init__(self, env: Env):
        if isinstance(env, PreviousAction):
            raise ValueError("the previous action is in view already")
        if len(env.observation_shape) != 1:
            raise ValueError(f"protocol.prev_action needs vector observations; {env.name!r} with obs="
                             f"{env.obs_mode!r} gives {list(env.observation_shape)}: a frame has no place for "
                             "the previous action")
        super().__init__(env)
        self._dim = int(env.observation_shape[0])

    def reset(self, key: jax.Array) -> State:
        state = self.inner.reset(key)
        return state.replace(obs=jnp.concatenate([state.obs, jnp.zeros(self.inner.action_size, state.obs.dtype)]))

    def step(self, state: State, action: jax.Array) -> State:
        self.check_action(action)
        action = jnp.asarray(action, jnp.float32)
        nxt = self.inner.step(state.replace(obs=state.obs[: self._dim]), action)
        executed = jnp.where(jnp.all(jnp.isfinite(action)), action, 0.0)  # as `Env.step` executes it
        return nxt.replace(obs=jnp.concatenate([nxt.obs, executed.astype(nxt.obs.dtype)]))

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (self._dim + self.inner.action_size,)

    @property
    def observation_dtype(self):
        return self.inner.observation_dtype

    def __repr__(self) -> str:
        return f"<PreviousAction {self.inner!r}>"
