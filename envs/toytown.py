"""ToyTown: the suite's CARLA analog (NoCrash in a pure-JAX town), `envs.make("toytown", ...)`.

The ego car drives a route of `route_length` metres that bends (so steering matters) through
`intersections` signalised intersections (random phases, amber before red, an all-red clearance for
the cross street) among cars that stop and go (at lights, behind each other, now and then at random),
cars crossing at the intersections, and pedestrians who sometimes cross (`envs.toytown_traffic`).
`traffic` sets NoCrash's conditions: `empty` (no one else), `regular` and `dense`. The route comes from
a layout seed (`envs.toytown_world`): `town="train"` draws it from `train_layouts`, `town="test"` from
the held-out `test_layouts`; `weather="test"` renders with a held-out palette (NoCrash's new town and
new weather).

The car is a kinematic bicycle (`wheelbase`; reference point at its centre) with CARLA's three
actions: `steer` in [-1, 1] (× `max_steer` rad, positive turns left), `throttle` in [0, 1]
(× `throttle_accel`) and `brake` in [0, 1] (× `brake_accel`), against a rolling resistance; speed in
[0, `max_speed`] (no reverse).

Observations:
  * `image` (default): the ego-centric top-down camera (`envs.toytown_render`), `[H, W, 3] uint8`,
    64×64 by default, whose top rows are the measurement strip: the speed as a grey level with
    `speed_input=True` (CARLA's setting, "with speed"), black with `speed_input=False` ("w/o speed").
    Cars show brake lights while they brake or stand.
  * `pos`: the one-frame state (`toytown_expert.one_frame_names`): what one camera frame shows, as numbers,
    the driving analog of MuJoCo's `pos` (the positions with the velocities stripped). The lane, the bend,
    the stop line and its light, the gap to the car ahead and whether its brake lights are on, the pedestrian
    in the way, a blocked junction, and the ego's speed only with `speed_input`; no other agent's speed, no
    light's time left, no progress, so only a history reveals motion.
  * `full`: `[24] float32`, the state the rule-based expert acts on (`FEATURES`): speed, lane offset
    and heading error, the lane's centre 4-16 m ahead, the bend ahead, the next stop line and its
    light, the car ahead, the pedestrian in the way, whether the junction is blocked, progress.
    `bc-full` trains on it. The speed is part of it whatever `speed_input` says.

Task versions (`task_version`, recorded in every data key, results file and fingerprint; results of two
versions never merge): 1, the first tables': no brake lights, and the measurement strip drawn over the view's
farthest rows (2.25 m at 64×64, where the expert still reacts); 2 (the default): brake lights, and the strip
above the scene, which keeps its full `view_ahead`. The expert, the physics and the full state are the same in
both; what the camera (and so `pos`) shows is not.

The episode ends at the goal, or at the ego's first collision (with a car, a pedestrian, or leaving
the road); the time limit is `episode_length`. Per-episode metrics (`episode_metrics`, NoCrash's):
`success` (goal reached in time without a collision), `route_completion`, `collisions` and its three
kinds, `red_light_violations` (entering a junction on red; not a failure by itself, as in NoCrash),
`timeout`, `stuck` (standing still for `stuck_seconds` while free to go: no red or amber light it
should stop for, no car within 8 m ahead, no pedestrian in the way: the inertia failure) and
`avg_speed`. The reward is the route progress of the step (a return is the route completion).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from flax import struct

from envs import registry
from envs import toytown_render as render_lib
from envs import toytown_traffic as traffic
from envs import toytown_world as world
from envs.base import ConfiguredEnv, State
from envs.toytown_expert import (FEATURES, METRICS, episode_metrics, expert_action, features, free_to_go,  # noqa: F401
                                 one_frame, one_frame_names)

# NoCrash's traffic conditions: (route cars per 100 m per lane, pedestrians per 100 m of route)
TRAFFIC = {"empty": (0.0, 0.0), "regular": (1.0, 1.0), "dense": (2.5, 2.5)}
SPLITS = ("train", "test")
TASK_VERSION = 2  # what the camera shows (module docstring); VERSIONS lists those that can be made
VERSIONS = (1, 2)
START_S = 5.0  # the ego starts this far along the route, standing, in its lane


@dataclasses.dataclass(frozen=True)
class ToyTownConfig:
    """ToyTown's static settings (hashable; override with `envs.make("toytown", key=value)`).

    Attributes:
      traffic: `empty`, `regular` or `dense` (`TRAFFIC`).
      vehicle_density, pedestrian_density: route cars per 100 m per lane and pedestrians per 100 m of route,
        >= 0; None: the traffic condition's. Cross-street traffic runs wherever route cars do.
      speed_input: image observations show the speed (the measurement strip), or not ("w/o speed").
      town: `train` or `test`: the range of layout seeds the route is drawn from.
      weather: `train` or `test`: the palette the camera renders with.
      layout: a fixed layout seed (>= 0) for every episode; -1 draws one from the town's range per episode.
      train_layouts, test_layouts: [first, last) layout seeds of each town.
      route_length: metres from the start to the goal, at least 60 m per block (`intersections + 1` blocks).
      intersections: signalised intersections on the route, >= 1.
      dt: seconds per control step.
      episode_length: control steps per episode (the time limit).
      speed_limit: the expert's cruising speed, m/s.
      max_speed: the car's top speed, m/s.
      wheelbase: m.  max_steer: the steering angle at steer = ±1, rad.
      throttle_accel, brake_accel: acceleration at full throttle, deceleration at full brake, m/s².
      rolling_resistance: deceleration of a moving car off the pedals, m/s².
      lane_width: m (two lanes: the road is twice as wide).
      green_range, red_range: a light's route green and route red last uniformly this long, s (per
        intersection and episode); red must hold the cross street's clearances, amber and >= 2 s of green.
      amber_seconds: the amber between green and red, s (a car that cannot stop crosses before the red).
      clearance_seconds: the all-red between the two directions, s.
      car_stop_rate: random stops per second of a moving route car.  car_stop_seconds: their length, s.
      cross_speed: the cross-street cars' speed, m/s.  cross_wait: seconds out of sight between crossings.
      ped_wait: seconds a pedestrian waits before crossing.  ped_clear_distance: a pedestrian sets off only
        when no car is within this many metres (so one never steps in front of a car that cannot stop).
      stuck_seconds: standing still this long while free to go is `stuck`.
      image_size: (height, width) of `image` observations, each >= 16.
      view_ahead, view_behind: metres of road shown ahead of and behind the car's centre.
      task_version: what the camera shows (the module docstring): 2, or 1 for the first tables' camera.
      reveal: full-state features (`FEATURES`) added to the one-frame state (`pos`), in this order: a diagnostic
        of what one frame lacks (the one-frame ceiling gives `("lead_speed",)`); () everywhere else.
    """

    traffic: str = "dense"
    vehicle_density: float | None = None
    pedestrian_density: float | None = None
    speed_input: bool = True
    town: str = "train"
    weather: str = "train"
    layout: int = -1
    train_layouts: tuple[int, int] = (0, 50)
    test_layouts: tuple[int, int] = (1000, 1050)
    route_length: float = 400.0
    intersections: int = 4
    dt: float = 0.1
    episode_length: int = 2000
    speed_limit: float = 8.0
    max_speed: float = 14.0
    wheelbase: float = 2.7
    max_steer: float = 0.5
    throttle_accel: float = 3.0
    brake_accel: float = 8.0
    rolling_resistance: float = 0.4
    lane_width: float = 3.5
    green_range: tuple[float, float] = (8.0, 16.0)
    red_range: tuple[float, float] = (10.0, 16.0)
    amber_seconds: float = 3.0
    clearance_seconds: float = 1.5
    car_stop_rate: float = 1.0 / 60.0
    car_stop_seconds: tuple[float, float] = (2.0, 6.0)
    cross_speed: float = 7.0
    cross_wait: tuple[float, float] = (0.0, 10.0)
    ped_wait: tuple[float, float] = (2.0, 20.0)
    ped_clear_distance: float = 20.0
    stuck_seconds: float = 4.0
    image_size: tuple[int, int] = (64, 64)
    view_ahead: float = 28.0
    view_behind: float = 8.0
    task_version: int = TASK_VERSION
    reveal: tuple[str, ...] = ()

    def __post_init__(self):
        if self.traffic not in TRAFFIC:
            raise ValueError(f"unknown traffic {self.traffic!r}; valid: {', '.join(TRAFFIC)}")
        for name in ("town", "weather"):
            if getattr(self, name) not in SPLITS:
                raise ValueError(f"unknown {name} {getattr(self, name)!r}; valid: {', '.join(SPLITS)}")
        for name in ("vehicle_density", "pedestrian_density"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, (int, float)) and 0 <= value < math.inf):
                raise ValueError(f"{name} must be a number >= 0 (or None: the traffic condition's), got {value!r}")
        if not isinstance(self.intersections, int) or self.intersections < 1:
            raise ValueError(f"intersections must be an integer >= 1, got {self.intersections!r}")
        least = world.MIN_BLOCK * (self.intersections + 1)
        if not self.route_length >= least:
            raise ValueError(f"route_length must be at least {least:g} m for {self.intersections} intersection(s) "
                             f"({world.MIN_BLOCK:g} m per block of intersections + 1), got {self.route_length!r}")
        h, w = self.image_size
        if min(h, w) < 16:
            raise ValueError(f"image_size must be at least 16x16, got {h}x{w}")
        if self.task_version not in VERSIONS:
            raise ValueError(f"task_version must be one of {', '.join(map(str, VERSIONS))}, got {self.task_version!r}")
        hidden = [f for f in self.reveal if f not in FEATURES or f in one_frame_names(self, reveal=False)]
        if hidden or len(set(self.reveal)) != len(self.reveal):
            valid = ", ".join(f for f in FEATURES if f not in one_frame_names(self, reveal=False))
            raise ValueError(f"reveal takes full-state features the one-frame state leaves out, each once, got "
                             f"{list(self.reveal)}; valid: {valid}")
        if not isinstance(self.speed_input, bool):
            raise ValueError(f"speed_input must be True or False, got {self.speed_input!r}")
        checks = {
            "dt": self.dt > 0, "episode_length": self.episode_length > 0,
            "layout": isinstance(self.layout, int) and self.layout >= -1,
            "train_layouts": 0 <= self.train_layouts[0] < self.train_layouts[1],
            "test_layouts": 0 <= self.test_layouts[0] < self.test_layouts[1],
            "speed_limit": 0 < self.speed_limit <= self.max_speed,
            "wheelbase": self.wheelbase > 0, "max_steer": 0 < self.max_steer < 1.5,
            "throttle_accel": self.throttle_accel > self.rolling_resistance >= 0, "brake_accel": self.brake_accel > 0,
            "lane_width": self.lane_width > traffic.CAR_WIDTH,
            "green_range": 0 < self.green_range[0] <= self.green_range[1],
            "red_range": 2 * self.clearance_seconds + self.amber_seconds + 2 <= self.red_range[0] <= self.red_range[1],
            "amber_seconds": self.amber_seconds > 0, "clearance_seconds": self.clearance_seconds >= 0,
            "car_stop_rate": self.car_stop_rate >= 0, "car_stop_seconds": 0 < self.car_stop_seconds[0]
            <= self.car_stop_seconds[1], "cross_speed": self.cross_speed > 0,
            "cross_wait": 0 <= self.cross_wait[0] <= self.cross_wait[1],
            "ped_wait": 0 <= self.ped_wait[0] <= self.ped_wait[1], "ped_clear_distance": self.ped_clear_distance >= 0,
            "stuck_seconds": self.stuck_seconds > 0,
            "view_ahead": self.view_ahead > traffic.CAR_LENGTH,
            "view_behind": self.view_behind > traffic.CAR_LENGTH / 2,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"invalid ToyTown settings: {bad} (see ToyTownConfig's docstring for the valid ranges)")

    @property
    def densities(self) -> tuple[float, float]:
        """(route cars per 100 m per lane, pedestrians per 100 m): the overrides, else the condition's."""
        cars, peds = TRAFFIC[self.traffic]
        return (cars if self.vehicle_density is None else float(self.vehicle_density),
                peds if self.pedestrian_density is None else float(self.pedestrian_density))

    @property
    def cars_per_lane(self) -> int:
        return round(self.densities[0] * (self.route_length + 2 * traffic.MARGIN) / 100)

    @property
    def pedestrians(self) -> int:
        return round(self.densities[1] * self.route_length / 100)

    @property
    def stuck_steps(self) -> int:
        return max(1, round(self.stuck_seconds / self.dt))


