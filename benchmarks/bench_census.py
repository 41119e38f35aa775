"""SnapPy's closed census loaded as spaces (not a test): each manifold of OrientableClosedCensus
through `spaces.load("snappy:closed:N")` into a fresh cache folder (SnapPy's Dirichlet domain, the
space file written, loaded and validated, checked against SnapPy's volume, relations and homology).
Prints how many load, in which precision, the time each takes (median, 90th percentile, largest),
the slowest, and why any fails.
Run: .venv/bin/python benchmarks/bench_census.py [--step 1] [--start 0] [--stop 11031]
(--step 20 loads every 20th manifold: a sample of 552, a few minutes on one core)
"""

import argparse
import collections
import os
import re
import tempfile
import time

import numpy as np
import snappy

from thurston_addon import spaces


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--start", type=int, default=0)
    parser.add_argument("--stop", type=int, default=len(snappy.OrientableClosedCensus))
    parser.add_argument("--step", type=int, default=1, help="load every step-th manifold (1: all of them)")
    args = parser.parse_args()
    indices = range(args.start, min(args.stop, len(snappy.OrientableClosedCensus)), args.step)
    times, precisions, failures, slowest = [], collections.Counter(), collections.defaultdict(list), []
    fallbacks = collections.Counter()  # why double precision was not enough
    with tempfile.TemporaryDirectory() as cache:
        os.environ["THURSTON_CACHE_DIR"] = cache
        began = time.perf_counter()
        for k, i in enumerate(indices):
            name = str(snappy.OrientableClosedCensus[i])
            t0 = time.perf_counter()
            try:
                space = spaces.load(f"snappy:closed:{i}")
            except spaces.SpaceError as exc:
                reason = str(exc).split(": ", 1)[-1]
                failures[reason[:140]].append(f"{i} {name}")
                continue
            dt = time.perf_counter() - t0
            times.append(dt)
            with open(space.source) as f:
                head = [f.readline(), f.readline()]
            if "quad-double" in head[0]:
                precisions["quad-double"] += 1
                why = re.sub(r"^.*?snappy:closed:\d+( \(double precision\))?: ", "", head[1]).strip()
                fallbacks[re.sub(r"'g\d+'|\d[\d.e+-]*", "#", why)[:120]] += 1  # grouped: numbers and names as #
            else:
                precisions["double"] += 1
            slowest.append((dt, i, name, len(space.domain.faces)))
            if (k + 1) % 100 == 0:
                print(f"  {k + 1}/{len(indices)} in {time.perf_counter() - began:.0f} s", flush=True)
        total = time.perf_counter() - began
    t = np.array(times) if times else np.zeros(1)
    print(
        f"\nSnapPy {snappy.__version__}: closed census {args.start}:{args.stop}:{args.step} ({len(indices)} manifolds)"
    )
    print("| asked | loaded | double | quad-double | failed | median s | p90 s | max s | total s |")
    print("|---|---|---|---|---|---|---|---|---|")
    print(
        f"| {len(indices)} | {len(times)} | {precisions['double']} | {precisions['quad-double']} | "
        f"{sum(map(len, failures.values()))} | {np.median(t):.3f} | {np.percentile(t, 90):.3f} | "
        f"{t.max():.3f} | {total:.0f} |"
    )
    print("\nslowest:\n| index | name | faces | s |\n|---|---|---|---|")
    for dt, i, name, faces in sorted(slowest, reverse=True)[:8]:
        print(f"| {i} | {name} | {faces} | {dt:.3f} |")
    if fallbacks:
        print("\nwhy double precision was not enough (then quad-double passed):\n| count | reason |\n|---|---|")
        for why, n in fallbacks.most_common():
            print(f"| {n} | {why} |")
    if failures:
        print("\nfailures:\n| count | reason | first ones |\n|---|---|---|")
        for reason, which in sorted(failures.items(), key=lambda kv: -len(kv[1])):
            print(f"| {len(which)} | {reason} | {', '.join(which[:3])} |")


if __name__ == "__main__":
    main()
