"""ToyTown's one-frame ceiling: `python -m experiments.toytown_ceiling FILE.json ... --out OUT.json`.

How well can a policy drive from what one frame shows? Each FILE is a sweep of BC-SO on the one-frame state
(`--obs pos`), at one task version (1: no brake lights; 2: brake lights in view) and, where the sweep set
`protocol.reveal`, with full-state features one frame cannot show added (the car ahead's true speed). The queue
`results/queue/toytown-state.sh` runs the four sweeps (versions 1 and 2, each alone and with `lead_speed`
revealed); this command reads their results and writes one row per file: the version, what was revealed, the
seeds, NoCrash's success with its 95% t-interval over seeds, and the other metrics' means. Prints the table; `--out`
writes it as JSON with the files' commands and hashes.

The before/after pair answers the state-row issue's first question: do brake lights lift the one-frame ceiling
(the queue at a red light becomes visible), and how far is it still from the full state (the lead's speed)?
"""

from __future__ import annotations

import hashlib
import json
import pathlib
import sys

from experiments._cli import Parser, fail, unwritable_file

COLUMNS = ("success", "collisions_vehicle", "collisions", "stuck", "timeout", "route_completion", "avg_speed")


def row(path: pathlib.Path) -> dict:
    """One file's row (module docstring); `ValueError` (one line) for a file that is not a one-frame BC-SO sweep
    of ToyTown."""
    from ape_jax.pipeline import results
    from experiments import stats

    res = results.load(path)
    protocol = res.protocol or {}
    if res.env != "toytown" or res.obs != "pos":
        raise ValueError(f"{path}: not a ToyTown one-frame sweep (env {res.env!r}, obs {res.obs!r})")
    runs = [r for r in res.runs if r["method"] == "bc-so" and r["status"] == "ok"]
    if not runs:
        raise ValueError(f"{path}: holds no finished bc-so run")
    per_seed = {k: [float(r["eval"][k]) for r in runs] for k in COLUMNS}
    success = stats.mean_interval([100 * v for v in per_seed["success"]]) if len(runs) > 1 else None
    return {
        "file": str(path), "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "command": res.command, "task_version": protocol.get("task_version", 1),
        "speed_input": protocol.get("speed_input"), "revealed": list(protocol.get("reveal") or []),
        "seeds": len(runs), "episodes_per_seed": runs[0]["eval"]["episodes"],
        "success_pct": round(100 * sum(per_seed["success"]) / len(runs), 2),
        "success_ci95": None if success is None else [round(success.low, 2), round(success.high, 2)],
        "success_per_seed": [round(100 * v, 1) for v in per_seed["success"]],
        **{k: round(sum(v) / len(v), 4) for k, v in per_seed.items() if k != "success"},
    }


def table(rows: list[dict]) -> str:
    """The rows as a markdown table."""
    head = ["version", "one frame +", "seeds", "success %", "95% CI", *COLUMNS[1:]]
    lines = ["| " + " | ".join(head) + " |", "|---:|---|---:|---:|---|" + "---:|" * (len(COLUMNS) - 1)]
    for r in rows:
        ci = "-" if r["success_ci95"] is None else f"[{r['success_ci95'][0]:.1f}, {r['success_ci95'][1]:.1f}]"
        lines.append(f"| {r['task_version']} | {', '.join(r['revealed']) or '-'} | {r['seeds']} | "
                     f"{r['success_pct']:.1f} | {ci} | " + " | ".join(f"{r[k]:.3f}" for k in COLUMNS[1:]) + " |")
    return "\n".join(lines)


def parse(argv=None):
    """The command line, checked (one line and exit status 2 for a bad value)."""
    p = Parser(prog="python -m experiments.toytown_ceiling", description=__doc__.splitlines()[0])
    p.add_argument("files", nargs="+", type=pathlib.Path, help="results.json files of one-frame BC-SO sweeps")
    p.add_argument("--out", type=pathlib.Path, default=None, help="write the rows here as JSON (with provenance)")
    args = p.parse_args(argv)
    missing = [str(f) for f in args.files if not f.is_file()]
    if missing:
        fail(p, f"no such results file: {', '.join(missing)}")
    if args.out is not None and (why := unwritable_file(args.out)):
        fail(p, why)
    return args


def main(argv=None) -> int:
    args = parse(argv)
    from ape_jax.pipeline.results import ResultsError
    from experiments._provenance import system

    try:
        rows = sorted((row(f) for f in args.files), key=lambda r: (r["task_version"], r["revealed"]))
    except (ValueError, ResultsError) as e:
        print(f"python -m experiments.toytown_ceiling: error: {e}", file=sys.stderr)
        return 2
    print(table(rows))
    if args.out is not None:
        command = ["python", "-m", "experiments.toytown_ceiling", *(sys.argv[1:] if argv is None else argv)]
        record = {"env": "toytown", "what": "the one-frame ceiling: BC-SO on the one-frame state, by task version "
                                            "and what is revealed beyond one frame (experiments.toytown_ceiling)",
                  "command": command, "rows": rows, "system": system()}
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(record, indent=1) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
