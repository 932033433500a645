"""``make demo``: the main job on its embedded default, quickly.

Runs the quick version of every built-in benchmark suite (one forcing and one remnant
realisation per batch: the papers' simulation studies in miniature), writes each
suite's results table and report under ``results/demo/`` and an index page linking
them, and prints where they are. The full suites are ``manualcontrol bench SUITE``
(see ``manualcontrol suites``).

Where processes fork (Linux) the suites run in streams at once, one process each and
as many as ``--workers`` (default: the number of cores) or suites allow; a stream runs
its suites on its share of the workers and takes the next (the most runs first) as it
finishes one, and each suite's report is drawn by a child process while
its stream goes on: drawing the figures costs about as much as the runs. On a fresh
clone the streams also compile the family's kernels side by side instead of one after
another.
Elsewhere the suites run one after the other on the process pool.

Ctrl-C stops every stream with one line per suite it was running (the runs kept) and
no traceback; running the demo again resumes each suite from its stored runs.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import signal
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from manualcontrol.bench.cli import positive_int
from manualcontrol.bench.report import pyplot, write_report
from manualcontrol.bench.runner import SuiteInterrupted, run_suite
from manualcontrol.bench.scenarios import BUILTIN_SUITES, Suite, load_suite
from manualcontrol.envs._files import atomic_write


def _write_report_here(suite: Suite, rows: list[dict[str, Any]], folder: Path) -> None:
    """A report child's body: write the report; a failure is its exit status."""
    try:
        write_report(suite, rows, folder)
    except KeyboardInterrupt:  # Ctrl-C: the demo says it once
        raise SystemExit(130) from None
    except BaseException:
        traceback.print_exc()
        raise SystemExit(1) from None


def _progress(name: str) -> Any:
    def progress(done: int, total: int, row: dict) -> None:
        # one line per run: make shows it at once, no progress bar needed
        state = "" if row.get("status", "ok") == "ok" else f" ({row.get('error', '')})"
        print(f"  {name}: {done}/{total}{state}", flush=True)

    return progress


def _run_stream(
    suites: dict[str, Suite],
    names: Any,
    out: Path,
    forked: bool,
    results: Any,
    workers: int = 1,
) -> None:
    """Run ``names`` one after the other; put ``(name, runs, failed, report_ok)`` each.

    ``names``: a list, or a queue shared by the streams, read until it gives None. Each
    suite runs on ``workers`` processes (in this one when 1). With ``forked`` each
    report is drawn by a forked child while the next suite runs; otherwise here. What
    finished is put even when a later suite raises.
    """
    if forked:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)  # one BLAS thread a stream (see runner._one_thread)
    children = []
    if not isinstance(names, list):
        names = iter(names.get, None)
    try:
        for name in names:
            suite, folder = suites[name], out / name
            print(f"{name}: {len(suite.scenarios(quick=True))} runs ...", flush=True)
            backend = "inprocess" if workers == 1 else "process"
            try:
                rows = run_suite(
                    suite,
                    folder,
                    quick=True,
                    backend=backend,
                    workers=workers,
                    progress=_progress(name),
                )
            except SuiteInterrupted as stop:
                print(f"{name}: interrupted: {stop.done} of {stop.total} runs kept", flush=True)
                raise
            bad = sum(row.get("status") != "ok" for row in rows)
            if forked:
                child = multiprocessing.get_context("fork").Process(
                    target=_write_report_here, args=(suite, rows, folder)
                )
                child.start()
                children.append((name, len(rows), bad, child))
            else:
                write_report(suite, rows, folder)
                _said_done(name, len(rows), bad, True, out)
                results.put((name, len(rows), bad, True))
    except KeyboardInterrupt:
        if forked:  # a stream ends quietly, no traceback; the demo says the rest
            raise SystemExit(130) from None
        raise
    finally:
        if forked:  # only waiting now: a Ctrl-C reaches the report children themselves
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        for name, runs, bad, child in children:
            child.join()
            if child.exitcode == 130:
                print(f"{name}: {runs} runs; its report was interrupted", flush=True)
                continue
            _said_done(name, runs, bad, child.exitcode == 0, out)
            results.put((name, runs, bad, child.exitcode == 0))


