"""A sweep's settings as three records, and the one function that resolves them.

    s = resolve("hopper", "pos", preset="default", recipe="bn-mlp", sets=["recipe.batch_size=32"])
    s.protocol.split, s.budget.iterations, s.recipe.beta1      # "rows", 30_000, 0.5

- `Protocol` (`ape_jax.tasks`): the task's setting — how demonstrations are collected and split and how
  policies are evaluated (frame skip, horizon, reward scale, data sizes, split, history, evaluation steps).
- `Budget` (`--preset`, whose names it keeps: `quick`, `default`, `paper`): how much compute — iterations,
  seeds, evaluation episodes, APE fit steps, the chunk of iterations per compiled call.
- `Recipe` (`--recipe`): how a policy is built and trained — the network and its initialisation, the
  optimiser, batch size, the learning rate's schedule, the loss. The methods' own
  settings (the weightings' grids, FCA's α, PALR's weights, ...) are not the recipe's: each method owns a record
  (`Method.knobs`, `--set METHOD.KNOB=VALUE`, `ape_jax.pipeline.method_knobs`), resolved into `Settings.knobs`.
  `mlp` is the project's first recipe; `bn-mlp` is the FCA code's (BatchNorm network, Adam β1 0.5, batch 64), the
  default under the mujoco-state protocols for state observations (named `fca` before: `FORMER_RECIPES`);
  `mlp-b1024` is PALR's code's optimisation on the project's network (batch 1,024, constant Adam 3e-4), the default
  under the palr protocols (named `palr` before, as the method is); `drq` is DrQ's pixel encoder at 84×84 with
  random shifts, for images (`IMAGE_RECIPES`).

`resolve` starts from the named records, applies the image observations' budget (`IMAGE_PRESETS`) and an image
recipe's own settings (`IMAGE_RECIPES`), the task's own overrides (`Task.presets`, e.g. ToyCar's), the smoke
run's amounts (`smoke_overrides`, `--smoke`) and the `--set SECTION.FIELD=VALUE` (or `METHOD.KNOB=VALUE`)
overrides, in that order, and validates the result; nothing rewrites a record after it is built. A bad name,
field or value is a one-line `SettingsError`.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any
from collections.abc import Iterable, Mapping

from ape_jax import knobs, methods, models, tasks
from ape_jax.learner import LearnerConfig, lr_boundaries
from ape_jax.models import IMAGE_ENCODERS
from ape_jax.tasks import Protocol
from ape_jax.pipeline.hints import SettingsError, check as _check, coerce as _coerce
from ape_jax.pipeline import method_knobs
from ape_jax.pipeline import sets
from ape_jax.pipeline.renames import FORMER_RECIPES, current_protocol, notice_renamed  # noqa: F401 (callers read them here)

from ape_jax.weighting import SOFTMAX_GRID, STEP_GRID, SoftmaxKnobs  # noqa: F401 - the paper's grids, where callers look


# the most any budget count may be: the device counts steps, seeds and episodes in 32-bit integers (a larger
# one passed every check, trained, then overflowed at the first step); cost is `experiments.sweep`'s check
BUDGET_MAX = 2**31 - 1


def _one_of(name: str, value: Any, valid: tuple) -> None:
    _check(value in valid, f"{name} {value!r} is not one of {', '.join(map(str, valid))}")


@dataclasses.dataclass(frozen=True)
class Budget:
    """How much compute a sweep spends (`--preset`): nothing here changes what a run computes per step, except
    `width`'s rounding."""

    iterations: int
    seeds: int
    eval_episodes: int
    ape_steps: int
    chunk: int = 500              # iterations per compiled call (progress and checkpoint granularity)
    probe_steps: int = 2_000      # the copycat diagnostics' probes' and ψ's Adam steps; 0: no diagnostics
    eval_at: tuple[int, ...] = ()  # iterations before the end at which every policy is also evaluated
    # configurations per device trained (and policies evaluated) together in one call (`grid.grid_runner`), so
    # each is computed by the same program whatever else the sweep holds; 0: a whole program at once (every file
    # before this field: XLA rounds another width differently, so such numbers depend on the sweep's size)
    width: int = 1
    # the seeds run are first_seed, ..., first_seed + seeds - 1: a run's key depends on its seed alone
    # (`methods.run_key`), so a long sweep split by seeds into several files computes what one sweep of all the
    # seeds would, and the report merges the files (`experiments.report`'s `analysis.groups.merge`)
    first_seed: int = 0

    def __post_init__(self):
        for f in dataclasses.fields(self):
            if f.name == "eval_at":
                continue
            least = 0 if f.name in ("probe_steps", "width", "first_seed") else 1
            value = getattr(self, f.name)
            _check(isinstance(value, int) and least <= value <= BUDGET_MAX,
                   f"budget.{f.name} must be an integer >= {least} and <= {BUDGET_MAX:,}, got {value!r}")
        _check(self.first_seed + self.seeds - 1 <= BUDGET_MAX,
               f"budget.first_seed + budget.seeds - 1 must be at most {BUDGET_MAX:,} (the last seed), got "
               f"{self.first_seed + self.seeds - 1:,}")
        at = self.eval_at
        _check(all(isinstance(i, int) and not isinstance(i, bool) for i in at)
               and list(at) == sorted(set(at)) and all(0 < i < self.iterations for i in at),
               f"budget.eval_at must be increasing iterations between 0 and budget.iterations ({self.iterations}), "
               f"exclusive (the end is always evaluated), got {list(at)}")


