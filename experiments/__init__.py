"""The project's entry points (`python -m experiments.sweep`, ...): command lines over `ape_jax`.

Importing the package quiets XLA's C++ error log unless the environment sets its level (`TF_CPP_MIN_LOG_LEVEL`),
before JAX is imported: XLA:CPU writes two spurious errors of several kilobytes ("Target machine feature
+prefer-no-gather is not supported on the host machine ... could lead to execution errors such as SIGILL") for
every program it loads from the persistent compilation cache on CPUs whose LLVM tuning flags it takes for
instruction sets (openxla/xla#44565, jax-ml/jax#38445), and then runs the program it loaded, correctly. XLA's
real failures still reach Python as exceptions; `TF_CPP_MIN_LOG_LEVEL=0` shows the log again.

It also gives OpenBLAS one thread unless the environment says otherwise (`OPENBLAS_NUM_THREADS`), before SciPy's
library loads (MJX imports SciPy): jaxlib's CPU linear solves (Cholesky, LU: PALR's estimator,
`ape_jax.baselines.palr`) call SciPy's LAPACK, whose OpenBLAS threads waited ~20 ms per call on a loaded 2-core
machine (a 64 × 64 solve: 0.1 ms with one thread, 20 ms with two); PALR then trained at 0.12× BC-OH's updates/s
instead of ~0.9× (`experiments.bench_train --methods-only`). XLA's own kernels do not use OpenBLAS.
"""

import os

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
