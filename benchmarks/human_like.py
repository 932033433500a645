"""The human-like suite's verdict per estimator: the frequency response and the limits.

Reads a ``results.csv`` of ``manualcontrol bench human-like`` (runs the suite into
``results/human-like`` first when none is given) and prints, per batch and estimator,
the medians of the identified frequency response's gap to the true pilot's at the
forcing frequencies (mean absolute gain, dB, and phase, degrees), the share of runs
within 2 dB and 10 degrees, the largest share of a run any parameter spent at a limit,
and the median relative bias of the delay and the neuromuscular frequency; then the
totals per estimator, the online filter and its smoothed twin apart.

Run: .venv/bin/python benchmarks/human_like.py [results.csv]
"""

import csv
import math
import statistics
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

PASS_GAIN_DB, PASS_PHASE_DEG = 2.0, 10.0


def number(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def main(argv):
    if argv:
        table = Path(argv[0])
    else:
        out = Path("results/human-like")
        subprocess.run(
            [
                sys.executable,
                "-m",
                "manualcontrol.bench.cli",
                "bench",
                "human-like",
                "--out",
                str(out),
                "--quiet",
            ],
            check=True,
        )
        table = out / "results.csv"
    rows = list(csv.DictReader(table.open()))
    groups = defaultdict(list)
    for row in rows:
        groups[(row["batch"], row["estimator"])].append(row)
    print(
        f"{'batch':36s} {'estimator':13s} {'runs':>4s} {'dB':>6s} {'deg':>6s} {'pass':>5s} "
        f"{'at limit':>8s} {'tau_v bias':>10s} {'omega_nms bias':>14s}"
    )
    totals = defaultdict(lambda: [0, 0, 0.0])
    for (batch, estimator), members in sorted(groups.items()):
        gain = [number(r["frequency_gain_error_db"]) for r in members]
        phase = [number(r["frequency_phase_error_deg"]) for r in members]
        passed = sum(
            g <= PASS_GAIN_DB and p <= PASS_PHASE_DEG for g, p in zip(gain, phase, strict=True)
        )
        at_limit = max(number(r["max_time_at_limit"]) for r in members)
        tau = statistics.median(number(r.get("rel_bias_tau_v")) for r in members)
        omega = statistics.median(number(r.get("rel_bias_omega_nms")) for r in members)
        total = totals[estimator]
        total[0] += passed
        total[1] += len(members)
        total[2] = max(total[2], at_limit)
        print(
            f"{batch:36s} {estimator:13s} {len(members):4d} {statistics.median(gain):6.2f} "
            f"{statistics.median(phase):6.1f} {100 * passed / len(members):4.0f}% "
            f"{100 * at_limit:7.0f}% {tau:+10.2f} {omega:+14.2f}"
        )
    print()
    for estimator, (passed, count, at_limit) in sorted(totals.items()):
        print(
            f"{estimator:13s} within {PASS_GAIN_DB:g} dB and {PASS_PHASE_DEG:g} deg: "
            f"{passed}/{count} runs ({100 * passed / count:.0f} %); largest share of a run "
            f"at a limit {100 * at_limit:.0f} %"
        )


if __name__ == "__main__":
    main(sys.argv[1:])
