"""Start-up cost: each import and command in fresh processes, against numpy + scipy + gymnasium.

Every row is a new Python process (``python -c "import ..."``, or the ``manualcontrol``
command as installed); the rows run round-robin, one of each per repeat, so a busy
machine slows them alike. It reports the median wall time and the median CPU time
(user + system, of the process and its children) of each, and the ratio of the CPU
median to that of ``import numpy, scipy, gymnasium`` measured in the same run.

``identify`` reads a 30-s simulated recording (made first, in its own process) with the
DEKF, once as a user runs it and once with ``--no-plot`` (no figure: matplotlib's import
and drawing are most of the first); every command runs once before the timing, so
numba's on-disk caches and Python's bytecode caches are warm
(``PYTHONDONTWRITEBYTECODE`` is dropped for the processes run here, so that they are
written) and what is timed is a start-up as a user sees it the second time. The
processes run with one BLAS thread (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``; set
them to measure otherwise), as ``make`` runs the project.

Targets: ``import manualcontrol.estimators`` at most 3x the reference, a warm
``identify`` at most 2x.

Run: .venv/bin/python benchmarks/startup.py [--repeats N]
Old code, for a side-by-side run: PYTHONPATH=<old tree mapped as manualcontrol>.
"""

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REFERENCE = "import numpy, scipy, gymnasium"
IMPORTS = (
    "manualcontrol",
    "manualcontrol.envs",
    "manualcontrol.pilots",
    "manualcontrol.estimators",
    "manualcontrol.agents",
    "manualcontrol.bench.cli",
)
#: The processes' environment: this one's, with bytecode caches written as by default,
#: and one BLAS thread unless told otherwise, as the Makefile runs everything (idle BLAS
#: threads spinning at start-up would add CPU time that depends on the machine's load).
ENV = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
ENV.setdefault("OPENBLAS_NUM_THREADS", "1")
ENV.setdefault("OMP_NUM_THREADS", "1")
TARGETS = {"import manualcontrol.estimators": 3.0, "manualcontrol identify": 2.0}

RECORDING = """
import sys
from manualcontrol.pilots import Pilot, simulate
recording = simulate(
    Pilot("precision"), "popovici2017", "popovici2017", run_in=0.0, measurement_time=30.0
)
recording.save(sys.argv[1])
"""


def command_line():
    """The installed ``manualcontrol`` script beside this Python, else the same via ``-c``."""
    script = Path(sys.executable).parent / "manualcontrol"
    if script.is_file():
        return [str(script)]
    return [sys.executable, "-c", "from manualcontrol.bench.cli import main_exit; main_exit()"]


def rows(folder):
    """(label, argv) of every measured process, the reference first."""
    python = [sys.executable, "-c"]
    cli = command_line()
    recording = folder / "run.npz"
    subprocess.run([*python, RECORDING, str(recording)], check=True, env=ENV)
    out = folder / "identified"
    return [
        (REFERENCE, [*python, REFERENCE]),
        *((f"import {name}", [*python, f"import {name}"]) for name in IMPORTS),
        ("manualcontrol --help", [*cli, "--help"]),
        ("manualcontrol suites", [*cli, "suites"]),
        ("manualcontrol estimators", [*cli, "estimators"]),
        (
            "manualcontrol identify",
            [*cli, "identify", str(recording), "--estimator", "dekf", "--out", str(out)],
        ),
        (
            "manualcontrol identify --no-plot",
            [
                *cli,
                "identify",
                str(recording),
                "--estimator",
                "dekf",
                "--out",
                str(out),
                "--no-plot",
            ],
        ),
    ]


def run(argv):
    """One fresh process: (wall s, CPU s), CPU read from the children's resource usage."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    result = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=ENV)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed:\n{result.stderr.decode(errors='replace')}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="fresh processes a row (5)")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    folder = Path(tempfile.mkdtemp(prefix="manualcontrol-startup-"))
    try:
        measured = rows(folder)
        for _, argv in measured:  # warm: bytecode and numba's on-disk caches written
            run(argv)
        times = {label: [] for label, _ in measured}
        for _ in range(args.repeats):
            for label, argv in measured:
                times[label].append(run(argv))
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    reference = statistics.median(cpu for _, cpu in times[REFERENCE])
    width = max(len(label) for label in times)
    print(f"median of {args.repeats} fresh processes each; ratio = CPU / {REFERENCE!r}")
    print(f"{'':<{width}}  {'wall s':>7s}  {'CPU s':>6s}  {'ratio':>6s}  target")
    for label, samples in times.items():
        wall = statistics.median(w for w, _ in samples)
        cpu = statistics.median(c for _, c in samples)
        target = TARGETS.get(label)
        note = "" if target is None else f"<= {target:g}x"
        print(f"{label:<{width}}  {wall:7.2f}  {cpu:6.2f}  {cpu / reference:5.1f}x  {note}")


if __name__ == "__main__":
    main()
