#!/usr/bin/env bash
# Sets up a fresh Debian bookworm machine: system packages, a virtualenv in .venv, the C++ core.
# Safe to run again: every step is skipped or incremental when already done.
set -euo pipefail
cd "$(dirname "$0")/.."

need=()
for pkg in libembree-dev g++ cmake; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if ((${#need[@]})); then
  echo "setup: installing ${need[*]}"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
fi

python=${PYTHON:-python3.11}
command -v "$python" >/dev/null || python=python3
[[ -x .venv/bin/python ]] || "$python" -m venv .venv
.venv/bin/pip install -q --disable-pip-version-check -r requirements.txt
# The core is compiled by CMake through scikit-build-core; the editable install keeps the Python
# sources live and rebuilds the extension incrementally in build/.
# (CI set: scikit-build-core then waits 40 s, not 10, for `cmake --version` on a loaded machine.)
# The 'denoise' extra (pyoidn: Open Image Denoise for --denoise), the 'farm' extra (ray: --cluster)
# and the 'census' extra (SnapPy: --space snappy:NAME) are installed for the tests.
CI="${CI:-1}" .venv/bin/pip install -q --disable-pip-version-check --no-build-isolation -e '.[denoise,farm,census]'
echo "setup: ready ($(.venv/bin/python -c 'import thurston_core; print(thurston_core.__name__, thurston_core.EMBREE_VERSION)'))"
