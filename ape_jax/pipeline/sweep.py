"""The main job as a library: a sweep is five phases, each with a named output.

    spec = SweepSpec.make("hopper", methods=("bc-so", "bc-oh"), preset="quick", recipe="fca")
    results, policies = run_sweep(spec)

A spec holds the task, the observation mode, the methods and the three records that
fix everything else (`ape_jax.pipeline.presets.Settings`: protocol, budget, recipe).

1. `prepare` → `Prepared`: the environment, its task record and expert, the
   demonstrations (the expert's, collected once and cached, or `--dataset`)
   split as the protocol says (by rows or by episode), and the observation
   `Normalizer` fitted on the training rows;
2. `fit_ape` → `ApeFit`: ψ fitted on the training split's actions, and both
   splits' APE (`ape_jax.ape`);
3. `plan` → `[Program]`: every (method, hparams, seed) of the sweep, grouped
   into the compiled programs they train in (`ape_jax.methods`: BC-OH, the
   weighting grids and the weighting baselines share the grid program; BC-SO,
   with a history of one, is a second; Boosting, FCA and DAgger have their
   own); `train` → `[Trained]`: each program trained vmapped over its runs and
   sharded over devices (`training.train_program`), in chunks so progress moves
   and checkpoints can be taken;
4. `evaluate` → `Evaluated`: every policy on the same episodes, with the copycat
   diagnostics (the rollouts' `imitation_error` and `rollout_ape`, `ape_jax.evaluate`;
   the embedding probe, own-rollout predictability and verdict, `ape_jax.diagnostics`)
   and the loss analysis on both splits;
5. `assemble` → `results.Results`.

A run's PRNG key comes from its identity (`methods.run_key(seed, method,
hparams)`), so a configuration gets the same initialisation, batches and evaluation
episodes whatever else runs beside it (the same numbers up to float rounding: a
program vmapped over more runs may round differently, which long training and
chaotic rollouts amplify). Host concerns come in through `Hooks` (progress bars,
messages, training curves); files are written by `ape_jax.pipeline.checkpoint` and
`ape_jax.pipeline.results`, not here.

This module holds the phases and their typed outputs. What they read and write lives
beside it: `spec` (the `SweepSpec`, its `Run`s and the checks that refuse it early),
`training` (the training driver: `Program`, `train_program` with its checkpointed
chunks and rounds and the restore on every process), `ape_jax.scores` (the score table
the weighted learner reads) and `results` (the records `assemble` writes, the
fingerprint). Their public names are importable from here too (`__all__`), so a caller
of the sweep needs this module alone.
"""

from __future__ import annotations

import dataclasses
import inspect
import resource
import time
from typing import Any
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import ape as ape_lib
from ape_jax import diagnostics as diagnostics_lib
from ape_jax import evaluate as evaluate_lib
from ape_jax import methods as methods_lib
from ape_jax import observations
from ape_jax import tasks
from ape_jax.grid import differing_processes
from ape_jax.learner import Data, LearnerConfig, make_train
from ape_jax.pipeline import checkpoint as ckpt_lib
from ape_jax.pipeline import collect, minari_io, provenance
from ape_jax.pipeline import judge as judge_lib
from ape_jax.pipeline import results as results_lib
from ape_jax.pipeline.checkpoint import SweepCheckpoint
from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline.data import Part
from ape_jax.pipeline.presets import Settings
from ape_jax.pipeline.records import (COPYCAT_METRICS, CURVE_POINTS, DIAG, diagnostics_config, diagnostics_record,
                                      eval_record, run_record, snapshot_record, window_means)
from ape_jax.pipeline.spec import PROTOCOL_KEYS, Run, SweepSpec, check_fits, check_protocol, grid_runs
from ape_jax.pipeline.training import (CPU_IMAGE_CHUNK, Program, traced_hparams, train_program,
                                       trains_sequentially)
from ape_jax.scores import method_scores, score_rows, score_table