@dataclasses.dataclass(frozen=True)
class Recipe:
    """How a policy is built and trained (`--recipe`).

    Attributes:
      name: the recipe it started from (`RECIPES`); `--set` keeps the name, results record every field.
      network: state policies: `"mlp"` (no normalisation) or `"bn-mlp"` (the FCA code's: BatchNorm after each
        encoder layer, LeakyReLU on the embedding; `ape_jax.models.StatePolicy`).
      init: Dense kernels: `"lecun"` (Flax's default) or `"xavier"` (xavier-uniform, the FCA code's).
      encoder: image policies: `"small"` (CPU), `"patch"` (CPU, ~5× faster per update, `models.PatchPolicy`),
        `"drq"` (DrQ's four 3×3 convolutions, for 84×84 frames, `models.DrQPolicy`) or `"resnet18"` (the
        supplement's, for GPUs). Each takes images of at least its `min_side` pixels a side (drq: 15).
      encoder_norm: the image encoders `"small"`, `"patch"` and `"drq"`: `"none"` or `"group"` (GroupNorm after
        each encoder layer, `ape_jax.models.encoder_norm`).
      dtype: the policies' arithmetic, `"float32"` or `"bfloat16"` (mixed precision: bfloat16 layers, float32
        parameters, optimiser state and loss; `ape_jax.models`). A sweep refuses bfloat16 on a backend without
        bfloat16 arithmetic (`models.bf16_problem`). Settings recorded before this field are float32.
      augment_shift: images: each training sample's frames shifted by a random offset of up to this many pixels,
        the same for its whole history (`ape_jax.learner.random_shift`); 0: none. At most a quarter of the
        image's shorter side.
      lr, beta1, beta2: Adam's learning rate and moment decays, for every method that trains a policy.
      batch_size: minibatch rows per update.
      lr_schedule: the learning rate over the run (`ape_jax.learner.lr_schedule`, an optax schedule):
        `"piecewise"` (× `lr_decay` at each of `lr_decay_at`: the paper's), `"constant"`, or `"cosine"` (from 0 to
        `lr` over the first `warmup` of the run, then a cosine to 0 at its end).
      lr_decay_at: piecewise: fractions of the run at which the learning rate drops × `lr_decay` (the paper: ×0.1
        at 100k and 200k of 300k).
      lr_decay: piecewise: the factor at each of `lr_decay_at`, in (0, 1].
      warmup: cosine: the fraction of the run its learning rate climbs from 0, in [0, 1).
      bn_momentum: BatchNorm's running statistics' update, PyTorch's convention (0.1).
      loss: `"l2"` or `"l1"`; None: the task's (L2 for MuJoCo, L1 for the driving tasks).
      loss_weights: each action dimension's share of the loss; empty: the task's (`Task.loss_weights`: CILRS's
        0.5 / 0.45 / 0.05 for ToyTown's steer, throttle and brake; else 1 each).
      perception: camera sweeps: `"none"` (policies learn from pixels), `"task"` (the task's pretrained perception
        encoder, `envs/perception/<task>.npz`) or an encoder file's path (`ape_jax.perception`): the frames are seen
        through the frozen encoder, each frame's embedding computed once, and every policy is a state policy on the
        embeddings (the recipe's `network`; its image fields do not apply and are recorded at their defaults).
      perception_sha256: the encoder file's SHA-256, filled in when the settings are resolved (recorded in results
        and fingerprints, so two encoders never merge); given, a file with another is refused.
      perception_output: what a policy sees of a frame through the encoder: `"embedding"` (its features) or
        `"readout"` (its estimate of the one-frame targets, in their units).
      perception_training: `"frozen"` (the encoder's weights fixed, each frame embedded once) or `"finetune"` (the
        paper's setting: the encoder starts the policy's image encoder, `recipe.encoder` "perception", and trains
        end to end with it on the frames; for GPUs: every update runs the encoder forward and back).
    """

    name: str = "mlp"
    network: str = "mlp"
    init: str = "lecun"
    encoder: str = "small"
    encoder_norm: str = "none"
    augment_shift: int = 0
    dtype: str = "float32"
    lr: float = 2e-4
    beta1: float = 0.9
    beta2: float = 0.999
    batch_size: int = 128
    lr_decay_at: tuple[float, ...] = (1 / 3, 2 / 3)
    lr_schedule: str = "piecewise"
    lr_decay: float = 0.1
    warmup: float = 0.0
    bn_momentum: float = 0.1
    loss: str | None = None
    loss_weights: tuple[float, ...] = ()
    perception: str = "none"
    perception_sha256: str | None = None
    perception_output: str = "embedding"
    perception_training: str = "frozen"

    def __post_init__(self):
        object.__setattr__(self, "name", FORMER_RECIPES.get(self.name, self.name))  # a file's former name: today's
        # the knobs a LearnerConfig takes from the recipe: one rule each (`ape_jax.knobs`), the config's too
        knobs.check("recipe.", SettingsError, network=self.network, init=self.init, encoder=self.encoder,
                    encoder_norm=self.encoder_norm, augment_shift=self.augment_shift, loss=self.loss,
                    beta1=self.beta1, beta2=self.beta2, bn_momentum=self.bn_momentum, batch_size=self.batch_size,
                    lr_schedule=self.lr_schedule, lr_decay=self.lr_decay, dtype=self.dtype)
        _check(all(0.0 <= v < math.inf for v in self.loss_weights)
               and (not self.loss_weights or max(self.loss_weights) > 0),
               f"recipe.loss_weights: finite numbers >= 0, not all 0 (empty: the task's), got {self.loss_weights!r}")
        _check(self.lr > 0 and math.isfinite(self.lr), f"recipe.lr must be a finite number > 0, got {self.lr!r}")
        _check(isinstance(self.perception, str) and self.perception.strip() != "",
               f"recipe.perception: none, task, or an encoder file's path, got {self.perception!r}")
        _check(self.perception_output in ("embedding", "readout"),
               f"recipe.perception_output: embedding or readout, got {self.perception_output!r}")
        _check(self.perception_training in ("frozen", "finetune"),
               f"recipe.perception_training: frozen or finetune, got {self.perception_training!r}")
        _check(self.perception_training == "frozen" or self.perception != "none",
               "recipe.perception_training=finetune trains a pretrained encoder: name it with recipe.perception (task "
               "or a file)")
        _check(self.encoder != "perception" or self.perception_training == "finetune",
               "recipe.encoder 'perception' is a pretrained encoder fine-tuned: set recipe.perception (task or a file) "
               "and recipe.perception_training=finetune instead")
        sha = self.perception_sha256
        _check(sha is None or (isinstance(sha, str) and len(sha) == 64 and all(c in "0123456789abcdef" for c in sha)),
               f"recipe.perception_sha256: 64 hexadecimal digits (or none), got {sha!r}")
        _check(all(0.0 < f < 1.0 for f in self.lr_decay_at) and list(self.lr_decay_at) == sorted(set(self.lr_decay_at)),
               f"recipe.lr_decay_at must be increasing fractions in (0, 1), got {self.lr_decay_at!r}")
        _check(0.0 <= self.warmup < 1.0, f"recipe.warmup must be a fraction in [0, 1), got {self.warmup!r}")
        _check(self.warmup == 0.0 or self.lr_schedule == "cosine",
               f"recipe.warmup is the cosine schedule's (--set recipe.lr_schedule=cosine), got lr_schedule "
               f"{self.lr_schedule!r}")


