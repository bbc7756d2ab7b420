"""The sweep's own argument checks (`experiments.sweep`): its grids given on the command line, a
demonstration cache it would have to write, and what it asks for in updates and episodes (`cost`, against
`_cli.UPDATES_LIMIT` and `EPISODES_LIMIT`). Each refuses with one line and exit status 2 (`_cli.fail`)."""

from __future__ import annotations

import dataclasses
import math

from experiments._cli import EPISODES_LIMIT, UPDATES_LIMIT, fail, unwritable


def grid(p, flag: str, text: str, parse_one) -> tuple:
    """A comma list of settings, each parsed by `parse_one` (ValueError -> a one-line refusal)."""
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        fail(p, f"{flag} is empty")
    try:
        values = tuple(parse_one(t) for t in items)
    except ValueError as e:
        fail(p, f"{flag}: {e}")
    if len(set(values)) != len(values):
        fail(p, f"{flag} lists a setting twice")
    return values


def step_setting(text: str) -> tuple[float, float]:
    """One `THR:W` of `--step-grid`: THR in (0, 1), W a finite number >= 1."""
    thr, sep, w = text.partition(":")
    if not sep:
        raise ValueError(f"{text!r} is not THR:W (e.g. 0.1:5)")
    thr, w = float(thr), float(w)
    if not 0.0 < thr < 1.0:
        raise ValueError(f"THR must be in (0, 1), got {thr:g}")
    if not 1.0 <= w < math.inf:
        raise ValueError(f"W must be a finite number >= 1, got {w:g}")
    return thr, w


def temperature(text: str) -> float:
    """One temperature of `--softmax-grid`: a finite number > 0."""
    tau = float(text)
    if not 0.0 < tau < math.inf:
        raise ValueError(f"tau must be a finite number > 0, got {tau:g}")
    return tau


def demonstrations_writable(spec) -> None:
    """Refuses, before --out is touched, a sweep that must collect its demonstrations (none cached in its
    --data-dir) into a --data-dir that cannot be written (`_cli.unwritable`); a `--dataset` sweep writes none."""
    from ape_jax.pipeline import data, setup

    if spec.dataset is not None:
        return
    key = spec.setup.data_key
    if key.get("frames", "rollout") == "states":   # rendered from a state dataset: that one is what is saved
        key = setup.state_source(key)
    path = data.cache_path(spec.data_dir or data.cache_dir(), key)
    if not path.exists() and (why := unwritable(path.parent)):
        fail(None, f"--data-dir {path.parent}: cannot save the demonstrations to be collected there: {why}")


@dataclasses.dataclass(frozen=True)
class Cost:
    """What a sweep asks for: `configurations` (method settings) x `seeds` x `iterations` model updates, and
    `episodes` evaluation episodes (every policy at the end and at each `eval_at`)."""

    configurations: int
    seeds: int
    iterations: int
    episodes: int

    @property
    def updates(self) -> int:
        return self.configurations * self.seeds * self.iterations

    @property
    def over(self) -> bool:
        return self.updates > UPDATES_LIMIT or self.episodes > EPISODES_LIMIT

    def __str__(self) -> str:
        return (f"this sweep asks for {self.updates:,} model updates ({self.configurations:,} configurations x "
                f"{self.seeds:,} seeds x {self.iterations:,} iterations) and {self.episodes:,} evaluation episodes")


def cost(env: str, settings, names) -> Cost | None:
    """The sweep's `Cost` from its settings and methods, before anything runs; None where a method's grid cannot
    be listed without the demonstrations (a plugin's that reads the training split's size)."""
    from ape_jax import methods, tasks
    from ape_jax.pipeline.sweep import grid_runs

    budget = settings.budget
    ctx = methods.GridContext(task=tasks.get(env), n_train=settings.protocol.train_transitions or 1,
                              knobs=settings.knobs)
    try:
        configurations = len(grid_runs(names, 1, ctx))
    except Exception:  # noqa: BLE001 - a plugin's grid; the sweep lists it again with the real split
        return None
    return Cost(configurations, budget.seeds, budget.iterations,
                configurations * budget.seeds * budget.eval_episodes * (1 + len(budget.eval_at)))
