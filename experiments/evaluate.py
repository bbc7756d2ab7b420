"""Evaluate a finished sweep's saved policies again: `python -m experiments.evaluate OUT`.

Adds to `OUT/results.json` the evaluation fields it lacks (the copycat
diagnostics: each run's `diagnostics`, the embedding probe, own-rollout
predictability and verdict of `ape_jax.diagnostics`, and `imitation_error` and
`rollout_ape`; the training APE's quantiles; for sweeps run before they
existed), from the policies in
`OUT/params/`, on the same episodes (`ape_jax.pipeline.reevaluate`). Every run's return
and recorded metric must come out as recorded, or nothing is written (exit 2). The file is
replaced atomically; `--out FILE` writes elsewhere and leaves it alone.
"""

from __future__ import annotations

import pathlib
import sys

from experiments._cli import Parser, add_compile_cache_flag, fail, unwritable_file, use_compile_cache


def main(argv=None) -> int:
    from ape_jax.pipeline import data

    p = Parser(prog="python -m experiments.evaluate", description=__doc__.splitlines()[0])
    p.add_argument("run", type=pathlib.Path, help="a sweep's --out directory (results.json and params/)")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="write the completed results here (default: replace RUN/results.json)")
    p.add_argument("--data-dir", type=pathlib.Path, default=None, help=f"demonstration cache (default: {data.cache_dir()})")
    add_compile_cache_flag(p)
    args = p.parse_args(argv)
    use_compile_cache(args)
    source = args.run / "results.json"
    from ape_jax.pipeline import results as results_lib

    if not source.exists():
        fail(p, f"{source} does not exist: RUN must be a finished sweep's --out directory")
    try:
        res = results_lib.load(source)
    except results_lib.ResultsError as e:
        fail(p, str(e))
    target = args.out or source
    if (why := unwritable_file(target)) is not None:
        fail(p, why)
    from ape_jax.pipeline.reevaluate import ReevaluationError, reevaluate
    from envs.experts import ExpertError
    from experiments._provenance import system

    try:
        new = reevaluate(res, args.run / "params", args.data_dir, system=system())
    except (ReevaluationError, ExpertError, ValueError) as e:
        fail(p, str(e))
    results_lib.save(target, new)
    added = new.reevaluated["fields"]
    print(f"wrote {target}: " + (f"added {', '.join(added)}" if added else "nothing was missing")
          + f" ({new.reevaluated['eval_s']:.0f} s, of which diagnostics {new.reevaluated['diagnostics_s']:.0f} s); "
          "every recorded return and metric came out as recorded")
    return 0


if __name__ == "__main__":
    sys.exit(main())
