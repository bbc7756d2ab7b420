"""The sweep's own argument checks (`experiments.sweep`): its grids given on the command line, and a
demonstration cache it would have to write. Each refuses with one line and exit status 2 (`_cli.fail`)."""

from __future__ import annotations

import math

from experiments._cli import fail, unwritable


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
