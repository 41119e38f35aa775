"""Render each preset's default view (its default scene and camera) to docs/<id>.png, and print the
README's gallery table. Run: .venv/bin/python scripts/render_gallery.py [--size 320x180] [--quality standard]"""
from __future__ import annotations

import argparse
from pathlib import Path

from thurston_addon import images, render, spaces
from thurston_addon.scene import default_scene

DOCS = Path(__file__).resolve().parents[1] / "docs"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="320x180")
    ap.add_argument("--quality", default="standard")
    args = ap.parse_args()
    w, h = map(int, args.size.split("x"))
    DOCS.mkdir(exist_ok=True)
    rows = ["| preset | geometry | default view |", "|---|---|---|"]
    for sid in spaces.preset_ids():
        space = spaces.load(sid)
        result = render.render(space, default_scene(space), render.Settings(width=w, height=h, quality=args.quality))
        out = DOCS / f"{sid}.png"
        images.write(out, result.passes)
        rows.append(f"| `{sid}` | {space.geometry.name} | ![{sid}](docs/{out.name}) |")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