__all__ = [
    # the phases and their outputs
    "Hooks", "Normalizer", "Prepared", "prepare", "ApeFit", "part_errors", "fit_ape", "plan", "Trained", "train",
    "PolicyGroup", "Evaluated", "diagnosable", "group_diagnostics", "evaluate_group", "evaluate", "assemble",
    "policies", "train_sweep", "run_sweep", "EVAL_SEED", "DIAGNOSTICS_SEED",
    # the spec and its checks (`spec`)
    "SweepSpec", "Run", "grid_runs", "check_protocol", "check_fits", "PROTOCOL_KEYS",
    # the training driver (`training`)
    "Program", "train_program", "traced_hparams", "trains_sequentially", "CPU_IMAGE_CHUNK",
    # the score table (`ape_jax.scores`)
    "score_rows", "method_scores", "score_table",
    # the records of results.json (`results`)
    "run_record", "snapshot_record", "eval_record", "diagnostics_record", "diagnostics_config", "window_means",
    "CURVE_POINTS", "COPYCAT_METRICS", "DIAG",
]

EVAL_SEED = 12345  # every policy is evaluated on the same episodes
DIAGNOSTICS_SEED = 0  # the embedding probes' and ψ's key in `ape_jax.diagnostics.diagnose`


class _NoBar:
    def __init__(self, *a, **k):
        self.n = 0

    def update(self, n=1):
        self.n += n

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@dataclasses.dataclass(frozen=True)
class Hooks:
    """What the host gives a sweep: how to show progress and where to send messages and curves.

    Attributes:
      bar: `bar(desc=..., total=..., unit=...)`, a context manager with
        `update(n)` (e.g. `tqdm.tqdm`); one per phase.
      log: receives one-line progress messages.
      curves: `curves(program, runs, iterations)` before each program trains: a sink for its per-iteration
        metrics (e.g. `logs.CurveLog`), told `start(restored)` with the curves a resumed program restored
        (`[len(runs), n]` per metric, or None), `append(metrics)` after every chunk, and `close()` at the end.
    """

    bar: Callable[..., Any] = _NoBar
    log: Callable[[str], None] = print
    curves: Callable[[str, Sequence[Run], int], Any] | None = None


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
                                       unroll=self.sequential(settings.recipe.encoder))


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

    env = envs.make(spec.env, obs=spec.obs, **spec.env_overrides())
    settings = spec.data_settings()
    protocol = spec.protocol
    if spec.dataset is None:
        found = spec.setup.expert
        card = spec.setup.references()  # a reference not measured is refused before collecting
        with hooks.bar(desc="collect", total=spec.episodes, unit="episode") as b:
            demos, meta, path, cached = collect.collect_cached(settings, spec.data_dir or data_lib.cache_dir(),
                                                            progress=lambda n: b.update(n - b.n),
                                                            save=jax.process_index() == 0, references=card,
                                                            expert=found)
            b.update(spec.episodes - b.n)
        source, digest = ("cached" if cached else "collected"), meta.get("sha256")
        expert, description = found.policy(env), found.description  # the policy loaded once per sweep
    else:
        where = str(spec.dataset)
        recorded = minari_io.dataset_metadata(spec.dataset)
        check_task(recorded, spec, where)   # first: another task's data fails every later check, each its own way
        check_protocol(minari_io.dataset_settings(spec.dataset), spec, where)
        found = collect.dataset_expert(env, protocol, recorded, where)
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
    check_fits(demos, env, str(path))
    if spec.protocol.prev_action:  # the previous action in view, in the rollouts and the demonstrations alike
        env, demos = observations.with_previous_action(env, demos)
    hooks.log(f"demonstrations: {len(demos):,} transitions in {demos.num_episodes} episodes ({source}: {path})")
    train, val = data_lib.split_parts(demos, protocol.split, protocol.train_transitions, protocol.val_transitions,
                                      protocol.val_frac, seed=0)
    if len(train) < spec.recipe.batch_size:
        raise ValueError(f"the training split has {len(train)} transitions, fewer than the batch size "
                         f"{spec.recipe.batch_size}; collect more episodes")
    expert = None if expert is None else collect.labeller(expert, env, protocol.labels)
    return Prepared(env=env, task=spec.task, train=train, val=val, normalizer=Normalizer.fit(train.obs),
                    expert=expert, card=card, data_path=str(path), source=source, settings=settings,
                    data_sha256=digest, expert_description=description)


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
            ape_train, ape_val, scale = ape_lib.normalize(ape_train, ape_val, settings.recipe.ape_normalization)
            fit = ApeFit(params=params, train=np.asarray(ape_train), val=np.asarray(ape_val), scale=float(scale),
                         final_fit_mse=float(np.mean(np.asarray(losses)[-50:])))
            ckpt_lib.save_ape(checkpoint, fit)
        b.update(steps)
    return fit


