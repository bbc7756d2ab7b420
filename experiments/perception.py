"""Pretrains a task's perception encoder once: `python -m experiments.perception --env toytown`.

The encoder reads what one frame shows (the task's declared targets, ToyTown's one-frame state), trained on frames
of the training layouts only and never on the expert's actions (`ape_jax.pipeline.perception`, docs/perception.md).
It writes its card as JSON (`--out`, default `results/perception/<task>.json`): targets, data, size, cost, the
held-out `1 − R²` of each target, the encoder file's SHA-256; and the encoder file (`--encoder`; default: beside
`--out` with the suffix `.npz`, or, without `--out`, `envs/perception/<task>.npz`, the shipped one that
`--set recipe.perception=task` reads).

Bad input is refused with one line and exit status 2 before anything runs: a task without a perception card,
counts below 1, a learning rate that is not a positive number, an output that cannot be written.
"""

from __future__ import annotations

import json
import math
import pathlib
import statistics
import sys

from experiments._cli import Parser, fail, interruptible, unwritable_file

ROOT = pathlib.Path(__file__).resolve().parents[1]


def parse(argv=None):
    from ape_jax import tasks

    with_card = [t for t in tasks.sweepable() if tasks.get(t).perception is not None]
    p = Parser(prog="python -m experiments.perception", description=__doc__.splitlines()[0])
    p.add_argument("--env", required=True, help=f"the task ({', '.join(with_card)} declare a perception card)")
    p.add_argument("--steps", type=int, default=16_000, help="Adam updates (default 16,000)")
    p.add_argument("--batch", type=int, default=128, help="frames per update (default 128)")
    p.add_argument("--lr", type=float, default=1e-3, help="Adam's peak learning rate, cosine to 0 (default 1e-3)")
    p.add_argument("--image-size", help="the frames' size, N or HxW (default: the task's card's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=pathlib.Path, help="the card as JSON (default results/perception/<task>.json)")
    p.add_argument("--encoder", type=pathlib.Path,
                   help="the encoder file (default: --out's path with .npz; without --out, envs/perception/<task>.npz)")
    args = p.parse_args(argv)
    if args.env not in tasks.TASKS or tasks.get(args.env).perception is None:
        fail(p, f"{args.env} declares no perception card; tasks with one: {', '.join(with_card) or 'none'}")
    if args.steps < 1 or args.batch < 1:
        fail(p, f"--steps and --batch must be >= 1, got {args.steps} and {args.batch}")
    if not (args.lr > 0 and math.isfinite(args.lr)):
        fail(p, f"--lr must be a finite number > 0, got {args.lr}")
    if args.image_size is not None:
        from ape_jax.pipeline.hints import image_size

        try:
            args.image_size = image_size(args.image_size)
        except ValueError as e:
            fail(p, f"--image-size {args.image_size!r}: {e}")
    shipped = args.out is None
    args.out = args.out or ROOT / "results" / "perception" / f"{args.env}.json"
    args.encoder = args.encoder or (ROOT / "envs" / "perception" / f"{args.env}.npz" if shipped
                                    else args.out.with_suffix(".npz"))
    for path in (args.out, args.encoder):
        if (why := unwritable_file(path)) is not None:
            fail(p, why)
    return args


@interruptible("nothing was written")
def main(argv=None) -> int:
    args = parse(argv)
    from tqdm.auto import tqdm

    from ape_jax.perception import card as card_lib
    from ape_jax.pipeline import perception as pretrain_lib
    from experiments._provenance import system

    bar = None

    def progress(done: int, loss: float) -> None:
        nonlocal bar
        bar = bar or tqdm(total=args.steps, desc="pretrain", unit="update", file=sys.stderr)
        bar.update(done - bar.n)
        bar.set_postfix(loss=f"{loss:.4f}", refresh=False)

    params, card = pretrain_lib.pretrain(args.env, steps=args.steps, batch=args.batch, lr=args.lr, seed=args.seed,
                                         image_size=args.image_size, log=lambda s: print(s, file=sys.stderr),
                                         progress=progress)
    if bar is not None:
        bar.close()
    sha = card_lib.save(args.encoder, params, card)
    where = args.encoder.resolve()
    record = {"file": str(where.relative_to(ROOT)) if where.is_relative_to(ROOT) else str(args.encoder),
              "sha256": sha, "command": ["python", "-m", "experiments.perception", *(argv or sys.argv[1:])], **card,
              "system": system()}
    record.pop("target_mean"), record.pop("target_std")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1) + "\n")
    print(f"encoder: {args.encoder} (SHA-256 {sha[:12]}…, {card['training']['parameters']:,} parameters, "
          f"{card['training']['total_s'] / 60:.1f} min)")
    for condition, scores in card["heldout"].items():
        read = {k: v for k, v in scores.items() if v is not None}
        worst = sorted(read, key=read.get, reverse=True)[:3]
        print(f"  held out, {condition}: median 1 − R² {statistics.median(read.values()):.3f}; worst "
              + ", ".join(f"{k} {read[k]:.2f}" for k in worst))
    print(f"card: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
