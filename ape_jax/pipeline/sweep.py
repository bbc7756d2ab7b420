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
   own); `train_program` → `Trained`: one program trained vmapped over its
   runs and sharded over devices, in chunks so progress moves and checkpoints
   can be taken;
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
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import pathlib
import resource
import time
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import ape as ape_lib
from ape_jax import diagnostics as diagnostics_lib
from ape_jax import evaluate as evaluate_lib
from ape_jax import methods as methods_lib
from ape_jax import tasks
from ape_jax.grid import differing_processes, from_process_zero, grid_runner, pad_grid
from ape_jax.learner import Data, Learner, LearnerConfig, make_train
from ape_jax.models import IMAGE_ENCODERS
from ape_jax.pipeline import checkpoint as ckpt_lib
from ape_jax.pipeline import collect, minari_io
from ape_jax.pipeline import results as results_lib
from ape_jax.pipeline.checkpoint import ProgramCheckpoint, SweepCheckpoint
from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline.data import Demonstrations, Part
from ape_jax.pipeline.presets import Settings, resolve

# Image policies on CPU: XLA:CPU runs convolution gradients inside a loop ~50x slower than
# outside one, and vmapped (grouped) ones ~3x slower per model, so there every
# configuration of a convolutional encoder trains one after another through one compiled,
# fully unrolled chunk. An encoder of matrix products only (`loop_friendly`, e.g. "patch")
# trains as states do: the grid vmapped, in scanned chunks of the budget's size.
CPU_IMAGE_CHUNK = 10
EVAL_SEED = 12345  # every policy is evaluated on the same episodes
COPYCAT_METRICS = ("imitation_error", "rollout_ape")  # the copycat diagnostics (`ape_jax.evaluate`)
DIAGNOSTICS_SEED = 0  # the embedding probes' and ψ's key in `ape_jax.diagnostics.diagnose`
DIAG = "diag_"  # the prefix of the diagnostics' arrays among a group's evaluation outputs
CURVE_POINTS = 100  # points of each run's training curve in results.json (the full curves: OUT/curves/)


