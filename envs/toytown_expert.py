"""ToyTown's full state, its rule-based expert, and its per-episode metrics.

The expert drives as CARLA's autopilot does, with smooth controls: it steers by pure pursuit on its lane's
centre and sets its acceleration by the Intelligent Driver Model (the other cars' model,
`envs.toytown_traffic.idm`) towards the speed limit, slower in bends, with the obstacles it must not reach
as IDM leaders: the car ahead, the stop line of a red light or of an amber one it can still stop for, a
junction a crossing car is in, a pedestrian in its way. The acceleration becomes throttle or brake through
the car's own constants (`throttle_accel`, `brake_accel`, `rolling_resistance`), so the pedals move as
smoothly as the situation does. It sees only what the camera shows: obstacles within `view_ahead` of the
car's centre (`perception`), the light's colour and not the time it has left.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs import toytown_traffic as traffic
from envs import toytown_world as world

LOOKAHEAD = (4.0, 8.0, 12.0, 16.0)  # metres ahead along the route at which the full state holds the lane's centre
FEATURES = ("speed", "lane_offset", "heading_error",
            *(f"lane_{axis}{int(m)}" for m in LOOKAHEAD for axis in ("x", "y")),
            "curvature_ahead", "stop_gap", "light_green", "light_amber", "light_red", "light_left",
            "lead_gap", "lead_speed", "ped_gap", "ped_offset", "ped_speed", "junction_blocked", "progress")
_I = {name: i for i, name in enumerate(FEATURES)}
A_LATERAL = 2.0  # the expert's largest lateral acceleration in a bend, m/s²
FREE_GAP = 8.0  # free to go: no car within this gap ahead, m
METRICS = ("success", "route_completion", "collisions", "collisions_vehicle", "collisions_pedestrian",
           "collisions_offroad", "red_light_violations", "timeout", "stuck", "avg_speed")


def perception(cfg) -> float:
    """How far ahead of the car's front the expert reacts to anything: what the camera shows, m."""
    return cfg.view_ahead - traffic.CAR_LENGTH / 2


def _lead(sim) -> tuple[jax.Array, jax.Array]:
    """`([N] gaps, [] k)`: each route car's bumper gap ahead of the ego in its lane (`traffic.FAR` for the others),
    and the nearest one's index."""
    gaps = jnp.where((sim.car_lane == 0) & (sim.car_active > 0) & (sim.car_s > sim.s),
                     sim.car_s - sim.s - traffic.CAR_LENGTH, traffic.FAR)
    return gaps, jnp.argmin(gaps)


def features(sim, cfg) -> jax.Array:
    """The full state (`FEATURES`), `[24] float32`, of simulator state `sim` (`envs.toytown.ToyTownSim`).

    Lengths in m, speeds in m/s, angles in rad; points in the car's frame (x ahead, y to the left); a gap with
    nothing seen within `perception` is `traffic.FAR`; `light_*` one-hot for the next stop line's light
    (zeros past the last); `light_left` the seconds its colour has left (for `bc-full`; the expert ignores it).
    """
    w, L, far, seen = cfg.lane_width, traffic.CAR_LENGTH, traffic.FAR, perception(cfg)
    route = sim.route
    _, _, heading, _ = world.pose_at(route, sim.s)
    heading_error = jnp.mod(sim.yaw - heading + jnp.pi, 2 * jnp.pi) - jnp.pi
    px, py, ph, _ = world.pose_at(route, sim.s + jnp.array(LOOKAHEAD, jnp.float32))
    lx, ly = px + 0.5 * w * jnp.sin(ph), py - 0.5 * w * jnp.cos(ph)  # the lane's centre, w/2 to the right
    c, s_ = jnp.cos(sim.yaw), jnp.sin(sim.yaw)
    ahead_x = (lx - sim.x) * c + (ly - sim.y) * s_
    ahead_y = (ly - sim.y) * c - (lx - sim.x) * s_
    front = sim.s + L / 2
    one = jnp.ones((), jnp.float32)
    gap_line, j = traffic.stop_line_ahead(sim.inter_s, front, one, w)
    visible = gap_line < seen
    state, left = world.route_phase(sim.lights, sim.t * cfg.dt, cfg.amber_seconds)
    light = jax.nn.one_hot(state[j], 3) * visible
    blocked = traffic.junction_blocked(sim.cross_u, sim.cross_wait, w)[j] & visible
    lead_gaps, k = _lead(sim)
    lead_seen = lead_gaps[k] < seen
    peds = {n: getattr(sim, n) for n in ("ped_s", "ped_d", "ped_dir", "ped_walking", "ped_active")}
    ped_gap, i = traffic.pedestrian_gaps(peds, front[None], one[None], w)
    ped_seen = ped_gap[0] < seen
    i = i[0]
    out = jnp.stack([
        sim.v, sim.d + 0.5 * w, heading_error, *jnp.stack([ahead_x, ahead_y], -1).reshape(-1),
        world.curvature_ahead(route, sim.s, 25.0), jnp.where(visible, gap_line, far), *light,
        jnp.where(visible, jnp.minimum(left[j], 30.0), 0.0), jnp.where(lead_seen, jnp.maximum(lead_gaps[k], 0.0), far),
        jnp.where(lead_seen, sim.car_v[k], 0.0), jnp.where(ped_seen, ped_gap[0], far),
        jnp.where(ped_seen, sim.ped_d[i] - sim.d, 0.0),
        jnp.where(ped_seen, sim.ped_dir[i] * sim.ped_speed[i] * sim.ped_walking[i], 0.0),
        blocked.astype(jnp.float32), sim.s / cfg.route_length])
    return out.astype(jnp.float32)


