"""A sweep's setup, resolved once from its task, observation mode and protocol: how the protocol applies to the
environment, who demonstrates (`ExpertRef`), the returns results are normalised by, and the key that names the
demonstrations. Resolving it is pure data: it reads the expert's card and references (JSON), builds no MJX
environment and restores no checkpoint; the expert's policy is loaded on first use, once.

    setup = Setup.resolve("hopper", "pos", tasks.get("hopper").protocol("fca", "pos"))
    setup.data_key           # names the cached demonstrations (`data.cache_path`); part of the sweep's fingerprint
    setup.expert.policy()    # the expert as `full_obs -> action`, loaded here the first time, then reused
    setup.references()       # its returns under the protocol (None for a rule-based expert)

The sweep (`SweepSpec.setup`), `experiments.collect`, `experiments.keyframes` and the collection itself
(`collect.collect_cached`) read this record instead of deriving the expert, its description or the data's
name again. This is the one file that says how a protocol applies to an environment (`protocol_setup`).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
from collections.abc import Callable
from typing import Any

import envs
from ape_jax import tasks
from ape_jax.pipeline import data as data_lib


@dataclasses.dataclass(frozen=True)
class ProtocolSetup:
    """A protocol as it applies to one environment: what the sweep, `experiments.collect` and the keyframe picture
    collect under it, so the three name the same cached dataset.

    Attributes:
      name: the protocol's name (`ape_jax.tasks.PROTOCOLS`).
      settings: every field, resolved for the environment (results.json's `protocol`).
      env_overrides: the `envs.make` settings it fixes (frame skip, episode length, reward scale).
      episodes: expert episodes to collect: as many whole episodes as its expert steps take, else the task's.
      expert: the expert variant demonstrating (`ape_jax.tasks.Protocol.expert`; None: the task's own).
      labels: what the demonstrations store as the label, `"clipped"` or `"raw"` (`ape_jax.tasks.Protocol.labels`).
    """

    name: str
    settings: dict
    env_overrides: dict
    episodes: int
    expert: str | None = None
    labels: str = "clipped"


def protocol_setup(env_name: str, obs: str, protocol: str | tasks.Protocol | None = None) -> ProtocolSetup:
    """Protocol `protocol` (a name, None: the task's default for `obs`, or a record, e.g. with `--set` changes) for
    `env_name`; `ValueError` for one the task cannot take. Builds no environment."""
    if isinstance(protocol, tasks.Protocol):
        tasks.get(env_name).protocol(protocol.name, obs)  # ValueError for a protocol the task cannot take
        proto = protocol
    else:
        proto = tasks.get(env_name).protocol(protocol, obs)
    _check_task_settings(env_name, proto)
    proto = with_task_version(env_name, proto)
    brax = env_name in envs.brax_env.brax_names()
    standard = envs.brax_env.default_frame_skip(env_name) if brax else None
    settings = proto.settings(standard)
    if settings["episode_length"] is None:
        settings["episode_length"] = envs.default_episode_length(env_name)
    episodes = (-(-proto.collect_transitions // settings["episode_length"]) if proto.collect_transitions is not None
                else proto.episodes or tasks.get(env_name).episodes)
    return ProtocolSetup(proto.name, settings, proto.env_overrides(standard), episodes, proto.expert, proto.labels)


def with_task_version(env_name: str, proto: tasks.Protocol) -> tasks.Protocol:
    """`proto` with the task version it runs (`tasks.Protocol.task_version`) made explicit: the task's current one
    where it has versions (ToyTown's `task_version`) and `proto` names none; `proto` itself otherwise. So data keys,
    results and fingerprints record the version, and a replay rebuilds the same task after the default moves."""
    version = current_task_version(env_name)
    return proto if proto.task_version is not None or version is None else dataclasses.replace(proto,
                                                                                               task_version=version)


def current_task_version(env_name: str) -> int | None:
    """The version a registered task with versions (a `task_version` setting) is made at by default; else None."""
    spec = envs.registry.get(env_name)
    return spec.default_config().task_version if spec is not None and "task_version" in spec.settings() else None


def _check_task_settings(env_name: str, proto: tasks.Protocol) -> None:
    """`ValueError` where `proto` sets a task setting (`Protocol.task_settings`, `eval_settings`) that `env_name`
    does not have (a speed input asked of Hopper)."""
    asked = {**proto.task_settings(), **proto.eval_settings()}
    if not asked:
        return
    spec = envs.registry.get(env_name)
    has = set(spec.settings()) if spec is not None else set()
    missing = [k for k in asked if k not in has]
    if missing:
        names = ", ".join(f"protocol.{k if k in proto.task_settings() else 'eval_' + k}" for k in missing)
        raise ValueError(f"{names}: {env_name} has no such setting (a driving task's, e.g. toytown's)")


@dataclasses.dataclass(frozen=True, eq=False)
class ExpertRef:
    """Who demonstrates, resolved from its card: the environment's rule-based expert, a shipped checkpoint
    (`envs/experts/<name>/`) or an imported one (the user's expert directory, `envs.experts.user_root`).

    Attributes:
      env: the environment.
      variant: the expert variant (`ape_jax.tasks.Protocol.expert`; None: the task's own).
      description: how demonstrations and results name it (the data key's `expert`): its kind and, for a
        checkpoint, its path, card SHA-256, algorithm and returns; for an imported expert, its file's format,
        SHA-256 and origin; for a rule-based one, the rule and the environment settings it drives.
    """

    env: str
    variant: str | None
    description: dict
    _loaded: dict = dataclasses.field(default_factory=dict, repr=False)  # the policy, once loaded

    @property
    def name(self) -> str:
        """The expert's directory name, `env` or `env-variant` (`envs.experts.load` takes it)."""
        return self.env if self.variant is None else f"{self.env}-{self.variant}"

    @property
    def kind(self) -> str:
        """`"rule-based"`, `"checkpoint"` or `"imported"`."""
        return self.description["kind"]

    @classmethod
    def resolve(cls, env_name: str, variant: str | None = None, env_overrides: dict | None = None,
                env: envs.Env | None = None) -> ExpertRef:
        """The expert of `env_name` (with `variant`, the one shipped or imported under `<env>-<variant>`), from its
        card alone. A rule-based expert's description records the settings of the environment it drives
        (ToyCar's physics: a changed default must not reuse demonstrations cached before it): `env`'s, else those
        of one made with `env_overrides`.

        Raises:
          ValueError: a variant of a rule-based expert.
          envs.experts.ExpertError: no such expert (naming the command that trains or imports one).
        """
        from envs import experts

        if tasks.get(env_name).expert == "rule-based":
            if variant is not None:
                raise ValueError(f"{env_name}'s expert is rule-based: it has no variant {variant!r} "
                                 "(protocol.expert)")
            env = env or envs.make(env_name, **(env_overrides or {}))  # ToyCar: plain Python, nothing compiled
            config = getattr(env, "config", None)
            config = json.loads(json.dumps(dataclasses.asdict(config))) if dataclasses.is_dataclass(config) else None
            return cls(env_name, None, {"kind": "rule-based", "function": f"{type(env).__module__}.expert_action",
                                        "config": config})
        name = env_name if variant is None else f"{env_name}-{variant}"
        card = experts.card(name)
        if experts.is_imported(name):
            source = card.get("source", {})
            return cls(env_name, variant, {
                "kind": "imported", "name": name, "variant": variant, "format": source.get("format"),
                "sha256": source.get("sha256"), "origin": source.get("origin"),
                "network": {k: v for k, v in card["network"].items() if k != "layer_sizes"}})
        card_file = experts.directory(name) / experts.CARD
        return cls(env_name, variant, {
            "kind": "checkpoint", "path": f"envs/experts/{name}",
            "card_sha256": hashlib.sha256(card_file.read_bytes()).hexdigest(),
            "algorithm": card.get("algorithm"), "return_mean": card.get("return_mean"),
            "return_std": card.get("return_std"), "random_return_mean": card.get("random_return_mean"),
            "env_steps": card.get("env_steps"),
        })

    @classmethod
    def of_key(cls, key: dict) -> ExpertRef:
        """The expert a data key names (`data_key`), resolved again from its card (a dataset collected earlier)."""
        variant = variant_of(key["env"], key.get("expert") or {})
        overrides = {k: (tuple(v) if isinstance(v, list) else v) for k, v in key.get("env_overrides", {}).items()}
        return cls.resolve(key["env"], variant, overrides)

    def policy(self, env: envs.Env | None = None) -> Callable[[Any], Any]:
        """The expert as `full_obs -> action`, its output as it gives it (unbounded for a `"linear"` head:
        `collect.labeller` clips it for the labels it stores); a checkpoint is restored the first time and reused.
        A rule-based expert is its environment's `expert` (`env` is needed)."""
        if self.kind == "rule-based":
            if env is None:
                raise ValueError(f"{self.env}'s rule-based expert needs its environment")
            return env.expert
        if "policy" not in self._loaded:
            from envs import experts

            self._loaded["policy"] = experts.load(self.name)
        return self._loaded["policy"]


def variant_of(env_name: str, description: dict) -> str | None:
    """The expert variant an expert's description (`ExpertRef.description`) names: an imported expert's `variant`,
    else the suffix of the shipped expert's directory, if any."""
    if description.get("kind") == "imported":
        return description.get("variant")
    name = (description.get("path") or "").rsplit("/", 1)[-1]
    return name[len(env_name) + 1:] if name.startswith(env_name + "-") else None


def data_key(env_name: str, obs: str, episodes: int, expert: ExpertRef, *, seed: int = 0, noise_frac: float = 0.0,
             noise_std: float = 0.0, batch: int = 32, labels: str = "clipped", frames: str = "rollout",
             noise_steps: int = 1, **env_overrides) -> dict:
    """The collection settings that name a cached dataset (`data.cache_path`) and enter a sweep's fingerprint
    (`collect.data_key` takes the same arguments in the same order, the expert by name):
    the task, observation mode, episodes, seed, noise, batch, environment settings, the expert's description
    and the storage format; `labels`, `frames` (`tasks.Protocol.frames`) and `noise_steps` (bursts) recorded only
    when not their default, so the names of datasets collected before those fields stay valid."""
    if labels not in tasks.LABELS:
        raise ValueError(f"labels {labels!r} is not one of {', '.join(tasks.LABELS)}")
    if frames not in tasks.FRAMES or (frames != "rollout" and obs != "image"):
        raise ValueError(f"frames {frames!r} is not one of {', '.join(tasks.FRAMES)} (states: images only)")
    overrides = {k: (list(v) if isinstance(v, tuple) else v) for k, v in sorted(env_overrides.items())}
    return {"env": env_name, "obs": obs, "episodes": int(episodes), "seed": int(seed),
            "noise_frac": float(noise_frac), "noise_std": float(noise_std), "batch": int(batch),
            "env_overrides": overrides, "expert": expert.description, "format": data_lib.FORMAT,
            **({"labels": labels} if labels != "clipped" else {}),
            **({"frames": frames} if frames != "rollout" else {}),
            **({"noise_steps": int(noise_steps)} if noise_steps != 1 else {})}


def state_source(key: dict) -> dict:
    """The data key of the state dataset whose simulator states a `frames: "states"` image dataset (`key`)
    renders: the same settings observing positions (`obs="pos"`), without the image size. `key` itself where its
    frames come from the rollout."""
    if key.get("frames", "rollout") == "rollout":
        return key
    source = {k: v for k, v in key.items() if k != "frames"}
    source["obs"] = "pos"
    source["env_overrides"] = {k: v for k, v in key["env_overrides"].items() if k != "image_size"}
    return source


def reference_returns(env_name: str, protocol: tasks.Protocol) -> dict | None:
    """The returns results are normalised by under `protocol` (`envs.experts.reference`: the expert's mean return
    `return_mean` and a random policy's `random_return_mean`, measured under the protocol), None for a task
    whose expert has no card (a rule-based one, e.g. ToyCar's).

    Raises:
      envs.experts.ExpertError: no reference measured under the protocol (naming the command that measures it).
    """
    if not tasks.get(env_name).has_card:
        return None
    from envs import experts

    key, error = protocol.reference or protocol.name, None
    for name in (key, *(old for old, new in tasks.FORMER_PROTOCOLS.items() if new == key)):  # measured before
        try:                                                                                # the renaming
            return experts.reference(protocol.expert_name(env_name), name)
        except experts.ExpertError as e:
            error = error or e
    raise error


@dataclasses.dataclass(frozen=True, eq=False)
class Setup:
    """One task, observation mode and protocol, resolved once (`resolve`).

    Attributes:
      env, obs: the task and observation mode.
      protocol: the protocol record (with any `--set` changes).
      applied: the protocol as it applies to the environment (`protocol_setup`).
      collection: the `envs.make` settings demonstrations are collected with (the protocol's, and the image size).
      evaluation: the settings policies are evaluated with (the collection's, and the protocol's `eval_steps`).
      episodes: expert episodes collected: as many as the protocol's expert steps take, else its or the task's.
    The expert (`expert`), its references (`references`) and the data key (`data_key`) are resolved on first
    use, once: a setup for a `--dataset` sweep never reads the protocol's expert.
    """

    env: str
    obs: str
    protocol: tasks.Protocol
    applied: ProtocolSetup
    collection: dict
    evaluation: dict
    episodes: int

    @classmethod
    def resolve(cls, env: str, obs: str, protocol: tasks.Protocol) -> Setup:
        """The setup of `env`/`obs` under `protocol`; `ValueError` for a protocol the task cannot take."""
        applied = protocol_setup(env, obs, protocol)
        size = protocol.image_size
        collection = {**applied.env_overrides, **({"image_size": size} if obs == "image" and size else {})}
        steps = protocol.eval_steps
        evaluation = {**collection, **({"episode_length": steps} if steps is not None else {}),
                      **protocol.eval_settings()}
        return cls(env, obs, protocol, applied, collection, evaluation, applied.episodes)

    @functools.cached_property
    def expert(self) -> ExpertRef:
        """The protocol's expert (`ExpertRef.resolve`), from its card."""
        return ExpertRef.resolve(self.env, self.protocol.expert, self.collection)

    @functools.cached_property
    def data_key(self) -> dict:
        """What names the demonstrations the protocol's expert gives (`data_key`, seed 0)."""
        p = self.protocol
        return data_key(self.env, self.obs, self.episodes, self.expert, labels=p.labels,
                        frames=p.frames if self.obs == "image" else "rollout", noise_frac=p.noise_frac,
                        noise_std=p.noise_std, noise_steps=p.noise_steps if p.noise_frac > 0 else 1,
                        **self.collection)

    def references(self) -> dict | None:
        """The expert's returns under the protocol (`reference_returns`), read once."""
        if "_references" not in self.__dict__:   # a frozen record: cached beside its fields, as cached_property does
            self.__dict__["_references"] = reference_returns(self.env, self.protocol)
        return self.__dict__["_references"]
