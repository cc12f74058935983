"""Memory wrapper: ``python -m bench.child OVERRIDE ...`` runs ``python -m framework.run`` once.

Prints one line ``BENCH_CHILD {json}`` with the job's peak RSS from
``resource.getrusage(RUSAGE_CHILDREN)`` after it exits (the largest single process among the
job and the descendants it waited for), the peak of the summed RSS of the whole process tree
(sampled every 0.1 s with psutil: counts Dask workers too), the wall time and the exit code.
"""
from __future__ import annotations

import json
import resource
import subprocess
import sys
import time

import psutil


def tree_rss(proc: psutil.Process) -> int:
    """Summed RSS in bytes of ``proc`` and all its descendants (0 for vanished ones)."""
    total = 0
    try:
        procs = [proc, *proc.children(recursive=True)]
    except psutil.Error:
        return 0
    for p in procs:
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass
    return total


def main(overrides: list[str]) -> int:
    """Run the job, sample its tree's RSS, print the ``BENCH_CHILD`` line; return its exit code."""
    t0 = time.perf_counter()
    job = subprocess.Popen([sys.executable, "-m", "framework.run", *overrides],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    ps, peak_tree = psutil.Process(job.pid), 0
    while job.poll() is None:
        peak_tree = max(peak_tree, tree_rss(ps))
        time.sleep(0.1)
    err = job.stderr.read()
    wall = time.perf_counter() - t0
    peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    print("BENCH_CHILD " + json.dumps({"rc": job.returncode, "wall_s": wall, "maxrss_mib": peak_kb / 1024,
                                       "tree_peak_mib": peak_tree / 2**20, "stderr_tail": err[-2000:]}))
    return job.returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
