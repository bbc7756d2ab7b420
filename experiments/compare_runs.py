"""The runs two sweeps share, side by side: does a configuration give the same numbers in another program?

    python -m experiments.compare_runs RUN_A RUN_B
    python -m experiments.compare_runs results/NAME.json runs/replay/NAME     # a committed file and its replay

`RUN_A` and `RUN_B` are sweep `--out` folders (each with `results.json`, read and validated by
`ape_jax.pipeline.results.load`, and `params/`: `ape_jax.pipeline.rundir.RunDir`), or results files (no
parameters: a committed one). For every run both hold (the same method, hyperparameters and seed, hence the same
PRNG key), it prints the two mean returns, whether every number the two record of the run is the same (its
evaluation: each episode's return and metrics, and its losses), and how far apart the saved parameters are (largest
absolute difference over all weights, where both saved them), then a summary: the median and largest return
difference, and how many runs have identical records and bit-identical parameters. A run's key does not
fix its float rounding, which can depend on how many runs a program vmaps over (docs/reliability.md, "Seeds are
not bit-reproducible across program sizes"). Sweeps of two versions of a task (ToyTown's `task_version`) are
refused: their runs share keys but not what the policies saw.
"""

from __future__ import annotations

import json
import pathlib
import statistics
import sys

import numpy as np

from ape_jax.pipeline.rundir import RunDir
from experiments._cli import Parser, fail, not_a_folder


def _ident(run: dict) -> tuple:
    return run["method"], json.dumps(run["hparams"], sort_keys=True), run["seed"]


def _runs(path: pathlib.Path) -> dict[tuple, dict]:
    """The finished runs of a sweep folder or a results file, by identity."""
    from ape_jax.pipeline import results as results_lib

    runs = results_lib.load(path if path.is_file() else RunDir(path).results).runs
    return {_ident(r): r for r in runs if r["status"] == "ok"}


def _task_version(path: pathlib.Path) -> int | None:
    """The task version a sweep folder or results file ran (`tasks.Protocol.task_version`; None: a task without)."""
    from ape_jax.pipeline import results as results_lib

    return (results_lib.load(path if path.is_file() else RunDir(path).results).protocol or {}).get("task_version")


def _encoder(path: pathlib.Path) -> str | None:
    """The SHA-256 of the perception encoder a sweep saw its frames through (`recipe.perception_sha256`), or None."""
    from ape_jax.pipeline import results as results_lib

    res = results_lib.load(path if path.is_file() else RunDir(path).results)
    return ((res.settings or {}).get("recipe") or {}).get("perception_sha256")


def _recorded(run: dict) -> str:
    """What a run records that training and evaluation computed: its evaluation, losses and training curves, and
    those of its snapshots (`at`); not its diagnostics, which judging a file adds to."""
    at = [{k: v for k, v in snap.items() if k != "diagnostics"} for snap in run.get("at") or []]
    return json.dumps({**{k: run.get(k) for k in ("eval", "losses", "train_final", "train_curve")}, "at": at},
                      sort_keys=True)


def _params(folder: pathlib.Path) -> dict[tuple, list[np.ndarray]]:
    """Each saved run's parameter leaves, by identity (none for a results file)."""
    import jax

    from ape_jax.pipeline.checkpoint import load_policies

    if folder.is_file():
        return {}
    out = {}
    for group in load_policies(RunDir(folder).params).values():
        leaves = [np.asarray(x) for x in jax.tree.leaves(group["params"])]
        for i, run in enumerate(group["runs"]):
            out[_ident(run)] = [x[i] for x in leaves]
    return out


