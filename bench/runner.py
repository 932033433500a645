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

Each scenario is seeded by its own settings only, so the numbers are identical
whatever the backend and the number of workers. Every finished run is stored at once
under ``<out>/runs/<key>.json`` (its row) and ``<key>.npz`` (the estimator's
traces); a suite run again skips those (resume), and a failing scenario is recorded
as failed with its error while the batch goes on. At the end the rows are written to
``results.csv`` and ``results.parquet``.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from manualcontrol.bench.scenarios import Scenario, Suite
from manualcontrol.envs._files import atomic_write
from manualcontrol.envs._validation import check_choice, check_int
from manualcontrol.envs.recording import Recording

__all__ = ["BACKENDS", "ESTIMATORS", "make_estimator", "run_scenario", "run_suite", "write_table"]

BACKENDS: tuple[str, ...] = ("process", "inprocess", "ray")


def _dekf(settings: Mapping[str, Any]) -> Any:
    from manualcontrol.estimators.dekf import DEKF, DEKFSettings

    return DEKF(DEKFSettings.from_dict(dict(settings)))


#: Estimators a scenario can name, each built from its settings table.
ESTIMATORS: dict[str, Callable[[Mapping[str, Any]], Any]] = {"dekf": _dekf}


def make_estimator(spec: Mapping[str, Any]) -> Any:
    """An estimator from ``{"name": ..., **settings}``."""
    spec = dict(spec)
    name = check_choice("estimator name", spec.pop("name", None), tuple(ESTIMATORS))
    return ESTIMATORS[name](spec)


def simulate_scenario(scenario: Scenario) -> Recording:
    """The scenario's simulated run, run-in kept (the estimator converges on it)."""
    from manualcontrol.pilots import simulate

    return simulate(
        scenario.build_pilot(),
        scenario.element,
        scenario.forcing,
        realisation=scenario.realisation,
        task=scenario.task,
        available_preview=scenario.available_preview,
        dt=scenario.dt,
        run_in=scenario.run_in,
        measurement_time=scenario.measurement_time,
        seed=scenario.remnant_seed,
        loop=scenario.loop,
        keep_run_in=True,
    )


def run_scenario(scenario: Scenario, out: Path | None = None) -> dict[str, Any]:
    """Simulate, estimate and score one scenario; return its results row.

    Errors become a row with ``status = "failed"`` and the message, never an exception.
    With ``out``, the row and the estimator's traces are stored under ``out/runs``.
    """
    from manualcontrol.bench.scoring import score

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
    started = time.perf_counter()
    try:
        recording = simulate_scenario(scenario)
        simulated = time.perf_counter()
        estimator = make_estimator(scenario.estimator)
        result = estimator.estimate(recording)
        finished = time.perf_counter()
        row.update(score(scenario, recording, result))
        row.update(
            status="ok",
            error="",
            simulation_time_s=simulated - started,
            estimation_time_s=finished - simulated,
        )
        if out is not None:
            result.save(out / "runs" / f"{scenario.key}.npz")
    except Exception as error:
        row.update(
            status="failed",
            error=f"{type(error).__name__}: {error}",
            traceback=traceback.format_exc(limit=6),
        )
    row["run_time_s"] = time.perf_counter() - started
    row["scenario"] = scenario.to_dict()
    if out is not None:
        text = json.dumps(_json_safe(row), indent=1)
        atomic_write(out / "runs" / f"{scenario.key}.json", lambda p: p.write_text(text))
    return row


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


def _one_thread() -> None:
    """Pool-worker start: one BLAS thread per process.

    Several workers each spinning a BLAS thread pool on few cores slow the small
    matrix exponentials of every run down a hundredfold (measured: 8 quick performance
    runs took 342 s instead of 25 s on 2 cores).
    """
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


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


def _run_with_ray(scenarios: Sequence[Scenario], out: Path) -> Iterable[dict[str, Any]]:
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
    remote = ray.remote(run_scenario)
    pending = [remote.remote(scenario, out) for scenario in scenarios]
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
    suite's scenario order.
    """
    check_choice("backend", backend, BACKENDS)
    scenarios = suite.scenarios(quick) if isinstance(suite, Suite) else list(suite)
    out = Path(out)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    rows = _done_rows(out, scenarios)
    todo = [scenario for scenario in scenarios if scenario.key not in rows]
    total, done = len(scenarios), len(rows)
    if progress is not None and done:
        progress(done, total, {})

    def collect(row: dict[str, Any]) -> None:
        nonlocal done
        rows[row["key"]] = row
        done += 1
        if progress is not None:
            progress(done, total, row)

    if backend == "inprocess" or (backend == "process" and len(todo) <= 1):
        for scenario in todo:
            collect(run_scenario(scenario, out))
    elif backend == "process":
        count = (
            check_int("workers", workers, minimum=1)
            if workers is not None
            else (os.cpu_count() or 1)
        )
        # Compile once: the first run here, before the pool starts, compiles every
        # kernel a run uses (or loads them from numba's cache) and writes the cache;
        # forked workers inherit the compiled code, spawned ones load the cache.
        with _one_thread_here():
            collect(run_scenario(todo[0], out))
        rest = todo[1:]
        if rest:
            with ProcessPoolExecutor(
                max_workers=min(count, len(rest)),
                initializer=_one_thread,
                mp_context=_pool_context(),
            ) as pool:
                futures = [pool.submit(run_scenario, scenario, out) for scenario in rest]
                for future in as_completed(futures):
                    collect(future.result())
    else:
        for row in _run_with_ray(todo, out):
            collect(row)
    ordered = [rows[scenario.key] for scenario in scenarios]
    write_table(ordered, out)
    return ordered


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
