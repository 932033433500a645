"""The ``manualcontrol`` command.

Subcommands: ``simulate`` (a pilot in a tracking task -> a recording), ``identify``
(a recording or an experiment file -> parameter traces and plots), ``describe`` (a
compensatory trial -> its describing function, crossover and a fitted model), ``bench`` (a suite
-> results table and report), ``suites`` (list them), ``train`` (an RL surrogate
operator) and ``evaluate`` (a trained agent -> report). ``manualcontrol COMMAND
--help`` explains every option.

Exit codes: 0 success; 2 a usage or input error (the message says what to fix, no
traceback); 3 a benchmark finished but some of its runs failed (see the results
table); 1 an unexpected internal error (with traceback).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["main"]

EXIT_OK, EXIT_INTERNAL, EXIT_USAGE, EXIT_RUNS_FAILED = 0, 1, 2, 3


class UsageError(Exception):
    """A mistake of the user: reported as a one-line message, exit code 2."""


_WORDS = {"true": True, "false": False, "null": None, "none": None}


def _value(text: str) -> Any:
    """A command-line value: JSON when it parses (numbers, lists, tables), else the string.

    ``true``/``false``/``null`` are read in any case (``False`` as Python writes it).
    """
    if text.strip().lower() in _WORDS:
        return _WORDS[text.strip().lower()]
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _env_options(items: Sequence[str] | None, task: str = "compensatory") -> dict[str, Any]:
    """``--env KEY=VALUE`` items parsed to the type each keyword of the task's env takes.

    A switch takes true/false (yes/no, 1/0), a number a number, an optional number
    also null; anything else is refused naming the option, so ``include_rates=False``
    can no longer arrive as the (truthy) string "False".
    """
    import inspect

    if task == "lane-keeping":
        from manualcontrol.envs.driving import LaneKeeping as Environment
    else:
        from manualcontrol.envs.tracking import TrackingEnv as Environment

    signature = inspect.signature(Environment.__init__)
    known = {name: p for name, p in signature.parameters.items() if name != "self"}
    out = {}
    for item in items or ():
        if "=" not in item:
            raise UsageError(f"--env must look like KEY=VALUE, got {item!r}")
        name, text = (part.strip() for part in item.split("=", 1))
        if name not in known:
            raise UsageError(
                f"--env {name}: unknown environment keyword; known: {', '.join(sorted(known))}"
            )
        default = known[name].default
        word = text.lower()
        if isinstance(default, bool):
            switches = {
                "true": True,
                "yes": True,
                "1": True,
                "false": False,
                "no": False,
                "0": False,
            }
            if word not in switches:
                raise UsageError(f"--env {name} must be true or false, got {text!r}")
            out[name] = switches[word]
        elif isinstance(default, float) or (
            default is None and "float" in str(known[name].annotation)
        ):
            if word in ("null", "none") and default is None:
                out[name] = None
                continue
            try:
                out[name] = float(text)
            except ValueError:
                allowed = "a number or null" if default is None else "a number"
                raise UsageError(f"--env {name} must be {allowed}, got {text!r}") from None
        else:
            out[name] = _value(text)
    return out


def _check_output(option: str, path: Path, *, folder: bool) -> None:
    """Refuse an output path that cannot be written, before any work or any folder is made."""
    path = Path(path)
    if folder and path.exists() and not path.is_dir():
        raise UsageError(f"{option} {path}: is a file; give a folder")
    if not folder and path.is_dir():
        raise UsageError(f"{option} {path}: is a folder; give a file name")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise UsageError(f"{option} {path}: {parent} is a file, not a folder")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise UsageError(f"{option} {path}: {parent} is not writable")
            break


def _assignments(items: Sequence[str] | None, what: str) -> dict[str, Any]:
    out = {}
    for item in items or ():
        if "=" not in item:
            raise UsageError(f"{what} must look like NAME=VALUE, got {item!r}")
        name, text = item.split("=", 1)
        out[name.strip()] = _value(text)
    return out


def _schedule(text: Any) -> Any:
    """``0.3``, ``sigmoid:0.6,0.3,50,20``, ``sine:0.2,0.05,90,0``, ``ramp:...``, ``step:...``."""
    from manualcontrol.envs.schedules import Ramp, Sigmoid, Sine, Step

    if not isinstance(text, str):
        return text
    kind, _, arguments = text.partition(":")
    builders = {"sigmoid": Sigmoid, "sine": Sine, "ramp": Ramp, "step": Step}
    if kind not in builders or not arguments:
        raise UsageError(
            f"a parameter value must be a number or KIND:ARGS with KIND one of "
            f"{', '.join(builders)}, got {text!r}"
        )
    try:
        return builders[kind](*(float(a) for a in arguments.split(",")))
    except (TypeError, ValueError) as error:
        raise UsageError(f"bad {kind} schedule {text!r}: {error}") from None


def _limitation(flag: str, text: str | None) -> Any:
    """A human limitation's value from the command line: a number or ``KIND:ARGS``.

    A schedule becomes its saved dict, the form the training configuration keeps.
    """
    if text is None:
        return 0.0
    try:
        return float(text)
    except ValueError:
        pass
    try:
        return _schedule(text).to_dict()
    except UsageError as error:
        raise UsageError(f"{flag}: {error}") from None


# ------------------------------------------------------------------- commands


def _cmd_suites(args: argparse.Namespace) -> int:
    from manualcontrol.bench.scenarios import BUILTIN_SUITES, describe, load_suite

    for name in BUILTIN_SUITES:
        suite = load_suite(name)
        full, quick = suite.scenarios(), suite.scenarios(quick=True)
        print(f"{name}: {suite.description}")
        print(f"    {len(full)} runs ({describe(full)}); --quick: {len(quick)} runs")
    return EXIT_OK


def _cmd_estimators(args: argparse.Namespace) -> int:
    from manualcontrol.estimators.registry import ESTIMATORS

    width = max(len(name) for name in ESTIMATORS)
    for entry in ESTIMATORS.values():
        print(f"{entry.name:<{width}}  {entry.summary} [{entry.reference}]")
    return EXIT_OK


def _cmd_simulate(args: argparse.Namespace) -> int:
    import warnings

    from manualcontrol.pilots import Pilot
    from manualcontrol.pilots.stability import UnstableLoopWarning

    _check_output("--out", args.out, folder=False)
    if args.plot is not None:
        _check_output("--plot", args.plot, folder=False)
    parameters = {
        name: _schedule(value) for name, value in _assignments(args.param, "--param").items()
    }
    # unset parameters take typical values for the element: a stable loop by default
    pilot = Pilot.typical(
        args.model, args.element, parameters, remnant=args.remnant, delay_order=args.delay_order
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UnstableLoopWarning)
        recording = _simulate_run(args, pilot)
    for warning in caught:
        if issubclass(warning.category, UnstableLoopWarning):
            print(f"manualcontrol simulate: warning: {warning.message}", file=sys.stderr)
    figure = None
    if args.plot:
        from manualcontrol.bench.report import plot_recording

        figure = plot_recording(recording, args.plot)
    try:
        path = recording.save(args.out)
    except BaseException:
        if figure is not None:
            figure.unlink(missing_ok=True)  # nothing left behind when the command fails
        raise
    print(f"wrote {path} ({recording.duration:g} s, {len(recording)} samples)")
    if figure is not None:
        print(f"wrote {figure}")
    return EXIT_OK


def _simulate_run(args: argparse.Namespace, pilot: Any) -> Any:
    from manualcontrol.envs._validation import check_choice
    from manualcontrol.envs.tasks import DISTURBANCE_POINTS
    from manualcontrol.pilots import simulate

    # checked here so the message names the flag, not simulate()'s keyword
    disturbance_at = check_choice("--disturbance-at", args.disturbance_at, DISTURBANCE_POINTS)
    return simulate(
        pilot,
        args.element,
        args.forcing,
        realisation=args.realisation,
        task=args.task,
        available_preview=args.available_preview,
        dt=args.dt,
        run_in=args.run_in,
        measurement_time=args.measurement_time,
        seed=args.seed,
        loop=args.loop,
        on_unstable="warn" if args.allow_unstable else "raise",
        disturbance_at=disturbance_at,
    )


def _load_trial(args: argparse.Namespace) -> Any:
    """The recording named on the command line, time in seconds, error signal formed.

    The file must give the control signal u. Its columns that no signal reads are listed
    on one line of stdout, so that a column left out by an unmatched name shows; the
    library's errors for a missing column, jittery time stamps or a time step that looks
    like milliseconds are worded with the options that fix them (``--column``,
    ``--resample``, ``--time-unit``, ``--dt``).
    """
    from manualcontrol.envs.recording import MissingColumnError, NonUniformTimeError, Recording

    columns = _assignments(args.column, "--column")
    for name, value in columns.items():
        if not isinstance(value, str):
            columns[name] = str(value)  # a numeric column name such as 2
    try:
        recording = Recording.load(
            args.recording,
            columns=columns or None,
            dt=args.dt,
            time_unit=args.time_unit,
            resample=args.resample,
            require=("u",),
        )
    except MissingColumnError as error:
        raise UsageError(error.explain(f"--column {error.name}=COLUMN")) from None
    except NonUniformTimeError as error:
        raise UsageError(error.explain("pass --resample")) from None
    if recording.dt >= 1.0:
        if args.time_unit == "ms":
            hint = "--time-unit ms divides the file's time column by 1000; --dt is in seconds"
        elif 1.0 <= recording.dt <= 100.0:
            hint = (
                "the time column looks like milliseconds: pass --time-unit ms; if there is "
                "no time column, pass --dt SECONDS"
            )
        else:
            hint = (
                "if the time column is in milliseconds, pass --time-unit ms; if there is no "
                "time column, pass --dt SECONDS"
            )
        raise UsageError(
            f"{args.recording}: the sample time is {recording.dt:g} s; manual-control data "
            f"are sampled at tens of Hz or faster: {hint}"
        )
    ignored = recording.metadata.get("ignored_columns")
    if ignored:
        print(f"ignored columns: {', '.join(ignored)}")
    resampled = recording.metadata.get("resampled")
    if resampled:
        print(
            f"resampled: {resampled['samples_in_file']} time stamps, off a uniform grid by up "
            f"to {resampled['from_jitter_ms']:.3g} ms, interpolated linearly onto "
            f"{len(recording)} samples at dt = {resampled['dt']:.6g} s"
        )
    if "e" not in recording and "ft" not in recording and "y" in recording:
        # a disturbance-only compensatory trial: labs often log no target, which is zero
        print("no target or error column: the target is taken as zero (e = -y)")
        recording = recording.with_signals(ft=np.zeros(len(recording)))
    if "e" not in recording and "ft" in recording and "y" in recording:
        recording = recording.with_error_signal()
    return recording


def _target_source(args: argparse.Namespace) -> dict[str, Any]:
    """Where a preview fit reads the target ahead: ``--forcing`` or ``--target-period``."""
    if args.forcing is not None and args.target_period is not None:
        raise UsageError("give --forcing or --target-period, not both")
    if args.forcing is not None:
        from manualcontrol.envs.signals import forcing_preset

        return {"forcing": forcing_preset(args.forcing, args.realisation)}
    if args.target_period is not None:
        return {"target_period": args.target_period}
    if getattr(args, "period", None) is not None:  # the forcing repeats: so does the target
        return {"target_period": args.period}
    return {}


_PREVIEW_HINT = (
    "the preview model reads the target ahead of each sample (ft at t + anticipation_time), "
    "which the recording does not hold: pass --forcing PRESET [--realisation N] (the forcing "
    "the trial was run with) or --target-period SECONDS (the recording lasts whole periods "
    "of the target). A pursuit display shows no target ahead: fit its pursuit form with "
    "--set anticipation_time=0."
)


def _cmd_identify(args: argparse.Namespace) -> int:
    from manualcontrol.bench.report import plot_estimation
    from manualcontrol.envs._files import atomic_write
    from manualcontrol.estimators.analysis.identification import build_estimator, identify
    from manualcontrol.estimators.members.pilot_filter import EVIDENCE
    from manualcontrol.estimators.registry import ESTIMATORS

    _check_output("--out", args.out, folder=True)
    recording = _load_trial(args)
    source = _trial_forcing(args)  # --forcing and --period together: said before any work
    element = _trial_element(recording, args)  # an unreadable --element: in its own words
    settings = _assignments(args.set, "--set")
    if args.estimator not in ESTIMATORS:
        raise UsageError(
            f"--estimator must be one of {', '.join(ESTIMATORS)} (`manualcontrol estimators`), "
            f"got {args.estimator!r}"
        )
    pilot_model = ESTIMATORS[args.estimator].pilot_model
    if not pilot_model and args.model is not None:
        raise UsageError(
            f"--model names the pilot structure of "
            f"{', '.join(n for n, e in ESTIMATORS.items() if e.pilot_model)}; the "
            f"{args.estimator} estimator has its own model (set its settings with --set)"
        )
    # where the target ahead (and the RML's describing function) come from: the pilot-model
    # members read them; the others have their own models and take no such option
    target = _target_source(args) if pilot_model else {}
    estimator = build_estimator(args.estimator, settings, model=args.model, element=args.element)
    if not source and args.target_period is not None:  # the target's period is the forcing's
        source = {"period": args.target_period}
    try:
        identification = identify(
            recording,
            estimator,
            element=element,
            target=target,
            forcing=source.get("forcing"),
            period=source.get("period"),
            disturbance_at=args.disturbance_at,
        )
    except ValueError as error:
        if "target ahead of the samples is unknown" in str(error):
            raise UsageError(_PREVIEW_HINT) from None
        for setting in ("remnant_injection='choose'", "start='describing-function'"):
            if f"{setting} needs the describing function" in str(error):
                flag = setting.replace("'", "")
                raise UsageError(
                    f"--set {flag} reads the describing function at the forcing "
                    "frequencies: give --forcing PRESET or --period SECONDS (the forcing "
                    "signals being in the file)"
                ) from None
        raise
    result, check = identification.result, identification.check
    model_output = identification.model_output
    one_step, resimulated = check.one_step_vaf, check.resimulated_vaf
    r_1, outside = check.innovation_lag1, check.innovation_outside
    final = identification.final
    health = result.health
    stability = identification.closed_loop
    summary = identification.summary
    chosen = summary.get("cross_validation")  # "<name>-cv": the scale the run chose
    sigmoid = summary.get("sigmoid")  # "sigmoid-fit": the change it found
    restarts = summary.get("restarts")  # a filter with restarts: the pass kept
    injection = summary.get("remnant_injection")  # the RML's "choose": the model kept
    assumed = identification.held_at_generic_values  # held at values no one measured
    out = Path(args.out)
    path = result.save(out / "estimation.npz")
    atomic_write(out / "summary.json", lambda p: p.write_text(json.dumps(summary, indent=2)))
    figure = plot_estimation(recording, result, out / "parameters.png", model_output=model_output)
    print(f"estimated {', '.join(result.estimated)}; final values {final}")
    if assumed:
        listed = ", ".join(f"{name} {value:.4g}" for name, value in assumed.items())
        print(
            f"held at the generic starting values, not estimated: {listed}; if the pilot's "
            "are known, give them (--set initial='{\"name\": value}'), else estimate them"
        )
    if math.isnan(one_step) and math.isnan(r_1):
        print(f"fit: resimulated VAF {resimulated:.1f} % (no one-step prediction: offline fit)")
    else:
        print(
            f"fit: one-step VAF {one_step:.1f} % (from t = {check.scored_from:.2f} s, when the "
            f"filter had settled), resimulated VAF {resimulated:.1f} %; innovation lag-1 "
            f"autocorrelation {r_1:.2f}, {100 * outside:.0f} % of lags up to 0.5 s outside the "
            "white-noise band (white innovations give about 5 %)"
        )
    _print_frequency_check(check)
    if chosen is not None:
        errors = ", ".join(
            f"x{scale:g} {error:.4f}"
            for scale, error in zip(chosen["scales"], chosen["errors"], strict=True)
        )
        print(f"process noise: the filter's Q x{chosen['scale']:g} (held-out errors {errors})")
    if sigmoid is not None:
        changes = ", ".join(
            f"{name} {sigmoid['start'][name]:.4g} -> {sigmoid['end'][name]:.4g}"
            for name in sigmoid["varying"]
        )
        print(
            f"change: inflection at {sigmoid['t_mid']:.2f} s, 99 % of it in "
            f"{sigmoid['transition_time']:.2f} s; {changes}"
        )
        for warning in sigmoid["warnings"]:
            print(f"manualcontrol identify: warning: sigmoid fit: {warning}", file=sys.stderr)
    if restarts is not None:
        costs = ", ".join(
            "n/a" if cost is None else f"{cost:.4f}" for cost in restarts["innovation_cost"]
        )
        evidence = ", ".join(f"{z:+.1f}" for z in restarts["evidence"][1:] if z is not None)
        print(
            f"restarts: pass {restarts['chosen'] + 1} of {len(restarts['innovation_cost'])} kept "
            f"(innovation cost of each pass {costs}; lower is more likely; a restart is kept "
            f"below -{EVIDENCE:g} standard errors against the pass kept before it: "
            f"{evidence or 'n/a'})"
        )
        if restarts["ended"]:
            print(f"restarts ended early: {restarts['ended']}")
    if isinstance(injection, Mapping):
        where = {"input": "perception", "output": "stick"}
        gaps = ", ".join(
            f"at the {where[p]} "
            + (
                f"{injection['gain_error_db'][p]:.1f} dB, {injection['phase_error_deg'][p]:.0f} deg"
                if injection["gain_error_db"][p] is not None
                else "no finite estimate"
            )
            for p in ("input", "output")
        )
        print(
            f"remnant model: at the {where[injection['chosen']]}, the pass nearer the "
            f"describing function ({gaps})"
        )
    print(f"wrote {path}, {out / 'summary.json'}, {figure}")
    for warning in check.warnings:
        print(f"manualcontrol identify: warning: {warning}", file=sys.stderr)
    code = EXIT_OK
    if health.diverged:
        print(
            f"manualcontrol identify: error: the filter diverged at t = "
            f"{health.divergence_time:.2f} s ({health.divergence_reason}); the traces after "
            "that are not estimates. Try a smaller --set q2=..., a larger --set r2=..., or "
            "initial values nearer the pilot (--set initial='{\"K_p\": ...}')",
            file=sys.stderr,
        )
        code = EXIT_RUNS_FAILED
    if stability.get("stable") is False:
        level = "warning" if args.allow_unstable else "error"
        print(
            f"manualcontrol identify: {level}: {stability['message']}"
            + ("" if args.allow_unstable else " (--allow-unstable to accept it)"),
            file=sys.stderr,
        )
        if not args.allow_unstable:
            code = EXIT_RUNS_FAILED
    return code


def _cmd_describe(args: argparse.Namespace) -> int:
    from manualcontrol.bench.report import plot_describing_function
    from manualcontrol.envs._files import atomic_write
    from manualcontrol.estimators.analysis.frequency import (
        describing_function,
        fit_describing_function,
    )

    _check_output("--out", args.out, folder=True)
    recording = _load_trial(args)
    source = _trial_forcing(args)
    element = _trial_element(recording, args)
    fixed = _assignments(args.fix, "--fix")
    for name, value in fixed.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise UsageError(f"--fix {name}= needs a number, got {value!r}")
    try:
        describing = describing_function(
            recording,
            source.get("forcing"),
            period=source.get("period"),
            element=element,
            disturbance_at=args.disturbance_at,
            task=args.task,
        )
    except ValueError as error:
        text = str(error).replace(
            "give the forcing (forcing=) or its period (period=, seconds)",
            "give --forcing PRESET or --period SECONDS",
        )
        text = text.replace("disturbance_at", "--disturbance-at")
        raise UsageError(text) from None
    from manualcontrol.envs.tasks import task_named
    from manualcontrol.pilots.models import MODEL_NAMES, make_model

    display = task_named(describing.task)
    model = args.model or display.pilot_model
    if model not in MODEL_NAMES:
        raise UsageError(f"--model must be one of {', '.join(MODEL_NAMES)}, got {model!r}")
    names = make_model(model).parameter_names
    for name in fixed:
        if name not in names:
            raise UsageError(
                f"--fix {name}=: the {model} model has no parameter {name!r} (its parameters: "
                f"{', '.join(names)})"
            )
    try:
        fit = fit_describing_function(describing, model, fixed=fixed or None)
    except ValueError as error:
        raise UsageError(f"--model {model}: {error}") from None
    counts = {name: describing.source.count(name) for name in ("target", "disturbance")}
    sets = ", ".join(f"{name} {count}" for name, count in counts.items() if count)
    start, end = describing.window
    plural = "s" if describing.periods > 1 else ""
    if not display.shows_error_only:
        print(
            f"{describing.task} display: the table holds the disturbance's lines (U/E there is "
            "the pilot's response to y); the model is fitted to every line's U from the "
            "target and y"
        )
    print(
        f"describing function at {describing.frequencies.size} forcing frequencies ({sets}) "
        f"over {describing.periods} period{plural} of {describing.period:g} s "
        f"(t = {start:.2f} to {end:.2f} s); remnant: {100 * describing.remnant_share:.0f} % "
        "of u's variance off the forcing frequencies"
    )
    print("  omega [rad/s]  |H_p| [dB]  phase [deg]  SNR(u)  SNR(remnant injected)  forcing")
    for w, g, ph, snr, injected, kind in zip(
        describing.frequencies,
        describing.gain_db,
        describing.phase_deg,
        describing.snr,
        describing.snr_injected,
        describing.source,
        strict=True,
    ):
        print(f"  {w:13.3f}  {g:10.2f}  {ph:11.1f}  {snr:6.1f}  {injected:21.1f}  {kind}")
    element_text = "given" if describing.element_given else "measured from y, u and fd"
    if math.isfinite(describing.crossover_frequency):
        print(
            f"open loop (element {element_text}): crossover {describing.crossover_frequency:.2f} "
            f"rad/s, phase margin {describing.phase_margin:.0f} deg"
        )
    else:
        print(
            f"open loop (element {element_text}): |H_p H_c| does not cross 1 inside the forcing "
            "band; no crossover"
        )
    values = ", ".join(
        f"{name} {fit.values[name]:.3g}"
        + (f" +- {fit.standard_deviations[name]:.2g}" if name in fit.fitted else " (held)")
        for name in fit.values
    )
    print(f"fitted {fit.model} model: {values}")
    loop = ""
    if math.isfinite(fit.crossover_frequency):
        loop = (
            f"; its loop crosses over at {fit.crossover_frequency:.2f} rad/s with "
            f"{fit.phase_margin:.0f} deg phase margin"
        )
    print(
        f"  misses the measured points by {fit.gain_error_db:.1f} dB and "
        f"{fit.phase_error_deg:.0f} deg (mean absolute){loop}"
    )
    warnings_found = []
    if fit.at_bounds:
        warnings_found.append(
            f"the fit ended on a bound for {', '.join(fit.at_bounds)} (human ranges: "
            "tau_v 0.05-0.6 s, omega_nms 4-30 rad/s, zeta_nms 0.05-1.2): the model does not "
            "describe these data there; try holding a parameter (--fix) or another --model"
        )
    gap_gain, gap_phase = describing.element_error()
    if math.isfinite(gap_gain) and (gap_gain > 1.0 or gap_phase > 10.0):
        warnings_found.append(
            f"the element given differs from the one measured in the file by {gap_gain:.1f} dB "
            f"and {gap_phase:.0f} deg (mean absolute): check --element and --disturbance-at "
            f"(now {describing.disturbance_at})"
        )
    strong = int(
        np.sum(describing.snr_injected >= 10.0)
        if display.shows_error_only
        else np.sum(describing.lines.snr >= 10.0)
    )
    if strong < len(fit.fitted) + 1:
        warnings_found.append(
            f"only {strong} forcing frequencies have a signal-to-noise ratio of 10 or more: "
            "the remnant swamps the rest, so the fit is loose; more periods would help"
        )
    if display.shows_error_only and describing.element_given:
        from manualcontrol.estimators.analysis.human_likeness import human_likeness

        try:
            human = human_likeness(
                recording,
                element,
                forcing=source.get("forcing"),
                period=source.get("period"),
                disturbance_at=args.disturbance_at,
            )
        except ValueError:
            human = None  # a display the figures do not describe: the table above stands
        if human is not None:
            print(f"human-likeness: {human.verdict.text()}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    summary = {
        "describing_function": describing.to_dict(),
        "fit": fit.to_dict(),
        "warnings": warnings_found,
    }
    atomic_write(out / "summary.json", lambda p: p.write_text(json.dumps(summary, indent=2)))
    figure = plot_describing_function(
        describing, out / "bode.png", models={f"fitted {fit.model}": fit.values}, model=fit.model
    )
    print(f"wrote {out / 'summary.json'}, {figure}")
    for warning in warnings_found:
        print(f"manualcontrol describe: warning: {warning}", file=sys.stderr)
    return EXIT_OK


def _rounded(value: float) -> float | None:
    return round(float(value), 4) if math.isfinite(value) else None


def _trial_element(recording: Any, args: argparse.Namespace) -> Any:
    """The controlled element: ``--element``, else the recording's own, else None."""
    from manualcontrol.envs.elements import make_element, parse_element

    if args.element is not None:
        try:
            return parse_element(args.element)
        except ValueError as error:
            raise UsageError(f"--element: {error}") from None
    known = recording.metadata.get("controlled_element")
    return make_element(known) if known is not None else None


