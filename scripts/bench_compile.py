"""The simulation loop's first-call (compile) time against its cached load, in one run.

A child process with an empty numba cache (a temporary NUMBA_CACHE_DIR) advances one short
segment through each path of ``simulation.run_segment``: one run, runs split one per task or
HALF_LANES per task over the threads (when there are two or more), and more than LANES runs;
then a second child does the same with the cache the first one wrote. Each child prints the
wall time (s) of each path's first call; the first child's is the compile, the second's the
load from disk. Since run_segment calls simulation.compile_loop(), the first path's call
compiles (or loads) both kernels and the later paths' first calls only run. Prints one JSON
line: cold and cached seconds per path, their totals and the ratio.

    PYTHONPATH=. .venv/bin/python scripts/bench_compile.py        (about 3 minutes)
"""

import json
import os
import subprocess
import sys
import tempfile
import time

#: Batches that take each path of run_segment (with two or more threads for the middle two).
PATHS = {"one_run": 1, "one_per_task": 3, "half_lanes_per_task": 6, "lanes_per_task": 11}

CHILD = """
import json, sys, time
import numpy as np
from inertia_gym.scenario import Scenario
from inertia_gym.simulation import initial_state, run_segment
sc = Scenario()
walls = {}
for name, batch in json.loads(sys.argv[1]).items():
    rngs = [np.random.default_rng(r) for r in range(batch)]
    state = initial_state(sc, rngs)
    start = time.perf_counter()
    run_segment(sc, state, 50, np.tile([[[5, 20]]], (batch, 1, 1)), [0.3, 2.0, 1.0],
                [1.0, 0.0, 0.0], rngs)
    walls[name] = time.perf_counter() - start
print(json.dumps(walls))
"""


def first_calls(cache_dir: str) -> dict[str, float]:
    """Seconds of each path's first call in a fresh process using `cache_dir`."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    out = subprocess.run([sys.executable, "-c", CHILD, json.dumps(PATHS)], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    with tempfile.TemporaryDirectory(prefix="inertia-gym-bench-compile-") as cache_dir:
        t0 = time.perf_counter()
        cold = first_calls(cache_dir)
        cold_wall = time.perf_counter() - t0
        cached = first_calls(cache_dir)
    print(json.dumps({
        "cold_s": {k: round(v, 2) for k, v in cold.items()},
        "cached_s": {k: round(v, 3) for k, v in cached.items()},
        "cold_total_s": round(sum(cold.values()), 1),
        "cold_process_wall_s": round(cold_wall, 1),
        "cached_total_s": round(sum(cached.values()), 2),
        "cold_over_cached": round(sum(cold.values()) / sum(cached.values()), 1),
    }))


if __name__ == "__main__":
    main()
