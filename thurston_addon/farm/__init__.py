"""Render farms: one render or one .blend file's frames split into Ray tasks (tiles of a frame,
sample passes of a frame, frames of an animation) on a Ray cluster, merged into the image a single
process renders, kept part by part so that a stopped job resumes. Ray (the 'farm' extra) is
imported only when a farm runs (cluster.py). This module re-exports the public API."""

from .cluster import FarmError, parse_address
from .jobs import Job, Part, split
from .merge import merge
from .run import render

__all__ = ["FarmError", "Job", "Part", "merge", "parse_address", "render", "split"]
