"""The tutorial (docs/tutorial.ipynb) and the runner CI executes it with (experiments.run_notebook).

The default run checks the committed notebook without running it: valid nbformat 4, outputs stripped, every step
of the tour present, public names only; and that the runner names a failing cell. `pytest -m slow` executes the
notebook top to bottom as CI does and checks what it drew."""

import ast
import base64
import json
import os
import pathlib
import re
import subprocess
import sys

import nbformat
import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
NOTEBOOK = ROOT / "docs" / "tutorial.ipynb"
# the steps of the tour (issue 28), in order, as the notebook's section headings; and a call each must show
STEPS = [("## 1. Make an environment and look at a frame", "envs.make("),
         ("## 2. Collect demonstrations", "collect.collect("),
         ("## 3. Fit ψ and look at the keyframes", "figures.keyframes("),
         ("## 4. Weight a dataset", "weighting.step("),
         ("## 5. Train a small grid with `grid_runner`", "grid_runner("),
         ("## 6. Evaluate", "make_evaluator("),
         ("## 7. Write a plugin", "@methods.weighting("),
         ("## 8. Report", "report.build(")]
PROJECT = ("ape_jax", "envs", "experiments")


def _notebook():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    return nb


def _run(*args, cwd=ROOT, env=None, timeout=120):
    return subprocess.run([sys.executable, "-m", "experiments.run_notebook", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout, env=env)


def test_the_committed_notebook_is_valid_nbformat_4_with_its_outputs_stripped():
    nb = _notebook()
    assert nb.nbformat == 4 and nb.metadata.kernelspec.name == "python3"
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert len(code) >= 8
    for cell in code:
        assert cell.outputs == [] and cell.execution_count is None, f"cell {cell.id} keeps its outputs"
        assert "execution" not in cell.metadata, f"cell {cell.id} keeps its timing"
    assert len({c.id for c in nb.cells}) == len(nb.cells)
    # outputs stripped on disk too: no image or error can hide in the JSON
    assert '"output_type"' not in NOTEBOOK.read_text()


def test_the_notebook_walks_through_every_step_in_order_each_with_its_call():
    nb = _notebook()
    headings = [line for c in nb.cells if c.cell_type == "markdown" for line in c.source.splitlines()
                if line.startswith("## ")]
    assert headings == [h for h, _ in STEPS]
    # each step's cells (up to the next heading) show the API it is about, and a short text says why
    sections, current = {}, None
    for cell in nb.cells:
        heading = next((h for h, _ in STEPS if cell.cell_type == "markdown" and cell.source.startswith(h)), None)
        current = heading or current
        if current is not None:
            sections.setdefault(current, []).append(cell)
    for heading, call in STEPS:
        cells = sections[heading]
        assert any(c.cell_type == "code" and call in c.source for c in cells), f"{heading}: no {call}"
        assert len(cells[0].source.split()) >= 30, f"{heading}: say what the step shows and why"
    # the figures the text promises: a frame and the keyframes, drawn inline
    assert nb.cells[1].source.startswith("%matplotlib inline")


def test_the_notebook_uses_public_names_only_and_writes_to_a_temporary_folder():
    nb = _notebook()
    source = "\n".join(c.source for c in nb.cells if c.cell_type == "code")
    tree = ast.parse("\n".join(line for line in source.splitlines() if not line.startswith("%")))
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(PROJECT):
            assert not any(p.startswith("_") for p in node.module.split(".")), node.module
            assert not any(a.name.startswith("_") for a in node.names), [a.name for a in node.names]
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            pytest.fail(f"the notebook reaches into a private name: .{node.attr}")
    assert "tempfile.mkdtemp(" in source and "shutil.rmtree(work)" in source
    assert not re.search(r"https?://", source), "the notebook must not download anything"


def test_the_runner_refuses_a_missing_or_broken_file_in_one_line(tmp_path):
    proc = _run(tmp_path / "missing.ipynb")
    assert proc.returncode == 2 and proc.stderr.strip().count("\n") == 0
    assert "missing.ipynb: no such notebook file" in proc.stderr
    (tmp_path / "broken.ipynb").write_text("{not json")
    proc = _run(tmp_path / "broken.ipynb")
    assert proc.returncode == 2 and "not a valid nbformat 4 notebook" in proc.stderr
    assert proc.stderr.strip().count("\n") == 0


def test_the_runner_executes_in_this_venv_and_names_the_cell_that_fails(tmp_path):
    nb = nbformat.v4.new_notebook(cells=[
        nbformat.v4.new_markdown_cell("# A notebook"),
        nbformat.v4.new_code_cell("import os, sys\nprint(sys.prefix)\nprint(os.getcwd())"),
        nbformat.v4.new_code_cell("x = 1\nx / 0"),
        nbformat.v4.new_code_cell("print('never')"),
    ])
    path = tmp_path / "nb" / "failing.ipynb"
    path.parent.mkdir()
    nbformat.write(nb, path)
    before = path.read_bytes()
    proc = _run(path, "--out", tmp_path / "executed.ipynb")
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "cell 3 of 4 (code cell 2: x = 1) failed" in proc.stderr and "ZeroDivisionError" in proc.stderr
    assert path.read_bytes() == before   # the notebook itself is never written
    executed = nbformat.read(tmp_path / "executed.ipynb", as_version=4)
    printed = "".join(o.get("text", "") for o in executed.cells[1].outputs).split("\n")
    # this venv's kernel, in the notebook's folder
    assert printed[0] == sys.prefix and printed[1] == str(path.parent.resolve())
    assert executed.cells[3].outputs == []

    nb.cells = nb.cells[:2]
    nbformat.write(nb, path)
    proc = _run(path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert re.search(r"1 code cells ran in \d+ s", proc.stdout) and sys.executable in proc.stdout


def test_the_runner_refuses_a_kernel_of_another_environment_before_the_first_cell(tmp_path):
    """A `python3` kernel spec found before the venv's (here through JUPYTER_PATH) runs another Python: refused."""
    spec = tmp_path / "jupyter" / "kernels" / "python3"
    spec.mkdir(parents=True)
    elsewhere = ("import sys; sys.prefix = '/elsewhere'; from ipykernel import kernelapp; "
                 "kernelapp.launch_new_instance()")
    (spec / "kernel.json").write_text(json.dumps({"argv": [sys.executable, "-c", elsewhere, "-f", "{connection_file}"],
                                                  "display_name": "another", "language": "python"}))
    path = tmp_path / "one.ipynb"
    nbformat.write(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("open('ran', 'w').close()")]), path)
    proc = _run(path, env={**os.environ, "JUPYTER_PATH": str(tmp_path / "jupyter")})
    assert proc.returncode == 1 and "(environment /elsewhere), not this Python's environment" in proc.stderr
    assert not (tmp_path / "ran").exists()   # stopped before the notebook's first cell


