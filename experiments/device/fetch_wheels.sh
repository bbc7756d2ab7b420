#!/usr/bin/env bash
# Downloads experiments/device/wheels.txt (Python 3.12, manylinux x86_64, no dependencies) into .whl/,
# which git ignores (.git/info/exclude) and the device tool carries: `run(..., carry=[".whl"])`.
# --lean: then drops the wheels no sweep imports (MuJoCo's viewer app and OpenGL, 16 MB of the 34), so .whl/ and
# the image plan's demonstrations (.devdata/, 36 MB for three tasks) fit in the 64 MiB the device tool carries.
set -euo pipefail
cd "$(dirname "$0")/../.."
LEAN=0; [ "${1:-}" = --lean ] && LEAN=1
grep -qxF '/.whl/' .git/info/exclude 2>/dev/null || echo '/.whl/' >> .git/info/exclude
mkdir -p .whl
grep -v '^#' experiments/device/wheels.txt | grep . | xargs python3 -m pip download -q --no-deps --only-binary=:all: \
  --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
  --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform manylinux1_x86_64 -d .whl
if [ "$LEAN" = 1 ]; then rm -f .whl/mujoco_studio-*.whl .whl/pyopengl-*.whl .whl/PyOpenGL-*.whl; fi
du -sh .whl