# -- 3. plan and train ----------------------------------------------------------------------------------------------

def plan(spec: SweepSpec, prepared: Prepared) -> list[Program]:
    """Phase 3a: the sweep's runs, grouped by the program they train in (in registry order)."""
    recipe = spec.recipe
    ctx = methods_lib.GridContext(task=prepared.task, step_grid=recipe.step_grid, softmax_grid=recipe.softmax_grid,
                                  n_train=len(prepared.train), fca_alphas=recipe.fca_alphas,
                                  ib_weights=recipe.ib_weights, fca_adversary_lr=recipe.fca_adversary_lr,
                                  recipe=recipe)
    runs = grid_runs(spec.methods, spec.budget.seeds, ctx, spec.budget.first_seed)
    if not runs:
        raise ValueError(f"nothing to train: the recipe's grids are empty for {', '.join(spec.methods)}")
    programs = []
    for name in dict.fromkeys(methods_lib.get(r.method).program for r in runs):
        mine = tuple(r for r in runs if methods_lib.get(r.method).program == name)
        method = methods_lib.get(mine[0].method)
        view = prepared.view(method.observation)   # FullStateError before anything compiles
        cfg = view.learner_config(spec.settings, method.history or spec.protocol.history)
        if method.learner is None:
            learner = make_train(cfg)
        else:
            learner = method.learner(methods_lib.LearnerContext(
                cfg=cfg, env=view.env, expert=view.expert, obs_mean=view.normalizer.mean,
                obs_std=view.normalizer.std, n_train=len(view.train), recipe=recipe))
        programs.append(Program(name, cfg, mine, learner))
    return programs


@dataclasses.dataclass(frozen=True)
class Trained:
    """One program's output: its policies (leaves `[len(runs), ...]`), per-iteration metrics, and times."""

    program: Program
    params: Any
    metrics: dict
    compile_s: float
    train_s: float
    snapshots: dict = dataclasses.field(default_factory=dict)  # {iteration: params} at `Budget.eval_at`


def observation_of(program: Program) -> str | None:
    """The observation a program's policies read (`Method.observation` of its methods: one per program)."""
    return methods_lib.get(program.runs[0].method).observation


def train(programs: Sequence[Program], spec: SweepSpec, prepared: Prepared, data: Data, hooks: Hooks = Hooks(),
          checkpoint: SweepCheckpoint | None = None) -> list[Trained]:
    """Phase 3b: every program trained, one after another; compile time estimated apart from steady state.

    `data` is the training split in the sweep's observation; a program reading another (`bc-full`) trains on
    the same rows, APE and scores in its own (`Prepared.view`)."""
    sequential = prepared.sequential(spec.recipe.encoder)
    if sequential:
        hooks.log(f"image policies on CPU: configurations train one after another, {CPU_IMAGE_CHUNK} unrolled "
                  "iterations per call (XLA:CPU is slow at convolution gradients in loops and under vmap)")
        if spec.recipe.encoder == "resnet18":
            hooks.log("warning: ResNet-18 trains about a hundred times slower than the small encoder on a CPU; "
                      "the paper preset's image protocol is meant for GPUs")
    rows = score_rows(spec.methods)
    if jax.process_count() > 1:
        # each process gives its devices their rows from its own copy: every copy must be the same
        differ = differing_processes(data)
        if differ:
            raise ValueError(f"the training data of process(es) {', '.join(map(str, differ))} differ from process "
                             "0's (other demonstrations, or another machine computing them differently): every "
                             "process must train on the same data")
    out = []
    total = sum(p.learner.rounds * p.learner.round_iterations for p in programs)
    with hooks.bar(desc="train", total=total, unit="it") as b:
        for program in programs:
            stamps: list[float] = []

            def tick(n, stamps=stamps):
                stamps.append(time.perf_counter())
                b.update(n)

            t0 = time.perf_counter()
            iterations = program.learner.rounds * program.learner.round_iterations
            curves = None if hooks.curves is None else hooks.curves(program.name, program.runs, iterations)
            view = prepared.view(observation_of(program))
            own = data if view is prepared else data.replace(obs=view.normalizer(view.train.demos.obs))
            params, metrics, snapshots = train_program(
                program, traced_hparams(program.runs, spec.recipe.lr, rows), spec.budget, own, tick,
                chunk=CPU_IMAGE_CHUNK if sequential else None, vectorize=not sequential,
                checkpoint=None if checkpoint is None else checkpoint.program(program.name), curves=curves)
            jax.block_until_ready(params)
            chunk_times = np.diff([t0, *stamps])
            steady = float(np.median(chunk_times[1:])) if len(chunk_times) > 1 else 0.0
            compile_s = max(0.0, float(chunk_times[0]) - steady) if len(chunk_times) else 0.0
            out.append(Trained(program, params, metrics, compile_s, float(sum(chunk_times)) - compile_s, snapshots))
            if curves is not None:
                curves.close()
    return out


