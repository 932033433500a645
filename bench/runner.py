"""Batch runner: scenarios in, one results row per run out.

:func:`run_suite` runs every scenario of a suite with a backend:

``"process"`` (default)
    a local :class:`concurrent.futures.ProcessPoolExecutor` over all cores. The first
    scenario runs in this process before the pool starts, so the compiled kernels are
    built (or loaded from numba's cache) once: forked workers (Linux) inherit them,
    workers started otherwise load the cache that first run wrote;
``"inprocess"``
    one after the other in this process (debugging, tests);
``"ray"``
    `Ray <https://www.ray.io>`_ tasks, for clusters (``pip install 'manualcontrol[dist]'``;
    connects to ``RAY_ADDRESS`` or starts a local instance).

Scenarios that differ only in their estimator share one simulation: a worker
simulates it once and runs every estimator on the same recording (one row per
estimator, the ``estimator`` column naming it). The runs of one pilot's Monte Carlo (a
batch's realisations and seeds) are simulated together where a worker gets several
(:func:`run_scenario_groups`, :func:`~manualcontrol.pilots.simulate_many`): the loop is
discretised once, the forced run stepped once per realisation and the remnant's once
per seed; the process pool and Ray hand each worker a batch's runs one or more seeds
at a time (a seed with more realisations than a task holds is cut). Each scenario is
seeded by its own settings only, so the numbers are identical whatever the backend, the
number of workers and what was simulated together. Every finished run is stored at
once under ``<out>/runs/<key>.json`` (its row) and ``<key>.npz`` (the estimator's
traces); a suite run again skips those (resume), and a failing scenario is recorded as
failed with its error while the batch goes on. At the end the rows are written to
``results.csv`` and ``results.parquet``.

Ctrl-C stops a run cleanly: the pool's workers ignore it (no traceback from them), the
main process cancels what has not started, stops the workers and raises
:class:`SuiteInterrupted` (a ``KeyboardInterrupt``) saying how many runs are stored;
running the same suite into the same folder again resumes from there.

A results folder belongs to one suite: :func:`run_suite` refuses a folder whose
results (the ``suite`` column of ``results.csv``, or of the stored runs when there is
no table yet) came from another suite, rather than replace its table and leave its
report beside rows it does not describe. A folder of the same suite's results is
resumed; an empty or absent folder, or one holding no results, is used as it is.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import multiprocessing
import os
import signal
import sys
import time
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from manualcontrol.bench.scenarios import Scenario, Suite
from manualcontrol.envs._files import atomic_write
from manualcontrol.envs._validation import check_choice, check_int
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.offline.smoothing import smooth
from manualcontrol.estimators.registry import ESTIMATORS, make_estimator

__all__ = [
    "BACKENDS",
    "ESTIMATORS",
    "SuiteInterrupted",
    "make_estimator",
    "run_scenario",
    "run_scenario_groups",
    "run_scenarios",
    "run_suite",
    "write_table",
]

BACKENDS: tuple[str, ...] = ("process", "inprocess", "ray")


class SuiteInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`run_suite`: ``done`` of ``total`` runs are stored in ``out``.

    Running the same suite into ``out`` again resumes: the stored runs are skipped.
    """

    def __init__(self, done: int, total: int, out: Path) -> None:
        super().__init__(f"interrupted: {done} of {total} runs kept in {out}")
        self.done, self.total, self.out = done, total, out


def simulate_scenario(scenario: Scenario) -> Recording:
    """The scenario's simulated run, run-in kept (the estimator converges on it)."""
    if scenario.task == "lane-keeping":
        from manualcontrol.bench.driving import simulate_lane_keeping

        return simulate_lane_keeping(scenario)
    if scenario.system is not None:
        from manualcontrol.pilots.open_loop import simulate_open_loop

        return simulate_open_loop(
            scenario.build_system(),
            scenario.forcing,
            realisation=scenario.realisation,
            dt=scenario.dt,
            run_in=scenario.run_in,
            measurement_time=scenario.measurement_time or 60.0,
            seed=scenario.remnant_seed,
            keep_run_in=True,
        )
    from manualcontrol.pilots import simulate

    return simulate(
        scenario.build_pilot(),
        scenario.element,
        scenario.forcing,
        realisation=scenario.realisation,
        seed=scenario.remnant_seed,
        **_tracking_options(scenario),
    )


