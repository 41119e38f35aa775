"""A render farm on this machine: 1 and 2 Ray workers (`--cluster local:N`) against the single-process
render (one thread, so that the workers' share is the comparison), for tiles and sample passes;
the time of a cluster's start, the overhead per task and the bytes shipped per task. Wall times,
the least of the repeats, the runs interleaved. Prints a table (docs/farm.md)."""

import argparse
import pickle
import tempfile
import time
from pathlib import Path

from timing import least_interleaved

from thurston_addon import farm, render, scenes, spaces
from thurston_addon.farm import cluster, work


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--size", default="160x90")
    p.add_argument("--repeat", type=int, default=2)
    args = p.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    space = spaces.load("torus")
    scene = scenes.default_scene(space)
    c = space.camera
    camera = scenes.Camera(c.position, c.forward, c.up, c.fov)
    settings = render.Settings(width=w, height=h, samples=8, bounces=1, light_paths=0, threads=1)
    out = Path(tempfile.mkdtemp()) / "bench.exr"
    quiet = lambda *a: None  # noqa: E731

    def on(address, **split):
        return lambda: farm.render(space, scene, settings, camera, address, out, progress=quiet, **split)

    def start_only():
        with cluster.connected("local:2"):
            pass

    splits = {"tiles (8)": dict(tiles=8), "sample passes (8)": dict(sample_passes=8)}
    runs = [lambda: render.render(space, scene, settings, camera), start_only]
    for split in splits.values():
        runs += [on("local:1", **split), on("local:2", **split)]
    best, _ = least_interleaved(runs, args.repeat, time.perf_counter)
    one, start = best[0], best[1]
    print(
        f"torus {w}x{h}, {settings.samples} samples, 1 bounce; single process (1 thread): {one:.2f} s; "
        f"a local cluster's start and stop: {start:.2f} s\n"
    )
    print(
        "| split | workers | job (s) | job less start (s) | speed-up less start | tasks | overhead per task (s) | bytes per task (job, part in, result out) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    job = farm.Job(space, scene, settings, camera)
    job_bytes = len(pickle.dumps(job, protocol=5))
    for k, (name, split) in enumerate(splits.items()):
        parts = farm.split(settings, split.get("tiles", 1), split.get("sample_passes", 1))
        result_bytes = len(pickle.dumps(work.render_part(job, "bench", parts[-1]), protocol=5))
        part_bytes = len(pickle.dumps(parts[-1], protocol=5))
        for n, t in zip((1, 2), best[2 + 2 * k : 4 + 2 * k]):
            net = t - start
            # with n workers each runs len(parts) / n tasks: what the job took beyond the work, per task
            overhead = (net - one / n) / (len(parts) / n)
            print(
                f"| {name} | {n} | {t:.2f} | {net:.2f} | {one / net:.2f} | {len(parts)} | {overhead:.3f} | "
                f"{job_bytes} (once per worker), {part_bytes}, {result_bytes} |"
            )


if __name__ == "__main__":
    main()
