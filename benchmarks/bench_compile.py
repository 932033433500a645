"""What a fresh clone compiles: numba compile time per kernel over the quick suites.

Runs the quick subset of the chosen suites (default: every built-in one, what
``make demo`` runs) in this one process, with numba's on-disk cache pointed at an
empty temporary folder, and records numba's ``numba:compile`` events:

- per top-level kernel (one called from Python), the wall seconds of its compilation,
  its callees included, and when it started;
- nested compilations of numba's own overloads whose names are given with
  ``--watch`` (default: ``raise_with_shape_context``, the shape-error message a slice
  assignment from an array makes numba compile, 3-5 s a process).

The sum of the top-level figures is the compile cost a fresh clone pays once per
process; ``make demo`` splits the suites over its streams (see ``bench.demo``), so
its wall time is about the larger stream's share of this.

Run: .venv/bin/python benchmarks/bench_compile.py [--suite NAME ...]
Old code, for a side-by-side run: PYTHONPATH=<old tree mapped as manualcontrol>.
"""

import argparse
import os
import tempfile
import time
from pathlib import Path


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", action="append", help="only these suites (repeatable)")
    parser.add_argument("--watch", action="append", default=None, help="nested names to list")
    args = parser.parse_args()
    watch = args.watch or ["raise_with_shape_context"]
    with tempfile.TemporaryDirectory() as folder:
        # before numba is imported anywhere: its configuration reads this once
        os.environ["NUMBA_CACHE_DIR"] = str(Path(folder) / "numba")
        run(args.suite, watch, Path(folder) / "results")


def run(suites, watch, out):
    from numba.core import event

    started = time.perf_counter()
    top, nested, open_at = [], [], []

    class Recorder(event.Listener):
        def on_start(self, ev):
            open_at.append(time.perf_counter())

        def on_end(self, ev):
            begun = open_at.pop()
            function = ev.data["dispatcher"].py_func
            name = f"{function.__module__}.{function.__qualname__}"
            seconds = time.perf_counter() - begun
            if not open_at:
                top.append((begun - started, seconds, name))
            elif any(w in name for w in watch):
                nested.append((seconds, name, str(ev.data["args"])))

    event.register("numba:compile", Recorder())
    from manualcontrol.bench.demo import _Collected, _run_stream
    from manualcontrol.bench.scenarios import BUILTIN_SUITES, load_suite

    names = suites or list(BUILTIN_SUITES)
    cpu = time.process_time()
    _run_stream({n: load_suite(n) for n in names}, names, out, False, _Collected(), 1)
    cpu = time.process_time() - cpu
    total = sum(seconds for _, seconds, _ in top)
    print(f"quick suites {', '.join(names)}: {cpu:.1f} CPU-s in all, {total:.1f} s compiling")
    print(f"{'start':>7s} {'compile':>8s}  top-level kernel")
    for begun, seconds, name in top:
        if seconds >= 0.05:
            print(f"{begun:7.1f} {seconds:8.2f}  {name}")
    if nested:
        print("watched nested compilations:")
        for seconds, name, types in nested:
            print(f"        {seconds:8.2f}  {name} {types}")
    else:
        print(f"watched nested compilations ({', '.join(watch)}): none")


if __name__ == "__main__":
    main()