def _trial_forcing(args: argparse.Namespace) -> dict[str, Any]:
    """The forcing lines' source: ``--forcing`` (a preset) or ``--period``."""
    if args.forcing is not None and args.period is not None:
        raise UsageError("give --forcing or --period, not both")
    if args.forcing is not None:
        from manualcontrol.envs.signals import forcing_preset

        return {"forcing": forcing_preset(args.forcing, args.realisation)}
    if args.period is not None:
        return {"period": args.period}
    return {}


def _print_frequency_check(check: Any) -> None:
    frequency = check.frequency
    if frequency is None:
        print(f"frequency domain: {check.frequency_note}")
        return
    best = (
        f"{frequency['best_gain_error_db']:.1f} dB, {frequency['best_phase_error_deg']:.0f} deg"
        if frequency["best_gain_error_db"] is not None
        else "n/a: too few forcing lines for its parameters"
    )
    line = (
        f"frequency domain: the identified model (second-half medians) misses the measured "
        f"describing function by {frequency['gain_error_db']:.1f} dB and "
        f"{frequency['phase_error_deg']:.0f} deg (the model fitted to it: {best})"
    )
    if frequency["measured_crossover_frequency"] is not None:
        line += (
            f"; crossover {frequency['measured_crossover_frequency']:.2f} rad/s, phase margin "
            f"{frequency['measured_phase_margin']:.0f} deg measured"
        )
        if frequency["crossover_frequency"] is not None:
            line += (
                f", {frequency['crossover_frequency']:.2f} rad/s and "
                f"{frequency['phase_margin']:.0f} deg identified"
            )
    print(line)


