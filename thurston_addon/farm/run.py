"""A farm's driver: a render split into parts, the job put once in Ray's object store, one task
per part not kept from an earlier run, one progress line for the job, the parts kept as they
finish and merged; Ctrl-C (or a failure) cancels every task."""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

from .. import render as single
from . import cluster, work
from .jobs import Job, split
from .merge import merge, pooled, still_sampling
from .resume import Kept

# a task whose worker process dies is run again (elsewhere, or on a new worker) up to this often
RETRIES = 3
DEFAULT_TILES = 16


def render(
    space,
    scene,
    settings: single.Settings,
    camera,
    address: str,
    out: Path,
    tiles: int | None = None,
    sample_passes: int = 1,
    write=None,
    progress=None,
) -> single.Result:
    """The render render.render(space, scene, settings, camera) gives, by tasks on the Ray cluster
    of `address` (cluster.parse_address), passed to write(result), which writes `out`; the finished
    parts are kept beside `out` until it is written. progress(done, total, busy) is called as
    parts finish (default: one line on stderr)."""
    cluster.parse_address(address)  # refused before anything is kept
    settings.check()
    single.camera_frame(space, camera)  # a camera that cannot be used is refused before the cluster starts
    tiles = tiles or (1 if sample_passes > 1 else min(DEFAULT_TILES, settings.height))
    parts = split(settings, tiles, sample_passes)
    job = Job(space, scene, settings, camera)
    key = job.key(parts)
    kept = Kept(out, key)
    results = kept.start()

    def samples() -> str:  # the progress line's detail
        n = settings.samples_per_pixel
        if parts[0].region is not None:
            return f"{n} samples/pixel"
        return f"{sum(len(p.samples) for p in parts if p.index in results)}/{n} samples/pixel"

    progress = progress or Line(parts[0].plural, samples)
    seconds = 0.0  # the job's time on the cluster (from its start, or joining it, to the last part)
    if any(p.index not in results for p in parts):
        with cluster.connected(address):
            t0 = time.perf_counter()
            active = None  # adaptive sampling over rounds: the pixels still taking samples
            for r in range(parts[-1].round + 1):
                if r > 0:
                    active = still_sampling(settings, pooled(parts, results), active)
                    if not active.any():
                        break  # every pixel has stopped: the later rounds are not needed
                todo = [p for p in parts if p.round == r and p.index not in results]
                if todo:
                    _run(job, key, todo, active, results, kept, len(parts), progress)
            seconds = time.perf_counter() - t0
    progress(len(parts), len(parts), 0)
    result = merge(job, parts, results, seconds)
    if write is not None:
        write(result)
    kept.clear()
    return result


def _run(job, key, todo, active, results, kept, total, progress):
    threads = job.settings.threads or 1  # each task one slot's CPUs, not the whole machine's
    shared = dataclasses.replace(job, settings=dataclasses.replace(job.settings, threads=threads))

    def finished(part, result):
        kept.keep(part.index, result)
        results[part.index] = result

    run_tasks(
        work.render_part,
        shared,
        [((key, part, active), part) for part in todo],
        finished,
        threads,
        lambda busy: progress(len(results), total, busy),
    )


def run_tasks(function, shared, calls, finished, cpus: int, report):
    """function(shared, *args) for each (args, part) of `calls` as Ray tasks of `cpus` CPUs each,
    `shared` put in the object store once; finished(part, result) as each ends (on this thread),
    report(workers busy) after; a task whose worker dies is run again. Ctrl-C or a failure
    cancels every task still running."""
    ray = cluster.import_ray()
    task = ray.remote(function).options(num_cpus=cpus, max_retries=RETRIES)
    ref = ray.put(shared)
    running = {task.remote(ref, *args): part for args, part in calls}
    try:
        while running:
            done, _ = ray.wait(list(running), num_returns=1, timeout=0.5)
            for r in done:
                part = running.pop(r)
                try:
                    result = ray.get(r)
                except ray.exceptions.RayTaskError as exc:
                    raise cluster.FarmError(f"{part.label} {part.index}: {exc.cause}") from None
                except ray.exceptions.RayError as exc:
                    raise cluster.FarmError(f"{part.label} {part.index} failed on the cluster: {exc}") from None
                finished(part, result)
            report(cluster.cpus_busy() // cpus)
    finally:
        for r in running:  # no task left running for nothing
            ray.cancel(r, force=True)


class Line:
    """One progress line for the job on stderr: parts done, detail() (the samples), workers busy,
    time, ETA (redrawn on a terminal; in a log, a line per finished part)."""

    def __init__(self, label: str, detail=None):
        self.label, self.detail, self.start, self.done = label, detail, time.perf_counter(), -1
        self.tty = sys.stderr.isatty()

    def __call__(self, done: int, total: int, busy: int):
        if done == self.done and not self.tty:
            return
        self.done = done
        busy = 0 if done == total else busy  # (the cluster's count of held CPUs lags the last part)
        elapsed = time.perf_counter() - self.start
        eta = f", ETA {elapsed / done * (total - done):.0f} s" if 0 < done < total else ""
        detail = f" ({self.detail()})" if self.detail else ""
        line = f"farm: {done}/{total} {self.label}{detail}, {busy} workers busy, {elapsed:.1f} s{eta}"
        print(f"{line:<80}", end="\r" if self.tty and done < total else "\n", file=sys.stderr, flush=True)
