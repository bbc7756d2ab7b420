"""The main job as a library: demonstrations -> APE -> the weighting grid × seeds -> evaluation -> results.

`experiments.sweep` is its command line. One sweep is one environment and
observation mode:

1. **collect** the shipped expert's demonstrations (cached, `ape_jax.collect`),
   split 80/20 by episode, standardise state observations with training
   statistics;
2. **fit APE** on the training split (`ape_jax.ape`), normalise by the training mean;
3. **train** BC-OH and the step and softmax grids as one program (vmapped,
   sharded over devices, in chunks so a progress bar moves), and BC-SO
   (history 1, a different input width) as a second;
4. **evaluate** every policy on the same episodes (`ape_jax.evaluate`), and run
   the loss analysis on both splits;
5. assemble `results.json` as `DESIGN.md` fixes it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax import ape as ape_lib
from ape_jax import collect, evaluate
from ape_jax.data import Demonstrations
from ape_jax.grid import grid_runner, pad_grid
from ape_jax.learner import Data, Hparams, LearnerConfig, make_train, stack_hparams

METHODS = ("bc-so", "bc-oh", "ours-step", "ours-softmax")
STEP_GRID = tuple((thr, w) for thr in (0.1, 0.2) for w in (3.0, 5.0, 10.0))
SOFTMAX_GRID = (0.1, 0.2, 0.5, 1.0, 5.0, 10.0)


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

    def learner_config(self, obs_shape, action_dim, history, loss) -> LearnerConfig:
        return LearnerConfig(obs_shape=tuple(obs_shape), action_dim=action_dim, history=history,
                             iterations=self.iterations, batch_size=self.batch_size,
                             lr_decay_every=self.lr_decay_every or max(1, math.ceil(self.iterations / 3)),
                             loss=loss)


PRESETS = {
    "quick": Preset(iterations=3_000, seeds=1, eval_episodes=5, ape_steps=1_000, chunk=500),
    "default": Preset(iterations=30_000, seeds=3, eval_episodes=20, ape_steps=5_000, chunk=2_000),
    "paper": Preset(iterations=300_000, seeds=5, eval_episodes=100, ape_steps=20_000, chunk=10_000),
}


@dataclasses.dataclass(frozen=True)
class Run:
    """One trained configuration: method, hyperparameters, seed."""

    method: str
    hparams: dict
    seed: int


def grid_runs(methods: tuple[str, ...], seeds: int) -> list[Run]:
    """Every (method, hparams, seed) of the sweep, in a fixed order: BC-SO, BC-OH, step grid, softmax grid."""
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {unknown}; valid: {list(METHODS)}")
    out = []
    for seed in range(seeds):
        if "bc-so" in methods:
            out.append(Run("bc-so", {}, seed))
        if "bc-oh" in methods:
            out.append(Run("bc-oh", {}, seed))
        if "ours-step" in methods:
            out += [Run("ours-step", {"thr": thr, "w": w}, seed) for thr, w in STEP_GRID]
        if "ours-softmax" in methods:
            out += [Run("ours-softmax", {"tau": tau}, seed) for tau in SOFTMAX_GRID]
    return out


def hparams_of(run: Run, lr: float) -> Hparams:
    if run.method == "ours-step":
        return Hparams.make("step", lr=lr, thr=run.hparams["thr"], w=run.hparams["w"])
    if run.method == "ours-softmax":
        return Hparams.make("softmax", lr=lr, tau=run.hparams["tau"])
    return Hparams.make("uniform", lr=lr)


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


def _data(split: Demonstrations, ape: jax.Array, mean, std) -> Data:
    obs = jnp.asarray(split.obs)
    if mean is not None:
        obs = (obs - mean) / std
    return Data(obs=obs, action=jnp.asarray(split.action), t=jnp.asarray(split.t), ape=jnp.asarray(ape))


def train_program(cfg: LearnerConfig, runs: list[Run], preset: Preset, data: Data,
                  progress: Callable[[int], None]) -> tuple[Any, dict]:
    """Trains `runs` (all with the same history) as one vmapped, sharded program, in chunks.

    Returns:
      (params, metrics): leaves `[len(runs), ...]`; metrics `[len(runs), iterations]`.
    """
    learner = make_train(cfg)
    keys = jnp.stack([jax.random.fold_in(jax.random.PRNGKey(r.seed), i) for i, r in enumerate(runs)])
    hps = stack_hparams([hparams_of(r, preset.lr) for r in runs])
    init = grid_runner(learner.init)
    pad = -len(runs) % len(init.devices)  # padded once, so the chunk runners never pad or trim
    hps = pad_grid(hps, pad)
    state = init(pad_grid(keys, pad), hps, data)
    runners, done, metrics = {}, 0, []
    while done < cfg.iterations:
        n = min(preset.chunk, cfg.iterations - done)
        if n not in runners:
            runners[n] = grid_runner(lambda s, hp, d, n=n: learner.run(s, hp, d, n))
        state, m = runners[n](state, hps, data)
        metrics.append(jax.device_get(m))
        done += n
        progress(n)
    metrics = jax.tree.map(lambda *xs: np.concatenate(xs, axis=1)[: len(runs)], *metrics)
    return jax.tree.map(lambda x: x[: len(runs)], state.params), metrics


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
              data_dir, bar: Callable = _NoBar, log: Callable[[str], None] = print) -> tuple[dict, dict]:
    """Runs the whole sweep; returns `(results, params)` (results as `DESIGN.md`'s `results.json`).

    Args:
      bar: `bar(desc=..., total=..., unit=...)`, a context manager with
        `update(n)` (e.g. `tqdm.tqdm`); one per phase.
      log: receives one-line progress messages.
    """
    import envs
    from envs import experts

    t_start = time.perf_counter()
    timing = {"compile_s": 0.0, "train_s": 0.0, "eval_s": 0.0}
    runs = grid_runs(methods, preset.seeds)
    env = envs.make(env_name, obs=obs, **({} if preset.eval_steps is None else {"episode_length": preset.eval_steps}))
    card = experts.card(env_name) if env_name != "toycar" else None

    settings = collect.settings(env_name, obs, preset.episodes, seed=0)
    with bar(desc="collect", total=preset.episodes, unit="episode") as b:
        demos, data_meta, data_path, cached = collect.collect_cached(
            settings, data_dir, progress=lambda n: b.update(n - b.n))
        if cached:
            b.update(preset.episodes - b.n)
    log(f"demonstrations: {len(demos):,} transitions in {demos.num_episodes} episodes "
        f"({'cached' if cached else 'collected'}: {data_path})")
    train, val, mean, std = prepare(demos, preset)

    with bar(desc="fit APE", total=preset.ape_steps, unit="step") as b:
        fit = jax.jit(lambda k, a, t: ape_lib.fit(k, a, t, steps=preset.ape_steps))
        ape_params, ape_losses = fit(jax.random.PRNGKey(0), jnp.asarray(train.action), jnp.asarray(train.t))
        ape_train = ape_lib.errors(ape_params, jnp.asarray(train.action), jnp.asarray(train.t))
        ape_val = ape_lib.errors(ape_params, jnp.asarray(val.action), jnp.asarray(val.t))
        b.update(preset.ape_steps)
    ape_train, ape_val, ape_scale = ape_lib.normalize(ape_train, ape_val, preset.ape_normalization)
    train_data, val_data = _data(train, ape_train, mean, std), _data(val, ape_val, mean, std)

    loss = "l1" if env_name == "toycar" else "l2"
    programs = [(h, [r for r in runs if (r.method == "bc-so") == (h == 1)]) for h in (preset.history, 1)]
    programs = [(h, rs) for h, rs in programs if rs]
    results_runs, params_out = [None] * len(runs), {}
    with bar(desc="train", total=preset.iterations * len(programs), unit="it") as b:
        trained = []
        for history, prog_runs in programs:
            cfg = preset.learner_config(env.observation_shape, env.action_size, history, loss)
            stamps = []

            def tick(n, stamps=stamps):
                stamps.append(time.perf_counter())
                b.update(n)

            t0 = time.perf_counter()
            params, metrics = train_program(cfg, prog_runs, preset, train_data, tick)
            jax.block_until_ready(params)
            chunk_times = np.diff([t0, *stamps])
            steady = float(np.median(chunk_times[1:])) if len(chunk_times) > 1 else 0.0
            timing["compile_s"] += max(0.0, float(chunk_times[0]) - steady)
            timing["train_s"] += float(sum(chunk_times)) - max(0.0, float(chunk_times[0]) - steady)
            trained.append((cfg, prog_runs, params, metrics))

    key_eval = jax.random.PRNGKey(12345)  # the same episodes for every policy
    with bar(desc="evaluate", total=sum(len(r) for _, r in programs) * preset.eval_episodes, unit="episode") as b:
        for cfg, prog_runs, params, metrics in trained:
            t0 = time.perf_counter()
            evaluator = evaluate.make_evaluator(env, cfg, mean, std, preset.eval_episodes)
            out = jax.device_get(evaluator(params, key_eval))
            timing["eval_s"] += time.perf_counter() - t0
            b.update(len(prog_runs) * preset.eval_episodes)
            losses = {split: jax.device_get(evaluate.loss_analysis(cfg, params, d))
                      for split, d in (("train", train_data), ("val", val_data))}
            for j, r in enumerate(prog_runs):
                results_runs[runs.index(r)] = _run_record(r, j, out, losses, metrics, card, preset)
            params_out[f"h{cfg.history}"] = {"runs": [dataclasses.asdict(r) for r in prog_runs],
                                             "params": params, "obs_mean": mean, "obs_std": std}

    timing["total_s"] = time.perf_counter() - t_start
    results = {
        "schema": 1, "env": env_name, "obs": obs, "preset": preset_name,
        "config": {**dataclasses.asdict(preset), "methods": list(methods), "loss": loss,
                   "ape": {"normalization": preset.ape_normalization, "scale": ape_scale,
                           "final_fit_mse": float(np.mean(np.asarray(ape_losses)[-50:]))},
                   "ape_normalization": preset.ape_normalization,
                   "data": {"path": str(data_path), "train_transitions": len(train),
                            "val_transitions": len(val), "settings": settings}},
        "expert": _expert_record(card),
        "runs": results_runs,
        "summary": summarize(results_runs),
        "timing": timing,
        "system": _system(),
    }
    return results, params_out


def _run_record(run: Run, j: int, out: dict, losses: dict, metrics: dict, card: dict | None, preset: Preset):
    returns = np.asarray(out["return"][j], np.float64)
    record = {"method": run.method, "hparams": run.hparams, "seed": run.seed, "status": "ok", "error": None}
    loss_curve = np.asarray(metrics["loss"][j])
    bad = np.flatnonzero(~np.isfinite(loss_curve))
    if len(bad):
        record.update(status="failed", error=f"training loss became non-finite at iteration {int(bad[0])}")
    elif not np.all(np.isfinite(returns)):
        record.update(status="failed", error="evaluation returns are non-finite")
    ev = {"episodes": int(len(returns)), "return_mean": float(returns.mean()), "return_std": float(returns.std())}
    if card is not None:
        ev["normalized"] = float(evaluate.normalized(returns.mean(), card["return_mean"], card["random_return_mean"]))
    for k in ("success", "red_light_violations", "progress", "avg_speed", "stuck"):
        if k in out:
            ev[k] = float(np.mean(out[k][j]))
    if "success" in ev:
        ev.setdefault("normalized", 100.0 * ev["success"])
    record["eval"] = ev
    record["losses"] = {split: {k: float(v[j]) for k, v in losses[split].items()} for split in losses}
    record["train_loss_final"] = float(np.mean(loss_curve[-100:]))
    return _finite_or_none(record)


def _finite_or_none(tree):
    """The record with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(tree, dict):
        return {k: _finite_or_none(v) for k, v in tree.items()}
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
    import subprocess

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=__file__.rsplit("/", 2)[0], timeout=10).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        commit = None
    return {"jax": jax.__version__, "backend": jax.default_backend(), "devices": jax.device_count(),
            "commit": commit}
