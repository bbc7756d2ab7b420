"""The index of the committed results: `python -m experiments.results_index [--check]`.

Writes `results/README.md`: one row per JSON file under `results/` (each folder below it a section of its own),
saying what the file holds — task, observation mode, protocol, expert and labels, recipe, budget, seeds, methods,
commit and machine, read from the file, never from its name — and the command that runs it again into a new
folder. A sweep's replay is built from the settings it records (`replay.arguments`, the inverse of
`presets.resolve`), not from its recorded command, which ends in `--resume` on a folder of the machine it ran on;
the output of another tool (`experiments.pose_probe`) is replayed by its recorded command with a new `--out`.
`--check` exits 1 (one line) when `results/README.md` is not what this would write now.

    found = entries(pathlib.Path("results"))   # one Entry per JSON file, the top folder's first
    found[0].command   # ["python", "-m", "experiments.sweep", "--env", "halfcheetah", ..., "--out", "runs/replay/..."]
    render(found)      # the README's text
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import shlex
import sys

from ape_jax import methods as methods_lib
from ape_jax.pipeline import presets, replay
from ape_jax.pipeline import results as results_lib
from ape_jax.pipeline.data import write_atomic
from experiments._cli import Parser

PROG = "python -m experiments.results_index"
RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"
REPLAY = pathlib.PurePosixPath("runs/replay")   # where every replay writes, one folder (or file) per results file


def dataset_of(r: results_lib.Results) -> str | None:
    """The `--dataset` a sweep trained from (None: the demonstrations it collected from an expert)."""
    return ((r.config.get("data") or {}).get("settings") or {}).get("dataset")


def settings_arguments(r: results_lib.Results) -> list[str]:
    """`--env`, `--obs` and the sweep arguments under which today's `presets.resolve` gives the settings `r`
    records (`replay.arguments`; a `--smoke` run's with `--smoke`), the methods' own settings of the methods it ran
    only (an old file's recipe set FCA-IB's α with FCA's, say). Methods and dataset are the caller's to add.

    Raises:
      SettingsError: no arguments give them (a preset, protocol or recipe this code no longer knows).
    """
    records = dataclasses.replace(r.records(), smoke=bool(r.config.get("smoke")))
    return ["--env", r.env, "--obs", r.obs,
            *replay.arguments(r.env, r.obs, records, methods=tuple(r.config.get("methods") or ()))]


@dataclasses.dataclass(frozen=True)
class Entry:
    """What the index says of one JSON file under `results/`.

    Attributes:
      path: the file, relative to `results/` (`exploratory/probes/x.json`).
      kind: `"sweep"` (a results file), `"tool"` (another entry point's output that records its command) or
        `"other"` (neither: listed, not replayable).
      cells: the row's cells after the file's, in `HEADS[kind]`'s order, the replay's last.
      command: the replay's argv into a new folder under `runs/replay/`; for a sweep whose settings no arguments
        give, its recorded command without `--resume`/`--out` (`from_settings` False); None where there is none.
      from_settings: whether `command` is built from the file's recorded settings (the replay the test checks).
      needs: what the replay needs that the repository does not ship, one line each (an imported expert).
    """

    path: str
    kind: str
    cells: tuple[str, ...]
    command: list[str] | None
    from_settings: bool = False
    needs: tuple[str, ...] = ()


HEADS = {"sweep": ("task", "obs", "protocol", "expert, labels", "recipe", "budget", "seeds", "methods", "commit",
                   "machine", "replay into a new folder"),
         "tool": ("tool", "task", "commit", "machine", "replay into a new file"),
         "other": ("why",)}


def _sweep_command(r: results_lib.Results, out: pathlib.PurePosixPath) -> list[str]:
    """The replay of results file `r` into `out`: its settings as arguments (`settings_arguments`; the seeds as
    `--seeds`), its methods, its dataset, and `--yes` where its cost needs it."""
    from experiments import sweep

    args, seeds = settings_arguments(r), r.records().budget.seeds
    for i in range(len(args) - 1):   # `--seeds N` says it as the sweep's own shortcut
        if args[i:i + 2] == ["--set", f"budget.seeds={seeds}"]:
            args = args[:i] + args[i + 2:]
            break
    names = r.config["methods"]
    dataset = dataset_of(r)
    cost = sweep.cost(r.env, r.records(), tuple(names))
    return ["python", "-m", "experiments.sweep", *args, "--methods", ",".join(names), "--seeds", str(seeds),
            *(["--dataset", dataset] if dataset else []), *(["--yes"] if cost is not None and cost.over else []),
            "--out", str(out)]


def without_output(command: list[str]) -> list[str]:
    """A recorded command without `--resume`, `--fresh` and its `--out` (the folder of the machine it ran on)."""
    out, skip = [], False
    for arg in command:
        if skip or arg in ("--resume", "--fresh") or arg.startswith("--out="):
            skip = False
            continue
        skip = arg == "--out"
        if not skip:
            out.append(arg)
    return out


def _pieces(found: dict[pathlib.Path, results_lib.Results]) -> set[pathlib.Path]:
    """The files that are one piece of a sweep split by seeds (`budget.first_seed`): a first seed other than 0, or
    another file of the same folder with the same identity but the seeds (`Results.fingerprint`)."""
    def identity(path: pathlib.Path, r: results_lib.Results) -> str:
        fp = r.fingerprint()
        budget = {k: v for k, v in fp["settings"].get("budget", {}).items() if k not in ("seeds", "first_seed")}
        return json.dumps([str(path.parent), {**fp, "settings": {**fp["settings"], "budget": budget}}],
                          sort_keys=True)

    keys = {p: identity(p, r) for p, r in found.items()}
    return {p for p, r in found.items()
            if r.records().budget.first_seed or sum(k == keys[p] for k in keys.values()) > 1}


def _commit(system: dict) -> str:
    if not system.get("commit"):
        return "not recorded"
    return f"`{system['commit']}`" + (" (uncommitted changes)" if system.get("dirty") else "")


def _sweep_entry(rel: str, r: results_lib.Results, piece: bool) -> Entry:
    """A results file's row (`entries`): the demonstrator named as the report names it (`analysis.expert_words`)."""
    # here, not at the top: the report's sections import this module (`settings_arguments`)
    from experiments.report.analysis import demonstrator, expert_words, former_preset, other_history, protocol_of

    settings, p, found = r.records(), protocol_of(r), demonstrator(r) or {}
    imported = found.get("kind") == "imported"
    words = expert_words({**p, **({"expert_sha256": found.get("sha256")} if imported else {})}) or "own"
    split = [r.split, *([f"history {h}"] if (h := other_history(p)) is not None else []),
             *(["previous action in view"] if p.get("prev_action") else [])]
    former = former_preset(r)
    budget = (r.preset + (f" (the {former} then)" if former else "") + f", {settings.budget.iterations:,} it."
              + (" (smoke)" if settings.smoke else ""))
    first, n = settings.budget.first_seed, settings.budget.seeds
    needs, notes = [], []
    if imported:
        name = p.get("expert") or found.get("variant")
        needs.append(f"{r.env}'s expert `{name}` (SHA-256 `{found.get('sha256')}`"
                     + (f", from {found['origin']}" if found.get("origin") else "")
                     + f"): `python -m experiments.import_expert PATH --env {r.env} --name {name}`")
        notes.append(f"needs {r.env}'s expert `{name}` imported first (above)")
    if dataset_of(r):
        needs.append(f"the dataset `{dataset_of(r)}` (`--dataset`), which the repository does not hold")
        notes.append("needs its dataset (above)")
    try:
        command, from_settings = _sweep_command(r, REPLAY / rel.removesuffix(".json")), True
    except presets.SettingsError as e:
        command, from_settings = (without_output(r.command) if r.command else None), False
        notes.insert(0, f"no arguments give its settings today ({e}): "
                        + ("its recorded command" if command else "it records no command"))
    if from_settings and r.written_schema in (1, 2):
        seeds = ("; its seeds were position-based then (today a run's key comes from its identity), so the replay "
                 "trains other runs" if r.written_schema == 1 else "")
        notes.insert(0, f"results schema {r.written_schema}: settings rebuilt from its flat config (what it does not "
                        f"record: today's values){seeds}")
    unknown = [m for m in r.config["methods"] if m not in methods_lib.names()]
    cells = (r.env, r.obs, f"{p['name']} ({', '.join(split)})", words, r.recipe_name, budget,
             f"{n} (seeds {first}–{first + n - 1})" if piece else str(n),
             ", ".join(r.config["methods"]) + (f" ({', '.join(unknown)}: a plugin's)" if unknown else ""),
             _commit(r.system or {}), (r.system or {}).get("machine") or "not recorded",
             (f"`{shlex.join(command)}`" if command else "—") + "".join(f"; {x}" for x in notes))
    return Entry(rel, "sweep", cells, command, from_settings, tuple(needs))


def _tool_entry(rel: str, obj: dict) -> Entry:
    """Another entry point's output that records its command (`entries`): that command, into a new file."""
    cmd = [str(x) for x in obj["command"]]
    command = [*without_output(cmd), "--out", str(REPLAY / rel)]
    system = obj.get("system") or {}
    return Entry(rel, "tool", (f"`{cmd[2] if cmd[:2] == ['python', '-m'] else cmd[0]}`", str(obj.get("env", "—")),
                               _commit(system), system.get("machine") or "not recorded", f"`{shlex.join(command)}`"),
                 command)


def entries(root: pathlib.Path = RESULTS) -> list[Entry]:
    """Every JSON file under `root` (`results/`), its own files first, then each folder's (recursively), by path."""
    paths = sorted(root.rglob("*.json"), key=lambda p: (len(p.relative_to(root).parts) > 1, p.relative_to(root)))
    loaded, why = {}, {}
    for p in paths:
        try:
            loaded[p] = results_lib.load(p)
        except results_lib.ResultsError as e:
            why[p] = str(e)
    pieces = _pieces(loaded)
    out = []
    for p in paths:
        rel = p.relative_to(root).as_posix()
        if p in loaded:
            out.append(_sweep_entry(rel, loaded[p], p in pieces))
            continue
        try:
            obj = json.loads(p.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            obj = None
        if isinstance(obj, dict) and isinstance(obj.get("command"), list) and obj["command"]:
            out.append(_tool_entry(rel, obj))
        else:
            out.append(Entry(rel, "other", (why[p].removeprefix(f"{p}: "),), None))
    return out


HEADER = f"""# Results files

_Written by `{PROG}` from the files themselves: do not edit it by hand; `--check` says
whether it is current._

Every JSON file under `results/`, one row each: what it holds, read from the file, and the command that runs it
again into a new folder. `python -m experiments.report results/*.json` builds [BENCHMARKS.md](../BENCHMARKS.md)
from the first table's files; the folders' files are quoted by hand ([exploratory/README.md](exploratory/README.md)
says where). `queue/` and `retrained/queue.sh` hold the shell queues that wrote the later files; since Dec 6 a
queue runs each sweep from a snapshot of the committed code (a git worktree, `queue/_lib.sh`), so the commit a file
records is the code that ran, whatever was edited in the checkout meanwhile.

**Names.** A name is a reader's shorthand, not a record: the file holds every setting, and the table reads the file.
Names are built as `TASK-OBS[-PROTOCOL][-SPLIT]-PRESET[-RECIPE][-VARIANT][-LABELS][-SUFFIX][-seedsK].json`:

- `TASK-OBS`: the task and its observations (`pos`, positions only; `image`).
- `PROTOCOL`: absent for Brax's own (the first files and the image files); else `mujoco-state` or a member of its
  family (`mujoco-state-fs2`, `-fs4`: another frame skip; `mujoco-state-train5k`, `-train80k`: another training
  set), `-h7` after it for history 7; `nocrash`, `nocrash-nospeed` for the driving tables.
- `SPLIT`: `rows` where the demonstrations are split by rows; absent where they are split by episode.
- `PRESET`: the budget, `default` or `paper` (`TASK-image-patch-*`: the current `default` image preset, whose
  encoder is the patch encoder); `RECIPE`, `bn-mlp` or `mlp`, follows it where the name has a split.
- `VARIANT`: another demonstrator or setting (`cs294`, FCA's imported CS294 expert; `rough`, `ppo`, shipped variants;
  `prevaction`, the previous action in view); `LABELS`: `raw` or `clipped`.
- `SUFFIX`: which part of a sweep: `main`, `bc` (BC-SO, BC-OH, ours), `grid`, `softmax`, `ours`, `fca`, `fcaib`,
  `baselines`, `after` (BC-full and the methods after the paper), `map` (a cell of the copycat map), `long`
  (100,000 iterations), `sensitivity`, `rerun`.
- `-seedsK`: one piece of a sweep split by seeds, from seed `K` (`--set budget.first_seed=K`); the report merges
  the pieces.
- Files written before each thing had one name (`docs/design.md`, "Words") keep the names they were committed
  under: `fca` for the protocol (`fca-fs2`, ...) and the recipe, `fcaexpert` for FCA's expert. Their settings read
  as today's names, so the columns below and the report show `mujoco-state`, `bn-mlp` and `cs294`.

**Replaying.** A sweep's command is built from the settings it records (`ape_jax.pipeline.replay.arguments`, the
inverse of `presets.resolve`), with its methods and seeds, into `runs/replay/NAME`; `tests/test_results_index.py`
parses every command and checks that it resolves to the file's protocol, budget and recipe. It runs those settings
on today's code; the program the file ran is its own `command`, where it records one, at its commit (without
`--resume`, with a new `--out`). What a replay agrees to — bit for bit where the code and the kind of processor
are the same, within the interval over seeds elsewhere — is in
[docs/reliability.md](../docs/reliability.md#replaying-a-results-file).
"""


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _section(title: str, found: list[Entry], folder: str) -> list[str]:
    lines = [f"## {title}", ""]
    for kind, intro in (("sweep", "Sweeps (`experiments.sweep`):"),
                        ("tool", "Other tools' outputs, each replayed by its recorded command:"),
                        ("other", "Not results files:")):
        rows = [e for e in found if e.kind == kind]
        if not rows:
            continue
        lines += [f"{intro} {len(rows)} file(s).", "", "| file | " + " | ".join(HEADS[kind]) + " |",
                  "|---" * (len(HEADS[kind]) + 1) + "|"]
        for e in rows:
            name = e.path.removeprefix(f"{folder}/") if folder else e.path
            lines.append(f"| [`{name}`]({e.path}) | " + " | ".join(_cell(c) for c in e.cells) + " |")
        lines.append("")
    return lines


def render(found: list[Entry]) -> str:
    """`results/README.md`: the header, what replays need beyond the repository, then a section per folder."""
    lines = HEADER.splitlines()
    needs = list(dict.fromkeys(n for e in found for n in e.needs))
    if needs:
        lines += ["", "**Before replaying**, what some commands need that the repository does not ship (their rows say "
                  "which; PATH is the file whose SHA-256 is given):", "", *(f"- {n}" for n in needs)]
    folders = list(dict.fromkeys(e.path.split("/")[0] if "/" in e.path else "" for e in found))
    for folder in folders:
        part = [e for e in found if (e.path.split("/")[0] if "/" in e.path else "") == folder]
        title = f"`results/{folder}/`" if folder else "`results/*.json`: the report's files"
        lines += ["", *_section(title, part, folder)]
    return "\n".join(lines).rstrip() + "\n"


def main(argv=None) -> int:
    """Writes `results/README.md` (or, with `--check`, says whether it is current: exit 1 if not)."""
    p = Parser(prog=PROG, description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true", help="exit 1 if results/README.md is not what this would write")
    args = p.parse_args(argv)
    text, out = render(entries(RESULTS)), RESULTS / "README.md"
    if args.check:
        if not out.is_file() or out.read_text() != text:
            print(f"{out.relative_to(RESULTS.parent)} is not current; run {PROG}", file=sys.stderr)
            return 1
        return 0
    write_atomic(out, lambda f: f.write(text.encode()))
    print(f"wrote {out.relative_to(RESULTS.parent)} ({len(text.splitlines())} lines)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