@struct.dataclass
class ToyTownSim:
    """ToyTown's simulator state: flat named arrays (a dataset stores each as `sim/<name>`).

    Per episode: `layout` `[] int32`; the route's pieces `route_*` `[R]` (`toytown_world.Route`); the intersections'
    arc lengths `inter_s` `[n]`; their lights `light_green`, `light_red`, `light_offset` `[n]`. The ego: `x`, `y`
    (m), `yaw` (rad), `v` (m/s), and its route coordinates `s`, `d` (m), `[]` each. Route cars `car_*` `[N]`; cross-
    street cars `cross_*` `[n, 2]`; pedestrians `ped_*` `[P]` (`toytown_traffic`); `car_brake`, `cross_brake`: their
    brake lights (`toytown_traffic.braking`). The episode's bookkeeping, `[]` each: `t` (int32 steps), `key`, the
    sticky collision flags `hit_car`, `hit_pedestrian`, `off_road`, the count `red_lights`, `still` (int32 steps
    standing while free to go), the sticky `stuck` and `goal`.
    """

    layout: jax.Array
    route_s0: jax.Array
    route_x0: jax.Array
    route_y0: jax.Array
    route_h0: jax.Array
    route_kappa: jax.Array
    inter_s: jax.Array
    light_green: jax.Array
    light_red: jax.Array
    light_offset: jax.Array
    x: jax.Array
    y: jax.Array
    yaw: jax.Array
    v: jax.Array
    s: jax.Array
    d: jax.Array
    car_s: jax.Array
    car_v: jax.Array
    car_lane: jax.Array
    car_v0: jax.Array
    car_stop: jax.Array
    car_active: jax.Array
    car_brake: jax.Array
    cross_u: jax.Array
    cross_v: jax.Array
    cross_wait: jax.Array
    cross_brake: jax.Array
    ped_s: jax.Array
    ped_d: jax.Array
    ped_dir: jax.Array
    ped_walking: jax.Array
    ped_speed: jax.Array
    ped_wait: jax.Array
    ped_active: jax.Array
    t: jax.Array
    key: jax.Array
    hit_car: jax.Array
    hit_pedestrian: jax.Array
    off_road: jax.Array
    red_lights: jax.Array
    still: jax.Array
    stuck: jax.Array
    goal: jax.Array

    @property
    def route(self) -> world.Route:
        return world.Route(self.route_s0, self.route_x0, self.route_y0, self.route_h0, self.route_kappa)

    @property
    def lights(self) -> world.Lights:
        return world.Lights(self.light_green, self.light_red, self.light_offset)

    def fields(self, prefix: str) -> dict:
        """The fields whose names start with `prefix` (e.g. `"car_"`), by name."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name.startswith(prefix)}


class ToyTown(ConfiguredEnv):
    """The ToyTown environment (see the module docstring)."""

    name = "toytown"
    config_class = ToyTownConfig
    obs_modes = ("full", "pos", "image")
    episode_metric_names = METRICS
    action_names = ("steer", "throttle", "brake")

    @property
    def observation_shape(self) -> tuple[int, ...]:
        if self.obs_mode == "image":
            return (*self.config.image_size, 3)
        return (len(one_frame_names(self.config) if self.obs_mode == "pos" else FEATURES),)

    @property
    def action_size(self) -> int:
        return 3

    @property
    def action_bounds(self) -> tuple[jax.Array, jax.Array]:
        return jnp.array([-1.0, 0.0, 0.0], jnp.float32), jnp.ones(3, jnp.float32)

    def _observe(self, sim: ToyTownSim) -> jax.Array:
        if self.obs_mode == "image":
            return render_lib.render(sim, self.config)
        if self.obs_mode == "pos":
            return one_frame(sim, self.config)
        return features(sim, self.config)

    def _reset(self, key: jax.Array) -> State:
        sim = initial_sim(key, self.config)
        zero = jnp.zeros((), jnp.float32)
        return State(sim, self._observe(sim), zero, zero, _step_metrics(sim, sim))

    def _step(self, state: State, action: jax.Array) -> State:
        sim = step_sim(state.pipeline_state, action, self.config)
        reward = (sim.s - state.pipeline_state.s) / self.config.route_length
        done = jnp.maximum(state.done, jnp.maximum(sim.goal, _crashed(sim)))
        return State(sim, self._observe(sim), reward.astype(jnp.float32), done,
                     _step_metrics(state.pipeline_state, sim))

    def sim_state(self, state: State) -> ToyTownSim:
        return state.pipeline_state

    def observe_sim(self, sim: ToyTownSim | dict) -> jax.Array:
        return self._observe(ToyTownSim(**sim) if isinstance(sim, dict) else sim)

    def render(self, state: State) -> jax.Array:
        return render_lib.render(state.pipeline_state, self.config)

    def expert_observation(self, state: State) -> jax.Array:
        return features(state.pipeline_state, self.config)

    def expert(self, full_obs: jax.Array) -> jax.Array:
        """The rule-based expert on this environment's settings; see `toytown_expert.expert_action`."""
        return expert_action(full_obs, self.config)

    def episode_metrics(self, sims: ToyTownSim, final: State, valid: jax.Array) -> dict[str, jax.Array]:
        return episode_metrics(jax.tree.map(lambda a: a[0], sims), final.pipeline_state, valid, self.config)

    def caption(self, sim: ToyTownSim | dict, metrics: dict[str, float] | None = None) -> dict[str, str]:
        """A video caption's words (`Env.caption`): the speed and the light ahead as the full state has them (red,
        amber, green; none within sight), and with the episode's `metrics` its outcome (success; a collision and
        with what; a timeout; stuck; red lights run)."""
        full = dict(zip(FEATURES, features(ToyTownSim(**sim) if isinstance(sim, dict) else sim, self.config).tolist()))
        lit = [colour for colour in ("red", "amber", "green") if full[f"light_{colour}"] > 0.5]
        words = {"speed": f"{full['speed']:.1f} m/s", "light": lit[0] if lit else "none"}
        if metrics is not None:
            hit = [what for what in ("vehicle", "pedestrian", "offroad") if metrics[f"collisions_{what}"] > 0]
            ends = ["success"] if metrics["success"] > 0 else [f"collision ({', '.join(hit)})"] if hit else \
                ["timeout"]
            ends += ["stuck"] * (metrics["stuck"] > 0) + \
                [f"{metrics['red_light_violations']:.0f} red light(s) run"] * (metrics["red_light_violations"] > 0)
            words["outcome"] = ", ".join(ends)
        return words


