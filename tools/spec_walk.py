"""How far a reader walks to follow a sweep's spec through the code: `python tools/spec_walk.py [--list]`.

A reviewer following `spec` from `run_sweep` reads each function the sweep reaches while it resolves and uses its
settings, once, in the order the sweep first reaches it, and moves between files as they go. This script records
that walk for a tiny sweep (ToyCar, one seed, a few iterations, with profiling on): the first call of every
function defined where a sweep's settings are resolved and carried (the host pipeline `ape_jax/pipeline/`, the
task and method registries `ape_jax/tasks.py` and `ape_jax/methods/`, the environments' and experts' lookups
`envs/__init__.py` and `envs/experts/`), by file; the compiled work (the learner, the models, the evaluation
loops, the diagnostics) is what the settings configure, not where they are resolved, and is left out, and so are
comprehensions, lambdas, class bodies and dunder methods (`skimmed`). A *stay*
is a run of consecutive functions in one file; a *return* is a stay in a file the walk had already left. It
prints both counts (and with `--list`, the walk).
"""

from __future__ import annotations

import argparse
import inspect
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


ROOMS = ("ape_jax/pipeline/", "ape_jax/tasks.py", "ape_jax/methods/", "envs/__init__.py", "envs/experts/")


def skimmed(code) -> bool:
    """Whether a reader opens this code to follow the settings: not a comprehension, lambda, module or class body
    (read with what encloses them), nor a dunder method (`__len__`, `__enter__`: the protocol of an object, not
    where settings go)."""
    name = code.co_name
    return (not name.startswith("<") and not (name.startswith("__") and name.endswith("__"))
            and bool(code.co_flags & inspect.CO_NEWLOCALS))


def walk(spec) -> list[tuple[str, str]]:
    """`[(file, function)]`: the first call of every function in `ROOMS` while `run_sweep(spec)` runs, in order."""
    from ape_jax.pipeline import sweep as S

    calls: list[tuple[str, str]] = []
    seen: set = set()
    rooms = tuple(str(ROOT / room) for room in ROOMS)

    def profile(frame, event, arg):
        code = frame.f_code
        if event != "call" or not code.co_filename.startswith(rooms) or not skimmed(code):
            return
        if code not in seen:
            seen.add(code)
            calls.append((str(pathlib.Path(code.co_filename).relative_to(ROOT)), code.co_name))

    sys.setprofile(profile)
    try:
        S.run_sweep(spec, S.Hooks(log=lambda message: None))
    finally:
        sys.setprofile(None)
    return calls


def stays(calls: list[tuple[str, str]]) -> list[tuple[str, list[str]]]:
    """The walk as stays: runs of consecutive calls in one file, each with its functions."""
    out: list[tuple[str, list[str]]] = []
    for path, name in calls:
        if out and out[-1][0] == path:
            out[-1][1].append(name)
        else:
            out.append((path, [name]))
    return out


def returns(walked: list[tuple[str, list[str]]]) -> int:
    """Stays in a file the walk had been in before (and left)."""
    seen, back = set(), 0
    for path, _ in walked:
        back += path in seen
        seen.add(path)
    return back


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--list", action="store_true", help="print every stay: its file and the functions called there")
    args = p.parse_args(argv)
    import tempfile

    from ape_jax.pipeline.spec import SweepSpec

    with tempfile.TemporaryDirectory() as tmp:
        spec = SweepSpec.make("toycar", "full", ("bc-so", "bc-oh"), recipe="mlp", data_dir=pathlib.Path(tmp),
                              sets=["budget.iterations=20", "budget.chunk=10", "budget.seeds=1",
                                    "budget.eval_episodes=2", "budget.probe_steps=0", "budget.ape_steps=10",
                                    "protocol.episodes=4"])
        walked = stays(walk(spec))
    if args.list:
        for path, names in walked:
            print(f"{path}: {', '.join(dict.fromkeys(names))}")
    print(f"{len(walked)} stays, {returns(walked)} returns to files already left")
    return 0


if __name__ == "__main__":
    sys.exit(main())
