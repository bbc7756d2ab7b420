"""The README's and the docs' examples as commands a test can run: fenced blocks read in page order, each shell
command classified (run it, or leave it with a written reason), sweeps shrunk to seconds.

A page's blocks run in order in one folder, so a page reads as a session: the sweep that writes
`runs/sweep/hopper-pos-quick` runs before the report that reads it, a `# my_weighting.py` block is written as that
module before the sweep that imports it. Shrinking a sweep: the `--smoke` amounts (`presets.smoke_overrides`:
4 iterations, 1 seed, 3 short demonstration episodes, ...) given as `--set`s after the command's own, without
`--smoke` itself, so what the report and `compare` refuse for a smoke run still runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import re
import shlex

ROOT = pathlib.Path(__file__).resolve().parent.parent
PAGES = ("README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").rglob("*.md")))

# commands the examples show but a test does not run, each with why (matched as a substring of the command)
SKIPPED = {
    "python3 -m venv": "installs: CI's own install runs it",
    "pip install": "installs: CI's own install runs it",
    "-m pytest": "the tests themselves: CI runs them",
    "mkdocs serve": "serves until stopped: CI builds the site with mkdocs build --strict",
    "experiments.run_notebook": "CI executes the tutorial after the tests",
    "PATH/TO/": "FCA's expert file is never shipped: the user fetches it (tests/test_import_expert.py imports one "
                "of its kind)",
    "--coordinator": "needs a second machine (tests/test_distributed.py runs two processes on one)",
    "experiments.train_expert": "trains an expert for an hour (tests/test_experts.py trains a tiny one)",
    "experiments.perception --env": "pretrains an encoder for ~11 minutes and rewrites the shipped one "
                                    "(tests/test_perception.py pretrains a small one)",
    "experiments.expert_references": "rewrites a shipped expert's card (tests/test_import_expert.py measures one)",
    "compare_runs runs/a runs/b": "placeholders for two sweeps of yours (tests/test_compare_runs.py runs it)",
    "protocol.expert=cs294": "needs FCA's expert, which the import above reads from the user's file",
}
# commands whose documented outcome at the shrunk amounts is a refusal: `(exit status, what stderr says)`
REFUSED = {
    "experiments.compare": (2, "no reference file matches its settings; the nearest"),
}
COLLECT_SMALL = ["--episodes", "2"]


@dataclasses.dataclass(frozen=True)
class Block:
    """One fenced block of a page: its language, text and first line number."""

    page: str
    lang: str
    text: str
    line: int

    @property
    def module(self) -> str | None:
        """`NAME` where a Python block starts with `# NAME.py` (a module the page's commands import), else None."""
        first = self.text.splitlines()[0] if self.text else ""
        m = re.fullmatch(r"#\s*(\w+)\.py\s*", first)
        return m.group(1) if m else None


def blocks(page: str) -> list[Block]:
    """The `python` and `bash` blocks of `page` (a path from the repository root), in order."""
    text = (ROOT / page).read_text()
    out = []
    for m in re.finditer(r"^```(\w+)\n(.*?)^```", text, re.S | re.M):
        if m.group(1) in ("python", "bash", "sh"):
            out.append(Block(page, "bash" if m.group(1) == "sh" else m.group(1), m.group(2),
                             text[:m.start()].count("\n") + 1))
    return out


def commands(block: Block) -> list[str]:
    """A shell block's commands: continuation lines joined, comments dropped, `a && b` split into `a`, `b`."""
    joined = re.sub(r"\\\n\s*", " ", block.text)
    out = []
    for line in joined.splitlines():
        line = re.sub(r"(^|\s)#.*$", "", line).strip()
        out += [part.strip() for part in line.split("&&") if part.strip()]
    return out


def skip_reason(command: str) -> str | None:
    """Why `command` is not run, or None to run it."""
    return next((why for key, why in SKIPPED.items() if key in command), None)


def entry_point(command: str) -> str | None:
    """`experiments.X` for a `python -m experiments.X ...` command (any interpreter path), else None."""
    m = re.match(r"^(?:\S*/)?python3?\s+-m\s+(experiments\.\w+)", command)
    return m.group(1) if m else None


def runnable(command: str, python: str) -> str:
    """`command` with the interpreter replaced by `python` and the amounts shrunk (a sweep's, a collection's)."""
    words = shlex.split(command, comments=False)
    start = next(i for i, w in enumerate(words) if w == "-m")
    module, args = words[start + 1], words[start + 2:]
    if module == "experiments.sweep":
        args += small_sweep(args)
    elif module == "experiments.collect":
        args += COLLECT_SMALL
    # globs (runs/sweep/*/results.json) stay unquoted for the shell to expand
    return " ".join([shlex.quote(python), "-m", module, *(a if "*" in a else shlex.quote(a) for a in args)])


def small_sweep(args: list[str]) -> list[str]:
    """The `--set`s that give a sweep of `args` the `--smoke` amounts, without `--smoke`."""
    from ape_jax import tasks
    from ape_jax.pipeline import presets

    p = argparse.ArgumentParser(add_help=False)
    for flag in ("--env", "--obs", "--protocol", "--recipe"):
        p.add_argument(flag)
    p.add_argument("--preset", default="quick")
    known, _ = p.parse_known_args(args)
    env = known.env or "hopper"
    obs = known.obs or tasks.get(env).default_obs
    protocol = tasks.get(env).protocol(known.protocol, obs).name
    small = presets.resolve(env, obs, protocol, known.preset, known.recipe, smoke=True)
    full = presets.resolve(env, obs, protocol, known.preset, known.recipe)
    values = {s: dataclasses.asdict(getattr(full, s)) for s in presets.SECTIONS}
    out = []
    for key in presets.smoke_overrides(values):
        section = next(s for s in presets.SECTIONS if key in presets.fields(s))
        out += ["--set", presets.format_set(section, key, getattr(getattr(small, section), key))]
    return out


def next_commands(stdout: str) -> list[str]:
    """The commands a sweep prints under `next:` at its end (their `# comments` dropped)."""
    lines = stdout.splitlines()
    if "next:" not in lines:
        return []
    after = lines[lines.index("next:") + 1:]
    return [re.sub(r"\s+#.*$", "", line).strip() for line in after if entry_point(line.strip())]
