"""Evaluate a finished sweep's saved policies again: `python -m experiments.evaluate OUT`.

Adds to `OUT/results.json` the evaluation fields it lacks (the copycat
diagnostics: each run's `diagnostics`, the embedding probe, own-rollout
predictability and verdict of `ape_jax.diagnostics`, and `imitation_error` and
`rollout_ape`; the training APE's quantiles; for sweeps run before they
existed), from the policies in
`OUT/params/`, on the same episodes (`ape_jax.pipeline.reevaluate`). Every run's return
and recorded metric must come out as recorded, or nothing is written (exit 2). The file is
replaced atomically; `--out FILE` writes elsewhere and leaves it alone.

`--replaces FILE` is for a results file whose policies were never kept: RUN is
FILE's sweep trained again (the same task, protocol, recipe, budget, grids and
runs; refused with exit 2 otherwise). RUN's policies are evaluated as above and
RUN's completed results are written to FILE (or `--out`), with what FILE
recorded (command, provenance, summary, each run's return) kept under
`replaces`; RUN's own `results.json` is left alone. It prints each
configuration's mean return before and after.

`--video METHOD[:SEED]` instead writes a GIF of one of the policy's evaluation
episodes (`--episode`, default 0) to `RUN/videos/` (or `--video-out FILE.gif`),
rendered as the sweep's evaluation saw it, captioned with the method, step, the
task's words (ToyTown's speed and light ahead), the return and, at the end, the
outcome (`ape_jax.pipeline.watch`); a method that ran several settings shows its
best (by mean return), at its first seed unless SEED is given. `expert` is the
task's expert on the same episode; `--video ours-step:0,expert` shows both side
by side. It plays at the control step's rate (ToyTown: 10 frames per second),
skipping steps of long episodes (said in the output). `results.json` is left alone.

`--rejudge FILE [FILE ...]` instead recomputes each results file's controlled
copycat verdict from its recorded diagnostics (no policies needed;
`ape_jax.pipeline.judge`): each policy's embedding probe against the no-history
control, BC-SO on the same rows with the same probe, from FILE itself where its
sweep trained BC-SO, else from a sibling: `--control SIBLING`, or a results file
beside FILE with the same demonstrations, protocol, recipe, training length and
probe (`--resampled` also accepts a named control whose demonstrations were
collected with the same settings but differ in their bytes, as another CPU's
float rounding makes them; the file records both SHA-256). Each run's first
verdict (`verdict`) stays beside the new
`controlled_verdict`. A file without diagnostics is skipped (said so); one
without a control is refused (exit 2), and then nothing is written. The files
are replaced atomically; judging a judged file again changes nothing.
"""

from __future__ import annotations

import pathlib
import sys

from ape_jax.pipeline.rundir import RunDir
from experiments._cli import (Parser, add_compile_cache_flag, fail, interruptible, not_a_folder,
                             raise_if_interrupted, unreadable, unwritable_file, use_compile_cache)


