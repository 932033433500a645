"""numba against a compiled C extension for the DEKF: install, first use, speed, equality.

The estimators' kernels are numba; warm they are fast, but a fresh clone's first
``estimate`` compiles for about 30 CPU-s. This measures the alternative of a compiled
extension built at install, on one estimator: ``estimators/members/_dekf_native.c``, a
plain C99 port of the DEKF's compiled path (``_dekf_core.dekf_step``, the
``dekf_step_many`` loop a run goes through, and everything they call), operation for
operation, which the package builds with the system ``cc`` and calls through ``ctypes``
on the records the project's own ``DEKF.estimate`` builds (``_dekf_native.py``;
``envs/_native.py`` builds it). Since this measurement the DEKF runs it wherever it
builds; ``MANUALCONTROL_NATIVE=0`` runs numba, which is how the numba figures here are
taken.
On a 30-s simulated run (precision pilot, ``popovici2017``, seed 0, as
``benchmarks/first_use.py``) and each ``--configs`` setting of the DEKF, side by side:

- install: ``cc`` building the shared library from a clean folder (wall and CPU of the
  compiler); numba's counterpart is a fresh process on an empty ``NUMBA_CACHE_DIR``
  running one ``estimate`` (what ``make``'s kernel compilation pays);
- first use, each a fresh process, CPU seconds: numba after its cache is filled, and C
  on an empty cache (import, the package building its library, one ``estimate``: a
  fresh clone's first use; the package's modules still import numba, and the process
  checks that it compiled no numba kernel), against
  ``import numpy, scipy, gymnasium`` (the floor; ratios are against it) and what
  ``import numba`` adds to it (paid by the C path too while the package imports numba);
- steady speed, in this process, the two taking turns: the kernel of a whole run per
  sample (median of ``--repeats``), the whole ``estimate``, and one sample from Python:
  numba's compiled entry (what ``DEKF.update`` calls), numba's dispatcher, and the C
  step through ``ctypes``; ``DEKF.update`` itself for scale;
- equality: every array of the output record (mean, std, scalar, flag, pinned and the
  smoother storage) and every array of the records after the run, C against numba:
  bit for bit (the same bytes), else equal values (NaN equal to NaN) or the largest
  difference, over configurations that cover the kernel's branches: SI and DI
  elements; dropped samples (NaN in u and e) with limits and a pinned parameter; 6 s
  of NaN (the variance windows run empty); the dimensional eq. 49 with jitter, causal
  windows, identity noise input, a held parameter and no pin ring; 50 Hz (two Euler
  substeps) with Padé order 2 and smoother storage; the gain-delay model (a chain
  with feedthrough); the preview model (two inputs, a branch chain with and without
  the anticipation Padé); a non-finite stop and a covariance stop; and the online
  path, the C step sample by sample against numba's run. (Built with contraction
  allowed, e.g. ``--cflags "-std=gnu99 -O2 -march=native"`` on an FMA machine, the C
  differs from numba from the first samples on.)

Absolute speeds drift on a shared host: compare the ratios of one run.

Run: .venv/bin/python benchmarks/numba_alternatives.py [--configs SI,DI] [--repeats N]
     [--cflags "-std=c99 -O3 -march=native -ffp-contract=off"] [--skip-cold]
"""

import argparse
import ctypes
import json
import math
import os
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

#: First-use and speed configurations (keyword arguments of ``DEKF``).
CONFIGS = {"SI": {}, "DI": {"ce": "DI"}}

IMPORT_ONLY = """
import resource
import numpy, scipy, gymnasium
usage = resource.getrusage(resource.RUSAGE_SELF)
print(usage.ru_utime + usage.ru_stime)
"""

IMPORT_NUMBA = """
import resource
import numpy, scipy, gymnasium
usage = resource.getrusage(resource.RUSAGE_SELF)
before = usage.ru_utime + usage.ru_stime
import numba
usage = resource.getrusage(resource.RUSAGE_SELF)
print(usage.ru_utime + usage.ru_stime - before)
"""

