"""Compile the package's kernels into numba's on-disk cache, split across the cores.

numba compiles a kernel the first time a process calls it and keeps the machine code
on disk (``cache=True``), so only the first use on a machine pays: 20-40 CPU-s per
estimator, against a fraction of a second to load it afterwards. Run at install (the
Makefile's install step does), the first ``identify``, ``bench`` or test of a newcomer
loads instead of compiling, and the cores compile side by side, each kernel once,
where the test workers or the demo's streams would otherwise compile the same kernels
at the same time.

What runs, each job in its own process (the longest first): short simulations of
every tracking task, of the open-loop ARMAX system and of the lane-keeping driver
(and the driver's resimulation, which the driving bench scores with), a few steps of
each registered environment and of the native vector envs, of a pilot acting in one
through its controller and of the training wrappers' motor noise, and every
registered estimator's
``estimate`` (smoothed where it can be) and ``update`` on a short recording of the kind
it reads, and the batched step of those that have one
(:class:`~manualcontrol.estimators.batch.FilterBatch`): the pilot filters on the
precision and the preview model; and the isolated pilot of a resimulation, which
discretises and runs the LPV toolkit's kernels. The C ports, the members' and the LPV
toolkit's (matrix exponentials and LPV runs, ``envs/_dynamics_native.c``) and the RTS
smoother's (``estimators/filters/_smoother_native.c``), are built too
(``envs/_native.py``: under a second each), and so is the pilot filters' online step
(``estimators/_online_native.c``, a CPython extension: where Python's headers are not
installed it is skipped and the Python path runs), and the numba kernels they replace compiled
only where they are needed: where no C compiler is found (or ``MANUALCONTROL_NATIVE=0``)
they are what runs, so the install step compiles them; elsewhere they are only the
reference the C ports' tests compare with, two of the three minutes of a fresh
machine's compiling, so ``--numba-reference`` compiles them alone (``make test`` runs
it before pytest, and ``make demo`` never waits for it). Nothing is written but the
kernel cache; a job that fails is reported and the rest go on (its kernels then
compile at first use, as without this step).

Run: ``python -m manualcontrol.bench.compile_kernels [--workers N] [--numba-reference]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback
import warnings
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

import gymnasium as gym
import numpy as np

import manualcontrol.envs  # noqa: F401  (registers the environments)
from manualcontrol.estimators.registry import ESTIMATORS
from manualcontrol.pilots import Pilot, simulate
from manualcontrol.pilots.driver import Driver
from manualcontrol.pilots.driving import simulate_driving

__all__ = ["JOBS", "compile_kernels", "main"]


def _tracking_runs() -> None:

    from manualcontrol.pilots.open_loop import ARMAXSystem, simulate_open_loop

    simulate_open_loop(ARMAXSystem((0.59,), (1.5, -1.1), 0.125), measurement_time=2.0)
    for element in ("SI", "DI"):
        pilot = Pilot.typical("precision", element)
        simulate(pilot, element, "popovici2017", run_in=1.0, measurement_time=2.0, seed=0)
    simulate(
        Pilot.typical("preview", "SI"),
        "SI",
        "popovici2017",
        task="preview",
        run_in=1.0,
        measurement_time=2.0,
        seed=0,
    )


def _environments() -> None:

    from manualcontrol.agents.wrappers import MotorNoise
    from manualcontrol.pilots.controller import PilotController

    # a pilot acting in an environment, and the training wrappers' compiled remnant
    env = gym.make("ManualControl/CompensatoryTracking-v0", measurement_time=2.0)
    observation, _ = env.reset(seed=0)
    controller = PilotController(Pilot.typical("precision", "SI"), env, seed=0)
    for _ in range(5):
        observation, *_ = env.step(controller.act(observation))
    noisy = MotorNoise(env)
    noisy.reset(seed=0)
    for _ in range(5):
        noisy.step(np.zeros(1))
    env.close()
    for env_id in gym.registry:
        if not env_id.startswith("ManualControl/"):
            continue
        env = gym.make(env_id)
        env.reset(seed=0)
        for _ in range(5):
            env.step(np.zeros(env.action_space.shape, dtype=np.float64))
        env.close()
        try:
            vector = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
        except Exception:  # an env without a native vector form
            continue
        vector.reset(seed=0)
        for _ in range(5):
            vector.step(np.zeros(vector.action_space.shape, dtype=np.float64))
        vector.close()


def _driving_run() -> None:

    from manualcontrol.pilots.driving import resimulate_driver

    driver = Driver()
    recording = simulate_driving(driver, measurement_time=2.0)
    names = driver.model.parameter_names
    perceptions = ("theta_far", "theta_near", "delta_d", "Gamma_s")
    resimulate_driver(
        np.column_stack([recording.parameters[name] for name in names]),
        np.column_stack([recording[name] for name in perceptions]),
        recording.metadata["speed"],
        recording.dt,
    )


def _recording_for(name: str) -> Any:

    if name.startswith("zhao"):
        return simulate_driving(Driver(), measurement_time=4.0)
    if name == "schiess-roland":
        return simulate(
            Pilot("schiess-roland"),
            "schiess-roland1975",
            "schiess-roland1975",
            run_in=0.0,
            measurement_time=4.0,
            seed=0,
            measurement_noise={"u": 0.00092, "y": 0.00092},
        )
    return simulate(
        Pilot("precision"), "popovici2017", "popovici2017", measurement_time=12.0, seed=0
    )


def _estimator(name: str, settings: dict[str, Any] | None = None) -> None:

    entry = ESTIMATORS[name]
    recording = _recording_for(name)
    estimator = entry.build(settings or {})
    options = {"smooth": True} if entry.smoothable else {}
    estimator.estimate(recording, **options)
    if not callable(getattr(estimator, "update", None)):
        return
    keys = tuple(estimator.sample_keys)
    signals = estimator.signals(recording)
    if not isinstance(signals, dict):
        signals = dict(zip(keys, signals, strict=True))
    reset: dict[str, Any] = {}
    if hasattr(getattr(estimator.settings, "noise", None), "initial_variance"):
        reset = {"var_u0": 1.0, "var_e0": 1.0}
    elif hasattr(estimator, "initial_states_of"):
        reset = {"initial_states": estimator.initial_states_of(recording)}
    elif "speed" in recording.metadata:
        reset = {"speed": recording.metadata["speed"]}
    estimator.reset(recording.dt, **reset)
    for k in range(3):
        estimator.update({key: float(signals[key][k]) for key in keys})
    if getattr(type(estimator), "_step_many_kernel", None) is not None:
        from manualcontrol.estimators.batch import FilterBatch

        # the batched step the vector observer calls, for a causal start as online
        causal = estimator.configure(initial_variance="causal", initial={"K_p": 1.0})
        batch = FilterBatch(causal, 2)
        batch.reset(recording.dt)
        for k in range(3):
            batch.step({key: np.full(2, signals[key][k]) for key in keys})


def _pilot_filter_on_preview(name: str) -> Callable[[], None]:
    def job() -> None:

        recording = simulate(
            Pilot.typical("preview", "SI"),
            "SI",
            "popovici2017",
            task="preview",
            measurement_time=12.0,
            seed=0,
        )
        estimator = ESTIMATORS[name].build({"model": "preview", "anticipation_time": 0.9})
        estimator.estimate(recording, smooth=True)

    return job


def _lpv_toolkit() -> None:

    from manualcontrol.estimators.analysis.metrics import resimulate_parameters

    recording = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", measurement_time=2.0, seed=0
    )
    traces = {"K_p": 1.5 + 0.01 * np.arange(len(recording)) / len(recording)}
    parameters = {"K_v": 0.5, "tau_v": 0.2, "omega_nms": 8.0, "zeta_nms": 0.3, **traces}
    resimulate_parameters("precision", parameters, recording)


#: LLVM's optimisation level of ``--numba-reference``, where the user's ``NUMBA_OPT``
#: does not set one. There the C ports run and these kernels are only the tests'
#: reference, most of a fresh ``make test``'s compiling; numba's default level, 3,
#: spends part of it in passes that change no number: the estimates are the same
#: bytes at either level (numba asks LLVM for no fast-math, so no level may reorder,
#: contract or vectorise floating-point arithmetic; the C-against-numba tests pass on
#: either), and most members run as fast at 1, the Zhao UKFs somewhat slower
#: (``benchmarks/reference_opt_level.py``), which only a later ``MANUALCONTROL_NATIVE=0``
#: run, loading these kernels, would notice. Where numba is what runs (no compiler), the
#: install step keeps numba's default.
REFERENCE_OPT_LEVEL = "1"


def _numba_kernels(job: Callable[[], None]) -> Callable[[], None]:
    """``job`` with the C ports off: the numba kernels they replace compile as well.

    A kernel with a C port runs it wherever it builds, but its numba kernels are the
    reference its tests compare it with and what runs where no compiler is found
    (``envs/_native.py``).
    """

    def numba_job() -> None:
        before = os.environ.get("MANUALCONTROL_NATIVE")
        os.environ["MANUALCONTROL_NATIVE"] = "0"
        try:
            job()
        finally:
            if before is None:
                del os.environ["MANUALCONTROL_NATIVE"]
            else:
                os.environ["MANUALCONTROL_NATIVE"] = before

    numba_job.numba_reference = True  # type: ignore[attr-defined]
    return numba_job


def _c_ports() -> None:

    from manualcontrol.envs import _dynamics_native, _native
    from manualcontrol.estimators import _online_native
    from manualcontrol.estimators.filters import _smoother_native

    # name -> its C port's binding
    ported = {"LPV toolkit": _dynamics_native, "RTS smoother": _smoother_native}
    for name, entry in ESTIMATORS.items():
        binding = getattr(type(entry.build({})), "_native_binding", None)  # not all shells
        if binding is not None:
            ported[name] = binding
    failures = [
        f"{name}: " + _native.native_failure(binding.SOURCE)
        for name, binding in ported.items()
        if binding.library() is None
    ]
    if failures:
        raise RuntimeError("C ports not built: " + "; ".join(failures))
    # the pilot filters' online fast path: it also needs Python's headers, and where they
    # are missing the Python path runs (the same numbers), so its absence fails nothing
    _online_native.library()
    _lpv_toolkit()
    for name in ported:  # each member's C path, once
        if name in ESTIMATORS:
            _estimator(name)


#: The jobs, the longest first (CPU-s on a fresh machine, roughly in this order).
JOBS: dict[str, Callable[[], None]] = {
    # the numba kernels of the estimators and the LPV toolkit, C ports off
    # (_numba_kernels), then the C ports
    "rml": _numba_kernels(lambda: _estimator("rml")),
    "dekf": _numba_kernels(lambda: _estimator("dekf")),
    "joint-ukf": _numba_kernels(lambda: _estimator("joint-ukf")),
    "dual-ukf": _numba_kernels(lambda: _estimator("dual-ukf")),
    "schiess-roland": _numba_kernels(lambda: _estimator("schiess-roland")),
    "zhao-ukf": _numba_kernels(lambda: _estimator("zhao-ukf")),
    "zhao-multi-ukf": _numba_kernels(lambda: _estimator("zhao-multi-ukf")),
    "rdi": _numba_kernels(lambda: _estimator("rdi")),
    "rml on the preview model": _numba_kernels(_pilot_filter_on_preview("rml")),
    "dekf on the preview model": _numba_kernels(_pilot_filter_on_preview("dekf")),
    "joint-ukf on the preview model": _numba_kernels(_pilot_filter_on_preview("joint-ukf")),
    "C ports": _c_ports,
    "LPV toolkit": _numba_kernels(_lpv_toolkit),
    "tracking simulations": _tracking_runs,
    "environments": _environments,
    "lane-keeping simulation": _driving_run,
}


#: The jobs that compile only numba kernels a C port replaces (module docstring).
NUMBA_REFERENCE: tuple[str, ...] = tuple(
    name for name, job in JOBS.items() if getattr(job, "numba_reference", False)
)


def selected_jobs(numba_reference: bool = False) -> list[str]:
    """The jobs to run, in :data:`JOBS` order.

    ``numba_reference``: those of :data:`NUMBA_REFERENCE` alone. Otherwise every other
    job, and those too where the C ports cannot run here (no compiler, or
    ``MANUALCONTROL_NATIVE=0``): there the numba kernels are what runs.
    """
    if numba_reference:
        return list(NUMBA_REFERENCE)
    from manualcontrol.envs import _native

    ports_run = _native.native_enabled() and _native._compiler() is not None
    return [name for name in JOBS if not (ports_run and name in NUMBA_REFERENCE)]


def _run_job(name: str) -> tuple[str, float, str | None]:
    start = time.process_time()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            JOBS[name]()
    except Exception:  # reported; its kernels compile at first use
        return name, time.process_time() - start, traceback.format_exc(limit=3)
    return name, time.process_time() - start, None


def _run_jobs(names: list[str], workers: int, report: Callable[[str], None]) -> bool:
    ok = True
    with ProcessPoolExecutor(max_workers=max(1, min(workers, len(names)))) as pool:
        futures = [pool.submit(_run_job, name) for name in names]
        for future in as_completed(futures):
            name, seconds, failure = future.result()
            if failure is None:
                report(f"  compiled: {name} ({seconds:.0f} CPU-s)")
            else:
                ok = False
                report(f"  not compiled: {name} (compiles at first use instead)\n{failure}")
    return ok


def compile_kernels(
    workers: int | None = None,
    report: Callable[[str], None] = print,
    numba_reference: bool = False,
) -> bool:
    """Run the jobs :func:`selected_jobs` picks on ``workers`` processes; True if all succeeded.

    ``numba_reference`` compiles at :data:`REFERENCE_OPT_LEVEL` unless ``NUMBA_OPT`` is set.
    """
    workers = workers or os.cpu_count() or 1
    start = time.perf_counter()
    names = selected_jobs(numba_reference)
    # the workers inherit it, and numba reads NUMBA_OPT again before each compile
    set_level = numba_reference and "NUMBA_OPT" not in os.environ
    if set_level:
        os.environ["NUMBA_OPT"] = REFERENCE_OPT_LEVEL
    try:
        ok = _run_jobs(names, workers, report)
    finally:
        if set_level:
            del os.environ["NUMBA_OPT"]
    report(f"kernels compiled in {time.perf_counter() - start:.0f} s on {workers} processes")
    if not numba_reference and any(name not in names for name in NUMBA_REFERENCE):
        report(
            "  the numba kernels the C ports replace are left to compile when first used "
            "(where a C port does not build or MANUALCONTROL_NATIVE=0, and by the tests, "
            "which compare the two; --numba-reference compiles them now)"
        )
    return ok


def main(argv: list[str] | None = None) -> int:
    """The command: compile, print a line per job; exit status 1 if a job failed."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=None, help="processes (default: cores)")
    parser.add_argument(
        "--numba-reference",
        action="store_true",
        help="compile only the numba kernels the C ports replace: the reference their "
        "tests compare with (make test runs this before pytest)",
    )
    args = parser.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        parser.error(f"--workers must be a whole number >= 1, got {args.workers}")
    print(
        "compiling the numba kernels the C ports replace (the tests' reference):"
        if args.numba_reference
        else "compiling the kernels into the kernel cache, C ports built (once per machine):",
        flush=True,
    )
    done = compile_kernels(args.workers, lambda line: print(line, flush=True), args.numba_reference)
    return 0 if done else 1


if __name__ == "__main__":
    sys.exit(main())
