"""The project's entry points (`python -m experiments.sweep`, ...): command lines over `ape_jax`.

Importing the package quiets XLA's C++ error log unless the environment sets its level (`TF_CPP_MIN_LOG_LEVEL`),
before JAX is imported: XLA:CPU writes two spurious errors of several kilobytes ("Target machine feature
+prefer-no-gather is not supported on the host machine ... could lead to execution errors such as SIGILL") for
every program it loads from the persistent compilation cache on CPUs whose LLVM tuning flags it takes for
instruction sets (openxla/xla#44565, jax-ml/jax#38445), and then runs the program it loaded, correctly. XLA's
real failures still reach Python as exceptions; `TF_CPP_MIN_LOG_LEVEL=0` shows the log again.
"""

import os

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
