"""Cold first use of each estimator against the import of its dependencies, side by side.

A researcher's first ``identify`` pays numba's compilation of the estimator's kernels.
Each figure here is one fresh process with numba's on-disk cache pointed at an empty
folder (a fresh clone's first run; a member with a C port builds it there, in a child
process counted too), timed as CPU seconds of that process and its children:

- ``import numpy, scipy, gymnasium``: the floor any tool on this stack pays;
- ``import manualcontrol.estimators``: what importing the family adds;
- per estimator: import, one ``estimate`` of a 30-s simulated run (compiling its
  kernels), then a second ``estimate`` in the same process (the compiled speed);
- per estimator again, a fresh process on the cache the first one filled: first use
  after ``make`` has compiled the kernels at install (``bench.compile_kernels``).

The ratios are against the dependencies' import measured in the same run (hosts differ
by 3-4x in absolute speed). The recording is simulated once, in a warm process, and
saved to a temporary file each cold process loads: a precision pilot's run, a drive for
the driver-model filters, and for Schiess-Roland a run of its own pilot on its paper's
task besides (on the precision pilot's run its filter diverges after 5.5 s, and the
exact flow of eqs. 7-12 splits its last samples before the stop into ever more
substeps, 2^20 in the last one: a second and a half of arithmetic, no compilation,
which the rows show apart).

Run: .venv/bin/python benchmarks/first_use.py [--estimators dekf,rml,...] [--repeats N]
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

DEFAULT = "dekf,rml,joint-ukf,dual-ukf,rdi,schiess-roland,zhao-ukf"

IMPORT_ONLY = """
import resource
import numpy, scipy, gymnasium
usage = resource.getrusage(resource.RUSAGE_SELF)
print(usage.ru_utime + usage.ru_stime)
"""

IMPORT_FAMILY = """
import resource
import manualcontrol.estimators
usage = resource.getrusage(resource.RUSAGE_SELF)
print(usage.ru_utime + usage.ru_stime)
"""

FIRST_USE = """
import resource, sys, time, warnings
warnings.simplefilter("ignore")
def cpu():  # the process and its children (a C compiler building a member's C port)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime + children.ru_utime + children.ru_stime
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators import make_estimator
recording = Recording.load(sys.argv[2])
estimator = make_estimator({"name": sys.argv[1]})
start = cpu()
estimator.estimate(recording)
first = cpu() - start
start = time.perf_counter()
estimator.estimate(recording)
print(cpu(), first, time.perf_counter() - start)
"""

SIMULATE = """
import sys, warnings
warnings.simplefilter("ignore")
from manualcontrol.pilots import Pilot, simulate
from manualcontrol.pilots.driver import Driver
from manualcontrol.pilots.driving import simulate_driving
simulate(Pilot("precision"), "popovici2017", "popovici2017", seed=0,
         measurement_time=30.0).save(sys.argv[1])
simulate_driving(Driver(), measurement_time=30.0).save(sys.argv[2])
simulate(Pilot("schiess-roland"), "schiess-roland1975", "schiess-roland1975", seed=0,
         measurement_time=30.0).save(sys.argv[3])
"""


def run(code, *args, cache=None):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = cache
    out = subprocess.run(
        [sys.executable, "-c", code, *args], env=env, capture_output=True, text=True, check=False
    )
    if out.returncode != 0:
        raise RuntimeError(out.stderr.strip().splitlines()[-1])
    return [float(x) for x in out.stdout.split()]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--estimators", default=DEFAULT)
    parser.add_argument("--repeats", type=int, default=3, help="fresh processes per import figure")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        tracking, driving = str(Path(folder) / "run.npz"), str(Path(folder) / "drive.npz")
        own_task = str(Path(folder) / "schiess_roland.npz")
        run(SIMULATE, tracking, driving, own_task)
        floor = statistics.median(run(IMPORT_ONLY)[0] for _ in range(args.repeats))
        family = statistics.median(run(IMPORT_FAMILY)[0] for _ in range(args.repeats))
        rows = {"import numpy, scipy, gymnasium": (floor, None, None)}
        rows["import manualcontrol.estimators"] = (family, None, None)
        cases = []
        for name in args.estimators.split(","):
            cases.append((name, name, driving if name.startswith("zhao") else tracking))
            if name == "schiess-roland":
                cases.append((f"{name} (own task)", name, own_task))
        for label, name, recording in cases:
            cache = tempfile.mkdtemp(dir=folder)
            try:
                total, first, warm = run(FIRST_USE, name, recording, cache=cache)
                installed = run(FIRST_USE, name, recording, cache=cache)
            except RuntimeError as error:
                print(f"{label}: {error}", file=sys.stderr)
                continue
            rows[f"{label}: cold process"] = (total, first, warm)
            rows[f"{label}: after install"] = tuple(installed)
    width = max(map(len, rows))
    print(f"{'CPU s':>{width + 10}} {'x import':>9} {'estimate':>9} {'warm run':>9}")
    for label, (total, first, warm) in rows.items():
        extra = "" if first is None else f" {first:9.2f} {warm:9.3f}"
        print(f"{label:{width}} {total:9.2f} {total / floor:9.1f}{extra}")
    print(json.dumps({label: values[0] for label, values in rows.items()}))


if __name__ == "__main__":
    main()
