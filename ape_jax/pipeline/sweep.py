"""The main job as a library: demonstrations -> APE -> the weighting grid × seeds -> evaluation -> results.

`experiments.sweep` is its command line. One sweep is one environment and
observation mode:

1. **collect** the shipped expert's demonstrations (cached, `ape_jax.pipeline.collect`),
   split 80/20 by episode, standardise state observations with training
   statistics;
2. **fit APE** on the training split (`ape_jax.ape`), normalise by the training mean;
3. **train** BC-OH, the step and softmax grids and the weighting baselines
   (BOCPD, ActFreq, k-means, HistoryDropout) as one program (vmapped, sharded
   over devices, in chunks so a progress bar moves); BC-SO (history 1, a
   different input width) as a second; boosting, FCA and DAgger as programs
   of their own (`ape_jax.baselines`), each vmapped over seeds;
4. **evaluate** every policy on the same episodes (`ape_jax.evaluate`), with the
   copycat diagnostics (imitation error on its own states, APE of its own
   actions), and run the loss analysis on both splits;
5. assemble `results.json` as `DESIGN.md` fixes it.
"""

from __future__ import annotations

import dataclasses
import math
import resource
import time
from typing import Any, Callable

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import ape as ape_lib
from ape_jax import evaluate
from ape_jax.pipeline import collect, minari_io
from ape_jax.pipeline.data import Demonstrations
from ape_jax.pipeline.checkpoint import ProgramCheckpoint, SweepCheckpoint
from ape_jax.grid import grid_runner, pad_grid
from ape_jax.learner import Data, Hparams, Learner, LearnerConfig, make_train

METHODS = ("bc-so", "bc-oh", "ours-step", "ours-softmax",
           "bcpd", "actfreq", "kmeans", "boosting", "history-dropout", "fca", "dagger")
ONLINE = ("dagger",)  # the only method that queries the expert during training
STEP_GRID = tuple((thr, w) for thr in (0.1, 0.2) for w in (3.0, 5.0, 10.0))
SOFTMAX_GRID = (0.1, 0.2, 0.5, 1.0, 5.0, 10.0)
# Rows of the score table the weightings read (`ape_jax.weighting`): APE first.
SCORES = ("ape", "bcpd", "actfreq", "kmeans")
# Methods trained by the weighted learner, as one vmapped program (BC-SO is a
# second, with history 1); boosting, FCA and DAgger are programs of their own.
WEIGHTED = ("bc-oh", "ours-step", "ours-softmax", "bcpd", "actfreq", "kmeans", "history-dropout")
# Image policies on CPU: XLA:CPU runs convolution gradients inside a loop ~50x slower than
# outside one, and vmapped (grouped) ones ~3x slower per model, so there every
# configuration trains one after another through one compiled, fully unrolled chunk.
CPU_IMAGE_CHUNK = 10
EVAL_SEED = 12345  # every policy is evaluated on the same episodes
# Evaluation outputs beside the return that a run's record keeps (per-episode means): ToyCar's driving
# metrics and the copycat diagnostics.
EVAL_METRICS = ("success", "red_light_violations", "progress", "avg_speed", "stuck", "imitation_error", "rollout_ape")


@dataclasses.dataclass(frozen=True)
class Preset:
    """Every setting of a sweep that is not the environment (recorded in results.json)."""

    iterations: int
    seeds: int
    eval_episodes: int
    ape_steps: int
    episodes: int = 25            # demonstrations collected (80% train, 20% validation)
    batch_size: int = 128
    lr: float = 2e-4
    lr_decay_every: int | None = None  # default: a third of the iterations (the paper: 100k of 300k)
    history: int = 2
    eval_steps: int | None = None  # default: the environment's episode length (1000 for MuJoCo)
    chunk: int = 500              # iterations per compiled chunk (progress granularity)
    ape_normalization: str = "mean"
    val_frac: float = 0.2
    step_grid: tuple[tuple[float, float], ...] = STEP_GRID  # (THR, W) of ours-step
    softmax_grid: tuple[float, ...] = SOFTMAX_GRID            # τ of ours-softmax
    image_size: tuple[int, int] | None = None  # image observations: (height, width); None: the env's default
    encoder: str = "small"                     # image policies: "small" (CPU) or "resnet18" (the paper's, GPU)

    def learner_config(self, obs_shape, action_dim, history, loss, unroll: bool = False) -> LearnerConfig:
        return LearnerConfig(obs_shape=tuple(obs_shape), action_dim=action_dim, history=history,
                             iterations=self.iterations, batch_size=self.batch_size,
                             lr_decay_every=self.lr_decay_every or max(1, math.ceil(self.iterations / 3)),
                             loss=loss, unroll=unroll, encoder=self.encoder if len(obs_shape) == 3 else "small")


