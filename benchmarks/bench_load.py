"""Space load time against the number of generators (not a test): the torus's three translations
and their inverses repeated under new names, so that every list has the same group and domain, and
the work that grows with the list is what is measured (issue 21: 5002 generators took over 8
minutes before repeats were dropped ahead of the shortening's pairwise work). Prints a row per
count: generators, the median load time of a few loads, the time per generator added beyond the
smallest list and its ratio to the second row's (near 1: linear). The counts are interleaved over
the repeats.
Run: .venv/bin/python benchmarks/bench_load.py [--counts 10,100,1000,5000] [--repeats 3]
"""

import argparse
import time

import numpy as np

from thurston_addon import spaces


def space_data(count: int) -> dict:
    """A torus space file's fields with `count` generators (at least 6): its three translations
    and their inverses, repeated under new names."""
    torus = spaces.load("torus")
    base = [M for M in torus.generators] + [np.linalg.inv(M) for M in torus.generators]
    gens = [{"name": f"g{k}", "matrix": base[k % len(base)].tolist()} for k in range(count)]
    return {"geometry": "E3", "generator": gens}


def load_seconds(data: dict) -> float:
    start = time.perf_counter()
    space = spaces.from_data(data, "repeated")
    space.domain.covectors()
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", default="10,100,1000,5000")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    counts = [int(c) for c in args.counts.split(",")]
    data = {n: space_data(n) for n in counts}
    times = {n: [] for n in counts}
    for _ in range(args.repeats):
        for n in counts:  # interleaved: a slow moment of the machine falls on every count alike
            times[n].append(load_seconds(data[n]))
    # the cost of each generator beyond the smallest list's (its fixed cost: the domain, the checks)
    base_n, base_t = counts[0], float(np.median(times[counts[0]]))
    print("| generators | load (s) | per added generator (ms) | ratio to the second row's |")
    print("|---|---|---|---|")
    first = None
    for n in counts:
        t = float(np.median(times[n]))
        if n == base_n:
            print(f"| {n} | {t:.3f} | (the base) | |")
            continue
        per = (t - base_t) / (n - base_n)
        first = first or per
        print(f"| {n} | {t:.3f} | {per * 1e3:.3f} | {per / first:.2f} |")


if __name__ == "__main__":
    main()