@pytest.mark.slow
def test_the_tutorial_runs_top_to_bottom_and_draws_its_figures(tmp_path):
    """As CI runs it (`.ci/run`); its temporary folder is removed at the end, the notebook left as it was."""
    before = NOTEBOOK.read_bytes()
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    env = {**os.environ, "TMPDIR": str(scratch)}
    proc = _run(NOTEBOOK, "--out", tmp_path / "executed.ipynb", "--timeout", "600", env=env, timeout=1500)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    assert re.search(r"code cells ran in \d+ s", proc.stdout)
    assert NOTEBOOK.read_bytes() == before
    assert not list(scratch.glob("ape_jax-tutorial-*")), "the tutorial left its folder behind"
    executed = json.loads((tmp_path / "executed.ipynb").read_text())
    outputs = [o for c in executed["cells"] for o in c.get("outputs", [])]
    assert not [o for o in outputs if o["output_type"] == "error"]
    pngs = [base64.b64decode(o["data"]["image/png"]) for o in outputs if "image/png" in o.get("data", {})]
    assert len(pngs) >= 4 and all(p.startswith(b"\x89PNG") for p in pngs)   # frames, keyframes, curves, report
    markdown = "".join("".join(o["data"]["text/markdown"]) for o in outputs if "text/markdown" in o.get("data", {}))
    assert "| BC-OH |" in markdown and "action-change" in markdown   # the evaluation table, the report's grid