def _cmd_bench(args: argparse.Namespace) -> int:
    from manualcontrol.bench.report import write_report
    from manualcontrol.bench.runner import run_suite
    from manualcontrol.bench.scenarios import load_suite

    if args.backend == "ray":
        import importlib.util

        if importlib.util.find_spec("ray") is None:
            raise UsageError(
                "--backend ray needs Ray: pip install 'manualcontrol[dist]' (or use the "
                "default --backend process)"
            )
    suite = load_suite(args.suite)
    if args.estimators is not None:
        names = [name.strip() for name in args.estimators.split(",") if name.strip()]
        suite = suite.with_estimators(names)
    out = Path(args.out or f"results/{suite.name}{'-quick' if args.quick else ''}")
    _check_output("--out", out, folder=True)
    total = len(suite.scenarios(args.quick))
    bar = _progress(total, f"{suite.name}", args.quiet)

    def progress(done: int, total: int, row: dict[str, Any]) -> None:
        bar.update(done - bar.n)
        if row.get("status") == "failed":
            bar.write(f"failed: {row['key']}: {row['error']}")

    rows = run_suite(
        suite, out, backend=args.backend, workers=args.workers, quick=args.quick, progress=progress
    )
    bar.close()
    failed = sum(row.get("status") != "ok" for row in rows)
    print(f"results: {out / 'results.csv'} ({len(rows)} runs, {failed} failed)")
    if not args.no_report:
        print(f"report:  {write_report(suite, rows, out)}")
    return EXIT_OK if not failed else EXIT_RUNS_FAILED