PRESETS = {
    "quick": Preset(iterations=3_000, seeds=1, eval_episodes=5, ape_steps=1_000, chunk=500),
    "default": Preset(iterations=30_000, seeds=3, eval_episodes=20, ape_steps=5_000, chunk=2_000),
    "paper": Preset(iterations=300_000, seeds=5, eval_episodes=100, ape_steps=20_000, chunk=10_000),
}
# Image observations. A conv policy trains tens of times slower per iteration than the state MLP on a
# 2-core CPU, so there `quick` and `default` shrink the images, the
# iterations and the grid to the paper's step setting and the softmax τ that was best on states;
# `paper` keeps the supplement's protocol with its ResNet-18, for GPUs.
IMAGE_PRESETS = {
    "quick": dict(iterations=300, eval_episodes=3, chunk=100, image_size=(32, 32),
                  step_grid=((0.1, 5.0),), softmax_grid=()),
    "default": dict(iterations=5_000, eval_episodes=10, chunk=250, image_size=(32, 32),
                    step_grid=((0.1, 5.0),), softmax_grid=(10.0,)),
    "paper": dict(encoder="resnet18"),
}
# ToyCar, the supplement's Table 4: 1k expert samples, 5 trials, BC-SO, BC-OH and Ours (THR 10%, W 5).
TOYCAR_PRESETS = {
    "quick": dict(image_size=(32, 32)),
    "default": dict(iterations=2_000, seeds=5, eval_episodes=20, chunk=250, image_size=(64, 64), softmax_grid=()),
    "paper": dict(seeds=5, softmax_grid=()),
}


def preset_for(name: str, env_name: str, obs: str) -> Preset:
    """Preset `name` as it applies to `env_name` with observations `obs` (images shrink it on CPUs)."""
    preset = PRESETS[name]
    if obs == "image":
        preset = dataclasses.replace(preset, **IMAGE_PRESETS[name])
        if env_name == "toycar":
            preset = dataclasses.replace(preset, **TOYCAR_PRESETS[name])
    return preset


@dataclasses.dataclass(frozen=True)
class Run:
    """One trained configuration: method, hyperparameters, seed."""

    method: str
    hparams: dict
    seed: int


def baseline_hparams(method: str, env_name: str, n_train: int | None = None) -> list[dict]:
    """The settings a baseline runs with (its reading of the paper is in its module's docstring)."""
    from ape_jax.baselines import boosting, dagger, fca

    return {
        "bcpd": [{"thr": 0.1, "w": 5.0}],   # the step function at the paper's setting for ours
        "actfreq": [{}],
        "kmeans": [{}],
        "boosting": [{"rounds": boosting.ROUNDS}],
        "history-dropout": [{"p": 0.5}],
        "fca": [{"alpha": fca.ALPHA[env_name]}],
        "dagger": [{"rounds": dagger.ROUNDS, "budget": n_train or 0}],
    }[method]


def grid_runs(methods: tuple[str, ...], seeds: int, env_name: str = "hopper", n_train: int | None = None,
              step_grid=STEP_GRID, softmax_grid=SOFTMAX_GRID) -> list[Run]:
    """Every (method, hparams, seed) of the sweep, in a fixed order: BC-SO, BC-OH, step grid, softmax grid, baselines.

    `n_train` (the training split's size) sets DAgger's query budget.
    """
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {unknown}; valid: {list(METHODS)}")
    out = []
    for seed in range(seeds):
        for method in METHODS:
            if method not in methods:
                continue
            if method in ("bc-so", "bc-oh"):
                out.append(Run(method, {}, seed))
            elif method == "ours-step":
                out += [Run(method, {"thr": thr, "w": w}, seed) for thr, w in step_grid]
            elif method == "ours-softmax":
                out += [Run(method, {"tau": tau}, seed) for tau in softmax_grid]
            else:
                out += [Run(method, hp, seed) for hp in baseline_hparams(method, env_name, n_train)]
    return out