def _tracking_options(scenario: Scenario) -> dict[str, Any]:
    """:func:`~manualcontrol.pilots.simulate`'s keywords for a tracking scenario.

    All of them but the realisation and the seed, which are each run's own.
    """
    postview = {} if scenario.gap is None else {"gap": scenario.build_gap()}
    return {
        "task": scenario.task,
        "available_preview": scenario.available_preview,
        "dt": scenario.dt,
        "run_in": scenario.run_in,
        "measurement_time": scenario.measurement_time,
        "loop": scenario.loop,
        "keep_run_in": True,
        "loss_of_control": scenario.loss_of_control,
        **postview,
        "start_time": scenario.start_time,
        "initial_state": scenario.initial_state,
        "measurement_noise": scenario.measurement_noise,
        "disturbance_at": scenario.disturbance_at,
    }


def _monte_carlo_key(scenario: Scenario) -> str | None:
    """What the runs of one pilot's Monte Carlo share: all but realisation and seed.

    Scenarios with the same key are simulated together
    (:func:`~manualcontrol.pilots.simulate_many`); None for the runs simulated alone
    (lane keeping and open-loop systems).
    """
    if scenario.task == "lane-keeping" or scenario.system is not None:
        return None
    data = scenario.to_dict()
    for name in ("estimator", "realisation", "remnant_seed"):
        data.pop(name)
    return json.dumps(data, sort_keys=True, default=str)


#: A simulation as a group's runs use it: the recording (None when it failed), the
#: error and its traceback (None when it did not), and the seconds it took.
_Simulated = tuple[Recording | None, tuple[BaseException, str] | None, float]


def _simulate_alone(scenario: Scenario) -> _Simulated:
    started = time.perf_counter()
    try:
        recording = simulate_scenario(scenario)
    except Exception as error:
        return None, (error, traceback.format_exc(limit=6)), time.perf_counter() - started
    return recording, None, time.perf_counter() - started


def _simulations(groups: Sequence[Sequence[Scenario]]) -> Iterator[_Simulated]:
    """Each group's simulation, in order; a Monte Carlo's runs simulated together.

    Consecutive groups of one pilot's Monte Carlo (:func:`_monte_carlo_key`) share
    their loop and its runs (:func:`~manualcontrol.pilots.simulate_many`): every
    recording is the one the group would simulate alone, bit for bit. Each simulation
    counts the seconds of its own recording, the shared work included where it was
    first needed. A run that fails is simulated again alone, so its row says what it
    says alone (error and traceback), and the runs after it are simulated together
    again; Monte Carlo runs that cannot even be set up together are each run alone.
    """
    from manualcontrol.pilots import simulate_many

    i = 0
    while i < len(groups):
        first = groups[i][0]
        key = _monte_carlo_key(first)
        end = i + 1
        while key is not None and end < len(groups) and _monte_carlo_key(groups[end][0]) == key:
            end += 1
        firsts = [group[0] for group in groups[i:end]]
        runs = None
        if len(firsts) > 1:
            try:
                # the pilot is built once here and once per run alone: its warnings
                # (a parameter outside the human range) are given to every run
                with warnings.catch_warnings(record=True) as built:
                    warnings.simplefilter("always")
                    pilot = first.build_pilot()
                runs = simulate_many(
                    pilot,
                    first.element,
                    first.forcing,
                    runs=[(scenario.realisation, scenario.remnant_seed) for scenario in firsts],
                    **_tracking_options(first),
                )
            except Exception:
                runs = None  # each run alone says what is wrong with it
        if runs is None:
            for scenario in firsts:
                yield _simulate_alone(scenario)
            i = end
            continue
        for scenario in firsts:
            started = time.perf_counter()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    recording = next(runs)
                except Exception:
                    recording = None
            i += 1
            if recording is None:
                # alone, it warns again and fails as it does alone; outside the handler,
                # its traceback is its own, unchained
                yield _simulate_alone(scenario)
                break  # the iteration ended with the error: start again after it
            for warning in [*built, *caught]:
                warnings.warn(warning.message, warning.category, stacklevel=2)
            yield recording, None, time.perf_counter() - started