def _cmd_train(args: argparse.Namespace) -> int:
    from manualcontrol.agents.training import TrainingConfig, train

    _check_output("--out", args.out, folder=True)
    if args.recipe is not None:
        config = _recipe_config(args)
        agent = train(config, args.out, report=None if args.quiet else print)
        print(f"saved agent to {agent.path} (config.json, policy.pt, model.zip)")
        return EXIT_OK
    delay = _limitation("--delay", args.delay)
    motor_noise = _limitation("--motor-noise", args.motor_noise)
    wrappers = []
    if delay:
        wrappers.append(
            {"kind": "action_delay", "delay": delay, "observe_queue": not args.hide_queue}
        )
    elif args.hide_queue:
        raise UsageError("--hide-queue needs an action delay (--delay SECONDS)")
    if args.neuromuscular:
        omega, zeta = args.neuromuscular
        wrappers.append({"kind": "neuromuscular", "omega_nms": omega, "zeta_nms": zeta})
    if motor_noise:
        wrappers.append({"kind": "motor_noise", "power_ratio": motor_noise})
    fields = {
        "observation_noise_ratio": ("--observation-noise", args.observation_noise),
        "effort_rate_weight": ("--effort-rate-weight", args.effort_rate_weight),
    }
    try:
        config = TrainingConfig(
            task=args.task,
            env_kwargs=_env_options(args.env, args.task),
            wrappers=tuple(wrappers),
            algorithm=args.algorithm,
            total_timesteps=100_000 if args.steps is None else args.steps,
            n_envs=args.envs,
            seed=args.seed,
            checkpoint_every=args.checkpoint_every,
            algorithm_kwargs=_assignments(args.algorithm_option, "--algorithm-option"),
            policy_kwargs={} if args.net_arch is None else {"net_arch": list(args.net_arch)},
            history_length=args.history,
            deterministic=args.deterministic_evaluation,
            **{name: _limitation(flag, text) for name, (flag, text) in fields.items()},
        )
    except ValueError as error:
        text = str(error)
        for name, (flag, _) in {**fields, "history_length": ("--history", None)}.items():
            text = text.replace(name, flag)
        raise UsageError(text) from None
    agent = train(config, args.out, report=None if args.quiet else print)
    print(f"saved agent to {agent.path} (config.json, policy.pt, model.zip)")
    return EXIT_OK