# The one-frame state (`obs="pos"`): the full state without what no single frame shows. Every other agent's speed,
# a light's time left and the route's progress are never in it; the ego's speed only where the measurement strip
# shows it; whether the car ahead brakes or stands where the camera draws brake lights (task version 2).
HIDDEN = ("lead_speed", "ped_speed", "light_left", "progress")
LEAD_BRAKES = "lead_brakes"  # 1 while the car ahead (within `perception`) shows its brake lights


def one_frame_names(cfg, reveal: bool = True) -> tuple[str, ...]:
    """The one-frame state's features under settings `cfg` (a `ToyTownConfig`), in order: `FEATURES` less `HIDDEN`
    (and less `speed` without the speed input), then `lead_brakes` from task version 2, then `cfg.reveal` (with
    `reveal`). The perception stage reads exactly these from a frame."""
    names = tuple(f for f in FEATURES if f not in HIDDEN and (f != "speed" or cfg.speed_input))
    names += (LEAD_BRAKES,) * (cfg.task_version >= 2)
    return names + (tuple(cfg.reveal) if reveal else ())


def one_frame(sim, cfg) -> jax.Array:
    """The one-frame state (`one_frame_names(cfg)`) of simulator state `sim`: `[D] float32`, its values as
    `features` gives them (a gap with nothing seen is `traffic.FAR`), `lead_brakes` 0/1."""
    full = features(sim, cfg)
    _, k = _lead(sim)
    brakes = jnp.where(full[_I["lead_gap"]] < traffic.FAR, sim.car_brake[k], 0.0)
    values = {**{name: full[i] for name, i in _I.items()}, LEAD_BRAKES: brakes}
    return jnp.stack([values[name] for name in one_frame_names(cfg)]).astype(jnp.float32)


def _stop_needed(obs: jax.Array) -> jax.Array:
    """`[] bool`: the next stop line is one to stop at (red; amber when it can stop; a blocked junction)."""
    v, gap = obs[_I["speed"]], obs[_I["stop_gap"]]
    state = jnp.argmax(obs[_I["light_green"]:_I["light_red"] + 1])
    return (gap < traffic.FAR) & (traffic.must_stop(state, gap, v) | (obs[_I["junction_blocked"]] > 0))


def free_to_go(sim, cfg) -> jax.Array:
    """`[] bool`: nothing should keep the car standing: no stop line to stop at, no car within `FREE_GAP`
    ahead, no pedestrian in the way (what `stuck` counts standing still against)."""
    obs = features(sim, cfg)
    return ~_stop_needed(obs) & (obs[_I["lead_gap"]] > FREE_GAP) & (obs[_I["ped_gap"]] >= traffic.FAR)


