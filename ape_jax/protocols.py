"""The protocols: how a task's demonstrations and evaluation are set up, apart from the compute preset.

    proto = protocols.PROTOCOLS["mujoco-state"]   # Protocol(frame_skip=1, horizon=500, history=2, ...)

A protocol is a record (`Protocol`) in a family (`FAMILIES`: the paper's MuJoCo-State setting and its variants,
Brax's own, PALR's, NoCrash's driving); a task names the protocols it can take (`ape_jax.tasks.Task.protocols`).
`ape_jax.tasks` re-exports every name here, where most callers read them.
"""

from __future__ import annotations

import dataclasses
import re
from types import MappingProxyType
from typing import Any
from collections.abc import Mapping


SPLITS = ("rows", "episodes")
LABELS = ("clipped", "raw")
FRAMES = ("rollout", "states")


STATE = "mujoco-state"   # the paper's MuJoCo-State protocol (FCA's data setting) and its family
# Names before each thing had one (`docs/design.md`, "Words"): the MuJoCo-State protocols were `fca`, `fca-fs2`, ...
# (the method `fca` is FCA's algorithm), and FCA's imported CS294 Hopper expert was imported as `fca`. An old name
# reads as its new one: on the command line with a notice (`ape_jax.pipeline.presets.renamed`), in a results file or
# checkpoint silently, so their settings, fingerprints and replays are what they were.
FORMER_PROTOCOLS: Mapping[str, str] = MappingProxyType(
    {f"fca{v}": f"{STATE}{v}" for v in ("", "-fs2", "-fs4", "-train5k", "-train80k")})
FORMER_EXPERTS: Mapping[str, str] = MappingProxyType({"fca": "cs294"})


def protocol_name(name: str) -> str:
    """The protocol's name now: `name`, or what a former name (`FORMER_PROTOCOLS`) is called now."""
    return FORMER_PROTOCOLS.get(name, name)


def current_names(block: Mapping[str, Any]) -> dict[str, Any]:
    """A protocol record's fields or block (a file's, a fingerprint's) with its `name`, `reference` and `expert`
    as they are called now (each as given where it was not renamed, or is absent)."""
    former = {"name": FORMER_PROTOCOLS, "reference": FORMER_PROTOCOLS, "expert": FORMER_EXPERTS}
    return {k: former[k].get(v, v) if k in former and isinstance(v, str) else v for k, v in block.items()}


def current_expert(description: dict) -> dict:
    """An expert's description (a data key's `expert`: `name` `env-variant`, `variant`) with a former variant name
    (`FORMER_EXPERTS`) as it is called now; the rest as it is."""
    old = description.get("variant")
    if old not in FORMER_EXPERTS:
        return description
    name = description.get("name")
    renamed = name[:-len(old)] + FORMER_EXPERTS[old] if isinstance(name, str) and name.endswith(f"-{old}") else name
    return {**description, "variant": FORMER_EXPERTS[old], **({"name": renamed} if "name" in description else {})}


