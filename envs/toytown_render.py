"""ToyTown's camera: an ego-centric top-down view, rotated with the car, rendered inside `jit`.

The car points up and sits `view_behind` metres above the bottom edge; the view reaches `view_ahead`
metres ahead, with square pixels. Every pixel is classified in route coordinates (`s`, `d`): the
route's road and its sidewalks, the cross street of the nearest intersection, the lane edges, the
dashed centre line (3 m dashes every 6 m: they scroll past, so speed shows between frames and not in
one frame), the stop lines, the traffic lights' lamps (red, amber or green, on the corners before the
junction), cars, pedestrians and the ego car, each class its own colour (`PALETTES`; `weather="test"`
swaps the palette for a held-out one, NoCrash's "new weather").

Why route coordinates: projecting every pixel onto the route is the expensive part, and the mapping
from the image to (s, d) is smooth near the road, so it is computed exactly on a coarse grid (cells of
`COARSE_METRES`, 8 pixels at 64×64; each coarse point's nearest centreline sample, refined along its
tangent) and interpolated bilinearly to the pixels (within ~0.2 m on the tightest bend). Cars and
pedestrians are then boxes aligned with (s, d), a few comparisons per pixel, and the ego car is a
constant mask. Thin features are at least a pixel wide, so they survive 16×16. A frame costs about a
third of ToyCar's 128×128 one (`docs/speed.md`); the comments say which XLA:CPU habits that needed.

The measurement strip (`speed_input`): the top `strip_rows(h)` rows show the car's speed as a grey
level (`255 · v / SPEED_SCALE`, clipped); without the speed input they are black, so the frames of the
two settings differ only there. A policy reads the speed from the frame itself: the learner takes one
array per observation.

What the camera shows depends on the task version (`task_version`, `envs.toytown`). Version 2: cars show
brake lights (the last `brake_length` metres of a car, its rear, in their own colour) while they brake or
stand, so one frame tells a queue from moving traffic; and the strip sits above the scene, which spans the
rows below it, so the whole `view_ahead` the expert reacts to is in view. Version 1 (the first tables'): no
brake lights, and the strip drawn over the scene's farthest rows.
"""

from __future__ import annotations

import functools

import numpy as np

import jax
import jax.numpy as jnp

from envs import toytown_world as world
from envs.toytown_traffic import CAR_LENGTH, CAR_WIDTH, PED_HALF, cross_position

SPEED_SCALE = 12.0  # m/s shown as a white measurement strip
CARS_DRAWN, PEDS_DRAWN = 8, 4  # the route cars and pedestrians nearest the view's middle that are drawn
COARSE_METRES = 4.5  # the (s, d) grid's cells, m
LANE_SHIFT = 1e5  # lane 1's cars and pixels are drawn at s + this (an s no route reaches)

GRASS, SIDEWALK, ROAD, MARK, LAMP_RED, LAMP_AMBER, LAMP_GREEN, CAR, PEDESTRIAN, EGO, BRAKE_LIGHT = range(11)
CLASS_NAMES = ("grass", "sidewalk", "road", "marking", "red", "amber", "green", "car", "pedestrian", "ego",
               "brake light")
# one colour per class (rows in the order above), 0-255
PALETTES = {
    # a clear day
    "train": np.array([[92, 140, 71], [158, 153, 143], [84, 84, 89], [242, 242, 242], [230, 26, 26],
                       [250, 191, 13], [26, 217, 51], [38, 89, 217], [230, 64, 200], [0, 230, 230],
                       [170, 0, 40]], np.uint8),
    # held out ("new weather"): a wet dusk, darker ground and asphalt, warmer lamps, other paint
    "test": np.array([[58, 78, 52], [112, 104, 100], [46, 48, 58], [205, 205, 178], [255, 60, 40],
                      [255, 160, 30], [60, 240, 120], [110, 70, 200], [255, 120, 120], [0, 230, 230],
                      [255, 20, 90]], np.uint8),
}


