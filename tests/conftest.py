"""Test configuration: CPU only, and cheaper XLA compiles.

Most of the suite's time is XLA compiling MJX physics. Backend optimisation
level 0 cuts that by about a fifth on a 2-core CPU; tests run tiny programs,
so the slower generated code does not matter. Set before jax is imported.
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
if "--xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()
