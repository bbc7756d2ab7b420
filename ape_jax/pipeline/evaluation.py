"""A sweep's fourth phase (`ape_jax.pipeline.sweep`): every policy on the same episodes (`EVAL_SEED`), with the
copycat diagnostics and the loss analysis on both splits.

Policies are evaluated in groups of one network: one observation, one history, and one way of acting. A method
whose record gives `Method.runtime` (`ape_jax.evaluate.Runtime`: ACT's action chunks, PrimeNet's composite)
gets groups of its own, named after its program (`h1-action-chunks`), read through its runtime everywhere here.
"""

from __future__ import annotations

import dataclasses
import inspect
import time
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import diagnostics as diagnostics_lib
from ape_jax import evaluate as evaluate_lib
from ape_jax import methods as methods_lib
from ape_jax.learner import Data, LearnerConfig
from ape_jax.pipeline import checkpoint as ckpt_lib
from ape_jax.pipeline.checkpoint import SweepCheckpoint
from ape_jax.pipeline.hooks import Hooks
from ape_jax.pipeline.prepare import ApeFit, Prepared
from ape_jax.pipeline.training import Trained
from ape_jax.pipeline.records import DIAG
from ape_jax.pipeline.spec import Run

EVAL_SEED = 12345  # every policy is evaluated on the same episodes
DIAGNOSTICS_SEED = 0  # the embedding probes' and ψ's key in `ape_jax.diagnostics.diagnose`


# -- 4. evaluate ----------------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class PolicyGroup:
    """Policies with the same observation and history (the same network): one evaluation program.

    `observation`: what they read (`Prepared.observing`: None, the sweep's own; `"full"`, the full state); `view`:
    the sweep in that observation (`Prepared.view`, a sweep's `Program.view`), what they are evaluated, analysed
    and diagnosed in, and whose normalizer they are saved with."""

    history: int
    cfg: LearnerConfig
    runs: tuple[Run, ...]
    params: Any  # leaves [len(runs), ...]
    observation: str | None = None
    view: Prepared | None = dataclasses.field(default=None, compare=False, repr=False)

    @property
    def kind(self) -> str | None:
        """How its policies act: None, `cfg.model()` on the history; else the program of a method whose module
        reads its policies itself (`policy_kind`)."""
        return policy_kind(self.runs[0].method) if self.runs else None

    @property
    def name(self) -> str:
        """`h<H>` for the sweep's observation (the name every sweep has used), `<observation>-h<H>` for another;
        `-<kind>` after it for a method's own policies (`h1-action-chunks`)."""
        name = f"h{self.history}" if self.observation is None else f"{self.observation}-h{self.history}"
        return name if self.kind is None else f"{name}-{self.kind}"

    @property
    def runtime(self) -> evaluate_lib.Runtime | None:
        """How its policies are read where they are not `cfg.model()` (`ape_jax.evaluate.runtime_of`), or None."""
        if self.kind is None:
            return None
        return evaluate_lib.runtime_of(self.cfg, self.runs[0].method, [dict(r.hparams) for r in self.runs])


def policy_kind(method: str) -> str | None:
    """The program of `method` where its record gives its trained policies a run-time policy of their own
    (`Method.runtime`, what `evaluate.runtime_factory` reads): its policies form groups of their own; None for a plain
    `cfg.model()` (or a method not registered here)."""
    try:
        record = methods_lib.get(method)
    except methods_lib.MethodError:   # a plugin's, of a file evaluated again: not registered in this process
        return None
    return record.program if record.runtime is not None else None


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


def group_diagnostics(group: PolicyGroup, data: tuple[Data, Data], actions: np.ndarray, valid: np.ndarray,
                      steps: int) -> dict[str, np.ndarray]:
    """The group's copycat diagnostics (`ape_jax.diagnostics.diagnose`) as `{"diag_<field>": [P]}`, probed on
    `data`, the training and validation rows of its view with their APE (`Prepared.data`); the expert's
    rollouts are its demonstrations' training episodes (a sweep collects them without noise, so they are its
    own rollouts) as executed (`Demonstrations.executed`: the clipped actions the env ran, like the policies'
    rollout actions, whatever the labels), the velocity the demonstrations' `qvel` where they hold one. A
    network that gives no embedding (its `__call__` takes no `return_embedding`, e.g. a plugin's) gets
    `{"diag_absent": [P]}`; a group with a `Runtime` is probed through its `apply`, which gives one."""
    runtime = group.runtime
    if runtime is None and "return_embedding" not in inspect.signature(type(group.cfg.model()).__call__).parameters:
        return {f"{DIAG}absent": np.ones(len(group.runs))}  # reported absent, never as zero
    (train, val), view = data, group.view
    demos = view.train.demos
    velocity = state = None
    both = [d.sim for d in (demos, view.val.demos)]
    if all("qvel" in sim for sim in both):
        velocity = tuple(sim["qvel"] for sim in both)
        if all("qpos" in sim for sim in both):  # the experts' observation: the root's x left out, as Brax does
            state = tuple(np.concatenate([sim["qpos"][:, 1:], sim["qvel"]], axis=-1) for sim in both)
    expert = diagnostics_lib.demonstration_rollouts(demos.executed, demos.episode)
    d = diagnostics_lib.diagnose(jax.random.PRNGKey(DIAGNOSTICS_SEED), group.cfg, group.params, train, val,
                                 actions, valid, expert, velocity, steps=steps, state=state,
                                 apply=None if runtime is None else runtime.apply)
    rows = d.pop("probe_rows")
    return {**{DIAG + k: np.asarray(v) for k, v in d.items()},
            f"{DIAG}probe_rows_train": np.full(len(group.runs), rows[0]),
            f"{DIAG}probe_rows_val": np.full(len(group.runs), rows[1]),
            f"{DIAG}probe_steps": np.full(len(group.runs), steps)}