def strip_rows(height: int) -> int:
    """Rows of the measurement strip at the top of a frame `height` pixels high (2 at 16-32 px, 4 at 64)."""
    return max(2, height // 16)


def scene_top(cfg) -> int:
    """The first row of the scene: `strip_rows` from task version 2 (the strip above it), 0 before (over it)."""
    return strip_rows(cfg.image_size[0]) if cfg.task_version >= 2 else 0


def brake_length(mpp: float) -> float:
    """Metres of a car's rear drawn as its brake lights: at least two pixels, at most a third of the car."""
    return float(min(max(1.0, 2 * mpp), CAR_LENGTH / 3))


def coarse_factor(mpp: float) -> int:
    """Pixels per coarse cell: cells of about `COARSE_METRES` whatever the image size (1 to 16 pixels)."""
    return int(np.clip(round(COARSE_METRES / mpp), 1, 16))


def _upsample(coarse: jax.Array, axis: int, n: int, factor: int) -> jax.Array:
    """Linear interpolation along `axis` from coarse points at pixel coordinates `factor·k − 0.5` to the `n`
    pixel centres (pixel i at coordinate i). Each pixel lies at one of `factor` fixed fractions between two
    coarse points, so it is `factor` weighted sums and a reshape: no gather (slow on XLA:CPU)."""
    x = jnp.moveaxis(coarse, axis, -1)
    frac = (jnp.arange(factor, dtype=jnp.float32) + 0.5) / factor
    fine = x[..., :-1, None] * (1.0 - frac) + x[..., 1:, None] * frac  # [..., K, factor]
    return jnp.moveaxis(fine.reshape(*fine.shape[:-2], -1)[..., :n], -1, axis)


def camera(cfg):
    """The static parts of the camera: metres per pixel, pixels per coarse cell, the coarse grid's forward and
    left offsets from the car (`[ceil(H / factor) + 1]`, `[ceil(W / factor) + 1]`), and the ego car's pixel
    mask `[H, W] bool`. The scene spans rows `scene_top(cfg)` to `H`: `view_ahead + view_behind` metres."""
    h, w = cfg.image_size
    top = scene_top(cfg)
    mpp = (cfg.view_ahead + cfg.view_behind) / (h - top)
    factor = coarse_factor(mpp)
    rows = factor * np.arange(-(-h // factor) + 1) - 0.5  # coarse points' pixel coordinates
    cols = factor * np.arange(-(-w // factor) + 1) - 0.5
    forward = (cfg.view_ahead - (rows - top + 0.5) * mpp).astype(np.float32)  # row coordinate -> metres ahead
    left = (mpp * w / 2 - (cols + 0.5) * mpp).astype(np.float32)  # column coordinate -> metres to the left
    f_px = cfg.view_ahead - (np.arange(h) - top + 0.5) * mpp
    l_px = mpp * w / 2 - (np.arange(w) + 0.5) * mpp
    ego = ((np.abs(f_px)[:, None] <= max(CAR_LENGTH / 2, mpp / 2))
           & (np.abs(l_px)[None, :] <= max(CAR_WIDTH / 2, mpp / 2)))
    return mpp, factor, forward, left, ego


def _packed(rgb: np.ndarray) -> np.ndarray:
    """Colours `[..., 3]` as uint32 whose bytes in memory are R, G, B, 255, so that a bitcast to 4 bytes gives the
    channels. The classes are composed as one integer per pixel: XLA fuses the composition into its consumer
    per output element, and would compose each pixel three times for three uint8 channels (and a palette
    lookup would be a gather per pixel)."""
    p = rgb.astype(np.uint32)
    little = (p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16) | (255 << 24)).astype(np.uint32)
    big = ((p[..., 0] << 24) | (p[..., 1] << 16) | (p[..., 2] << 8) | 255).astype(np.uint32)
    return little if _little_endian() else big


@functools.cache
def _little_endian() -> bool:
    """Whether `lax.bitcast_convert_type` puts a uint32's low byte first (it does on CPUs and GPUs)."""
    with jax.ensure_compile_time_eval():  # asked while tracing a frame: run it now, not in the traced program
        return int(np.asarray(jax.lax.bitcast_convert_type(jnp.array([1], jnp.uint32), jnp.uint8))[0, 0]) == 1


def render(sim, cfg) -> jax.Array:
    """The camera's frame of simulator state `sim` (`envs.toytown.ToyTownSim`): `[H, W, 3] uint8`."""
    mpp, factor, forward, left, ego_mask = camera(cfg)
    h, w_px = cfg.image_size
    colour = _packed(PALETTES[cfg.weather])
    c, s_ = jnp.cos(sim.yaw), jnp.sin(sim.yaw)
    gx = sim.x + forward[:, None] * c - left[None, :] * s_
    gy = sim.y + forward[:, None] * s_ + left[None, :] * c
    cs, cd = world.project(sim.route, gx, gy, sim.s, cfg.view_behind + 20.0, cfg.view_ahead + 20.0, 2.0)
    lerp = lambda g: _upsample(_upsample(g, 0, h, factor), 1, w_px, factor)  # noqa: E731
    S, D = lerp(cs), lerp(cd)  # [H, W] route coordinates of each pixel
    w = cfg.lane_width
    middle = sim.s + (cfg.view_ahead - cfg.view_behind) / 2
    j = jnp.argmin(jnp.abs(sim.inter_s - middle))  # the one intersection in view (they are >= 60 m apart)
    ds = S - sim.inter_s[j]
    ad, ads = jnp.abs(D), jnp.abs(ds)
    ahead_side = ds * D > 0  # the quarter of the junction before it on the right, and its mirror image
    line = max(0.15, 0.5 * mpp)  # half-width of painted lines: at least a pixel wide
    nearest = jnp.minimum(ad, ads)  # distance from the nearer road's centre line
    code = jnp.where(nearest < w, colour[ROAD], jnp.where(nearest < w + 2.0, colour[SIDEWALK], colour[GRASS]))
    code = code.astype(jnp.uint32)
    dash = (ad < line) & (S * (1 / 6.0) - jnp.floor(S * (1 / 6.0)) < 0.5)  # 3 m of every 6 m
    edge = jnp.abs(ad - (w - 0.3)) < line
    stop = (jnp.abs(ads - (w + 1.0)) < line) & (ad < w) & ahead_side
    code = jnp.where(((dash | edge) & (ads > w + 2.0)) | stop, colour[MARK], code)
    # route cars: a box in their lane's band; lane 1 is shifted far along s, so one comparison of s per car
    # tells both the place and the lane
    n_cars = min(CARS_DRAWN, sim.car_s.shape[0])
    _, near = jax.lax.top_k(-jnp.abs(sim.car_s - middle), n_cars)
    key = sim.car_s[near] + LANE_SHIFT * sim.car_lane[near]
    S_lane = S + LANE_SHIFT * (D > 0)
    car = jnp.abs(ad - 0.5 * w) < CAR_WIDTH / 2
    along = jnp.abs(S_lane - key[0]) < CAR_LENGTH / 2
    for k in range(1, n_cars):
        along |= jnp.abs(S_lane - key[k]) < CAR_LENGTH / 2
    xs, xd = cross_position(sim.cross_u[j][None], sim.inter_s[j][None], w)
    cross = jnp.zeros(S.shape, bool)
    for k in range(2):
        cross |= (jnp.abs(S - xs[0, k]) < CAR_WIDTH / 2) & (jnp.abs(D - xd[0, k]) < CAR_LENGTH / 2)
    code = jnp.where((car & along) | cross, colour[CAR], code)
    if cfg.task_version >= 2:  # brake lights: each braking or standing car's rear (a lane-1 car drives towards -s)
        half = brake_length(mpp) / 2
        rear = key - (1.0 - 2.0 * sim.car_lane[near]) * (CAR_LENGTH / 2 - half)
        lit = jnp.zeros(S.shape, bool)
        for k in range(n_cars):
            lit |= (jnp.abs(S_lane - rear[k]) < half) & (sim.car_brake[near[k]] > 0)
        lit &= car
        side = np.array([1.0, -1.0])  # cross slot 0 drives towards +d, slot 1 towards -d
        for k in range(2):
            lit |= ((jnp.abs(S - xs[0, k]) < CAR_WIDTH / 2) & (sim.cross_brake[j, k] > 0)
                    & (jnp.abs(D - (xd[0, k] - side[k] * (CAR_LENGTH / 2 - half))) < half))
        code = jnp.where(lit, colour[BRAKE_LIGHT], code)
    ped_half = max(PED_HALF, 0.75 * mpp)  # at least a pixel whatever the angle
    n_peds = min(PEDS_DRAWN, sim.ped_s.shape[0])
    _, near = jax.lax.top_k(-jnp.abs(sim.ped_s - middle), n_peds)
    ped = jnp.zeros(S.shape, bool)
    for k in range(n_peds):
        ped |= (jnp.abs(S - sim.ped_s[near[k]]) < ped_half) & (jnp.abs(D - sim.ped_d[near[k]]) < ped_half)
    code = jnp.where(ped, colour[PEDESTRIAN], code)
    # the lamps, on the sidewalk's corner to the right before the junction, for each direction
    lamp_half = max(0.8, 0.75 * mpp)
    lamp = (jnp.abs(ads - (w + 2.0)) < lamp_half) & (jnp.abs(ad - (w + 1.2)) < lamp_half) & ahead_side
    state, _ = world.route_phase(sim.lights, sim.t * cfg.dt, cfg.amber_seconds)
    lit = jnp.asarray(colour[[LAMP_GREEN, LAMP_AMBER, LAMP_RED]])[state[j]]
    code = jnp.where(lamp, lit, code)
    code = jnp.where(ego_mask, colour[EGO], code)
    # the measurement strip: grey as light as the speed is high, or black
    level = (jnp.round(255.0 * jnp.clip(sim.v / SPEED_SCALE, 0.0, 1.0)).astype(jnp.uint32) if cfg.speed_input
             else jnp.zeros((), jnp.uint32))
    grey = jnp.asarray(_packed(np.zeros(3))) + level * jnp.asarray(_packed(np.ones(3)) - _packed(np.zeros(3)))
    code = jnp.where((np.arange(h) < strip_rows(h))[:, None], grey, code)  # over the scene's top (version 1)
    return jax.lax.bitcast_convert_type(code, jnp.uint8)[..., :3]
