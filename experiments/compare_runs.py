"""The runs two sweeps share, side by side: does a configuration give the same numbers in another program?

    python -m experiments.compare_runs RUN_A RUN_B

`RUN_A` and `RUN_B` are sweep `--out` folders (each with `results.json`, read and validated by
`ape_jax.pipeline.results.load`, and `params/`: `ape_jax.pipeline.rundir.RunDir`). For every run both
hold (the same method, hyperparameters and seed, hence the same PRNG key), it prints the two mean returns and
how far apart the saved parameters are (largest absolute difference over all weights), then a summary: the
median and largest return difference, and how many runs have bit-identical parameters. A run's key does not
fix its float rounding, which can depend on how many runs a program vmaps over (docs/reliability.md, "Seeds are
not bit-reproducible across program sizes").
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


def _returns(folder: pathlib.Path) -> dict[tuple, float]:
    from ape_jax.pipeline import results as results_lib

    runs = results_lib.load(RunDir(folder).results).runs
    return {_ident(r): r["eval"]["return_mean"] for r in runs if r["status"] == "ok"}


def _params(folder: pathlib.Path) -> dict[tuple, list[np.ndarray]]:
    """Each saved run's parameter leaves, by identity."""
    import jax

    from ape_jax.pipeline.checkpoint import load_policies

    out = {}
    for group in load_policies(RunDir(folder).params).values():
        leaves = [np.asarray(x) for x in jax.tree.leaves(group["params"])]
        for i, run in enumerate(group["runs"]):
            out[_ident(run)] = [x[i] for x in leaves]
    return out


def compare(a: pathlib.Path, b: pathlib.Path) -> list[dict]:
    """One row per run both sweeps hold, in `a`'s order: identity, both returns, and the largest absolute
    difference between their parameters (None where either sweep saved none for it)."""
    returns_a, returns_b = _returns(a), _returns(b)
    params_a, params_b = _params(a), _params(b)
    rows = []
    for ident in (i for i in returns_a if i in returns_b):
        pa, pb = params_a.get(ident), params_b.get(ident)
        diff = (None if pa is None or pb is None else
                max(float(np.max(np.abs(x.astype(np.float64) - y))) for x, y in zip(pa, pb)))
        rows.append({"method": ident[0], "hparams": json.loads(ident[1]), "seed": ident[2],
                     "return_a": returns_a[ident], "return_b": returns_b[ident], "param_max_abs_diff": diff})
    return rows


def main(argv=None) -> int:
    parser = Parser(prog="python -m experiments.compare_runs", description=__doc__.split("\n\n")[0])
    parser.add_argument("run_a", type=pathlib.Path, help="a sweep's --out folder")
    parser.add_argument("run_b", type=pathlib.Path, help="another sweep's --out folder")
    args = parser.parse_args(argv)
    from ape_jax.pipeline.results import ResultsError

    for folder in (args.run_a, args.run_b):
        if why := not_a_folder(folder, "a sweep's --out folder"):
            fail(parser, why)
        if not RunDir(folder).finished():
            fail(parser, f"{folder} is not a finished sweep's --out folder (results.json and params/)")
    try:
        rows = compare(args.run_a, args.run_b)
    except ResultsError as e:  # one line naming the file
        fail(parser, str(e))
    except Exception as e:  # noqa: BLE001 - damaged files: say which, never a traceback
        fail(parser, f"could not read the sweeps: {type(e).__name__}: {e}")
    if not rows:
        fail(parser, "the two sweeps share no run (the same method, hyperparameters and seed)")
    print(f"{'method':<16} {'hparams':<28} {'seed':>4} {'return A':>10} {'return B':>10} {'|param diff|':>12}")
    for r in rows:
        hp = ", ".join(f"{k}={v:g}" for k, v in r["hparams"].items()) or "-"
        diff = "—" if r["param_max_abs_diff"] is None else f"{r['param_max_abs_diff']:.3g}"
        print(f"{r['method']:<16} {hp:<28} {r['seed']:>4} {r['return_a']:>10,.1f} {r['return_b']:>10,.1f} {diff:>12}")
    gaps = [abs(r["return_a"] - r["return_b"]) for r in rows]
    same = sum(r["param_max_abs_diff"] == 0.0 for r in rows)
    print(f"{len(rows)} shared runs: |return A − return B| median {statistics.median(gaps):,.1f}, "
          f"largest {max(gaps):,.1f}; bit-identical parameters in {same} of {len(rows)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