def expert_action(full_obs: jax.Array, cfg) -> jax.Array:
    """The rule-based expert: `[24] full state -> [3] (steer, throttle, brake)` (module docstring).

    Steering: pure pursuit on the lane's centre at a lookahead of 2.5 m + 0.5 s of travel (4-12 m),
    interpolated between the full state's lane points. Speed: IDM (a_max 2 m/s², comfortable braking 3 m/s²,
    1.2 s headway) towards min(speed limit, the bend's speed at `A_LATERAL`), with the car ahead (3 m standstill
    gap), the stop line (1 m) and a pedestrian in the way (2.5 m) as leaders. Deterministic, pure, jit- and
    vmap-able.
    """
    o = {name: full_obs[i] for name, i in _I.items()}
    v = o["speed"]
    # pure pursuit: the lane point at the lookahead, then the arc through it
    pts = full_obs[_I["lane_x4"]:_I["lane_y16"] + 1].reshape(len(LOOKAHEAD), 2)
    look = jnp.clip(2.5 + 0.5 * v, LOOKAHEAD[0], 12.0)
    pos = (look - LOOKAHEAD[0]) / (LOOKAHEAD[1] - LOOKAHEAD[0])
    k = jnp.clip(jnp.floor(pos).astype(jnp.int32), 0, len(LOOKAHEAD) - 2)
    frac = pos - k
    target = pts[k] * (1 - frac) + pts[k + 1] * frac
    curvature = 2.0 * target[1] / jnp.maximum(jnp.sum(target * target), 1.0)
    steer = jnp.clip(jnp.arctan(cfg.wheelbase * curvature) / cfg.max_steer, -1.0, 1.0)
    # IDM towards the speed the bend allows, with the obstacles as leaders
    v_want = jnp.minimum(cfg.speed_limit, jnp.sqrt(A_LATERAL / jnp.maximum(o["curvature_ahead"], 1e-4)))
    gaps = jnp.stack([o["lead_gap"], o["stop_gap"], o["ped_gap"]])
    speeds = jnp.stack([o["lead_speed"], 0.0, 0.0])
    on = jnp.stack([o["lead_gap"] < traffic.FAR, _stop_needed(full_obs), o["ped_gap"] < traffic.FAR])
    accel = traffic.idm(v, v_want, gaps, speeds, jnp.array([traffic.GAP_CAR, traffic.GAP_LINE, traffic.GAP_PED]), on)
    # the pedals that give that acceleration (rolling resistance acts on a moving car)
    need = accel + cfg.rolling_resistance * (v > 0)
    throttle = jnp.clip(need / cfg.throttle_accel, 0.0, 1.0)
    brake = jnp.clip(-need / cfg.brake_accel, 0.0, 1.0)
    return jnp.stack([steer, throttle, brake]).astype(jnp.float32)


def episode_metrics(initial, final, valid: jax.Array, cfg) -> dict[str, jax.Array]:
    """NoCrash's metrics of one episode, `[] float32` each (`METRICS`; vmap over episodes for a batch).

    Args:
      initial: the simulator state at reset (`envs.toytown.ToyTownSim`, fields unbatched).
      final: the state after the episode's last step (the rollout freezes it at `done`).
      valid: `[T] float32`, 1 for the steps inside the episode.
      cfg: the environment's settings.
    """
    crashed = jnp.maximum(jnp.maximum(final.hit_car, final.hit_pedestrian), final.off_road)
    steps = jnp.maximum(jnp.sum(valid.astype(jnp.float32)), 1.0)
    travelled = final.s - initial.s
    return {
        "success": final.goal * (1.0 - crashed),
        "route_completion": jnp.clip(travelled / (cfg.route_length - initial.s), 0.0, 1.0),
        "collisions": crashed,
        "collisions_vehicle": final.hit_car,
        "collisions_pedestrian": final.hit_pedestrian,
        "collisions_offroad": final.off_road,
        "red_light_violations": final.red_lights,
        "timeout": (1.0 - final.goal) * (1.0 - crashed),
        "stuck": final.stuck,
        "avg_speed": travelled / (steps * cfg.dt),
    }