def run_scenario(scenario: Scenario, out: Path | None = None) -> dict[str, Any]:
    """Simulate, estimate and score one scenario; return its results row.

    Errors become a row with ``status = "failed"`` and the message, never an exception.
    With ``out``, the row and the estimator's traces are stored under ``out/runs``.
    """
    (row,) = run_scenarios([scenario], out)
    return row


def run_scenarios(scenarios: Sequence[Scenario], out: Path | None = None) -> list[dict[str, Any]]:
    """Scenarios sharing one simulation: simulate once, run every estimator on it.

    Returns one row per scenario, in order (see :func:`run_scenario`). A failed
    simulation fails every row; a failed estimator fails its own row only.
    """
    _check_group(scenarios)
    return _run_group(scenarios, out, _simulate_alone(scenarios[0]))


def run_scenario_groups(
    groups: Sequence[Sequence[Scenario]], out: Path | None = None
) -> Iterator[list[dict[str, Any]]]:
    """:func:`run_scenarios` for each group, in order, yielding each group's rows as it ends.

    Consecutive groups that are runs of one pilot's Monte Carlo (a batch's realisations
    and seeds) are simulated together, their shared work done once
    (:func:`~manualcontrol.pilots.simulate_many`); every row is the one
    :func:`run_scenarios` gives its group alone, bit for bit, but for its times.
    """
    for group in groups:
        _check_group(group)
    for group, simulated in zip(groups, _simulations(groups), strict=True):
        yield _run_group(group, out, simulated)


def _run_chunk(groups: Sequence[Sequence[Scenario]], out: Path) -> list[dict[str, Any]]:
    """Every row of ``groups`` (:func:`run_scenario_groups`): a pool worker's task."""
    return [row for rows in run_scenario_groups(groups, out) for row in rows]


def _check_group(scenarios: Sequence[Scenario]) -> None:
    if len({scenario.simulation_key for scenario in scenarios}) > 1:
        raise ValueError("run_scenarios takes scenarios that share one simulation")


def _run_group(
    scenarios: Sequence[Scenario], out: Path | None, simulated: _Simulated
) -> list[dict[str, Any]]:
    """The rows of one group, from its simulation (see :func:`run_scenarios`)."""
    from manualcontrol.bench.scoring import score

    recording, failure, simulation_time = simulated
    twins = _twinned_filters(scenarios)
    shared: dict[str, Any] = {}
    rows = []
    for scenario in scenarios:
        row: dict[str, Any] = {
            "key": scenario.key,
            "suite": scenario.suite,
            "batch": scenario.batch,
            "realisation": scenario.realisation,
            "remnant_seed": scenario.remnant_seed,
            "task": scenario.task,
            "element": scenario.element
            if isinstance(scenario.element, str)
            else json.dumps(scenario.element),
            "forcing": scenario.forcing,
            "estimator": scenario.estimator["name"],
        }
        begun = time.perf_counter()
        try:
            if failure is not None:
                raise failure[0]
            result, shift = _estimate(scenario.estimator, recording, twins, shared)
            begun -= shift  # a shared filter pass counts for the online row only
            finished = time.perf_counter()
            row.update(score(scenario, recording, result))
            row.update(
                status="ok",
                error="",
                simulation_time_s=simulation_time,
                estimation_time_s=finished - begun,
            )
            if out is not None:
                result.save(out / "runs" / f"{scenario.key}.npz")
        except Exception as error:
            row.update(
                status="failed",
                error=f"{type(error).__name__}: {error}",
                traceback=failure[1] if failure is not None else traceback.format_exc(limit=6),
            )
        # the simulation's cost is shared: each row carries its own estimation plus the
        # simulation once, so a batch's run times add up per estimator
        row["run_time_s"] = time.perf_counter() - begun + simulation_time
        row["scenario"] = scenario.to_dict()
        if out is not None:
            text = json.dumps(_json_safe(row), indent=1)
            atomic_write(out / "runs" / f"{scenario.key}.json", lambda p, t=text: p.write_text(t))
        rows.append(row)
    return rows


