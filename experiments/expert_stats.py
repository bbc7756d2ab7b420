"""Measure how rough an expert's labels are: `python -m experiments.expert_stats --env hopper --expert own,rough`.

Collects each expert's demonstrations under a protocol (default `mujoco-state`: frame skip 1, 50,000 expert steps, the
expert's raw output as the label) and measures them (`ape_jax.experts.stats`): the share of label entries outside
the action range, the copy-previous error (mean Σ_d (a_t − a_{t−1})² within episodes), ψ's held-out error (fitted
on the protocol's 20,000 training rows, scored on its 4,000 validation rows) and the action variance (per dim,
summed). Prints a table and merges the rows into `--out` (JSON, one entry per expert, other entries kept).

`--expert` names experts: `own` (the task's, `envs/experts/<env>/`) or a variant (`envs/experts/<env>-VARIANT/`:
`ppo`, `rough`; or one imported by `experiments.import_expert --name VARIANT`); `--dir` any expert directory (a
card and its policy, e.g. a candidate written by `experiments.train_expert --out`). These statistics chose the
shipped rough experts (docs/design.md).
"""

from __future__ import annotations

import hashlib
import json
import pathlib
import sys
import time

from experiments._cli import Parser, fail, not_a_folder, unwritable_file


def measure(env_name: str, policy, protocol: str = "mujoco-state", psi_steps: int = 5_000, seed: int = 0) -> dict:
    """The statistics of `policy`'s demonstrations under `protocol`.

    Args:
      env_name: a Brax task (`hopper`, ...).
      policy: the expert, `full_obs [D] -> action [A]` (its raw output is the label).
      protocol: a protocol name (`ape_jax.tasks.PROTOCOLS`).
      psi_steps: ψ's Adam steps.
      seed: the collection's and ψ's seed.

    Returns:
      `ActionStats.as_dict()` plus `return_mean` (the demonstrations' mean episode return), `episodes`,
      `protocol` (its settings) and `seconds`.
    """
    import jax
    import numpy as np

    import envs
    from ape_jax.experts import stats
    from ape_jax.pipeline import collect
    from ape_jax.pipeline import data as data_lib

    t0 = time.perf_counter()
    setup = collect.protocol_setup(env_name, "pos", protocol)
    env = envs.make(env_name, obs="pos", **setup.env_overrides)
    key_collect, key_psi = jax.random.split(jax.random.PRNGKey(seed))
    demos = collect.collect(env, policy, key_collect, setup.episodes, labels="raw")  # the expert's own output
    train = setup.settings.get("train_transitions") or int(0.8 * len(demos))
    val = setup.settings.get("val_transitions") or len(demos) - train
    train_part, val_part = data_lib.split_parts(demos, "rows", train, val, seed=seed)
    low, high = (np.asarray(b) for b in env.action_bounds)
    measured = stats.action_stats(key_psi, demos.action, demos.episode, demos.t, train_part.rows, val_part.rows,
                                  psi_steps, low, high)
    returns = np.bincount(demos.episode, weights=demos.reward)
    return {**measured.as_dict(), "return_mean": float(returns.mean()), "episodes": int(len(returns)),
            "protocol": setup.settings, "psi_steps": psi_steps, "seed": seed,
            "seconds": round(time.perf_counter() - t0, 1)}


def record(out: pathlib.Path, env_name: str, label: str, entry: dict) -> None:
    """Merges `entry` as `experts[label]` into the JSON file `out` (written atomically; other entries kept)."""
    from ape_jax.pipeline.data import write_atomic

    data = json.loads(out.read_text()) if out.is_file() else {}
    data.setdefault("env", env_name)
    data.setdefault("experts", {})[label] = entry
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, lambda f: f.write((json.dumps(data, indent=2, sort_keys=True) + "\n").encode()))


COLUMNS = (("return", "return_mean", "{:,.1f}"), ("outside [-1,1]", "outside", "{:.3f}"),
           ("copy error", "copy_error", "{:.4f}"), ("ψ error", "psi_error", "{:.4f}"),
           ("variance", "variance", "{:.3f}"))