def evaluate_group(ape: ApeFit, episodes: int, group: PolicyGroup, probe_steps: int = 0,
                   width: int = 0) -> tuple[dict, dict, float]:
    """Evaluation outputs `{"return": [P, E], metric: [P, E], ...}` (copycat diagnostics included: the
    `ape_jax.diagnostics` ones as `diag_<field>` `[P]` with `probe_steps` where `diagnosable`), the loss
    analysis `{"train": {...: [P]}, "val": {...}}` of one group, and the diagnostics' seconds. The policies go
    `width` at a time (`Budget.width`; 0: all together) through the evaluation and the loss analysis. The group is
    evaluated, analysed and diagnosed in its own view (`PolicyGroup.view`: another observation's for a group
    reading one); a group with a `Runtime` (`PolicyGroup.runtime`) acts and is scored through it."""
    view, runtime = group.view, group.runtime
    diagnostics = diagnosable(episodes, probe_steps, view.train.demos.num_episodes)
    evaluator = evaluate_lib.make_evaluator(view.env, group.cfg, view.normalizer.mean, view.normalizer.std, episodes,
                                            expert=view.expert, ape_params=ape.params, ape_scale=ape.raw_mean,
                                            keep_actions=diagnostics, width=width or None, runtime=runtime)
    out = jax.device_get(evaluator(group.params, jax.random.PRNGKey(EVAL_SEED)))
    # both splits on device with their APE, once: the loss analysis and the diagnostics read the same rows
    data = view.data(view.train, ape.train), view.data(view.val, ape.val)
    losses = {split: jax.device_get(evaluate_lib.loss_analysis(group.cfg, group.params, d, width=width or None,
                                                               runtime=runtime))
              for split, d in zip(("train", "val"), data)}
    diag_s = 0.0
    if diagnostics:
        t0 = time.perf_counter()
        out.update(group_diagnostics(group, data, out.pop("actions"), out.pop("valid"), probe_steps))
        diag_s = time.perf_counter() - t0
    return out, losses, diag_s


def evaluate(trained: Sequence[Trained], ape: ApeFit, episodes: int, hooks: Hooks = Hooks(),
             checkpoint: SweepCheckpoint | None = None, probe_steps: int = 0, width: int = 0) -> Evaluated:
    """Phase 4: every policy on the same `episodes` episodes, one program per observation, history and kind of
    policy (`PolicyGroup`, in its programs' view, `Program.view`; groups saved in `checkpoint` reused), `width`
    policies at a time (`Budget.width`; 0: a group at once), with the copycat diagnostics at `probe_steps`
    (`Budget.probe_steps`; 0: none); the same for the policies kept at each iteration of `Budget.eval_at`
    (`Trained.snapshots`)."""
    points = sorted({i for t in trained for i in t.snapshots})
    seconds = {"eval": 0.0, "diagnostics": 0.0}
    total = sum(len(t.program.runs) * (1 + len(t.snapshots)) for t in trained) * episodes
    with hooks.bar(desc="evaluate", total=total, unit="episode") as b:

        def evaluated(seen: tuple[str | None, int, str | None], mine: list[Trained], params: list,
                      at: int | None = None):
            program = mine[0].program
            group = PolicyGroup(seen[1], program.cfg, tuple(r for t in mine for r in t.program.runs),
                                jax.tree.map(lambda *xs: jnp.concatenate(xs), *params), seen[0], program.view)
            name = f"eval-{group.name}" + ("" if at is None else f"-at{at}")
            saved = ckpt_lib.load_evaluation(checkpoint, name)
            if saved is None:
                t0 = time.perf_counter()
                out, loss, diag_s = evaluate_group(ape, episodes, group, probe_steps, width)
                saved = out, loss
                seconds["eval"] += time.perf_counter() - t0
                seconds["diagnostics"] += diag_s
                ckpt_lib.save_evaluation(checkpoint, name, *saved)
            b.update(len(group.runs) * episodes)
            return group, *saved

        def seen(t: Trained) -> tuple[str | None, int, str | None]:
            return t.program.observation, t.program.cfg.history, policy_kind(t.program.runs[0].method)

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
