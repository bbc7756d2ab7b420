"""What a sweep is before it starts: its `SweepSpec`, the runs it holds, and the checks that refuse it early.

    spec = SweepSpec.make("hopper", methods=("bc-so", "bc-oh"), preset="quick", recipe="fca")
    spec.fingerprint()        # what a checkpoint and a finished results.json are compared by

A spec holds the task, the observation mode, the methods and the three records
that fix everything else (`ape_jax.pipeline.presets.Settings`: protocol, budget,
recipe). Its `fingerprint` is `ape_jax.pipeline.results.fingerprint`, the one a
finished `results.json` gives too. A `Run` is one (method, hparams, seed) of it
(`sweep.grid_runs` lists them in plan order). The spec refuses, when it is made, what
cannot run (a method's `refuses`, a history longer than an episode, ...); the checks of
the demonstrations themselves (`check_protocol`, `check_fits`) are the prepare phase's
(`ape_jax.pipeline.prepare`). The phases that run a spec are `ape_jax.pipeline.sweep`'s.
"""

from __future__ import annotations

import copy
import dataclasses
import pathlib
from collections.abc import Sequence

import jax

import envs

from ape_jax import methods as methods_lib
from ape_jax import tasks
from ape_jax.pipeline import results as results_lib
from ape_jax.pipeline.presets import Budget, Recipe, Settings, resolve
from ape_jax.pipeline.setup import Setup


