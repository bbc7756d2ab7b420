"""Where a result came from: versions, devices, machine, and the git commit of the code that ran.

    system()   # {"ape_jax", "jax", "backend", "devices", "commit", "dirty", "machine"}: results.json's `system`

`ape_jax.pipeline.sweep.run_sweep` records it in the results it returns, so a sweep run from Python says which
code made it, as the command line's does; the commit is None where the package is not a git checkout.
"""

from __future__ import annotations

import os
import pathlib
import platform
import re
import subprocess

import jax

import ape_jax

ROOT = pathlib.Path(__file__).resolve().parents[2]  # the checkout the package sits in


def system() -> dict:
    """Versions (this package's and jax's), devices, machine, and the git commit of the code (`dirty`: tracked
    files modified).

    Take it when a job starts: the code that runs, not what is checked out when it ends.
    """
    def git(*args):
        return subprocess.run(["git", *args], capture_output=True, text=True, timeout=10, cwd=ROOT).stdout.strip()

    try:
        commit, dirty = git("rev-parse", "--short", "HEAD") or None, bool(git("status", "--porcelain", "-uno"))
    except (OSError, subprocess.SubprocessError):
        commit, dirty = None, None
    return {"ape_jax": ape_jax.__version__, "jax": jax.__version__, "backend": jax.default_backend(),
            "devices": jax.device_count(), "commit": commit, "dirty": dirty, "machine": machine()}


def machine() -> str:
    """The CPU model and core count (and the accelerator, if any), for provenance lines."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            names = re.findall(r"model name\s*:\s*(.*)", f.read())
        cpu = names[0].strip() if names else cpu
    except OSError:
        pass
    accel = "" if jax.default_backend() == "cpu" else f", {jax.devices()[0].device_kind}"
    return f"{cpu}, {os.cpu_count()} cores{accel}"
