"""ToyTown's other road users: cars in the route's two lanes, cars on the cross streets, pedestrians.

Everything moves in route coordinates (`envs.toytown_world`: `s` along the route, `d` to its left), so a
car keeps its lane round every bend without steering. All cars drive by the Intelligent Driver Model
(Treiber, Hennecke and Helbing, 2000): a free-road term towards the car's own desired speed and, for
each obstacle ahead, a braking term that keeps a standstill gap `s0` and a time headway. Obstacles are
the car ahead in the lane (the ego car included), the stop line of a red light (or an amber one the
car can still stop for), a pedestrian in the lane, a junction a crossing car is in, and now and then
a stop of the car's own (a random hesitation of a few seconds). Pedestrians wait on the sidewalk and
now and then cross, only while no car is close, and stop short of a car in their way.

Route cars wrap round: one leaving the road's far end comes back at the other, so the traffic density
stays as it was set. Cross-street cars drive across, then wait a random time out of sight and come
again. Cars never collide with each other by construction (their gaps), so only the ego's collisions
are counted (`envs.toytown`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

CAR_LENGTH, CAR_WIDTH = 4.5, 2.0  # every car's size, m
PED_HALF = 0.35  # a pedestrian's half size, m
MARGIN = 40.0  # route cars drive this far beyond both ends of the route before wrapping round
CROSS_REACH = 40.0  # cross-street cars drive from this far on one side to this far on the other
A_MAX, B_COMF, HEADWAY = 2.0, 3.0, 1.2  # IDM: acceleration, comfortable braking (m/s²), time headway (s)
B_AMBER = 4.0  # a car stops for an amber light when it can with at most this braking, m/s²
GAP_CAR, GAP_LINE, GAP_PED = 3.0, 1.0, 2.5  # IDM standstill gaps to a car, a stop line, a pedestrian, m
FAR = 40.0  # the gap reported when there is no obstacle, m
NEVER = 1e9  # the wait of a cross-street car that never comes (no cross traffic), s
NOWHERE = -1e4  # where inactive route cars and pedestrians are kept, m of route
BRAKE_DECEL = 0.5  # a car whose speed falls faster than this (m/s²) shows its brake lights
STANDING = 0.1  # a car slower than this (m/s) stands, and shows its brake lights too


def idm(v, v0, gaps, v_obstacles, s0, active):
    """IDM acceleration `[...]` of cars at speed `v` (`[...]`) wanting `v0`, with obstacles `[..., K]` at
    bumper gaps `gaps` moving at `v_obstacles` (each with standstill gap `s0` and on where `active`)."""
    dv = v[..., None] - v_obstacles
    s_star = s0 + jnp.maximum(0.0, v[..., None] * HEADWAY + v[..., None] * dv / (2 * jnp.sqrt(A_MAX * B_COMF)))
    brake = jnp.max(jnp.where(active, (s_star / jnp.maximum(gaps, 0.1)) ** 2, 0.0), axis=-1)
    return A_MAX * (1.0 - (v / jnp.maximum(v0, 0.1)) ** 4 - brake)


def must_stop(state, gap, v):
    """Whether a car `gap` metres before a stop line at speed `v` stops for a light in `state`: on red, and on
    amber when it can stop with `B_AMBER` (a car that cannot goes on, and crosses before the red)."""
    from envs.toytown_world import AMBER, RED

    return (state == RED) | ((state == AMBER) & (gap >= v * v / (2 * B_AMBER)))


def stop_line_ahead(inter_s, q_front, direction, lane_width):
    """`(gap, j)`: the gap from a front at progress `q_front` (`[...]`, along `direction` ±1) to the next stop
    line ahead (1 m before the cross street), and the intersection's index; `FAR` where none is ahead."""
    q_line = direction[..., None] * inter_s - (lane_width + 1.0)  # [..., n] each direction's line, in progress
    gap = q_line - q_front[..., None]
    ahead = gap > -0.5  # a car standing on its line still sees it
    j = jnp.argmin(jnp.where(ahead, gap, jnp.inf), axis=-1)
    g = jnp.take_along_axis(gap, j[..., None], -1)[..., 0]
    return jnp.where(jnp.any(ahead, axis=-1), g, FAR), j