registry.register("toytown", ToyTown, ToyTownConfig, obs_modes=ToyTown.obs_modes, default_obs="image")


def _crashed(sim: ToyTownSim) -> jax.Array:
    return jnp.maximum(jnp.maximum(sim.hit_car, sim.hit_pedestrian), sim.off_road)


def _step_metrics(before: ToyTownSim, after: ToyTownSim) -> dict[str, jax.Array]:
    """Per-step flags: what this step added (0 at reset)."""
    return {"collision": _crashed(after) - _crashed(before),
            "red_light_violation": after.red_lights - before.red_lights}


def initial_sim(key: jax.Array, cfg: ToyTownConfig) -> ToyTownSim:
    """A random initial state: the layout (the town's range, or `cfg.layout`), lights, traffic; the ego
    standing in its lane `START_S` metres along the route."""
    k_layout, k_lights, k_cars, k_cross, k_peds, k_next = jax.random.split(key, 6)
    layout = draw_layout(k_layout, cfg)
    route, inter_s = world.make_route(layout, cfg.route_length, cfg.intersections)
    n, w = cfg.intersections, cfg.lane_width
    lights = world.draw_lights(k_lights, n, cfg.green_range, cfg.red_range, cfg.amber_seconds)
    x, y, h, _ = world.pose_at(route, jnp.float32(START_S))
    d0 = -0.5 * w
    f32 = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    # route cars: evenly spread along both lanes with some jitter, none close to the ego
    per_lane, span = max(cfg.cars_per_lane, 1), cfg.route_length + 2 * traffic.MARGIN
    k_pos, k_v0, k_v = jax.random.split(k_cars, 3)
    lane = jnp.repeat(jnp.arange(2, dtype=jnp.float32), per_lane)
    slot = jnp.tile(jnp.arange(per_lane, dtype=jnp.float32), 2)
    spacing = span / per_lane
    car_s = -traffic.MARGIN + spacing * (slot + 0.6 * jax.random.uniform(k_pos, slot.shape))
    rel = car_s - START_S
    clear = jnp.where(lane == 0, (rel < -25.0) | (rel > 20.0), jnp.abs(rel) > 10.0)
    active = (cfg.cars_per_lane > 0) & clear
    v0 = jax.random.uniform(k_v0, slot.shape, minval=5.5, maxval=8.0)
    # cross-street cars: approaching, or out of sight for a while; none without route traffic
    k_u, k_wait = jax.random.split(k_cross)
    cross_u = jax.random.uniform(k_u, (n, 2), minval=-traffic.CROSS_REACH, maxval=-(w + 10.0))
    wait = jax.random.uniform(k_wait, (n, 2), maxval=cfg.cross_wait[1]) * (jax.random.uniform(k_wait, (n, 2)) < 0.5)
    cross_wait = wait if cfg.cars_per_lane > 0 else jnp.full((n, 2), traffic.NEVER)
    # pedestrians: waiting on either sidewalk ahead of the ego
    count = max(cfg.pedestrians, 1)
    k_ps, k_pdir, k_pspeed, k_pwait = jax.random.split(k_peds, 4)
    p_dir = jnp.where(jax.random.uniform(k_pdir, (count,)) < 0.5, -1.0, 1.0)
    p_on = jnp.full((count,), cfg.pedestrians > 0)
    zero, zeros = jnp.zeros((), jnp.float32), jnp.zeros(slot.shape, jnp.float32)
    sim = ToyTownSim(
        layout=layout, route_s0=route.s0, route_x0=route.x0, route_y0=route.y0, route_h0=route.h0,
        route_kappa=route.kappa, inter_s=inter_s, light_green=lights.green, light_red=lights.red,
        light_offset=lights.offset,
        x=x - d0 * jnp.sin(h), y=y + d0 * jnp.cos(h), yaw=h, v=zero, s=f32(START_S), d=f32(d0),
        car_s=jnp.where(active, car_s, traffic.NOWHERE), car_v=v0 * jax.random.uniform(k_v, slot.shape) * active,
        car_lane=lane, car_v0=v0, car_stop=zeros, car_active=active.astype(jnp.float32), car_brake=zeros,
        cross_u=cross_u, cross_v=jnp.full((n, 2), cfg.cross_speed), cross_wait=cross_wait,
        cross_brake=jnp.zeros((n, 2), jnp.float32),
        ped_s=jnp.where(p_on, traffic.crossing_place(jax.random.uniform(k_ps, (count,), minval=START_S + 25.0,
                                                                         maxval=cfg.route_length), inter_s, w),
                        traffic.NOWHERE),
        ped_d=-p_dir * (w + 1.0), ped_dir=p_dir, ped_walking=jnp.zeros(count),
        ped_speed=jax.random.uniform(k_pspeed, (count,), minval=1.1, maxval=1.6),
        ped_wait=jax.random.uniform(k_pwait, (count,), maxval=cfg.ped_wait[1]), ped_active=p_on.astype(jnp.float32),
        t=jnp.zeros((), jnp.int32), key=k_next, hit_car=zero, hit_pedestrian=zero, off_road=zero,
        red_lights=zero, still=jnp.zeros((), jnp.int32), stuck=zero, goal=zero)
    sim = sim.replace(car_brake=(sim.car_v < traffic.STANDING) * sim.car_active)
    return sim.replace(still=jnp.where(free_to_go(sim, cfg) & (sim.v < 0.1), 1, 0).astype(jnp.int32))


