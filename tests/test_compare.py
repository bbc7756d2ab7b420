"""`python -m experiments.compare`: the README's plugin example against references of the same settings, end to
end (ToyCar's `full` observations: no MJX compile), and files that are not comparable refused in one line."""

import json
import os
import subprocess
import sys

import pytest

from experiments import compare

pytestmark = pytest.mark.integration  # end-to-end sweeps: `pytest -m integration`, which CI runs

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PLUGIN = '''
import jax.numpy as jnp
from ape_jax import methods


@methods.weighting("action-norm")
def action_norm(key, actions, t):
    return jnp.sum(actions ** 2, axis=-1)
'''
COMMON = ["--env", "toycar", "--obs", "full", "--iterations", "30", "--seeds", "2", "--eval-episodes", "2", "--quiet",
          "--step-grid", "0.1:5", "--set", "budget.probe_steps=0"]


def _sweep(tmp_path, out, *args):
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "plugins")}
    proc = subprocess.run([sys.executable, "-m", "experiments.sweep", *COMMON, *args, "--out", str(out),
                           "--data-dir", str(tmp_path / "data")], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("compare")
    (tmp / "plugins").mkdir()
    (tmp / "plugins" / "my_weighting.py").write_text(PLUGIN)
    refs = _sweep(tmp, tmp / "refs" / "main", "--methods", "bc-so,bc-oh,ours-step")
    mine = _sweep(tmp, tmp / "mine", "--plugins", "my_weighting", "--methods", "action-norm")
    return tmp, refs, mine


def _compare(*args):
    return subprocess.run([sys.executable, "-m", "experiments.compare", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def test_the_readme_plugin_is_compared_with_the_references_per_task_and_across_tasks(sweeps):
    tmp, refs, mine = sweeps
    proc = _compare(str(mine), "--against", str(refs.parent), "--resamples", "200")
    assert proc.returncode == 0, proc.stderr[-2000:]
    text = (mine / "compare.md").read_text()
    assert "| action-norm (yours) | thr 0.1, w 5 | 2 |" in text
    for reference in ("BC-SO", "BC-OH", "Ours, step THR 10% W 5"):
        assert f"| action-norm − {reference} |" in text
    assert "| FCA" not in text                       # no reference ran it: no row, not an empty one
    assert "## Across tasks" in text and "| action-norm (yours) | 1 |" in text
    assert (mine / "compare-profile.png").stat().st_size > 5_000
    assert text.splitlines()[0] in proc.stdout


def test_a_file_whose_settings_differ_from_every_reference_is_refused_naming_the_fields(sweeps, tmp_path):
    _, refs, mine = sweeps
    r = json.loads((mine / "results.json").read_text())
    r["settings"]["recipe"]["batch_size"] = 64
    (tmp_path / "other.json").write_text(json.dumps(r))
    proc = _compare(str(tmp_path / "other.json"), "--against", str(refs.parent), "--out", str(tmp_path))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "recipe.batch_size (128 there, 64 here)" in proc.stderr and "main/results.json" in proc.stderr
    assert not (tmp_path / "compare.md").exists()


def test_references_alone_and_missing_files_are_refused(sweeps, tmp_path):
    _, refs, _ = sweeps
    proc = _compare(str(refs), "--against", str(refs.parent), "--out", str(tmp_path))
    assert proc.returncode == 2 and "holds only reference methods" in proc.stderr
    proc = _compare(str(tmp_path / "nope"), "--out", str(tmp_path))
    assert proc.returncode == 2 and "no such file or folder" in proc.stderr


def test_comparable_fields_leave_out_what_does_not_change_a_configuration():
    assert compare.FREE["knobs"] is None and "seeds" in compare.FREE["budget"]   # the methods' own settings: free
    assert "batch_size" not in compare.FREE["recipe"] and "iterations" not in compare.FREE["budget"]
