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
   own), each with the sweep as its policies see it (`Program.view`, made here
   once and read from the program by `train` and `evaluate`); `train` →
   `[Trained]`: each program trained vmapped over its runs and sharded over
   devices (`training.train_program`), in chunks so progress moves and
   checkpoints can be taken;
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

This module holds the third and fifth phases and the sweep itself; the first two are
`prepare`'s, the fourth `evaluation`'s, the host's hooks `hooks`'. What they read and write lives
beside it: `spec` (the `SweepSpec`, its `Run`s and the checks that refuse it early),
`training` (the training driver: `Program`, `train_program` with its checkpointed
chunks and rounds and the restore on every process), `ape_jax.scores` (the score table
the weighted learner reads), `records` (the records `assemble` writes) and `results`
(the results file, the fingerprint). Their public names are importable from here too (`__all__`), so a caller
of the sweep needs this module alone.
"""
from __future__ import annotations

import dataclasses
import resource
import time
from collections.abc import Sequence

import jax
import numpy as np

from ape_jax import methods as methods_lib
from ape_jax.grid import differing_processes
from ape_jax.learner import Data, make_train
from ape_jax.pipeline import judge as judge_lib
from ape_jax.pipeline import provenance
from ape_jax.pipeline import results as results_lib
from ape_jax.pipeline.checkpoint import SweepCheckpoint
from ape_jax.pipeline.evaluation import (DIAGNOSTICS_SEED, EVAL_SEED, Evaluated, PolicyGroup, diagnosable, evaluate,
                                         evaluate_group, group_diagnostics)
from ape_jax.pipeline.hooks import Hooks
from ape_jax.pipeline.prepare import (PROTOCOL_KEYS, ApeFit, Normalizer, Prepared, check_fits, check_protocol, fit_ape,
                                      part_errors, prepare)
from ape_jax.pipeline.records import (COPYCAT_METRICS, CURVE_POINTS, DIAG, diagnostics_config, diagnostics_record,
                                      eval_record, run_record, snapshot_record, window_means)
from ape_jax.pipeline.spec import Run, SweepSpec
from ape_jax.pipeline.training import (CPU_IMAGE_CHUNK, Program, Trained, traced_hparams, train_program,
                                       trains_sequentially)
from ape_jax.scores import method_scores, score_rows, score_table

__all__ = [
    # the phases and their outputs
    "Hooks", "Normalizer", "Prepared", "prepare", "ApeFit", "part_errors", "fit_ape", "plan", "Trained", "train",
    "PolicyGroup", "Evaluated", "diagnosable", "group_diagnostics", "evaluate_group", "evaluate", "assemble",
    "policies", "train_sweep", "run_sweep", "EVAL_SEED", "DIAGNOSTICS_SEED",
    # the spec (`spec`), its runs, and the demonstrations' checks (`prepare`)
    "SweepSpec", "Run", "grid_runs", "check_protocol", "check_fits", "PROTOCOL_KEYS",
    # the training driver (`training`)
    "Program", "train_program", "traced_hparams", "trains_sequentially", "CPU_IMAGE_CHUNK",
    # the score table (`ape_jax.scores`)
    "score_rows", "method_scores", "score_table",
    # the records of results.json (`records`)
    "run_record", "snapshot_record", "eval_record", "diagnostics_record", "diagnostics_config", "window_means",
    "CURVE_POINTS", "COPYCAT_METRICS", "DIAG",
]


# -- 3. plan and train ----------------------------------------------------------------------------------------------

def grid_runs(names: Sequence[str], seeds: int, ctx: methods_lib.GridContext, first_seed: int = 0) -> list[Run]:
    """Every (method, hparams, seed) of the sweep, seeds `first_seed, ..., first_seed + seeds - 1`: methods in
    registry order, then settings, then seeds."""
    order = [m for m in methods_lib.names() if m in names]
    return [Run(m, settings, seed) for m in order for settings in methods_lib.get(m).settings(ctx)
            for seed in range(first_seed, first_seed + seeds)]


def plan(spec: SweepSpec, prepared: Prepared) -> list[Program]:
    """Phase 3a: the sweep's runs, grouped by the program they train in (in registry order), each program with the
    observation its policies read and the sweep in it (`Program.view`, made here once: training and evaluation
    read it from the program)."""
    ctx = methods_lib.GridContext(task=prepared.task, n_train=len(prepared.train), knobs=spec.settings.knobs)
    runs = grid_runs(spec.methods, spec.budget.seeds, ctx, spec.budget.first_seed)
    if not runs:
        raise ValueError(f"nothing to train: the grids of {', '.join(spec.methods)} are empty")
    programs = []
    for name in dict.fromkeys(methods_lib.get(r.method).program for r in runs):
        mine = tuple(r for r in runs if methods_lib.get(r.method).program == name)
        method = methods_lib.get(mine[0].method)
        observation = prepared.observing(method.observation)
        view = prepared.view(observation)   # FullStateError before anything compiles
        cfg = view.learner_config(spec.settings, method.history or spec.protocol.history)
        if method.learner is None:
            learner = make_train(cfg)
        else:
            learner = method.learner(methods_lib.LearnerContext(
                cfg=cfg, env=view.env, expert=view.expert, obs_mean=view.normalizer.mean,
                obs_std=view.normalizer.std, n_train=len(view.train), knobs=spec.settings.knobs))
        programs.append(Program(name, cfg, mine, learner, observation, view,
                                method.reads(ctx) if method.reads is not None else None))
    # a program whose runs read another's trained policies (`Method.reads`: Priming, BC-SO's) trains after it
    return sorted(programs, key=lambda p: p.reads is not None)


def train(programs: Sequence[Program], spec: SweepSpec, prepared: Prepared, data: Data, hooks: Hooks = Hooks(),
          checkpoint: SweepCheckpoint | None = None) -> list[Trained]:
    """Phase 3b: every program trained, one after another; compile time estimated apart from steady state.

    `data` is the training split in the sweep's observation; a program reading another (`bc-full`) trains on
    the same rows, APE and scores in its own (`Program.view`)."""
    if jax.process_count() > 1:
        # each process gives its devices their rows from its own copy: every copy must be the same
        differ = differing_processes(data)
        if differ:
            raise ValueError(f"the training data of process(es) {', '.join(map(str, differ))} differ from process "
                             "0's (other demonstrations, or another machine computing them differently): every "
                             "process must train on the same data")
    # the sweep's own observation decides, for every program (`bc-full` too)
    sequential = trains_sequentially(prepared.env.observation_shape, spec.recipe.encoder)
    if sequential:
        hooks.log(f"image policies on CPU: configurations train one after another, {CPU_IMAGE_CHUNK} unrolled "
                  "iterations per call (XLA:CPU is slow at convolution gradients in loops and under vmap)")
        if spec.recipe.encoder == "resnet18":
            hooks.log("warning: ResNet-18 trains about a hundred times slower than the small encoder on a CPU; "
                      "the paper preset's image protocol is meant for GPUs")
    rows = score_rows(spec.methods)
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
            view = program.view
            own = data if program.observation is None else data.replace(obs=view.normalizer(view.train.demos.obs))
            hparams = traced_hparams(program.runs, spec.recipe.lr, rows)
            if read := program.reads:   # e.g. Priming's prime: each run its own seed's BC-SO policy (one process:
                # `SweepSpec` refuses a reading method in a multi-process sweep)
                source = next(t for t in out if any(r.method == read for r in t.program.runs))
                hparams = methods_lib.read_trained(hparams, program.runs, read, source.program.runs, source.params)
            params, metrics, snapshots = train_program(
                program, hparams, spec.budget, own, tick,
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
            "episodes": spec.setup.episodes, "recipe": spec.recipe.name}
    config = {**flat, **({"smoke": True} if spec.settings.smoke else {}),
              **({"preset_iterations": spec.settings.preset_iterations}
                 if spec.settings.preset_iterations is not None else {}),
              "methods": list(spec.methods), "loss": spec.recipe.loss or task.loss, "metric": task.metric,
              "task_metrics": list(task.metrics),
              "ape": {"normalization": spec.settings.ape_normalization, "scale": ape.scale,
                      "final_fit_mse": ape.final_fit_mse,
                      # the validation split's mean, on the scale it trained on; × scale ÷ raw_mean it is the
                      # expert's reference for the policies' rollout_ape (÷ the raw training mean)
                      "val_mean": float(np.mean(ape.val)), "raw_mean": ape.raw_mean,
                      # the training split's normalised APE distribution, for the weights' histograms
                      "quantiles": np.quantile(np.asarray(ape.train), np.linspace(0, 1, 101)).tolist()},
              "ape_normalization": spec.settings.ape_normalization,
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
    if prepared.perception is not None:   # the encoder the frames were seen through (its SHA-256 is the recipe's)
        config["perception"] = prepared.perception
    if (diag := diagnostics_config(prepared.train.demos, evaluated.outputs)) is not None:
        config["diagnostics"] = diag
    config["env"] = {"dt": float(prepared.env.dt), "episode_length": int(prepared.env.episode_length),
                     "overrides": {k: list(v) if isinstance(v, tuple) else v for k, v in spec.setup.evaluation.items()}}
    res = results_lib.Results(
        env=spec.env, obs=spec.obs, preset=spec.preset_name, config=config, expert=expert, runs=runs,
        summary=results_lib.summarize(runs, task.metrics), timing=timing,
        command=list(spec.command) if spec.command is not None else None,
        protocol=dict(spec.setup.applied.settings), settings=blocks,
        methods={m: results_lib.method_info(m) for m in dict.fromkeys(r["method"] for r in runs)})
    return judge_lib.judge_own(res)  # the controlled copycat verdict, where the sweep trained its control (BC-SO)


def policies(evaluated: Evaluated) -> dict[str, dict]:
    """The trained policies per group (observation and history, `PolicyGroup.name`), as
    `checkpoint.save_policies` writes them, each with its own observation statistics (its view's)."""
    return {g.name: {"runs": [dataclasses.asdict(r) for r in g.runs], "params": g.params,
                     "history": g.history, "observation": g.observation,
                     "obs_mean": g.view.normalizer.mean, "obs_std": g.view.normalizer.std}
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


def peak_device_mb() -> float | None:
    """The most memory this process held on its first local device, in MB, where the backend counts it (GPUs and
    TPUs: `peak_bytes_in_use`); None on a CPU."""
    try:
        stats = jax.local_devices()[0].memory_stats() or {}
    except Exception:  # noqa: BLE001 - a backend without memory statistics
        return None
    peak = stats.get("peak_bytes_in_use")
    return None if peak is None else peak / 2**20


def run_sweep(spec: SweepSpec, hooks: Hooks = Hooks(),
              checkpoint: SweepCheckpoint | None = None) -> tuple[results_lib.Results, dict[str, dict]]:
    """Runs the whole sweep; returns its `Results` and its policies (`policies`).

    With an opened `SweepCheckpoint`, every finished phase and the training
    states are saved there, and what it already holds is reused.
    """
    t_start, started = time.perf_counter(), provenance.system()  # the code that runs, taken when it starts
    prepared, ape, trained = train_sweep(spec, hooks, checkpoint)
    evaluated = evaluate(trained, ape, spec.budget.eval_episodes, hooks, checkpoint, spec.budget.probe_steps,
                         spec.budget.width)
    timing = {"compile_s": sum(t.compile_s for t in trained), "train_s": sum(t.train_s for t in trained),
              "eval_s": evaluated.eval_s, "diagnostics_s": evaluated.diagnostics_s,  # included in eval_s
              "total_s": time.perf_counter() - t_start,
              "resumed": bool(checkpoint is not None and checkpoint.resumed),
              # included in the phases' times
              "checkpoint_s": checkpoint.save_s if checkpoint is not None else 0.0,
              "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,  # this process's peak
              **({"peak_device_mb": peak} if (peak := peak_device_mb()) is not None else {})}
    res = assemble(spec, prepared, ape, trained, evaluated, timing)
    res.system = started
    return res, policies(evaluated)
