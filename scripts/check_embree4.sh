#!/usr/bin/env bash
# Developer check (not CI): build the core against Embree 4's API and run tests/core/test_core.py on it.
#
# Debian bookworm ships only Embree 3, and no PyPI package ships Embree 4's headers: the embreex
# wheel bundles libembree4 (4.4.0) but only Cython .pxd files. So this script takes the library from
# that wheel and the headers from EMBREE4_INCLUDE_DIR (a directory holding embree4/rtcore.h, e.g.
# the include/ of an Embree 4 release or source tree):
#
#   EMBREE4_INCLUDE_DIR=/path/to/embree-4.x/include bash scripts/check_embree4.sh
#
# Without headers it still downloads and inspects the wheel, says what is missing and exits 2.
# The headers' rtcore_config.h must match the library's build (4.4.0, default options). Needs .venv
# (scripts/setup.sh), cmake and g++; builds in build/embree4/.
set -euo pipefail
cd "$(dirname "$0")/.."
python=.venv/bin/python
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

"$python" -m pip download -q --disable-pip-version-check --no-deps --only-binary :all: \
  -d "$work/wheel" "embreex==4.4.0.post1"
"$python" -m zipfile -e "$work"/wheel/*.whl "$work/unpacked"
lib=$(find "$work/unpacked" -name 'libembree4*.so*' | head -n 1)
[[ -n "$lib" ]] || { echo "check_embree4: the embreex wheel holds no libembree4" >&2; exit 1; }
echo "check_embree4: library $lib"

include=${EMBREE4_INCLUDE_DIR:-}
if [[ -z "$include" ]]; then
  found=$(find "$work/unpacked" -path '*embree4/rtcore.h' | head -n 1)
  [[ -n "$found" ]] && include=$(dirname "$(dirname "$found")")
fi
if [[ -z "$include" || ! -f "$include/embree4/rtcore.h" ]]; then
  echo "check_embree4: no Embree 4 headers: the wheel has none; set EMBREE4_INCLUDE_DIR to a" \
       "directory holding embree4/rtcore.h" >&2
  exit 2
fi

build=build/embree4
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=Release -DPython_EXECUTABLE="$PWD/$python" \
  -DTHURSTON_EMBREE4_INCLUDE_DIR="$include" -DTHURSTON_EMBREE4_LIBRARY="$lib"
cmake --build "$build" -j 2
module=$(find "$build" -maxdepth 1 -name 'thurston_core*.so' | head -n 1)

# The editable install's finder would import the Embree 3 build: load this one by path first.
LD_LIBRARY_PATH="$(dirname "$lib")${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" "$python" - "$module" <<'PY'
import importlib.util, sys
spec = importlib.util.spec_from_file_location("thurston_core", sys.argv[1])
core = importlib.util.module_from_spec(spec)
sys.modules["thurston_core"] = core
spec.loader.exec_module(core)
print("check_embree4: thurston_core built with Embree", core.EMBREE_VERSION)
assert core.EMBREE_VERSION.startswith("4."), core.EMBREE_VERSION
import pytest
status = pytest.main(["-q", "-p", "no:cacheprovider", "tests/core/test_core.py"])

# EMBREE_VERSION is the headers' version: check which libraries the process really mapped.
with open("/proc/self/maps") as maps:
    loaded = sorted({line.split()[-1] for line in maps
                     if "libembree" in line or "libtbb" in line})
print("check_embree4: loaded", *loaded, sep="\n  ")
assert any("libembree4" in path for path in loaded), loaded
assert not any("libembree3" in path for path in loaded), loaded
sys.exit(status)
PY
