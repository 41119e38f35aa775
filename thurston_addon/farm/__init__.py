"""Render farms: one render or one .blend file's frames split into Ray tasks (tiles of a frame,
sample passes of a frame; a .blend file's frames: blender/farm_frames.py) on a Ray cluster, merged into the image a single
process renders, kept part by part so that a stopped job resumes. Ray (the 'farm' extra) is
imported only when a farm runs (cluster.py). This module re-exports the public API."""

from .cluster import FarmError, connected, parse_address
from .jobs import Job, Part, split
from .merge import merge
from .run import Line, render, run_tasks

__all__ = ["FarmError", "Job", "Line", "Part", "connected", "merge", "parse_address", "render", "run_tasks", "split"]