def trains_sequentially(obs_shape: Sequence[int], encoder: str) -> bool:
    """Whether a sweep trains policies of `encoder` on `obs_shape` observations one configuration after another,
    `CPU_IMAGE_CHUNK` unrolled iterations per call: images through a convolutional encoder on a CPU."""
    return (len(obs_shape) == 3 and jax.default_backend() == "cpu"
            and not IMAGE_ENCODERS[encoder].loop_friendly)


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
    curves: Callable[[str, Sequence["Run"], int], Any] | None = None


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
            methods_lib.get(m)  # MethodError for an unknown name
        self.setup  # ValueError for a protocol the task cannot take

    @classmethod
    def make(cls, env: str, obs: str | None = None, methods: Sequence[str] | None = None, protocol: str | None = None,
             preset: str = "quick", recipe: str | None = None, sets: Sequence[str] = (), **kw) -> "SweepSpec":
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
    def setup(self) -> collect.ProtocolSetup:
        """The protocol as it applies to this environment (`collect.protocol_setup`), resolved once: a protocol
        without an episode length of its own makes the environment to read it."""
        return collect.protocol_setup(self.env, self.obs, self.protocol)

    @property
    def episodes(self) -> int:
        """Expert episodes collected: as many as the protocol's expert steps take, else its or the task's count."""
        return self.setup.episodes

    def protocol_settings(self) -> dict:
        """Every field of the protocol as it applies to this environment (results.json's `protocol`)."""
        return dict(self.setup.settings)

    def collection_overrides(self) -> dict:
        """The `envs.make` settings demonstrations are collected with: the protocol's, and the image size."""
        size = self.protocol.image_size
        image = {"image_size": size} if self.obs == "image" and size else {}
        return {**self.setup.env_overrides, **image}

    def env_overrides(self) -> dict:
        """The `envs.make` settings policies are evaluated with: the collection's, and the protocol's `eval_steps`."""
        steps = self.protocol.eval_steps
        return {**self.collection_overrides(), **({"episode_length": steps} if steps is not None else {})}

    def data_settings(self) -> dict:
        """What names the demonstrations: the collection settings, or the dataset file's path and size."""
        if self.dataset is None:
            return collect.settings(self.env, self.obs, self.episodes, seed=0, expert=self.protocol.expert,
                                    **self.collection_overrides())
        path = pathlib.Path(self.dataset)
        files = ([path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
                 if path.is_dir() else [])
        return {"dataset": str(path.absolute()), "bytes": sum(p.stat().st_size for p in files)}

    def fingerprint(self) -> dict:
        """Everything that determines the results (`checkpoint.SweepCheckpoint` compares these)."""
        return {"env": self.env, "obs": self.obs, "preset": self.preset_name, "settings": self.settings.to_json(),
                "methods": list(self.methods), "data": self.data_settings(), "protocol": self.protocol_settings()}


# -- 1. prepare -----------------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Normalizer:
    """Per-dimension standardisation of state observations with training statistics; images pass as they are."""

    mean: np.ndarray | None
    std: np.ndarray | None

    @classmethod
    def fit(cls, obs: np.ndarray) -> "Normalizer":
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
      expert: the expert as `full observation -> action`.
      card: the expert's card (returns to normalise by), None for a rule-based expert.
      data_path: where the demonstrations came from; `source`: "cached", "collected" or "from".
      settings: what names the demonstrations (`SweepSpec.data_settings`).
    """

    env: Any
    task: tasks.Task
    train: Part
    val: Part
    normalizer: Normalizer
    expert: Callable[[jax.Array], jax.Array]
    card: dict | None
    data_path: str
    source: str
    settings: dict

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


def prepare(spec: SweepSpec, hooks: Hooks = Hooks()) -> Prepared:
    """Phase 1: the environment, the demonstrations (collected or cached, or `spec.dataset`), the split and the
    normaliser. Raises `ValueError` (one line) for demonstrations that do not fit the environment or are too few.
    """
    import envs

    env = envs.make(spec.env, obs=spec.obs, **spec.env_overrides())
    settings = spec.data_settings()
    if spec.dataset is None:
        with hooks.bar(desc="collect", total=spec.episodes, unit="episode") as b:
            demos, _, path, cached = collect.collect_cached(settings, spec.data_dir or data_lib.cache_dir(),
                                                            progress=lambda n: b.update(n - b.n),
                                                            save=jax.process_index() == 0)
            b.update(spec.episodes - b.n)
        source = "cached" if cached else "collected"
    else:
        check_protocol(minari_io.dataset_settings(spec.dataset), spec, str(spec.dataset))
        demos, path = minari_io.load_dataset(spec.dataset)
        source = "from"
    check_fits(demos, env, str(path))
    hooks.log(f"demonstrations: {len(demos):,} transitions in {demos.num_episodes} episodes ({source}: {path})")
    protocol = spec.protocol
    train, val = data_lib.split_parts(demos, protocol.split, protocol.train_transitions, protocol.val_transitions,
                                      protocol.val_frac, seed=0)
    if len(train) < spec.recipe.batch_size:
        raise ValueError(f"the training split has {len(train)} transitions, fewer than the batch size "
                         f"{spec.recipe.batch_size}; collect more episodes")
    expert, _ = collect.expert_for(env, protocol.expert)
    card = collect.reference_returns(spec.env, protocol)
    return Prepared(env=env, task=spec.task, train=train, val=val, normalizer=Normalizer.fit(train.obs),
                    expert=expert, card=card, data_path=str(path), source=source, settings=settings)


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

@dataclasses.dataclass(frozen=True)
class Program:
    """Runs that train in one compiled program, with its config and learner."""

    name: str
    cfg: LearnerConfig
    runs: tuple[Run, ...]
    learner: Learner


def grid_runs(names: Sequence[str], seeds: int, ctx: methods_lib.GridContext) -> list[Run]:
    """Every (method, hparams, seed) of the sweep: methods in registry order, then settings, then seeds."""
    order = [m for m in methods_lib.names() if m in names]
    return [Run(m, settings, seed) for m in order for settings in methods_lib.get(m).settings(ctx)
            for seed in range(seeds)]


def score_rows(names: Sequence[str]) -> tuple[str, ...]:
    """Rows of the score table the weighted learner reads: `"ape"`, then each method with scores of its own."""
    return ("ape", *(m for m in methods_lib.names() if m in names and methods_lib.get(m).score is not None))


def method_scores(names: Sequence[str], train: Part) -> jax.Array:
    """`[len(score_rows(names)) - 1, N] float32`: each weighting method's scores of the training rows (the rows
    after the APE). A method scores the whole episodes (its `t` and actions in order), read at the part's rows.

    Raises `methods.PluginError` for scores that are not `[M]` finite float32.
    """
    action, t = jnp.asarray(train.demos.action), jnp.asarray(train.demos.t)
    rows = [train.own(methods_lib.get(m).score(methods_lib.score_key(m), action, t)) for m in score_rows(names)[1:]]
    return jnp.asarray(np.stack(rows)) if rows else jnp.zeros((0, len(train)), jnp.float32)


def score_table(ape: jax.Array, scores: jax.Array) -> jax.Array:
    """The table the weighted learner reads: the APE (row 0) above the methods' scores (`method_scores`)."""
    return jnp.concatenate([jnp.asarray(ape, jnp.float32)[None], scores])


