"""Report section of the ``zhao2019`` suite: Zhao et al. (2019) side by side.

Batches carry ``drive``, ``condition`` and ``member`` in their ``reference`` table; this
module groups them into one table per condition (drives down, UKF1, UKF2 and the
multi-UKF across: NRMSE, the lag and noise of the paper's Sec. 5 discussion, the drift
on the straight) and one figure per condition and drive in the layout of the paper's
Figs. 5-7 and 10-11 (each member's estimate of ``K_p`` and ``K_c`` against the truth,
the perception angles below). It also checks Algorithm 3's observer poles at the
paper's 1 ms (eqs. 17-18).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from manualcontrol.bench import runner
from manualcontrol.bench.report import draw_trace, save_figure, subplots
from manualcontrol.bench.scenarios import scenario_from_dict
from manualcontrol.estimators.members.zhao_ukf import ZhaoUKFSettings, zhao_tuning
from manualcontrol.estimators.protocol import load_result

__all__ = ["report_section"]

MEMBERS = ("UKF1", "UKF2", "multi-UKF")
PARAMETERS = ("K_p", "K_c")
_COLOURS = {"UKF1": "tab:blue", "UKF2": "tab:orange", "multi-UKF": "k"}


def _mean(rows: Sequence[Mapping[str, Any]], key: str) -> float:
    values = []
    for row in rows:
        try:
            value = float(row.get(key))
        except (TypeError, ValueError):
            continue
        if math.isfinite(value):
            values.append(value)
    return float(np.mean(values)) if values else math.nan


def _cell(value: float, digits: int = 4, bold: bool = False) -> str:
    if not math.isfinite(value):
        return "—"
    text = f"{value:.{digits}f}"
    return f"**{text}**" if bold else text


def _groups(suite: Any, rows: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, dict[str, list]]]:
    """Condition -> drive -> member -> successful rows."""
    groups: dict[str, dict[str, dict[str, list]]] = {}
    for batch in suite.batches:
        reference = dict(batch.reference)
        if not {"drive", "condition", "member"} <= set(reference):
            continue
        ok = [r for r in rows if r.get("batch") == batch.name and r.get("status") == "ok"]
        condition = groups.setdefault(reference["condition"], {})
        condition.setdefault(reference["drive"], {})[reference["member"]] = ok
    return groups


def _table(drives: Mapping[str, Mapping[str, list]]) -> list[str]:
    lines = [
        "| drive | member | NRMSE K_p | NRMSE K_c | lag K_p (s) | lag K_c (s) | noise K_p | "
        "noise K_c | straight drift K_p | straight drift K_c | runs |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for drive, members in drives.items():
        best = {
            name: min(
                (_mean(members.get(m, []), f"nrmse_{name}") for m in MEMBERS),
                key=lambda v: v if math.isfinite(v) else math.inf,
            )
            for name in PARAMETERS
        }
        for member in MEMBERS:
            runs = members.get(member)
            if not runs:
                continue
            cells = [
                _cell(_mean(runs, f"nrmse_{n}"), bold=_mean(runs, f"nrmse_{n}") == best[n])
                for n in PARAMETERS
            ]
            cells += [_cell(_mean(runs, f"lag_{n}"), 2) for n in PARAMETERS]
            cells += [_cell(_mean(runs, f"noise_{n}")) for n in PARAMETERS]
            cells += [_cell(100 * _mean(runs, f"straight_drift_{n}"), 2) + " %" for n in PARAMETERS]
            lines.append(f"| {drive} | {member} | " + " | ".join(cells) + f" | {len(runs)} |")
    return lines


def _figure(condition: str, drive: str, members: Mapping[str, list], out: Path) -> Path | None:
    results = {}
    recording = None
    for member in MEMBERS:
        runs = members.get(member) or []
        if not runs:
            continue
        path = out / "runs" / f"{runs[0]['key']}.npz"
        if not path.is_file():
            continue
        results[member] = load_result(path)
        if recording is None:
            recording = runner.simulate_scenario(scenario_from_dict(runs[0]["scenario"]))
    if not results or recording is None:
        return None
    fig, axes = subplots(3, 1, reusable=True, figsize=(10, 7.5), sharex=True)
    for axis, name in zip(axes, PARAMETERS, strict=False):
        draw_trace(
            axis, recording.t, recording.parameters[name], color="tab:red", lw=1.6, label="true"
        )
        for member, result in results.items():
            draw_trace(
                axis, result.t, result.mean_of(name), color=_COLOURS[member], lw=0.9, label=member
            )
        axis.set_ylabel(name)
    axes[0].legend(loc="upper left", fontsize=8, ncol=4)
    draw_trace(axes[2], recording.t, recording["theta_far"], lw=0.8, label=r"$\theta_{far}$")
    draw_trace(axes[2], recording.t, recording["theta_near"], lw=0.8, label=r"$\theta_{near}$")
    axes[2].set_ylabel("rad")
    axes[2].legend(loc="upper left", fontsize=8)
    axes[2].set_xlabel("time [s]")
    axes[0].set_title(f"zhao2019: {drive}, {condition} (first run of each member)")
    slug = f"zhao2019-{drive}-{condition}".replace(" ", "").replace(",", "-").replace("=", "")
    slug = "".join(c for c in slug if c.isalnum() or c in "-_.")
    return save_figure(fig, out / "figures" / f"{slug}.png")


def report_section(suite: Any, rows: Sequence[Mapping[str, Any]], out: str | Path) -> list[str]:
    """Markdown lines (and figures under ``out/figures``) for the zhao2019 suite."""
    out = Path(out)
    poles = zhao_tuning(ZhaoUKFSettings(), 0.001, 18.0).observer_poles()
    lines = [
        "## Zhao et al. (2019): UKF1, UKF2 and the multi-UKF",
        "",
        "Observer poles of Algorithm 3 with the paper's tuning at T_s = 1 ms (eqs. 17-18, "
        "Table 2's v_x = 18 m/s): "
        + ", ".join(f"{z.real:.2f}" for z in poles)
        + " rad/s (the paper: about -1, -10, -50).",
        "",
        "NRMSE from 20 s (thesis eq. 37; the best per drive in bold); lag: the delay that "
        "best aligns the estimate with the truth's change; noise: RMS about the 2-s moving "
        "average, relative; straight drift: the largest change on the 74-89 s straight.",
        "",
    ]
    for condition, drives in _groups(suite, rows).items():
        lines += [f"### {condition}", "", *_table(drives), ""]
        for drive, members in drives.items():
            figure = _figure(condition, drive, members, out)
            if figure is not None:
                lines += [f"![{drive}, {condition}](figures/{figure.name})", ""]
    return lines