def hparams_of(run: Run, lr: float):
    """The traced hyperparameters of one run (an `Hparams`, or FCA's `FcaHparams`)."""
    hp = run.hparams
    if run.method == "ours-step":
        return Hparams.make("step", lr=lr, thr=hp["thr"], w=hp["w"])
    if run.method == "ours-softmax":
        return Hparams.make("softmax", lr=lr, tau=hp["tau"])
    if run.method == "bcpd":
        return Hparams.make("step", lr=lr, thr=hp["thr"], w=hp["w"], source=SCORES.index("bcpd"))
    if run.method in ("actfreq", "kmeans"):
        return Hparams.make("given", lr=lr, source=SCORES.index(run.method))
    if run.method == "history-dropout":
        return Hparams.make("uniform", lr=lr, history_dropout=hp["p"])
    if run.method == "fca":
        from ape_jax.baselines.fca import FcaHparams

        return FcaHparams.make(alpha=hp["alpha"], lr=lr)
    return Hparams.make("uniform", lr=lr)


def program_of(method: str) -> str:
    """The compiled program a method trains in: `"grid"` (the weighted learner), `"bc-so"`, or its own."""
    return "grid" if method in WEIGHTED else method


def data_settings(env_name: str, obs: str, preset: Preset, dataset: str | None = None) -> dict:
    """What names a sweep's demonstrations: the collection settings, or the dataset file's path and size."""
    import pathlib

    if dataset is None:
        return collect.settings(env_name, obs, preset.episodes, seed=0, **_image_overrides(obs, preset))
    path = pathlib.Path(dataset)
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else []
    return {"dataset": str(path.absolute()), "bytes": sum(p.stat().st_size for p in files)}


def _image_overrides(obs: str, preset: Preset) -> dict:
    return {"image_size": preset.image_size} if obs == "image" and preset.image_size is not None else {}


def fingerprint(env_name: str, obs: str, preset_name: str, preset: Preset, methods: tuple[str, ...],
                data: dict) -> dict:
    """Everything that determines a sweep's results (`checkpoint.SweepCheckpoint` compares these)."""
    return {"env": env_name, "obs": obs, "preset": preset_name, "settings": dataclasses.asdict(preset),
            "methods": list(methods), "data": data}


def results_fingerprint(results: dict) -> dict:
    """The `fingerprint` of the sweep that wrote `results` (a `results.json`)."""
    fields = [f.name for f in dataclasses.fields(Preset)]
    config = results.get("config", {})
    return {"env": results.get("env"), "obs": results.get("obs"), "preset": results.get("preset"),
            "settings": {k: config.get(k) for k in fields}, "methods": config.get("methods"),
            "data": config.get("data", {}).get("settings")}


def prepare(demos: Demonstrations, preset: Preset, seed: int = 0):
    """Split by episode, standardise state observations; returns (train, val, obs_mean, obs_std)."""
    train, val = demos.split(preset.val_frac, seed=seed)
    if len(train) < preset.batch_size:
        raise ValueError(f"the training split has {len(train)} transitions, fewer than the batch size "
                         f"{preset.batch_size}; collect more episodes")
    if np.asarray(demos.obs).dtype == np.uint8:
        return train, val, None, None
    mean = np.asarray(train.obs).mean(0)
    std = np.asarray(train.obs).std(0) + 1e-6
    return train, val, mean.astype(np.float32), std.astype(np.float32)