def braking(v_before, v_after, dt) -> jax.Array:
    """Brake lights, `[...] float32` 0/1: on while a car brakes (its speed falls faster than `BRAKE_DECEL`) or
    stands (slower than `STANDING`), as real cars and CARLA's show them. Speeds `[...]` a step `dt` apart."""
    return ((v_after < v_before - BRAKE_DECEL * dt) | (v_after < STANDING)).astype(jnp.float32)


def lane_d(lane, lane_width):
    """The lateral offset of lane `lane` (0: the ego's, along the route; 1: the oncoming one)."""
    return jnp.where(lane > 0, 0.5, -0.5) * lane_width


def step_cars(cars: dict, ego: dict, peds: dict, inter_s, route_state, blocked, key, cfg) -> dict:
    """One step of the route cars.

    Args:
      cars: `car_*` fields, `[N]` each (`s`, `v`, `lane`, `v0`, `stop`, `active`).
      ego: `s`, `d`, `v` of the ego car, `[]`.
      peds: `ped_*` fields, `[P]`.
      inter_s: `[n]` the intersections' arc lengths.
      route_state: `[n]` the route's lights (`toytown_world.route_phase`).
      blocked: `[n]` a cross-street car is in the junction.
      key: PRNG key of the random stops.
      cfg: `ToyTownConfig`.

    Returns:
      The new `car_*` fields.
    """
    s, v, lane, v0, stop, active = (cars[f"car_{k}"] for k in ("s", "v", "lane", "v0", "stop", "active"))
    w = cfg.lane_width
    direction = 1.0 - 2.0 * lane
    q = direction * s
    # the car ahead in the same lane
    same = (lane[:, None] == lane[None, :]) & (active[None, :] > 0)
    ahead = q[None, :] - q[:, None]
    gap_cars = jnp.where(same & (ahead > 0), ahead - CAR_LENGTH, jnp.inf)
    lead = jnp.argmin(gap_cars, axis=1)
    gap_car = jnp.min(gap_cars, axis=1)
    v_lead = v[lead]
    # the ego, where it is in this lane
    ego_in = jnp.abs(ego["d"] - lane_d(lane, w)) < 0.5 * w + 0.5 * CAR_WIDTH - 0.3
    gap_ego = direction * ego["s"] - q - CAR_LENGTH
    use_ego = ego_in & (gap_ego > -CAR_LENGTH) & (gap_ego < gap_car)
    gap_car = jnp.where(use_ego, jnp.maximum(gap_ego, 0.0), gap_car)
    v_lead = jnp.where(use_ego, direction * ego["v"], v_lead)
    # lights, and junctions a cross-street car is in
    gap_line, j = stop_line_ahead(inter_s, q + CAR_LENGTH / 2, direction, w)
    stop_line = (gap_line < FAR) & (must_stop(route_state[j], gap_line, v) | (blocked[j] & (gap_line > 0)))
    # pedestrians in the lane ahead
    g_ped, _ = pedestrian_gaps(peds, q + CAR_LENGTH / 2, direction, w)
    gaps = jnp.stack([gap_car, gap_line, g_ped], -1)
    speeds = jnp.stack([v_lead, jnp.zeros_like(v), jnp.zeros_like(v)], -1)
    on = jnp.stack([gap_car < FAR, stop_line, g_ped < FAR], -1)
    a = idm(v, v0, gaps, speeds, jnp.array([GAP_CAR, GAP_LINE, GAP_PED]), on)
    # a random stop: brake to a standstill, stand for `stop` seconds
    k_go, k_len = jax.random.split(key)
    start = (jax.random.uniform(k_go, s.shape) < cfg.car_stop_rate * cfg.dt) & (stop <= 0) & (v > 1.0)
    stop = jnp.where(start, jax.random.uniform(k_len, s.shape, minval=cfg.car_stop_seconds[0],
                                               maxval=cfg.car_stop_seconds[1]), stop)
    a = jnp.where(stop > 0, jnp.minimum(a, -B_COMF), a)
    stop = jnp.where((stop > 0) & (v < 0.1), stop - cfg.dt, stop)
    v_new = jnp.clip(v + a * cfg.dt, 0.0, 1.2 * v0)
    s_new = s + direction * v_new * cfg.dt
    span = cfg.route_length + 2 * MARGIN
    s_new = jnp.where(s_new > cfg.route_length + MARGIN, s_new - span, s_new)
    s_new = jnp.where(s_new < -MARGIN, s_new + span, s_new)
    moved = active > 0
    return {"car_s": jnp.where(moved, s_new, s), "car_v": jnp.where(moved, v_new, 0.0), "car_lane": lane,
            "car_v0": v0, "car_stop": stop, "car_active": active}