# -- 4. evaluate ----------------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class PolicyGroup:
    """Policies with the same observation and history (the same network): one evaluation program.

    `observation`: what they read (`Prepared.observing`: None, the sweep's own; `"full"`, the full state)."""

    history: int
    cfg: LearnerConfig
    runs: tuple[Run, ...]
    params: Any  # leaves [len(runs), ...]
    observation: str | None = None

    @property
    def name(self) -> str:
        """`h<H>` for the sweep's observation (the name every sweep has used), `<observation>-h<H>` for another."""
        return f"h{self.history}" if self.observation is None else f"{self.observation}-h{self.history}"


@dataclasses.dataclass(frozen=True)
class Evaluated:
    """The evaluation phase's output: per group, the evaluation outputs and loss analysis, row j = run j.

    `snapshots`: the same at each iteration of `Budget.eval_at`, `{iteration: ((group, outputs, losses), ...)}`
    (a group there holds the runs whose programs passed that iteration)."""

    groups: tuple[PolicyGroup, ...]
    outputs: tuple[dict, ...]   # per group: {"return": [P, E], metric: [P, E], "diag_<field>": [P], ...}
    losses: tuple[dict, ...]    # per group: {"train": {...: [P]}, "val": {...}}
    eval_s: float               # the diagnostics' time included
    diagnostics_s: float = 0.0
    snapshots: dict = dataclasses.field(default_factory=dict)


def diagnosable(episodes: int, probe_steps: int, expert_episodes: int = 2) -> bool:
    """Whether a sweep's policies get the embedding probe and predictability diagnostics: `probe_steps > 0`
    (`Budget.probe_steps`), and at least 2 evaluation episodes and 2 training episodes of the expert (ψ fits
    on half of each side's episodes and scores the rest)."""
    return probe_steps > 0 and episodes >= 2 and expert_episodes >= 2


def group_diagnostics(prepared: Prepared, ape: ApeFit, group: PolicyGroup, actions: np.ndarray,
                      valid: np.ndarray, steps: int) -> dict[str, np.ndarray]:
    """The group's copycat diagnostics (`ape_jax.diagnostics.diagnose`) as `{"diag_<field>": [P]}`; the expert's
    rollouts are its demonstrations' training episodes (a sweep collects them without noise, so they are its
    own rollouts) as executed (`Demonstrations.executed`: the clipped actions the env ran, like the policies'
    rollout actions, whatever the labels), the velocity the demonstrations' `qvel` where they hold one. A
    network that gives no embedding (its `__call__` takes no `return_embedding`, e.g. a plugin's) gets
    `{"diag_absent": [P]}`."""
    if "return_embedding" not in inspect.signature(type(group.cfg.model()).__call__).parameters:
        return {f"{DIAG}absent": np.ones(len(group.runs))}  # reported absent, never as zero
    train, val = prepared.data(prepared.train, ape.train), prepared.data(prepared.val, ape.val)
    demos = prepared.train.demos
    velocity = state = None
    both = [d.sim for d in (demos, prepared.val.demos)]
    if all("qvel" in sim for sim in both):
        velocity = tuple(sim["qvel"] for sim in both)
        if all("qpos" in sim for sim in both):  # the experts' observation: the root's x left out, as Brax does
            state = tuple(np.concatenate([sim["qpos"][:, 1:], sim["qvel"]], axis=-1) for sim in both)
    expert = diagnostics_lib.demonstration_rollouts(demos.executed, demos.episode)
    d = diagnostics_lib.diagnose(jax.random.PRNGKey(DIAGNOSTICS_SEED), group.cfg, group.params, train, val,
                                 actions, valid, expert, velocity, steps=steps, state=state)
    rows = d.pop("probe_rows")
    return {**{DIAG + k: np.asarray(v) for k, v in d.items()},
            f"{DIAG}probe_rows_train": np.full(len(group.runs), rows[0]),
            f"{DIAG}probe_rows_val": np.full(len(group.runs), rows[1]),
            f"{DIAG}probe_steps": np.full(len(group.runs), steps)}