# The project's first recipe, and the FCA code's (AlvinWen428/fighting-copycat-agents: `gan_mlp.py`,
# `factory.py`, `utils/misc.py`): its network, xavier-uniform init, Adam(2e-4, β1 0.5, β2 0.999) and batch 64;
# both drop the learning rate ×0.1 at a third and two thirds of the run (the FCA code: 100k and 200k of 300k).
# `mlp-b1024`: PALR's code's optimisation (KAIST-AILab/palr `train.py`: Adam(3e-4) with PyTorch's moments, batch
# 1,024, a constant learning rate over 500,000 iterations: `--set budget.iterations=500000`), on the project's
# network and loss (theirs: 128-64-128 units and a tanh-Gaussian likelihood); the default recipe of the `palr-h*`
# protocols. The FCA code's recipe was named `fca` and PALR's `palr`, as the methods are (one name per thing):
# `--recipe fca` reads as `bn-mlp` and `--recipe palr` as `mlp-b1024`, with a notice; a file's or checkpoint's
# former name silently (`renames.FORMER_RECIPES`).
RECIPES: Mapping[str, Recipe] = {
    "mlp": Recipe("mlp"),
    "bn-mlp": Recipe("bn-mlp", network="bn-mlp", init="xavier", beta1=0.5, batch_size=64),
    "mlp-b1024": Recipe("mlp-b1024", lr=3e-4, batch_size=1024, lr_decay_at=()),
    "drq": Recipe("drq", encoder="drq", augment_shift=4),
}
# Image recipes: the settings an image recipe brings whatever the preset's (`IMAGE_PRESETS`), applied after it.
# `drq`: the pixel encoder of continuous control from pixels (Yarats et al. 2021, DrQ and DrQ-v2: four 3×3
# convolutions of 32 channels on 84×84 frames, the history's frames stacked on channels, random shifts of up to
# ±4 pixels), with the project's optimiser (the `mlp` recipe's); `--set recipe.dtype=bfloat16` on a GPU.
IMAGE_RECIPES: Mapping[str, Mapping[str, Any]] = {
    "drq": {"encoder": "drq", "encoder_norm": "none", "augment_shift": 4, "image_size": (84, 84)},
}
BUDGETS: Mapping[str, Budget] = {
    "quick": Budget(iterations=3_000, seeds=1, eval_episodes=5, ape_steps=1_000, chunk=500, probe_steps=500),
    "default": Budget(iterations=30_000, seeds=3, eval_episodes=20, ape_steps=5_000, chunk=2_000),
    "paper": Budget(iterations=300_000, seeds=5, eval_episodes=100, ape_steps=20_000, chunk=10_000,
                    eval_at=(30_000, 100_000)),
}
# Image observations. A conv policy trains tens of times slower per iteration than the state MLP on a
# 2-core CPU, so there `quick` and `default` shrink the images and the grid to the paper's step setting (the
# keys `step_grid` and `softmax_grid`: every step and softmax weighting's grid, `method_knobs.LEGACY`);
# `paper` keeps the supplement's protocol with its ResNet-18, for GPUs. Keys are fields of any of the three
# records. `default` trains the patch encoder with GroupNorm (`recipe.encoder`, `encoder_norm`:
# ~4.6x the small conv encoder's updates/s at 32x32, `experiments.bench_images`) on 100 demonstrations
# (80 train): the probes of BENCHMARKS.md's "Images on a CPU" found the image policies short of
# demonstrations, not of encoder capacity, once normalised and trained past 5,000 updates; 20,000 updates,
# the policies also evaluated at 10,000. The shipped `*-image-default.json` files ran the first image preset
# (the small conv encoder, 25 demonstrations, 5,000 updates, softmax tau 10; CHANGELOG.md).
IMAGE_PRESETS = {
    "quick": dict(iterations=300, eval_episodes=3, chunk=100, image_size=(32, 32),
                  step_grid=((0.1, 5.0),), softmax_grid=()),
    "default": dict(iterations=20_000, eval_episodes=10, chunk=1_000, eval_at=(10_000,), image_size=(32, 32),
                    episodes=100, encoder="patch", encoder_norm="group", step_grid=((0.1, 5.0),), softmax_grid=()),
    "paper": dict(encoder="resnet18"),
}
SECTIONS = ("protocol", "budget", "recipe")
_RECORDS = {"protocol": Protocol, "budget": Budget, "recipe": Recipe}


