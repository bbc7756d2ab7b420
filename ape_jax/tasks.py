"""One record per task: what the sweep, the evaluation and the report need to know of an environment.

    task = tasks.get("hopper")      # Task(loss="l2", episodes=25, fca_alpha=0.1, metric="return", ...)

Everything that differs between tasks lives in its `Task`, so no other module
asks which environment it is running: the BC loss (L2 for MuJoCo, L1 for the
driving sandbox), how many expert episodes are collected, FCA's α, the main
metric (the return, or a success rate where the reward says nothing), the
environment's own per-episode metrics, where the expert comes from, and the
preset settings a task overrides. `TASKS` lists the tasks with an expert;
any other Brax environment gets the defaults (`get`), and needs an expert
trained by `experiments.train_expert` before a sweep can run on it.
"""

from __future__ import annotations

import dataclasses
from types import MappingProxyType
from typing import Any, Mapping


@dataclasses.dataclass(frozen=True)
class Task:
    """A task's settings.

    Attributes:
      name: the environment's name in `envs.make`.
      title: how tables and figures name it.
      loss: the BC loss, `"l2"` or `"l1"`.
      episodes: expert episodes collected for a sweep (80% train, 20% validation).
      fca_alpha: FCA's adversarial weight α for this task (the paper's supplement).
      metric: the main evaluation metric: `"return"`, or one of `metrics`
        (a rate in [0, 1], reported in %).
      metrics: the environment's per-episode metrics (`env.episode_metrics`),
        reported beside (before) the return.
      default_obs: the observation mode a sweep uses unless told.
      expert: `"shipped"` (a trained checkpoint with a card, `envs.experts`) or
        `"rule-based"` (the environment's own `expert`).
      presets: overrides of preset settings, `{obs mode: {preset: {setting: value}}}`,
        applied after the observation mode's own.
      paper: the paper's main-metric results per method name (mean, std), for
        the report (a rate metric's in %).
    """

    name: str
    title: str
    loss: str = "l2"
    episodes: int = 25
    fca_alpha: float = 0.1
    metric: str = "return"
    metrics: tuple[str, ...] = ()
    default_obs: str = "pos"
    expert: str = "shipped"
    presets: Mapping[str, Mapping[str, Mapping[str, Any]]] = dataclasses.field(
        default_factory=lambda: MappingProxyType({}))
    paper: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=lambda: MappingProxyType({}))

    def __post_init__(self):
        if self.loss not in ("l1", "l2"):
            raise ValueError(f"task {self.name!r}: loss must be 'l1' or 'l2', got {self.loss!r}")
        if self.metric != "return" and self.metric not in self.metrics:
            raise ValueError(f"task {self.name!r}: metric {self.metric!r} is neither 'return' nor one of {self.metrics}")
        if self.expert not in ("shipped", "rule-based"):
            raise ValueError(f"task {self.name!r}: expert must be 'shipped' or 'rule-based', got {self.expert!r}")

    @property
    def has_card(self) -> bool:
        """Whether the expert has a card (`envs.experts.card`) with returns to normalise by."""
        return self.expert == "shipped"

    def preset_overrides(self, obs: str, preset: str) -> dict[str, Any]:
        return dict(self.presets.get(obs, {}).get(preset, {}))


# ToyCar: the supplement's Table 4 protocol (1k expert samples, 5 trials, BC-SO, BC-OH and Ours at THR 10%,
# W 5); its reward is 0, so it is judged by its driving metrics. FCA's α as for the MuJoCo tasks' range.
_TOYCAR_METRICS = ("success", "red_light_violations", "progress", "avg_speed", "stuck")
TASKS: Mapping[str, Task] = MappingProxyType({t.name: t for t in (
    Task("hopper", "Hopper", fca_alpha=0.1),
    Task("halfcheetah", "HalfCheetah", fca_alpha=0.5),
    Task("walker2d", "Walker2d", fca_alpha=0.5),
    Task("toycar", "ToyCar", loss="l1", episodes=10, fca_alpha=0.2, metric="success", metrics=_TOYCAR_METRICS,
         default_obs="image", expert="rule-based", presets={"image": {
             "quick": {"image_size": (32, 32)},
             "default": {"iterations": 2_000, "seeds": 5, "eval_episodes": 20, "chunk": 250,
                         "image_size": (64, 64), "softmax_grid": ()},
             "paper": {"seeds": 5, "softmax_grid": ()}}},
         # the supplement's Table 4: success %, mean ± std over 5 trials (ours-step: THR 10%, W 5)
         paper=MappingProxyType({"bc-so": (97.2, 0.7), "bc-oh": (95.1, 4.5), "ours-step": (97.8, 0.5)})),
)})


def get(name: str) -> Task:
    """The record of task `name`; a Brax environment without one gets the defaults (a return, L2, 25 episodes)."""
    if name in TASKS:
        return TASKS[name]
    return Task(name, name)


def sweepable() -> tuple[str, ...]:
    """The tasks a sweep can run on out of the box (each has an expert)."""
    return tuple(TASKS)
