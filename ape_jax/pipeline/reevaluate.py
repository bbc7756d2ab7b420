"""Evaluating a finished sweep's saved policies again, to add what its results lack.

    results = reevaluate(json.load(open("OUT/results.json")), "OUT/params")

A sweep saves every trained policy (`OUT/params/h{H}`, orbax, beside
`h{H}.json`, the runs in order). This rebuilds everything the evaluation needs
from `results.json` alone: the preset, the environment, the demonstrations
(from the cache, collected again if missing), and ψ (fitted again; key 0 makes
it deterministic). It then runs the sweep's own evaluation
(`sweep._evaluate_group`, the same episodes) and adds the fields the file
lacks, such as the copycat diagnostics `imitation_error` and `rollout_ape`
written by newer code, and the training APE's `quantiles`.

Nothing is overwritten that the file has: each run's return and every
metric it records must come out as recorded (they do on the same machine and
jax; they would not if the policies, the environment or the demonstrations
had changed), and otherwise `ReevaluationError` says which differ, and
nothing is returned.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import time
from typing import Callable

import flax.serialization
import jax
import numpy as np

from ape_jax.pipeline import collect, minari_io
from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline import sweep as sweep_lib


class ReevaluationError(ValueError):
    """The saved sweep cannot be evaluated again as recorded (one line, for the command line)."""


def preset_of(config: dict) -> sweep_lib.Preset:
    """The `Preset` a results file's `config` records (JSON lists back to tuples; fields it predates: defaults)."""
    fields = {f.name for f in dataclasses.fields(sweep_lib.Preset)}
    values = {k: v for k, v in config.items() if k in fields}
    for k in ("step_grid", "image_size"):
        if values.get(k) is not None:
            values[k] = tuple(tuple(x) if isinstance(x, list) else x for x in values[k])
    if "softmax_grid" in values:
        values["softmax_grid"] = tuple(values["softmax_grid"])
    return sweep_lib.Preset(**values)


def load_policies(params_dir: str | pathlib.Path) -> dict[str, dict]:
    """`{"h1": {"runs": [{"method", "hparams", "seed"}...], "params": ..., "obs_mean", "obs_std"}, ...}`.

    Leaves of `params` are `[len(runs), ...]`; `obs_mean`/`obs_std` are None
    for image policies.
    """
    import orbax.checkpoint as ocp

    params_dir = pathlib.Path(params_dir)
    groups = sorted(p.stem for p in params_dir.glob("h*.json"))
    if not groups:
        raise ReevaluationError(f"{params_dir} holds no saved policies (h*.json beside orbax folders)")
    out = {}
    with ocp.StandardCheckpointer() as ckpt:
        for name in groups:
            if not (params_dir / name).is_dir():
                raise ReevaluationError(f"{params_dir / name} is missing: the sweep's parameters were not saved")
            tree = ckpt.restore((params_dir / name).absolute())
            out[name] = {"runs": json.loads((params_dir / f"{name}.json").read_text()), "params": tree["params"],
                         "obs_mean": tree.get("obs_mean"), "obs_std": tree.get("obs_std")}
    return out


def _key(run: dict) -> tuple:
    return run["method"], json.dumps(run["hparams"], sort_keys=True), run["seed"]