# argv: recording, settings (JSON); MANUALCONTROL_NATIVE=0 in the environment for numba
FIRST_USE = """
import json, os, resource, sys, time, warnings
warnings.simplefilter("ignore")
def cpu():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)  # the C compiler
    return usage.ru_utime + usage.ru_stime + children.ru_utime + children.ru_stime
path, settings = sys.argv[1:3]
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.members import _dekf_core
from manualcontrol.estimators.members.dekf import DEKF
recording = Recording.load(path)
estimator = DEKF(**json.loads(settings))
imported = cpu()
estimator.estimate(recording)
first = cpu() - imported
start = time.perf_counter()
estimator.estimate(recording)
warm = time.perf_counter() - start
compiled = len(_dekf_core.dekf_step_many.signatures) + len(_dekf_core.dekf_step.signatures)
cached = sum(
    len(files) for folder, _, files in os.walk(os.environ["NUMBA_CACHE_DIR"])
    if "manualcontrol-native" not in folder
)
print(cpu(), imported, first, warm, compiled, cached)
"""

SIMULATE = """
import sys, warnings
warnings.simplefilter("ignore")
from manualcontrol.pilots import Pilot, simulate
simulate(Pilot("precision"), "popovici2017", "popovici2017", seed=0,
         measurement_time=30.0).save(sys.argv[1])
"""


def run(code, *args, cache=None, native=True):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    env["MANUALCONTROL_NATIVE"] = "1" if native else "0"
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = cache
    out = subprocess.run(
        [sys.executable, "-c", code, *map(str, args)],
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode != 0:
        raise RuntimeError(out.stderr.strip().splitlines()[-1])
    return [float(x) for x in out.stdout.split()]


class CPort:
    """The C port as this script drives it: built with chosen flags, bound to one estimator."""

    def __init__(self, flags):
        from manualcontrol.estimators.members import _dekf_native

        self.flags = flags
        self.source = _dekf_native.SOURCE
        self.binding = _dekf_native

    def build(self, folder, cc):
        """Compile into ``folder``; ``(library, wall s, CPU s)`` of the compiler process."""
        folder.mkdir(parents=True, exist_ok=True)
        library = folder / "libdekf.so"
        command = [cc, *self.flags, str(self.source), "-o", str(library), "-lm"]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True, text=True)
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return library, wall, cpu

    def load(self, library):
        return self.binding.declare(ctypes.CDLL(str(library)))

    def records(self, lib, records, out):
        return self.binding.NativeRecords(lib, records, out)

    def use(self, estimator, lib):
        """Make ``estimator`` run its whole-recording kernel through this build."""

        def run(inputs, u, e, out):
            self.records(lib, estimator._records, out).run(inputs, u, e)
            estimator.c_calls += 1

        estimator._run = run
        estimator.c_calls = 0
        return estimator


# ------------------------------------------------------------------ equality cases


def equality_cases():
    """(name, recording, DEKF keywords, estimate keywords) covering the kernel's branches."""
    import numpy as np

    from manualcontrol.pilots import Pilot, simulate

    base = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=0, measurement_time=30.0
    )
    u, e = np.array(base.u), np.array(base.e)
    u[700:750] = np.nan  # 0.5 s of u dropped at 7 s, three samples of e at 9 s
    e[900:903] = np.nan
    gaps = base.with_signals(u=u, e=e)
    u, e = np.array(base.u), np.array(base.e)
    u[1000:1600] = np.nan  # 6 s of nothing: the 5-s variance windows run empty
    e[1000:1600] = np.nan
    blackout = base.with_signals(u=u, e=e)
    spike = np.array(base.u)
    spike[1500] = 1e300  # the filter goes non-finite at 15 s and stops
    fifty = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=0, measurement_time=30.0, dt=0.02
    )
    preview = {
        "K_f": 0.9,
        "omega_f": 1.0,
        "K_p": 0.24,
        "K_v": 0.36,
        "omega_nms": 8.0,
        "zeta_nms": 0.45,
        "tau_v": 0.3,
        "tau_f": 0.6,
    }
    ahead = simulate(Pilot("preview", preview), "DI", "vanderel-bw4", seed=1, measurement_time=30.0)
    pursuit = {name: value for name, value in preview.items() if name != "tau_f"}
    return [
        ("SI (DEKF())", base, {}, {}),
        ("DI (ce='DI')", base, {"ce": "DI"}, {}),
        (
            "NaN in u and e, limits, pinned",
            gaps,
            {"limits": {"K_v": (0.45, 0.55), "zeta_nms": (0.29, 0.30)}, "pinned_time": 1.0},
            {},
        ),
        ("6 s of NaN in u and e (empty windows)", blackout, {}, {}),
        (
            "eq. 49 dimensional, jitter, causal, Gamma=I, +",
            base,
            {
                "total_derivative": "dimensional",
                "jitter": 1e-12,
                "initial_variance": "causal",
                "noise_input": "identity",
                "r2_parameter": 2.0,
                "estimated": ("K_p", "K_v", "tau_v", "omega_nms"),
                "pinned_time": math.inf,
            },
            {},
        ),
        (
            "50 Hz (2 Euler substeps), Pade order 2",
            fifty,
            {"delay_order": 2},
            {"smoother_inputs": True},
        ),
        ("gain-delay model (chain with feedthrough)", base, {"model": "gain-delay"}, {}),
        (
            "preview DI (2 inputs, branch chain, Pade)",
            ahead,
            {"model": "preview", "ce": "DI", "anticipation_time": 1.5, "initial": preview},
            {},
        ),
        (
            "preview DI pursuit (branch without Pade)",
            ahead,
            {"model": "preview", "ce": "DI", "anticipation_time": 0.0, "initial": pursuit},
            {},
        ),
        ("u = 1e300 at 15 s: non-finite", base.with_signals(u=spike), {}, {}),
        ("max_covariance 10: covariance", base, {"max_covariance": 10.0}, {}),
    ]