#: train flags a recipe sets itself, with their unset values.
_RECIPE_SETS = {
    "--task": ("task", "compensatory"),
    "--env": ("env", None),
    "--delay": ("delay", None),
    "--hide-queue": ("hide_queue", False),
    "--neuromuscular": ("neuromuscular", None),
    "--motor-noise": ("motor_noise", None),
    "--observation-noise": ("observation_noise", None),
    "--effort-rate-weight": ("effort_rate_weight", None),
    "--history": ("history", 1),
    "--deterministic-evaluation": ("deterministic_evaluation", False),
    "--algorithm": ("algorithm", "sac"),
    "--envs": ("envs", 1),
    "--algorithm-option": ("algorithm_option", None),
    "--net-arch": ("net_arch", None),
}


def _recipe_config(args: argparse.Namespace) -> Any:
    from manualcontrol.agents.recipes import RECIPE_ELEMENTS, recipe

    if args.recipe not in RECIPE_ELEMENTS:
        names = ", ".join(RECIPE_ELEMENTS)
        raise UsageError(f"--recipe must be one of {names}, got {args.recipe!r}")
    given = [flag for flag, (name, unset) in _RECIPE_SETS.items() if getattr(args, name) != unset]
    if given:
        raise UsageError(
            f"--recipe {args.recipe} sets the training itself; drop {', '.join(given)} (a "
            "recipe takes --seed, --steps and --checkpoint-every)"
        )
    config = recipe(args.recipe, seed=args.seed, total_timesteps=args.steps)
    if args.checkpoint_every is not None:
        config = dataclasses.replace(config, checkpoint_every=args.checkpoint_every)
    return config


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from manualcontrol.agents.evaluation import evaluate, write_report
    from manualcontrol.agents.training import load_agent

    if args.out is not None:
        _check_output("--out", args.out, folder=True)
    agent = load_agent(args.agent, trust_pickle=args.trust_pickle)
    evaluation = evaluate(agent, seed=args.seed, deterministic=args.deterministic)
    path = write_report(evaluation, args.out or Path(args.agent) / "evaluation")
    summary = evaluation.summary()
    noise = "on" if evaluation.noise else "off (--deterministic)"
    print(f"RMS error {summary['rms_error']:.4f} (wrappers' noise {noise})")
    print(f"identified {summary['identified']}")
    if evaluation.human is not None:
        for line in evaluation.human.lines():
            print(line)
        from manualcontrol.agents.evaluation import optimal_control_reference

        ocm = optimal_control_reference(agent.config)
        if ocm is not None:
            omega_c, margin, tau_e = ocm.crossover()
            print(
                f"  optimal control model on this task (delay {ocm.tau_v:g} s): crossover "
                f"{omega_c:.2f} rad/s, phase margin {margin:.0f} deg, tau_e {tau_e:.3f} s"
            )
    for flag in summary["implausible"]:
        print(
            f"manualcontrol evaluate: warning: implausible identification: {flag}", file=sys.stderr
        )
    print(f"report: {path}")
    return EXIT_OK


