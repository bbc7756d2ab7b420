"""What a sweep is before it starts: its `SweepSpec`, the runs it holds, and the checks that refuse it early.

    spec = SweepSpec.make("hopper", methods=("bc-so", "bc-oh"), preset="quick", recipe="fca")
    spec.fingerprint()        # what a checkpoint and a finished results.json are compared by

A spec holds the task, the observation mode, the methods and the three records
that fix everything else (`ape_jax.pipeline.presets.Settings`: protocol, budget,
recipe). Its `fingerprint` is `ape_jax.pipeline.results.fingerprint`, the one a
finished `results.json` gives too. A `Run` is one (method, hparams, seed) of it;
`grid_runs` lists them in plan order. `check_protocol` and `check_fits` refuse
demonstrations of another protocol or shape before anything compiles. The phases
that run a spec are `ape_jax.pipeline.sweep`'s.
"""

from __future__ import annotations

import dataclasses
import functools
import pathlib
from collections.abc import Sequence

import jax
import numpy as np

from ape_jax import methods as methods_lib
from ape_jax import tasks
from ape_jax.pipeline import results as results_lib
from ape_jax.pipeline.data import Demonstrations
from ape_jax.pipeline.presets import Settings, resolve
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

    def __post_init__(self):
        for m in self.methods:
            method = methods_lib.get(m)  # MethodError for an unknown name
            why = method.refuses(self.settings, self.obs) if method.refuses is not None else None
            if why:
                raise ValueError(why)
        _ = self.setup  # ValueError for a protocol the task cannot take
        length, history = self.setup.applied.settings.get("episode_length"), self.protocol.history
        if isinstance(length, int) and history > length:
            raise ValueError(f"protocol.history {history} is longer than an episode ({length:,} steps): a history "
                             f"can hold at most the frames one episode stores")
        if self.protocol.prev_action and self.obs == "image":
            raise ValueError("protocol.prev_action needs vector observations (--obs pos or full): a frame has no "
                             "place for the previous action")

    @classmethod
    def make(cls, env: str, obs: str | None = None, methods: Sequence[str] | None = None, protocol: str | None = None,
             preset: str = "quick", recipe: str | None = None, sets: Sequence[str] = (), **kw) -> SweepSpec:
        """A spec from names, as the command line gives them (defaults: the task's observation mode and protocol,
        the default methods, the protocol's recipe); `kw`: `dataset`, `data_dir`, `command`."""
        obs = obs or tasks.get(env).default_obs
        settings = resolve(env, obs, protocol=protocol, preset=preset, recipe=recipe, sets=sets)
        return cls(env, obs, settings, tuple(methods if methods is not None else methods_lib.default()), **kw)

    @property
    def task(self) -> tasks.Task:
        return tasks.get(self.env)

    @property
    def protocol(self) -> tasks.Protocol:
        return self.settings.protocol

    @property
    def budget(self):
        return self.settings.budget

    @property
    def recipe(self):
        return self.settings.recipe

    @property
    def preset_name(self) -> str:
        return self.settings.preset

    @functools.cached_property
    def setup(self) -> Setup:
        """The task, observation mode and protocol resolved once (`setup.Setup`): how the protocol applies to the
        environment, its expert, references and data key. Pure data: nothing is built or restored."""
        return Setup.resolve(self.env, self.obs, self.protocol)

    @property
    def episodes(self) -> int:
        """Expert episodes collected: as many as the protocol's expert steps take, else its or the task's count."""
        return self.setup.episodes

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
            return self.setup.data_key
        path = pathlib.Path(self.dataset)
        files = ([path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
                 if path.is_dir() else [])
        return {"dataset": str(path.absolute()), "bytes": sum(p.stat().st_size for p in files)}

    def fingerprint(self) -> dict:
        """Everything that determines the results (`results.fingerprint`; `checkpoint.SweepCheckpoint` compares
        these, and so does a rerun with a finished `results.json`)."""
        return results_lib.fingerprint(self.env, self.obs, self.preset_name, self.settings.to_json(), self.methods,
                                       self.data_settings(), self.protocol_settings())


def grid_runs(names: Sequence[str], seeds: int, ctx: methods_lib.GridContext, first_seed: int = 0) -> list[Run]:
    """Every (method, hparams, seed) of the sweep, seeds `first_seed, ..., first_seed + seeds - 1`: methods in
    registry order, then settings, then seeds."""
    order = [m for m in methods_lib.names() if m in names]
    return [Run(m, settings, seed) for m in order for settings in methods_lib.get(m).settings(ctx)
            for seed in range(first_seed, first_seed + seeds)]


PROTOCOL_KEYS = ("n_frames", "episode_length", "reward_scale")  # the collection settings a protocol fixes


def check_protocol(recorded: dict | None, spec: SweepSpec, where: str) -> None:
    """Refuses (ValueError, one line) a dataset whose recorded collection settings are of another protocol.

    `recorded`: the dataset's collection settings (`minari_io.dataset_settings`); None (a dataset that
    records none, e.g. your own or a Minari one) cannot be checked and passes.
    """
    if recorded is None:
        return
    had = {k: v for k, v in (recorded.get("env_overrides") or {}).items() if k in PROTOCOL_KEYS}
    want = {k: v for k, v in spec.collection_overrides().items() if k in PROTOCOL_KEYS}
    if had != want:
        raise ValueError(f"{where} was collected with {had or 'the environment defaults'}, not under the "
                         f"{spec.protocol.name!r} protocol's {want or 'environment defaults'}; pass the --protocol it "
                         "was collected under, or collect it again")


def check_fits(demos: Demonstrations, env, where: str) -> None:
    """Refuses (ValueError, one line) demonstrations whose observations or actions the environment cannot take."""
    obs_shape, action_dim = tuple(np.shape(demos.obs)[1:]), int(np.shape(demos.action)[1])
    if obs_shape != tuple(env.observation_shape) or action_dim != env.action_size:
        raise ValueError(f"{where}: observations {list(obs_shape)} and {action_dim}-d actions do not fit "
                         f"{env.name!r}, which has observations {list(env.observation_shape)} and "
                         f"{env.action_size}-d actions; pick the matching --env/--obs")
    if len(env.observation_shape) == 3 and np.asarray(demos.obs).dtype != np.uint8:
        raise ValueError(f"{where}: image observations must be uint8, got {np.asarray(demos.obs).dtype}")