def draw_layout(key: jax.Array, cfg: ToyTownConfig) -> jax.Array:
    """`[] int32`: the episode's layout seed, `cfg.layout` if fixed, else uniform in the town's range."""
    if cfg.layout >= 0:
        return jnp.asarray(cfg.layout, jnp.int32)
    first, last = cfg.train_layouts if cfg.town == "train" else cfg.test_layouts
    return jax.random.randint(key, (), first, last, dtype=jnp.int32)


def step_sim(sim: ToyTownSim, action: jax.Array, cfg: ToyTownConfig) -> ToyTownSim:
    """One control step: the ego car, then the other road users, then collisions, lights and counters."""
    steer, throttle, brake = jnp.clip(action, jnp.array([-1.0, 0.0, 0.0]), 1.0)
    accel = cfg.throttle_accel * throttle - cfg.brake_accel * brake - cfg.rolling_resistance * (sim.v > 0)
    v = jnp.clip(sim.v + accel * cfg.dt, 0.0, cfg.max_speed)
    yaw = sim.yaw + v * jnp.tan(steer * cfg.max_steer) / cfg.wheelbase * cfg.dt
    x, y = sim.x + v * jnp.cos(yaw) * cfg.dt, sim.y + v * jnp.sin(yaw) * cfg.dt
    s, d = world.project(sim.route, x, y, sim.s, 3.0, 6.0, 0.5)
    ego = {"s": s, "d": d, "v": v}
    key, k_cars, k_cross, k_peds = jax.random.split(sim.key, 4)
    t = sim.t + 1
    w = cfg.lane_width
    state_before, _ = world.route_phase(sim.lights, sim.t * cfg.dt, cfg.amber_seconds)
    state_now, _ = world.route_phase(sim.lights, t * cfg.dt, cfg.amber_seconds)
    cross_state = world.cross_phase(sim.lights, t * cfg.dt, cfg.amber_seconds, cfg.clearance_seconds)
    blocked = traffic.junction_blocked(sim.cross_u, sim.cross_wait, w)
    cars = traffic.step_cars(sim.fields("car_"), ego, sim.fields("ped_"), sim.inter_s, state_now, blocked, k_cars, cfg)
    # a junction is occupied while any route car (the ego included) is in it
    all_s = jnp.concatenate([cars["car_s"], s[None]])
    all_d = jnp.concatenate([traffic.lane_d(cars["car_lane"], w), d[None]])
    inside = (jnp.abs(all_s[None, :] - sim.inter_s[:, None]) < w + traffic.CAR_LENGTH / 2) & (jnp.abs(all_d) < w + 0.5)
    cross = traffic.step_cross(sim.fields("cross_"), cross_state, jnp.any(inside, axis=1), k_cross, cfg)
    peds = traffic.step_peds(sim.fields("ped_"), ego, cars, sim.inter_s, k_peds, cfg)
    cars["car_brake"] = traffic.braking(sim.car_v, cars["car_v"], cfg.dt) * cars["car_active"]
    cross["cross_brake"] = traffic.braking(sim.cross_v, cross["cross_v"], cfg.dt)
    hits = collisions(s, d, cars, cross, peds, sim.inter_s, w)
    # entering a junction on red: the car's front crosses a stop line while the light shows red
    line = sim.inter_s - w - 1.0
    front_before, front_now = sim.s + traffic.CAR_LENGTH / 2, s + traffic.CAR_LENGTH / 2
    ran = jnp.sum((front_before < line) & (front_now >= line) & (state_before == world.RED))
    nxt = sim.replace(x=x, y=y, yaw=yaw, v=v, s=s, d=d, **cars, **cross, **peds, t=t, key=key,
                      hit_car=jnp.maximum(sim.hit_car, hits["car"]),
                      hit_pedestrian=jnp.maximum(sim.hit_pedestrian, hits["pedestrian"]),
                      off_road=jnp.maximum(sim.off_road, (jnp.abs(d) > w).astype(jnp.float32)),
                      red_lights=sim.red_lights + ran, goal=jnp.maximum(sim.goal, (s >= cfg.route_length) * 1.0))
    still = jnp.where(free_to_go(nxt, cfg) & (v < 0.1), sim.still + 1, 0).astype(jnp.int32)
    return nxt.replace(still=still, stuck=jnp.maximum(sim.stuck, (still >= cfg.stuck_steps) * 1.0))


