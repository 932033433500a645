"""``make demo``: the main job on its embedded default, quickly.

Runs the quick version of every built-in benchmark suite (one forcing and one remnant
realisation per batch: the papers' simulation studies in miniature) with the local
process pool, writes each suite's results table and report under ``results/demo/``
and an index page linking them, and prints where they are. The full suites are
``manualcontrol bench SUITE`` (see ``manualcontrol suites``).

Where processes fork (Linux), each suite's report is written by a child process while
the next suite runs: drawing the figures costs as much as the runs, and the two
overlap. Suites with the most runs go first, so the last reports to wait for are
small ones.
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from manualcontrol.bench.report import _pyplot, write_report
from manualcontrol.bench.runner import run_suite
from manualcontrol.bench.scenarios import BUILTIN_SUITES, Suite, load_suite
from manualcontrol.envs._files import atomic_write


def _write_report_here(suite: Suite, rows: list[dict[str, Any]], folder: Path) -> None:
    """A report child's body: write the report; a failure is its exit status."""
    try:
        write_report(suite, rows, folder)
    except BaseException:
        traceback.print_exc()
        raise SystemExit(1) from None


def _report_writer() -> Any:
    """``Process`` factory for the report children, or None where forking is not safe."""
    if not sys.platform.startswith("linux"):
        return None
    _pyplot()  # imported once here, not in every child
    return multiprocessing.get_context("fork").Process


def main(argv: list[str] | None = None) -> int:
    """Run the quick suites; return 0 when every run succeeded, 3 otherwise."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/demo"), help="output folder")
    parser.add_argument("--workers", type=int, default=None, help="process-pool size")
    parser.add_argument(
        "--suite", action="append", choices=BUILTIN_SUITES, help="only these suites (repeatable)"
    )
    args = parser.parse_args(argv)
    started = time.perf_counter()
    suites = {name: load_suite(name) for name in args.suite or BUILTIN_SUITES}
    counts = {name: len(suite.scenarios(quick=True)) for name, suite in suites.items()}
    order = sorted(suites, key=lambda name: -counts[name])
    writer = _report_writer()
    pending: dict[str, tuple[Any, int, int]] = {}
    summary: dict[str, tuple[int, int, bool]] = {}

    def finish(name: str) -> None:
        child, runs, bad = pending.pop(name)
        ok = True
        if child is not None:
            child.join()
            ok = child.exitcode == 0
        summary[name] = (runs, bad, ok)
        state = f"-> {args.out / name / 'report.md'}" if ok else "(the report failed, see above)"
        print(f"{name}: {runs} runs, {bad} failed {state}", flush=True)

    for name in order:
        suite = suites[name]
        folder = args.out / name
        print(f"{name}: {counts[name]} runs ...", flush=True)

        def progress(done: int, total: int, row: dict, name: str = name) -> None:
            # one line per run: make shows it at once, no progress bar needed
            state = "" if row.get("status", "ok") == "ok" else f" ({row.get('error', '')})"
            print(f"  {name}: {done}/{total}{state}", flush=True)

        rows = run_suite(suite, folder, quick=True, workers=args.workers, progress=progress)
        bad = sum(row.get("status") != "ok" for row in rows)
        child = None
        if writer is None:
            write_report(suite, rows, folder)
        else:
            child = writer(target=_write_report_here, args=(suite, rows, folder))
            child.start()
        pending[name] = (child, len(rows), bad)
        for done in [n for n, (c, _, _) in pending.items() if c is None or not c.is_alive()]:
            finish(done)
    for name in list(pending):
        finish(name)
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
