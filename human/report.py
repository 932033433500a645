"""After a session: one participant's runs described and identified, as a report.

:func:`write_session_report` reads a session folder (``session.json`` and the run
files that :func:`~manualcontrol.human.session.run_session` wrote) and writes
``<out>/<participant>/report/``:

``report.md``
    The session (protocol, digest, order, device, status); the RMS error of every run,
    practice and measurement, in the order flown (learning shows there); then per
    condition the describing function measured at the forcing frequencies over its
    measurement runs, and the parameters identified from each measurement run with
    their cross-checks.
``rms.png``, ``<condition>-describing-function.png``, ``<condition>-traces.png``
    RMS error per run; per condition the Bode plot of the describing function (each
    run and their mean) and the identified parameters' traces over time (each run).
``report.json``
    Everything the tables show, for programs.

The folder is written whole beside the old one, then moved into its place: a report
is complete or absent (or the previous one), never half-written.

Describing function
-------------------
Each measurement run's ``H_p = U/E`` at the forcing frequencies
(:func:`~manualcontrol.estimators.analysis.frequency.describing_function`, the last
whole forcing periods of the run). The condition's is the mean of the runs' complex
``H_p`` at each frequency; the spread is the standard deviation of the runs' gains (dB)
and phases (deg). Crossover frequency and phase margin are given per run. A run
shorter than one forcing period, or a two-channel task whose forcing has no
disturbance, has none (the report says why).

Identification
--------------
Each measurement run goes through :func:`~manualcontrol.estimators.analysis.identification.identify`
with the estimator docs/estimators.md recommends for a lab's trial identified as it
runs, ``rml``, given the experiment's element (the protocol's ``element``): the
precision model for a compensatory task, the preview model for pursuit (its pursuit
form, ``anticipation_time = 0``) and preview (``anticipation_time`` must be given:
``estimator_settings``). The forcing is passed, so the fit is checked against the
describing function, and the target ahead is read from it. What ``manualcontrol
identify`` reports is reported: final values, one-step and resimulated VAF, innovation
whiteness, the frequency-domain check, the closed loop's stability, parameters held at
generic values and the warnings. Postview and lane-keeping conditions are described
(RMS error) but not identified here.
"""

from __future__ import annotations

import contextlib
import json
import math
import shutil
import tempfile
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

# bench.report loads matplotlib (the optional ``plot`` extra) only inside its figure
# functions, on the first figure drawn
from manualcontrol.bench.report import draw_trace, save_figure, subplots
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair
from manualcontrol.estimators.analysis.frequency import describing_function
from manualcontrol.estimators.analysis.identification import build_estimator, identify
from manualcontrol.estimators.registry import ESTIMATORS
from manualcontrol.human.protocol import parse_protocol
from manualcontrol.human.session import load_manifest, rms_error_of
from manualcontrol.pilots.models import make_model

__all__ = ["REPORT_FOLDER", "SessionReport", "identify_run", "write_session_report"]

#: The report's folder in a participant's folder.
REPORT_FOLDER = "report"
#: The estimator the report identifies with (docs/estimators.md, "Which one").
DEFAULT_ESTIMATOR = "rml"
_PILOT_MODEL = {"compensatory": "precision", "pursuit": "preview", "preview": "preview"}


@dataclass(frozen=True)
class SessionReport:
    """A written report: its folder, the markdown file, the figures and the data."""

    folder: Path
    markdown: Path
    figures: tuple[Path, ...]
    data: Mapping[str, Any]


def _clean(value: Any) -> Any:
    """JSON-able: NaN and infinities as None, numpy scalars as floats."""
    if isinstance(value, Mapping):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def _fixed(value: Any, decimals: int = 1) -> str:
    if value is None or not math.isfinite(float(value)):
        return "n/a"
    return f"{float(value):.{decimals}f}"


def _fmt(value: Any, digits: int = 4) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, float, np.floating)):
        value = float(value)
        return f"{value:.{digits}g}" if math.isfinite(value) else "n/a"
    return str(value)


# ------------------------------------------------------------------ identification


def _effective_settings(condition: Any, settings: Mapping[str, Any] | None) -> dict[str, Any]:
    """The estimator's settings for the condition: a pursuit fit has no anticipation."""
    settings = dict(settings or {})
    if condition.task == "pursuit":
        settings.setdefault("anticipation_time", 0.0)
    return settings


