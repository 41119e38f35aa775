"""Render one member of each family of spaces (and two SnapPy manifolds) in its default view to
docs/catalogue/<name>.png, and print docs/catalogue.md's table with each one's invariants: the
geometry, the volume (checked on load against the closed form or SnapPy's), the faces of the
domain, the group order (S3) and the first homology computed from the domain (Dirichlet spaces).
Run: .venv/bin/python scripts/render_catalogue.py [--size 240x135] [--quality standard] [NAME ...]
(names: only those members, their rows printed for the table)"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from thurston_addon import images, render, spaces
from thurston_addon.scenes import default_scene
from thurston_addon.spaces import homology
from thurston_addon.spaces.writing import file_name

OUT = Path(__file__).resolve().parents[1] / "docs" / "catalogue"
MEMBERS = [
    "lens(7,2)",
    "lens(12,5)",
    "prism(3)",
    "binary(tetrahedral)",
    "binary(octahedral)",
    "binary(icosahedral)",
    "flat(didicosm)",
    "flat(amphicosm1)",
    "flat(amphicosm2)",
    "flat(amphidicosm1)",
    "flat(amphidicosm2)",
    "nil(3)",
    "sol(3,1,2,1)",
    "surface_x_circle(2)",
    "unit_tangent(2)",
    "surface_x_circle(3)",
    "unit_tangent(3)",
    "snappy:m003(-3,1)",
    "snappy:m004(5,1)",
]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="240x135")
    ap.add_argument("--quality", default="standard")
    ap.add_argument("names", nargs="*", help="only these members (default: all of them)")
    args = ap.parse_args()
    w, h = map(int, args.size.split("x"))
    OUT.mkdir(parents=True, exist_ok=True)
    rows = ["| name | geometry | volume | faces | group order | H1 | default view |", "|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as cache:
        os.environ["THURSTON_CACHE_DIR"] = cache
        for name in args.names or MEMBERS:
            space = spaces.load(name)
            result = render.render(
                space, default_scene(space), render.Settings(width=w, height=h, quality=args.quality)
            )
            png = OUT / file_name(name).replace(".toml", ".png")
            images.write(png, result.passes, overwrite=True)
            dirichlet = hasattr(space, "edge_cycles")
            h1 = homology.homology_text(homology.first_homology(space)) if dirichlet else "(see the family)"
            order = getattr(space, "group_order", None) if dirichlet else None
            rows.append(
                f"| `{name}` | {space.geometry.name} | {space.volume:.10g} | {len(space.domain.faces)} | "
                f"{order or '∞'} | {h1} | ![{name}](catalogue/{png.name}) |"
            )
            print(rows[-1], flush=True)
    print("\n".join(rows))


if __name__ == "__main__":
    main()
