"""ToyCar: the supplement's sandbox (§5), in pure JAX.

A car drives along a straight road with one traffic light that stays red or
green for random lengths of time. The car is a point-mass double integrator
with two actions, throttle and brake, each in [0, 1], applying fixed positive
and negative accelerations against a constant rolling resistance (a car off
the pedals slows down); speed is clipped to [0, max_speed]. The episode
ends when the car reaches the end of the road (or at the time limit, applied
by the rollout). Success = reaching the end without crossing the light's stop
line while it is red.

Observations:
  * `full`: `[5] float32` = (car position m, speed m/s, light position m,
    light is green {0, 1}, seconds left in the light's current status): the
    fully observed state the rule-based expert acts on.
  * `image` (default): a top-down view that follows the car, `[H, W, 3] uint8`,
    default 128×128. The supplement's imitators see 3×128×128 (channels-first,
    PyTorch); we keep JAX's channels-last layout for every image in the
    project. A dashed centre line scrolls past, so speed is visible in a stack
    of frames but not in one frame; the light's colour is visible (green,
    amber in the last `amber_seconds` of green, red), the time left in its
    status is not.

Per-episode metrics (`episode_metrics`) follow the driving protocol:
`success`, `red_light_violations`, `progress`, `avg_speed` and `stuck` (the car
stood still for `stuck_seconds` while nothing stopped it: the light was green
or already behind it), BC-OH's "inertia" failure.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from envs import registry
from envs.base import ConfiguredEnv, State

METRICS = ("success", "red_light_violations", "progress", "avg_speed", "stuck")  # `episode_metrics`, in order


@dataclasses.dataclass(frozen=True)
class ToyCarConfig:
    """ToyCar's static settings (hashable; override with `envs.make("toycar", key=value)`).

    Attributes:
      dt: seconds per control step.
      road_length: metres from the road's start to the goal line.
      start_range: the car starts uniformly in this range of positions, metres.
      start_speed_max: initial speed is uniform in [0, this], m/s.
      light_range: the light's position is uniform in this range, metres.
      max_speed: speed limit, m/s.
      throttle_accel: acceleration at full throttle, m/s².
      brake_accel: deceleration at full brake, m/s².
      rolling_resistance: deceleration of a moving car with no throttle, m/s² (rolling resistance and
        engine braking, always on): a car that lets go of the pedals slows down, so a policy that
        releases the brake a little early near the stop line does not creep over it.
      red_range, green_range: a status lasts uniformly this many seconds.
      amber_seconds: the last this-many seconds of a green status show amber (yellow), as real
        lights do: the light's colour then tells whether it is about to turn red, which the time
        left (not in the image) otherwise decides alone. A car that can no longer stop goes on
        amber, so this must exceed the time such a car needs to reach the line (at most ~1.1 s
        with the other defaults; the expert's test checks the defaults run no red light).
      stop_margin: the expert stops this many metres before the stop line.
      stuck_seconds: standing still this long while free to go counts as stuck.
      episode_length: control steps per episode (the time limit).
      image_size: (height, width) of `image` observations.
      view_behind, view_ahead: metres of road shown behind and ahead of the car.
    """

    dt: float = 0.1
    road_length: float = 100.0
    start_range: tuple[float, float] = (0.0, 5.0)
    start_speed_max: float = 4.0
    light_range: tuple[float, float] = (40.0, 70.0)
    max_speed: float = 10.0
    throttle_accel: float = 3.0
    brake_accel: float = 6.0
    rolling_resistance: float = 1.0
    red_range: tuple[float, float] = (2.0, 8.0)
    green_range: tuple[float, float] = (2.0, 8.0)
    amber_seconds: float = 2.0
    stop_margin: float = 1.0
    stuck_seconds: float = 3.0
    episode_length: int = 300
    image_size: tuple[int, int] = (128, 128)
    view_behind: float = 6.0
    view_ahead: float = 26.0

    def __post_init__(self):
        checks = {
            "dt": self.dt > 0,
            "road_length": self.road_length > 0,
            "max_speed": self.max_speed > 0,
            "throttle_accel": self.throttle_accel > 0,
            "brake_accel": self.brake_accel > 0,
            "rolling_resistance": 0 <= self.rolling_resistance < self.throttle_accel,
            "light_range": 0 < self.light_range[0] <= self.light_range[1] < self.road_length,
            "start_range": 0 <= self.start_range[0] <= self.start_range[1] < self.light_range[0],
            "red_range": 0 < self.red_range[0] <= self.red_range[1],
            "green_range": 0 < self.green_range[0] <= self.green_range[1],
            "amber_seconds": self.amber_seconds >= 0,
            "episode_length": self.episode_length > 0,
            "image_size": len(self.image_size) == 2 and min(self.image_size) > 0,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"invalid ToyCar settings: {bad} (see ToyCarConfig's docstring for the valid ranges)")

    @property
    def stuck_steps(self) -> int:
        return max(1, round(self.stuck_seconds / self.dt))


@struct.dataclass
class ToyCarSim:
    """ToyCar's simulator state (all `[] float32` except `key` and `t`)."""

    x: jax.Array  # car position, m
    v: jax.Array  # speed, m/s
    light_x: jax.Array  # stop line position, m
    green: jax.Array  # 1.0 if the light is green
    remaining: jax.Array  # seconds left in the light's current status
    t: jax.Array  # [] int32 control steps since reset
    key: jax.Array  # PRNG key for the light's future durations


def _duration(key: jax.Array, green: jax.Array, cfg: ToyCarConfig) -> jax.Array:
    lo = jnp.where(green > 0, cfg.green_range[0], cfg.red_range[0])
    hi = jnp.where(green > 0, cfg.green_range[1], cfg.red_range[1])
    return jax.random.uniform(key, (), minval=lo, maxval=hi)


def crossed_on_red(x_prev: jax.Array, x_next: jax.Array, light_x: jax.Array, green_prev: jax.Array) -> jax.Array:
    """1.0 where a car moving from `x_prev` to `x_next` crossed the stop line on red."""
    return ((x_prev < light_x) & (x_next >= light_x) & (green_prev <= 0)).astype(jnp.float32)


class ToyCar(ConfiguredEnv):
    """The ToyCar environment (see the module docstring)."""

    name = "toycar"
    config_class = ToyCarConfig

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (*self.config.image_size, 3) if self.obs_mode == "image" else (5,)

    @property
    def action_size(self) -> int:
        return 2

    @property
    def action_bounds(self) -> tuple[jax.Array, jax.Array]:
        return jnp.zeros(2, jnp.float32), jnp.ones(2, jnp.float32)

    def _observe(self, sim: ToyCarSim) -> jax.Array:
        return render(sim, self.config) if self.obs_mode == "image" else full_observation(sim)

    def _reset(self, key: jax.Array) -> State:
        cfg = self.config
        k_x, k_v, k_l, k_g, k_d, k_r, k_next = jax.random.split(key, 7)
        green = (jax.random.uniform(k_g) < 0.5).astype(jnp.float32)
        sim = ToyCarSim(
            x=jax.random.uniform(k_x, (), minval=cfg.start_range[0], maxval=cfg.start_range[1]),
            v=jax.random.uniform(k_v, (), minval=0.0, maxval=cfg.start_speed_max),
            light_x=jax.random.uniform(k_l, (), minval=cfg.light_range[0], maxval=cfg.light_range[1]),
            green=green,
            # the episode starts somewhere inside the current status
            remaining=_duration(k_d, green, cfg) * jax.random.uniform(k_r, (), minval=0.05, maxval=1.0),
            t=jnp.zeros((), jnp.int32),
            key=k_next,
        )
        zero = jnp.zeros((), jnp.float32)
        return State(sim, self._observe(sim), zero, zero, {"red_light_violation": zero})

    def _step(self, state: State, action: jax.Array) -> State:
        cfg = self.config
        sim = state.pipeline_state
        throttle, brake = jnp.clip(action, 0.0, 1.0)
        accel = cfg.throttle_accel * throttle - cfg.brake_accel * brake - cfg.rolling_resistance
        v = jnp.clip(sim.v + accel * cfg.dt, 0.0, cfg.max_speed)
        x = sim.x + v * cfg.dt
        violation = crossed_on_red(sim.x, x, sim.light_x, sim.green)
        key, k_dur = jax.random.split(sim.key)
        remaining = sim.remaining - cfg.dt
        switch = remaining <= 0
        green = jnp.where(switch, 1.0 - sim.green, sim.green)
        remaining = jnp.where(switch, remaining + _duration(k_dur, green, cfg), remaining)
        nxt = ToyCarSim(x=x, v=v, light_x=sim.light_x, green=green, remaining=remaining, t=sim.t + 1, key=key)
        done = jnp.maximum(state.done, (x >= cfg.road_length).astype(jnp.float32))
        return State(nxt, self._observe(nxt), jnp.zeros((), jnp.float32), done, {"red_light_violation": violation})

    def sim_state(self, state: State) -> ToyCarSim:
        return state.pipeline_state

    def observe_sim(self, sim: ToyCarSim | dict) -> jax.Array:
        return self._observe(ToyCarSim(**sim) if isinstance(sim, dict) else sim)

    def render(self, state: State) -> jax.Array:
        return render(state.pipeline_state, self.config)

    def expert_observation(self, state: State) -> jax.Array:
        return full_observation(state.pipeline_state)

    def expert(self, full_obs: jax.Array) -> jax.Array:
        """The rule-based expert on this environment's settings; see `expert_action`."""
        return expert_action(full_obs, self.config)

    episode_metric_names = METRICS
    action_names = ("throttle", "brake")

    def episode_metrics(self, sims: ToyCarSim, final: State, valid: jax.Array) -> dict[str, jax.Array]:
        # the states after each step are the states before the next one, then the final one
        after = jax.tree.map(lambda p, f: jnp.concatenate([p[1:], f[None]]), sims, final.pipeline_state)
        return episode_metrics(jax.tree.map(lambda p: p[0], sims), after, valid, self.config)

    def caption(self, sim: ToyCarSim | dict, metrics: dict[str, float] | None = None) -> dict[str, str]:
        """A video caption's words (`Env.caption`): the speed, the light (green, amber, red; none once passed) and
        with the episode's `metrics` its outcome (success; else red light, stuck or timeout)."""
        sim = ToyCarSim(**sim) if isinstance(sim, dict) else sim
        light = ("none" if float(sim.x) > float(sim.light_x) else "red" if float(sim.green) <= 0 else
                 "amber" if bool(amber(sim.green, sim.remaining, self.config)) else "green")
        words = {"speed": f"{float(sim.v):.1f} m/s", "light": light}
        if metrics is not None:
            failed = [f"ran {metrics['red_light_violations']:.0f} red"] * (metrics["red_light_violations"] > 0) + \
                ["stuck"] * (metrics["stuck"] > 0)
            words["outcome"] = "success" if metrics["success"] > 0 else ", ".join(failed) or "timeout"
        return words


registry.register("toycar", ToyCar, ToyCarConfig, obs_modes=ToyCar.obs_modes, default_obs="image")


def full_observation(sim: ToyCarSim) -> jax.Array:
    """`[5] float32`: position, speed, light position, light is green, time left in its status."""
    return jnp.stack([sim.x, sim.v, sim.light_x, sim.green, sim.remaining]).astype(jnp.float32)


def _stop_distance(v: jax.Array, cfg: ToyCarConfig) -> jax.Array:
    """A safe upper bound on the distance needed to stop from speed `v` (discrete braking; the rolling
    resistance, which only shortens it, left out)."""
    return v**2 / (2 * cfg.brake_accel) + v * cfg.dt


def amber(green: jax.Array, remaining: jax.Array, cfg: ToyCarConfig = ToyCarConfig()) -> jax.Array:
    """True where a green light (`green` > 0, `remaining` seconds left in its status) shows amber: its last
    `cfg.amber_seconds`."""
    return (green > 0) & (remaining <= cfg.amber_seconds)


def expert_action(full_obs: jax.Array, cfg: ToyCarConfig = ToyCarConfig()) -> jax.Array:
    """The rule-based expert: `[5] full observation -> [2] (throttle, brake)`.

    Drives at full throttle unless the light ahead asks it to stop, as a driver
    does: on green it goes; on amber it stops if it still can and goes through
    if it cannot (it then crosses before the red, see `ToyCarConfig.amber_seconds`);
    on red it stops. Stopping keeps the invariant "I can still stop before the
    line": it throttles only while it could still stop after this step, coasts
    while coasting keeps that true, and brakes when neither does. Its decisions
    read only what the image shows (the light's colour, the distance) and the
    speed, never the time left in the light's status. Deterministic, pure, jit-
    and vmap-able; actions are always 0 or 1.
    """
    x, v, light_x, green, remaining = full_obs
    before = x < light_x
    line = light_x - cfg.stop_margin
    v_throttle = jnp.minimum(v + (cfg.throttle_accel - cfg.rolling_resistance) * cfg.dt, cfg.max_speed)
    can_stop_after_throttle = x + v_throttle * cfg.dt + _stop_distance(v_throttle, cfg) <= line
    can_stop_after_coast = x + v * cfg.dt + _stop_distance(v, cfg) <= line
    # stopping keeps "can stop now" true after every step, so it is false on amber only for a car that was
    # going (green) and is already inside its stopping distance: that car goes through
    can_stop_now = x + _stop_distance(v, cfg) <= line
    go = (green > 0) & (~amber(green, remaining, cfg) | ~can_stop_now)
    throttle = ~before | go | can_stop_after_throttle
    brake = ~throttle & ~can_stop_after_coast
    return jnp.stack([throttle, brake]).astype(jnp.float32)


def episode_metrics(
    initial: ToyCarSim, traj: ToyCarSim, valid: jax.Array, cfg: ToyCarConfig = ToyCarConfig()
) -> dict[str, jax.Array]:
    """Driving metrics of one episode from its trajectory.

    Args:
      initial: the simulator state at reset (fields `[]`).
      traj: the simulator states after each step, stacked (fields `[T]`).
      valid: `[T] float32`, 1 for steps inside the episode (a prefix: the steps
        up to and including the terminal one).
      cfg: the environment's settings.

    Returns:
      `success`, `red_light_violations`, `progress`, `avg_speed`, `stuck`, each
      `[] float32`; vmap over episodes for a batch.
    """
    valid = valid.astype(jnp.float32)
    x, v, green, light_x, x0 = traj.x, traj.v, traj.green, initial.light_x, initial.x
    x_prev = jnp.concatenate([x0[None], x[:-1]])
    green_prev = jnp.concatenate([initial.green[None], green[:-1]])  # status while each step ran
    violations = jnp.sum(crossed_on_red(x_prev, x, light_x, green_prev) * valid)
    n = jnp.maximum(jnp.sum(valid), 1.0)
    last = jnp.argmax(jnp.cumsum(valid))  # index of the last valid step
    x_final = x[last]
    reached = x_final >= cfg.road_length
    progress = 1.0 - jnp.maximum(cfg.road_length - x_final, 0.0) / (cfg.road_length - x0)
    free_to_go = (green > 0) | (x >= light_x)
    standing = (v < 1e-3) & free_to_go & (valid > 0)

    def run_length(count, s):
        count = jnp.where(s, count + 1, 0)
        return count, count

    _, runs = jax.lax.scan(run_length, jnp.zeros((), jnp.int32), standing)
    return {
        "success": (reached & (violations == 0)).astype(jnp.float32),
        "red_light_violations": violations,
        "progress": jnp.clip(progress, 0.0, 1.0),
        "avg_speed": (x_final - x0) / (n * cfg.dt),
        "stuck": (jnp.max(runs) >= cfg.stuck_steps).astype(jnp.float32),
    }


# -- rendering ---------------------------------------------------------------------------
_GRASS = jnp.array([0.36, 0.55, 0.28])
_ROAD = jnp.array([0.33, 0.33, 0.35])
_MARK = jnp.array([0.95, 0.95, 0.95])
_CAR = jnp.array([0.10, 0.35, 0.85])
_RED = jnp.array([0.90, 0.10, 0.10])
_GREEN = jnp.array([0.10, 0.85, 0.20])
_AMBER = jnp.array([0.98, 0.75, 0.05])
_POLE = jnp.array([0.15, 0.15, 0.15])


def render(sim: ToyCarSim, cfg: ToyCarConfig = ToyCarConfig()) -> jax.Array:
    """Top-down view following the car: `[H, W, 3] uint8`.

    The road runs left to right; the car is drawn `view_behind` metres from the
    left edge. Shown: grass, asphalt, a dashed centre line (3 m dashes every
    6 m, so motion is visible between frames), the stop line and a traffic
    light box beside the road in the light's colour, the chequered finish line,
    and the car (4 m × 2 m).
    """
    h, w = cfg.image_size
    span = cfg.view_behind + cfg.view_ahead
    half_height = span * h / w / 2  # metres from the road's centre to the image's top edge
    wx = sim.x - cfg.view_behind + (jnp.arange(w) + 0.5) / w * span  # [W]
    wy = half_height - (jnp.arange(h) + 0.5) / h * 2 * half_height  # [H]
    X, Y = jnp.meshgrid(wx, wy)  # [H, W]
    # thin lines are at least one pixel wide, so they survive small images
    px_x, px_y = span / w / 2, half_height / h
    road_half = 3.5
    on_road = jnp.abs(Y) <= road_half
    img = jnp.where(on_road[..., None], _ROAD, _GRASS)
    dash = on_road & (jnp.abs(Y) <= max(0.25, px_y)) & ((X % 6.0) < 3.0)
    img = jnp.where(dash[..., None], _MARK, img)
    stop_line = on_road & (jnp.abs(X - sim.light_x) <= max(0.4, px_x))
    img = jnp.where(stop_line[..., None], _MARK, img)
    lamp = (jnp.abs(X - sim.light_x) <= 1.5) & (Y >= road_half + 0.8) & (Y <= road_half + 3.8)
    pole = (jnp.abs(X - sim.light_x) <= max(0.4, px_x)) & (Y > road_half) & (Y < road_half + 0.8)
    img = jnp.where(pole[..., None], _POLE, img)
    colour = jnp.where(amber(sim.green, sim.remaining, cfg), _AMBER, jnp.where(sim.green > 0, _GREEN, _RED))
    img = jnp.where(lamp[..., None], colour, img)
    finish = on_road & (jnp.abs(X - cfg.road_length) <= 1.0)
    checker = ((jnp.floor(X) + jnp.floor(Y)) % 2) > 0
    img = jnp.where(finish[..., None], jnp.where(checker[..., None], _MARK, _POLE), img)
    car = (X >= sim.x - 4.0) & (X <= sim.x) & (jnp.abs(Y + road_half / 2) <= 1.0)
    img = jnp.where(car[..., None], _CAR, img)
    return jnp.round(img * 255).astype(jnp.uint8)