@dataclasses.dataclass(frozen=True)
class Run:
    """One trained configuration: method, hyperparameters, seed (its identity, and so its PRNG key)."""

    method: str
    hparams: dict
    seed: int

    @property
    def key(self) -> jax.Array:
        return methods_lib.run_key(self.seed, self.method, self.hparams)

    @property
    def ident(self) -> tuple:
        """A hashable identity: `(method, sorted hparams items, seed)`."""
        return self.method, tuple(sorted(self.hparams.items())), self.seed


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """Everything that fixes a sweep before it starts (its checkpoint fingerprint).

    Attributes:
      env, obs: the task and observation mode.
      settings: the protocol, budget and recipe (`presets.resolve(env, obs, ...)`).
      methods: registered method names (`ape_jax.methods`).
      dataset: train from this dataset (`minari_io.load_dataset`) instead of
        the shipped expert's demonstrations; it must fit `env`/`obs`.
      data_dir: the demonstration cache (None: `ape_jax.pipeline.data.cache_dir()`).
      command: the command line, recorded in results.json.
    """

    env: str
    obs: str
    settings: Settings
    methods: tuple[str, ...]
    dataset: str | None = None
    data_dir: pathlib.Path | None = None
    command: tuple[str, ...] | None = None
    # resolved once, from the fields above (`__post_init__`): read them, never derive them again
    task: tasks.Task = dataclasses.field(init=False, repr=False, compare=False)
    protocol: tasks.Protocol = dataclasses.field(init=False, repr=False, compare=False)
    budget: Budget = dataclasses.field(init=False, repr=False, compare=False)
    recipe: Recipe = dataclasses.field(init=False, repr=False, compare=False)
    preset_name: str = dataclasses.field(init=False, repr=False, compare=False)
    setup: Setup = dataclasses.field(init=False, repr=False, compare=False)

    def __post_init__(self):
        several = jax.process_count() > 1   # the policies a method reads are sharded over the processes' devices
        for m in self.methods:
            method = methods_lib.get(m)  # MethodError for an unknown name
            why = method.refuses(self.settings, self.policy_obs) if method.refuses is not None else None
            if why or (why := methods_lib.unread(m, self.settings.knobs, self.methods)):
                raise ValueError(why)
            if several and (read := methods_lib.read_by(m, self.settings.knobs)):
                raise ValueError(f"{m} reads {read}'s trained policies, which a multi-process sweep does not "
                                 "gather: run it in one process")
        resolved = {"task": tasks.get(self.env), "protocol": self.settings.protocol, "budget": self.settings.budget,
                    "recipe": self.settings.recipe, "preset_name": self.settings.preset,
                    # the task, observation mode and protocol (`setup.Setup`): how the protocol applies to the
                    # environment, its expert, references and data key. Pure data: nothing is built or restored.
                    # ValueError for a protocol the task cannot take.
                    "setup": Setup.resolve(self.env, self.obs, self.settings.protocol)}
        for name, value in resolved.items():
            object.__setattr__(self, name, value)
        length, history = self.setup.applied.settings.get("episode_length"), self.protocol.history
        if isinstance(length, int) and self.protocol.history_span > length:
            stride = self.protocol.history_stride
            span = f" at stride {stride} ({self.protocol.history_span:,} steps)" if stride > 1 else ""
            raise ValueError(f"protocol.history {history}{span} is longer than an episode ({length:,} steps): a "
                             f"history can hold at most the frames one episode stores")
        if self.protocol.prev_action and self.policy_obs == "image":
            raise ValueError("protocol.prev_action needs vector observations (--obs pos or full): a frame has no "
                             "place for the previous action")
        if self.protocol.frames == "states":
            if self.obs != "image":
                raise ValueError("protocol.frames=states: for image observations (--obs image) only")
            if self.dataset is not None:
                raise ValueError("protocol.frames=states renders the cached state dataset the protocol names; a "
                                 "--dataset brings its own frames: leave protocol.frames at rollout")
            if "pos" not in envs.obs_modes(self.env):
                raise ValueError(f"protocol.frames=states: {self.env!r} has no positions-only dataset to render "
                                 "(the MuJoCo tasks only)")

    @classmethod
    def make(cls, env: str, obs: str | None = None, methods: Sequence[str] | None = None, protocol: str | None = None,
             preset: str = "quick", recipe: str | None = None, sets: Sequence[str] = (), **kw) -> SweepSpec:
        """A spec from names, as the command line gives them (defaults: the task's observation mode and protocol,
        the default methods, the protocol's recipe); `kw`: `dataset`, `data_dir`, `command`."""
        obs = obs or tasks.get(env).default_obs
        settings = resolve(env, obs, protocol=protocol, preset=preset, recipe=recipe, sets=sets)
        return cls(env, obs, settings, tuple(methods if methods is not None else methods_lib.default()), **kw)

    @property
    def policy_obs(self) -> str:
        """What the policies observe: `"embedding"` where the frames are seen through a frozen perception encoder
        (`recipe.perception`: vectors, as a state is), else the sweep's observation mode (a fine-tuned encoder's
        policies see frames)."""
        r = self.settings.recipe
        return "embedding" if self.obs == "image" and r.perception != "none" and r.perception_training == "frozen" \
            else self.obs

    @property
    def episodes(self) -> int:
        """Expert episodes collected: as many as the protocol's expert steps take, else its or the task's count."""
        return self.setup.applied.episodes

    def protocol_settings(self) -> dict:
        """Every field of the protocol as it applies to this environment (results.json's `protocol`)."""
        return dict(self.setup.applied.settings)

    def collection_overrides(self) -> dict:
        """The `envs.make` settings demonstrations are collected with: the protocol's, and the image size."""
        return dict(self.setup.collection)

    def env_overrides(self) -> dict:
        """The `envs.make` settings policies are evaluated with: the collection's, and the protocol's `eval_steps`."""
        return dict(self.setup.evaluation)

    def data_settings(self) -> dict:
        """What names the demonstrations: the protocol's expert's data key (`Setup.data_key`), or the dataset
        file's path and size."""
        if self.dataset is None:
            return copy.deepcopy(self.setup.data_key)   # the caller's own: the setup's stays as resolved
        path = pathlib.Path(self.dataset)
        files = ([path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
                 if path.is_dir() else [])
        return {"dataset": str(path.absolute()), "bytes": sum(p.stat().st_size for p in files)}

    def fingerprint(self) -> dict:
        """Everything that determines the results (`results.fingerprint`; `checkpoint.SweepCheckpoint` compares
        these, and so does a rerun with a finished `results.json`)."""
        return results_lib.fingerprint(self.env, self.obs, self.preset_name, self.settings.to_json(), self.methods,
                                       self.data_settings(), self.protocol_settings())