def compare(a: pathlib.Path, b: pathlib.Path) -> list[dict]:
    """One row per run both sweeps hold, in `a`'s order: identity, both returns, and the largest absolute
    difference between their parameters (None where either sweep saved none for it)."""
    runs_a, runs_b = _runs(a), _runs(b)
    params_a, params_b = _params(a), _params(b)
    rows = []
    for ident in (i for i in runs_a if i in runs_b):
        pa, pb = params_a.get(ident), params_b.get(ident)
        diff = (None if pa is None or pb is None else
                max(float(np.max(np.abs(x.astype(np.float64) - y))) for x, y in zip(pa, pb)))
        rows.append({"method": ident[0], "hparams": json.loads(ident[1]), "seed": ident[2],
                     "return_a": runs_a[ident]["eval"]["return_mean"], "return_b": runs_b[ident]["eval"]["return_mean"],
                     "same_record": _recorded(runs_a[ident]) == _recorded(runs_b[ident]), "param_max_abs_diff": diff})
    return rows


def main(argv=None) -> int:
    parser = Parser(prog="python -m experiments.compare_runs", description=__doc__.split("\n\n")[0])
    parser.add_argument("run_a", type=pathlib.Path, help="a sweep's --out folder, or a results file")
    parser.add_argument("run_b", type=pathlib.Path, help="another sweep's --out folder, or a results file")
    args = parser.parse_args(argv)
    from ape_jax.pipeline.results import ResultsError

    from ape_jax.pipeline import results as results_lib

    for folder in (args.run_a, args.run_b):
        if folder.is_file():   # a results file, read and validated here so a file of another kind is named as such
            try:
                results_lib.load(folder)
            except ResultsError as e:
                fail(parser, f"{folder} is a file, not a sweep's --out folder, nor a results file ({e})")
            continue
        if why := not_a_folder(folder, "a sweep's --out folder"):
            fail(parser, why)
        if not RunDir(folder).finished():
            fail(parser, f"{folder} is not a finished sweep's --out folder (results.json and params/)")
    try:
        versions = [_task_version(path) for path in (args.run_a, args.run_b)]
        if versions[0] != versions[1]:
            fail(parser, f"{args.run_a} ran task version {versions[0]} and {args.run_b} version {versions[1]}: "
                         f"two versions of a task show other things, so their runs are never compared or merged")
        encoders = [_encoder(path) for path in (args.run_a, args.run_b)]
        if encoders[0] != encoders[1]:
            fail(parser, f"{args.run_a} saw its frames through {encoders[0] or 'no encoder'} and {args.run_b} "
                         f"through {encoders[1] or 'none'}: runs of two perception encoders are never compared")
        rows = compare(args.run_a, args.run_b)
    except ResultsError as e:  # one line naming the file
        fail(parser, str(e))
    except Exception as e:  # noqa: BLE001 - damaged files: say which, never a traceback
        fail(parser, f"could not read the sweeps: {type(e).__name__}: {e}")
    if not rows:
        fail(parser, "the two sweeps share no run (the same method, hyperparameters and seed)")
    print(f"{'method':<16} {'hparams':<28} {'seed':>4} {'return A':>10} {'return B':>10} {'same record':>11} "
          f"{'|param diff|':>12}")
    for r in rows:
        hp = ", ".join(f"{k}={v:g}" for k, v in r["hparams"].items()) or "-"
        diff = "—" if r["param_max_abs_diff"] is None else f"{r['param_max_abs_diff']:.3g}"
        print(f"{r['method']:<16} {hp:<28} {r['seed']:>4} {r['return_a']:>10,.1f} {r['return_b']:>10,.1f} "
              f"{'yes' if r['same_record'] else 'no':>11} {diff:>12}")
    gaps = [abs(r["return_a"] - r["return_b"]) for r in rows]
    same = sum(r["param_max_abs_diff"] == 0.0 for r in rows)
    compared = sum(r["param_max_abs_diff"] is not None for r in rows)
    print(f"{len(rows)} shared runs: |return A − return B| median {statistics.median(gaps):,.1f}, "
          f"largest {max(gaps):,.1f}; every recorded number the same in {sum(r['same_record'] for r in rows)} of "
          f"{len(rows)}; bit-identical parameters in {same} of {compared} with parameters on both sides")
    return 0


if __name__ == "__main__":
    sys.exit(main())