def pedestrian_gaps(peds, q_front, direction, w):
    """`([N] gap, [N] index)`: from each front (progress `q_front` along `direction`) to the nearest pedestrian
    ahead who is crossing and on the road (either lane: a car waits until the crossing is done, so no one waits
    for the other); `FAR` where none."""
    on_road = (peds["ped_walking"] > 0) & (jnp.abs(peds["ped_d"]) < w + 0.5) & (peds["ped_active"] > 0)
    gap = direction[:, None] * peds["ped_s"][None, :] - q_front[:, None] - PED_HALF
    gaps = jnp.where(on_road[None, :] & (gap > -1.0) & (gap < FAR), jnp.maximum(gap, 0.0), FAR)
    return jnp.min(gaps, axis=1), jnp.argmin(gaps, axis=1)


def crossing_place(s, inter_s, w):
    """`s` moved off the junctions: a pedestrian crosses the route between intersections, not in a junction
    (where the cross street's cars drive)."""
    near = jnp.abs(s[:, None] - inter_s[None, :]) < w + 3.0
    return s + jnp.any(near, axis=1) * (2 * w + 6.0)


def step_cross(cross: dict, cross_state, occupied, key, cfg) -> dict:
    """One step of the cross-street cars, `[n, 2]` per field (`u`: progress along the cross street, `v`,
    `wait`: seconds left out of sight before it comes again, ~forever where there is no cross traffic; slot 0
    drives to the route's left, slot 1 to its right). `occupied` `[n]`: a route car is in the junction."""
    u, v, wait = cross["cross_u"], cross["cross_v"], cross["cross_wait"]
    w = cfg.lane_width
    gap = -(w + 1.0) - (u + CAR_LENGTH / 2)  # to the stop line, 1 m before the route's road
    state = jnp.broadcast_to(cross_state[:, None], u.shape)
    stop = (gap > -0.5) & (must_stop(state, gap, v) | occupied[:, None])
    a = idm(v, jnp.full_like(v, cfg.cross_speed), jnp.maximum(gap, 0.0)[..., None], jnp.zeros_like(v)[..., None],
            jnp.array([GAP_LINE]), stop[..., None])
    waiting = wait > 0
    v_new = jnp.where(waiting, 0.0, jnp.clip(v + a * cfg.dt, 0.0, cfg.cross_speed))
    u_new = jnp.where(waiting, u, u + v_new * cfg.dt)
    done = u_new > CROSS_REACH
    again = jax.random.uniform(key, u.shape, minval=cfg.cross_wait[0], maxval=cfg.cross_wait[1])
    again = jnp.where(wait > NEVER / 2, NEVER, again)
    return {"cross_u": jnp.where(done, -CROSS_REACH, u_new),
            "cross_v": jnp.where(done, cfg.cross_speed, v_new),
            "cross_wait": jnp.where(done, again, jnp.maximum(wait - cfg.dt, 0.0))}