def identify_run(
    recording: Any,
    condition: Any,
    *,
    estimator: str = DEFAULT_ESTIMATOR,
    settings: Mapping[str, Any] | None = None,
) -> Any:
    """One run through :func:`identify` as the report does it (module docstring).

    ``condition`` is the run's :class:`~manualcontrol.human.protocol.Condition`. Raises
    ``ValueError`` for a task the report does not identify or a missing setting.
    """
    model = _PILOT_MODEL.get(condition.task)
    if model is None:
        raise ValueError(
            f"a {condition.task} run is not identified here (no pilot-model member of the "
            "family for it; see docs/estimators.md)"
        )
    settings = _effective_settings(condition, settings)
    if condition.task == "preview" and "anticipation_time" not in settings:
        raise ValueError(
            "the preview model needs anticipation_time (s): give it per condition, e.g. "
            f"estimator_settings={{{condition.name!r}: {{'anticipation_time': 0.9}}}}"
        )
    element = condition.options["element"]
    forcing = ForcingPair.from_dict(recording.metadata["forcing"])
    pilot_model = ESTIMATORS[estimator].pilot_model if estimator in ESTIMATORS else False
    built = build_estimator(
        estimator, settings, model=model if pilot_model else None, element=element
    )
    target = {"forcing": forcing} if pilot_model and model == "preview" else {}
    return identify(
        recording,
        built,
        element=element,
        target=target,
        forcing=forcing,
        disturbance_at=condition.options.get("disturbance_at", "output"),
    )


#: Said beside a pure gain's identification with the lag-less precision model.
_LAG_CAUTION = (
    "On a pure gain humans equalise with a lag (McRuer & Jex 1967), which the precision "
    "model lacks: these values describe the lag-less model, and its frequency check says "
    "how far that is from the measured describing function. `manualcontrol describe` fits "
    "the precision model with its lag (`precision-lag`) to a run."
)


def _describing(recordings: Sequence[tuple[int, Any]], condition: Any) -> dict[str, Any]:
    """Each measurement run's describing function and the condition's mean."""
    runs, notes, functions = [], [], []
    for number, recording in recordings:
        try:
            describing = describing_function(
                recording,
                ForcingPair.from_dict(recording.metadata["forcing"]),
                element=condition.options["element"],
                disturbance_at=condition.options.get("disturbance_at", "output"),
                task=condition.task,
            )
        except (ValueError, KeyError) as error:
            notes.append({"run": number, "note": str(error)})
            continue
        functions.append((number, describing))
        runs.append(
            {
                "run": number,
                "crossover_frequency": describing.crossover_frequency,
                "phase_margin": describing.phase_margin,
                "remnant_share": describing.remnant_share,
                "periods": describing.periods,
                "pilot_gain_db": describing.gain_db.tolist(),
                "pilot_phase_deg": describing.phase_deg.tolist(),
                "snr": describing.snr.tolist(),
            }
        )
    data: dict[str, Any] = {"runs": runs, "notes": notes}
    if not functions:
        return data
    frequencies = functions[0][1].frequencies
    same = all(
        d.frequencies.shape == frequencies.shape and np.allclose(d.frequencies, frequencies)
        for _, d in functions
    )
    if not same:
        notes.append({"run": None, "note": "the runs' forcing frequencies differ: no mean"})
        return data
    pilots = np.array([d.pilot for _, d in functions])
    mean = pilots.mean(axis=0)
    gains = 20.0 * np.log10(np.abs(pilots))
    mean_phase = np.degrees(np.unwrap(np.angle(mean)))
    # on the runs' branch at the lowest frequency
    first = np.mean([d.phase_deg[0] for _, d in functions])
    mean_phase += 360.0 * np.round((first - mean_phase[0]) / 360.0)
    # each run's phase on the branch of the mean, within 180 deg of it
    phases = mean_phase + np.degrees(np.angle(pilots / mean))
    for run, aligned in zip(runs, phases, strict=True):
        run["pilot_phase_deg"] = aligned.tolist()
    spread = len(functions) > 1
    data["mean"] = {
        "frequencies": frequencies.tolist(),
        "source": list(functions[0][1].source),
        "gain_db": (20.0 * np.log10(np.abs(mean))).tolist(),
        "phase_deg": mean_phase.tolist(),
        "gain_sd_db": (
            gains.std(axis=0, ddof=1) if spread else np.full(len(mean), np.nan)
        ).tolist(),
        "phase_sd_deg": (
            phases.std(axis=0, ddof=1) if spread else np.full(len(mean), np.nan)
        ).tolist(),
        "snr": np.mean([d.snr for _, d in functions], axis=0).tolist(),
        "runs": [number for number, _ in functions],
    }
    return data


