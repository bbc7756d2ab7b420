"""A fault drill: `python -m experiments.drill [--env hopper] [--preset quick] [--kills 2]`.

Runs a sweep uninterrupted, then the same sweep killed with SIGKILL `--kills`
times (each time as soon as the training checkpoints have advanced by
`--kill-every` saves since the last start) and resumed after each kill, and
reports whether the resumed `results.json` numbers equal the uninterrupted
ones bit for bit, what the interruptions cost in time, and how long the
checkpoints took to save. Everything runs as `python -m experiments.sweep`
subprocesses (extra sweep flags after `--`); outputs go under `--out`.

This is what docs/reliability.md's "Faults tried" section reports; the tests run a
shrunken version (`tests/test_resume.py`).
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

from ape_jax.pipeline.rundir import RunDir
from experiments._cli import Parser, fail, unwritable


def parser() -> Parser:
    """The drill's command line (every option described: `--help`)."""
    p = Parser(prog="python -m experiments.drill", description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help="the sweep's --env (default: hopper)")
    p.add_argument("--preset", default="quick",
                   help="the sweep's --preset (default: quick); a larger budget leaves more checkpoints to kill at")
    p.add_argument("--kills", type=int, default=2, help="how many times to kill the sweep (default: 2)")
    p.add_argument("--kill-every", type=int, default=2,
                   help="kill once this many new training checkpoints were saved since the last start (default: 2)")
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path("runs/drill"),
                   help="where the two sweeps (uninterrupted/, killed/) and their log (drill.log) go; both "
                        "sweep folders are deleted first (default: runs/drill)")
    p.add_argument("sweep_args", nargs="*", metavar="-- SWEEP_FLAGS",
                   help="more `experiments.sweep` flags for both sweeps, after `--` (e.g. -- --seeds 2)")
    return p


def parse(argv=None):
    p = parser()
    args = p.parse_args(argv)
    if args.kills < 1 or args.kill_every < 1:
        fail(p, "--kills and --kill-every must be >= 1")
    why = unwritable(args.out)
    if why:
        fail(p, f"--out {args.out}: {why}")
    return args


def _saved_steps(out: pathlib.Path) -> int:
    """How many training checkpoints the sweep in `out` has completed, over all programs (latest kept each)."""
    ckpt = RunDir(out).checkpoints
    return sum(int(step.name) for prog in ckpt.glob("train-*") for step in prog.iterdir() if step.name.isdigit()) \
        if ckpt.exists() else 0


def _sweep(args, out: pathlib.Path) -> list[str]:
    return [sys.executable, "-m", "experiments.sweep", "--env", args.env, "--preset", args.preset, "--quiet",
            "--out", str(out), *args.sweep_args]


def _numbers(results: dict) -> dict:
    return {k: v for k, v in results.items() if k not in ("timing", "system", "command")}


def main(argv=None) -> int:
    args = parse(argv)
    reference, drilled = args.out / "uninterrupted", args.out / "killed"
    for d in (reference, drilled):
        shutil.rmtree(d, ignore_errors=True)
    args.out.mkdir(parents=True, exist_ok=True)
    log = open(args.out / "drill.log", "w")  # the sweeps' own output

    t0 = time.perf_counter()
    if subprocess.run(_sweep(args, reference), stdout=log, stderr=log).returncode:
        return fail(None, f"the uninterrupted sweep failed; see {args.out / 'drill.log'}")
    uninterrupted_s = time.perf_counter() - t0

    t0, kills = time.perf_counter(), []
    for k in range(args.kills + 1):
        start_saved = _saved_steps(drilled)
        proc = subprocess.Popen(_sweep(args, drilled), stdout=log, stderr=log)
        if k == args.kills:
            proc.wait()
            break
        # The progress (iterations saved) grows by a chunk per save; kill after `kill_every` saves past the start.
        seen = {start_saved}
        while proc.poll() is None and len(seen) <= args.kill_every:
            seen.add(_saved_steps(drilled))
            time.sleep(0.05)
        if proc.poll() is not None:
            return fail(None, f"the sweep finished before kill {k + 1}; use a bigger preset or a smaller --kill-every")
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        kills.append({"at_iterations_saved": _saved_steps(drilled), "returncode": proc.returncode})
        print(f"kill {k + 1}: SIGKILL with {_saved_steps(drilled):,} training iterations checkpointed "
              f"(over all programs); resuming", flush=True)
    drilled_s = time.perf_counter() - t0
    if proc.returncode:
        return fail(None, f"the resumed sweep failed (exit {proc.returncode}); see {args.out / 'drill.log'}")

    # the files as written, not as a reader upgrades them: the drill compares what the sweeps wrote
    a = json.loads(RunDir(reference).results.read_text())
    b = json.loads(RunDir(drilled).results.read_text())
    same = _numbers(a) == _numbers(b)
    print(f"\n{args.env}, preset {args.preset}: killed {args.kills}× with SIGKILL and resumed -> results.json "
          f"numbers {'IDENTICAL' if same else 'DIFFERENT'} to the uninterrupted run\n"
          f"  uninterrupted: {uninterrupted_s:.0f} s (checkpoint saves {a['timing']['checkpoint_s']:.1f} s of it)\n"
          f"  killed + resumed: {drilled_s:.0f} s in all (last leg's checkpoint saves "
          f"{b['timing']['checkpoint_s']:.1f} s)")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