def _is_twin(spec: Mapping[str, Any]) -> bool:
    """Whether ``spec`` names a smoothed twin (its filter's run, smoothed)."""
    entry = ESTIMATORS.get(spec["name"])
    return entry is not None and entry.twin == "smoothed"


def _online(spec: Mapping[str, Any]) -> dict[str, Any]:
    """The spec of the online filter ``spec`` runs: a smoothed twin names its filter."""
    return {**spec, "name": ESTIMATORS[spec["name"]].base} if _is_twin(spec) else dict(spec)


def _filter_key(spec: Mapping[str, Any]) -> str:
    """:func:`_online` as text, to find a filter and its twin in one group."""
    return json.dumps(_online(spec), sort_keys=True, default=str)


def _twinned_filters(scenarios: Sequence[Scenario]) -> set[str]:
    """Filters that run in this group both online and as their smoothed twin."""
    online = {_filter_key(s.estimator) for s in scenarios if not _is_twin(s.estimator)}
    smoothed = {_filter_key(s.estimator) for s in scenarios if _is_twin(s.estimator)}
    return online & smoothed


def _estimate(
    spec: Mapping[str, Any], recording: Recording, twins: set[str], shared: dict[str, Any]
) -> tuple[Any, float]:
    """``make_estimator(spec).estimate(recording)``, one filter pass for a twinned pair.

    When a group runs a filter and its ``-smoothed`` twin with the same settings, the
    filter runs once with its smoother inputs kept; the online row gets that result
    without them and the twin its smoothed version: the same numbers as two separate
    runs (tested), for one pass of the filter instead of two.

    Also returns the seconds to move into this row's time: the shared pass counts for
    the online row (as it would alone) and the twin keeps only its smoothing.
    """
    key = _filter_key(spec)
    if key not in twins:
        return make_estimator(spec).estimate(recording), 0.0
    computed_here = key not in shared
    if computed_here:
        begun = time.perf_counter()
        full = make_estimator(_online(spec)).estimate(recording, smoother_inputs=True)
        shared[key] = full, time.perf_counter() - begun
    full, seconds = shared[key]
    if full.smoothed:  # a filter set to smooth already: nothing to share
        return make_estimator(spec).estimate(recording), -seconds if computed_here else 0.0
    if _is_twin(spec):
        return smooth(full), -seconds if computed_here else 0.0
    return dataclasses.replace(full, smoother_inputs=None), 0.0 if computed_here else seconds


def _groups(scenarios: Sequence[Scenario]) -> list[list[Scenario]]:
    """Scenarios grouped by their simulation, in first-seen order."""
    groups: dict[str, list[Scenario]] = {}
    for scenario in scenarios:
        groups.setdefault(scenario.simulation_key, []).append(scenario)
    return list(groups.values())


def _json_safe(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.generic):
        return _json_safe(value.item())
    return value


def _done_rows(out: Path, scenarios: Sequence[Scenario]) -> dict[str, dict[str, Any]]:
    done = {}
    for scenario in scenarios:
        path = out / "runs" / f"{scenario.key}.json"
        if path.is_file():
            try:
                done[scenario.key] = json.loads(path.read_text())
            except json.JSONDecodeError:
                continue  # a damaged row is run again
    return done


def _suites_in(out: Path, running: set[str]) -> tuple[list[str], str]:
    """Suites whose results ``out`` holds, and where that was read.

    The ``suite`` column of ``results.csv`` when there is one; else the stored runs'
    rows (an interrupted run has no table yet), read until one of another suite than
    ``running`` turns up.
    """
    import csv

    table = out / "results.csv"
    if table.is_file():
        try:
            with table.open(newline="", encoding="utf-8") as handle:
                found = {row.get("suite") or "" for row in csv.DictReader(handle)}
        except (OSError, UnicodeDecodeError, csv.Error):
            found = set()
        found.discard("")
        if found:
            return sorted(found), "results.csv"
    runs = out / "runs"
    found = set()
    if runs.is_dir():
        for path in sorted(runs.glob("*.json")):
            try:
                name = json.loads(path.read_text(encoding="utf-8")).get("suite")
            except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
                continue  # a damaged row says nothing (and is run again)
            if isinstance(name, str) and name:
                found.add(name)
                if name not in running:
                    break
    return sorted(found), "runs/*.json"