def _identifications(
    recordings: Sequence[tuple[int, Any]],
    condition: Any,
    estimator: str,
    settings: Mapping[str, Any] | None,
) -> tuple[dict[str, Any], list[tuple[int, Any]]]:
    """Each measurement run identified, with the mean and spread of the final values."""
    runs, results, notes = [], [], []
    for number, recording in recordings:
        try:
            identification = identify_run(
                recording, condition, estimator=estimator, settings=settings
            )
        except ValueError as error:
            notes.append({"run": number, "note": str(error)})
            if _PILOT_MODEL.get(condition.task) is None or "anticipation_time" in str(error):
                break  # the same for every run
            continue
        runs.append({"run": number, "summary": identification.summary})
        results.append((number, identification.result))
    effective = _effective_settings(condition, settings)
    data: dict[str, Any] = {
        "estimator": estimator,
        "model": effective.get("model", _PILOT_MODEL.get(condition.task)),
        "settings": effective,
        "runs": runs,
        "notes": notes,
    }
    from manualcontrol.pilots.models import model_for_element

    model = data["model"]
    if model is not None and model_for_element(model, condition.options["element"]) != model:
        data["caution"] = _LAG_CAUTION  # the lag humans adopt on this element left out
    if runs:
        names = list(runs[0]["summary"]["final"])
        values = np.array([[run["summary"]["final"][n] for n in names] for run in runs])
        data["mean"] = dict(zip(names, values.mean(axis=0).tolist(), strict=True))
        if len(runs) > 1:
            data["sd"] = dict(zip(names, values.std(axis=0, ddof=1).tolist(), strict=True))
    return data, results


# ------------------------------------------------------------------ figures


def _rms_figure(records: Sequence[Mapping[str, Any]], path: Path) -> Path:
    fig, axis = subplots(1, 1, figsize=(8, 3.6))
    names = list(dict.fromkeys(record["condition"] for record in records))
    colours = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
    for i, name in enumerate(names):
        colour = colours[i % len(colours)]
        for kind, face in (("practice", "white"), ("measurement", colour)):
            chosen = [r for r in records if r["condition"] == name and r["kind"] == kind]
            if chosen:
                axis.plot(
                    [r["number"] for r in chosen],
                    [rms_error_of(r) for r in chosen],
                    "o",
                    mec=colour,
                    mfc=face,
                    ms=7,
                    label=f"{name} {kind}",
                )
    axis.set_xlabel("run (in the order flown)")
    axis.set_ylabel("RMS error")
    axis.set_title("RMS error per run (open: practice, filled: measurement)", fontsize=9)
    axis.legend(loc="upper right", fontsize=8)
    return save_figure(fig, path)


def _describing_figure(name: str, describing: Mapping[str, Any], path: Path) -> Path:
    mean = describing["mean"]
    omega = np.asarray(mean["frequencies"])
    fig, axes = subplots(2, 1, figsize=(7.5, 6.0), sharex=True)
    for run in describing["runs"]:
        if len(run["pilot_gain_db"]) != len(omega):
            continue
        axes[0].plot(omega, run["pilot_gain_db"], "o", color="0.6", ms=4)
        axes[1].plot(omega, run["pilot_phase_deg"], "o", color="0.6", ms=4)
    for axis, key, spread in (
        (axes[0], "gain_db", "gain_sd_db"),
        (axes[1], "phase_deg", "phase_sd_deg"),
    ):
        values = np.asarray(mean[key], dtype=np.float64)
        error = np.asarray([np.nan if v is None else v for v in mean[spread]], dtype=np.float64)
        if np.isfinite(error).any():
            axis.errorbar(omega, values, yerr=error, fmt="none", ecolor="k", lw=0.8, capsize=2)
        axis.plot(omega, values, "ks-", ms=5, lw=1.0, label="mean of the runs")
    axes[0].plot([], [], "o", color="0.6", ms=4, label="each measurement run")
    axes[0].set_xscale("log")
    axes[0].set_ylabel("|H_p| [dB]")
    axes[1].set_ylabel("phase H_p [deg]")
    axes[1].set_xlabel("frequency [rad/s]")
    axes[0].set_title(f"{name}: pilot describing function at the forcing frequencies", fontsize=9)
    axes[0].legend(loc="lower left", fontsize=8)
    return save_figure(fig, path)


