"""``make demo``: the main job on its embedded default, quickly.

Runs the quick version of every built-in benchmark suite (one forcing and one remnant
realisation per batch: the papers' simulation studies in miniature) with the local
process pool, writes each suite's results table and report under ``results/demo/``
and an index page linking them, and prints where they are. The full suites are
``manualcontrol bench SUITE`` (see ``manualcontrol suites``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from manualcontrol.bench.report import write_report
from manualcontrol.bench.runner import run_suite
from manualcontrol.bench.scenarios import BUILTIN_SUITES, load_suite
from manualcontrol.envs._files import atomic_write


def main(argv: list[str] | None = None) -> int:
    """Run the quick suites; return 0 when every run succeeded, 3 otherwise."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/demo"), help="output folder")
    parser.add_argument("--workers", type=int, default=None, help="process-pool size")
    parser.add_argument(
        "--suite", action="append", choices=BUILTIN_SUITES, help="only these suites (repeatable)"
    )
    args = parser.parse_args(argv)
    lines = ["# manualcontrol demo: the built-in suites, quick", ""]
    failed = 0
    started = time.perf_counter()
    for name in args.suite or BUILTIN_SUITES:
        suite = load_suite(name)
        folder = args.out / name
        total = len(suite.scenarios(quick=True))
        print(f"{name}: {total} runs ...", flush=True)

        def progress(done: int, total: int, row: dict, name: str = name) -> None:
            # one line per run: make shows it at once, no progress bar needed
            state = "" if row.get("status", "ok") == "ok" else f" ({row.get('error', '')})"
            print(f"  {name}: {done}/{total}{state}", flush=True)

        rows = run_suite(suite, folder, quick=True, workers=args.workers, progress=progress)
        report = write_report(suite, rows, folder)
        bad = sum(row.get("status") != "ok" for row in rows)
        failed += bad
        print(f"{name}: {len(rows)} runs, {bad} failed -> {report}")
        lines.append(
            f"- [{name}]({name}/report.md): {len(rows)} runs, {bad} failed. {suite.description}"
        )
    lines += [
        "",
        f"These quick subsets took {time.perf_counter() - started:.0f} s here. The full "
        "suites (hundreds of runs each) are `.venv/bin/manualcontrol bench SUITE`.",
    ]
    index = atomic_write(args.out / "README.md", lambda p: p.write_text("\n".join(lines) + "\n"))
    print(f"index: {index}")
    return 0 if not failed else 3


if __name__ == "__main__":
    sys.exit(main())