@dataclasses.dataclass(frozen=True)
class Settings:
    """A sweep's three records, resolved for one task and observation mode (`resolve`), and the methods' own
    settings (`knobs`: `{method: its Method.knobs record}`, `ape_jax.pipeline.method_knobs`; those at their
    defaults are left out, so a record is there only where the sweep's settings differ from its method's own)."""

    protocol: Protocol
    budget: Budget
    recipe: Recipe
    preset: str = "quick"   # the budget's name
    smoke: bool = False     # the preset's amounts shrunk to seconds (`smoke_overrides`): its numbers mean nothing
    # the iterations the preset gave before `sets` (`--iterations`, `--set budget.iterations=`) were applied, so a
    # results file says itself whether it trained its preset's budget (None: settings not made by `resolve`)
    preset_iterations: int | None = None
    knobs: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "knobs", method_knobs.without_defaults(self.knobs))
        self.ape_normalization   # noqa: B018 - refuses softmax weightings that disagree, here rather than mid-sweep

    @property
    def ape_normalization(self) -> str:
        """How the sweep's one APE fit is scaled (`SoftmaxKnobs.ape_normalization`): its softmax weightings'
        shared setting; `SettingsError` where two differ."""
        found = {m: self.knob(m).ape_normalization for m in methods.sharing(SoftmaxKnobs)}
        if len(set(found.values())) > 1:
            raise SettingsError("the softmax weightings' ape_normalization differ (" + ", ".join(
                f"{m}: {v}" for m, v in found.items()) + "): the sweep fits one APE, scaled once")
        return next(iter(found.values()), "none")

    def knob(self, method: str) -> Any:
        """Method `method`'s settings record in this sweep (`Method.knobs`): the sweep's, else its defaults."""
        return methods.knobs_of(method, self.knobs)

    def learner_config(self, obs_shape, action_dim: int, history: int, task_loss: str,
                       unroll: bool = False, task_loss_weights: tuple[float, ...] = ()) -> LearnerConfig:
        """The static learner settings of a program whose policies see `history` observations, `protocol.history_stride`
        steps apart (the task's loss and its action weights where the recipe names none)."""
        r, iterations = self.recipe, self.budget.iterations
        images = len(obs_shape) == 3
        stride = self.protocol.history_stride if history > 1 else 1
        return LearnerConfig(obs_shape=tuple(obs_shape), action_dim=action_dim, history=(history - 1) * stride + 1,
                             history_stride=stride,
                             iterations=iterations, batch_size=r.batch_size,
                             lr_schedule=r.lr_schedule, lr_decay=r.lr_decay, warmup_steps=round(r.warmup * iterations),
                             lr_boundaries=(lr_boundaries(iterations, r.lr_decay_at) if r.lr_schedule == "piecewise"
                                            else ()), beta1=r.beta1, beta2=r.beta2,
                             network="mlp" if images else r.network, init=r.init, bn_momentum=r.bn_momentum,
                             loss=r.loss or task_loss, loss_weights=r.loss_weights or tuple(task_loss_weights),
                             unroll=unroll, encoder=r.encoder if images else "small",
                             encoder_norm=r.encoder_norm if images else "none",
                             augment_shift=r.augment_shift if images else 0, dtype=r.dtype,
                             perception_sha256=r.perception_sha256 if images and r.encoder == "perception" else "")

    def to_json(self) -> dict[str, dict]:
        """`{"protocol": ..., "budget": ..., "recipe": ...}`, every field (results.json's blocks), and `"knobs"` where
        a method's own settings were given."""
        out = {name: _jsonable(dataclasses.asdict(getattr(self, name))) for name in SECTIONS}
        return {**out, "knobs": method_knobs.to_json(self.knobs)} if self.knobs else out

    @classmethod
    def from_json(cls, blocks: Mapping[str, Mapping[str, Any]], preset: str = "quick") -> Settings:
        """The settings results.json's blocks record (fields a block predates: the defaults; a recipe's method
        fields from before the methods owned them, `method_knobs.LEGACY`: the methods' records)."""
        legacy = method_knobs.from_legacy(blocks.get("recipe") or {})
        return cls(*(_record(name, blocks.get(name) or {}) for name in SECTIONS), preset=preset,
                   knobs=method_knobs.from_json(blocks.get("knobs"), legacy))


