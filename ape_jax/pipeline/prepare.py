"""A sweep's first two phases (`ape_jax.pipeline.sweep`): `prepare` (the environment, the demonstrations split
as the protocol says, their expert and references, the observation normaliser) and `fit_ape` (ψ on the training
actions, both splits' APE)."""

from __future__ import annotations

import copy
import dataclasses
import pathlib
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import ape as ape_lib
from ape_jax import methods as methods_lib
from ape_jax import observations, tasks
from ape_jax.learner import Data, LearnerConfig
from ape_jax.pipeline import checkpoint as ckpt_lib
from ape_jax.pipeline import collect, minari_io
from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline.checkpoint import SweepCheckpoint
from ape_jax.pipeline.data import Demonstrations, Part
from ape_jax.pipeline.hooks import Hooks
from ape_jax.pipeline.presets import Settings
from ape_jax.pipeline.spec import SweepSpec
from ape_jax.pipeline.training import trains_sequentially

# -- 1. prepare -----------------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Normalizer:
    """Per-dimension standardisation of state observations with training statistics; images pass as they are."""

    mean: np.ndarray | None
    std: np.ndarray | None

    @classmethod
    def fit(cls, obs: np.ndarray) -> Normalizer:
        obs = np.asarray(obs)
        if obs.dtype == np.uint8:
            return cls(None, None)
        return cls(obs.mean(0).astype(np.float32), (obs.std(0) + 1e-6).astype(np.float32))

    def __call__(self, obs: jax.Array) -> jax.Array:
        obs = jnp.asarray(obs)
        return obs if self.mean is None else (obs - self.mean) / self.std


@dataclasses.dataclass(frozen=True)
class Prepared:
    """The prepare phase's output: what every later phase trains and evaluates on.

    Attributes:
      env: the environment the policies are evaluated in.
      task: its task record.
      train, val: the demonstrations' training and validation rows (`data.Part`: rows of whole episodes).
      normalizer: fitted on the training rows.
      expert: the expert's label as `full observation -> action` (`collect.labeller`: clipped to the action
        bounds, or raw, as `protocol.labels` says): the demonstrations' own expert (a `--dataset`'s, found by
        `collect.dataset_expert`); None for a dataset whose expert cannot be queried.
      card: the returns to normalise by (`return_mean`, `return_std`, `random_return_mean`): the expert's under the
        protocol, or a `--dataset`'s recorded ones; None for a rule-based expert or a dataset without references.
      expert_description: how the demonstrations describe their expert (`collect.expert_for`'s description:
        its card's or file's SHA-256, origin), None where they name none.
      data_path: where the demonstrations came from; `source`: "cached", "collected" or "from".
      settings: what names the demonstrations (`SweepSpec.data_settings`).
      data_sha256: the SHA-256 of the collected (or cached) demonstrations' file, which tells two collections
        with the same settings apart; None for `--dataset` and for a file another process is still writing.
      views: the other observations' views built so far (`view`), by observation.
      perception: the encoder the frames are seen through (`perception.Encoder.describe`), None for none.
    """

    env: Any
    task: tasks.Task
    train: Part
    val: Part
    normalizer: Normalizer
    expert: Callable[[jax.Array], jax.Array] | None
    card: dict | None
    data_path: str
    source: str
    settings: dict
    data_sha256: str | None = None
    expert_description: dict | None = None
    views: dict = dataclasses.field(default_factory=dict, compare=False, repr=False)
    perception: dict | None = None

    def observing(self, observation: str | None) -> str | None:
        """The observation `observation` (`Method.observation`) names here: None where it is the sweep's own
        (`"full"` in a sweep with `--obs full`), else itself. Policies are grouped by it."""
        return None if observation in (None, self.env.obs_mode) else observation

    def view(self, observation: str | None) -> Prepared:
        """The sweep as policies reading `observation` (`Method.observation`) see it: this record for the sweep's
        own; for `"full"` the same rows observed in the `obs="full"` environment (`observations.full_state`: the
        demonstrations' simulator state observed by the environment's own code), standardised with their own
        training statistics. Built once and kept. Raises `observations.FullStateError` (one line) for
        demonstrations without the simulator state."""
        observation = self.observing(observation)
        if observation is None:
            return self
        if observation not in self.views:
            demos = {id(p.demos): p.demos for p in (self.train, self.val)}   # one copy where both parts share it
            env = None
            for key, d in demos.items():
                env, demos[key] = observations.full_state(self.env, d, self.data_path)
            train, val = (Part(demos[id(p.demos)], p.rows) for p in (self.train, self.val))
            self.views[observation] = dataclasses.replace(self, env=env, train=train, val=val,
                                                          normalizer=Normalizer.fit(train.obs), views={})
        return self.views[observation]

    def sequential(self, encoder: str) -> bool:
        """Whether policies of `encoder` train one configuration after another here (`trains_sequentially`)."""
        return trains_sequentially(self.env.observation_shape, encoder)

    def data(self, part: Part, ape: jax.Array, scores: jax.Array | None = None) -> Data:
        """`part` on device with its APE (and score table), observations standardised: the whole episodes, and
        the part's rows among them."""
        d = part.demos
        return Data(obs=self.normalizer(d.obs), action=jnp.asarray(d.action), t=jnp.asarray(d.t),
                    ape=jnp.asarray(ape), scores=scores,
                    rows=None if part.rows is None else jnp.asarray(part.rows, jnp.int32))

    def learner_config(self, settings: Settings, history: int) -> LearnerConfig:
        return settings.learner_config(self.env.observation_shape, self.env.action_size, history, self.task.loss,
                                       unroll=self.sequential(settings.recipe.encoder),
                                       task_loss_weights=self.task.loss_weights)