def plan(spec: SweepSpec, prepared: Prepared) -> list[Program]:
    """Phase 3a: the sweep's runs, grouped by the program they train in (in registry order)."""
    recipe = spec.recipe
    ctx = methods_lib.GridContext(task=prepared.task, step_grid=recipe.step_grid, softmax_grid=recipe.softmax_grid,
                                  n_train=len(prepared.train), fca_alphas=recipe.fca_alphas,
                                  ib_weights=recipe.ib_weights)
    runs = grid_runs(spec.methods, spec.budget.seeds, ctx)
    if not runs:
        raise ValueError(f"nothing to train: the recipe's grids are empty for {', '.join(spec.methods)}")
    programs = []
    for name in dict.fromkeys(methods_lib.get(r.method).program for r in runs):
        mine = tuple(r for r in runs if methods_lib.get(r.method).program == name)
        method = methods_lib.get(mine[0].method)
        cfg = prepared.learner_config(spec.settings, method.history or spec.protocol.history)
        if method.learner is None:
            learner = make_train(cfg)
        else:
            learner = method.learner(methods_lib.LearnerContext(
                cfg=cfg, env=prepared.env, expert=prepared.expert, obs_mean=prepared.normalizer.mean,
                obs_std=prepared.normalizer.std, n_train=len(prepared.train)))
        programs.append(Program(name, cfg, mine, learner))
    return programs


def traced_hparams(runs: Sequence[Run], lr: float, rows: Sequence[str]) -> Any:
    """The runs' traced hyperparameters stacked along a leading axis (`Method.hparams`, each with its score row)."""
    def one(r: Run):
        method = methods_lib.get(r.method)
        return method.hparams(r.hparams, lr, rows.index(r.method) if method.score is not None else 0)

    return jax.tree.map(lambda *xs: jnp.stack(xs), *[one(r) for r in runs])


@dataclasses.dataclass(frozen=True)
class Trained:
    """One program's output: its policies (leaves `[len(runs), ...]`), per-iteration metrics, and times."""

    program: Program
    params: Any
    metrics: dict
    compile_s: float
    train_s: float
    snapshots: dict = dataclasses.field(default_factory=dict)  # {iteration: params} at `Budget.eval_at`


