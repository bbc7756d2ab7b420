"""The test lists `.ci/run` reads (tests/compat.txt, tests/layouts.txt) name tests that exist: a renamed test would
otherwise drop out of its pass silently, or fail CI with "not found" only after the first pass's half hour."""

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
LISTS = ("compat.txt", "layouts.txt")


def _entries(name: str) -> list[str]:
    lines = (ROOT / "tests" / name).read_text().splitlines()
    return [line.strip() for line in lines if line.strip() and not line.lstrip().startswith("#")]


@pytest.mark.parametrize("name", LISTS)
def test_every_entry_of_a_ci_list_names_an_existing_test_file_or_function(name):
    entries = _entries(name)
    assert entries, f"tests/{name} lists nothing"
    for entry in entries:
        path, _, node = entry.partition("::")
        file = ROOT / path
        assert file.is_file(), f"tests/{name}: {path} does not exist"
        if node:
            functions = {n.name for n in ast.walk(ast.parse(file.read_text())) if isinstance(n, ast.FunctionDef)}
            assert node.split("[")[0] in functions, f"tests/{name}: {path} has no test {node}"


def test_the_ci_script_runs_both_lists():
    script = (ROOT / ".ci" / "run").read_text()
    for name in LISTS:
        assert f"tests/{name}" in script
    assert "taskset -c 0" in script and "--xla_cpu_multi_thread_eigen=false" in script
