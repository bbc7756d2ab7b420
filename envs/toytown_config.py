"""ToyTown's settings: `ToyTownConfig`, NoCrash's traffic conditions (`TRAFFIC`) and the task versions
(`TASK_VERSION`, `VERSIONS`: what the camera shows, `envs.toytown`'s docstring). A frozen record whose defaults are
the task's, fixed before any imitator was trained on it (docs/design.md); `envs.make("toytown", key=value)` overrides
them, and `__post_init__` refuses a value out of range in one line."""

from __future__ import annotations

import dataclasses
import math

from envs import toytown_traffic as traffic
from envs import toytown_world as world
from envs.toytown_expert import FEATURES, one_frame_names


# NoCrash's traffic conditions: (route cars per 100 m per lane, pedestrians per 100 m of route)
TRAFFIC = {"empty": (0.0, 0.0), "regular": (1.0, 1.0), "dense": (2.5, 2.5)}
SPLITS = ("train", "test")
TASK_VERSION = 2  # what the camera shows (module docstring); VERSIONS lists those that can be made
VERSIONS = (1, 2)


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