def _said_done(name: str, runs: int, bad: int, report_ok: bool, out: Path) -> None:
    state = f"-> {out / name / 'report.md'}" if report_ok else "(the report failed, see above)"
    print(f"{name}: {runs} runs, {bad} failed {state}", flush=True)


def _interrupted(out: Path) -> int:
    print(
        f"demo: interrupted (Ctrl-C); the runs so far are kept under {out}: run the demo "
        "again to resume",
        flush=True,
    )
    return 130


class _Collected(list):
    """What a stream run in this process reports (the ``put`` of a queue)."""

    put = list.append


def main(argv: list[str] | None = None) -> int:
    """Run the quick suites; return 0 when every run succeeded, 3 otherwise (130: Ctrl-C)."""
    parser = argparse.ArgumentParser(
        prog="python -m manualcontrol.bench.demo", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--out", type=Path, default=Path("results/demo"), help="output folder")
    parser.add_argument(
        "--workers", type=positive_int, default=None, help="processes in all (default: cores)"
    )
    parser.add_argument(
        "--suite", action="append", choices=BUILTIN_SUITES, help="only these suites (repeatable)"
    )
    args = parser.parse_args(argv)
    workers = args.workers or os.cpu_count() or 1
    started = time.perf_counter()
    suites = {name: load_suite(name) for name in args.suite or BUILTIN_SUITES}
    counts = {name: len(suite.scenarios(quick=True)) for name, suite in suites.items()}
    if sys.platform.startswith("linux"):
        pyplot()  # imported once here, not in every child
        context = multiprocessing.get_context("fork")
        results, tasks = context.SimpleQueue(), context.SimpleQueue()
        # the streams take the next suite as they finish one, the most runs first
        for name in sorted(suites, key=lambda name: -counts[name]):
            tasks.put(name)
        count = min(workers, len(suites))
        for _ in range(count):
            tasks.put(None)
        # more cores than suites: each stream runs its suites on a pool of its share
        share = workers // count
        streams = [
            context.Process(
                target=_run_stream, args=(suites, tasks, args.out, True, results, share)
            )
            for _ in range(count)
        ]
        for stream in streams:
            stream.start()
        try:
            for stream in streams:  # what a stream puts is a few bytes: it never waits for us
                stream.join()
        except KeyboardInterrupt:  # the streams had it too: each ends with its own line
            for stream in streams:
                stream.join()
            return _interrupted(args.out)
        collected = []
        while not results.empty():
            collected.append(results.get())
    else:
        collected = _Collected()
        order = sorted(suites, key=lambda name: -counts[name])
        try:
            _run_stream(suites, order, args.out, False, collected, workers)
        except KeyboardInterrupt:
            return _interrupted(args.out)
    summary = {name: (runs, bad, ok) for name, runs, bad, ok in collected}
    for name in suites:
        if name not in summary:  # its stream died before it finished
            print(f"{name}: did not finish (see the errors above)", flush=True)
            summary[name] = (counts[name], counts[name], False)
    lines = ["# manualcontrol demo: the built-in suites, quick", ""]
    for name in sorted(summary):
        runs, bad, ok = summary[name]
        report = f"[{name}]({name}/report.md)" if ok else f"{name} (report failed)"
        lines.append(f"- {report}: {runs} runs, {bad} failed. {suites[name].description}")
    lines += [
        "",
        f"These quick subsets took {time.perf_counter() - started:.0f} s here. The full "
        "suites (hundreds of runs each) are `.venv/bin/manualcontrol bench SUITE`.",
    ]
    index = atomic_write(args.out / "README.md", lambda p: p.write_text("\n".join(lines) + "\n"))
    print(f"index: {index}")
    failed = sum(bad for _, bad, _ in summary.values())
    reports_ok = all(ok for _, _, ok in summary.values())
    return 0 if not failed and reports_ok else 3


if __name__ == "__main__":
    sys.exit(main())
