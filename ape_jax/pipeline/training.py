"""The training driver: a sweep's compiled programs, trained in checkpointed chunks on one process or several.

    program = Program("grid", cfg, runs, make_train(cfg))
    params, metrics, snapshots = train_program(program, traced_hparams(runs, lr, rows), budget, data, progress)

A `Program` is the runs that train in one compiled `jit(vmap(scan))` (the sweep's
`plan` groups them; `ape_jax.methods` says which program a method trains in).
`train_program` trains one: its grid axis vmapped `Budget.width` per device at a
time and sharded over every device (`ape_jax.grid.grid_runner`), in chunks of
iterations so progress moves and checkpoints can be taken, round by round for
round-based learners (boosting, DAgger), stopping at each iteration of
`Budget.eval_at` to keep the policies there. With a `checkpoint.ProgramCheckpoint`
it continues from the latest save bit for bit; with several JAX processes the state
to resume comes from process 0 (`grid.from_process_zero`), since only it reads
checkpoints. Image policies on a CPU through a convolutional encoder train one
configuration after another (`trains_sequentially`, `CPU_IMAGE_CHUNK`).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import methods as methods_lib
from ape_jax.grid import from_process_zero, grid_runner, pad_grid
from ape_jax.learner import Data, Learner, LearnerConfig
from ape_jax.models import IMAGE_ENCODERS
from ape_jax.pipeline import checkpoint as ckpt_lib
from ape_jax.pipeline.checkpoint import ProgramCheckpoint
from ape_jax.pipeline.spec import Run

# Image policies on CPU: XLA:CPU runs convolution gradients inside a loop ~50x slower than
# outside one, and vmapped (grouped) ones ~3x slower per model, so there every
# configuration of a convolutional encoder trains one after another through one compiled,
# fully unrolled chunk. An encoder of matrix products only (`loop_friendly`, e.g. "patch")
# trains as states do: the grid vmapped, in scanned chunks of the budget's size.
CPU_IMAGE_CHUNK = 10


def trains_sequentially(obs_shape: Sequence[int], encoder: str) -> bool:
    """Whether a sweep trains policies of `encoder` on `obs_shape` observations one configuration after another,
    `CPU_IMAGE_CHUNK` unrolled iterations per call: images through a convolutional encoder on a CPU."""
    return (len(obs_shape) == 3 and jax.default_backend() == "cpu"
            and not IMAGE_ENCODERS[encoder].loop_friendly)


@dataclasses.dataclass(frozen=True)
class Program:
    """Runs that train in one compiled program, with its config and learner, and the sweep as its policies see it.

    Attributes:
      observation: what its policies read (`Method.observation` as `prepare.Prepared.observing` names it: None,
        the sweep's own; `"full"`, the full state).
      view: the sweep in that observation (`prepare.Prepared.view`: the environment, the demonstrations' rows, their
        normalizer and the expert), made once when the sweep is planned; what the program trains on and its
        policies are evaluated in. None for a program trained outside a sweep.
      reads: the method whose trained policies its runs read (`Method.reads`: Priming's, BC-SO), trained first and
        handed to its hyperparameters (`methods.read_trained`); None for most.
    """

    name: str
    cfg: LearnerConfig
    runs: tuple[Run, ...]
    learner: Learner
    observation: str | None = None
    view: Any = dataclasses.field(default=None, compare=False, repr=False)
    reads: str | None = None


def traced_hparams(runs: Sequence[Run], lr: float, rows: Sequence[str]) -> Any:
    """The runs' traced hyperparameters stacked along a leading axis (`Method.hparams`, each with its score row)."""
    def one(r: Run):
        method = methods_lib.get(r.method)
        return method.hparams(r.hparams, lr, rows.index(r.method) if method.score is not None else 0)

    return jax.tree.map(lambda *xs: jnp.stack(xs), *[one(r) for r in runs])


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
    """`checkpoint.restore(state)` as process 0 has it, on every process (one process: its own restore).

    Only process 0 reads checkpoints (the others get none), but every process
    must run the same training chunks: the iteration it resumes from, the
    state and the curves so far are sent from it to the others, bit for bit.
    """
    if jax.process_count() == 1:
        return checkpoint.restore(state) if checkpoint is not None else None
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


@dataclasses.dataclass(frozen=True)
class Trained:
    """One program's output: its policies (leaves `[len(runs), ...]`), per-iteration metrics, and times."""

    program: Program
    params: Any
    metrics: dict
    compile_s: float
    train_s: float
    snapshots: dict = dataclasses.field(default_factory=dict)  # {iteration: params} at `Budget.eval_at`

