"""Test configuration: CPU only, cheaper XLA compiles, and compiled programs shared within a run.

Most of the suite's time is XLA compiling MJX physics. Tests run tiny programs, so
the speed of the generated code does not matter and three settings buy compile time:
- backend optimisation level 0 (about a fifth less);
- XLA:CPU's older elemental emitters instead of its MLIR fusion emitters (about a
  quarter less on MJX's step, measured on a 2-core AMD EPYC). XLA aborts on a flag
  it does not know, so it is only set where a child process shows this jaxlib takes it;
- JAX's persistent compilation cache in a fresh temporary folder per pytest run,
  shared by the xdist workers and the sweeps they start in subprocesses, so a
  program compiled by one is loaded by the others. Fresh per run: a run's time is
  a fresh clone's.
Set before jax is imported; the first process of a run (pytest-xdist's controller,
or plain pytest) decides, and its workers and their subprocesses inherit the variables.
"""

import atexit
import os
import shutil
import subprocess
import sys
import tempfile

FAST_COMPILE_FLAGS = ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false")


def _accepted(flag: str) -> bool:
    """Whether jaxlib's XLA starts with `flag` (a child process: XLA aborts on unknown flags)."""
    probe = "import jax.numpy as jnp; jnp.zeros(1).block_until_ready()"
    env = {**os.environ, "XLA_FLAGS": flag, "JAX_PLATFORMS": "cpu"}
    try:
        return subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, timeout=120).returncode == 0
    except (OSError, subprocess.SubprocessError):  # a probe that cannot run or hangs: do without the flag
        return False


os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # LAPACK's threads stall on a loaded CPU (experiments/__init__)
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:  # the run's first process
    flags = os.environ.get("XLA_FLAGS", "")
    for flag in FAST_COMPILE_FLAGS:
        if flag.split("=")[0] not in flags and (flag == FAST_COMPILE_FLAGS[0] or _accepted(flag)):
            flags = f"{flags} {flag}".strip()
    os.environ["XLA_FLAGS"] = flags
    _cache = tempfile.mkdtemp(prefix="ape_jax-tests-xla-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _cache
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)


# The heaviest modules first (most of their time is compiling MJX physics or running small sweeps): pytest-xdist
# hands tests out in collection order, so a heavy module near the end keeps one worker busy while the other has
# finished. Measured per test on the 2-core AMD EPYC (CPU seconds, a fresh clone, 2026-12-03).
HEAVY_FIRST = ("test_resume.py", "test_sweep.py", "test_distributed.py", "test_phases.py", "test_experts.py",
               "test_data.py", "test_envs.py", "test_toycar.py", "test_render.py", "test_learner.py", "test_fca.py")


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(HEAVY_FIRST)))  # stable: a module's order is kept
