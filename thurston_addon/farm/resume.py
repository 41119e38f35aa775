"""The parts of a job finished so far, kept beside its output in a folder named by the job's key
(.OUTPUT.farm-KEY), so that a stopped job started again with the same arguments renders only the
rest; another job's folder for the same output (a changed scene or setting) is removed at the
start, and the job's own once its output is written."""

from __future__ import annotations

import glob
import io
import json
import shutil
from pathlib import Path

import numpy as np

from .. import files


class Kept:
    def __init__(self, out: Path, key: str):
        self.out = Path(out)
        self.folder = self.out.parent / f".{self.out.name}.farm-{key}"

    def start(self) -> dict[int, dict]:
        """The parts this job finished before (by index); other jobs' parts for this output removed."""
        for other in self.out.parent.glob(f".{glob.escape(self.out.name)}.farm-*"):
            if other != self.folder and other.is_dir():
                shutil.rmtree(other, ignore_errors=True)
        kept = {}
        for path in sorted(self.folder.glob("part-*.npz")):
            try:
                kept[int(path.stem.removeprefix("part-"))] = _read(path)
            except (OSError, ValueError, KeyError):
                continue  # unreadable: rendered again
        return kept

    def keep(self, index: int, result: dict):
        """One finished part, written whole or not at all."""
        try:
            self.folder.mkdir(exist_ok=True)
        except OSError as exc:
            raise files.OutputError(f"cannot keep the finished parts in {str(self.folder)!r}: {exc.strerror}") from None
        buffer = io.BytesIO()
        arrays = {f"a:{name}": a for name, a in result["arrays"].items()}
        np.savez(buffer, stats=np.array(json.dumps(result["stats"], default=_plain)), **arrays)
        files.write_bytes(self.folder / f"part-{index}.npz", buffer.getbuffer(), overwrite=True)

    def clear(self):
        shutil.rmtree(self.folder, ignore_errors=True)


def _read(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        arrays = {name.removeprefix("a:"): z[name] for name in z.files if name.startswith("a:")}
        return {"arrays": arrays, "stats": json.loads(str(z["stats"]))}


def _plain(value):
    """numpy scalars as JSON numbers."""
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON")