def train_program(program: Program, hparams: Any, budget, data: Data, progress: Callable[[int], None],
                  chunk: int | None = None, vectorize: bool = True,
                  checkpoint: ProgramCheckpoint | None = None, curves: Any = None) -> tuple[Any, dict, dict[int, Any]]:
    """Trains a program's runs vmapped and sharded over devices, in chunks of iterations.

    Round-based learners (boosting, DAgger) get `next_round` between rounds.
    `chunk` overrides the budget's iterations per compiled call; `vectorize=False`
    trains the runs one after another instead of vmapped (`grid.grid_runner`);
    vmapped, the runs train `budget.width` per device at a time (0: all at once).
    A chunk that would pass an iteration of `budget.eval_at` (counted over all
    rounds) stops there, and the policies are kept (a snapshot).
    With a `checkpoint`, training continues from its latest save and saves
    the state and curves after every chunk that passes a multiple of its
    interval, and at the end; snapshots are saved when taken. `curves` (a `Hooks.curves` sink) is started with
    the restored curves and gets every chunk's metrics as it finishes.

    Returns:
      (params, metrics, snapshots): the policies' parameters, leaves `[len(runs), ...]`;
      metrics `[len(runs), rounds * round_iterations]`; `{iteration: params}` at `budget.eval_at`.
    """
    learner, runs = program.learner, program.runs
    keys = jnp.stack([r.key for r in runs])
    chunk = chunk or budget.chunk
    width = getattr(budget, "width", 0) or None
    init = grid_runner(learner.init, vectorize=vectorize, width=width)
    pad = -len(runs) % len(init.devices)  # padded once, so the chunk runners never pad or trim
    hps = pad_grid(hparams, pad)
    state = init(pad_grid(keys, pad), hps, data)
    start, metrics = 0, []
    if jax.process_count() == 1:
        saved = checkpoint.restore(state) if checkpoint is not None else None
    else:
        saved = _restore_on_every_process(checkpoint, state, learner, hps, data)
    trim = functools.partial(jax.tree.map, lambda x: x[: len(runs)])
    at = tuple(getattr(budget, "eval_at", ()))
    snapshots = {}
    if saved is not None:
        start, state, restored = saved
        metrics.append(restored)
        progress(start)
        if checkpoint is not None:  # process 0's: the others never evaluate
            like = trim(learner.policy_params(state))
            snapshots = {i: checkpoint.load_snapshot(i, like) for i in at if i <= start}
    if curves is not None:
        curves.start(trim(metrics[0]) if metrics else None)
    total = learner.rounds * learner.round_iterations
    runners = {}
    for r in range(learner.rounds):
        first = r * learner.round_iterations  # this round's first iteration, counted over all rounds
        if start >= first + learner.round_iterations:
            continue  # finished before the checkpoint
        if r and start <= first:
            runners.setdefault("next_round", grid_runner(learner.next_round, vectorize=vectorize,
                                                                  width=width))
            state = runners["next_round"](state, hps, data)
        done = max(0, start - first)
        while done < learner.round_iterations:
            n = min(chunk - done % chunk, learner.round_iterations - done)  # chunks end at multiples of chunk
            n = min([n, *(i - first - done for i in at if i > first + done)])  # and stop at a snapshot
            if n not in runners:
                runners[n] = grid_runner(lambda s, hp, d, n=n: learner.run(s, hp, d, n), vectorize=vectorize,
                                         width=width)
            state, m = runners[n](state, hps, data)
            metrics.append(jax.device_get(m))
            if curves is not None:
                curves.append(trim(metrics[-1]))
            done += n
            if first + done in at:
                snapshots[first + done] = trim(learner.policy_params(state))
                if checkpoint is not None:
                    checkpoint.save_snapshot(first + done, snapshots[first + done])
            if checkpoint is not None and (checkpoint.due(first + done) or first + done == total):
                metrics = [_concat(metrics)]
                checkpoint.save(first + done, state, metrics[0])
            progress(n)
    return trim(learner.policy_params(state)), trim(_concat(metrics)), snapshots


