"""Computes APE and the sample weights of a demonstration dataset:
`python -m experiments.weights --dataset PATH --out weights.npz`.

The dataset is the project's own (`NAME.npz` beside `NAME.json`, see
`ape_jax.pipeline.data`) or a Minari dataset (its directory, or its id under
`$MINARI_DATASETS_PATH`; see `ape_jax.pipeline.minari_io`); any episodes of
(observation, action) will do. APE is fitted on **all** of the dataset (the
sweep fits on its training split only, so its numbers differ) and divided by
its mean ("mean" normalisation). The output holds, per sample, in dataset order:

- `ape` (normalised), `ape_raw`: `[N] float32`;
- `step_weights`: the step function's weights, `w` for the ⌊thr·N⌋ largest APE, 1 elsewhere;
- `softmax_weights`: `N · softmax(ape / tau)` over the whole dataset. The sweep
  applies the softmax per minibatch (`B · softmax` of the batch's APE), so this
  is the dataset-level version, for inspection: it shows which samples the
  softmax favours and how strongly, with the same mean of 1;
- `episode`, `t`: `[N] int32`, to line the weights up with the dataset;
- `meta`: a JSON string (dataset, settings, APE scale, versions).

Read it with `np.load(path)`; `json.loads(str(f["meta"]))` for the metadata.

Bad input is refused with one line on stderr and exit status 2 before the fit
starts: settings out of range, an `--out` that cannot be written, a dataset
that is missing, truncated, or has wrong keys, shapes, dtypes or non-finite
values. A refused run leaves an existing `--out` as it was.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys

from experiments._cli import Parser, fail, unwritable_file

FORMATS = ("auto", "npz", "minari")


def parse(argv=None) -> argparse.Namespace:
    p = Parser(prog="python -m experiments.weights", description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", required=True, help="NAME.npz (the project's format), or a Minari dataset "
                   "directory or id")
    p.add_argument("--out", required=True, type=pathlib.Path,
                   help="the .npz file to write (its directory is made if missing)")
    p.add_argument("--format", choices=FORMATS, default="auto",
                   help="auto (default): .npz files are the project's format, anything else Minari")
    p.add_argument("--ape-steps", type=int, default=5000, help="Adam steps fitting the APE model (default: 5000)")
    p.add_argument("--thr", type=float, default=0.1, help="step weighting: fraction upweighted, in (0, 1)")
    p.add_argument("--w", type=float, default=5.0, help="step weighting: their weight, >= 1")
    p.add_argument("--tau", type=float, default=0.2, help="softmax temperature, > 0")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the APE fit")
    args = p.parse_args(argv)
    if not 0.0 < args.thr < 1.0:
        fail(p, f"--thr must be in (0, 1), got {args.thr}")
    if not 1.0 <= args.w < math.inf:
        fail(p, f"--w must be a finite number >= 1, got {args.w}")
    if not 0.0 < args.tau < math.inf:
        fail(p, f"--tau must be a finite number > 0, got {args.tau}")
    if args.ape_steps < 1:
        fail(p, f"--ape-steps must be >= 1, got {args.ape_steps}")
    if args.out.suffix != ".npz":
        fail(p, f"--out must name a .npz file, got {args.out}")
    why = unwritable_file(args.out)
    if why:
        fail(p, f"--out {args.out}: cannot write there: {why}")
    if args.format == "auto":
        args.format = "npz" if args.dataset.endswith((".npz", ".json")) else "minari"
    return args


def fit_ape(demos, steps: int, seed: int):
    """Raw APE `[N]` of every sample, from ψ fitted on all of `demos`; a progress bar after a second."""
    from tqdm import tqdm

    from ape_jax import ape

    with tqdm(total=steps, desc="fit APE", unit="step", delay=1.0, dynamic_ncols=True) as bar:
        return ape.fit_all(demos.action, demos.t, steps, seed, bar)


def main(argv=None) -> int:
    args = parse(argv)
    import jax
    import numpy as np

    from ape_jax import ape, weighting
    from ape_jax.pipeline import data, minari_io
    from ape_jax.pipeline.data import DataError

    try:
        demos, where = minari_io.load_dataset(args.dataset, args.format)
    except DataError as e:
        return fail(None, str(e))
    n, lengths = len(demos), np.bincount(np.unique(demos.episode, return_inverse=True)[1])
    if lengths.max() < 2:
        return fail(None, f"{where}: every episode has fewer than 2 steps; APE predicts an action from the "
                    "episode's previous ones")
    upweighted = int((np.asarray(weighting.step(np.zeros(n, np.float32), args.thr, 2.0)) > 1).sum())  # ⌊thr·N⌋
    if upweighted < 1:
        return fail(None, f"{where}: too small: with {n} samples, ⌊thr·N⌋ = 0 would be upweighted "
                    f"(--thr {args.thr})")
    ape_raw = fit_ape(demos, args.ape_steps, args.seed)
    try:
        ape_norm, _, scale = ape.normalize(ape_raw, ape_raw[:0], "mean")
    except ValueError as e:
        return fail(None, f"{where}: {e}")
    ape_norm = np.asarray(ape_norm, np.float32)
    step_w = np.asarray(weighting.step(ape_norm, args.thr, args.w))
    soft_w = np.asarray(weighting.softmax(ape_norm, args.tau))
    meta = {"dataset": where, "format": args.format, "num_transitions": n, "num_episodes": int(len(lengths)),
            "ape_steps": args.ape_steps, "seed": args.seed, "thr": args.thr, "w": args.w, "tau": args.tau,
            "ape_normalization": "mean", "ape_scale": scale, "fit_on": "all samples",
            "softmax": "dataset level: N * softmax(ape / tau); the sweep applies it per minibatch",
            "jax": jax.__version__}
    arrays = {"ape": ape_norm, "ape_raw": np.asarray(ape_raw, np.float32), "step_weights": step_w,
              "softmax_weights": soft_w, "episode": np.asarray(demos.episode, np.int32),
              "t": np.asarray(demos.t, np.int32), "meta": np.array(json.dumps(meta, sort_keys=True))}
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        data.write_atomic(args.out, lambda f: np.savez(f, **arrays))
    except OSError as e:
        return fail(None, f"--out {args.out}: cannot write ({e.strerror or e})")
    p50, p90, p99 = np.percentile(ape_norm, [50, 90, 99])
    print(f"{n:,} samples in {len(lengths)} episodes ({where})\n"
          f"APE / mean ({scale:.3g}): median {p50:.3g}, 90th {p90:.3g}, 99th {p99:.3g}, max {ape_norm.max():.3g}\n"
          f"step weights: {upweighted:,} samples ({args.thr:.0%}) upweighted to {args.w:g}; "
          f"softmax (tau {args.tau:g}, whole dataset): weights {soft_w.min():.3g} .. {soft_w.max():.3g}\n"
          f"weights: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