@dataclasses.dataclass(frozen=True)
class Protocol:
    """How a task's demonstrations and evaluation are set up, apart from the compute preset.

    Attributes:
      name: the protocol's name (`PROTOCOLS`): `"mujoco-state"`, `"brax"`, ...
      frame_skip: simulator steps per control step (Brax's `n_frames`); None: the environment's own.
      horizon: simulated time per episode, in the environment's *standard* control steps (at its own
        frame skip); None: its own episode length. At frame skip 1 an episode of `horizon` standard steps
        is `horizon × standard frame skip` control steps.
      collect_transitions: expert steps collected (whole episodes, rounded up); None: the task's episodes.
      train_transitions, val_transitions: the demonstrations' split sizes; None: split by episode, `val_frac`
        of the episodes validating.
      split: how the split is drawn: `"rows"` (the FCA code's: a fixed random permutation of all collected rows
        gives the training and the validation rows; histories still read whole episodes) or `"episodes"`
        (whole episodes apart, cut to size).
      val_frac: the validation share of episodes, where no sizes are given.
      history: observations the policies see (BC-SO: 1).
      episodes: expert episodes collected where `collect_transitions` is None; None: the task's.
      eval_steps: steps of an evaluation episode; None: the protocol's episode length.
      image_size: rendered frames' (height, width) for image observations; None: the environment's default.
      doc: one line saying where the protocol comes from.
      reference: the protocol whose expert references (`envs.experts.reference`) apply: one with the same
        simulator settings (frame skip, episode length, reward scale); None: this one's own.
      expert: which shipped expert demonstrates: None, the task's own (`envs/experts/<env>/`, SAC); a variant
        name (`"ppo"`) for one shipped beside it (`envs/experts/<env>-<variant>/`, `expert_name`).
      labels: what the demonstrations store as the label: `"clipped"` (the expert's action clipped to the action
        range, what the environment executes) or `"raw"` (the expert's output as it gave it, unbounded for a
        Gaussian policy's mean: what the FCA code stored). The executed action is clipped either way.
      prev_action: the observation carries the previous action (de Haan et al. 2019; PALR's "POA"): the
        demonstration's a_{t-1} in training, the policy's own in rollouts; zeros at an episode's start.
      frames: image observations: where the demonstrations' frames come from. `"rollout"`: rendered in the
        collecting rollout, at each step. `"states"`: the same settings' state-observation dataset (the `pos`
        one, the rows the state sweeps train on; collected first, or found in the cache, e.g. collected on a
        CPU) with each row's simulator state rendered afterwards, in jitted batches
        (`ape_jax.pipeline.collect.render_states`): a device renders what a CPU collected, and only the
        states travel. Hopper's and Walker2d's frames then show the body poses after the step's last physics
        substep, where the rollout's show them before it (`envs.brax_env.BraxEnv.observe_sim`).
      traffic, speed_input, task_version: the task's own settings of that name for collection and evaluation (a
        driving task's: ToyTown's NoCrash condition, its speed measurement, what its camera shows); None: the task's
        default. A task without the setting refuses it. `protocol_setup` records the task version in use.
      reveal: the task's `reveal` setting: full-state features added to its one-frame state (`obs="pos"`), a
        diagnostic of what one frame lacks (ToyTown's one-frame ceiling); (): none.
      history_stride: control steps between the frames of a history (1: consecutive). A history of `history`
        frames at stride `k` spans `(history - 1) · k + 1` steps: the policy sees the current frame and the ones
        `k`, `2k`, ... steps before it (padded at an episode's start as any history is).
      eval_town, eval_weather: the task's `town` and `weather` in evaluation only (ToyTown's held-out layouts and
        palette, NoCrash's "new town" and "new weather"); None: as collected.
      noise_frac, noise_steps, noise_std: noise injected into the executed actions while demonstrating, the
        labels staying the expert's own (`ape_jax.pipeline.collect`): a share `noise_frac` of the steps perturbed,
        in bursts of `noise_steps` steps (1: each step on its own, DART's), each burst a triangular pulse peaking
        at a Gaussian offset of std `noise_std` (CARLA100's); 0: none.

    Rewards are scaled by `frame_skip / standard frame skip`, so returns stay on the scale of the
    standard control step (the FCA code's 1/4 and 1/5).
    """

    name: str
    frame_skip: int | None = None
    horizon: int | None = None
    collect_transitions: int | None = None
    train_transitions: int | None = None
    val_transitions: int | None = None
    history: int = 2
    doc: str = dataclasses.field(default="", compare=False)
    reference: str | None = None
    split: str = "episodes"
    val_frac: float = 0.2
    episodes: int | None = None
    eval_steps: int | None = None
    image_size: tuple[int, int] | None = None
    expert: str | None = None
    labels: str = "clipped"
    prev_action: bool = False
    frames: str = "rollout"
    traffic: str | None = None
    speed_input: bool | None = None
    task_version: int | None = None
    reveal: tuple[str, ...] = ()
    history_stride: int = 1
    eval_town: str | None = None
    eval_weather: str | None = None
    noise_frac: float = 0.0
    noise_steps: int = 1
    noise_std: float = 0.0

    def __post_init__(self):
        names = current_names({"name": self.name, "reference": self.reference, "expert": self.expert})
        for field, value in names.items():   # a former name (a file's, an old command's) reads as today's
            object.__setattr__(self, field, value)
        if self.split not in SPLITS:
            raise ValueError(f"protocol.split {self.split!r} is not one of {', '.join(SPLITS)}")
        if self.split == "rows" and (self.train_transitions is None or self.val_transitions is None):
            raise ValueError("protocol.split 'rows' needs train_transitions and val_transitions")
        if not 0.0 <= self.val_frac < 1.0:
            raise ValueError(f"protocol.val_frac must be in [0, 1), got {self.val_frac!r}")
        for name in ("frame_skip", "horizon", "collect_transitions", "train_transitions", "val_transitions",
                     "episodes", "eval_steps"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"protocol.{name} must be >= 1 or none, got {value!r}")
        if self.history < 1:
            raise ValueError(f"protocol.history must be >= 1, got {self.history!r}")
        if isinstance(self.history_stride, bool) or not isinstance(self.history_stride, int) or self.history_stride < 1:
            raise ValueError(f"protocol.history_stride must be a whole number of steps >= 1, got "
                             f"{self.history_stride!r}")
        if self.image_size is not None and min(self.image_size) < 1:
            raise ValueError(f"protocol.image_size must be positive, got {self.image_size!r}")
        if self.labels not in LABELS:
            raise ValueError(f"protocol.labels {self.labels!r} is not one of {', '.join(LABELS)}")
        if self.frames not in FRAMES:
            raise ValueError(f"protocol.frames {self.frames!r} is not one of {', '.join(FRAMES)}")
        if not isinstance(self.prev_action, bool):
            raise ValueError(f"protocol.prev_action must be true or false, got {self.prev_action!r}")
        if not 0.0 <= self.noise_frac < 1.0 or self.noise_std < 0 or self.noise_steps < 1:
            raise ValueError(f"protocol noise: noise_frac must be in [0, 1), noise_std >= 0 and noise_steps >= 1, got "
                             f"{self.noise_frac!r}, {self.noise_std!r} and {self.noise_steps!r}")
        if self.speed_input is not None and not isinstance(self.speed_input, bool):
            raise ValueError(f"protocol.speed_input must be true, false or none, got {self.speed_input!r}")
        if self.expert is not None and not re.fullmatch(r"[a-z0-9_]+", str(self.expert)):
            raise ValueError(f"protocol.expert must be a variant name of lowercase letters, digits and _ "
                             f"(e.g. ppo), got {self.expert!r}")

    @property
    def family(self) -> str:
        """The family the protocol is listed under (`FAMILIES`: `"mujoco-state"` for the paper's and its variants)."""
        return protocol_family(self.name)

    def expert_name(self, env: str) -> str:
        """The shipped expert this protocol's demonstrations come from: `env`, or `env-<expert>` for a variant
        (`envs.experts.load` takes either)."""
        return env if self.expert is None else f"{env}-{self.expert}"

    def settings(self, standard_frame_skip: int | None) -> dict[str, Any]:
        """Every field, resolved for an environment whose own frame skip is `standard_frame_skip` (None: not a
        Brax environment): what results.json records as `protocol`."""
        skip = self.frame_skip or standard_frame_skip
        out = {"name": self.name, "frame_skip": skip, "standard_frame_skip": standard_frame_skip,
               "episode_length": None, "reward_scale": 1.0, "collect_transitions": self.collect_transitions,
               "train_transitions": self.train_transitions,
               "val_transitions": self.val_transitions, "history": self.history, "split": self.split,
               "eval_steps": self.eval_steps}
        if self.expert is not None:  # only when set: records and cache names from before the field stay valid
            out["expert"] = self.expert
        if self.labels != "clipped":  # the same: only where it differs from what every earlier file did
            out["labels"] = self.labels
        if self.prev_action:
            out["prev_action"] = True
        if self.frames != "rollout":
            out["frames"] = self.frames
        if self.history_stride != 1:
            out["history_stride"] = self.history_stride
        out.update({k: v for k, v in self.task_settings().items()})
        out.update({f"eval_{k}": v for k, v in self.eval_settings().items()})
        if self.noise_frac > 0:
            out.update(noise_frac=self.noise_frac, noise_steps=self.noise_steps, noise_std=self.noise_std)
        if standard_frame_skip is not None and self.frame_skip is not None:
            out["reward_scale"] = self.frame_skip / standard_frame_skip
        if self.horizon is not None and standard_frame_skip is not None:
            out["episode_length"] = self.horizon * standard_frame_skip // skip
        return out

    def env_overrides(self, standard_frame_skip: int | None) -> dict[str, Any]:
        """The `envs.make` settings this protocol fixes (frame skip, episode length, reward scale)."""
        s = self.settings(standard_frame_skip)
        out: dict[str, Any] = {}
        if self.frame_skip is not None:
            out.update(n_frames=self.frame_skip, reward_scale=s["reward_scale"])
        if s["episode_length"] is not None:
            out["episode_length"] = s["episode_length"]
        return {**out, **self.task_settings()}

    def task_settings(self) -> dict[str, Any]:
        """The task's own settings this protocol fixes for collection and evaluation (`traffic`, `speed_input`,
        `task_version`, `reveal`), where set."""
        out = {k: getattr(self, k) for k in ("traffic", "speed_input", "task_version") if getattr(self, k) is not None}
        return {**out, **({"reveal": tuple(self.reveal)} if self.reveal else {})}

    @property
    def history_span(self) -> int:
        """Control steps a history of `history` frames at `history_stride` covers, the current one included."""
        return (self.history - 1) * self.history_stride + 1

    def eval_settings(self) -> dict[str, Any]:
        """The task's settings evaluation changes (`town`, `weather`: held-out layouts and palette)."""
        return {k: getattr(self, f"eval_{k}") for k in ("town", "weather") if getattr(self, f"eval_{k}") is not None}



