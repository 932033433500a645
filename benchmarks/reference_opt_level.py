"""The numba reference at two LLVM optimisation levels: compile time, speed, and the bytes.

The numba kernels a C port replaces are compiled by ``make test`` before pytest
(``python -m manualcontrol.bench.compile_kernels --numba-reference``), at
``REFERENCE_OPT_LEVEL`` unless ``NUMBA_OPT`` names one. For each level given, round-robin
over the repeats, each in fresh processes on an empty numba cache folder of its own:

- the install step's kernels are compiled first (not timed: a fresh clone has them
  from its install step);
- the reference is compiled and timed: wall seconds, and CPU seconds of its processes;
- each member's numba ``estimate`` of a 60-s simulated run is timed (the C ports off,
  the kernels just compiled loaded from the cache; median of 5 after one warm-up), and
  the bytes of its estimate hashed.

It prints the medians per level, the ratio of each to the first level's, and whether
every member's estimate has the same bytes at every level.

Run: .venv/bin/python benchmarks/reference_opt_level.py [--levels 3,1] [--repeats N]
"""

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

MEMBERS = (
    "dekf",
    "rml",
    "joint-ukf",
    "dual-ukf",
    "schiess-roland",
    "zhao-ukf",
    "zhao-multi-ukf",
    "rdi",
)

#: Run in a fresh process on the level's cache: each member's numba estimate, timed and hashed.
STEADY = """
import hashlib, json, statistics, sys, time
import numpy as np
from manualcontrol.estimators.registry import make_estimator
from manualcontrol.pilots import Pilot, simulate
from manualcontrol.pilots.driver import Driver
from manualcontrol.pilots.driving import simulate_driving

def recording_for(name):
    if name.startswith("zhao"):
        return simulate_driving(Driver(), measurement_time=60.0, seed=0)
    if name == "schiess-roland":  # its own pilot and task: on the precision pilot's it stops
        return simulate(Pilot("schiess-roland"), "schiess-roland1975", "schiess-roland1975",
                        run_in=0.0, measurement_time=60.0, seed=0,
                        measurement_noise={"u": 0.00092, "y": 0.00092})
    return simulate(Pilot("precision"), "popovici2017", "popovici2017", measurement_time=60.0,
                    seed=0)

out = {}
for name in sys.argv[1].split(","):
    recording = recording_for(name)
    result = make_estimator({"name": name}).estimate(recording)
    seconds = []
    for _ in range(5):
        start = time.process_time()
        make_estimator({"name": name}).estimate(recording)
        seconds.append(time.process_time() - start)
    digest = hashlib.sha256()
    for field in ("mean", "std", "predictions", "innovations", "innovation_covariance",
                  "finite", "covariance_ok", "dropped", "diverged", "pinned", "states"):
        digest.update(np.ascontiguousarray(getattr(result, field)).tobytes())
    out[name] = [statistics.median(seconds), digest.hexdigest()]
print(json.dumps(out))
"""


def children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run(argv, env):
    before, start = children_cpu(), time.perf_counter()
    result = subprocess.run(argv, env=env, capture_output=True, text=True)
    if result.returncode != 0:
        sys.exit(f"{' '.join(argv[:4])} failed:\n{result.stdout}\n{result.stderr}")
    return time.perf_counter() - start, children_cpu() - before, result.stdout


def one_level(level, folder):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(folder), "OPENBLAS_NUM_THREADS": "1"}
    env.pop("NUMBA_OPT", None)
    compile_kernels = [sys.executable, "-m", "manualcontrol.bench.compile_kernels"]
    run(compile_kernels, env)  # the install step's kernels, at numba's default level
    wall, cpu, _ = run([*compile_kernels, "--numba-reference"], {**env, "NUMBA_OPT": level})
    _, _, printed = run(
        [sys.executable, "-c", STEADY, ",".join(MEMBERS)], {**env, "MANUALCONTROL_NATIVE": "0"}
    )
    return wall, cpu, json.loads(printed.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", default="3,1", help="NUMBA_OPT levels, the first the base")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    levels = args.levels.split(",")
    runs = {level: [] for level in levels}
    with tempfile.TemporaryDirectory() as root:
        for repeat in range(args.repeats):
            for level in levels:
                folder = Path(root) / f"level{level}-{repeat}"
                runs[level].append(one_level(level, folder))
                wall, cpu, _ = runs[level][-1]
                print(
                    f"  NUMBA_OPT={level} run {repeat + 1}: reference {wall:.0f} s, {cpu:.0f} CPU-s"
                )
    base = levels[0]

    def median_of(level, pick):
        return statistics.median(pick(one) for one in runs[level])

    print(f"\nmedians of {args.repeats}; ratio to NUMBA_OPT={base}")
    print(f"{'':34}" + "".join(f"{'NUMBA_OPT=' + level:>22}" for level in levels))
    rows = [
        ("reference compile, wall s", lambda one: one[0]),
        ("reference compile, CPU s", lambda one: one[1]),
    ]
    rows += [
        (f"{name} numba estimate, ms", lambda one, name=name: 1000 * one[2][name][0])
        for name in MEMBERS
    ]
    for label, pick in rows:
        cells = []
        for level in levels:
            value = median_of(level, pick)
            cells.append(f"{value:10.1f} ({value / median_of(base, pick):5.2f}x)")
        print(f"{label:34}" + "".join(f"{cell:>22}" for cell in cells))
    digests = {
        name: {one[2][name][1] for level in levels for one in runs[level]} for name in MEMBERS
    }
    differing = [name for name, seen in digests.items() if len(seen) > 1]
    print(
        "estimates: the same bytes at every level"
        if not differing
        else f"estimates DIFFER between levels: {', '.join(differing)}"
    )


if __name__ == "__main__":
    main()