@interruptible("a results file is only ever replaced whole")
def main(argv=None) -> int:
    from ape_jax.pipeline import data

    p = Parser(prog="python -m experiments.evaluate", description=__doc__.splitlines()[0])
    p.add_argument("run", type=pathlib.Path, nargs="?", default=None,
                   help="a sweep's --out directory (results.json and params/)")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="write the completed results here (default: replace RUN/results.json)")
    p.add_argument("--replaces", type=pathlib.Path, default=None, metavar="FILE",
                   help="RUN is FILE's sweep trained again (FILE's policies were not kept): write RUN's completed "
                        "results to FILE (or --out), FILE's own record kept under `replaces`")
    p.add_argument("--data-dir", type=pathlib.Path, default=None,
                   help=f"demonstration cache (default: {data.cache_dir()})")
    p.add_argument("--video", default=None, metavar="METHOD[:SEED][,...]",
                   help="write a GIF of this policy's evaluation episode instead (results.json is left alone); "
                        "'expert' is the task's expert; several, comma-separated, side by side")
    p.add_argument("--episode", type=int, default=0, help="with --video: which evaluation episode (default 0)")
    p.add_argument("--video-out", type=pathlib.Path, default=None, metavar="FILE.gif",
                   help="with --video: where (default RUN/videos/METHOD-seedSEED-episodeN.gif)")
    p.add_argument("--rejudge", type=pathlib.Path, nargs="+", default=None, metavar="FILE",
                   help="recompute these results files' controlled copycat verdicts from their recorded diagnostics "
                        "instead (no policies needed; each file replaced)")
    p.add_argument("--control", type=pathlib.Path, nargs="+", default=None, metavar="SIBLING",
                   help="with --rejudge: take the no-history control (BC-SO) from these files where a FILE has none")
    p.add_argument("--resampled", action="store_true",
                   help="with --control: accept a control whose demonstrations were collected with the same settings "
                        "but differ in their bytes (another CPU's float rounding); recorded in the file")
    add_compile_cache_flag(p)
    args = p.parse_args(argv)
    if args.rejudge is not None:
        if args.run is not None or args.out or args.replaces or args.video or args.video_out or args.episode:
            fail(p, "--rejudge takes results files and nothing else: no RUN, --out, --replaces or --video")
        if args.resampled and not args.control:
            fail(p, "--resampled goes with --control SIBLING")
        return _rejudge(p, args.rejudge, args.control or [], args.resampled)
    if args.control is not None or args.resampled:
        fail(p, "--control and --resampled go with --rejudge FILE")
    if args.run is None:
        fail(p, "give RUN (a sweep's --out directory), or --rejudge FILE")
    if args.video is None and (args.video_out is not None or args.episode != 0):
        fail(p, "--episode and --video-out go with --video METHOD[:SEED]")
    if args.video_out is not None and args.video_out.suffix != ".gif":
        fail(p, f"--video-out must name a .gif file, got {args.video_out}")
    use_compile_cache(args)
    from ape_jax.pipeline import results as results_lib

    run = RunDir(args.run)
    source = run.results
    if why := not_a_folder(args.run, "a sweep's --out folder"):
        fail(p, f"{why}: RUN must be a finished sweep's --out directory")
    if not source.exists():
        fail(p, f"{source} does not exist: RUN must be a finished sweep's --out directory")
    try:
        res = results_lib.load(source)
    except results_lib.ResultsError as e:
        fail(p, str(e))
    if args.video is not None:
        if args.replaces is not None:
            fail(p, "--replaces writes results; --video writes a GIF: give one of them")
        return _video(p, args, res)
    old = None
    if args.replaces is not None:
        if args.replaces.resolve() == source.resolve():
            fail(p, f"--replaces names RUN's own results ({source}): give the file RUN was trained again to replace")
        if why := unreadable(args.replaces, "a results file"):
            fail(p, f"--replaces {why}")
        try:
            old = results_lib.load(args.replaces)
        except results_lib.ResultsError as e:
            fail(p, str(e))
        if differ := results_lib.retraining_differences(old, res):
            fail(p, f"{source} is not {args.replaces}'s sweep trained again: {differ[0]}"
                    + (f" (and {len(differ) - 1} more)" if len(differ) > 1 else ""))
    target = args.out or args.replaces or source
    if (why := unwritable_file(target)) is not None:
        fail(p, why)
    from ape_jax.pipeline.reevaluate import ReevaluationError, reevaluate
    from envs.experts import ExpertError
    from experiments._provenance import system

    try:
        new = reevaluate(res, run.params, args.data_dir, system=system())
    except (ReevaluationError, ExpertError, ValueError) as e:
        fail(p, str(e))
    if old is not None:
        new.replaces = results_lib.replaced_record(old, args.replaces.name, new)
    from ape_jax.pipeline import judge

    new = judge.judge_own(new)   # diagnostics just added: their controlled verdict, where the sweep had BC-SO
    raise_if_interrupted()   # a Ctrl-C whose exception was ignored (a gc callback): nothing written
    results_lib.save(target, new)
    if old is not None:
        print(_before_and_after(new))
    added = new.reevaluated["fields"]
    print(f"wrote {target}: " + (f"added {', '.join(added)}" if added else "nothing was missing")
          + f" ({new.reevaluated['eval_s']:.0f} s, of which diagnostics {new.reevaluated['diagnostics_s']:.0f} s); "
          "every recorded return and metric came out as recorded")
    return 0


def _before_and_after(new) -> str:
    """Each configuration's mean return in the file `new` replaces (`new.replaces`, the first training) and in `new`
    (trained again), a line each."""
    def key(row):
        return row["method"], tuple(sorted(row["hparams"].items()))

    was = {key(r): r for r in new.replaces["summary"]}
    commit = (new.replaces.get("system") or {}).get("commit")
    lines = [f"mean return over seeds, first training (commit {commit}) -> trained again:"]
    for row in new.summary:
        hp = ", ".join(f"{k} {v:g}" for k, v in row["hparams"].items())
        before = (was.get(key(row)) or {}).get("return_mean")
        lines.append(f"  {new.label(row['method'])}{f', {hp}' if hp else ''}: "
                     + (f"{before:,.1f}" if before is not None else "—") + " -> "
                     + (f"{row['return_mean']:,.1f}" if row["return_mean"] is not None else "failed"))
    return "\n".join(lines)


