"""Check that two builds render every preset's default view bit for bit alike: each preset's default
scene and camera (as scripts/render_gallery.py renders them) through each build's own command line, to
a multi-pass EXR, and every channel's pixels compared exactly. For a change that must not change images
(a restructure): build the tree before it in another checkout, then
    .venv/bin/python scripts/compare_builds.py --baseline ../before/.venv [--size 320x180 --quality standard]
        [--samples N --bounces N]   (path traced, as the gallery's --gi)
Prints a table (preset, channels, differing pixels, largest difference) and exits 1 if any differ."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

HERE = Path(__file__).resolve().parents[1]


def thurston(venv: Path, *args: str) -> str:
    done = subprocess.run([str(venv / "bin" / "thurston"), *args], capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"compare_builds: {venv}: thurston {' '.join(args)} failed:\n{done.stderr}")
    return done.stdout


def channels(path: Path) -> tuple[tuple[str, ...], np.ndarray]:
    image = oiio.ImageBuf(str(path))
    return tuple(image.spec().channelnames), image.get_pixels(oiio.FLOAT)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--baseline", type=Path, required=True, help="the other build's virtualenv")
    ap.add_argument("--build", type=Path, default=HERE / ".venv", help="this build's virtualenv")
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--quality", default="standard")
    ap.add_argument("--samples", help="samples per pixel (default: the quality's)")
    ap.add_argument("--bounces", help="path-traced bounces (default: direct light only)")
    args = ap.parse_args()
    presets = [p["id"] for p in json.loads(thurston(args.build, "spaces", "--json"))]
    baseline_presets = [p["id"] for p in json.loads(thurston(args.baseline, "spaces", "--json"))]
    if presets != baseline_presets:
        sys.exit(f"compare_builds: the builds list different presets: {presets} and {baseline_presets}")
    print("| preset | channels | differing pixels | largest difference |\n|---|---|---|---|")
    options = ["--size", args.size, "--quality", args.quality]
    options += [f"--{name}={value}" for name in ("samples", "bounces") if (value := getattr(args, name))]
    differ = 0
    with tempfile.TemporaryDirectory() as tmp:
        for sid in presets:
            renders = []
            for name, venv in (("build", args.build), ("baseline", args.baseline)):
                out = Path(tmp) / f"{sid}_{name}.exr"
                thurston(venv, "render", "--space", sid, *options, "--out", str(out))
                renders.append(channels(out))
            (names, a), (baseline_names, b) = renders
            if names != baseline_names or a.shape != b.shape:
                print(f"| `{sid}` | {names} vs {baseline_names} | all | - |")
                differ += 1
                continue
            same = (a == b) | (np.isnan(a) & np.isnan(b))
            pixels = int(np.count_nonzero(~same.all(axis=-1)))
            largest = float(np.nanmax(np.abs(a - b)[~same])) if pixels else 0.0
            print(f"| `{sid}` | {len(names)} | {pixels} | {largest:.3g} |", flush=True)
            differ += pixels > 0
    print(f"\n{len(presets) - differ} of {len(presets)} presets bit for bit alike")
    sys.exit(1 if differ else 0)


if __name__ == "__main__":
    main()
