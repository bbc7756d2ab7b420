"""ToyTown's world: the route a layout seed generates, its geometry, and the traffic lights' timing.

The route is a road of `route_length` metres cut into `intersections + 1` blocks of equal length; a
signalised intersection sits at each block boundary. Each block is a straight, a circular bend and a
straight: the straights keep at least `STRAIGHT` metres of straight road on each side of every
intersection (so its cross street meets the route at a right angle and cars stop on a straight), and
the bend turns by 20 to 45 degrees, left or right, while the route's heading stays within
`MAX_HEADING` of its start (so the road never comes back near itself). The route is a table of
pieces of constant curvature (`Route`); a point at arc length s is in closed form, so nothing is
sampled densely and the whole route is 5 numbers per piece.

Coordinates: `s` is the arc length along the route's centreline (0 at the start, `route_length` at the
goal; the first and last straights extend beyond both ends), `d` the signed lateral offset from the
centreline, positive to the left. Traffic drives on the right: the ego lane's centre is at
`d = -lane_width / 2`, the oncoming lane's at `+lane_width / 2`.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import struct

STRAIGHT = 20.0  # metres of straight road at least on each side of an intersection, and at both ends
MIN_BEND = 20.0  # the shortest bend, metres of arc
MIN_BLOCK = 2 * STRAIGHT + MIN_BEND  # so a route of n intersections is at least (n + 1) × 60 m
BEND_DEGREES = (20.0, 45.0)  # a bend's turn, each way
MAX_HEADING = math.radians(60.0)  # the route's heading stays within this of its start


@struct.dataclass
class Route:
    """A route's pieces of constant curvature, `[P]` float32 each (P = 2 × blocks + 1).

    Attributes:
      s0: arc length at each piece's start, m (`s0[0] = 0`).
      x0, y0: the piece's start point in the world, m.
      h0: the heading at its start, rad.
      kappa: its curvature, 1/m (0 on straights, positive turning left).
    """

    s0: jax.Array
    x0: jax.Array
    y0: jax.Array
    h0: jax.Array
    kappa: jax.Array


def num_pieces(intersections: int) -> int:
    return 2 * (intersections + 1) + 1


def make_route(layout: jax.Array, route_length: float, intersections: int) -> tuple[Route, jax.Array]:
    """The route of layout seed `layout` (`[] int32`), traceable.

    Returns:
      `(route, inter_s)`: the `Route` and the intersections' arc lengths, `[intersections] float32`.
    """
    blocks = intersections + 1
    block = route_length / blocks
    slack = block - MIN_BLOCK  # what the block's straights and bend share beyond their minimum lengths
    key = jax.random.PRNGKey(layout)
    k_a, k_b, k_turn, k_sign = jax.random.split(key, 4)
    # each block: straight a (≥ STRAIGHT), bend, straight b (≥ STRAIGHT); a share of the slack goes to each
    a = STRAIGHT + jax.random.uniform(k_a, (blocks,)) * slack * 0.35
    b = STRAIGHT + jax.random.uniform(k_b, (blocks,)) * slack * 0.35
    bend = block - a - b
    turn = jnp.radians(jax.random.uniform(k_turn, (blocks,), minval=BEND_DEGREES[0], maxval=BEND_DEGREES[1]))
    signs = jnp.where(jax.random.uniform(k_sign, (blocks,)) < 0.5, -1.0, 1.0)

    def choose(heading, i):  # flip a bend that would take the heading past MAX_HEADING
        sign = jnp.where(jnp.abs(heading + signs[i] * turn[i]) > MAX_HEADING, -signs[i], signs[i])
        return heading + sign * turn[i], sign

    _, sign = jax.lax.scan(choose, jnp.zeros(()), jnp.arange(blocks))
    # pieces: a_0, bend_0, (b_0 + a_1), bend_1, ..., (b_{n-1} + a_n), bend_n, b_n
    lengths, kappas = [a[0]], [jnp.zeros(())]
    for i in range(blocks):
        lengths += [bend[i], (b[i] + a[i + 1]) if i + 1 < blocks else b[i]]
        kappas += [sign[i] * turn[i] / bend[i], jnp.zeros(())]
    lengths, kappa = jnp.stack(lengths), jnp.stack(kappas)
    s0 = jnp.concatenate([jnp.zeros(1), jnp.cumsum(lengths)[:-1]])
    x, y, h = jnp.zeros(()), jnp.zeros(()), jnp.zeros(())
    xs, ys, hs = [], [], []
    for i in range(len(lengths)):
        xs.append(x), ys.append(y), hs.append(h)
        x, y, h = _advance(x, y, h, kappa[i], lengths[i])
    route = Route(s0=s0, x0=jnp.stack(xs), y0=jnp.stack(ys), h0=jnp.stack(hs), kappa=kappa)
    inter_s = block * jnp.arange(1, blocks, dtype=jnp.float32)
    return route, inter_s


def _advance(x, y, h, kappa, u):
    """The pose `u` metres along a piece of curvature `kappa` from pose (x, y, h): exact for arcs and lines
    (the chord has length u·sinc(κu/2) and heading h + κu/2)."""
    half = kappa * u / 2
    chord = u * jnp.sinc(half / jnp.pi)
    return x + chord * jnp.cos(h + half), y + chord * jnp.sin(h + half), h + 2 * half


def pose_at(route: Route, s: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """The centreline at arc lengths `s` (any shape): `(x, y, heading, curvature)`, each of `s`'s shape.

    Beyond both ends the first and last straights go on."""
    i = jnp.clip(jnp.sum(s[..., None] >= route.s0[1:], axis=-1), 0, route.s0.shape[0] - 1)
    u = s - route.s0[i]
    x, y, h = _advance(route.x0[i], route.y0[i], route.h0[i], route.kappa[i], u)
    return x, y, h, route.kappa[i]


def project(route: Route, px: jax.Array, py: jax.Array, s_guess: jax.Array, behind: float, ahead: float,
            step: float) -> tuple[jax.Array, jax.Array]:
    """Route coordinates `(s, d)` of world points `(px, py)` (any shape) near the route between
    `s_guess - behind` and `s_guess + ahead`.

    The nearest of the centreline's samples every `step` metres in that window, refined along its tangent,
    so `s` and `d` are exact on straights and within ~step²·κ/8 on bends. A point farther from the route
    than a bend's radius may take another part of the route's coordinates (nothing drawn there).
    """
    ss = s_guess + jnp.arange(-behind, ahead + step / 2, step, dtype=jnp.float32)
    sx, sy, sh, _ = pose_at(route, ss)
    c, s_ = jnp.cos(sh), jnp.sin(sh)
    # a running nearest sample, one sample at a time in a loop: elementwise work over the points, where an argmin
    # or a reduction over a samples axis runs as several slow passes on XLA:CPU; and a loop, not an unrolled
    # chain, because XLA would fuse an unrolled chain into each consumer of its result (each pixel's
    # interpolation reads four coarse points: it would project them again, for every pixel of every frame)
    def nearer(carry, sample):
        best, s_out, d_out = carry
        s_k, x_k, y_k, c_k, sin_k = sample
        dx, dy = px - x_k, py - y_k
        dist = dx * dx + dy * dy
        closer = dist < best
        return (jnp.where(closer, dist, best), jnp.where(closer, s_k + dx * c_k + dy * sin_k, s_out),
                jnp.where(closer, dy * c_k - dx * sin_k, d_out)), None

    start = jnp.full(jnp.shape(px), jnp.inf, jnp.float32), jnp.zeros(jnp.shape(px)), jnp.zeros(jnp.shape(px))
    (_, s_out, d_out), _ = jax.lax.scan(nearer, start, (ss, sx, sy, c, s_))
    return s_out, d_out


def curvature_ahead(route: Route, s: jax.Array, distance: float) -> jax.Array:
    """`[]` the largest |curvature| of the route over [s, s + distance] (samples every 2.5 m)."""
    _, _, _, kappa = pose_at(route, s + jnp.arange(0.0, distance + 1e-3, 2.5, dtype=jnp.float32))
    return jnp.max(jnp.abs(kappa))


# -- traffic lights ------------------------------------------------------------------------------------------
# Each intersection's light cycles: route green (G s), route amber (amber s), then route red (R s), during
# which the cross street has an all-red clearance, green, amber and a second clearance. G and R are drawn per
# intersection and episode, and the cycle starts at a random offset: random phases, amber always before red.
GREEN, AMBER, RED = 0, 1, 2


@struct.dataclass
class Lights:
    """`[n]` float32 each: per intersection, green and red durations (route direction) and the phase offset, s."""

    green: jax.Array
    red: jax.Array
    offset: jax.Array


def draw_lights(key: jax.Array, n: int, green_range, red_range, amber: float) -> Lights:
    k_g, k_r, k_o = jax.random.split(key, 3)
    green = jax.random.uniform(k_g, (n,), minval=green_range[0], maxval=green_range[1])
    red = jax.random.uniform(k_r, (n,), minval=red_range[0], maxval=red_range[1])
    offset = jax.random.uniform(k_o, (n,)) * (green + amber + red)
    return Lights(green, red, offset)


def route_phase(lights: Lights, seconds: jax.Array, amber: float) -> tuple[jax.Array, jax.Array]:
    """`(state, left)`: each intersection's light for the route at time `seconds`, `[n] int32` (`GREEN`,
    `AMBER`, `RED`), and the seconds left in that state, `[n] float32`."""
    cycle = lights.green + amber + lights.red
    tau = jnp.mod(seconds + lights.offset, cycle)
    state = jnp.where(tau < lights.green, GREEN, jnp.where(tau < lights.green + amber, AMBER, RED))
    left = jnp.where(state == GREEN, lights.green - tau,
                     jnp.where(state == AMBER, lights.green + amber - tau, cycle - tau))
    return state.astype(jnp.int32), left


def cross_phase(lights: Lights, seconds: jax.Array, amber: float, clearance: float) -> jax.Array:
    """`[n] int32`: each intersection's light for the cross street (`GREEN`, `AMBER`, `RED`): green and amber
    inside the route's red, with an all-red `clearance` before and after."""
    cycle = lights.green + amber + lights.red
    tau = jnp.mod(seconds + lights.offset, cycle)
    start, stop = lights.green + amber + clearance, cycle - clearance
    on = tau >= start
    state = jnp.where(on & (tau < stop - amber), GREEN, jnp.where(on & (tau < stop), AMBER, RED))
    return state.astype(jnp.int32)
