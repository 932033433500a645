"""Report section of the ``boer-kenyon1998`` suite: the RDI's delay against the truth.

The paper has no tables, only figures of the estimates against the truth (Figs. 1-4,
6, 7); the generic report's NRMSE says little about a delay that wanders. This section
re-runs each finished scenario (the runs are cheap and seeded, so the recordings are the
ones the estimates came from), takes the filtered and the RTS-smoothed estimates, and
reports what the paper's text claims:

* open loop (Sec. IV): the delay error in samples at 60 Hz after ``score_from`` at the
  identification steps (every ``decimation`` samples, where the RDI has just been
  corrected) and over all samples (the estimate held between steps), filtered and
  smoothed; the lag of the delay estimate behind the truth (the shift that best aligns
  the two); each estimated coefficient's mean relative error;
* gap-postview (Sec. V): when the estimate, started at 0, first comes within 30 ms of
  the truth, and the RMS error and bias after ``score_from``. The truth is the
  operator's equivalent delay: the gap, plus its delay, minus the time advance of the
  best pure gain-and-delay fit to its extrapolation ``K_p + K_v s`` over the track's
  spectrum (:func:`equivalent_advance`);
* the critical task (Sec. VI): the time and instability at loss of control, the RMS
  delay error and relative gain error over the run.

Figures: the four open-loop conditions, the postview task and the critical task, traces
against the truth (the first run of each batch).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.bench import runner
from manualcontrol.bench.report import draw_trace, save_figure, subplots
from manualcontrol.bench.scenarios import Scenario, Suite, scenario_from_dict
from manualcontrol.envs.elements import make_element
from manualcontrol.envs.signals import forcing_preset
from manualcontrol.envs.tasks import task_named
from manualcontrol.estimators.offline.smoothing import smooth

__all__ = ["equivalent_advance", "lag_behind", "report_section"]

FloatArray = NDArray[np.float64]

#: Postview recovery: the estimate counts as recovered within this of the truth (s).
RECOVERED = 0.03


def equivalent_advance(K_p: float, K_v: float, track: Any) -> tuple[float, float]:
    """Advance ``a`` (s) and gain ``b`` of the best fit ``b x(t + a)`` to ``K_p x + K_v x'``.

    Least squares over one period of the track's samples, in the frequency domain (the
    track is periodic band-limited noise, :class:`~manualcontrol.envs.signals.BandLimitedNoise`,
    or any signal with ``signal.values`` and ``dt``): for each ``a`` the best ``b`` is
    linear; ``a`` is found by a bounded scalar search over [0, 1] s. This is what a pure
    gain-and-delay identifier should find for the extrapolating postview operator.
    """
    from scipy.optimize import minimize_scalar

    samples = track.signal if hasattr(track, "signal") else track
    values = np.asarray(samples.values, dtype=np.float64)
    spectrum = np.fft.rfft(values)
    omega = 2.0 * np.pi * np.fft.rfftfreq(values.shape[0], samples.dt)
    response = spectrum * (K_p + 1j * omega * K_v)

    def fit(advance: float) -> tuple[float, float]:
        model = spectrum * np.exp(1j * omega * advance)
        gain = float(np.real(np.vdot(model, response)) / np.real(np.vdot(model, model)))
        return gain, float(np.sum(np.abs(response - gain * model) ** 2))

    best = minimize_scalar(
        lambda a: fit(a)[1], bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-9}
    )
    return float(best.x), fit(float(best.x))[0]


def lag_behind(estimate: FloatArray, truth: FloatArray, dt: float, most: float = 1.0) -> float:
    """The delay (s) of ``estimate`` behind ``truth``: the shift with least squared error.

    Shifts from ``-most`` to ``most`` seconds in whole samples; positive means the
    estimate follows the truth late.
    """
    n = estimate.shape[0]
    best, best_error = 0, math.inf
    for shift in range(-round(most / dt), round(most / dt) + 1):
        if shift >= 0:
            error = estimate[shift:] - truth[: n - shift]
        else:
            error = estimate[:shift] - truth[-shift:]
        if error.size == 0:
            continue
        value = float(np.mean(error * error))
        if value < best_error:
            best, best_error = shift, value
    return best * dt


def _rms(values: FloatArray) -> float:
    return float(np.sqrt(np.mean(values * values))) if values.size else math.nan


def _runs(rows: Sequence[Mapping[str, Any]], batch: str) -> list[Scenario]:
    return [
        scenario_from_dict(row["scenario"])
        for row in rows
        if row.get("batch") == batch and row.get("status") == "ok"
    ]


def _estimates(scenario: Scenario) -> tuple[Any, Any, Any]:
    recording = runner.simulate_scenario(scenario)
    estimator = runner.make_estimator(scenario.estimator)
    filtered = estimator.estimate(recording, smoother_inputs=True, smooth=False)
    return recording, filtered, smooth(filtered)


def _delay_name(result: Any) -> str:
    names = dict(result.settings["settings"].get("report_names") or {})
    return names.get("d", "d")


def _gain_name(result: Any) -> str:
    names = dict(result.settings["settings"].get("report_names") or {})
    return names.get("b_0", "b_0")


# ----------------------------------------------------------------------- open loop


def _open_loop(scenarios: list[Scenario]) -> tuple[dict[str, Any], Any]:
    stats: dict[str, list[float]] = {}
    coefficients: dict[str, list[float]] = {}
    example = None
    for scenario in scenarios:
        recording, filtered, smoothed = _estimates(scenario)
        if example is None:
            example = (recording, filtered, smoothed)
        samples = 1.0 / recording.dt
        t = np.asarray(recording.t)
        scored = t >= scenario.score_from - 1e-9
        decimation = int(filtered.settings["settings"]["decimation"])
        steps = scored & (np.arange(t.shape[0]) % decimation == 0)
        truth = np.asarray(recording.parameters["d"])
        for label, result in (("filtered", filtered), ("smoothed", smoothed)):
            error = (result.mean_of("d") - truth) * samples
            stats.setdefault(f"{label}_median", []).append(float(np.median(np.abs(error[steps]))))
            stats.setdefault(f"{label}_rms_steps", []).append(_rms(error[steps]))
            stats.setdefault(f"{label}_rms_all", []).append(_rms(error[scored]))
            stats.setdefault(f"{label}_bias", []).append(float(np.mean(error[scored])))
            stats.setdefault(f"{label}_lag", []).append(
                lag_behind(result.mean_of("d")[scored], truth[scored], recording.dt)
            )
        for name in filtered.estimated:
            if name == "d":
                continue
            true_value = float(np.mean(recording.parameters[name][scored]))
            mean = float(np.mean(filtered.mean_of(name)[scored]))
            coefficients.setdefault(name, []).append(mean / true_value - 1.0)
    return {"stats": stats, "coefficients": coefficients, "runs": len(scenarios)}, example


def _open_loop_lines(results: Mapping[str, Mapping[str, Any]]) -> list[str]:
    lines = [
        "### Sec. IV, open loop: delay error in 60-Hz samples after 10 s (mean over runs)",
        "",
        "At the 15-Hz identification steps: median |error|, RMS; over every 60-Hz sample "
        "(the estimate held between steps): RMS and bias; lag of the estimate behind the "
        "truth (ms); filtered / smoothed.",
        "",
        "| condition | runs | median | RMS steps | RMS all | bias | lag (ms) | coefficients: mean "
        "rel. error (worst run) |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for batch, result in results.items():
        stats = result["stats"]

        def pair(key: str, scale: float = 1.0, fmt: str = ".3f", stats=stats) -> str:
            f = float(np.mean(stats[f"filtered_{key}"])) * scale
            s = float(np.mean(stats[f"smoothed_{key}"])) * scale
            return f"{f:{fmt}} / {s:{fmt}}"

        coefficients = ", ".join(
            f"{name} {np.mean(values):+.2%} ({max(values, key=abs):+.2%})"
            for name, values in result["coefficients"].items()
        )
        lines.append(
            f"| {batch} | {result['runs']} | {pair('median')} | {pair('rms_steps')} | "
            f"{pair('rms_all')} | {pair('bias', fmt='+.3f')} | {pair('lag', 1000.0, '.0f')} | "
            f"{coefficients or '—'} |"
        )
    return lines


def _open_loop_figure(examples: Mapping[str, Any], out: Path) -> Path | None:
    if not examples:
        return None
    names = ("d", "a_1", "b_0", "b_1")
    fig, axes = subplots(
        len(names), len(examples), figsize=(4.2 * len(examples), 8.5), sharex=True, squeeze=False
    )
    for column, (batch, (recording, filtered, smoothed)) in enumerate(examples.items()):
        t = np.asarray(recording.t)
        for row, name in enumerate(names):
            axis = axes[row, column]
            scale = 1000.0 if name == "d" else 1.0
            draw_trace(
                axis, t, recording.parameters[name] * scale, color="tab:red", lw=1.2, label="true"
            )
            draw_trace(axis, t, filtered.mean_of(name) * scale, color="k", lw=0.8, label="filtered")
            if name in filtered.estimated:
                draw_trace(
                    axis,
                    t,
                    smoothed.mean_of(name) * scale,
                    color="tab:blue",
                    lw=0.8,
                    ls="--",
                    label="smoothed",
                )
            if column == 0:
                axis.set_ylabel("d [ms]" if name == "d" else name)
        axes[0, column].set_title(batch, fontsize=9)
        axes[-1, column].set_xlabel("time [s]")
    axes[0, 0].legend(loc="upper left", fontsize=7)
    return save_figure(fig, out / "figures" / "boer-kenyon1998-open-loop.png")


# ------------------------------------------------------------------------ postview


def _postview_truth(scenario: Scenario, recording: Any) -> tuple[FloatArray, float]:
    parameters = recording.parameters
    track = forcing_preset(scenario.forcing, scenario.realisation).target
    K_p = float(np.mean(parameters["K_p"]))
    K_v = float(np.mean(parameters["K_v"]))
    advance, _ = equivalent_advance(K_p, K_v, track)
    return np.asarray(parameters["gap"]) + np.asarray(parameters["tau_v"]) - advance, advance


def _postview(scenarios: list[Scenario]) -> tuple[dict[str, list[float]], Any]:
    stats: dict[str, list[float]] = {}
    example = None
    for scenario in scenarios:
        recording, filtered, smoothed = _estimates(scenario)
        truth, advance = _postview_truth(scenario, recording)
        if example is None:
            example = (recording, filtered, smoothed, truth)
        t = np.asarray(recording.t)
        name = _delay_name(filtered)
        close = np.abs(filtered.mean_of(name) - truth) < RECOVERED
        stats.setdefault("recovery", []).append(
            float(t[np.argmax(close)]) if close.any() else math.inf
        )
        scored = t >= scenario.score_from - 1e-9
        for label, result in (("filtered", filtered), ("smoothed", smoothed)):
            error = result.mean_of(name)[scored] - truth[scored]
            stats.setdefault(f"{label}_rms", []).append(_rms(error))
            stats.setdefault(f"{label}_bias", []).append(float(np.mean(error)))
        stats.setdefault("advance", []).append(advance)
        stats.setdefault("gain", []).append(
            float(np.mean(smoothed.mean_of(_gain_name(filtered))[scored]))
        )
    return stats, example


def _task_figure(
    title: str, example: Any, truth_d: FloatArray, truth_gain: Any, path: Path
) -> Path:
    recording, filtered, smoothed = example[:3]
    fig, axes = subplots(2, 1, reusable=True, figsize=(9, 5.5), sharex=True)
    t = np.asarray(recording.t)
    d_name, gain_name = _delay_name(filtered), _gain_name(filtered)
    draw_trace(axes[0], t, truth_d * 1000.0, color="tab:red", lw=1.2, label="true")
    draw_trace(axes[0], t, filtered.mean_of(d_name) * 1000.0, color="k", lw=0.8, label="filtered")
    draw_trace(
        axes[0],
        t,
        smoothed.mean_of(d_name) * 1000.0,
        color="tab:blue",
        lw=0.9,
        ls="--",
        label="smoothed",
    )
    if "gap" in recording.parameters:
        draw_trace(
            axes[0], t, recording.parameters["gap"] * 1000.0, color="tab:gray", lw=0.8, label="gap"
        )
    axes[0].set_ylabel("delay [ms]")
    axes[0].legend(loc="upper left", fontsize=8)
    if truth_gain is not None:
        draw_trace(axes[1], t, truth_gain, color="tab:red", lw=1.2, label="true")
    draw_trace(axes[1], t, filtered.mean_of(gain_name), color="k", lw=0.8, label="filtered")
    draw_trace(
        axes[1], t, smoothed.mean_of(gain_name), color="tab:blue", lw=0.9, ls="--", label="smoothed"
    )
    axes[1].set_ylabel("gain")
    axes[1].set_xlabel("time [s]")
    axes[0].set_title(title)
    return save_figure(fig, path)


# ------------------------------------------------------------------ critical task


def _critical(scenarios: list[Scenario]) -> tuple[dict[str, list[float]], Any]:
    stats: dict[str, list[float]] = {}
    example = None
    for scenario in scenarios:
        recording, filtered, smoothed = _estimates(scenario)
        if example is None:
            example = (recording, filtered, smoothed)
        t = np.asarray(recording.t)
        stats.setdefault("end", []).append(float(t[-1]))
        element = make_element(dict(recording.metadata["controlled_element"]))
        instability = element.parameters_at(t[-1:]).get("instability", np.full(1, np.nan))
        stats.setdefault("lambda", []).append(float(instability[0]))
        tau = np.asarray(recording.parameters["tau_v"])
        gain = np.asarray(recording.parameters["K_p"])
        for label, result in (("filtered", filtered), ("smoothed", smoothed)):
            stats.setdefault(f"{label}_delay_rms", []).append(
                _rms(result.mean_of(_delay_name(filtered)) - tau)
            )
            stats.setdefault(f"{label}_gain_rms", []).append(
                _rms(result.mean_of(_gain_name(filtered)) / gain - 1.0)
            )
    return stats, example


# --------------------------------------------------------------------------- section


def report_section(suite: Suite, rows: Sequence[Mapping[str, Any]], out: str | Path) -> list[str]:
    """Markdown lines of this suite's section (module docstring); figures under ``out``."""
    out = Path(out)
    lines = ["## Boer & Kenyon (1998): the delay against the truth", ""]
    open_loop: dict[str, Any] = {}
    examples: dict[str, Any] = {}
    for batch in suite.batches:
        scenarios = _runs(rows, batch.name)
        if not scenarios:
            continue
        task = scenarios[0].task
        if task == "open-loop":
            open_loop[batch.name], examples[batch.name] = _open_loop(scenarios)
        elif task_named(task).shows_postview:
            stats, example = _postview(scenarios)
            lines += [
                f"### Sec. V, gap-postview ({batch.name}, {len(scenarios)} runs)",
                "",
                "Truth: gap + tau_v - the operator's equivalent advance "
                f"({np.mean(stats['advance']) * 1000:.1f} ms; "
                "the best pure gain and delay fit to its extrapolation over the track).",
                "",
                "| recovery within 30 ms (s), worst | delay RMS after 10 s (ms) filtered / "
                "smoothed | bias (ms) filtered / smoothed | gain (smoothed mean) |",
                "| ---: | ---: | ---: | ---: |",
                f"| {max(stats['recovery']):.2f} | {np.mean(stats['filtered_rms']) * 1000:.1f} / "
                f"{np.mean(stats['smoothed_rms']) * 1000:.1f} (worst "
                f"{max(stats['smoothed_rms']) * 1000:.1f}) | "
                f"{np.mean(stats['filtered_bias']) * 1000:+.1f} / "
                f"{np.mean(stats['smoothed_bias']) * 1000:+.1f} | {np.mean(stats['gain']):.3f} |",
                "",
            ]
            figure = _task_figure(
                f"gap-postview: {batch.name}",
                example,
                example[3],
                example[0].parameters["K_p"],
                out / "figures" / f"boer-kenyon1998-{batch.name}.png",
            )
            lines += [f"![{batch.name}](figures/{figure.name})", ""]
        else:
            stats, example = _critical(scenarios)
            lines += [
                f"### Sec. VI, critical task ({batch.name}, {len(scenarios)} runs)",
                "",
                "| loss of control (s), lambda | delay RMS (ms) filtered / smoothed (worst) | "
                "gain RMS rel. error filtered / smoothed (worst) |",
                "| ---: | ---: | ---: |",
                f"| {np.mean(stats['end']):.1f}, {np.mean(stats['lambda']):.2f} | "
                f"{np.mean(stats['filtered_delay_rms']) * 1000:.1f} / "
                f"{np.mean(stats['smoothed_delay_rms']) * 1000:.1f} "
                f"({max(stats['smoothed_delay_rms']) * 1000:.1f}) | "
                f"{np.mean(stats['filtered_gain_rms']):.1%} / "
                f"{np.mean(stats['smoothed_gain_rms']):.1%} "
                f"({max(stats['smoothed_gain_rms']):.1%}) |",
                "",
            ]
            recording = example[0]
            figure = _task_figure(
                f"critical task: {batch.name}",
                example,
                np.asarray(recording.parameters["tau_v"]),
                recording.parameters["K_p"],
                out / "figures" / f"boer-kenyon1998-{batch.name}.png",
            )
            lines += [f"![{batch.name}](figures/{figure.name})", ""]
    if open_loop:
        lines[2:2] = [*_open_loop_lines(open_loop), ""]
        figure = _open_loop_figure(examples, out)
        if figure is not None:
            index = 2 + len(_open_loop_lines(open_loop)) + 1
            lines[index:index] = [f"![open loop](figures/{figure.name})", ""]
    return lines
