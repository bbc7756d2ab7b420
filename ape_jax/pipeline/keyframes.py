"""Keyframes of one demonstration episode: which steps they are, which to render, where to zoom in.

Host-side NumPy on plain arrays, no simulator and no matplotlib, for
`experiments.keyframes`; `experiments.report.figures.keyframes` draws the result.

- `keyframe_mask(ape, thr)` — the top `thr` of APE over the dataset, the samples
  `ape_jax.weighting.step` upweights, and the threshold they lie above;
- `pick_frames(...)` — an episode's highest-APE keyframes, spread out in time,
  and a few ordinary (low-APE) steps for contrast;
- `select(...)` — `pick_frames` with a default spacing, plus the close-up window
  around the highest-APE keyframe picked (`zoom_window`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Selection(NamedTuple):
    """The steps of one episode to show: rendered frames and the close-up."""

    steps: np.ndarray  # [k] int, the rendered steps in time order
    is_key: np.ndarray  # [k] bool, which of them are keyframes
    window: tuple[int, int] | None  # [start, stop) shown close up, or None: the whole episode


def keyframe_mask(ape: np.ndarray, thr: float) -> tuple[np.ndarray, float]:
    """The top `thr` of `ape` as `ape_jax.weighting.step` picks them (⌊thr·N⌋ largest, ties by index).

    Args:
      ape: `[N]` APE over the whole dataset.
      thr: fraction in (0, 1).

    Returns:
      (mask, threshold): `[N] bool`, and the smallest APE among the keyframes
      (+inf when ⌊thr·N⌋ = 0).
    """
    from ape_jax import weighting

    ape = np.asarray(ape, np.float32)
    mask = np.asarray(weighting.step(ape, thr, 2.0)) > 1.0
    return mask, float(ape[mask].min()) if mask.any() else float("inf")


def pick_frames(ape: np.ndarray, keyframe: np.ndarray, count: int, min_gap: int, ordinary: int = 1,
                skip_start: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """The steps of one episode worth rendering: its highest-APE keyframes, spread out, and ordinary steps.

    Keyframes are taken greedily by decreasing APE, each at least `min_gap`
    steps from those already taken; then up to `ordinary` non-keyframe steps of
    lowest APE, equally spread, skipping the first `skip_start` steps (where
    APE is near zero only because the missing past actions are padded).

    Args:
      ape: `[T]` APE of the episode's steps.
      keyframe: `[T] bool`, which of them are keyframes.
      count: keyframes wanted (fewer come back when not enough are far enough apart).
      min_gap: fewest steps between two picked steps, >= 1.
      ordinary: ordinary steps wanted.
      skip_start: ordinary steps are not taken before this step.

    Returns:
      (steps, is_key): `[k] int` steps in time order and `[k] bool`.
    """
    ape, keyframe = np.asarray(ape), np.asarray(keyframe, bool)
    if ape.shape != keyframe.shape or ape.ndim != 1:
        raise ValueError(f"pick_frames: ape and keyframe must both be [T], got {ape.shape} and {keyframe.shape}")
    picked: list[int] = []
    is_key: list[bool] = []

    def take(candidates, want, key):
        taken = 0
        for i in candidates:
            if taken == want:
                break
            if all(abs(int(i) - j) >= min_gap for j in picked):
                picked.append(int(i))
                is_key.append(key)
                taken += 1

    by_ape = np.argsort(-ape, kind="stable")
    take(by_ape[keyframe[by_ape]], count, True)
    calm = np.argsort(ape, kind="stable")
    take(calm[~keyframe[calm] & (calm >= skip_start)], ordinary, False)
    order = np.argsort(picked, kind="stable")
    return np.asarray(picked, int)[order], np.asarray(is_key, bool)[order]


def zoom_window(steps: int, center: int, width: int) -> tuple[int, int]:
    """`[start, stop)` of `width` steps (at most `steps`) centred on `center`, inside `[0, steps)`."""
    width = max(1, min(width, steps))
    start = min(max(center - width // 2, 0), steps - width)
    return start, start + width


def select(ape: np.ndarray, keyframe: np.ndarray, count: int, ordinary: int = 1, min_gap: int | None = None,
           zoom: int = 150, skip_start: int = 9) -> Selection:
    """`pick_frames` with a default spacing, and a close-up of `zoom` steps around the highest-APE keyframe.

    Args:
      ape: `[T]` APE of the episode's steps.
      keyframe: `[T] bool`, which of them are keyframes.
      count: keyframes wanted; `ordinary` ordinary steps wanted.
      min_gap: fewest steps between two picked steps (default: T / (2 × steps wanted)).
      zoom: width of the close-up; none (window None) when 0, when the episode is
        shorter than `2 * zoom`, or when no keyframe was picked.
      skip_start: ordinary steps are not taken before this step.

    Returns:
      The `Selection`.
    """
    ape = np.asarray(ape)
    steps = ape.shape[0]
    min_gap = min_gap or max(1, steps // (2 * max(1, count + ordinary)))
    frame_t, frame_key = pick_frames(ape, keyframe, count, min_gap, ordinary, skip_start=skip_start)
    window = None
    if 0 < zoom and 2 * zoom <= steps and frame_key.any():
        keys = frame_t[frame_key]
        window = zoom_window(steps, int(keys[np.argmax(ape[keys])]), zoom)
    return Selection(frame_t, frame_key, window)


def action_names(env) -> list[str] | None:
    """The environment's own action names (`env.action_names`), else a MuJoCo model's actuator (or joint) names.

    Args:
      env: an environment from `envs.make`.

    Returns:
      One name per action dimension, or None when the environment exposes no MuJoCo model.
    """
    if env.action_names is not None:
        return list(env.action_names)
    try:
        model = env.brax_env.sys.mj_model
    except AttributeError:
        return None
    names = []
    for i in range(model.nu):
        joint = model.joint(int(model.actuator(i).trnid[0])).name.removesuffix("_joint")
        names.append(model.actuator(i).name or joint or f"a{i}")
    return names
