"""`python -m experiments.report RESULTS... [--out BENCHMARKS.md] [--pages DIR] [--figures DIR]` (see
`experiments.report`)."""

import sys

from experiments.report import main

sys.exit(main())