def fit_ape(train: Demonstrations, val: Demonstrations, preset: Preset) -> dict:
    """ψ fitted on the training split's actions (key 0, deterministic) and both splits' normalised APE.

    Returns arrays (a checkpoint phase): `train`, `val` (APE), `scale` (the
    normalisation's divisor), `final_fit_mse`, `psi` (ψ, flax-serialised).
    """
    fit = jax.jit(lambda k, a, t: ape_lib.fit(k, a, t, steps=preset.ape_steps))
    ape_params, ape_losses = fit(jax.random.PRNGKey(0), jnp.asarray(train.action), jnp.asarray(train.t))
    ape_train = ape_lib.errors(ape_params, jnp.asarray(train.action), jnp.asarray(train.t))
    ape_val = ape_lib.errors(ape_params, jnp.asarray(val.action), jnp.asarray(val.t))
    ape_train, ape_val, ape_scale = ape_lib.normalize(ape_train, ape_val, preset.ape_normalization)
    return {"train": ape_train, "val": ape_val, "scale": ape_scale,
            "final_fit_mse": np.mean(np.asarray(ape_losses)[-50:]),
            "psi": np.frombuffer(flax.serialization.to_bytes(ape_params), np.uint8)}


def _data(split: Demonstrations, ape: jax.Array, mean, std, scores: jax.Array | None = None) -> Data:
    obs = jnp.asarray(split.obs)
    if mean is not None:
        obs = (obs - mean) / std
    return Data(obs=obs, action=jnp.asarray(split.action), t=jnp.asarray(split.t), ape=jnp.asarray(ape),
                scores=scores)


def score_table(methods: tuple[str, ...], train: Demonstrations, ape: jax.Array, seed: int = 0) -> jax.Array:
    """`[len(SCORES), N]`: the APE and, for the weighting baselines in `methods`, their scores (ones otherwise)."""
    from ape_jax.baselines import actfreq, bcpd, kmeans

    action, t = jnp.asarray(train.action), jnp.asarray(train.t)
    ones = jnp.ones_like(ape)
    rows = {
        "ape": lambda: ape,
        "bcpd": lambda: bcpd.changepoint_prob(action, t),
        "actfreq": lambda: jnp.asarray(actfreq.weights(action)),
        "kmeans": lambda: kmeans.weights(jax.random.PRNGKey(seed), action),
    }
    return jnp.stack([jnp.asarray(rows[name](), jnp.float32) if name == "ape" or name in methods else ones
                      for name in SCORES])


def make_learner(program: str, cfg: LearnerConfig, env, obs_mean, obs_std, n_train: int) -> Learner:
    """The `Learner` of one program (see `program_of`)."""
    if program in ("grid", "bc-so"):
        return make_train(cfg)
    if program == "boosting":
        from ape_jax.baselines import boosting

        return boosting.make_boosting(cfg)
    if program == "fca":
        from ape_jax.baselines import fca

        return fca.make_fca(cfg)
    if program == "dagger":
        from ape_jax.baselines import dagger

        expert, _ = collect.expert_for(env)
        return dagger.make_dagger(cfg, env, expert, obs_mean, obs_std, budget=n_train)
    raise ValueError(f"unknown program {program!r}")


def train_program(learner: Learner, runs: list[Run], preset: Preset, data: Data,
                  progress: Callable[[int], None], chunk: int | None = None, vectorize: bool = True,
                  checkpoint: ProgramCheckpoint | None = None) -> tuple[Any, dict]:
    """Trains `runs` (all of one program) vmapped and sharded over devices, in chunks of iterations.

    Round-based learners (boosting, DAgger) get `next_round` between rounds.
    `chunk` overrides the preset's iterations per compiled call; `vectorize=False`
    trains the runs one after another instead of vmapped (`grid.grid_runner`).
    With a `checkpoint`, training continues from its latest save and saves
    the state and curves after every chunk that passes a multiple of its
    interval, and at the end.

    Returns:
      (params, metrics): the policies' parameters, leaves `[len(runs), ...]`;
      metrics `[len(runs), rounds * round_iterations]`.
    """
    keys = jnp.stack([jax.random.fold_in(jax.random.PRNGKey(r.seed), i) for i, r in enumerate(runs)])
    hps = jax.tree.map(lambda *xs: jnp.stack(xs), *[hparams_of(r, preset.lr) for r in runs])
    chunk = chunk or preset.chunk
    init = grid_runner(learner.init, vectorize=vectorize)
    pad = -len(runs) % len(init.devices)  # padded once, so the chunk runners never pad or trim
    hps = pad_grid(hps, pad)
    state = init(pad_grid(keys, pad), hps, data)
    start, metrics = 0, []
    saved = checkpoint.restore(state) if checkpoint is not None else None
    if saved is not None:
        start, state, curves = saved
        metrics.append(curves)
        progress(start)
    total = learner.rounds * learner.round_iterations
    runners = {}
    for r in range(learner.rounds):
        first = r * learner.round_iterations  # this round's first iteration, counted over all rounds
        if start >= first + learner.round_iterations:
            continue  # finished before the checkpoint
        if r and start <= first:
            runners.setdefault("next_round", grid_runner(learner.next_round, vectorize=vectorize))
            state = runners["next_round"](state, hps, data)
        done = max(0, start - first)
        while done < learner.round_iterations:
            n = min(chunk, learner.round_iterations - done)
            if n not in runners:
                runners[n] = grid_runner(lambda s, hp, d, n=n: learner.run(s, hp, d, n), vectorize=vectorize)
            state, m = runners[n](state, hps, data)
            metrics.append(jax.device_get(m))
            done += n
            if checkpoint is not None and (checkpoint.due(first + done) or first + done == total):
                metrics = [_concat(metrics)]
                checkpoint.save(first + done, state, metrics[0])
            progress(n)
    metrics = jax.tree.map(lambda x: x[: len(runs)], _concat(metrics))
    return jax.tree.map(lambda x: x[: len(runs)], learner.policy_params(state)), metrics