def _state(frame_skip: int = 1, train: int = 20_000) -> Protocol:
    """The paper's MuJoCo-State protocol (the FCA code's data setting, which the paper follows) at simulator frame
    skip `frame_skip` with `train` training transitions: the same 500 standard steps of simulated time and 4,000
    validation transitions at any frame skip; the expert steps collected are its 50,000, or `train` + 10,000 where
    that is more."""
    skip = "" if frame_skip == 1 else f"-fs{frame_skip}"
    name = f"{STATE}{skip}" + ("" if train == 20_000 else f"-train{train // 1000}k")
    if name == STATE:
        doc = ("the paper's MuJoCo-State setting (FCA's code): frame skip 1, 500 standard steps of simulated time, "
               "rewards on the standard-step scale, 50,000 expert steps of which 20,000 train and 4,000 validate, rows "
               "drawn by a fixed permutation")
    elif train == 20_000:
        doc = (f"the copycat map's {STATE} at frame skip {frame_skip}: its simulated time, rewards and data sizes, "
               f"{frame_skip} simulator steps per control step")
    else:
        doc = (f"the copycat map's {STATE}{skip} with {train:,} training transitions instead of 20,000: as much "
               f"simulated time of demonstrations as {train * frame_skip // 4:,} frame-skip-4 steps")
    return Protocol(name, frame_skip=frame_skip, horizon=500, collect_transitions=max(50_000, train + 10_000),
                    train_transitions=train, val_transitions=4_000, doc=doc, split="rows",
                    reference=None if train == 20_000 else f"{STATE}{skip}")


