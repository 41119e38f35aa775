"""What the benchmarks share: the least time of repeated runs (the run least disturbed by the
machine's other work), and another build of the core or the add-on in place of the installed one."""

import importlib.util
import math
import sys
import time


def load_core(path):
    """Use the core built at `path` instead of the installed one (before anything imports it)."""
    spec = importlib.util.spec_from_file_location("thurston_core", path)
    core = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(core)
    sys.modules["thurston_core"] = core
    return core


def use_build(build):
    """Import thurston_addon (and thurston_core, if it holds one) from the folder `build`, not from
    this (editable) checkout; before anything imports them."""
    sys.meta_path[:] = [f for f in sys.meta_path if "Redirecting" not in type(f).__name__]  # the editable install
    sys.path.insert(0, build)


def best_of(repeat, fn):
    """(least seconds, last result) over repeat calls of fn."""
    (best,), (out,) = least_interleaved([fn], repeat, time.perf_counter)
    return best, out


def least_interleaved(runs, repeat, clock=time.process_time):
    """([least seconds of each zero-argument run], [its last result]): the runs called in turn,
    repeat times (interleaved, so that a drift of the machine's load falls on each alike), timed by
    `clock`: by default process CPU time (all threads; descheduling by other loads does not count)."""
    best, results = [math.inf] * len(runs), [None] * len(runs)
    for _ in range(repeat):
        for i, run in enumerate(runs):
            t = clock()
            results[i] = run()
            best[i] = min(best[i], clock() - t)
    return best, results