def _arrays(record, prefix=""):
    """Every array of a (nested) record, by dotted name."""
    import numpy as np

    found = {}
    for name, value in zip(record._fields, record, strict=True):
        if isinstance(value, np.ndarray):
            found[prefix + name] = value
        elif isinstance(value, tuple) and hasattr(value, "_fields"):
            found.update(_arrays(value, prefix + name + "."))
    return found


def _compare(ours, theirs):
    """(same bytes, same values with NaN equal to NaN, largest absolute difference)."""
    import numpy as np

    bits = ours.shape == theirs.shape and ours.tobytes() == theirs.tobytes()
    if ours.dtype.kind == "f":
        values = np.array_equal(ours, theirs, equal_nan=True)
    else:
        values = np.array_equal(ours, theirs)
    if values or ours.size == 0:
        return bits, values, 0.0
    with np.errstate(invalid="ignore"):
        difference = np.abs(ours.astype(float) - theirs.astype(float))
    finite = np.isfinite(difference)
    return bits, values, float(np.max(difference[finite])) if finite.any() else float("inf")


def equality(lib, port):
    """Per case: which output and record arrays differ, in bits or in value."""
    from manualcontrol.estimators.members.dekf import DEKF

    results = {}
    for name, recording, settings, options in equality_cases():
        outs, records = [], []
        for use_c in (False, True):
            estimator = DEKF(**settings)
            if use_c:
                port.use(estimator, lib)
            kernel = estimator._run
            kept = {}

            def spy(inputs, u, e, out, kernel=kernel, kept=kept):
                kernel(inputs, u, e, out)
                kept["out"] = out

            estimator._run = spy
            estimator.estimate(recording, **options)
            if use_c and estimator.c_calls != 1:
                raise RuntimeError("the C kernel did not run")
            outs.append(_arrays(kept["out"]))
            state = {}
            for label, record in zip(
                ("model", "config", "belief", "monitor", "report", "scratch"),
                estimator._records,
                strict=True,
            ):
                state.update(_arrays(record, label + "."))
            records.append(state)
        compared = {f: _compare(outs[1][f], outs[0][f]) for f in outs[0]}
        state = {f: _compare(records[1][f], records[0][f]) for f in records[0]}
        stored = (
            sum(
                a.size
                for f, a in outs[0].items()
                if f not in ("mean", "std", "scalar", "flag", "pinned")
            )
            > 0
        )
        results[name] = {
            "outputs_bit_identical": all(bits for bits, _, _ in compared.values()),
            "outputs_equal": all(values for _, values, _ in compared.values()),
            "unequal_outputs": {f: d for f, (_, values, d) in compared.items() if not values},
            "records_bit_identical": all(bits for bits, _, _ in state.values()),
            "unequal_records": [f for f, (bits, _, _) in state.items() if not bits],
            "smoother_storage_compared": stored,
            "samples": len(recording),
            "diverged": kept_stop(records[0]),
        }
    return results


