#!/usr/bin/env bash
# Downloads experiments/device/wheels.txt (Python 3.12, manylinux x86_64, no dependencies) into .whl/,
# which git ignores (.git/info/exclude) and the device tool carries: `run(..., carry=[".whl"])`.
set -euo pipefail
cd "$(dirname "$0")/../.."
grep -qxF '/.whl/' .git/info/exclude 2>/dev/null || echo '/.whl/' >> .git/info/exclude
mkdir -p .whl
grep -v '^#' experiments/device/wheels.txt | grep . | xargs python3 -m pip download -q --no-deps --only-binary=:all: \
  --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform manylinux1_x86_64 -d .whl
du -sh .whl
