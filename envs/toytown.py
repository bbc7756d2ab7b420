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

The settings are `envs.toytown_config.ToyTownConfig` (re-exported here). Task versions (`task_version`,
recorded in every data key, results file and fingerprint; results of two versions never merge): 1, the first
tables': no brake lights, and the measurement strip drawn over the view's farthest rows (2.25 m at 64×64,
where the expert still reacts); 2 (the default): brake lights, and the strip above the scene, which keeps its
full `view_ahead`. The expert, the physics and the full state are the same in both; what the camera (and so
`pos`) shows is not.

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
from envs.toytown_config import SPLITS, TASK_VERSION, TRAFFIC, VERSIONS, ToyTownConfig  # noqa: F401 (read here)

START_S = 5.0  # the ego starts this far along the route, standing, in its lane


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
    def observation_names(self) -> tuple[str, ...] | None:
        """The names of a vector observation's entries (`one_frame_names`, `FEATURES`); None for frames."""
        if self.obs_mode == "image":
            return None
        return one_frame_names(self.config) if self.obs_mode == "pos" else FEATURES

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
