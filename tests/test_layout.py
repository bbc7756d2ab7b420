"""The layers stay apart: the jit-pure core imports no host code, tasks are named only in their records,
and nothing writes into the working directory behind the user's back."""

import ast
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent


def _imports(path: pathlib.Path) -> set[str]:
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
    return out


def test_the_core_imports_neither_the_pipeline_nor_the_entry_points():
    core = [p for p in (ROOT / "ape_jax").rglob("*.py") if "pipeline" not in p.parts]
    assert len(core) > 15
    for path in core:
        bad = {m for m in _imports(path) if m.startswith(("ape_jax.pipeline", "experiments"))}
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"
    for path in (ROOT / "ape_jax" / "pipeline").rglob("*.py"):
        bad = {m for m in _imports(path) if m.startswith("experiments")}
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


def test_the_driving_sandbox_is_named_only_in_its_environment_and_its_task_record():
    allowed = {ROOT / "ape_jax" / "tasks.py"}
    for path in [*(ROOT / "ape_jax").rglob("*.py"), *(ROOT / "experiments").rglob("*.py")]:
        if path not in allowed:
            assert "toycar" not in path.read_text(), f"{path.relative_to(ROOT)} names the task: use its record"


def test_no_mujoco_log_is_written_into_the_working_directory(tmp_path):
    """MuJoCo writes MUJOCO_LOG.TXT wherever it runs unless a warning handler is installed first; the SAC
    trainer imports Brax, and HalfCheetah's model warns when compiled."""
    code = ("from ape_jax.experts import sac\n"
            "from brax import envs\n"
            "envs.get_environment('halfcheetah', backend='mjx')\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert list(tmp_path.iterdir()) == []