def _progress(total: int, description: str, quiet: bool) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc=description, unit="run", disable=quiet, file=sys.stderr)


# --------------------------------------------------------------------- parser


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {text!r}") from None
    if not (value > 0.0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def _add_trial_options(p: argparse.ArgumentParser) -> None:
    """What reading a lab's trial file takes: columns, time, the element and the forcing."""
    p.add_argument(
        "--column",
        action="append",
        metavar="SIGNAL=COLUMN",
        help="map a file column to a signal, e.g. u=stick; repeatable",
    )
    p.add_argument(
        "--dt",
        type=_positive_float,
        default=None,
        help="sample time (s) when the file has no time column",
    )
    p.add_argument(
        "--time-unit",
        choices=("s", "ms"),
        default="s",
        help="unit of the file's time column (default s); --dt is always in seconds",
    )
    p.add_argument(
        "--resample",
        action="store_true",
        help="if the file's time stamps are off a uniform grid by more than 1 %% of a "
        "sample (a logging clock's jitter), interpolate every signal linearly onto a "
        "uniform grid at the median sample interval (--dt when given) instead of refusing",
    )
    p.add_argument(
        "--forcing",
        default=None,
        help="forcing preset the trial was run with: its frequencies (the describing "
        "function) and the target ahead a preview fit reads",
    )
    p.add_argument("--realisation", type=int, default=0, help="realisation of --forcing")
    p.add_argument(
        "--period",
        type=_positive_float,
        default=None,
        help="period (s) of the forcing, when no --forcing preset describes it: the forcing "
        "frequencies are then read off the file's target and disturbance columns",
    )
    p.add_argument(
        "--element",
        default=None,
        help="the controlled element of the experiment: a preset (SI, DI, gain, ...) or a "
        "transfer function in s such as 1/s, 2.5/s^2, '1/(s(s+1))', '(s+2)/(s^2+0.5s+4)' "
        "(default: the recording's own, if it names one)",
    )
    p.add_argument(
        "--disturbance-at",
        choices=("output", "input"),
        default=None,
        help="where the disturbance column entered the loop: added to the element's output "
        "(default, unless the recording says) or to its input",
    )


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``manualcontrol`` command."""
    parser = argparse.ArgumentParser(
        prog="manualcontrol",
        description="Tracking tasks, cybernetic pilots and online estimators of manual control.",
        epilog="Exit codes: 0 ok, 2 usage or input error, 3 some benchmark runs failed, "
        "1 internal error.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = commands.add_parser("suites", help="list the built-in benchmark suites")
    p.set_defaults(run=_cmd_suites)

    p = commands.add_parser("estimators", help="list the estimator family, one line each")
    p.set_defaults(run=_cmd_estimators)

    p = commands.add_parser(
        "simulate", help="simulate a pilot in a tracking task, write a recording"
    )
    p.add_argument(
        "--model",
        default="precision",
        help="pilot model: precision, preview, schiess-roland, gain-delay; its parameters "
        "default to typical values for the element (thesis SI and DI pilots, ...)",
    )
    p.add_argument(
        "--param",
        action="append",
        metavar="NAME=VALUE",
        help="pilot parameter, a number or a schedule like sigmoid:0.6,0.3,50,20 (start, end, "
        "t_mid, transition_time), sine:mean,amplitude,period,phase, ramp:..., step:...; repeatable",
    )
    p.add_argument(
        "--remnant", default=None, help="remnant preset (popovici2017, vertregt2020-SI, ...)"
    )
    p.add_argument(
        "--delay-order",
        type=int,
        default=None,
        help="Padé order of the pilot delay (default exact)",
    )
    p.add_argument(
        "--element",
        default="SI",
        help="controlled element: a preset (SI, DI, popovici2017, ...) or a transfer function "
        "in s such as 1/s, 2.5/s^2, '1/(s(s+1))', 'num=[1]; den=[1, 1, 0]'",
    )
    p.add_argument("--forcing", default="vanderel-bw4", help="forcing preset")
    p.add_argument(
        "--disturbance-at",
        default="output",
        metavar="{output,input}",
        help="where the forcing's disturbance enters: added to the element's output "
        "(default) or to its input, driving the element (a force on the stick, a gust)",
    )
    p.add_argument("--realisation", type=int, default=0, help="forcing realisation index")
    p.add_argument(
        "--task", default=None, help="compensatory, pursuit or preview (default: the model's)"
    )
    p.add_argument(
        "--available-preview", type=float, default=None, help="preview shown (s), preview tasks"
    )
    p.add_argument("--dt", type=float, default=0.01, help="sample time (s)")
    p.add_argument("--run-in", type=float, default=60.0, help="run-in simulated and cut (s)")
    p.add_argument(
        "--measurement-time", type=float, default=None, help="measured time (s), default T_m"
    )
    p.add_argument("--seed", type=int, default=0, help="remnant seed")
    p.add_argument("--loop", default="continuous", help="continuous or sampled")
    p.add_argument(
        "--allow-unstable",
        action="store_true",
        help="keep a run whose loop diverges (a warning, flagged in the recording's "
        "metadata) instead of refusing it",
    )
    p.add_argument("--out", required=True, type=Path, help="recording file (.npz, .csv or .mat)")
    p.add_argument("--plot", type=Path, default=None, help="also draw the run to this PNG")
    p.set_defaults(run=_cmd_simulate)

    p = commands.add_parser(
        "identify", help="estimate pilot parameters from a recording or experiment file"
    )
    p.add_argument(
        "recording", type=Path, help="a Recording or an experiment file (.npz, .csv, .mat)"
    )
    p.add_argument(
        "--estimator",
        default="dekf",
        help="estimator name (default dekf; `manualcontrol estimators` lists the family)",
    )
    p.add_argument(
        "--model",
        default=None,
        help="pilot model structure of the pilot-model estimators (dekf, rml, joint-ukf, "
        "dual-ukf and their -smoothed twins): precision (default) or preview",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="estimator setting, e.g. ce=DI, anticipation_time=0.9, r2=4, "
        'estimated=["K_p","K_v"]; repeatable',
    )
    _add_trial_options(p)
    p.add_argument(
        "--target-period",
        type=_positive_float,
        default=None,
        help="period (s) of the target, for the target ahead a preview fit reads; the "
        "recording must last whole periods",
    )
    p.add_argument(
        "--allow-unstable",
        action="store_true",
        help="accept an identified pilot that closes an unstable loop (a warning)",
    )
    p.add_argument("--out", type=Path, default=Path("results/identify"), help="output folder")
    p.set_defaults(run=_cmd_identify)

    p = commands.add_parser(
        "describe",
        help="measure the pilot's describing function at the forcing frequencies of a "
        "compensatory trial: crossover, phase margin and a fitted pilot model",
    )
    p.add_argument(
        "recording", type=Path, help="a Recording or an experiment file (.npz, .csv, .mat)"
    )
    _add_trial_options(p)
    p.add_argument(
        "--task",
        choices=("compensatory", "pursuit", "preview"),
        default=None,
        help="the display (default: the recording's, else compensatory); on a pursuit or "
        "preview display the pilot sees the target and y, and the table shows the "
        "disturbance's lines, where the target is still",
    )
    p.add_argument(
        "--model",
        default=None,
        help="pilot model fitted to the describing function: precision (default on a "
        "compensatory display), preview (pursuit and preview), gain-delay",
    )
    p.add_argument(
        "--fix",
        action="append",
        metavar="NAME=VALUE",
        help="hold a model parameter at a value in the fit, e.g. K_v=0; repeatable",
    )
    p.add_argument("--out", type=Path, default=Path("results/describe"), help="output folder")
    p.set_defaults(run=_cmd_describe, target_period=None)

    p = commands.add_parser("bench", help="run a benchmark suite, write results and a report")
    p.add_argument("suite", help="built-in suite name (see `manualcontrol suites`) or a .toml file")
    p.add_argument("--out", type=Path, default=None, help="output folder (default results/SUITE)")
    p.add_argument("--quick", action="store_true", help="each batch's quick subset")
    p.add_argument(
        "--backend",
        default="process",
        choices=("process", "inprocess", "ray"),
        help="process pool (default), in this process, or Ray",
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="process-pool size (default: all cores)",
    )
    p.add_argument(
        "--estimators",
        default=None,
        metavar="NAME,NAME",
        help="run these estimators in every batch instead of the suite's (see "
        "`manualcontrol estimators`); each reads the same simulated runs",
    )
    p.add_argument("--no-report", action="store_true", help="skip the Markdown/PNG report")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=_cmd_bench)

    p = commands.add_parser("train", help="train an RL surrogate operator (stable-baselines3)")
    p.add_argument(
        "--recipe",
        default=None,
        metavar="NAME",
        help="a measured training recipe (si: compensatory tracking of 1/s with a human's "
        "delay, neuromuscular system, motor and observation noise and effort "
        "cost); takes --seed, --steps and --checkpoint-every, "
        "nothing else that sets the training",
    )
    p.add_argument(
        "--task", default="compensatory", help="compensatory, pursuit, preview or lane-keeping"
    )
    p.add_argument(
        "--env",
        action="append",
        metavar="KEY=VALUE",
        help="environment keyword, e.g. controlled_element=DI; repeatable",
    )
    p.add_argument(
        "--delay",
        default=None,
        metavar="SECONDS",
        help="action delay (s): a number or a schedule KIND:ARGS (ramp:0.2,0.3,10,30 rises "
        "from 0.2 to 0.3 s between t = 10 and 30 s; sigmoid, sine, step as in simulate --param)",
    )
    p.add_argument(
        "--hide-queue",
        action="store_true",
        help="hide the actions still in the delay queue from the agent (by default they "
        "are observed, which keeps the task Markov but lets the agent predict through "
        "the delay; hidden, it must act through the delay as a human does)",
    )
    p.add_argument(
        "--neuromuscular",
        type=float,
        nargs=2,
        metavar=("OMEGA", "ZETA"),
        default=None,
        help="neuromuscular filter frequency (rad/s) and damping",
    )
    p.add_argument(
        "--motor-noise",
        default=None,
        metavar="P_R",
        help="motor-noise power ratio (a number or a schedule KIND:ARGS)",
    )
    p.add_argument(
        "--observation-noise",
        default=None,
        metavar="RATIO",
        help="observation noise on the display: the optimal control model's noise-to-signal "
        "ratio of each observed signal (intensity pi RATIO times its variance; 0.01 is -20 dB; "
        "a number or a schedule KIND:ARGS); default none",
    )
    p.add_argument(
        "--effort-rate-weight",
        default=None,
        metavar="W",
        help="effort cost on the stick rate: the reward loses W (du/dt / action_bound)^2, W "
        "in s^2 (a number or a schedule KIND:ARGS); default none",
    )
    p.add_argument(
        "--history",
        type=int,
        default=1,
        metavar="N",
        help="observations the policy sees side by side (N dt seconds of memory: a policy "
        "that can adapt); default 1, the current one",
    )
    p.add_argument(
        "--deterministic-evaluation",
        action="store_true",
        help="evaluate this agent without the wrappers' noise by default (by default the "
        "noise stays on and makes the trial-to-trial variability)",
    )
    p.add_argument("--algorithm", default="sac", choices=("sac", "ppo"), help="RL algorithm")
    p.add_argument(
        "--steps",
        type=int,
        default=None,
        help="environment steps (default 100000, or the recipe's)",
    )
    p.add_argument("--envs", type=int, default=1, help="parallel environments")
    p.add_argument(
        "--algorithm-option",
        action="append",
        metavar="KEY=VALUE",
        help="keyword for the stable-baselines3 algorithm, e.g. n_steps=512; repeatable",
    )
    p.add_argument(
        "--net-arch",
        type=int,
        nargs="+",
        metavar="UNITS",
        default=None,
        help="hidden layer sizes of the policy (and value) networks, e.g. 64 64",
    )
    p.add_argument("--seed", type=int, default=0, help="seed")
    p.add_argument("--checkpoint-every", type=int, default=None, help="save weights every N steps")
    p.add_argument("--out", type=Path, required=True, help="output folder for the agent")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(run=_cmd_train)

    p = commands.add_parser("evaluate", help="evaluate a trained agent like a human operator")
    p.add_argument("agent", type=Path, help="folder written by `manualcontrol train`")
    p.add_argument(
        "--out", type=Path, default=None, help="report folder (default AGENT/evaluation)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the evaluation run")
    p.add_argument(
        "--deterministic",
        action="store_const",
        const=True,
        default=None,
        help="run without the wrappers' observation and motor noise (default: as the agent "
        "was configured, noise on); a noise-free run has no remnant, which no human shows",
    )
    p.add_argument(
        "--trust-pickle",
        action="store_true",
        help="load model.zip (pickle: runs code from the file; only for files you trust)",
    )
    p.set_defaults(run=_cmd_evaluate)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command; return its exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # argparse has printed its message (or the help)
        return exit_.code if isinstance(exit_.code, int) else EXIT_USAGE
    try:
        return args.run(args)
    except BrokenPipeError:
        # the reader left (`manualcontrol suites | head`): not an error of the command;
        # stdout goes to devnull so the interpreter's last flush does not fail again
        # (the Python documentation's recipe, exit status 1)
        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except (UsageError, ValueError, TypeError, KeyError, OSError) as error:
        # our checks raise these for bad input, the file system OSError for paths that
        # cannot be read or written; MANUALCONTROL_DEBUG=1 shows the traceback
        if os.environ.get("MANUALCONTROL_DEBUG"):
            raise
        message = error.args[0] if isinstance(error, KeyError) and error.args else error
        print(f"manualcontrol {args.command}: error: {message}", file=sys.stderr)
        return EXIT_USAGE


def main_exit() -> None:
    """Console-script entry point: run and exit with the command's code."""
    sys.exit(main())


if __name__ == "__main__":  # pragma: no cover
    main_exit()