def _check_results_folder(out: Path, running: Sequence[str]) -> None:
    """Refuse ``out`` when it holds results of a suite other than the one being run."""
    wanted = set(running)
    if not wanted or not out.is_dir():
        return
    found, where = _suites_in(out, wanted)
    foreign = [name for name in found if name not in wanted]
    if not foreign:
        return
    theirs = ", ".join(repr(name) for name in foreign)
    ours = ", ".join(repr(name) for name in sorted(wanted))
    raise ValueError(
        f"out folder {str(out)!r} holds results of suite {theirs} (its {where}), not of "
        f"suite {ours} being run; writing there would mix the two suites' results "
        f"(and leave the other's report): choose another --out folder, or remove "
        f"{str(out)!r} first"
    )


def _one_thread() -> None:
    """Pool-worker start: one BLAS thread per process, and Ctrl-C left to the main process.

    Several workers each spinning a BLAS thread pool on few cores slow the small
    matrix exponentials of every run down a hundredfold (measured: 8 quick performance
    runs took 342 s instead of 25 s on 2 cores). Ctrl-C reaches every process of the
    terminal's group: a worker ignores it (else each prints its own traceback), and the
    main process stops the workers (see :func:`_stop_pool`), with SIGTERM: a worker
    forked from a process that set its own SIGTERM handler (``ray.init`` sets one that
    raises ``SystemExit``) inherits it, and the executor's worker loop would catch that
    exit as the run's failure and start the next run instead of stopping.
    """
    from threadpoolctl import threadpool_limits

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    threadpool_limits(1)
    _keep_freed_memory()


#: glibc's ``mallopt`` parameters (``malloc.h``) and the values a pool worker sets:
#: blocks up to 32 MiB (glibc's largest threshold on 64 bits) from the heap, and the
#: heap's top kept up to 1 GiB free before it is given back.
_MALLOPT = {"M_TRIM_THRESHOLD": (-1, 1 << 30), "M_MMAP_THRESHOLD": (-3, 32 << 20)}


def _keep_freed_memory() -> bool:
    """A pool worker keeps the memory it frees for its next run (glibc); True if set.

    A run makes and frees arrays of megabytes (a matrix per sample, thousands of
    samples). By default glibc maps each such block afresh and unmaps it when freed,
    or trims the heap's top, so the next run takes the same memory back from the
    system a zeroed page at a time: thousands of page faults a run, most of its system
    time. A worker runs one run after another and lives for the suite only, so it keeps
    what it freed instead; its memory stays at its largest run's. Both parameters are
    needed: a high mapping threshold alone moves the blocks to the heap, whose top is
    then trimmed and faulted in again. Elsewhere than glibc nothing is changed.
    """
    import ctypes

    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    except (OSError, AttributeError):  # another C library: its own defaults
        return False
    return all(mallopt(parameter, value) == 1 for parameter, value in _MALLOPT.values())


