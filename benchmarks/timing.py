"""What the benchmarks share: the least time of repeated runs (the run least disturbed by the
machine's other work)."""
import math
import time


def best_of(repeat, fn):
    """(least seconds, last result) over repeat calls of fn."""
    best, out = math.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out