def _restore_on_every_process(checkpoint: ProgramCheckpoint | None, state: Any, learner: Learner, hparams: Any,
                               data: Data) -> tuple[int, Any, dict] | None:
    """`checkpoint.restore(state)` as process 0 has it, on every process of a multi-process run.

    Only process 0 reads checkpoints (the others get none), but every process
    must run the same training chunks: the iteration it resumes from, the
    state and the curves so far are sent from it to the others, bit for bit.
    """
    failure, saved = None, None
    if checkpoint is not None:
        try:
            saved = checkpoint.restore(state)
        except ckpt_lib.CheckpointError as e:  # told to the others before raising, or they would wait forever
            failure = e
    start = int(from_process_zero(np.int64(-1 if failure else saved[0] if saved else 0)))
    if start < 0:
        raise failure or ckpt_lib.CheckpointError("process 0 could not read its checkpoint of this program "
                                                  "(its output says why)")
    if start == 0:
        return None
    # the others know the curves' names and dtypes from the program's output, not from a file
    shapes = jax.eval_shape(jax.vmap(lambda s, hp, d: learner.run(s, hp, d, 1), in_axes=(0, 0, None)),
                            state, hparams, data)[1]
    curves = {k: np.zeros((v.shape[0], start), v.dtype) for k, v in shapes.items()}
    if saved is not None:
        state = saved[1]
        curves = {k: np.asarray(saved[2][k], v.dtype) for k, v in curves.items()}
    state, curves = from_process_zero((jax.tree.map(np.asarray, state), curves))
    return start, state, curves


def _concat(metrics: list[dict]) -> dict:
    """Per-chunk metrics `[G, n]` joined along the iteration axis."""
    return jax.tree.map(lambda *xs: np.concatenate(xs, axis=1), *metrics)