def _one_thread_here() -> Any:
    """One BLAS thread in this process while it runs a scenario (see :func:`_one_thread`)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(1)


def _pool_context() -> Any:
    """Fork where it is safe (Linux), so workers inherit the parent's compiled kernels.

    Elsewhere the platform's default start method; workers then load the kernels from
    the numba cache the parent's first run wrote, instead of compiling them again.
    """
    if sys.platform.startswith("linux"):
        return multiprocessing.get_context("fork")
    return None


# a worker that SIGTERM stops is gone in milliseconds (measured: 0.03 s for two)
_TERMINATE_GRACE_SECONDS = 2.0


def _stop_pool(pool: ProcessPoolExecutor, out: Path) -> None:
    """Cancel the runs not started, stop the workers at once, and tidy what they left.

    The workers ignore Ctrl-C and would finish their runs first; they are terminated
    instead, and killed where SIGTERM did not stop them within
    ``_TERMINATE_GRACE_SECONDS`` (a worker whose SIGTERM handler raises ``SystemExit``
    lives on: the executor's loop catches the exit as a failed run and takes the next).
    Every stored file is written atomically, so a run cut short leaves only its
    temporary file (``.<name>.*.part*`` in ``runs/``), removed here.
    """
    # the executor keeps its worker processes and its manager thread here (CPython) and
    # forgets them on shutdown
    workers = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for worker in workers:
        if worker.is_alive():
            worker.terminate()
    deadline = time.monotonic() + _TERMINATE_GRACE_SECONDS  # one grace for them all
    for worker in workers:
        worker.join(timeout=max(0.0, deadline - time.monotonic()))
    survivors = [worker for worker in workers if worker.is_alive()]
    for worker in survivors:
        worker.kill()
    for worker in survivors:
        worker.join(timeout=5.0)
    # the manager thread closes its wake-up pipe as it ends; left running, it races the
    # interpreter's exit hook, which writes to that pipe, and a closed one printed
    # "Exception ignored ... Bad file descriptor" after the interrupt's own message
    if manager is not None:
        manager.join(timeout=5.0)
    for leftover in (out / "runs").glob(".*.part*"):
        leftover.unlink(missing_ok=True)


def _run_with_ray(
    groups: Sequence[Sequence[Scenario]], out: Path
) -> Iterable[list[dict[str, Any]]]:
    """Every row of ``groups``, a Ray task's rows at a time (tasks: :func:`_chunks`)."""
    try:
        import ray
    except ImportError as error:
        raise RuntimeError(
            "the ray backend needs Ray: pip install 'manualcontrol[dist]'"
        ) from error
    if not ray.is_initialized():
        ray.init(
            address=os.environ.get("RAY_ADDRESS"), ignore_reinit_error=True, log_to_driver=False
        )
    # tasks of whole seeds, as the process pool's, cut for the cluster's cores
    # a cluster that lists no CPU yet (an autoscaler's head) gets a task per group
    cores = int(ray.cluster_resources().get("CPU", 0)) or max(1, len(groups))
    remote = ray.remote(_run_chunk)
    pending = [remote.remote(chunk, out) for chunk in _chunks(groups, cores)]
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        yield ray.get(ready[0])


def run_suite(
    suite: Suite | Sequence[Scenario],
    out: str | Path,
    *,
    backend: str = "process",
    workers: int | None = None,
    quick: bool = False,
    progress: Callable[[int, int, dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Run every scenario (resuming finished ones) and write the results table.

    ``progress(done, total, row)`` is called after each run. Returns the rows in the
    suite's scenario order. Raises ``ValueError`` before writing anything when ``out``
    holds results of another suite (see the module docstring).
    """
    check_choice("backend", backend, BACKENDS)
    if workers is not None:
        check_int("workers", workers, minimum=1)  # before any folder is made
    scenarios = suite.scenarios(quick) if isinstance(suite, Suite) else list(suite)
    out = Path(out)
    running = [suite.name] if isinstance(suite, Suite) else [s.suite for s in scenarios]
    _check_results_folder(out, running)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    rows = _done_rows(out, scenarios)
    todo = [scenario for scenario in scenarios if scenario.key not in rows]
    total, done = len(scenarios), len(rows)
    if progress is not None and done:
        progress(done, total, {})

    def collect(row: dict[str, Any]) -> None:
        nonlocal done
        # as stored (NaN -> null): a fresh row then equals the same row resumed
        rows[row["key"]] = json.loads(json.dumps(_json_safe(row)))
        done += 1
        if progress is not None:
            progress(done, total, row)

    try:
        _run_groups(_groups(todo), out, backend, workers, collect)
    except KeyboardInterrupt:
        kept = len(_done_rows(out, scenarios))  # what the workers stored counts too
        raise SuiteInterrupted(kept, total, out) from None
    ordered = [rows[scenario.key] for scenario in scenarios]
    write_table(ordered, out)
    return ordered


def _run_groups(
    groups: Sequence[Sequence[Scenario]],
    out: Path,
    backend: str,
    workers: int | None,
    collect: Callable[[dict[str, Any]], None],
) -> None:
    """Run every group with ``backend``, handing each row to ``collect`` as it comes."""
    if backend == "inprocess" or (backend == "process" and len(groups) <= 1):
        for rows in run_scenario_groups(groups, out):
            for row in rows:
                collect(row)
    elif backend == "process":
        count = (
            check_int("workers", workers, minimum=1)
            if workers is not None
            else (os.cpu_count() or 1)
        )
        # Compile once: the first simulation here, before the pool starts, compiles every
        # kernel a run uses (or loads them from numba's cache) and writes the cache;
        # forked workers inherit the compiled code, spawned ones load the cache.
        with _one_thread_here():
            for row in run_scenarios(groups[0], out):
                collect(row)
        chunks = _chunks(groups[1:], count)
        if chunks:
            pool = ProcessPoolExecutor(
                max_workers=min(count, len(chunks)),
                initializer=_one_thread,
                mp_context=_pool_context(),
            )
            try:
                futures = [pool.submit(_run_chunk, chunk, out) for chunk in chunks]
                for future in as_completed(futures):
                    for row in future.result():
                        collect(row)
            except BaseException:
                _stop_pool(pool, out)
                raise
            pool.shutdown(wait=True)
    else:
        for group_rows in _run_with_ray(groups, out):
            for row in group_rows:
                collect(row)


#: Tasks per worker the process pool's groups are cut into: more balance the workers'
#: loads at the end of a suite, fewer share more of each Monte Carlo's simulations.
_CHUNKS_PER_WORKER = 8


def _chunks(groups: Sequence[Sequence[Scenario]], workers: int) -> list[list[Sequence[Scenario]]]:
    """The pool's tasks: a pilot's Monte Carlo runs, seed by seed.

    A task holds about ``1 / (8 workers)`` of the groups, so the workers end the suite
    about together (and progress is reported a task at a time). Seeds are added to it
    whole, every realisation of each: a task of ``k`` seeds and ``R`` realisations steps
    each of its loops ``R + k`` times instead of ``2 k R`` (see
    :func:`~manualcontrol.pilots.simulate_many`). A seed with more realisations than a
    task holds is cut into tasks of its realisations, each stepping that seed's
    remnant once. Results do not depend on the cutting: each row is stored under its
    own key and the table keeps the suite's order.
    """
    families: dict[Any, dict[Any, list[Sequence[Scenario]]]] = {}
    for index, group in enumerate(groups):
        key = _monte_carlo_key(group[0])
        seeds = families.setdefault(("alone", index) if key is None else key, {})
        seeds.setdefault(group[0].remnant_seed, []).append(group)
    size = max(1, math.ceil(len(groups) / (workers * _CHUNKS_PER_WORKER)))
    tasks: list[list[Sequence[Scenario]]] = []
    for seeds in families.values():
        task: list[Sequence[Scenario]] = []
        for seed_groups in seeds.values():  # as the suite lists them
            if len(seed_groups) > size:
                # as few tasks as the size allows, their sizes differing by one at most
                count, pieces = len(seed_groups), math.ceil(len(seed_groups) / size)
                cuts = [count * j // pieces for j in range(pieces + 1)]
                tasks.extend(seed_groups[a:b] for a, b in itertools.pairwise(cuts))
                continue
            task.extend(seed_groups)
            if len(task) >= size:
                tasks.append(task)
                task = []
        if task:
            tasks.append(task)
    return tasks


def write_table(rows: Sequence[Mapping[str, Any]], out: str | Path) -> tuple[Path, Path | None]:
    """Write ``results.csv`` (and ``results.parquet`` when pyarrow is installed)."""
    import csv
    import io

    out = Path(out)
    # one scalar per cell: traces (moving VAF) and the scenario stay in runs/<key>.json
    flat = [
        {
            k: v
            for k, v in row.items()
            if not isinstance(v, (list, tuple, dict)) and k != "traceback"
        }
        for row in rows
    ]
    columns: list[str] = []
    for row in flat:
        for key in row:
            if key not in columns:
                columns.append(key)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, restval="")
    writer.writeheader()
    for row in flat:
        writer.writerow({k: ("" if v is None else v) for k, v in row.items()})
    csv_path = atomic_write(out / "results.csv", lambda p: p.write_text(buffer.getvalue()))
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return csv_path, None
    table = pa.Table.from_pylist([{c: row.get(c) for c in columns} for row in flat])
    parquet_path = atomic_write(out / "results.parquet", lambda p: pq.write_table(table, p))
    return csv_path, parquet_path