def collisions(s, d, cars, cross, peds, inter_s, w) -> dict[str, jax.Array]:
    """`{"car", "pedestrian"}`, `[] float32` 0/1: the ego at route coordinates (s, d) overlaps a car (route or
    cross street) or a pedestrian, bodies as boxes in route coordinates (a little inside the cars' outlines,
    so that passing close is not a collision)."""
    L, W = traffic.CAR_LENGTH, traffic.CAR_WIDTH
    route_hit = ((cars["car_active"] > 0) & (jnp.abs(cars["car_s"] - s) < L - 0.3)
                 & (jnp.abs(traffic.lane_d(cars["car_lane"], w) - d) < W - 0.2))
    xs, xd = traffic.cross_position(cross["cross_u"], inter_s, w)
    reach = (L + W) / 2 - 0.2
    cross_hit = (cross["cross_wait"] <= 0) & (jnp.abs(xs - s) < reach) & (jnp.abs(xd - d) < reach)
    ped_hit = ((peds["ped_active"] > 0) & (jnp.abs(peds["ped_s"] - s) < L / 2 + traffic.PED_HALF)
               & (jnp.abs(peds["ped_d"] - d) < W / 2 + traffic.PED_HALF))
    return {"car": (jnp.any(route_hit) | jnp.any(cross_hit)).astype(jnp.float32),
            "pedestrian": jnp.any(ped_hit).astype(jnp.float32)}