def _rejudge(p, files: list[pathlib.Path], controls: list[pathlib.Path], resampled: bool = False) -> int:
    """`--rejudge`: every file's controlled verdict (`ape_jax.pipeline.judge`), all found before any is written;
    `resampled`: a named control may stand on demonstrations of the same settings with other bytes."""
    from ape_jax.diagnostics import CONTROL
    from ape_jax.pipeline import judge
    from ape_jax.pipeline import results as results_lib

    def loaded(path):
        if why := unreadable(path, "a results file"):
            fail(p, why)
        try:
            return results_lib.load(path)
        except results_lib.ResultsError as e:
            fail(p, str(e))

    given = [(path.name, loaded(path)) for path in controls]
    beside: dict[pathlib.Path, list] = {}   # per folder, the results files in it (what is not one is passed over)
    judged, lines = [], []
    for path in files:
        res = loaded(path)
        if (why := unwritable_file(path)) is not None:
            fail(p, why)
        if not any(judge.readable(r) for r in res.runs):
            lines.append(f"skipped {path}: no copycat diagnostics")
            continue
        control = None
        if not judge.control_errors(res).get(int(res.config["iterations"])):
            if path.parent not in beside:
                beside[path.parent] = [(q.name, r) for q in sorted(path.parent.glob("*.json"))
                                       if (r := _results_or_none(q)) is not None]
            control = judge.find_control(res, given, resampled) or judge.find_control(
                res, [(n, r) for n, r in beside[path.parent] if n != path.name])
            if control is None:
                fail(p, f"{path}: no {CONTROL} control: neither the file nor "
                        + (", ".join(str(c) for c in controls) if controls else "a results file beside it")
                        + f" has {CONTROL} policies with diagnostics on the same demonstrations, protocol, recipe, "
                        f"training length and probe; run {CONTROL} in such a sweep, or name its file with --control"
                        + ("" if resampled else " (--resampled where its demonstrations differ only in their bytes)"))
        try:
            new = judge.judge(res, control, resampled=resampled)
        except judge.JudgeError as e:
            fail(p, f"{path}: {e}")
        judged.append((path, new))
        lines.append(f"rejudged {path}: control {CONTROL} from "
                     + ("the file itself" if control is None else control[0]) + "; " + _verdict_counts(new))
    for path, new in judged:
        results_lib.save(path, new)
    print("\n".join(lines))
    return 0


def _results_or_none(path: pathlib.Path):
    from ape_jax.pipeline import results as results_lib

    try:
        return results_lib.load(path)
    except results_lib.ResultsError:
        return None


def _verdict_counts(res) -> str:
    """`"copycat: first verdict 3/15, controlled 0/15 (the runs at the end)"`."""
    from ape_jax.pipeline import judge

    blocks = [d for r in res.runs if r["status"] == "ok" and (d := judge.readable(r)) is not None]
    first = sum(d.get("verdict") == "copycat" for d in blocks)
    controlled = [d for d in blocks if "controlled_verdict" in d]
    new = sum(d["controlled_verdict"] == "copycat" for d in controlled)
    return (f"copycat: first verdict {first}/{len(blocks)}, controlled {new}/{len(controlled)} (the runs at the "
            "end)")


def _video(p, args, res) -> int:
    """`--video`: one evaluation episode of saved policies (or the expert) as a captioned GIF, side by side."""
    from ape_jax.pipeline import watch

    run = RunDir(args.run)
    try:
        choices = watch.parse_choices(args.video)
        records = [None if method == watch.EXPERT else watch.choose_run(res, method, seed) for method, seed in choices]
    except watch.WatchError as e:
        return fail(p, str(e))
    names = [method if record is None else f"{method}-seed{record['seed']}"
             for (method, _), record in zip(choices, records)]
    target = args.video_out or run.videos / f"{'+'.join(names)}-episode{args.episode}.gif"
    if (why := unwritable_file(target)) is not None:
        return fail(p, f"cannot write the video to {target}: {why}")
    from envs.experts import ExpertError

    try:
        clips = [watch.expert_episode_of(res, args.episode, args.data_dir) if record is None else
                 watch.episode_of(res, run.params, method, record["seed"], args.episode, args.data_dir)
                 for (method, _), record in zip(choices, records)]
    except (watch.WatchError, ExpertError, ValueError) as e:
        return fail(p, str(e))
    watch.write_gif(clips, target)
    first = clips[0]
    shown = (f"every step, {first.speedup:.3g}× real time" if first.stride == 1 else
             f"every {first.stride}th step, frames skipped: {first.speedup:.3g}× real time")
    print(f"wrote {target}: " + "; ".join(
        f"{c.title}, {c.metric} {c.episode_metric:,.4g} (the evaluation's mean {c.mean_metric:,.4g})"
        + (f", {c.outcome}" if c.outcome else "") for c in clips)
        + f"; {max(len(c.frames) for c in clips)} frames at {first.fps:g} per second ({shown})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
