"""A render farm on this machine: 1 and 2 Ray workers (`--cluster local:N`) against the single-process
render (one thread, as each worker's task), for tiles and sample passes: the job's time on the
cluster (from joining it to the last part; the cluster's start and stop apart), the overhead per
task, and the bytes shipped per task. Wall times, the least of the repeats, the runs interleaved.
Prints a table (docs/farm.md)."""

import argparse
import math
import pickle
import tempfile
import time
from pathlib import Path

from thurston_addon import farm, render, scenes, spaces
from thurston_addon.farm import work


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--size", default="320x180")
    p.add_argument("--samples", type=int, default=8)
    p.add_argument("--repeat", type=int, default=2)
    args = p.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    space = spaces.load("torus")
    scene = scenes.default_scene(space)
    c = space.camera
    camera = scenes.Camera(c.position, c.forward, c.up, c.fov)
    settings = render.Settings(width=w, height=h, samples=args.samples, bounces=1, light_paths=0, threads=1)
    out = Path(tempfile.mkdtemp()) / "bench.exr"
    splits = {"tiles": dict(tiles=8), "sample passes": dict(sample_passes=8)}

    def single():
        t = time.perf_counter()
        render.render(space, scene, settings, camera)
        return time.perf_counter() - t, 0.0

    def start_stop():
        t = time.perf_counter()
        with farm.connected("local:2"):
            pass
        return time.perf_counter() - t, 0.0

    def on(address, split):
        def run():
            t = time.perf_counter()
            result = farm.render(space, scene, settings, camera, address, out, progress=lambda *a: None, **split)
            return time.perf_counter() - t, result.stats["seconds"]

        return run

    runs = {("single process", 1): single, ("cluster start and stop", 2): start_stop}
    for name, split in splits.items():
        for n in (1, 2):
            runs[(name, n)] = on(f"local:{n}", split)
    best = {k: (math.inf, math.inf) for k in runs}
    for _ in range(args.repeat):  # interleaved: the machine's drifting load falls on each alike
        for k, run in runs.items():
            wall, work_seconds = run()
            best[k] = (min(best[k][0], wall), min(best[k][1], work_seconds))
    one = best[("single process", 1)][0]
    print(
        f"torus {w}x{h}, {args.samples} samples, 1 bounce, light paths 0; single process (1 thread): {one:.2f} s; "
        f"a local cluster's start and stop: {best[('cluster start and stop', 2)][0]:.2f} s\n"
    )
    print(
        "| split | workers | tasks | job, wall (s) | on the cluster (s) | speed-up on the cluster | overhead per task (s) | bytes per task: job (once), part, result |"
    )
    print("|---|---|---|---|---|---|---|---|")
    job = farm.Job(space, scene, settings, camera)
    job_bytes = len(pickle.dumps(job, protocol=5))
    for name, split in splits.items():
        parts = farm.split(settings, split.get("tiles", 1), split.get("sample_passes", 1))
        result_bytes = len(pickle.dumps(work.render_part(job, "bench", parts[-1]), protocol=5))
        part_bytes = len(pickle.dumps(parts[-1], protocol=5))
        for n in (1, 2):
            wall, on_cluster = best[(name, n)]
            # each of n workers runs len(parts) / n tasks: the time beyond the work, per task
            overhead = (on_cluster - one / n) / (len(parts) / n)
            print(
                f"| {name} | {n} | {len(parts)} | {wall:.2f} | {on_cluster:.2f} | {one / on_cluster:.2f} | "
                f"{overhead:.3f} | {job_bytes}, {part_bytes}, {result_bytes} |"
            )


if __name__ == "__main__":
    main()