def train(programs: Sequence[Program], spec: SweepSpec, prepared: Prepared, data: Data, hooks: Hooks = Hooks(),
          checkpoint: SweepCheckpoint | None = None) -> list[Trained]:
    """Phase 3b: every program trained, one after another; compile time estimated apart from steady state."""
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
            params, metrics, snapshots = train_program(
                program, traced_hparams(program.runs, spec.recipe.lr, rows), spec.budget, data, tick,
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
    """Policies with the same history (the same network): one evaluation program."""

    history: int
    cfg: LearnerConfig
    runs: tuple[Run, ...]
    params: Any  # leaves [len(runs), ...]

    @property
    def name(self) -> str:
        return f"h{self.history}"


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
    own rollouts), the velocity the demonstrations' `qvel` where they hold one. A network that gives no
    embedding (its `__call__` takes no `return_embedding`, e.g. a plugin's) gets `{"diag_absent": [P]}`."""
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
    expert = diagnostics_lib.demonstration_rollouts(demos.action, demos.episode)
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
    `width` at a time (`Budget.width`; 0: all together) through the evaluation and the loss analysis."""
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
    """Phase 4: every policy on the same `episodes` episodes, one program per history (groups saved in
    `checkpoint` reused), `width` policies at a time (`Budget.width`; 0: a group at once), with the copycat
    diagnostics at `probe_steps` (`Budget.probe_steps`; 0: none); the same for the policies kept at each
    iteration of `Budget.eval_at` (`Trained.snapshots`)."""
    points = sorted({i for t in trained for i in t.snapshots})
    seconds = {"eval": 0.0, "diagnostics": 0.0}
    total = sum(len(t.program.runs) * (1 + len(t.snapshots)) for t in trained) * episodes
    with hooks.bar(desc="evaluate", total=total, unit="episode") as b:

        def evaluated(history: int, mine: list[Trained], params: list, name: str):
            group = PolicyGroup(history, mine[0].program.cfg, tuple(r for t in mine for r in t.program.runs),
                                jax.tree.map(lambda *xs: jnp.concatenate(xs), *params))
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

        final, snapshots = [], {i: [] for i in points}
        for history in dict.fromkeys(t.program.cfg.history for t in trained):
            mine = [t for t in trained if t.program.cfg.history == history]
            final.append(evaluated(history, mine, [t.params for t in mine], f"eval-h{history}"))
            for i in points:
                passed = [t for t in mine if i in t.snapshots]
                if passed:
                    snapshots[i].append(evaluated(history, passed, [t.snapshots[i] for t in passed],
                                                  f"eval-h{history}-at{i}"))
    groups, outputs, losses = zip(*final) if final else ((), (), ())
    return Evaluated(tuple(groups), tuple(outputs), tuple(losses), seconds["eval"], seconds["diagnostics"],
                     {i: tuple(v) for i, v in snapshots.items()})


def diagnostics_record(out: dict, j: int) -> dict | None:
    """Run `j`'s `diagnostics` in results.json from its group's outputs, None where the group has none (outputs
    saved before them, or a sweep that is not `diagnosable`)."""
    if f"{DIAG}absent" in out:
        return {"absent": "the policy's network gives no embedding (it takes no return_embedding)"}
    if f"{DIAG}copycat" not in out:
        return None
    value = {k: float(out[DIAG + k][j]) for k in diagnostics_lib.FIELDS if k != "copycat" and DIAG + k in out}
    value = {k: v if np.isfinite(v) else None for k, v in value.items()}  # e.g. no velocity: null, never 0
    value["predictability_steps"] = int(value["predictability_steps"])
    value["verdict"] = diagnostics_lib.COPYCAT if bool(out[f"{DIAG}copycat"][j]) else diagnostics_lib.NOT_COPYCAT
    return value


# -- 5. assemble ----------------------------------------------------------------------------------------------------

def eval_record(out: dict, j: int, prepared: Prepared) -> dict:
    """Row `j`'s `eval` block in results.json from its group's evaluation outputs `out`."""
    returns = np.asarray(out["return"][j], np.float64)
    ev = {"episodes": int(len(returns)), "return_mean": float(returns.mean()), "return_std": float(returns.std())}
    if prepared.card is not None:
        ev["normalized"] = float(evaluate_lib.normalized(returns.mean(), prepared.card["return_mean"],
                                                         prepared.card["random_return_mean"]))
    for k in (*prepared.task.metrics, *COPYCAT_METRICS):
        if k in out:
            ev[k] = float(np.mean(out[k][j]))
    if prepared.task.metric != "return":
        ev.setdefault("normalized", 100.0 * ev[prepared.task.metric])  # a rate, in % (no return to normalise)
    return ev


def run_record(run: Run, j: int, out: dict, losses: dict, curves: dict, prepared: Prepared) -> dict:
    """Run `run`'s record in results.json; `j` is its row in the evaluation outputs `out` and `losses`; `curves`
    its per-iteration training metrics (`"loss"` and the learner's others, e.g. FCA's `adversary_loss`)."""
    returns = np.asarray(out["return"][j], np.float64)
    record = {"method": run.method, "hparams": run.hparams, "seed": run.seed, "status": "ok", "error": None,
              "online": methods_lib.get(run.method).online}
    loss_curve = np.asarray(curves["loss"])
    bad = np.flatnonzero(~np.isfinite(loss_curve))
    if len(bad):
        record.update(status="failed", error=f"training loss became non-finite at iteration {int(bad[0])}")
    elif not np.all(np.isfinite(returns)):
        record.update(status="failed", error="evaluation returns are non-finite")
    record["eval"] = eval_record(out, j, prepared)
    if (diag := diagnostics_record(out, j)) is not None:
        record["diagnostics"] = diag
    record["losses"] = {split: {k: float(v[j]) for k, v in losses[split].items()} for split in losses}
    record["train_loss_final"] = float(np.mean(loss_curve[-100:]))
    # every training metric over the last 1% of the run (at least 100 minibatches): e.g. FCA's adversary against
    # its reference predictor of a_{t-1} from a_t alone
    tail = max(100, len(loss_curve) // 100)
    record["train_final"] = {k: float(np.mean(np.asarray(v)[-tail:])) for k, v in curves.items()}
    record["train_curve"] = window_means(loss_curve, CURVE_POINTS)
    return record


def snapshot_record(iteration: int, j: int, out: dict, losses: dict, curves: dict, prepared: Prepared) -> dict:
    """One entry of a run's `at` list in results.json: its policy at `iteration` (`Budget.eval_at`) evaluated as
    at the end (`eval`, `diagnostics`, `losses`), and its training loss over the 100 minibatches before."""
    loss = np.asarray(curves["loss"])[max(0, iteration - 100):iteration]
    record = {"iteration": iteration, "eval": eval_record(out, j, prepared),
              "losses": {split: {k: float(v[j]) for k, v in losses[split].items()} for split in losses},
              "train_loss": float(np.mean(loss)) if len(loss) else None}
    if (diag := diagnostics_record(out, j)) is not None:
        record["diagnostics"] = diag
    return record


def window_means(values: np.ndarray, points: int) -> list[float]:
    """`values` cut into `points` consecutive windows of equal length (the last takes the rest), each window's mean."""
    values = np.asarray(values, np.float64)
    width = max(1, len(values) // points)
    ends = [*range(width, len(values), width)][: points - 1] + [len(values)]
    return [float(values[a:b].mean()) for a, b in zip([0, *ends[:-1]], ends)]


def assemble(spec: SweepSpec, prepared: Prepared, ape: ApeFit, trained: Sequence[Trained], evaluated: Evaluated,
             timing: dict) -> results_lib.Results:
    """Phase 5: the sweep's `Results` (records in plan order)."""
    curves = {r.ident: {k: v[i] for k, v in t.metrics.items()} for t in trained for i, r in enumerate(t.program.runs)}
    records = {}
    for group, out, losses in zip(evaluated.groups, evaluated.outputs, evaluated.losses):
        for j, r in enumerate(group.runs):
            records[r.ident] = run_record(r, j, out, losses, curves[r.ident], prepared)
    for iteration, at in sorted(evaluated.snapshots.items()):
        for group, out, losses in at:
            for j, r in enumerate(group.runs):
                records[r.ident].setdefault("at", []).append(
                    snapshot_record(iteration, j, out, losses, curves[r.ident], prepared))
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
                       "episodes": prepared.train.num_episodes, "settings": prepared.settings}}
    card = prepared.card
    expert = ({"return_mean": card["return_mean"], "return_std": card["return_std"],
               "random_return_mean": card["random_return_mean"]} if card is not None else
              {"return_mean": None, "return_std": None, "random_return_mean": None, "kind": task.expert})
    if (diag := diagnostics_config(prepared, evaluated.outputs)) is not None:
        config["diagnostics"] = diag
    config["env"] = {"dt": float(prepared.env.dt), "episode_length": int(prepared.env.episode_length),
                     "overrides": {k: list(v) if isinstance(v, tuple) else v for k, v in spec.env_overrides().items()}}
    return results_lib.Results(
        env=spec.env, obs=spec.obs, preset=spec.preset_name, config=config, expert=expert, runs=runs,
        summary=results_lib.summarize(runs, task.metrics), timing=timing,
        command=list(spec.command) if spec.command is not None else None,
        protocol=spec.protocol_settings(), settings=blocks,
        methods={m: results_lib.method_info(m) for m in dict.fromkeys(r["method"] for r in runs)})