def _unit(model: str | None, name: str) -> str:
    if model is None:
        return name
    with contextlib.suppress(KeyError, ValueError):
        unit = make_model(model).spec(name).unit
        if unit and unit != "-":
            return f"{name} [{unit}]"
    return name


def _trace_figure(
    name: str, model: str | None, results: Sequence[tuple[int, Any]], path: Path
) -> Path:
    names = list(results[0][1].estimated)
    fig, axes = subplots(len(names), 1, figsize=(9, 1.7 * len(names) + 0.6), sharex=True)
    axes = np.atleast_1d(axes)
    for number, result in results:
        for axis, parameter in zip(axes, names, strict=True):
            draw_trace(axis, result.t, result.mean_of(parameter), lw=1.0, label=f"run {number}")
    for axis, parameter in zip(axes, names, strict=True):
        axis.set_ylabel(_unit(model, parameter))
    axes[0].set_title(f"{name}: identified parameters over each measurement run", fontsize=9)
    axes[0].legend(loc="upper right", fontsize=7, ncol=min(len(results), 4))
    axes[-1].set_xlabel("time [s]")
    return save_figure(fig, path)


# ------------------------------------------------------------------ the report


def _notes(notes: Sequence[Mapping[str, Any]]) -> str:
    """Notes of runs, one line per distinct note: ``runs 3, 4: why``."""
    grouped: dict[str, list[int]] = {}
    for note in notes:
        grouped.setdefault(note["note"], []).extend([] if note["run"] is None else [note["run"]])
    parts = []
    for text, runs in grouped.items():
        label = f"run{'s' if len(runs) > 1 else ''} {', '.join(map(str, runs))}: " if runs else ""
        parts.append(label + text.rstrip("."))
    return "; ".join(parts)