def _palr(history: int) -> Protocol:
    """PALR's setting (Seo et al., NeurIPS 2023; `KAIST-AILab/palr` `train.py` and `core/preprocess.py`) at history
    `history`: D4RL's `*-expert-v2` data, gym's frame skip and 1,000-step episodes (Brax's own here), the first
    30,000 transitions training and 2,000 from other episodes validating, positions only (`--obs pos`).

    Differences, chosen: the shipped expert demonstrates, not D4RL's (whose files cannot be fetched here), on
    whole episodes (30 of 1,000 steps, where theirs are D4RL's first 30,000 rows); HalfCheetah keeps its 8 joint
    positions (`obs="pos"`, `qpos[1:]`), where PALR's mask (`[0:4] + [8:13]`) keeps 4 positions and 5
    velocities (the root's x, z and pitch velocities and two joints'): with those velocities in view the past adds
    little and the copycat question is a different one, so every task here is positions only, as FCA's setting
    is. Their batch (1,024), learning rate (3e-4, constant) and 500,000 iterations are the `mlp-b1024` recipe's and
    `--set budget.iterations=500000`.
    """
    return Protocol(f"palr-h{history}", collect_transitions=40_000, train_transitions=30_000, val_transitions=2_000,
                    history=history, split="episodes", reference="brax",
                    doc=f"PALR's setting (Seo et al. 2023) at history {history}: Brax's frame skip and 1,000-step "
                        f"episodes, 30,000 training and 2,000 validation transitions of whole episodes, positions "
                        f"only (HalfCheetah's 8, not PALR's mask with 5 velocities); the mlp-b1024 recipe")


