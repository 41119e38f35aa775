"""SnapPy's closed census loaded as spaces (not a test): each manifold of OrientableClosedCensus
through `spaces.load("snappy:closed:N")` into a fresh cache folder (SnapPy's Dirichlet domain, the
space file written, loaded and validated, checked against SnapPy's volume, relations and homology).
Prints how many load, in which precision, the time each takes (median, 90th percentile, largest),
the slowest, and why any fails.
Run: .venv/bin/python benchmarks/bench_census.py [--step 1] [--start 0] [--stop 11031] [--log FILE]
(--step 20 loads every 20th manifold: a sample of 552, a few minutes on one core). With --log each
manifold's result is appended to FILE as it comes (one JSON line), so disjoint slices can run side
by side and be stopped at any time; `--summarize FILE...` prints the table of what the logs hold.
"""

import argparse
import collections
import json
import os
import re
import tempfile
import time

import numpy as np


def load_all(indices, log):
    """One record per manifold: index, name, seconds, precision (None: failed), why."""
    import snappy

    from thurston_addon import spaces

    records = []
    with tempfile.TemporaryDirectory() as cache:
        os.environ["THURSTON_CACHE_DIR"] = cache
        began = time.perf_counter()
        for k, i in enumerate(indices):
            record = {"index": i, "name": str(snappy.OrientableClosedCensus[i])}
            t0 = time.perf_counter()
            try:
                space = spaces.load(f"snappy:closed:{i}")
            except spaces.SpaceError as exc:
                record.update(precision=None, why=str(exc).split(": ", 1)[-1][:140])
            else:
                with open(space.source) as f:
                    head = [f.readline(), f.readline()]
                quad = "quad-double" in head[0]
                why = re.sub(r"^.*?snappy:closed:\d+( \(double precision\))?: ", "", head[1]).strip()
                record.update(
                    seconds=time.perf_counter() - t0,
                    precision="quad-double" if quad else "double",
                    faces=len(space.domain.faces),
                    # why double precision was not enough, grouped: numbers and names as #
                    why=re.sub(r"'g\d+'|\d[\d.e+-]*", "#", why)[:120] if quad else None,
                )
            records.append(record)
            if log:
                with open(log, "a") as f:
                    f.write(json.dumps(record) + "\n")
            if (k + 1) % 100 == 0:
                print(f"  {k + 1}/{len(indices)} in {time.perf_counter() - began:.0f} s", flush=True)
    return records


def summarize(records, title):
    loaded = [r for r in records if r["precision"]]
    failed = [r for r in records if not r["precision"]]
    t = np.array([r["seconds"] for r in loaded]) if loaded else np.zeros(1)
    count = collections.Counter(r["precision"] for r in loaded)
    print(f"\n{title} ({len(records)} manifolds)")
    print("| asked | loaded | double | quad-double | failed | median s | p90 s | max s | total s |")
    print("|---|---|---|---|---|---|---|---|---|")
    print(
        f"| {len(records)} | {len(loaded)} | {count['double']} | {count['quad-double']} | {len(failed)} | "
        f"{np.median(t):.3f} | {np.percentile(t, 90):.3f} | {t.max():.3f} | {t.sum():.0f} |"
    )
    print("\nslowest:\n| index | name | faces | s |\n|---|---|---|---|")
    for r in sorted(loaded, key=lambda r: -r["seconds"])[:8]:
        print(f"| {r['index']} | {r['name']} | {r['faces']} | {r['seconds']:.3f} |")
    fallbacks = collections.Counter(r["why"] for r in loaded if r["why"])
    if fallbacks:
        print("\nwhy double precision was not enough (then quad-double passed):\n| count | reason |\n|---|---|")
        for why, n in fallbacks.most_common():
            print(f"| {n} | {why} |")
    failures = collections.defaultdict(list)
    for r in failed:
        failures[r["why"]].append(f"{r['index']} {r['name']}")
    if failures:
        print("\nfailures:\n| count | reason | first ones |\n|---|---|---|")
        for reason, which in sorted(failures.items(), key=lambda kv: -len(kv[1])):
            print(f"| {len(which)} | {reason} | {', '.join(which[:3])} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--start", type=int, default=0)
    parser.add_argument("--stop", type=int, default=11031)
    parser.add_argument("--step", type=int, default=1, help="load every step-th manifold (1: all of them)")
    parser.add_argument("--log", help="append each manifold's result to this file (JSON lines)")
    parser.add_argument("--summarize", nargs="+", metavar="LOG", help="print the table of these logs, load nothing")
    args = parser.parse_args()
    if args.summarize:
        records = {}
        for path in args.summarize:
            with open(path) as f:
                records.update((r["index"], r) for r in map(json.loads, f))
        summarize(sorted(records.values(), key=lambda r: r["index"]), f"closed census: the logs {args.summarize}")
        return
    import snappy

    indices = range(args.start, min(args.stop, len(snappy.OrientableClosedCensus)), args.step)
    records = load_all(indices, args.log)
    summarize(records, f"SnapPy {snappy.__version__}: closed census {args.start}:{args.stop}:{args.step}")


if __name__ == "__main__":
    main()