def diagnostics_config(prepared: Prepared, outputs: Sequence[dict]) -> dict | None:
    """What the runs' `diagnostics` mean (results.json's `config.diagnostics`), None where no group's evaluation
    `outputs` have them."""
    out = next((o for o in outputs if f"{DIAG}probe_rows_train" in o), None)
    if out is None:
        return None
    demos = prepared.train.demos
    return {"thresholds": dataclasses.asdict(diagnostics_lib.THRESHOLDS),
            "probe_steps": int(out[f"{DIAG}probe_steps"][0]),
            "probe_rows": {"train": int(out[f"{DIAG}probe_rows_train"][0]),
                           "val": int(out[f"{DIAG}probe_rows_val"][0])},
            "expert_rollouts": f"the demonstrations' {demos.num_episodes} training episodes, cut to each policy's "
                               "step count",
            "velocity": "qvel" if "qvel" in demos.sim else None,
            "state": "qpos[1:], qvel (the expert's observation)" if {"qpos", "qvel"} <= set(demos.sim) else None}


def policies(evaluated: Evaluated, prepared: Prepared) -> dict[str, dict]:
    """The trained policies per history, as `checkpoint.save_policies` writes them."""
    return {g.name: {"runs": [dataclasses.asdict(r) for r in g.runs], "params": g.params,
                     "obs_mean": prepared.normalizer.mean, "obs_std": prepared.normalizer.std}
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
    t_start = time.perf_counter()
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
    return assemble(spec, prepared, ape, trained, evaluated, timing), policies(evaluated, prepared)