def _nocrash(speed_input: bool) -> Protocol:
    """NoCrash-Dense on ToyTown (the supplement's Table 1 with the speed in view, Table 2 without): dense traffic,
    demonstrations in the training layouts with CARLA100's noise (10% of the executed actions perturbed, in
    1-second bursts, labels kept), policies evaluated in the held-out layouts (NoCrash's new town) under the
    training palette (`--set protocol.eval_weather=test` for new weather too)."""
    name, doc = ("nocrash", "NoCrash-Dense with the speed in view (CARLA, supplement Table 1)") if speed_input else (
        "nocrash-nospeed", "NoCrash-Dense without the speed (CARLA-w/o-speed, supplement Table 2)")
    return Protocol(name, traffic="dense", speed_input=speed_input, eval_town="test", noise_frac=0.1, noise_steps=10,
                    noise_std=0.3, doc=f"{doc}: dense traffic, demonstrations in the training layouts with 10% of "
                                       f"the executed actions perturbed in 1 s bursts (labels kept), evaluation in "
                                       f"the held-out layouts")


# The copycat map (BENCHMARKS.md) compares mujoco-state at frame skips 1, 2 and 4 (where does the history stop
# helping?), and at frame skip 1 with a quarter and four times the training transitions (80,000 at frame skip 1
# cover the simulated time 20,000 cover at frame skip 4: is it the frame rate, or how much of the task the data
# shows?).
# PALR's paper runs every method at histories 2 and 4 (`palr-h2`, `palr-h4`).
STATE_FRAME_SKIPS = (1, 2, 4)
STATE_TRAIN_SIZES = (5_000, 80_000)
PALR_HISTORIES = (2, 4)
# The protocols by family: a family is one setting and its variants (the paper's at other frame skips and
# training-set sizes: `mujoco-state-fs2`, ...; PALR's at other histories), which the report reads together (the copycat
# map, Table 5 on the paper's scale). A protocol belongs to the family it is listed under, never by its name.
FAMILIES: Mapping[str, tuple[Protocol, ...]] = MappingProxyType({
    STATE: (*(_state(k) for k in STATE_FRAME_SKIPS), *(_state(1, n) for n in STATE_TRAIN_SIZES)),
    "brax": (Protocol("brax", doc="the environment's own settings: Brax's frame skip and 1,000-step episodes for "
                                  "MuJoCo"),),
    "palr": tuple(_palr(h) for h in PALR_HISTORIES),
    "nocrash": (_nocrash(True), _nocrash(False)),
})
PROTOCOLS: Mapping[str, Protocol] = MappingProxyType({p.name: p for ps in FAMILIES.values() for p in ps})
_FAMILY_OF = {p.name: family for family, ps in FAMILIES.items() for p in ps}
DRIVING_FAMILIES = ("nocrash",)  # the protocols that set a driving task's own settings (ToyTown's)

def protocol_family(name: str) -> str:
    """The family (`FAMILIES`) of the protocol named `name`; a name no family lists (a results file's from
    elsewhere) is a family of its own."""
    name = protocol_name(name)
    return _FAMILY_OF.get(name, name)
