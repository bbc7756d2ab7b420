"""Compute presets: everything a sweep sets that is not the task (recorded in results.json).

    preset = preset_for("default", "hopper", "pos")   # Preset(iterations=30_000, seeds=3, ...)

`PRESETS` are the state-observation budgets; image observations change them
(`IMAGE_PRESETS`), and a task may override settings for an observation mode
(`ape_jax.tasks.Task.presets`, e.g. ToyCar's Table 4 protocol). A preset is
frozen: derive a variant with `dataclasses.replace`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

from ape_jax import tasks
from ape_jax.learner import LearnerConfig

STEP_GRID = tuple((thr, w) for thr in (0.1, 0.2) for w in (3.0, 5.0, 10.0))
SOFTMAX_GRID = (0.1, 0.2, 0.5, 1.0, 5.0, 10.0)


@dataclasses.dataclass(frozen=True)
class Preset:
    """Every setting of a sweep that is not the environment."""

    iterations: int
    seeds: int
    eval_episodes: int
    ape_steps: int
    episodes: int | None = None   # demonstrations collected (80% train, 20% validation); None: the task's
    batch_size: int = 128
    lr: float = 2e-4
    lr_decay_every: int | None = None  # default: a third of the iterations (the paper: 100k of 300k)
    history: int = 2
    eval_steps: int | None = None  # default: the environment's episode length (1000 for MuJoCo)
    chunk: int = 500              # iterations per compiled chunk (progress granularity)
    ape_normalization: str = "none"   # the official code's softmax reads the raw APE; "mean": ÷ its training mean
    val_frac: float = 0.2
    step_grid: tuple[tuple[float, float], ...] = STEP_GRID  # (THR, W) of step weightings
    softmax_grid: tuple[float, ...] = SOFTMAX_GRID            # τ of softmax weightings
    image_size: tuple[int, int] | None = None  # image observations: (height, width); None: the env's default
    encoder: str = "small"                     # image policies: "small" (CPU) or "resnet18" (the paper's, GPU)

    def learner_config(self, obs_shape, action_dim, history, loss, unroll: bool = False) -> LearnerConfig:
        return LearnerConfig(obs_shape=tuple(obs_shape), action_dim=action_dim, history=history,
                             iterations=self.iterations, batch_size=self.batch_size,
                             lr_decay_every=self.lr_decay_every or max(1, math.ceil(self.iterations / 3)),
                             loss=loss, unroll=unroll, encoder=self.encoder if len(obs_shape) == 3 else "small")

    def env_overrides(self, obs: str) -> dict[str, Any]:
        """The `envs.make` settings this preset fixes for observations `obs` (image size, episode length)."""
        out: dict[str, Any] = {}
        if obs == "image" and self.image_size is not None:
            out["image_size"] = self.image_size
        if self.eval_steps is not None:
            out["episode_length"] = self.eval_steps
        return out

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, config: Mapping[str, Any]) -> "Preset":
        """The preset a results file's `config` records (JSON lists back to tuples; fields it predates: defaults)."""
        fields = {f.name for f in dataclasses.fields(cls)}
        values = {k: v for k, v in config.items() if k in fields}
        if values.get("step_grid") is not None:
            values["step_grid"] = tuple(tuple(x) for x in values["step_grid"])
        if values.get("image_size") is not None:
            values["image_size"] = tuple(values["image_size"])
        if "softmax_grid" in values:
            values["softmax_grid"] = tuple(values["softmax_grid"])
        return cls(**values)


PRESETS = {
    "quick": Preset(iterations=3_000, seeds=1, eval_episodes=5, ape_steps=1_000, chunk=500),
    "default": Preset(iterations=30_000, seeds=3, eval_episodes=20, ape_steps=5_000, chunk=2_000),
    "paper": Preset(iterations=300_000, seeds=5, eval_episodes=100, ape_steps=20_000, chunk=10_000),
}
# Image observations. A conv policy trains tens of times slower per iteration than the state MLP on a
# 2-core CPU, so there `quick` and `default` shrink the images, the iterations and the grid to the
# paper's step setting and the softmax τ that was best on states; `paper` keeps the supplement's
# protocol with its ResNet-18, for GPUs.
IMAGE_PRESETS = {
    "quick": dict(iterations=300, eval_episodes=3, chunk=100, image_size=(32, 32),
                  step_grid=((0.1, 5.0),), softmax_grid=()),
    "default": dict(iterations=5_000, eval_episodes=10, chunk=250, image_size=(32, 32),
                    step_grid=((0.1, 5.0),), softmax_grid=(10.0,)),
    "paper": dict(encoder="resnet18"),
}


def preset_for(name: str, env_name: str, obs: str) -> Preset:
    """Preset `name` as it applies to task `env_name` with observations `obs`, the task's episode count filled in."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; valid: {', '.join(PRESETS)}")
    task = tasks.get(env_name)
    preset = PRESETS[name]
    if obs == "image":
        preset = dataclasses.replace(preset, **IMAGE_PRESETS[name])
    return dataclasses.replace(preset, **{"episodes": task.episodes, **task.preset_overrides(obs, name)})


def resolved(preset: Preset, env_name: str) -> Preset:
    """`preset` with the settings it leaves to the task (`episodes`) filled in from task `env_name`."""
    if preset.episodes is None:
        return dataclasses.replace(preset, episodes=tasks.get(env_name).episodes)
    return preset
