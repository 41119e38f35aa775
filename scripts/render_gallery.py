"""Render each preset's default view (its default scene and camera) to docs/<id>.png, and print the
README's gallery table; with --gi, instead the default views of the given presets with direct light
only and path traced, side by side (docs/<id>_direct.png, docs/<id>_gi.png, both at --gi-samples
samples per pixel), and their table.
Run: .venv/bin/python scripts/render_gallery.py [--size 320x180] [--quality standard]
     [--gi torus,poincare,seifert_weber --gi-samples 16 --bounces 4]"""

from __future__ import annotations

import argparse
from pathlib import Path

from thurston_addon import images, render, spaces
from thurston_addon.scenes import default_scene

DOCS = Path(__file__).resolve().parents[1] / "docs"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--quality", default="standard")
    ap.add_argument("--gi", help="presets to render direct-only and path traced, side by side")
    ap.add_argument("--gi-samples", type=int, default=16)
    ap.add_argument("--bounces", type=int, default=4)
    args = ap.parse_args()
    w, h = map(int, args.size.split("x"))
    DOCS.mkdir(exist_ok=True)
    if args.gi:
        rows = [f"| preset | direct light | path traced ({args.bounces} bounces) |", "|---|---|---|"]
        for sid in args.gi.split(","):
            space = spaces.load(sid)
            cells = []
            for name, bounces in (("direct", 0), ("gi", args.bounces)):
                settings = render.Settings(width=w, height=h, samples=args.gi_samples, bounces=bounces)
                result = render.render(space, default_scene(space), settings)
                out = DOCS / f"{sid}_{name}.png"
                images.write(out, result.passes, overwrite=True)
                cells.append(f"![{sid} {name}](docs/{out.name})")
            rows.append(f"| `{sid}` | " + " | ".join(cells) + " |")
        print("\n".join(rows))
        return
    rows = ["| preset | geometry | default view |", "|---|---|---|"]
    for sid in spaces.preset_ids():
        space = spaces.load(sid)
        shading = "lambert" if space.geometry.point_lights else "normal"  # (graph: pseudo-colour only)
        settings = render.Settings(width=w, height=h, quality=args.quality, shading=shading)
        result = render.render(space, default_scene(space), settings)
        out = DOCS / f"{sid}.png"
        images.write(out, result.passes, overwrite=True)
        rows.append(f"| `{sid}` | {space.geometry.name} | ![{sid}](docs/{out.name}) |")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