def evaluate_group(prepared: Prepared, ape: ApeFit, episodes: int, group: PolicyGroup,
                   probe_steps: int = 0, width: int = 0) -> tuple[dict, dict, float]:
    """Evaluation outputs `{"return": [P, E], metric: [P, E], ...}` (copycat diagnostics included: the
    `ape_jax.diagnostics` ones as `diag_<field>` `[P]` with `probe_steps` where `diagnosable`), the loss
    analysis `{"train": {...: [P]}, "val": {...}}` of one group, and the diagnostics' seconds. The policies go
    `width` at a time (`Budget.width`; 0: all together) through the evaluation and the loss analysis. A group
    reading another observation is evaluated, analysed and diagnosed in its own view (`Prepared.view`)."""
    prepared = prepared.view(group.observation)
    diagnostics = diagnosable(episodes, probe_steps, prepared.train.demos.num_episodes)
    evaluator = evaluate_lib.make_evaluator(prepared.env, group.cfg, prepared.normalizer.mean, prepared.normalizer.std,
                                            episodes, expert=prepared.expert, ape_params=ape.params,
                                            ape_scale=ape.raw_mean, keep_actions=diagnostics, width=width or None)
    out = jax.device_get(evaluator(group.params, jax.random.PRNGKey(EVAL_SEED)))
    diag_s = 0.0
    if diagnostics:
        t0 = time.perf_counter()
        out.update(group_diagnostics(prepared, ape, group, out.pop("actions"), out.pop("valid"), probe_steps))
        diag_s = time.perf_counter() - t0
    losses = {split: jax.device_get(evaluate_lib.loss_analysis(group.cfg, group.params, prepared.data(s, a),
                                                               width=width or None))
              for split, s, a in (("train", prepared.train, ape.train), ("val", prepared.val, ape.val))}
    return out, losses, diag_s


def evaluate(trained: Sequence[Trained], prepared: Prepared, ape: ApeFit, episodes: int, hooks: Hooks = Hooks(),
             checkpoint: SweepCheckpoint | None = None, probe_steps: int = 0, width: int = 0) -> Evaluated:
    """Phase 4: every policy on the same `episodes` episodes, one program per observation and history
    (`PolicyGroup`; groups saved in `checkpoint` reused), `width` policies at a time (`Budget.width`; 0: a group
    at once), with the copycat diagnostics at `probe_steps` (`Budget.probe_steps`; 0: none); the same for the
    policies kept at each iteration of `Budget.eval_at` (`Trained.snapshots`)."""
    points = sorted({i for t in trained for i in t.snapshots})
    seconds = {"eval": 0.0, "diagnostics": 0.0}
    total = sum(len(t.program.runs) * (1 + len(t.snapshots)) for t in trained) * episodes
    with hooks.bar(desc="evaluate", total=total, unit="episode") as b:

        def evaluated(seen: tuple[str | None, int], mine: list[Trained], params: list, at: int | None = None):
            group = PolicyGroup(seen[1], mine[0].program.cfg, tuple(r for t in mine for r in t.program.runs),
                                jax.tree.map(lambda *xs: jnp.concatenate(xs), *params), seen[0])
            name = f"eval-{group.name}" + ("" if at is None else f"-at{at}")
            saved = ckpt_lib.load_evaluation(checkpoint, name)
            if saved is None:
                t0 = time.perf_counter()
                out, loss, diag_s = evaluate_group(prepared, ape, episodes, group, probe_steps, width)
                saved = out, loss
                seconds["eval"] += time.perf_counter() - t0
                seconds["diagnostics"] += diag_s
                ckpt_lib.save_evaluation(checkpoint, name, *saved)
            b.update(len(group.runs) * episodes)
            return group, *saved

        def seen(t: Trained) -> tuple[str | None, int]:
            return prepared.observing(observation_of(t.program)), t.program.cfg.history

        final, snapshots = [], {i: [] for i in points}
        for key in dict.fromkeys(seen(t) for t in trained):
            mine = [t for t in trained if seen(t) == key]
            final.append(evaluated(key, mine, [t.params for t in mine]))
            for i in points:
                passed = [t for t in mine if i in t.snapshots]
                if passed:
                    snapshots[i].append(evaluated(key, passed, [t.snapshots[i] for t in passed], i))
    groups, outputs, losses = zip(*final) if final else ((), (), ())
    return Evaluated(tuple(groups), tuple(outputs), tuple(losses), seconds["eval"], seconds["diagnostics"],
                     {i: tuple(v) for i, v in snapshots.items()})