def _markdown(data: Mapping[str, Any], figures: Mapping[str, str]) -> str:
    lines = [f"# Session report: {data['participant']}", ""]
    session = data["session"]
    lines += [
        f"- protocol: {session['protocol']} (digest `{session['digest']}`, from "
        f"`{session['source']}`)",
        f"- status: {session['status']}: {session['finished']} of {session['planned']} "
        f"planned runs flown, {session['skipped']} practice slot(s) skipped",
        f"- condition order: {', '.join(session['order'])} ({session['order_why']})",
        f"- input: {session['input']}",
        f"- runs whose timing was not good enough for identification: "
        f"{', '.join(map(str, session['timing_warnings'])) or 'none'}",
    ]
    if session["interruptions"]:
        lines.append(f"- interruptions: {session['interruptions']}")
    lines += ["", "## RMS error per run", ""]
    lines += [
        "| run | condition | kind | # | realisation | RMS | of | timing ok |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for run in data["runs"]:
        lines.append(
            f"| {run['number']} | {run['condition']} | {run['kind']} | {run['index']} | "
            f"{_fmt(run['realisation'])} | {_fmt(run['rms_error'])} | {run['rms_of']} | "
            f"{_fmt(run['timing_ok'])} |"
        )
    if "rms" in figures:
        lines += ["", f"![RMS error per run]({figures['rms']})"]
    for name, condition in data["conditions"].items():
        lines += ["", f"## Condition {name}", "", condition["description"], ""]
        describing = condition.get("describing_function")
        lines += ["### Describing function (measurement runs)", ""]
        if describing is None or "mean" not in describing:
            notes = _notes(describing["notes"]) if describing else ""
            lines.append(f"Not measured: {notes or 'no measurement run'}.")
        else:
            mean = describing["mean"]
            lines.append(
                f"Mean of runs {', '.join(map(str, mean['runs']))}; sd: spread between runs."
            )
            lines += [
                "",
                "| ω [rad/s] | forcing | gain [dB] | sd | phase [deg] | sd | SNR |",
                "| --- | --- | --- | --- | --- | --- | --- |",
            ]
            for i, omega in enumerate(mean["frequencies"]):
                lines.append(
                    f"| {omega:.3g} | {mean['source'][i]} | {_fixed(mean['gain_db'][i])} | "
                    f"{_fixed(mean['gain_sd_db'][i])} | {_fixed(mean['phase_deg'][i], 0)} | "
                    f"{_fixed(mean['phase_sd_deg'][i], 0)} | {_fmt(mean['snr'][i], 3)} |"
                )
            lines += ["", "| run | crossover [rad/s] | phase margin [deg] | remnant share |"]
            lines.append("| --- | --- | --- | --- |")
            for run in describing["runs"]:
                lines.append(
                    f"| {run['run']} | {_fixed(run['crossover_frequency'], 2)} | "
                    f"{_fixed(run['phase_margin'], 0)} | {_fixed(run['remnant_share'], 2)} |"
                )
            if describing["notes"]:
                lines += ["", f"Left out: {_notes(describing['notes'])}."]
            if name + "-df" in figures:
                lines += ["", f"![{name} describing function]({figures[name + '-df']})"]
        ident = condition.get("identification")
        lines += ["", "### Identified parameters", ""]
        if not ident or not ident["runs"]:
            notes = _notes(ident["notes"]) if ident else ""
            lines.append(f"Not identified: {notes or 'no measurement run'}.")
            continue
        names = list(ident["runs"][0]["summary"]["final"])
        lines.append(
            f"Estimator `{ident['estimator']}` on the {ident['model']} model, given the "
            f"element; settings {ident['settings'] or 'default'}. Final values per run, "
            "then the checks `manualcontrol identify` reports."
        )
        if ident.get("caution"):
            lines += ["", ident["caution"]]
        lines += [
            "",
            "| run | " + " | ".join(names) + " | VAF one-step [%] | VAF resim. [%] | "
            "freq. check [dB, deg] | loop stable |",
            "| --- " * (len(names) + 5) + "|",
        ]
        for run in ident["runs"]:
            summary = run["summary"]
            fit = summary["fit"]
            check = fit.get("frequency_check") or {}
            frequency = (
                f"{_fmt(check.get('gain_error_db'), 2)}, {_fmt(check.get('phase_error_deg'), 2)}"
                if check
                else "n/a"
            )
            lines.append(
                f"| {run['run']} | "
                + " | ".join(_fmt(summary["final"][n]) for n in names)
                + f" | {_fmt(fit['vaf_one_step_percent'], 3)} | "
                f"{_fmt(fit['vaf_resimulated_percent'], 3)} | {frequency} | "
                f"{_fmt(summary['closed_loop']['stable'])} |"
            )
        if "mean" in ident:
            lines.append(
                "| mean | " + " | ".join(_fmt(ident["mean"][n]) for n in names) + " | | | | |"
            )
        if "sd" in ident:
            lines.append("| sd | " + " | ".join(_fmt(ident["sd"][n]) for n in names) + " | | | | |")
        warned = [
            (run["run"], warning)
            for run in ident["runs"]
            for warning in run["summary"]["fit"]["warnings"]
        ]
        held = {
            name
            for run in ident["runs"]
            for name in run["summary"].get("held_at_generic_values", {})
        }
        if held:
            lines += ["", f"Held at generic values, not estimated: {', '.join(sorted(held))}."]
        if ident["notes"]:
            lines += ["", f"Not identified: {_notes(ident['notes'])}."]
        if warned:
            lines += ["", "Warnings:", ""]
            lines += [f"- run {number}: {warning}" for number, warning in warned]
        if name + "-traces" in figures:
            lines += ["", f"![{name} parameter traces]({figures[name + '-traces']})"]
    return "\n".join(lines) + "\n"


def _condition_description(condition: Any) -> str:
    options = condition.options
    parts = [f"task {condition.task}"]
    if condition.tracking:
        forcing = options["forcing"]
        name = forcing if isinstance(forcing, str) else forcing.get("name", "custom")
        parts += [f"element {options['element']}", f"forcing {name}"]
        parts.append(f"realisations {list(condition.realisations)}")
    for key in ("measurement_time", "available_preview", "disturbance_at", "dt"):
        if key in options:
            parts.append(f"{key} {options[key]}")
    parts.append(f"practice {condition.practice.describe()}")
    runs = condition.measurement_runs
    parts.append(f"{runs} measurement run{'s' if runs != 1 else ''}")
    return "; ".join(parts) + "."


def write_session_report(
    out_dir: str | Path,
    participant: str,
    *,
    estimator: str = DEFAULT_ESTIMATOR,
    estimator_settings: Mapping[str, Mapping[str, Any]] | None = None,
) -> SessionReport:
    """Write ``<out_dir>/<participant>/report/`` (module docstring) and describe it.

    Parameters
    ----------
    out_dir
        The sessions' folder (``--out`` of the session).
    participant
        Whose session.
    estimator
        The member of the family to identify with (default ``rml``).
    estimator_settings
        Settings per condition name (a preview condition's ``anticipation_time``).

    Raises
    ------
    SessionError
        No readable session in the folder.
    """
    folder = Path(out_dir) / participant
    manifest = load_manifest(folder)
    protocol = parse_protocol(manifest["protocol"], manifest.get("protocol_source", "<session>"))
    records = list(manifest["runs"])
    recordings: dict[int, Any] = {}
    for record in records:
        recordings[record["number"]] = Recording.load(folder / record["file"])
    conditions: dict[str, Any] = {}
    results: dict[str, list[tuple[int, Any]]] = {}
    for name in manifest["order"]["conditions"]:
        condition = protocol.condition(name)
        measured = [
            (r["number"], recordings[r["number"]])
            for r in records
            if r["condition"] == name and r["kind"] == "measurement"
        ]
        entry: dict[str, Any] = {"description": _condition_description(condition)}
        if measured and condition.task in _PILOT_MODEL:
            # a degenerate run (a stick never moved) gives NaN figures, shown as n/a
            with np.errstate(all="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                entry["describing_function"] = _describing(measured, condition)
                settings = (estimator_settings or {}).get(name)
                entry["identification"], results[name] = _identifications(
                    measured, condition, estimator, settings
                )
        elif measured:
            note = {
                "run": None,
                "note": f"a {condition.task} condition is not described or identified here",
            }
            entry["describing_function"] = {"runs": [], "notes": [note]}
            entry["identification"] = {"runs": [], "notes": [note]}
        conditions[name] = entry
    runs = [
        {
            "number": r["number"],
            "condition": r["condition"],
            "kind": r["kind"],
            "index": r["index"],
            "realisation": r["realisation"],
            "file": r["file"],
            "rms_error": r["rms_error"],
            "rms_of": r["rms_of"],
            "timing_ok": r["timing"]["good_enough_for_identification"],
        }
        for r in records
    ]
    calibration = records[0]["input"] if records else manifest["input"]
    data = _clean(
        {
            "participant": participant,
            "session": {
                "protocol": protocol.name,
                "digest": manifest["protocol_digest"],
                "source": manifest.get("protocol_source"),
                "status": manifest["status"],
                "planned": len(manifest["plan"]),
                "finished": len(records),
                "skipped": len(manifest["skipped"]),
                "order": manifest["order"]["conditions"],
                "order_why": manifest["order"]["why"],
                "input": ", ".join(f"{k} {v}" for k, v in calibration.items()),
                "timing_warnings": [
                    r["number"]
                    for r in records
                    if not r["timing"]["good_enough_for_identification"]
                ],
                "interruptions": len(manifest["interruptions"]),
            },
            "runs": runs,
            "conditions": conditions,
        }
    )
    target = folder / REPORT_FOLDER
    for leftover in folder.glob(f".{REPORT_FOLDER}-*"):  # a report killed half-way
        shutil.rmtree(leftover, ignore_errors=True)
    temporary = Path(tempfile.mkdtemp(prefix=f".{REPORT_FOLDER}-", dir=folder))
    try:
        figures: dict[str, str] = {}
        if records:
            _rms_figure(records, temporary / "rms.png")
            figures["rms"] = "rms.png"
        for name, entry in data["conditions"].items():
            describing = entry.get("describing_function") or {}
            if "mean" in describing:
                file = f"{name}-describing-function.png"
                _describing_figure(name, describing, temporary / file)
                figures[name + "-df"] = file
            if results.get(name):
                file = f"{name}-traces.png"
                model = entry["identification"]["model"]
                _trace_figure(name, model, results[name], temporary / file)
                figures[name + "-traces"] = file
        (temporary / "report.md").write_text(_markdown(data, figures), encoding="utf-8")
        (temporary / "report.json").write_text(
            json.dumps(data, indent=2, allow_nan=False), encoding="utf-8"
        )
        temporary.chmod(0o755)
        old = None
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{REPORT_FOLDER}-old-", dir=folder))
            target.replace(old / REPORT_FOLDER)
        temporary.replace(target)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if temporary.exists():
            shutil.rmtree(temporary, ignore_errors=True)
    return SessionReport(
        folder=target,
        markdown=target / "report.md",
        figures=tuple(target / file for file in figures.values()),
        data=data,
    )