def default_recipe(protocol: Protocol, obs: str) -> str:
    """The recipe a sweep uses unless told: the FCA code's (`bn-mlp`) under the mujoco-state protocols for states,
    PALR's code's (`mlp-b1024`) under the palr protocols, else `mlp`."""
    if protocol.family == "palr":
        return "mlp-b1024"
    return "bn-mlp" if protocol.family == tasks.STATE and obs != "image" else "mlp"


def smoke_overrides(values: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """The amounts of a `--smoke` run, given the resolved fields (`{section: {field: value}}`) it shrinks.

    Everything that decides what a step computes stays: the network and encoder, the image size, the history,
    the frame skip, the split's kind, the optimiser. The amounts become seconds: 3 demonstration episodes (2
    train, the fewest the diagnostics take) of 20 standard steps where the task takes a horizon (the MuJoCo
    tasks; a row-split protocol: 240 collected transitions, 144 training and 48 validating), one setting of
    each grid (`method_knobs.first_only`, in `resolve`), one seed, four iterations in chunks of two (evaluated
    after the first chunk too, so the mid-run evaluation runs; DAgger's four rounds get one iteration each),
    batch 4, two evaluation episodes (the fewest the diagnostics take), ten steps of the APE fit and of every
    diagnostic's probe.
    """
    protocol = values["protocol"]
    out: dict[str, Any] = dict(iterations=4, seeds=1, eval_episodes=2, ape_steps=10, chunk=2, eval_at=(2,),
                               batch_size=4, horizon=20, episodes=3)
    if values["budget"]["probe_steps"]:
        out["probe_steps"] = 10
    if protocol["collect_transitions"] is not None:
        out.update(collect_transitions=240, train_transitions=144, val_transitions=48)
    if protocol["eval_steps"] is not None:
        out["eval_steps"] = min(protocol["eval_steps"], 20)
    return out


def resolve(env: str, obs: str, protocol: str | None = None, preset: str = "quick", recipe: str | None = None,
            sets: Iterable[str] = (), smoke: bool = False) -> Settings:
    """The settings of a sweep of task `env` with observations `obs` (the module docstring says how).

    Args:
      protocol: `ape_jax.tasks.PROTOCOLS` name; None: the task's default for `obs`.
      preset: the budget's name (`BUDGETS`).
      recipe: `RECIPES` name; None: `default_recipe`.
      sets: `"SECTION.FIELD=VALUE"` overrides, applied last, in order.
      smoke: shrink the amounts to seconds (`smoke_overrides`), before `sets`: a check that the preset runs end
        to end (e.g. `paper` with images on a CPU), not a measurement.

    Raises:
      SettingsError: an unknown preset, recipe, protocol, section or field, or a value a field cannot take.
    """
    task = tasks.get(env)
    renamed = [(kind, old, new) for kind, old, new in (
        ("protocol", protocol, tasks.FORMER_PROTOCOLS.get(protocol or "")),
        ("recipe", recipe, FORMER_RECIPES.get(recipe or "")),
        *(("protocol.expert", item.partition("=")[2].strip(), tasks.FORMER_EXPERTS.get(item.partition("=")[2].strip()))
          for item in sets if item.partition("=")[0].strip() == "protocol.expert")) if new]
    recipe = FORMER_RECIPES.get(recipe, recipe) if recipe else recipe
    try:
        proto = task.protocol(protocol, obs)
    except ValueError as e:
        raise SettingsError(str(e)) from None
    if preset not in BUDGETS:
        raise SettingsError(f"unknown preset {preset!r}; valid: {', '.join(BUDGETS)}")
    recipe = recipe or default_recipe(proto, obs)
    if recipe not in RECIPES:
        raise SettingsError(f"unknown recipe {recipe!r}; valid: {', '.join(RECIPES)}")
    _check(obs == "image" or recipe not in IMAGE_RECIPES, f"recipe {recipe!r} is for image observations (--obs image)")
    values = {"protocol": dataclasses.asdict(proto), "budget": dataclasses.asdict(BUDGETS[preset]),
              "recipe": dataclasses.asdict(RECIPES[recipe])}
    knobs: dict[str, dict[str, Any]] = {}  # {method: {knob: value}}
    images = (IMAGE_PRESETS[preset], IMAGE_RECIPES.get(recipe, {})) if obs == "image" else ()
    for layer in (*images, task.preset_overrides(obs, preset)):
        for key, value in layer.items():
            if key in method_knobs.LEGACY:  # a grid of every weighting of its kind
                method_knobs.merge(knobs, method_knobs.legacy(key, value))
            else:
                values[_section_of(key)][key] = value
    for key, value in (smoke_overrides(values) if smoke else {}).items():
        values[_section_of(key)][key] = value
    if values["protocol"].get("task_version") is None:  # recorded as a number, so a replay makes the same task
        from ape_jax.pipeline.setup import current_task_version

        values["protocol"]["task_version"] = current_task_version(env)
    preset_iterations = values["budget"]["iterations"]
    explicit, old_names = set(), []
    for item in sets:
        section, field, value = parse_set(item)
        if section == "recipe" and field in method_knobs.LEGACY:
            old_names.append(field)
            method_knobs.merge(knobs, method_knobs.legacy(field, value))
        else:
            (knobs.setdefault(section, {}) if section not in _RECORDS else values[section])[field] = value
        explicit.add(field)
    if "eval_at" not in explicit:  # the preset's points inside the run only, when its length was changed
        budget = values["budget"]
        budget["eval_at"] = tuple(i for i in budget["eval_at"] if i < budget["iterations"])
    records = method_knobs.build(knobs)
    if smoke:  # one setting of each grid axis of every method's settings
        records = method_knobs.first_only(records)
    settings = Settings(*(_record(name, values[name]) for name in SECTIONS), preset=preset, smoke=smoke,
                        preset_iterations=preset_iterations, knobs=records)
    _check_image_recipe(settings.recipe, obs, settings.protocol.image_size)
    if settings.recipe.perception != "none":
        from ape_jax.pipeline.perception import pinned

        try:
            settings = dataclasses.replace(settings, recipe=pinned(settings.recipe, env, obs, settings.protocol,
                                                                   explicit))
        except ValueError as e:   # one line: the file, or what does not fit
            raise SettingsError(str(e)) from None
    if settings.recipe.dtype == "bfloat16" and (problem := models.bf16_problem()):
        raise SettingsError(f"recipe.dtype 'bfloat16': {problem}; use recipe.dtype=float32")
    for field in old_names:  # once the settings are good: a refusal stays one line
        method_knobs.notice(field)
    for kind, old, new in renamed:
        notice_renamed(kind, old, new)
    return settings


def _check_image_recipe(recipe: Recipe, obs: str, image_size: tuple[int, int] | None) -> None:
    """Refuses (`SettingsError`) an image setting of the recipe that the observations cannot take."""
    images = [f"recipe.{k}={getattr(recipe, k)}" for k, default in (("encoder_norm", "none"), ("augment_shift", 0))
              if getattr(recipe, k) != default]
    _check(obs == "image" or not images, f"{', '.join(images)}: for image observations (--obs image) only")
    if obs == "image" and image_size is not None:
        side = min(image_size)
        _check(recipe.augment_shift <= side // 4, f"recipe.augment_shift must be at most a quarter of the "
               f"image's shorter side ({side}: {side // 4}), got {recipe.augment_shift}")
        least = IMAGE_ENCODERS[recipe.encoder].min_side
        _check(side >= least, f"recipe.encoder {recipe.encoder!r} takes images of at least {least}×{least} "
               f"pixels, got protocol.image_size {image_size[0]}x{image_size[1]}")


def fields(section: str) -> tuple[str, ...]:
    """The fields `--set` can change in `section` (every field but the record's name and description)."""
    return sets.fields(_RECORDS, section)


def parse_set(item: str) -> tuple[str, str, Any]:
    """`"SECTION.FIELD=VALUE"` -> `(section, field, value)`, the value parsed by the field's type (`sets.parse_set`:
    numbers as written, `none`, lists comma-separated, the step grid as `THR:W`, an image size as `N`, `HxW` or
    `H,W`), a method's own knob (`method_knobs`) by its record."""
    return sets.parse_set(_RECORDS, item)


def format_set(section: str, field: str, value: Any) -> str:
    """`"SECTION.FIELD=VALUE"` that `parse_set` reads back as `value` (its inverse)."""
    return sets.format_set(_RECORDS, section, field, value)


# -- internals ------------------------------------------------------------------------------------------------------

def _section_of(key: str) -> str:
    for section in SECTIONS:
        if key in {f.name for f in dataclasses.fields(_RECORDS[section])}:
            return section
    raise SettingsError(f"an override names {key!r}, a field of none of {', '.join(SECTIONS)}")


def _jsonable(value: Any) -> Any:
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    return value


def _record(section: str, values: Mapping[str, Any]):
    """`values` as the section's record: unknown keys dropped, lists back to tuples, types checked."""
    cls = _RECORDS[section]
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    out = {k: _coerce(hints[k], v, f"{section}.{k}") for k, v in values.items() if k in known}
    if section == "protocol" and "name" not in out:
        out["name"] = "brax"
    if section == "budget" and values and "width" not in out:
        out["width"] = 0  # a file from before fixed widths trained each program whole
    try:
        return cls(**out)
    except SettingsError:
        raise
    except (TypeError, ValueError) as e:  # a required field missing; a protocol's own check
        raise SettingsError(str(e) if str(e).startswith(section) else f"{section}: {e}") from None
