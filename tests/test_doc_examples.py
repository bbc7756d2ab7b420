"""Every example of the README and the docs runs as written (`tests/_doc_examples.py`): the Python blocks as
scripts, the shell commands with the amounts shrunk to seconds, in page order in one folder per page. A command
the examples show but the test does not run is named in `SKIPPED` with its reason; a new one is neither run nor
skipped silently (the default run checks that every command is one or the other)."""

import os
import subprocess
import sys

import pytest

import _doc_examples as ex

TIMEOUT = 900


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One demonstration cache and expert folder for every page: a collection is made once."""
    return tmp_path_factory.mktemp("examples-cache")


def test_every_command_of_the_examples_is_run_or_skipped_with_a_reason():
    seen = []
    for page in ex.PAGES:
        for block in ex.blocks(page):
            if block.lang != "bash":
                continue
            for command in ex.commands(block):
                seen.append(command)
                assert ex.skip_reason(command) or ex.entry_point(command), \
                    f"{page}:{block.line}: {command!r} is neither an entry point nor skipped with a reason"
    assert len(seen) > 30 and sum(ex.entry_point(c) is not None and not ex.skip_reason(c) for c in seen) > 15
    for key in ex.SKIPPED:   # no stale reason: each still matches a command
        assert any(key in c for c in seen), f"SKIPPED[{key!r}] matches no command of the examples"


def test_a_sweep_is_shrunk_to_the_smoke_amounts_after_its_own_settings_without_the_smoke_flag():
    command = ex.runnable("python -m experiments.sweep --env walker2d --seeds 3 --out runs/w", "PY")
    words = command.split()
    assert "--smoke" not in words and words.index("--seeds") < words.index("budget.seeds=1")   # ours come last
    assert {"budget.iterations=4", "protocol.collect_transitions=240", "recipe.batch_size=4"} <= set(words)


def _run_page(page, tmp_path, cache):
    env = {**os.environ, "APE_JAX_CACHE": str(cache), "PYTHONPATH": os.pathsep.join([str(ex.ROOT), str(tmp_path)])}
    ran = []
    for i, block in enumerate(ex.blocks(page)):
        if block.lang == "python":
            name = block.module
            (tmp_path / f"{name or f'example_{i}'}.py").write_text(block.text)
            args = [sys.executable, "-c", f"import {name}"] if name else [sys.executable, f"example_{i}.py"]
            proc = subprocess.run(args, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=TIMEOUT)
            assert proc.returncode == 0, f"{page}:{block.line}: the Python example fails:\n{proc.stderr[-3000:]}"
            ran.append(f"python block at line {block.line}")
            continue
        for command in ex.commands(block):
            if ex.skip_reason(command):
                continue
            out = _run(command, f"{page}:{block.line}", tmp_path, env)
            ran.append(command)
            for suggested in ex.next_commands(out):   # what a sweep suggests next runs as suggested
                _run(suggested, f"{page}:{block.line}: {command!r} suggests", tmp_path, env)
                ran.append(suggested)
    return ran


def _run(command, where, cwd, env) -> str:
    """Runs `command` shrunk (`ex.runnable`) in `cwd`; asserts its documented exit status; returns its stdout."""
    proc = subprocess.run(["bash", "-c", ex.runnable(command, sys.executable)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=TIMEOUT)
    code, words = ex.REFUSED.get(ex.entry_point(command), (0, None))
    assert proc.returncode == code, f"{where}: {command!r} exits {proc.returncode}, not {code}:\n{proc.stderr[-3000:]}"
    if words is not None:   # a refusal at the shrunk amounts: one line saying why
        assert words in proc.stderr and proc.stderr.strip().count("\n") == 0, proc.stderr[-2000:]
    return proc.stdout


@pytest.mark.integration
@pytest.mark.parametrize("page", [p for p in ex.PAGES
                                  if any(not ex.skip_reason(c) for b in ex.blocks(p) if b.lang == "bash"
                                         for c in ex.commands(b)) or any(b.lang == "python" for b in ex.blocks(p))])
def test_the_examples_of_a_page_run_in_order(page, tmp_path, cache):
    assert _run_page(page, tmp_path, cache)


def test_the_readmes_commands_run_as_typed_from_the_clone_after_its_install():
    """The README installs into `./.venv` and never activates it, so each of its commands names that interpreter (a
    bare `python -m ...` fails with `No module named 'jax'` in a fresh shell): in code blocks and in inline code."""
    import re

    text = (ex.ROOT / "README.md").read_text()
    bare = [c for c in re.findall(r"(?:^|[`\s:])((?:[^\s`]*/)?python3? -m [^\s`]+)", text, re.M)
            if not c.startswith(".venv/bin/") and not c.startswith("python3 -m venv")]
    assert not bare, f"README commands that a fresh shell cannot run as typed: {bare}"
    assert text.count(".venv/bin/python -m experiments.") >= 6