PROTOCOL_KEYS = ("n_frames", "episode_length", "reward_scale")  # the collection settings a protocol fixes


def check_protocol(recorded: dict | None, spec: SweepSpec, where: str) -> None:
    """Refuses (ValueError, one line) a dataset whose recorded collection settings are of another protocol.

    `recorded`: the dataset's collection settings (`minari_io.dataset_settings`); None (a dataset that
    records none, e.g. your own or a Minari one) cannot be checked and passes.
    """
    if recorded is None:
        return
    had = {k: v for k, v in (recorded.get("env_overrides") or {}).items() if k in PROTOCOL_KEYS}
    want = {k: v for k, v in spec.setup.collection.items() if k in PROTOCOL_KEYS}
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


def check_task(recorded: dict | None, spec: SweepSpec, where: str) -> None:
    """Refuses (ValueError, one line) a dataset whose metadata (`minari_io.dataset_metadata`) names another task
    or observation mode than the sweep's, with the flags that fit it; one that names none passes (its shapes are
    checked once loaded)."""
    recorded = recorded if isinstance(recorded, dict) else {}
    settings = recorded.get("settings") if isinstance(recorded.get("settings"), dict) else {}
    env, obs = settings.get("env", recorded.get("env")), settings.get("obs", recorded.get("obs"))
    if env is not None and env != spec.env:
        raise ValueError(f"{where} holds {env}{f' ({obs})' if obs else ''} demonstrations, not {spec.env}'s; pass "
                         f"--env {env}{f' --obs {obs}' if obs else ''} to train on them")
    if obs is not None and obs != spec.obs:
        raise ValueError(f"{where} holds {env or spec.env} demonstrations observed as {obs!r}, not {spec.obs!r}; "
                         f"pass --obs {obs} to train on them")