# -- 5. assemble ----------------------------------------------------------------------------------------------------

def assemble(spec: SweepSpec, prepared: Prepared, ape: ApeFit, trained: Sequence[Trained], evaluated: Evaluated,
             timing: dict) -> results_lib.Results:
    """Phase 5: the sweep's `Results` (records in plan order)."""
    curves = {r.ident: {k: v[i] for k, v in t.metrics.items()} for t in trained for i, r in enumerate(t.program.runs)}
    records = {}
    for group, out, losses in zip(evaluated.groups, evaluated.outputs, evaluated.losses):
        for j, r in enumerate(group.runs):
            records[r.ident] = run_record(r, j, out, losses, curves[r.ident], prepared.task, prepared.card)
    for iteration, at in sorted(evaluated.snapshots.items()):
        for group, out, losses in at:
            for j, r in enumerate(group.runs):
                records[r.ident].setdefault("at", []).append(
                    snapshot_record(iteration, j, out, losses, curves[r.ident], prepared.task,
                                    prepared.card))
    order = {m: i for i, m in enumerate(methods_lib.names())}  # the plan's order: methods, settings, seeds
    runs = sorted((records[r.ident] for t in trained for r in t.program.runs), key=lambda rec: order[rec["method"]])
    task, blocks = prepared.task, spec.settings.to_json()
    # the flat view readers of schemas 1 and 2 know (the records are stored apart, as `protocol`, `budget`, `recipe`)
    flat = {**blocks["budget"], **{k: v for k, v in blocks["recipe"].items() if k != "name"},
            **{k: blocks["protocol"][k] for k in ("history", "eval_steps", "val_frac", "image_size")},
            "episodes": spec.episodes, "recipe": spec.recipe.name}
    config = {**flat, **({"smoke": True} if spec.settings.smoke else {}),
              **({"preset_iterations": spec.settings.preset_iterations}
                 if spec.settings.preset_iterations is not None else {}),
              "methods": list(spec.methods), "loss": spec.recipe.loss or task.loss, "metric": task.metric,
              "task_metrics": list(task.metrics),
              "ape": {"normalization": spec.recipe.ape_normalization, "scale": ape.scale,
                      "final_fit_mse": ape.final_fit_mse,
                      # the validation split's mean, on the scale it trained on; × scale ÷ raw_mean it is the
                      # expert's reference for the policies' rollout_ape (÷ the raw training mean)
                      "val_mean": float(np.mean(ape.val)), "raw_mean": ape.raw_mean,
                      # the training split's normalised APE distribution, for the weights' histograms
                      "quantiles": np.quantile(np.asarray(ape.train), np.linspace(0, 1, 101)).tolist()},
              "ape_normalization": spec.recipe.ape_normalization,
              "score_rows": list(score_rows(spec.methods)),
              "data": {"path": prepared.data_path, "train_transitions": len(prepared.train),
                       "val_transitions": len(prepared.val), "split": spec.protocol.split,
                       "episodes": prepared.train.num_episodes, "settings": prepared.settings,
                       "sha256": prepared.data_sha256}}
    card = prepared.card
    expert = ({"return_mean": card["return_mean"], "return_std": card["return_std"],
               "random_return_mean": card["random_return_mean"]} if card is not None else
              {"return_mean": None, "return_std": None, "random_return_mean": None, "kind": task.expert})
    if spec.dataset is not None and prepared.expert_description is not None:
        # a collected sweep names its expert in `config.data.settings`; a dataset's expert is recorded here
        expert["demonstrator"] = prepared.expert_description
    if (diag := diagnostics_config(prepared.train.demos, evaluated.outputs)) is not None:
        config["diagnostics"] = diag
    config["env"] = {"dt": float(prepared.env.dt), "episode_length": int(prepared.env.episode_length),
                     "overrides": {k: list(v) if isinstance(v, tuple) else v for k, v in spec.env_overrides().items()}}
    res = results_lib.Results(
        env=spec.env, obs=spec.obs, preset=spec.preset_name, config=config, expert=expert, runs=runs,
        summary=results_lib.summarize(runs, task.metrics), timing=timing,
        command=list(spec.command) if spec.command is not None else None,
        protocol=spec.protocol_settings(), settings=blocks,
        methods={m: results_lib.method_info(m) for m in dict.fromkeys(r["method"] for r in runs)})
    return judge_lib.judge_own(res)  # the controlled copycat verdict, where the sweep trained its control (BC-SO)


