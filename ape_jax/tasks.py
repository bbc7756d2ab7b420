"""One record per task: what the sweep, the evaluation and the report need to know of an environment.

    task = tasks.get("hopper")      # Task(loss="l2", episodes=25, fca_alpha=2.0, metric="return", ...)

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
from typing import Any
from collections.abc import Mapping

from ape_jax.protocols import (  # noqa: F401 (the protocols are read here too)
    DRIVING_FAMILIES, FAMILIES, FORMER_EXPERTS, FORMER_PROTOCOLS, FRAMES, LABELS, PALR_HISTORIES, PROTOCOLS, SPLITS,
    STATE, STATE_FRAME_SKIPS, STATE_TRAIN_SIZES, Protocol, _FAMILY_OF, current_expert, current_names, protocol_family,
    protocol_name)


@dataclasses.dataclass(frozen=True)
class Perception:
    """A task's perception card: what its encoder reads from one frame and what it is trained on
    (`ape_jax.pipeline.perception.pretrain`, docs/perception.md).

    Attributes:
      targets: the observation mode whose values the encoder reads from one frame (`pos`: what one frame shows).
      protocol: the protocol whose collection settings and expert noise make the training frames.
      image_size: the frames' size `(H, W)`.
      episodes: expert episodes in the training layouts; `perturbed_episodes` more with `perturbed_noise` times the
        protocol's noise (frames off the expert's path).
      stride: every `stride`-th step's frame is kept.
      frame_settings: task settings every frame is made with (ToyTown: the speed strip lit).
      heldout: named held-out conditions, each the task settings that make it (the card's `1 − R²` per target);
        `heldout_episodes` expert episodes each.
      near: targets the encoder regresses as `exp(−x / scale)` (`{name: scale}`), so that a distance's error counts
        most up close, where acting on it matters (ToyTown's gaps, `traffic.FAR` when nothing is seen); the read-out
        inverts it.
    """

    targets: str
    protocol: str
    image_size: tuple[int, int]
    episodes: int = 150
    perturbed_episodes: int = 50
    perturbed_noise: float = 3.0
    stride: int = 2
    frame_settings: Mapping[str, Any] = dataclasses.field(default_factory=lambda: MappingProxyType({}))
    heldout: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=lambda: MappingProxyType({}))
    heldout_episodes: int = 10
    near: Mapping[str, float] = dataclasses.field(default_factory=lambda: MappingProxyType({}))


@dataclasses.dataclass(frozen=True)
class Task:
    """A task's settings.

    Attributes:
      name: the environment's name in `envs.make`.
      title: how tables and figures name it.
      loss: the BC loss, `"l2"` or `"l1"`.
      loss_weights: each action dimension's share of the loss (`recipe.loss_weights` overrides); empty: 1 each.
      episodes: expert episodes collected for a sweep (80% train, 20% validation).
      fca_alpha: FCA's adversarial weight α for this task, as the FCA code runs it (its README: Hopper 2.0; its
        default, 1.0, where it gives none).
      fca_adversary_lr: the learning rate of FCA's adversary (its README: Hopper 4e-4; its default, 2e-4).
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
      protocols: the protocols (`PROTOCOLS`) the task can take.
      default_protocols: the protocol a sweep uses unless told, per observation mode (others: `"brax"`).
      perception: its perception card (`Perception`): a camera sweep may then see frames through the task's
        pretrained encoder (`recipe.perception=task`); None: it has none.
    """

    name: str
    title: str
    loss: str = "l2"
    loss_weights: tuple[float, ...] = ()
    episodes: int = 25
    fca_alpha: float = 1.0
    fca_adversary_lr: float = 2e-4
    metric: str = "return"
    metrics: tuple[str, ...] = ()
    default_obs: str = "pos"
    expert: str = "shipped"
    presets: Mapping[str, Mapping[str, Mapping[str, Any]]] = dataclasses.field(
        default_factory=lambda: MappingProxyType({}))
    paper: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=lambda: MappingProxyType({}))
    protocols: tuple[str, ...] = tuple(p for p in PROTOCOLS if _FAMILY_OF[p] not in DRIVING_FAMILIES)
    default_protocols: Mapping[str, str] = dataclasses.field(
        default_factory=lambda: MappingProxyType({"pos": STATE, "full": STATE}))
    perception: Perception | None = None

    def __post_init__(self):
        if self.loss not in ("l1", "l2"):
            raise ValueError(f"task {self.name!r}: loss must be 'l1' or 'l2', got {self.loss!r}")
        if self.metric != "return" and self.metric not in self.metrics:
            raise ValueError(f"task {self.name!r}: metric {self.metric!r} is neither 'return' nor one of "
                             f"{self.metrics}")
        if self.expert not in ("shipped", "rule-based"):
            raise ValueError(f"task {self.name!r}: expert must be 'shipped' or 'rule-based', got {self.expert!r}")

    def protocol(self, name: str | None, obs: str) -> Protocol:
        """Protocol `name` (None: this task's default for `obs`); `ValueError` listing the valid ones."""
        name = protocol_name(name or self.default_protocols.get(obs, "brax"))
        if name not in self.protocols:
            raise ValueError(f"unknown protocol {name!r} for {self.name}; valid: {', '.join(self.protocols)}")
        return PROTOCOLS[name]

    @property
    def has_card(self) -> bool:
        """Whether the expert has a card (`envs.experts.card`) with returns to normalise by."""
        return self.expert == "shipped"

    def preset_overrides(self, obs: str, preset: str) -> dict[str, Any]:
        return dict(self.presets.get(obs, {}).get(preset, {}))


# ToyCar: the supplement's Table 4 protocol (1k expert samples, 5 trials, BC-SO, BC-OH and Ours at THR 10%,
# W 5); its reward is 0, so it is judged by its driving metrics. FCA's α as for the MuJoCo tasks' range.
_TOYCAR_METRICS = ("success", "red_light_violations", "progress", "avg_speed", "stuck")
# ToyTown: the CARLA analog (NoCrash's metrics, `envs.toytown`); judged by success, loss L1 weighted as CILRS's
# (steer, throttle and brake 0.5 / 0.45 / 0.05), FCA's α 0.2 as the supplement runs it on CARLA.
CILRS_LOSS_WEIGHTS = (0.5, 0.45, 0.05)
# 40 expert episodes: ~44k transitions in dense traffic (~1,100 steps an episode), ~35k training after the 20%
# split, against FCA's 20k on MuJoCo. Fixed before any imitator was trained on it (docs/design.md, "ToyTown").
_TOYTOWN_METRICS = ("success", "route_completion", "collisions", "collisions_vehicle", "collisions_pedestrian",
                    "collisions_offroad", "red_light_violations", "timeout", "stuck", "avg_speed")
# The MuJoCo tasks' perception card: the pose (`pos`, the paper's MuJoCo-State observation) read from one frame of
# the `brax` protocol's image setting (the committed from-scratch image tables'), 32×32 as those tables' frames;
# held out on new episodes (one palette, no layouts).
_MUJOCO_PERCEPTION = Perception("pos", "brax", (32, 32), episodes=100, perturbed_episodes=0,
                                heldout=MappingProxyType({"new episodes": MappingProxyType({})}))
TASKS: Mapping[str, Task] = MappingProxyType({t.name: t for t in (
    # FCA's α and adversary lr: the FCA code's README runs Hopper at α 2.0 and 4e-4; it gives nothing for
    # Walker2d and HalfCheetah, whose α and lr are its defaults (`factory.py`: 1.0 and 2e-4). The keyframe
    # paper's supplement ran its own FCA at α 0.1 (Hopper) and 0.5 (the others): `--set fca.alphas=...`.
    Task("hopper", "Hopper", fca_alpha=2.0, fca_adversary_lr=4e-4, perception=_MUJOCO_PERCEPTION),
    Task("halfcheetah", "HalfCheetah", fca_alpha=1.0, perception=_MUJOCO_PERCEPTION),
    Task("walker2d", "Walker2d", fca_alpha=1.0, perception=_MUJOCO_PERCEPTION),
    Task("toycar", "ToyCar", loss="l1", episodes=10, fca_alpha=0.2, metric="success", metrics=_TOYCAR_METRICS,
         default_obs="image", expert="rule-based", protocols=("brax",), default_protocols={}, presets={"image": {
             "quick": {"image_size": (32, 32)},
             # a BC-SO policy that learns to stop on a 2-core CPU: 32×32 frames keep the lamp
             # (3×3 px) and the dashes that show speed; 100 demonstrations (~12k training samples, against the
             # paper's 1k: with 4.7k BC-SO reached 89%, and longer training overfit them); Adam at 1e-3
             # on batches of 64 for 5,000 updates; 200 evaluation episodes per policy, so a seed's success
             # rate is known to ~2 points
             # (the small conv encoder without normalisation, the setting these numbers were measured with,
             # whatever the MuJoCo tasks' image preset trains)
             "default": {"iterations": 5_000, "seeds": 5, "eval_episodes": 200, "chunk": 250, "episodes": 100,
                         "lr": 1e-3, "batch_size": 64, "image_size": (32, 32), "softmax_grid": (),
                         "encoder": "small", "encoder_norm": "none"},
             "paper": {"seeds": 5, "softmax_grid": ()}}},
         # the supplement's Table 4: success %, mean ± std over 5 trials (ours-step: THR 10%, W 5)
         paper=MappingProxyType({"bc-so": (97.2, 0.7), "bc-oh": (95.1, 4.5), "ours-step": (97.8, 0.5)})),
    Task("toytown", "ToyTown", loss="l1", loss_weights=CILRS_LOSS_WEIGHTS, episodes=40, fca_alpha=0.2,
         metric="success", metrics=_TOYTOWN_METRICS,
         default_obs="image", expert="rule-based", protocols=("nocrash", "nocrash-nospeed", "brax"),
         default_protocols={"image": "nocrash", "pos": "nocrash", "full": "nocrash"}, presets={
             # the one-frame state (`--obs pos`, the state row): the camera tables' demonstrations, updates, batch and
             # learning rate, and 100 evaluation episodes per policy (the state is cheap to evaluate); fixed before any
             # state table ran
             "pos": {
                 "quick": {"iterations": 2_000, "eval_episodes": 10, "chunk": 1_000, "episodes": 20, "lr": 1e-3,
                           "batch_size": 64, "step_grid": ((0.1, 5.0),), "softmax_grid": ()},
                 "default": {"iterations": 10_000, "seeds": 5, "eval_episodes": 100, "eval_at": (), "chunk": 2_000,
                             "episodes": 100, "lr": 1e-3, "batch_size": 64, "step_grid": ((0.1, 5.0),),
                             "softmax_grid": ()},
                 "paper": {"seeds": 5, "episodes": 100, "step_grid": ((0.1, 5.0),), "softmax_grid": ()}},
             "image": {
             # the task's own 64×64 camera in every preset (at 32×32 a pedestrian is under a pixel); `quick` trains
             # the tables' encoder (the patch encoder with GroupNorm, ~5× the small conv's updates/s) on 10
             # demonstrations, so the first run ends within minutes and reads against the tables' recipe
             "quick": {"image_size": (64, 64), "episodes": 10, "encoder": "patch", "encoder_norm": "group"},
             # Tables 1 and 2 on the 2-core CPU (results/queue/toytown-tables.sh: 11 methods × 5 seeds inside
             # about 3 hours a table): the patch encoder with GroupNorm on 100 demonstrations (~89k training
             # frames), 10,000 updates of batch 64, Adam at 1e-3, 25 evaluation episodes per policy. The learning
             # rate and the updates were chosen by BC-SO's validation loss alone, before any table ran (BC-SO,
             # seed 0: 0.0487 at 2e-4 and 0.0430 at 1e-3 after 10,000 updates, 0.0369 after 20,000, which the
             # budget does not allow; docs/tasks.md).
             "default": {"iterations": 10_000, "seeds": 5, "eval_episodes": 25, "eval_at": (), "chunk": 1_000,
                         "episodes": 100, "lr": 1e-3, "batch_size": 64, "image_size": (64, 64), "encoder": "patch",
                         "encoder_norm": "group", "step_grid": ((0.1, 5.0),), "softmax_grid": ()},
             "paper": {"image_size": (64, 64), "seeds": 5, "step_grid": ((0.1, 5.0),), "softmax_grid": ()}}},
         # the perception card (docs/perception.md): the one-frame state read from the 64×64 camera, frames of the
         # NoCrash demonstrations' settings with the speed strip lit, held out on new layouts and the new palette
         perception=Perception("pos", "nocrash", (64, 64), frame_settings=MappingProxyType({"speed_input": True}),
                               near=MappingProxyType({"stop_gap": 10.0, "lead_gap": 10.0, "ped_gap": 10.0}),
                               heldout=MappingProxyType({"test layouts": MappingProxyType({"town": "test"}),
                                                         "test layouts, test weather": MappingProxyType(
                                                             {"town": "test", "weather": "test"})}))),
)})


def get(name: str) -> Task:
    """The record of task `name`; a Brax environment without one gets the defaults (a return, L2, 25 episodes)."""
    if name in TASKS:
        return TASKS[name]
    return Task(name, name)


def sweepable() -> tuple[str, ...]:
    """The tasks a sweep can run on out of the box (each has an expert)."""
    return tuple(TASKS)