def table(rows: dict[str, dict]) -> str:
    """A Markdown table of entries (`measure`'s dicts) by label."""
    lines = ["| expert | " + " | ".join(c[0] for c in COLUMNS) + " |", "|---|" + "---:|" * len(COLUMNS)]
    lines += ["| " + label + " | " + " | ".join(fmt.format(r[key]) for _, key, fmt in COLUMNS) + " |"
              for label, r in rows.items()]
    return "\n".join(lines)


def main(argv=None) -> int:
    import envs
    from ape_jax import tasks
    from ape_jax.pipeline import presets
    from envs import experts

    p = Parser(prog="python -m experiments.expert_stats", description=__doc__.splitlines()[0])
    p.add_argument("--env", default="hopper", help="a task with a shipped expert")
    p.add_argument("--expert", default=None, metavar="NAMES",
                   help="comma-separated: own (the task's expert) or variants shipped beside it (ppo, rough, ...); "
                        "default: own unless --dir is given")
    p.add_argument("--dir", action="append", type=pathlib.Path, default=[], metavar="PATH",
                   help="an expert directory (card.json and policy/), labelled by its name; repeatable")
    p.add_argument("--protocol", default=tasks.STATE, help=f"one of {', '.join(tasks.PROTOCOLS)}")
    p.add_argument("--psi-steps", type=int, default=5_000, help="ψ's Adam steps (the default budget's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="JSON to merge the rows into (default runs/expert_stats/<env>-<protocol>.json)")
    args = p.parse_args(argv)
    if args.env not in envs.names() or not tasks.get(args.env).has_card:
        fail(p, f"unknown env {args.env!r} or one without a trained expert; valid: "
                f"{', '.join(sorted({n.partition('-')[0] for n in experts.available()}))}")
    args.protocol = presets.current_protocol(args.protocol)
    if args.protocol not in tasks.PROTOCOLS:
        fail(p, f"unknown protocol {args.protocol!r}; valid: {', '.join(tasks.PROTOCOLS)}")
    if args.psi_steps < 1:
        fail(p, f"--psi-steps must be >= 1, got {args.psi_steps}")
    names = [n.strip() for n in (args.expert or ("" if args.dir else "own")).split(",") if n.strip()]
    chosen = {}   # label -> (card's name, root or None)
    known = (*experts.available(), *experts.imported_names())
    for n in names:
        if n in tasks.FORMER_EXPERTS and f"{args.env}-{n}" not in known:   # imported under its former name
            presets.notice_renamed("expert", n, tasks.FORMER_EXPERTS[n])
            n = tasks.FORMER_EXPERTS[n]
        name = args.env if n == "own" else f"{args.env}-{n}"
        if name not in known:
            fail(p, f"no shipped or imported expert {name!r}; valid for --expert: own, "
                    f"{', '.join(a.partition('-')[2] for a in known if a.startswith(args.env + '-'))}")
        chosen[name] = (name, None)
    for d in args.dir:
        if why := not_a_folder(d, "an expert's folder"):
            fail(p, f"--dir {why}")
        if not (d / experts.CARD).is_file():
            fail(p, f"--dir {d}: no {experts.CARD} there")
        chosen[d.name] = (args.env, d)
    out = args.out or pathlib.Path("runs/expert_stats") / f"{args.env}-{args.protocol}.json"
    why = unwritable_file(out)
    if why:
        fail(p, f"--out {out}: cannot write there: {why}")
    try:
        tasks.get(args.env).protocol(args.protocol, "pos")
        policies = {label: experts.load(name, root) for label, (name, root) in chosen.items()}
    except (ValueError, experts.ExpertError) as e:
        fail(p, str(e))
    rows = {}
    for label, policy in policies.items():
        name, root = chosen[label]
        card_file = (root or experts.directory(name)) / experts.CARD
        card = json.loads(card_file.read_text())
        print(f"{label}: collecting under {args.protocol} and fitting ψ ...", flush=True)
        entry = measure(args.env, policy, args.protocol, args.psi_steps, args.seed)
        entry.update(source=str(root) if root is not None else
                     card["source"] if experts.is_imported(name) else f"envs/experts/{name}",
                     card_sha256=hashlib.sha256(card_file.read_bytes()).hexdigest(),
                     algorithm=card.get("algorithm"),
                     command=" ".join(["python", "-m", "experiments.expert_stats",
                                       *(sys.argv[1:] if argv is None else argv)]))
        record(out, args.env, label, entry)
        rows[label] = entry
    print(table(rows))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