def policies(evaluated: Evaluated, prepared: Prepared) -> dict[str, dict]:
    """The trained policies per group (observation and history, `PolicyGroup.name`), as
    `checkpoint.save_policies` writes them, each with its own observation statistics."""
    return {g.name: {"runs": [dataclasses.asdict(r) for r in g.runs], "params": g.params,
                     "history": g.history, "observation": g.observation,
                     "obs_mean": prepared.view(g.observation).normalizer.mean,
                     "obs_std": prepared.view(g.observation).normalizer.std}
            for g in evaluated.groups}


def train_sweep(spec: SweepSpec, hooks: Hooks = Hooks(),
                checkpoint: SweepCheckpoint | None = None) -> tuple[Prepared, ApeFit, list[Trained]]:
    """Phases 1-3: the demonstrations, the APE fit and every program trained.

    All that a sweep's processes other than process 0 run after
    `jax.distributed.initialize()`: the training programs are collectives every
    process joins; evaluating and writing are process 0's (`run_sweep`).
    """
    prepared = prepare(spec, hooks)
    programs = plan(spec, prepared)
    scores = method_scores(spec.methods, prepared.train)  # a plugin's bad scores are refused before APE compiles
    ape = fit_ape(prepared, spec.settings, hooks, checkpoint)
    data = prepared.data(prepared.train, ape.train, score_table(ape.train, scores))
    return prepared, ape, train(programs, spec, prepared, data, hooks, checkpoint)


def run_sweep(spec: SweepSpec, hooks: Hooks = Hooks(),
              checkpoint: SweepCheckpoint | None = None) -> tuple[results_lib.Results, dict[str, dict]]:
    """Runs the whole sweep; returns its `Results` and its policies (`policies`).

    With an opened `SweepCheckpoint`, every finished phase and the training
    states are saved there, and what it already holds is reused.
    """
    t_start, started = time.perf_counter(), provenance.system()  # the code that runs, taken when it starts
    prepared, ape, trained = train_sweep(spec, hooks, checkpoint)
    evaluated = evaluate(trained, prepared, ape, spec.budget.eval_episodes, hooks, checkpoint,
                         spec.budget.probe_steps, spec.budget.width)
    timing = {"compile_s": sum(t.compile_s for t in trained), "train_s": sum(t.train_s for t in trained),
              "eval_s": evaluated.eval_s, "diagnostics_s": evaluated.diagnostics_s,  # included in eval_s
              "total_s": time.perf_counter() - t_start,
              "resumed": bool(checkpoint is not None and checkpoint.resumed),
              # included in the phases' times
              "checkpoint_s": checkpoint.save_s if checkpoint is not None else 0.0,
              "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}  # this process's peak
    res = assemble(spec, prepared, ape, trained, evaluated, timing)
    res.system = started
    return res, policies(evaluated, prepared)