def _concat(metrics: list[dict]) -> dict:
    """Per-chunk metrics `[G, n]` joined along the iteration axis."""
    return jax.tree.map(lambda *xs: np.concatenate(xs, axis=1), *metrics)


class _NoBar:
    def __init__(self, *a, **k):
        self.n = 0

    def update(self, n=1):
        self.n += n

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def run_sweep(env_name: str, obs: str, preset_name: str, preset: Preset, methods: tuple[str, ...],
              data_dir, bar: Callable = _NoBar, log: Callable[[str], None] = print,
              checkpoint: SweepCheckpoint | None = None, dataset: str | None = None,
              curves: Callable[[str, list[Run], dict], None] | None = None) -> tuple[dict, dict]:
    """Runs the whole sweep; returns `(results, params)` (results as `DESIGN.md`'s `results.json`).

    Args:
      checkpoint: an opened `SweepCheckpoint`: every finished phase and the
        training states are saved there, and what it already holds is reused.
      dataset: train from this dataset (`minari_io.load_dataset`) instead of the
        shipped expert's demonstrations; its observations and actions must
        fit `env_name`, which evaluates the policies.
      curves: `curves(program, runs, metrics)` after each program trains, with
        its per-iteration metrics `[len(runs), iterations]` (e.g. `logs.write_curves`).
      bar: `bar(desc=..., total=..., unit=...)`, a context manager with
        `update(n)` (e.g. `tqdm.tqdm`); one per phase.
      log: receives one-line progress messages.
    """
    import envs
    from envs import experts

    t_start = time.perf_counter()
    system = _system()  # at the start: the code that runs, not what is checked out when it ends
    timing = {"compile_s": 0.0, "train_s": 0.0, "eval_s": 0.0}
    env = envs.make(env_name, obs=obs, **_image_overrides(obs, preset),
                    **({} if preset.eval_steps is None else {"episode_length": preset.eval_steps}))
    card = experts.card(env_name) if env_name != "toycar" else None

    settings = data_settings(env_name, obs, preset, dataset)
    if dataset is None:
        with bar(desc="collect", total=preset.episodes, unit="episode") as b:
            demos, _, data_path, cached = collect.collect_cached(
                settings, data_dir, progress=lambda n: b.update(n - b.n))
            if cached:
                b.update(preset.episodes - b.n)
        source = "cached" if cached else "collected"
    else:
        demos, data_path = minari_io.load_dataset(dataset)
        _check_fits(demos, env, env_name, data_path)
        source = "from"
    log(f"demonstrations: {len(demos):,} transitions in {demos.num_episodes} episodes ({source}: {data_path})")
    train, val, mean, std = prepare(demos, preset)
    runs = grid_runs(methods, preset.seeds, env_name, n_train=len(train), step_grid=preset.step_grid,
                     softmax_grid=preset.softmax_grid)
    if not runs:
        raise ValueError(f"nothing to train: the preset's grids are empty for {', '.join(methods)}")

    saved = checkpoint.load_arrays("ape") if checkpoint is not None else None
    with bar(desc="fit APE", total=preset.ape_steps, unit="step") as b:
        if saved is None:
            saved = fit_ape(train, val, preset)
            if checkpoint is not None:
                checkpoint.save_arrays("ape", saved)
        b.update(preset.ape_steps)
    ape_train, ape_val = jnp.asarray(saved["train"]), jnp.asarray(saved["val"])
    ape_scale, ape_fit_mse = float(saved["scale"]), float(saved["final_fit_mse"])
    ape_params = flax.serialization.msgpack_restore(saved["psi"].tobytes())  # ψ, for the copycat diagnostics
    scores = score_table(methods, train, ape_train)
    train_data, val_data = _data(train, ape_train, mean, std, scores), _data(val, ape_val, mean, std)

    loss = "l1" if env_name == "toycar" else "l2"
    sequential = len(env.observation_shape) == 3 and jax.default_backend() == "cpu"
    if sequential:
        log(f"image policies on CPU: configurations train one after another, {CPU_IMAGE_CHUNK} unrolled "
            "iterations per call (XLA:CPU is slow at convolution gradients in loops and under vmap)")
        if preset.encoder == "resnet18":
            log("warning: ResNet-18 trains about a hundred times slower than the small encoder on a CPU; "
                "the paper preset's image protocol is meant for GPUs")
    programs = []  # (name, cfg, runs, learner) in a fixed order
    for name in dict.fromkeys(program_of(r.method) for r in runs):  # a method with an empty grid has none
        history = 1 if name == "bc-so" else preset.history
        cfg = preset.learner_config(env.observation_shape, env.action_size, history, loss, unroll=sequential)
        programs.append((name, cfg, [r for r in runs if program_of(r.method) == name],
                         make_learner(name, cfg, env, mean, std, len(train))))
    total = sum(learn.rounds * learn.round_iterations for *_, learn in programs)
    trained = []
    with bar(desc="train", total=total, unit="it") as b:
        for name, cfg, prog_runs, learner in programs:
            stamps = []

            def tick(n, stamps=stamps):
                stamps.append(time.perf_counter())
                b.update(n)

            t0 = time.perf_counter()
            params, metrics = train_program(learner, prog_runs, preset, train_data, tick,
                                            chunk=CPU_IMAGE_CHUNK if sequential else None, vectorize=not sequential,
                                            checkpoint=None if checkpoint is None else checkpoint.program(name))
            jax.block_until_ready(params)
            chunk_times = np.diff([t0, *stamps])
            steady = float(np.median(chunk_times[1:])) if len(chunk_times) > 1 else 0.0
            timing["compile_s"] += max(0.0, float(chunk_times[0]) - steady)
            timing["train_s"] += float(sum(chunk_times)) - max(0.0, float(chunk_times[0]) - steady)
            trained.append((cfg, prog_runs, params, metrics))
            if curves is not None:
                curves(name, prog_runs, metrics)

    # Policies with the same history have the same network: one evaluation program per history.
    results_runs, params_out = [None] * len(runs), {}
    with bar(desc="evaluate", total=len(runs) * preset.eval_episodes, unit="episode") as b:
        for history in dict.fromkeys(cfg.history for cfg, *_ in trained):
            group = [t for t in trained if t[0].history == history]
            cfg = group[0][0]
            group_runs = [r for _, rs, _, _ in group for r in rs]
            params = jax.tree.map(lambda *xs: jnp.concatenate(xs), *[p for _, _, p, _ in group])
            out, losses = _evaluate_group(env, cfg, mean, std, preset, params, train_data, val_data, timing,
                                          checkpoint, f"eval-h{history}", (ape_params, ape_scale))
            b.update(len(group_runs) * preset.eval_episodes)
            j = 0
            for _, prog_runs, _, metrics in group:
                for i, r in enumerate(prog_runs):
                    results_runs[runs.index(r)] = _run_record(r, j, out, losses, metrics["loss"][i], card)
                    j += 1
            params_out[f"h{history}"] = {"runs": [dataclasses.asdict(r) for r in group_runs],
                                         "params": params, "obs_mean": mean, "obs_std": std}

    timing["total_s"] = time.perf_counter() - t_start
    timing["resumed"] = bool(checkpoint is not None and checkpoint.resumed)
    timing["checkpoint_s"] = checkpoint.save_s if checkpoint is not None else 0.0  # included in the phases' times
    timing["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # this process's peak memory
    results = {
        "schema": 1, "env": env_name, "obs": obs, "preset": preset_name,
        "config": {**dataclasses.asdict(preset), "methods": list(methods), "loss": loss,
                   "ape": {"normalization": preset.ape_normalization, "scale": ape_scale,
                           "final_fit_mse": ape_fit_mse,
                           # the expert's reference for the policies' rollout_ape (the training split's is 1)
                           "val_mean": float(jnp.mean(ape_val)),
                           # the training split's normalised APE distribution, for the weights' histograms
                           "quantiles": np.quantile(np.asarray(ape_train), np.linspace(0, 1, 101)).tolist()},
                   "ape_normalization": preset.ape_normalization,
                   "data": {"path": str(data_path), "train_transitions": len(train),
                            "val_transitions": len(val), "settings": settings}},
        "expert": _expert_record(card),
        "runs": results_runs,
        "summary": summarize(results_runs),
        "timing": timing,
        "system": system,
    }
    return results, params_out


def _check_fits(demos: Demonstrations, env, env_name: str, where: str) -> None:
    """Refuses (ValueError, one line) demonstrations whose observations or actions the environment cannot take."""
    obs_shape, action_dim = tuple(np.shape(demos.obs)[1:]), int(np.shape(demos.action)[1])
    if obs_shape != tuple(env.observation_shape) or action_dim != env.action_size:
        raise ValueError(f"{where}: observations {list(obs_shape)} and {action_dim}-d actions do not fit "
                         f"{env_name!r}, which has observations {list(env.observation_shape)} and "
                         f"{env.action_size}-d actions; pick the matching --env/--obs")
    if len(env.observation_shape) == 3 and np.asarray(demos.obs).dtype != np.uint8:
        raise ValueError(f"{where}: image observations must be uint8, got {np.asarray(demos.obs).dtype}")


def _evaluate_group(env, cfg: LearnerConfig, mean, std, preset: Preset, params, train_data: Data, val_data: Data,
                    timing: dict, checkpoint: SweepCheckpoint | None, name: str, ape: tuple[Any, float]
                    ) -> tuple[dict, dict]:
    """Evaluation outputs, copycat diagnostics and the loss analysis of a group of policies.

    Reused from `checkpoint` if saved there. `ape`: (ψ, its normalisation scale).
    """
    saved = checkpoint.load_arrays(name) if checkpoint is not None else None
    if saved is None:
        t0 = time.perf_counter()
        expert, _ = collect.expert_for(env)
        evaluator = evaluate.make_evaluator(env, cfg, mean, std, preset.eval_episodes, expert=expert,
                                            ape_params=ape[0], ape_scale=ape[1])
        out = jax.device_get(evaluator(params, jax.random.PRNGKey(EVAL_SEED)))
        timing["eval_s"] += time.perf_counter() - t0
        losses = {split: jax.device_get(evaluate.loss_analysis(cfg, params, d))
                  for split, d in (("train", train_data), ("val", val_data))}
        saved = {**{f"eval/{k}": v for k, v in out.items()},
                 **{f"{split}/{k}": v for split, ls in losses.items() for k, v in ls.items()}}
        if checkpoint is not None:
            checkpoint.save_arrays(name, saved)
    parts: dict[str, dict] = {"eval": {}, "train": {}, "val": {}}
    for k, v in saved.items():
        part, key = k.split("/", 1)
        parts[part][key] = v
    return parts["eval"], {"train": parts["train"], "val": parts["val"]}


def _run_record(run: Run, j: int, out: dict, losses: dict, loss_curve: np.ndarray, card: dict | None):
    """Run `run`'s record; `j` is its row in the evaluation outputs `out` and `losses`."""
    returns = np.asarray(out["return"][j], np.float64)
    record = {"method": run.method, "hparams": run.hparams, "seed": run.seed, "status": "ok", "error": None,
              "online": run.method in ONLINE}
    loss_curve = np.asarray(loss_curve)
    bad = np.flatnonzero(~np.isfinite(loss_curve))
    if len(bad):
        record.update(status="failed", error=f"training loss became non-finite at iteration {int(bad[0])}")
    elif not np.all(np.isfinite(returns)):
        record.update(status="failed", error="evaluation returns are non-finite")
    ev = {"episodes": int(len(returns)), "return_mean": float(returns.mean()), "return_std": float(returns.std())}
    if card is not None:
        ev["normalized"] = float(evaluate.normalized(returns.mean(), card["return_mean"], card["random_return_mean"]))
    for k in EVAL_METRICS:
        if k in out:
            ev[k] = float(np.mean(out[k][j]))
    if "success" in ev:
        ev.setdefault("normalized", 100.0 * ev["success"])
    record["eval"] = ev
    record["losses"] = {split: {k: float(v[j]) for k, v in losses[split].items()} for split in losses}
    record["train_loss_final"] = float(np.mean(loss_curve[-100:]))
    record["train_curve"] = window_means(loss_curve, CURVE_POINTS)
    return _finite_or_none(record)


CURVE_POINTS = 100  # points of each run's training curve in results.json (the full curves: OUT/curves/)


def window_means(values: np.ndarray, points: int) -> list[float]:
    """`values` cut into `points` consecutive windows of equal length (the last takes the rest), each window's mean."""
    values = np.asarray(values, np.float64)
    width = max(1, len(values) // points)
    ends = [*range(width, len(values), width)][: points - 1] + [len(values)]
    return [float(values[a:b].mean()) for a, b in zip([0, *ends[:-1]], ends)]


def _finite_or_none(tree):
    """The record with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(tree, dict):
        return {k: _finite_or_none(v) for k, v in tree.items()}
    if isinstance(tree, list):
        return [_finite_or_none(v) for v in tree]
    if isinstance(tree, float) and not math.isfinite(tree):
        return None
    return tree


def summarize(runs: list[dict]) -> list[dict]:
    """Mean and std over seeds of the per-seed mean returns, per (method, hparams); failed runs left out."""
    groups: dict[tuple, list[dict]] = {}
    for r in runs:
        groups.setdefault((r["method"], tuple(sorted(r["hparams"].items()))), []).append(r)
    rows = []
    for (method, hp), rs in groups.items():
        ok = [r for r in rs if r["status"] == "ok"]
        ret = np.array([r["eval"]["return_mean"] for r in ok], np.float64)
        norm = np.array([r["eval"].get("normalized", np.nan) for r in ok], np.float64)
        rows.append({"method": method, "hparams": dict(hp), "n_seeds": len(ok),
                     "return_mean": float(ret.mean()) if len(ok) else None,
                     "return_std": float(ret.std()) if len(ok) else None,
                     "normalized_mean": float(norm.mean()) if len(ok) else None,
                     "normalized_std": float(norm.std()) if len(ok) else None})
    return rows


def _expert_record(card: dict | None) -> dict:
    if card is None:
        return {"return_mean": None, "return_std": None, "random_return_mean": None, "kind": "rule-based"}
    return {"return_mean": card["return_mean"], "return_std": card["return_std"],
            "random_return_mean": card["random_return_mean"]}


def _system() -> dict:
    """Versions, devices, machine, and the git commit of the code (`dirty`: tracked files modified)."""
    import subprocess

    def git(*args):
        return subprocess.run(["git", *args], capture_output=True, text=True, timeout=10,
                              cwd=__file__.rsplit("/", 2)[0]).stdout.strip()

    try:
        commit, dirty = git("rev-parse", "--short", "HEAD") or None, bool(git("status", "--porcelain", "-uno"))
    except (OSError, subprocess.SubprocessError):
        commit, dirty = None, None
    return {"jax": jax.__version__, "backend": jax.default_backend(), "devices": jax.device_count(),
            "commit": commit, "dirty": dirty, "machine": machine()}


def machine() -> str:
    """The CPU model and core count (and the accelerator, if any), for the report's provenance lines."""
    import os
    import platform
    import re

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            names = re.findall(r"model name\s*:\s*(.*)", f.read())
        cpu = names[0].strip() if names else cpu
    except OSError:
        pass
    accel = "" if jax.default_backend() == "cpu" else f", {jax.devices()[0].device_kind}"
    return f"{cpu}, {os.cpu_count()} cores{accel}"