def kept_stop(state):
    """How the run diverged, from its scalar state ``sc``: '' if it did not."""
    sc = state["belief.sc"]
    reason = {1: "stopped: non-finite", 2: "stopped: covariance", 3: "pinned"}.get(int(sc[13]))
    return "" if reason is None else f"{reason} at sample {int(sc[12])}"


# ------------------------------------------------------------------- steady speed


def numba_run(records, inputs, u, e, out):
    """A whole run on numba's path, as ``DEKF._run`` makes it without the C port.

    The batched loop on the records and ``out`` as a stack of one, sample ``k`` into
    row ``k``.
    """
    import numpy as np

    from manualcontrol.estimators.filters.batch import one_filter_loop, stack_of_one
    from manualcontrol.estimators.members import _dekf_core as core

    stacked = stack_of_one((records, out))
    core.dekf_step_many(*one_filter_loop(stacked, inputs, u, e, np.arange(len(u))))


def steady(lib, port, settings, repeats):
    """Per-sample figures of numba and C in this process (the two taking turns)."""
    import numpy as np

    from manualcontrol.estimators.members import _dekf_core as core
    from manualcontrol.estimators.members.dekf import DEKF
    from manualcontrol.estimators.shell import compiled_entry
    from manualcontrol.pilots import Pilot, simulate

    recording = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=0, measurement_time=30.0
    )
    n = len(recording)
    kernel_time = {"numba": [], "c": []}
    estimate_time = {"numba": [], "c": []}
    struct_time = []
    estimators = {"numba": DEKF(**settings), "c": DEKF(**settings)}
    for kind, estimator in estimators.items():

        def timed(inputs, u, e, out, kind=kind, estimator=estimator):
            if kind == "c":  # the struct is filled outside the kernel's time (timed below)
                struct = port.records(lib, estimator._records, out)
                start = time.process_time()
                struct.run(inputs, u, e)
            else:  # what DEKF._run calls on numba's path
                start = time.process_time()
                numba_run(estimator._records, inputs, u, e, out)
            kernel_time[kind].append(time.process_time() - start)

        estimator._run = timed
        estimator.estimate(recording)  # warm (numba: compiled or loaded from the cache)
        kernel_time[kind].clear()
    for _ in range(repeats):
        for kind, estimator in estimators.items():
            start = time.process_time()
            estimator.estimate(recording)
            estimate_time[kind].append(time.process_time() - start)
    # the C call's own setup: filling the struct of pointers from the records
    c = estimators["c"]
    out = c._new_output(n, store=False)
    for _ in range(repeats):
        start = time.process_time()
        port.records(lib, c._records, out)
        struct_time.append(time.process_time() - start)

    # one sample from Python: the online path
    numba_est = estimators["numba"]
    signals = numba_est.signals(recording)
    inputs_table = np.ascontiguousarray(
        np.column_stack([signals[k] for k in numba_est.internal_model.input_names])
    )
    u, e = signals["u"].tolist(), signals["e"].tolist()
    rows = inputs_table.tolist()
    sc = numba_est._records[2].sc
    var_u0, var_e0 = float(sc[1]), float(sc[2])  # the variances estimate's reset used
    keys = numba_est.sample_keys
    samples = [{key: float(signals[key][k]) for key in keys} for k in range(n)]

    def reset(estimator):
        estimator.reset(recording.dt, var_u0=var_u0, var_e0=var_e0)
        return estimator._records, estimator._row, estimator._inputs

    def loop_entry(estimator):
        records, row, inputs = reset(estimator)
        arguments = (*records, inputs, u[0], e[0], 0, row)
        entry = compiled_entry(core.dekf_step, arguments)  # compiles/loads, steps sample 0
        start = time.process_time()
        for k in range(1, n):
            inputs[:] = rows[k]
            entry(*records, inputs, u[k], e[k], 0, row)
        return (time.process_time() - start) / (n - 1)

    def loop_dispatcher(estimator):
        records, row, inputs = reset(estimator)
        step = core.dekf_step
        start = time.process_time()
        for k in range(n):
            inputs[:] = rows[k]
            step(*records, inputs, u[k], e[k], 0, row)
        return (time.process_time() - start) / n

    def loop_c(estimator, rows_out=None):
        records, row, inputs = reset(estimator)
        struct = port.records(lib, records, row)
        call, ref, address = lib.dekf_step, struct.ref, inputs.ctypes.data
        start = time.process_time()
        for k in range(n):
            inputs[:] = rows[k]
            call(ref, address, u[k], e[k], 0)
            if rows_out is not None:
                for name in rows_out:
                    rows_out[name].append(getattr(row, name)[0].copy())
        return (time.process_time() - start) / n

    def loop_update(estimator, native=False):
        # the package's own choice: its C build (default flags) where native, else numba
        os.environ["MANUALCONTROL_NATIVE"] = "1" if native else "0"
        try:
            reset(estimator)
            start = time.process_time()
            for sample in samples:
                estimator.update(sample)
            return (time.process_time() - start) / n
        finally:
            os.environ["MANUALCONTROL_NATIVE"] = "0"

    online = DEKF(**settings)
    loops = {
        "numba entry (DEKF.update's)": lambda: loop_entry(online),
        "numba dispatcher": lambda: loop_dispatcher(online),
        "C via ctypes": lambda: loop_c(online),
        "DEKF.update (numba, whole)": lambda: loop_update(online),
        "DEKF.update (C, whole)": lambda: loop_update(online, native=True),
    }
    per_call = {name: [] for name in loops}
    for loop in loops.values():
        loop()  # warm
    for _ in range(max(3, repeats // 4)):
        for name, loop in loops.items():
            per_call[name].append(loop())
    # the online C path against numba's run, row by row
    fields = ("mean", "std", "scalar", "flag", "pinned")
    stepped = {name: [] for name in fields}
    loop_c(DEKF(**settings), stepped)
    reference = {}

    def keep(inputs, u_, e_, out):
        numba_run(check._records, inputs, u_, e_, out)
        reference["out"] = out

    check = DEKF(**settings)
    check._run = keep
    check.estimate(recording)
    online_equal = all(
        _compare(np.array(stepped[f]), getattr(reference["out"], f))[0] for f in fields
    )
    median = statistics.median
    return {
        "kernel_us_per_sample": {k: median(v) / n * 1e6 for k, v in kernel_time.items()},
        "estimate_ms": {k: median(v) * 1e3 for k, v in estimate_time.items()},
        "c_struct_us": median(struct_time) * 1e6,
        "step_us_per_call": {k: median(v) * 1e6 for k, v in per_call.items()},
        "online_c_step_equals_numba_run": online_equal,
    }


# --------------------------------------------------------------------------- main


def _native_flags():
    from manualcontrol.envs._native import FLAGS

    return FLAGS


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", default="SI,DI", help=f"of {', '.join(CONFIGS)}")
    parser.add_argument("--repeats", type=int, default=21, help="runs per steady figure")
    parser.add_argument("--imports", type=int, default=3, help="fresh processes per import")
    parser.add_argument("--cc", default="cc")
    parser.add_argument("--cflags", default=None, help="replace the default flags (quoted)")
    parser.add_argument(
        "--skip-cold", action="store_true", help="no cold numba process (it takes ~30 CPU-s)"
    )
    args = parser.parse_args()
    configs = args.configs.split(",")
    flags = (
        _native_flags() if args.cflags is None else (*shlex.split(args.cflags), "-fPIC", "-shared")
    )
    port = CPort(flags)
    # in this process numba runs unless this script hands an estimator the C build
    os.environ["MANUALCONTROL_NATIVE"] = "0"
    rows = {}
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        recording = folder / "run.npz"
        run(SIMULATE, recording)
        library, build_wall, build_cpu = port.build(folder / "build", args.cc)
        floor = statistics.median(run(IMPORT_ONLY)[0] for _ in range(args.imports))
        rows["import numpy, scipy, gymnasium"] = (floor, None, None, None)
        numba_import = statistics.median(run(IMPORT_NUMBA)[0] for _ in range(args.imports))
        rows["... then import numba (C path pays it too)"] = (numba_import, None, None, None)
        rows[f"C: {args.cc} builds the library (wall {build_wall:.2f} s)"] = (
            build_cpu,
            None,
            None,
            None,
        )
        checks = {}
        filled = None
        for name in configs:
            settings = json.dumps(CONFIGS[name])
            cache = tempfile.mkdtemp(dir=folder)
            if not args.skip_cold:
                total, imported, first, warm, _, _ = run(
                    FIRST_USE, recording, settings, cache=cache, native=False
                )
                rows[f"numba {name}: cold process (= install)"] = (total, imported, first, warm)
                total, imported, first, warm, _, _ = run(
                    FIRST_USE, recording, settings, cache=cache, native=False
                )
                rows[f"numba {name}: after install"] = (total, imported, first, warm)
                filled = filled or cache
            empty = tempfile.mkdtemp(dir=folder)
            total, imported, first, warm, compiled, cached = run(
                FIRST_USE, recording, settings, cache=empty
            )
            rows[f"C {name}: fresh process, empty cache"] = (total, imported, first, warm)
            checks[f"C {name}: numba compilations, numba cache files"] = (
                int(compiled),
                int(cached),
            )
        # this process: numba from the cache the cold process filled (else compiles here)
        # (with --skip-cold: NUMBA_CACHE_DIR if set, else compiled here into a temporary one)
        os.environ["NUMBA_CACHE_DIR"] = (
            filled or os.environ.get("NUMBA_CACHE_DIR") or str(folder / "numba")
        )
        warnings.simplefilter("ignore")
        lib = port.load(library)
        speed = {name: steady(lib, port, CONFIGS[name], args.repeats) for name in configs}
        same = equality(lib, port)

    print(f"flags: {' '.join(flags)}")
    print(
        f"{'fresh process, CPU s':44} {'total':>7} {'x import':>8} {'imports':>8} "
        f"{'estimate':>9} {'2nd (wall)':>10}"
    )
    for label, (total, imported, first, warm) in rows.items():
        extra = "" if first is None else f" {imported:8.2f} {first:9.3f} {warm:10.3f}"
        print(f"{label:44} {total:7.2f} {total / floor:8.1f}{extra}")
    for label, (compiled, cached) in checks.items():
        print(f"  {label}: {compiled}, {cached}")
    for name, figures in speed.items():
        print(
            f"\nsteady speed, {name} (this process; medians of {args.repeats})"
            f"{'numba':>12} {'C':>9} {'C/numba':>8}"
        )
        kernel = figures["kernel_us_per_sample"]
        print(
            f"  {'whole 30-s run, kernel, us/sample':50} {kernel['numba']:9.3f} "
            f"{kernel['c']:9.3f} {kernel['c'] / kernel['numba']:8.2f}"
        )
        whole = figures["estimate_ms"]
        print(
            f"  {'whole estimate(), ms':50} {whole['numba']:9.2f} {whole['c']:9.2f} "
            f"{whole['c'] / whole['numba']:8.2f}"
        )
        print(
            f"  {'C: filling the struct of pointers, us':50} {'':9} {figures['c_struct_us']:9.1f}"
        )
        step = figures["step_us_per_call"]
        base = step["numba entry (DEKF.update's)"]
        for label, value in step.items():
            print(
                f"  {'one sample from Python: ' + label + ', us':60} {value:9.3f} "
                f"{value / base:6.2f}x entry"
            )
        print(
            f"  online: C step row by row equals numba's run: "
            f"{figures['online_c_step_equals_numba_run']}"
        )
    print(
        "\nequality, C against numba: every array of the output record, and every array "
        "of the records after the run"
    )
    for name, result in same.items():
        if result["outputs_bit_identical"]:
            verdict = "bit-identical"
        elif result["outputs_equal"]:
            verdict = "equal values, different bits (signed zero or NaN payload)"
        else:
            verdict = f"DIFFERENT {result['unequal_outputs']}"
        records = (
            "records bit-identical"
            if result["records_bit_identical"]
            else f"records differ: {result['unequal_records']}"
        )
        stored = ", smoother storage too" if result["smoother_storage_compared"] else ""
        stop = f", {result['diverged']}" if result["diverged"] else ""
        print(f"  {name:44} {result['samples']} samples{stop}: {verdict}{stored}; {records}")
    summary = {label: values[0] for label, values in rows.items()}
    summary["build_wall_s"] = build_wall
    summary["steady"] = speed
    summary["bit_identical"] = {
        name: r["outputs_bit_identical"] and r["records_bit_identical"] for name, r in same.items()
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