def prepare(spec: SweepSpec, hooks: Hooks = Hooks()) -> Prepared:
    """Phase 1: the environment, the demonstrations (collected or cached, or `spec.dataset`), their expert and
    references, the split and the normaliser. A `--dataset` brings its own expert and references
    (`collect.dataset_expert`). Raises `ValueError` (one line) for demonstrations that do not fit the environment
    or are too few, a dataset whose labels leave the action range without `protocol.labels=raw`, and an online
    method (DAgger) where the dataset's expert cannot be queried.
    """
    import envs

    setup = spec.setup
    env = envs.make(spec.env, obs=spec.obs, **setup.evaluation)
    # what names the demonstrations (the prepared sweep's own copy: the setup's stays as resolved)
    settings = copy.deepcopy(setup.data_key) if spec.dataset is None else spec.data_settings()
    protocol = spec.protocol
    if spec.dataset is None:
        found = setup.expert
        expert, description = found.policy(env), found.description  # restored once: collection and labels use it
        card = setup.references()  # a reference not measured is refused before collecting
        with hooks.bar(desc="collect", total=setup.episodes, unit="episode") as b:
            demos, meta, path, cached = collect.collect_cached(settings, spec.data_dir or data_lib.cache_dir(),
                                                            progress=lambda n: b.update(n - b.n),
                                                            save=jax.process_index() == 0, references=card,
                                                            expert=found)
            b.update(setup.episodes - b.n)
        source, digest = ("cached" if cached else "collected"), meta.get("sha256")
        if (frames := meta.get("frames")) is not None:  # protocol.frames=states: rendered from the rows' states
            h, w, _ = frames["shape"]
            hooks.log(f"frames: {len(demos):,} rendered from the demonstrations' simulator states at {h}×{w} in "
                      f"{frames['render_s']:.1f} s ({frames['frames_per_s']:,} frames/s on {frames['backend']}; "
                      f"compiled in {frames['compile_s']:.1f} s)")
    else:
        where = str(spec.dataset)
        recorded, collected_under = minari_io.dataset_metadata(spec.dataset), minari_io.dataset_settings(spec.dataset)
        check_task(recorded, spec, where)   # first: another task's data fails every later check, each its own way
        check_protocol(collected_under, spec, where)
        found = collect.dataset_expert(env, spec.task, protocol, recorded, where)
        online = [m for m in spec.methods if methods_lib.get(m).online]
        if online and found.expert is None:
            raise ValueError(f"{', '.join(online)} queries the expert of the demonstrations, but {found.why}; drop "
                             f"{', '.join(online)} from --methods")
        demos, path = minari_io.load_dataset(spec.dataset)
        collect.check_labels(demos, env, protocol.labels, str(path))
        source, digest = "from", None
        expert, description, card = found.expert, found.description, found.references
        if card is None and spec.task.has_card:
            hooks.log(f"no normalised scores: {collect.no_references_advice(found, where)}")
    expert = None if expert is None else collect.labeller(expert, env, protocol.labels)
    check_fits(demos, env, str(path))
    seen = None
    if spec.recipe.perception != "none":
        from ape_jax import perception

        encoder = perception.resolve(spec.env, spec.recipe.perception, spec.recipe.perception_sha256)
        name = pathlib.Path(encoder.path).name
        if spec.recipe.perception_training == "finetune":   # it starts the policies' encoder (`perception.tuned`)
            hooks.log(f"perception: the policies' image encoder starts as {name} (SHA-256 {encoder.sha256[:12]}…) "
                      f"and trains end to end")
            seen = {**encoder.describe(), "output": "embedding", "training": "finetune"}
        else:   # the frames seen through the frozen encoder, embedded once
            with hooks.bar(desc="embed", total=len(demos), unit="frame") as b:
                output = spec.recipe.perception_output
                env, demos = perception.perceive(env, demos, encoder, progress=lambda n: b.update(n - b.n),
                                                 output=output)
            hooks.log(f"perception: {len(demos):,} frames seen through {name} (SHA-256 {encoder.sha256[:12]}…; its "
                      f"{output}, {env.observation_shape[0]} features a frame)")
            seen = {**encoder.describe(), "output": output}
    if spec.protocol.prev_action:  # the previous action in view, in the rollouts and the demonstrations alike
        env, demos = observations.with_previous_action(env, demos)
    hooks.log(f"demonstrations: {len(demos):,} transitions in {demos.num_episodes} episodes ({source}: {path})")
    train, val = data_lib.split_parts(demos, protocol.split, protocol.train_transitions, protocol.val_transitions,
                                      protocol.val_frac, seed=0)
    if len(train) < spec.recipe.batch_size:
        raise ValueError(f"the training split has {len(train)} transitions, fewer than the batch size "
                         f"{spec.recipe.batch_size}; collect more episodes")
    return Prepared(env=env, task=spec.task, train=train, val=val, normalizer=Normalizer.fit(train.obs),
                    expert=expert, card=card, data_path=str(path), source=source, settings=settings,
                    data_sha256=digest, expert_description=description, perception=seen)


# -- 2. fit APE -----------------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class ApeFit:
    """The APE phase's output: ψ and both splits' (normalised) APE.

    Attributes:
      params: ψ's parameters (`ape_jax.ape`).
      train, val: `[N]`, `[M]` float32 APE, divided by `scale`.
      scale: the normalisation's divisor (1 for `"none"`).
      final_fit_mse: ψ's training loss at the end of the fit.
    """

    params: Any
    train: Any
    val: Any
    scale: float
    final_fit_mse: float

    @property
    def raw_mean(self) -> float:
        """The training split's mean APE before normalisation (what the copycat diagnostic `rollout_ape` divides by)."""
        return float(self.scale * np.mean(self.train))


def part_errors(params: Any, part: Part) -> np.ndarray:
    """`[len(part)]` APE of a part's rows, ψ reading the past actions of their whole episodes."""
    d = part.demos
    return part.own(ape_lib.errors(params, jnp.asarray(d.action), jnp.asarray(d.t)))


def fit_ape(prepared: Prepared, settings: Settings, hooks: Hooks = Hooks(),
            checkpoint: SweepCheckpoint | None = None) -> ApeFit:
    """Phase 2: ψ fitted on the training rows' actions (key 0, deterministic), reused from `checkpoint`."""
    steps = settings.budget.ape_steps
    with hooks.bar(desc="fit APE", total=steps, unit="step") as b:
        fit = ckpt_lib.load_ape(checkpoint, ApeFit)
        if fit is None:
            train = prepared.train
            rows = None if train.rows is None else jnp.asarray(train.rows, jnp.int32)
            run = jax.jit(lambda k, a, t, r: ape_lib.fit(k, a, t, steps=steps, rows=r))
            params, losses = run(jax.random.PRNGKey(0), jnp.asarray(train.demos.action), jnp.asarray(train.demos.t),
                                 rows)
            ape_train, ape_val = part_errors(params, train), part_errors(params, prepared.val)
            ape_train, ape_val, scale = ape_lib.normalize(ape_train, ape_val, settings.ape_normalization)
            fit = ApeFit(params=params, train=np.asarray(ape_train), val=np.asarray(ape_val), scale=float(scale),
                         final_fit_mse=float(np.mean(np.asarray(losses)[-50:])))
            ckpt_lib.save_ape(checkpoint, fit)
        b.update(steps)
    return fit