def junction_blocked(cross_u, cross_wait, lane_width) -> jax.Array:
    """`[n] bool`: a cross-street car is past its stop line and not yet off the route's road."""
    front, rear = cross_u + CAR_LENGTH / 2, cross_u - CAR_LENGTH / 2
    return jnp.any((front > -(lane_width + 1.0)) & (rear < lane_width) & (cross_wait <= 0), axis=1)


def cross_position(cross_u, inter_s, lane_width):
    """`(s, d)` of each cross-street car, `[n, 2]`: slot 0 in the lane at `s_j + w/2` driving to the left (+d),
    slot 1 at `s_j - w/2` driving to the right."""
    side = jnp.array([1.0, -1.0])
    return inter_s[:, None] + side * 0.5 * lane_width, side * cross_u


def step_peds(peds: dict, ego: dict, cars: dict, inter_s, key, cfg) -> dict:
    """One step of the pedestrians, `[P]` per field (`s`, `d`, `dir` ±1: the way they cross, `walking`,
    `speed`, `wait`: seconds before they set off).

    A pedestrian sets off only when no car (the ego included) is within `ped_clear_distance` of its path
    coming, or on it; cars yield to anyone crossing, so once off it never meets a car on its path (it would
    stop short of one, a last resort)."""
    s, d, direction, walking, speed, wait = (peds[f"ped_{k}"] for k in ("s", "d", "dir", "walking", "speed",
                                                                         "wait"))
    w, kerb = cfg.lane_width, cfg.lane_width + 1.0
    car_s = jnp.concatenate([cars["car_s"], ego["s"][None]])
    car_d = jnp.concatenate([lane_d(cars["car_lane"], w), ego["d"][None]])
    car_dir = jnp.concatenate([1.0 - 2.0 * cars["car_lane"], jnp.ones(1)])
    car_on = jnp.concatenate([cars["car_active"], jnp.ones(1)]) > 0
    on = peds["ped_active"] > 0
    # a car coming within `ped_clear_distance`, or passing: do not set off
    upstream = car_dir[None, :] * (s[:, None] - car_s[None, :])  # > 0: the car has yet to pass
    close = jnp.any(car_on[None, :] & (upstream > -CAR_LENGTH) & (upstream < cfg.ped_clear_distance), axis=1)
    set_off = on & (walking <= 0) & (wait <= 0) & ~close
    walking = jnp.where(set_off, 1.0, walking)
    d_next = d + direction * speed * cfg.dt
    # stop short of a car in the way
    in_way = (car_on[None, :] & (jnp.abs(s[:, None] - car_s[None, :]) < CAR_LENGTH / 2 + PED_HALF)
              & (jnp.abs(d_next[:, None] - car_d[None, :]) < CAR_WIDTH / 2 + PED_HALF))
    move = (walking > 0) & ~jnp.any(in_way, axis=1)
    d = jnp.where(move, d_next, d)
    wait = jnp.where(walking > 0, wait, wait - cfg.dt)
    # across, or left far behind the ego while waiting: come again ahead of the ego, out of sight
    across = (walking > 0) & (direction * d >= kerb)
    behind = (walking <= 0) & (s < ego["s"] - 20.0)
    again = on & (across | behind)
    k_s, k_dir, k_wait, k_speed = jax.random.split(key, 4)
    new_dir = jnp.where(jax.random.uniform(k_dir, s.shape) < 0.5, -1.0, 1.0)
    ahead = crossing_place(ego["s"] + jax.random.uniform(k_s, s.shape, minval=35.0, maxval=110.0), inter_s, w)
    return {"ped_s": jnp.where(again, ahead, s),
            "ped_d": jnp.where(again, -new_dir * kerb, d),
            "ped_dir": jnp.where(again, new_dir, direction),
            "ped_walking": jnp.where(again, 0.0, walking),
            "ped_speed": jnp.where(again, jax.random.uniform(k_speed, s.shape, minval=1.1, maxval=1.6), speed),
            "ped_wait": jnp.where(again, jax.random.uniform(k_wait, s.shape, minval=cfg.ped_wait[0],
                                                            maxval=cfg.ped_wait[1]), wait),
            "ped_active": peds["ped_active"]}