def reevaluate(results: dict, params_dir: str | pathlib.Path, data_dir=None, log: Callable[[str], None] = print,
               rtol: float = 1e-4) -> dict:
    """A copy of `results` with the evaluation fields it lacks added from its saved policies.

    Args:
      results: a sweep's `results.json`.
      params_dir: the sweep's `params/`.
      data_dir: the demonstration cache (default: `ape_jax.pipeline.data.cache_dir()`).
      rtol: how closely each run's mean return must come out as recorded.

    Raises:
      ReevaluationError: the policies are missing, the demonstrations or ψ
        are not those of the sweep, or recorded returns or metrics differ
        from the recomputed ones.
    """
    import envs

    config, env_name, obs = results["config"], results["env"], results["obs"]
    preset = preset_of(config)
    policies = load_policies(params_dir)
    settings = config["data"]["settings"]
    if "dataset" in settings:
        demos, _ = minari_io.load_dataset(settings["dataset"])
    else:
        demos, _, path, cached = collect.collect_cached(settings, data_dir or data_lib.cache_dir())
        log(f"demonstrations: {len(demos):,} transitions ({'cached' if cached else 'collected again'}: {path})")
    train, val, mean, std = sweep_lib.prepare(demos, preset)
    if len(train) != config["data"]["train_transitions"]:
        raise ReevaluationError(f"the demonstrations have {len(train)} training transitions, the sweep had "
                                f"{config['data']['train_transitions']}: they are not the sweep's")
    ape = sweep_lib.fit_ape(train, val, preset)
    recorded_scale = config["ape"]["scale"]
    if not np.isclose(float(ape["scale"]), recorded_scale, rtol=1e-4):
        raise ReevaluationError(f"ψ fitted again gives a mean APE of {float(ape['scale']):.6g}, the sweep recorded "
                                f"{recorded_scale:.6g}: the demonstrations or the APE code changed")
    psi = flax.serialization.msgpack_restore(ape["psi"].tobytes())
    train_data = sweep_lib._data(train, ape["train"], mean, std)
    val_data = sweep_lib._data(val, ape["val"], mean, std)

    env = envs.make(env_name, obs=obs, **sweep_lib._image_overrides(obs, preset),
                    **({} if preset.eval_steps is None else {"episode_length": preset.eval_steps}))
    loss = config.get("loss", "l1" if env_name == "toycar" else "l2")
    sequential = len(env.observation_shape) == 3 and jax.default_backend() == "cpu"
    records = {_key(r): r for r in results["runs"]}
    new = json.loads(json.dumps(results))  # a deep copy: `results` is left as it was
    new_records = {_key(r): r for r in new["runs"]}
    timing, added, differ = {"eval_s": 0.0}, set(), []
    t0 = time.perf_counter()
    for name, group in policies.items():
        history = int(name[1:])
        if group["obs_mean"] is not None and mean is not None and not np.allclose(group["obs_mean"], mean, rtol=1e-5):
            raise ReevaluationError(f"the saved policies' observation statistics ({name}) are not those of the "
                                    "demonstrations: they were trained on other data")
        cfg = preset.learner_config(env.observation_shape, env.action_size, history, loss, unroll=sequential)
        log(f"evaluating {len(group['runs'])} saved policies with history {history} "
            f"({preset.eval_episodes} episodes each)")
        out, _ = sweep_lib._evaluate_group(env, cfg, mean, std, preset, group["params"], train_data, val_data,
                                           timing, None, f"eval-{name}", (psi, float(ape["scale"])))
        for j, run in enumerate(group["runs"]):
            key = _key(run)
            if key not in records:
                raise ReevaluationError(f"a saved policy ({run['method']} {run['hparams']} seed {run['seed']}) "
                                        "has no run in results.json: the params and the results are of different sweeps")
            was, ev = records[key].get("eval") or {}, new_records[key].setdefault("eval", {})
            now = {"return_mean": out["return"][j], **{k: out[k][j] for k in sweep_lib.EVAL_METRICS if k in out}}
            for k, values in now.items():
                value = float(np.mean(values))
                if was.get(k) is None:
                    if k != "return_mean":
                        ev[k] = value
                        added.add(k)
                elif not np.isclose(value, was[k], rtol=rtol, atol=1e-3):  # what is recorded must come out again
                    differ.append(f"{run['method']} {run['hparams']} seed {run['seed']} {k}: {value:.6g} vs "
                                  f"{was[k]:.6g}")
    if differ:
        raise ReevaluationError(f"{len(differ)} recorded evaluation numbers (returns, metrics) differ from the "
                                f"recomputed ones (e.g. {differ[0]}): the policies, the environment or the "
                                "evaluation changed")
    ape_record = new["config"].setdefault("ape", {})
    if "val_mean" not in ape_record:
        ape_record["val_mean"] = float(np.mean(ape["val"]))
        added.add("config.ape.val_mean")
    if "quantiles" not in ape_record:
        ape_record["quantiles"] = np.quantile(np.asarray(ape["train"]), np.linspace(0, 1, 101)).tolist()
        added.add("config.ape.quantiles")
    new["reevaluated"] = {"fields": sorted(added), "eval_s": time.perf_counter() - t0,
                          "system": sweep_lib._system()}
    return new
