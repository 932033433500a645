"""The ``manualcontrol`` command.

Subcommands: ``simulate`` (a pilot in a tracking task -> a recording), ``play`` (a
person flies a task -> a recording), ``identify`` (a recording or an experiment file ->
parameter traces and plots), ``describe`` (a compensatory trial -> its describing
function, crossover and a fitted model), ``bench`` (a suite -> results table and report),
``suites`` (list them), ``train`` (an RL surrogate operator), ``evaluate`` (a trained
agent -> report) and ``compile`` (the kernels into numba's cache, the C ports built).
``manualcontrol COMMAND --help`` explains every option.

Each command imports what it runs when it runs (``play``'s flags too: its parser is
filled when ``play`` is the command), so ``--help`` and the listings start at once.
The library's messages name its Python keywords (``forcing=``); :func:`cli_words`
words them as this command's flags (``--forcing PRESET``) wherever they are printed.

Exit codes: 0 success; 2 a usage or input error (the message says what to fix, no
traceback); 3 a benchmark finished but some of its runs failed (see the results
table), an identification that diverged or closes an unstable loop, or kernels that
did not compile; 130 interrupted with Ctrl-C (one line, no traceback); 1 an unexpected
internal error (with traceback).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import inspect
import json
import math
import os
import re
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["cli_words", "main"]

EXIT_OK, EXIT_INTERNAL, EXIT_USAGE, EXIT_RUNS_FAILED = 0, 1, 2, 3
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """A mistake of the user: reported as a one-line message, exit code 2."""


#: What ``identify`` runs unless told: the member docs/estimators.md recommends for a
#: lab's trial, which a session's report identifies with too
#: (``manualcontrol.human.report.DEFAULT_ESTIMATOR``). Not the DEKF: it reproduces its
#: papers, and on human-like pilots its delay comes out biased low.
IDENTIFY_ESTIMATOR = "rml"


# ------------------------------------------------- the library's words, as flags

#: Whole phrases of library messages that the command line says otherwise.
_PHRASES: tuple[tuple[str, str], ...] = (
    (
        "give the forcing (forcing=) or its period (period=, seconds)",
        "give --forcing PRESET or --period SECONDS",
    ),
    (
        " (or pass format='npz', 'csv' or 'mat')",
        " (rename the file to end in one of them)",
    ),
    (
        "(reset with var_u0 and var_e0, or use initial_variance='first-window' through estimate)",
        "(--set initial_variance=first-window measures them; they are zero when u or e "
        "never moves)",
    ),
    (
        "use typical parameters for the element (Pilot.typical(model, element); the "
        "`manualcontrol simulate` default), or pass on_unstable='warn' (--allow-unstable)",
        "leave the parameters at the element's typical values (drop --param), or pass "
        "--allow-unstable",
    ),
    ("pass resample=True", "pass --resample"),
    (" (`--forcing PRESET`)", ""),
    (
        "band=(low, high) in rad/s (`cv_band` in suite files and `--set`)",
        "--set cv_band='[low, high]' in rad/s",
    ),
    (
        "(folds, gap; `cv_folds`, `cv_gap` in suite files and `--set`)",
        "(--set cv_folds=N, --set cv_gap=SECONDS)",
    ),
    ("(task='pursuit' or 'preview')", "(--task pursuit or preview)"),
    (" (a ForcingPair or a callable of time)", ""),
    ("record metadata['forcing'], ", ""),
)

#: Keywords of the library's functions and the flag that gives each on the command line.
_FLAGS: dict[str, str] = {
    "forcing": "--forcing PRESET",
    "target_period": "--target-period SECONDS",
    "period": "--period SECONDS",
    "element": "--element",
    "dt": "--dt SECONDS",
    "disturbance_at": "--disturbance-at",
    "time_unit": "--time-unit",
    "time_column": "--column t=COLUMN",
    "task": "--task",
    "model": "--model",
}

#: Per command, the library's names a message may start with and the flag that sets
#: each: the message is then led by the flag (``dt must be > 0`` is ``--dt``'s).
_LEADING_NAMES: dict[str, tuple[tuple[str, str], ...]] = {
    "simulate": (
        ("pilot model", "--model"),
        ("forcing preset", "--forcing"),
        ("remnant", "--remnant"),
        ("task", "--task"),
        ("loop", "--loop"),
        ("controlled element", "--element"),
        ("element", "--element"),
        ("realisation", "--realisation"),
        ("available_preview", "--available-preview"),
        ("measurement_time", "--measurement-time"),
        ("run_in", "--run-in"),
        ("delay_order", "--delay-order"),
        ("disturbance_at", "--disturbance-at"),
        ("pilot parameter", "--param"),
    ),
    "train": (
        ("total_timesteps", "--steps"),
        ("n_envs", "--envs"),
        ("delay", "--delay"),
        ("omega_nms", "--neuromuscular"),
        ("zeta_nms", "--neuromuscular"),
        ("power_ratio", "--motor-noise"),
        ("task", "--task"),
        ("checkpoint_every", "--checkpoint-every"),
        ("select_every", "--select-every"),
        ("select_episodes", "--select-episodes"),
        ("algorithm_kwargs", "--algorithm-option"),
        ("observation_noise_ratio", "--observation-noise"),
        ("effort_rate_weight", "--effort-rate-weight"),
    ),
    "bench": (("estimators", "--estimators"),),
    "identify": (
        ("pilot model", "--model"),
        ("model", "--model"),
        ("target_period", "--target-period"),
        ("band", "--set cv_band"),
    ),
    "describe": (("pilot model", "--model"), ("model", "--model")),
}


def _led_by_flag(text: str, command: str) -> str:
    """``text`` led by the flag of the name it starts with (:data:`_LEADING_NAMES`)."""
    if re.match(r"^\w+Model has no parameter", text) and command == "simulate":
        return f"--param: {text}"
    for name, flag in _LEADING_NAMES.get(command, ()):
        if re.match(rf"^{re.escape(name)}\b", text):
            return f"{flag}: {text}"
    return text


#: Estimator settings the library's messages name (``identify --set NAME=VALUE``).
_SETTINGS = (
    "initial_variance",
    "initial",
    "start",
    "limits",
    "remnant_injection",
    "estimated",
    "anticipation_time",
    "window",
    "restarts",
    "q2",
    "r2",
    "ce",
)

#: ``name=`` where a keyword starts: not inside a word, a flag, or ``--set name=``.
_KEYWORD = r"(?<![\w\-.'\"`\[])(?<!--set )\b({names})="


def cli_words(text: str, command: str = "") -> str:
    """A library message as the command line says it: its flags for the Python keywords.

    ``give forcing= or period=`` becomes ``give --forcing PRESET or --period SECONDS``,
    ``time_unit='ms'`` ``--time-unit ms``, and for ``identify`` the estimator settings
    ``initial={'K_p': ...}`` ``--set initial='{"K_p": ...}'`` and ``start='generic'``
    ``--set start=generic``. Parameter values such as ``K_p=1.2`` and text already in
    the command line's words are left as they are.
    """
    for phrase, words in _PHRASES:
        text = text.replace(phrase, words)
    flags = _KEYWORD.format(names="|".join(sorted(_FLAGS, key=len, reverse=True)))

    def flag(found: re.Match[str]) -> str:
        name, value = found.group(1), found.group(2)
        word = _FLAGS[name]
        if not value:  # a bare keyword: the flag and its placeholder
            return word
        head, _, placeholder = word.partition(" ")
        value = value.strip("'")
        if "=" in placeholder:  # --column t=COLUMN: the value is the column
            return f"{head} {placeholder.split('=')[0]}={value}"
        return f"{head} {value}"

    text = re.sub(flags + r"('[^']*'|(?=[\s,;:)]|$))", flag, text)
    if command != "identify":
        return text
    settings = _KEYWORD.format(names="|".join(_SETTINGS))

    def setting(found: re.Match[str]) -> str:
        name, value = found.group(1), found.group(2)
        if not value:
            return f"--set {name}=..."
        if value.startswith("{"):  # a Python dict: JSON, quoted for the shell
            return "--set " + name + "='" + value.replace("'", '"') + "'"
        return "--set " + name + "=" + value.strip("'")

    return re.sub(settings + r"(\{[^}]*\}|'[^']*'|(?=[\s,;:)]|$))", setting, text)


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
    """``NAME=VALUE`` items as a dict, each value read by :func:`_value`.

    A value written as a JSON table or list (``{...}``, ``[...]``) that does not parse is
    refused, saying where it broke, instead of arriving as a string that a setting then
    calls "not a mapping".
    """
    out, given = {}, {}
    for item in items or ():
        if "=" not in item:
            raise UsageError(f"{what} must look like NAME=VALUE, got {item!r}")
        name, text = item.split("=", 1)
        name = name.strip()
        if not name:
            raise UsageError(f"{what} must look like NAME=VALUE, got {item!r} (no name)")
        if name in out:
            raise UsageError(
                f"{what} {name}= is given twice ({given[name]!r} and {item!r}): give it once"
            )
        given[name] = item
        if text.strip()[:1] in ("{", "["):
            try:
                json.loads(text)
            except json.JSONDecodeError as error:
                raise UsageError(
                    f"{what} {name}=: {text!r} is not valid JSON ({error.msg} at character "
                    f"{error.pos + 1}); JSON writes strings in double quotes and has no nan "
                    'or inf: where a setting allows infinity give the string "inf" or '
                    '"-inf" (e.g. limits=\'{"K_p": [0, "inf"]}\')'
                ) from None
        out[name] = _value(text)
    return out


#: Settings that hold a tuple of parameter names: ``--set estimated=K_p,K_v`` gives one.
_NAME_TUPLES = ("estimated",)


def _settings(items: Sequence[str] | None) -> dict[str, Any]:
    """``--set`` items: a bare name or comma-separated names for a tuple of names."""
    settings = _assignments(items, "--set")
    for key in _NAME_TUPLES:
        value = settings.get(key)
        if isinstance(value, str):
            settings[key] = tuple(name.strip() for name in value.split(",") if name.strip())
        if key in settings and settings[key] in ("", (), []):
            raise UsageError(
                f"--set {key}= names no parameter: give names (e.g. {key}=K_p,tau_v), or leave "
                "it out for the model's rules"
            )
    return settings


def _schedule(text: Any) -> Any:
    """``0.3``, ``sigmoid:0.6,0.3,50,20``, ``sine:0.2,0.05,90,0``, ``ramp:...``, ``step:...``."""
    from manualcontrol.envs.schedules import Ramp, Sigmoid, Sine, Step

    if not isinstance(text, str):
        return text
    kind, _, arguments = text.partition(":")
    builders = {"sigmoid": Sigmoid, "sine": Sine, "ramp": Ramp, "step": Step}
    if kind not in builders or not arguments:
        raise UsageError(
            f"a parameter value must be a finite number or KIND:ARGS with KIND one of "
            f"{', '.join(builders)}, got {text!r}"
        )
    builder = builders[kind]
    names = [
        name
        for name, parameter in inspect.signature(builder).parameters.items()
        if parameter.default is inspect.Parameter.empty
    ]
    try:
        numbers = [float(a) for a in arguments.split(",")]
    except ValueError:
        raise UsageError(
            f"bad {kind} schedule {text!r}: give {len(names)} numbers ({', '.join(names)})"
        ) from None
    if len(numbers) != len(names):
        raise UsageError(
            f"bad {kind} schedule {text!r}: give {len(names)} numbers ({', '.join(names)}), "
            f"got {len(numbers)}"
        )
    try:
        return builder(*numbers)
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
    from manualcontrol.bench.listing import builtin_suite_names, outline, read_builtin_suite

    for name in builtin_suite_names():
        suite = outline(read_builtin_suite(name))
        batches = ", ".join(f"{batch}: {count}" for batch, count in suite.runs.items())
        print(f"{name}: {suite.description}")
        print(
            f"    {sum(suite.runs.values())} runs ({batches}); "
            f"--quick: {sum(suite.quick_runs.values())} runs"
        )
    return EXIT_OK


def _cmd_estimators(args: argparse.Namespace) -> int:
    from manualcontrol.estimators.registry import ESTIMATORS

    width = max(len(name) for name in ESTIMATORS)
    for entry in ESTIMATORS.values():
        print(f"{entry.name:<{width}}  {entry.summary} [{entry.reference}]")
    return EXIT_OK


def _warn_of_aliasing(recording: Any, dt: float) -> None:
    """Warn where the forcing has lines at or above the Nyquist frequency of ``dt``."""
    from manualcontrol.envs.signals import ForcingPair, Multisine

    known = recording.metadata.get("forcing")
    if known is None:
        return
    pair = ForcingPair.from_dict(known)
    signals = [s for s in (pair.target, pair.disturbance) if isinstance(s, Multisine)]
    highest = max((float(np.max(s.frequencies)) for s in signals), default=0.0)
    if highest >= math.pi / dt:
        print(
            f"manualcontrol simulate: warning: the forcing has lines up to {highest:.3g} rad/s, "
            f"at or above the Nyquist frequency pi/dt = {math.pi / dt:.3g} rad/s of --dt {dt:g}: "
            "they alias onto lower frequencies; use a smaller --dt",
            file=sys.stderr,
        )


def _cmd_simulate(args: argparse.Namespace) -> int:
    import warnings

    from manualcontrol.pilots import Pilot
    from manualcontrol.pilots.stability import UnstableLoopWarning

    _check_output("--out", args.out, folder=False)
    if Path(args.out).exists() and not args.overwrite:
        # a lab's recording may sit there: a simulation replaces it only when told to
        raise UsageError(
            f"--out {args.out}: the file exists; give another name, or pass --overwrite to "
            "replace it"
        )
    if args.plot is not None:
        _check_output("--plot", args.plot, folder=False)
        if Path(args.plot).suffix.lower() != ".png":
            raise UsageError(f"--plot {args.plot}: the drawing is a PNG; name it FILE.png")
    parameters = {}
    for name, value in _assignments(args.param, "--param").items():
        try:
            parameters[name] = _schedule(value)
        except UsageError as error:
            raise UsageError(f"--param {name}=: {error}") from None
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
    _warn_of_aliasing(recording, args.dt)
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
    from manualcontrol.envs.recording import (
        SIGNAL_NAMES,
        MissingColumnError,
        NonUniformTimeError,
        Recording,
    )

    columns = _assignments(args.column, "--column")
    for name, value in columns.items():
        if not isinstance(value, str):
            columns[name] = str(value)  # a numeric column name such as 2
        if name not in SIGNAL_NAMES:
            raise UsageError(
                f"--column {name}={columns[name]}: {name!r} is no signal; --column maps a "
                f"signal ({', '.join(SIGNAL_NAMES)}) to the file's column, SIGNAL=COLUMN"
            )
        if not columns[name]:
            raise UsageError(f"--column {name}=: give the file's column name after '='")
    read_twice = sorted({c for c in columns.values() if list(columns.values()).count(c) > 1})
    if read_twice:
        signals = [n for n, c in columns.items() if c == read_twice[0]]
        raise UsageError(
            f"--column: the file's column {read_twice[0]!r} is given for {' and '.join(signals)}; "
            "each signal reads its own column"
        )
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
    except ValueError as error:
        if "is in more than one variable" in str(error):
            text = re.sub(r"columns=\{'(\w+)': '([^']+)'\}", r"--column \1=\2", str(error))
            raise UsageError(text) from None
        given = f"dt={args.dt!r} contradicts the time column"
        if args.dt is not None and given in str(error):
            text = str(error).replace(given, f"--dt {args.dt:g} contradicts the time column")
            raise UsageError(text.replace("leave dt= out", "leave --dt out")) from None
        raise
    if args.time_unit == "ms" and recording.dt < 1e-3:
        raise UsageError(
            f"{args.recording}: with --time-unit ms the sample time is {recording.dt:g} s "
            f"({1.0 / recording.dt:.3g} Hz): the time column looks like seconds; leave "
            "--time-unit out"
        )
    if recording.dt >= 1.0:
        if args.time_unit == "ms":
            hint = "--time-unit ms divides the file's time column by 1000; --dt is in seconds"
        elif args.dt is not None:
            hint = f"--dt {args.dt:g} is the sample time in seconds (a rate of 100 Hz is --dt 0.01)"
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
        # a disturbance-only compensatory trial: labs often log no target, which is zero;
        # but a forcing that moves the target says it was not, and e = -y would make the
        # pilot's describing function -1 at the target's lines, with no word of it
        forcing = None if getattr(args, "forcing", None) is None else _forcing_of_flag(args)
        if forcing is not None and forcing.target is not None:
            raise UsageError(
                f"{args.recording}: --forcing {args.forcing} moves the target, and the file "
                "has no target or error column to form the error from: name it (--column "
                "ft=COLUMN or --column e=COLUMN); if the trial moved no target, give a "
                "forcing file of its disturbance alone (--forcing FILE.json) or --period"
            )
        print("no target or error column: the target is taken as zero (e = -y)")
        recording = recording.with_signals(ft=np.zeros(len(recording)))
    if "e" not in recording and "ft" in recording and "y" in recording:
        recording = recording.with_error_signal()
    from manualcontrol.estimators.analysis.identification import control_never_moves

    still = control_never_moves(recording)  # said before any estimator or fit runs
    if still is not None:
        raise UsageError(f"{args.recording}: {still}")
    return recording


# ---------------------------------------------------------- result folders


#: What :func:`_held_result` calls a benchmark's results folder.
_BENCH_RESULT = "a benchmark's results (bench)"


def _held_result(out: Path) -> str | None:
    """What result ``out`` holds, in words (``"a dekf identification"``), or None."""
    summary = out / "summary.json"
    if not summary.is_file():
        if (out / "results.csv").is_file() or (out / "runs").is_dir():
            return _BENCH_RESULT
        return None
    try:
        data = json.loads(summary.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return "a summary.json that cannot be read"
    if isinstance(data, dict) and isinstance(data.get("estimator"), str):
        return f"a {data['estimator']} identification"
    if isinstance(data, dict) and "describing_function" in data:
        return "a describing-function measurement (describe)"
    return "a summary.json of another program"


def _check_result_folder(out: Path, mine: str, overwrite: bool) -> None:
    """Refuse ``out`` when it holds another result than ``mine`` (unless ``overwrite``)."""
    held = _held_result(out)
    if held is None or held == mine or overwrite:
        return
    raise UsageError(
        f"--out {out}: the folder holds {held} (its summary.json); writing {mine} there "
        "would replace it: give another --out folder, or pass --overwrite to replace it"
    )


@contextlib.contextmanager
def _staged(out: Path, stale: Sequence[str] = ()) -> Iterator[Path]:
    """A new folder beside ``out`` to write a result into; its files then replace out's.

    Until everything is written nothing in ``out`` changes: a failure or Ctrl-C leaves the
    earlier result there whole, never part of the old beside part of the new. The files
    move into ``out`` at the end with Ctrl-C held off meanwhile (an absent ``out`` is the
    staged folder renamed); files of ``out`` that this command does not write stay, except
    those named in ``stale`` (files of an earlier result this one leaves out, such as its
    figure, which would no longer match), removed in the same moment.
    """
    import shutil
    import tempfile

    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        stage = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".part", dir=out.parent))
    except PermissionError:
        if not out.is_dir():
            raise UsageError(f"--out {out}: cannot write in {out.parent}") from None
        # a writable folder in a read-only one: stage inside it (each file still moves whole)
        stage = Path(tempfile.mkdtemp(prefix=".staged.", suffix=".part", dir=out))
    try:
        yield stage
        with _ctrl_c_held():
            if not out.exists():
                os.chmod(stage, 0o777 & ~_umask())  # mkdtemp's folder is private
                os.rename(stage, out)
            else:
                for path in sorted(stage.iterdir()):
                    os.replace(path, out / path.name)
                for name in stale:
                    (out / name).unlink(missing_ok=True)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def _ctrl_c_held() -> Iterator[None]:
    """Hold Ctrl-C off for a moment (the main thread only); it takes effect on leaving."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[Any] = []
    previous = signal.signal(signal.SIGINT, lambda *frame: caught.append(frame))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


def _target_source(args: argparse.Namespace) -> dict[str, Any]:
    """Where a preview fit reads the target ahead: ``--forcing`` or ``--target-period``."""
    if args.forcing is not None and args.target_period is not None:
        raise UsageError("give --forcing or --target-period, not both")
    if args.forcing is not None:
        return {"forcing": _forcing_of_flag(args)}
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


#: What a high share of innovation lags outside the white-noise band means, and what to do.
_WHITENESS_GUIDE = (
    "  (white innovations need u to be the model's output plus white noise: a human's "
    "remnant is coloured, a model may miss some of the pilot's dynamics, and on noise-free "
    "data (a remnant-free simulation) the small residue left is smooth, so a high share is "
    "common and no error by itself; judge the parameters by the frequency-domain check "
    "(it needs --forcing or --period where the recording does not name its forcing))"
)


def _cmd_identify(args: argparse.Namespace) -> int:
    from manualcontrol.envs._files import atomic_write
    from manualcontrol.estimators.analysis.fit_check import WHITENESS_LIMIT
    from manualcontrol.estimators.analysis.identification import build_estimator, identify
    from manualcontrol.estimators.members.pilot_filter import EVIDENCE
    from manualcontrol.estimators.protocol import reporting_progress
    from manualcontrol.estimators.registry import ESTIMATORS

    _check_output("--out", args.out, folder=True)
    out = Path(args.out)
    _check_result_folder(out, f"a {args.estimator} identification", args.overwrite)
    recording = _load_trial(args)
    source = _trial_forcing(args, recording)  # --forcing with --period: said before any work
    # an unreadable --element: in its own words
    element = _trial_element(recording, args, "identify")
    settings = _settings(args.set)
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
    try:
        estimator = build_estimator(
            args.estimator, settings, model=args.model, element=args.element
        )
    except (TypeError, ValueError) as error:
        text = str(error)
        unknown = re.fullmatch(
            r"the (\S+) estimator has no setting (.+?); its settings: (.*)", text, re.DOTALL
        )
        if unknown is not None:
            names, known = (unknown.group(i).replace("'", "") for i in (2, 3))
            text = (
                f"--set {names}: the {unknown.group(1)} estimator has no such setting; its "
                f"settings: {known}"
            )
        raise UsageError(_led_by_flag(cli_words(text, "identify"), "identify")) from None
    if not source and args.target_period is not None:  # the target's period is the forcing's
        source = {"period": args.target_period}
    try:
        # the offline members take minutes on a long run: a line per step says how it goes
        with reporting_progress(_progress_line):
            identification = identify(
                recording,
                estimator,
                element=element,
                target=target,
                forcing=source.get("forcing"),
                period=source.get("period"),
                disturbance_at=args.disturbance_at,
                name=args.estimator,
            )
    except ValueError as error:
        if "target ahead of the samples is unknown" in str(error):
            raise UsageError(_PREVIEW_HINT) from None
        for setting in ("remnant_injection='choose'", "start='describing-function'"):
            if f"{setting} needs the describing function" in str(error):
                flag = setting.replace("'", "")
                reason = re.search(r"describing function of the run \((.*)\); pass", str(error))
                if reason and "forcing frequencies are unknown" not in reason.group(1):
                    # the forcing is known (a flag or the file's own): say why it failed
                    why = cli_words(reason.group(1), "identify")
                    # the filters' measurement has no --method to switch
                    why = re.sub(r" \(method='least-squares'[^)]*\)", "", why)
                    raise UsageError(
                        f"--set {flag} could not measure the describing function: {why}"
                    ) from None
                raise UsageError(
                    f"--set {flag} reads the describing function at the forcing "
                    "frequencies: give --forcing PRESET or --period SECONDS (the forcing "
                    "signals being in the file)"
                ) from None
        if "remnant_injection='choose-causal' measures" in str(error):
            raise UsageError(
                "--set remnant_injection=choose-causal measures the describing function of "
                "the samples so far at the forcing's lines: give --forcing PRESET (the "
                "forcing lines must be known; --period is not enough)"
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
    truth = identification.truth  # a simulation's true parameters: the errors against them
    with _staged(out, stale=("parameters.png",) if args.no_plot else ()) as stage:
        result.save(stage / "estimation.npz")
        text = json.dumps(summary, indent=2)
        atomic_write(stage / "summary.json", lambda p: p.write_text(text))
        if not args.no_plot:
            from manualcontrol.bench.report import plot_estimation

            plot_estimation(recording, result, stage / "parameters.png", model_output=model_output)
    path = out / "estimation.npz"
    written = [path, out / "summary.json"] + ([] if args.no_plot else [out / "parameters.png"])
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
        if math.isfinite(outside) and outside > WHITENESS_LIMIT:
            print(_WHITENESS_GUIDE)
    if truth is not None:
        errors = ", ".join(
            f"{name} {'n/a' if value is None else f'{value:.3g}'}"
            + (" (RMSE: its true mean is near 0)" if truth["error_kind"][name] == "rmse" else "")
            for name, value in truth["nrmse"].items()
        )
        print(f"against the simulation's true parameters (over the whole run): NRMSE {errors}")
    _print_frequency_check(check, args.period)
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
    if isinstance(injection, Mapping) and "decisions" in injection:
        where = {"input": "perception", "output": "stick"}
        changes = ", ".join(
            f"{where[d['point']]} from {d['t']:.0f} s" for d in injection["decisions"]
        )
        print(
            f"remnant model, chosen causally: at the {where[injection['chosen']]} at the end "
            f"({changes}; before the first decision, half a forcing period in, the perception)"
        )
    elif isinstance(injection, Mapping):
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
    print(f"wrote {', '.join(map(str, written))}")
    model = args.model or settings.get("model", "precision")
    if pilot_model:
        from manualcontrol.pilots.models import LAGGED_PRECISION, model_for_element

        if model_for_element(model, element) != model:  # the lag humans adopt left out
            print(
                "manualcontrol identify: warning: on a pure gain humans equalise with a lag "
                "(McRuer), which the precision model lacks: `manualcontrol describe` fits "
                f"the lag's model ({LAGGED_PRECISION}) to the describing function, and "
                f"--model {LAGGED_PRECISION} gives it to the filters",
                file=sys.stderr,
            )
    for warning in check.warnings:
        print(f"manualcontrol identify: warning: {cli_words(warning, 'identify')}", file=sys.stderr)
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
            f"manualcontrol identify: {level}: {cli_words(stability['message'], 'identify')}"
            + ("" if args.allow_unstable else " (--allow-unstable to accept it)"),
            file=sys.stderr,
        )
        if not args.allow_unstable:
            code = EXIT_RUNS_FAILED
    return code


#: A power ratio above this is printed as such: the remnant off the line is rounding
#: (a remnant-free simulation) and its digits say nothing (60 dB).
_RATIO_SHOWN = 1e6


def _power_ratio(value: float) -> str:
    """A signal-to-noise power ratio for the describe table, ``>1e+06`` past what means."""
    return f">{_RATIO_SHOWN:.0e}" if value > _RATIO_SHOWN else f"{value:.1f}"


def _cmd_describe(args: argparse.Namespace) -> int:
    from manualcontrol.bench.report import plot_describing_function
    from manualcontrol.envs._files import atomic_write
    from manualcontrol.estimators.analysis.frequency import (
        SHARED_LINE,
        describing_function,
        fit_describing_function,
    )

    _check_output("--out", args.out, folder=True)
    out = Path(args.out)
    _check_result_folder(out, "a describing-function measurement (describe)", args.overwrite)
    recording = _load_trial(args)
    source = _trial_forcing(args, recording)
    element = _trial_element(recording, args, "describe")
    fixed = _assignments(args.fix, "--fix")
    from manualcontrol.estimators.analysis.frequency import FIT_BOUNDS

    for name, value in fixed.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise UsageError(f"--fix {name}= needs a number, got {value!r}")
        low, high = FIT_BOUNDS.get(name, (-math.inf, math.inf))
        if not low <= value <= high:
            raise UsageError(
                f"--fix {name}={value:g} lies outside the range a fit allows, [{low:g}, {high:g}]"
            )
    known_task = recording.metadata.get("task")
    if args.task is not None and known_task is not None and args.task != known_task:
        raise UsageError(
            f"--task {args.task} contradicts the recording, a {known_task} run: leave --task "
            "out to read it from the recording"
        )
    try:
        describing = describing_function(
            recording,
            source.get("forcing"),
            period=source.get("period"),
            element=element,
            disturbance_at=args.disturbance_at,
            task=args.task,
            method=args.method,
        )
    except ValueError as error:
        text = cli_words(str(error), "describe").replace("disturbance_at", "--disturbance-at")
        text = text.replace("method='least-squares'", "--method least-squares")
        if "shorter than one forcing period" in text:
            text += "; --method least-squares reads a shorter stretch"
        raise UsageError(text) from None
    from manualcontrol.envs.tasks import task_named
    from manualcontrol.pilots.models import MODEL_NAMES, make_model, model_for_element

    display = task_named(describing.task)
    model = args.model or model_for_element(display.pilot_model, element)
    # their parameters have fit bounds
    fitted = ("precision", "precision-lag", "preview", "gain-delay")
    if model not in fitted:
        known = "" if model in MODEL_NAMES else " (no such model)"
        raise UsageError(
            f"--model must be one of {', '.join(fitted)}, the models a describing function is "
            f"fitted with, got {model!r}{known}"
        )
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
    counts = {
        name: describing.source.count(name) for name in ("target", "disturbance", SHARED_LINE)
    }
    sets = ", ".join(
        f"{'target and disturbance' if name == SHARED_LINE else name} {count}"
        for name, count in counts.items()
        if count
    )
    start, end = describing.window
    plural = "s" if describing.periods > 1 else ""
    if not display.shows_error_only:
        print(
            f"{describing.task} display: the table holds the disturbance's lines (U/E there is "
            "the pilot's response to y); the model is fitted to every line's U from the "
            "target and y"
        )
    if describing.method == "least-squares":
        stretch = (
            f"over every sample, {end - start:.2f} s (the forcing repeats every "
            f"{describing.period:g} s), by least squares"
        )
    else:
        stretch = f"over {describing.periods} period{plural} of {describing.period:g} s"
    print(
        f"describing function at {describing.frequencies.size} forcing frequencies ({sets}) "
        f"{stretch} (t = {start:.2f} to {end:.2f} s); remnant: "
        f"{100 * describing.remnant_share:.0f} % of u's variance off the forcing frequencies"
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
        print(
            f"  {w:13.3f}  {g:10.2f}  {ph:11.1f}  {_power_ratio(snr):>6s}  "
            f"{_power_ratio(injected):>21s}  {kind}"
        )
    element_text = "given" if describing.element_given else "measured from y, u and fd"
    if math.isfinite(describing.crossover_frequency):
        crossover, margin = describing.crossover_frequency, describing.phase_margin
        crossover_spread, margin_spread = describing.crossover_uncertainty()
        spread = (
            " (no deviation stated: redone on the lines perturbed as the remnant may, most "
            "readings lose the crossing)"
        )
        if math.isfinite(crossover_spread):  # one standard deviation each way
            low, high = (
                crossover * math.exp(-crossover_spread),
                crossover * math.exp(crossover_spread),
            )
            spread = (
                f" (within one standard deviation of the remnant: {low:.2f}-{high:.2f} rad/s,"
                f" {margin - margin_spread:.0f} to {margin + margin_spread:.0f} deg)"
            )
        print(
            f"open loop (element {element_text}): crossover {crossover:.2f} rad/s, phase margin "
            f"{margin:.0f} deg{spread}"
        )
    else:
        print(
            f"open loop (element {element_text}): no crossover: {describing.no_crossover_reason()}"
        )

    def spread(name: str) -> str:
        if name not in fit.fitted:
            return " (held)"
        deviation = fit.standard_deviations[name]
        return " (on its bound)" if math.isnan(deviation) else f" +- {deviation:.2g}"

    values = ", ".join(f"{name} {fit.values[name]:.3g}{spread(name)}" for name in fit.values)
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
    flat = _flat_measured_element(describing)
    if flat is not None and args.model is None and display.pilot_model == "precision":
        warnings_found.append(
            f"no --element, and the element measured from the file is flat, as a pure gain's "
            f"is ({flat[0]:.1f} dB, phase within {flat[1]:.0f} deg of 0 at the forcing "
            "lines): give it (--element 1 for a unit gain) and the precision model with "
            "McRuer's lag, which humans adopt on a gain, is fitted"
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
    summary = {
        "describing_function": describing.to_dict(),
        "fit": fit.to_dict(),
        "warnings": warnings_found,
    }
    with _staged(out, stale=("bode.png",) if args.no_plot else ()) as stage:
        text = json.dumps(summary, indent=2)
        atomic_write(stage / "summary.json", lambda p: p.write_text(text))
        if not args.no_plot:
            plot_describing_function(
                describing,
                stage / "bode.png",
                models={f"fitted {fit.model}": fit.values},
                model=fit.model,
            )
    written = [out / "summary.json"] + ([] if args.no_plot else [out / "bode.png"])
    print(f"wrote {', '.join(map(str, written))}")
    for warning in warnings_found:
        print(f"manualcontrol describe: warning: {warning}", file=sys.stderr)
    return EXIT_OK


def _rounded(value: float) -> float | None:
    return round(float(value), 4) if math.isfinite(value) else None


def _flat_measured_element(describing: Any) -> tuple[float, float] | None:
    """A measured element as flat as a pure gain's, where no element was given.

    Returns its mean gain (dB) and largest phase gap to 0 (deg), else None. Flat: within
    1 dB of its mean gain and 10 deg of zero phase at every forcing line. The element is
    measured from ``y``, ``u`` and the disturbance, which the element relates exactly,
    so remnant does not blur it as it blurs the pilot's response.
    """
    if describing.element_given:
        return None
    measured = np.asarray(describing.element_measured)
    if measured.size < 3 or not np.all(np.isfinite(measured)):
        return None
    gain_db = 20.0 * np.log10(np.abs(measured))
    phase = np.degrees(np.abs(np.angle(measured)))
    mean_gain = float(np.mean(gain_db))
    if np.max(np.abs(gain_db - mean_gain)) > 1.0 or np.max(phase) > 10.0:
        return None
    return mean_gain, float(np.max(phase))


def _trial_element(recording: Any, args: argparse.Namespace, command: str) -> Any:
    """The controlled element: ``--element``, else the recording's own, else None.

    An ``--element`` whose response differs from the one the recording names (a
    simulated or played run states its element) is used, as asked, with a warning
    first: every result after it (an unstable loop, a poor fit) then reads as what
    it is, the element given against the one flown.
    """
    from manualcontrol.envs.elements import make_element, parse_element

    known = recording.metadata.get("controlled_element")
    if args.element is None:
        return make_element(known) if known is not None else None
    try:
        element = parse_element(args.element)
    except ValueError as error:
        raise UsageError(f"--element: {error}") from None
    if known is not None:
        try:
            flown = make_element(known)
        except (TypeError, ValueError, KeyError):
            return element  # an unreadable stored element: nothing to hold the flag against
        omega = np.geomspace(0.1, 20.0, 9)  # the band tracking forcings cover
        given, recorded = element.frequency_response(omega), flown.frequency_response(omega)
        if not np.allclose(given, recorded, rtol=1e-6, atol=0.0):
            print(
                f"manualcontrol {command}: warning: --element {args.element} "
                f"({element.describe()}) differs from the element the recording was flown "
                f"with ({flown.describe()}); the identification uses --element",
                file=sys.stderr,
            )
    return element


def _trial_forcing(args: argparse.Namespace, recording: Any = None) -> dict[str, Any]:
    """The forcing lines' source: ``--forcing`` (a preset or file) or ``--period``.

    A ``--period`` the recording's own forcing contradicts is refused, as is a
    ``--realisation`` without the ``--forcing`` it picks from.
    """
    if args.forcing is not None and args.period is not None:
        raise UsageError("give --forcing or --period, not both")
    if args.forcing is None and args.realisation != 0:
        raise UsageError(
            f"--realisation {args.realisation} picks a realisation of --forcing PRESET, and "
            "no --forcing is given"
        )
    known = None if recording is None else recording.metadata.get("forcing")
    if args.period is not None and known is not None:
        from manualcontrol.envs.signals import ForcingPair
        from manualcontrol.estimators.members.pilot_rules import forcing_period

        try:
            period = forcing_period(ForcingPair.from_dict(known))
        except (TypeError, ValueError):
            period = None
        if period is not None and abs(period - args.period) > 1e-6 * period:
            raise UsageError(
                f"--period {args.period:g} contradicts the recording's forcing, which repeats "
                f"every {period:g} s: leave --period out to use it"
            )
    if args.forcing is not None:
        return {"forcing": _forcing_of_flag(args)}
    if args.period is not None:
        return {"period": args.period}
    return {}


#: What a forcing file holds, for the messages about one.
_FORCING_FILE_FORM = (
    'JSON {"target": {"frequencies": [rad/s], "amplitudes": [...], "phases": [rad], '
    '"measurement_time": s}, "disturbance": {the same}} (either may be left out; a '
    'recording\'s metadata["forcing"] is one)'
)


def _forcing_of_flag(args: argparse.Namespace) -> Any:
    """``--forcing``: a preset (with ``--realisation``) or a forcing file (.json)."""
    from manualcontrol.envs.signals import forcing_preset

    if str(args.forcing).endswith(".json"):
        if args.realisation != 0:
            raise UsageError(
                f"--realisation {args.realisation} picks a preset's realisation; "
                f"--forcing {args.forcing} is a file, which holds one forcing"
            )
        return _forcing_file(Path(args.forcing))
    try:
        return forcing_preset(args.forcing, args.realisation)
    except ValueError as error:
        if str(error).startswith("realisation"):
            raise UsageError(f"--realisation: {error}") from None
        raise UsageError(
            f"--forcing: {error}; or a forcing file (.json) of the multisines the trial used"
        ) from None


def _forcing_file(path: Path) -> Any:
    """The forcing a lab's experiment used, from a JSON file (:data:`_FORCING_FILE_FORM`)."""
    import json

    from manualcontrol.envs.signals import ForcingPair

    if not path.is_file():
        raise UsageError(f"--forcing {path}: no such file; a forcing file is {_FORCING_FILE_FORM}")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise UsageError(f"--forcing {path}: not valid JSON ({error})") from None
    if not isinstance(data, dict):
        raise UsageError(f"--forcing {path}: a forcing file is {_FORCING_FILE_FORM}")
    data.setdefault("kind", "forcing_pair")
    data.setdefault("name", path.stem)
    for key in ("target", "disturbance"):
        if isinstance(data.get(key), dict):
            data[key] = {"kind": "multisine", **data[key]}
    try:
        return ForcingPair.from_dict(data)
    except (TypeError, ValueError, KeyError) as error:
        raise UsageError(
            f"--forcing {path}: {error}; a forcing file is {_FORCING_FILE_FORM}"
        ) from None


def _print_frequency_check(check: Any, period: float | None = None) -> None:
    frequency = check.frequency
    if frequency is None:
        note = cli_words(check.frequency_note, "identify")
        if period is not None and "forcing period" in note:
            note += f" (the period given by --period {period:g})"
        print(f"frequency domain: {note}")
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


def _suite(spec: str) -> Any:
    """The suite ``spec`` names: a built-in name or a suite file, said plainly when neither."""
    from manualcontrol.bench.scenarios import BUILTIN_SUITES, load_suite

    path = Path(spec)
    if spec not in BUILTIN_SUITES and (path.suffix == ".toml" or os.sep in spec):
        builtin = ", ".join(BUILTIN_SUITES)
        if path.is_dir():
            raise UsageError(
                f"{spec!r} is a directory, not a suite file (give a .toml file or a "
                f"built-in suite: {builtin})"
            )
        if not path.exists():
            raise UsageError(f"no such suite file {spec!r} (built-in suites: {builtin})")
    return load_suite(spec)


def _check_estimators_fit(suite: Any, names: Sequence[str]) -> None:
    """Refuse ``--estimators`` that cannot read a batch's runs, saying what each reads."""
    from manualcontrol.bench.batches import estimator_misfit

    for batch in suite.batches:
        for name in names:
            misfit = estimator_misfit(name, batch.name, batch.template.get("task"))
            if misfit is not None:
                raise UsageError(f"--estimators: {misfit}")


def _cmd_bench(args: argparse.Namespace) -> int:
    from manualcontrol.bench.report import write_report
    from manualcontrol.bench.runner import SuiteInterrupted, run_suite

    if args.backend == "ray":
        import importlib.util

        if importlib.util.find_spec("ray") is None:
            raise UsageError(
                "--backend ray needs Ray: pip install 'manualcontrol[dist]' (or use the "
                "default --backend process)"
            )
    suite = _suite(args.suite)
    if args.estimators is not None:
        from manualcontrol.estimators.registry import ESTIMATORS

        names = [name.strip() for name in args.estimators.split(",") if name.strip()]
        _check_estimators_fit(suite, [name for name in names if name in ESTIMATORS])
        suite = suite.with_estimators(names)
    out = Path(args.out or f"results/{suite.name}{'-quick' if args.quick else ''}")
    _check_output("--out", out, folder=True)
    held = _held_result(out)
    if held is not None and held != _BENCH_RESULT:
        raise UsageError(
            f"--out {out}: the folder holds {held} (its summary.json); a benchmark's results "
            "go in a folder of their own: give another --out folder"
        )
    total = len(suite.scenarios(args.quick))
    bar = _progress(total, f"{suite.name}", args.quiet)

    def progress(done: int, total: int, row: dict[str, Any]) -> None:
        if not row:  # the runs stored by an earlier, interrupted command
            bar.write(f"resuming: {done} of {total} runs already done (in {out})", file=sys.stdout)
        bar.update(done - bar.n)
        if row.get("status") == "failed":
            bar.write(f"failed: {row['key']}: {row['error']}")

    try:
        rows = run_suite(
            suite,
            out,
            backend=args.backend,
            workers=args.workers,
            quick=args.quick,
            progress=progress,
        )
    except SuiteInterrupted as stop:
        bar.close()
        print(
            f"manualcontrol bench: interrupted: {stop.done} of {stop.total} runs kept in "
            f"{stop.out}; run the same command again to resume",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    bar.close()
    failed = sum(row.get("status") != "ok" for row in rows)
    print(f"results: {out / 'results.csv'} ({len(rows)} runs, {failed} failed)")
    if not args.no_report:
        from manualcontrol.estimators.protocol import reporting_progress

        with reporting_progress(None if args.quiet else _progress_line):
            print(f"report:  {write_report(suite, rows, out)}")
    return EXIT_OK if not failed else EXIT_RUNS_FAILED


def _cmd_train(args: argparse.Namespace) -> int:
    import warnings

    from manualcontrol.agents.training import (
        TrainingConfig,
        WarmStartWarning,
        train,
        warm_start_warning,
    )

    _check_output("--out", args.out, folder=True)
    report = None if args.quiet else _training_report
    if args.recipe is not None:
        config = _recipe_config(args)
        _saved(train(config, args.out, report=report))
        return EXIT_OK
    if args.select_episodes is not None and args.select_every is None:
        raise UsageError(
            f"--select-episodes {args.select_episodes} needs --select-every N: without it "
            "nothing is validated"
        )
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
            select_every=args.select_every,
            select_episodes=20 if args.select_episodes is None else args.select_episodes,
            algorithm_kwargs=_assignments(args.algorithm_option, "--algorithm-option"),
            policy_kwargs={} if args.net_arch is None else {"net_arch": list(args.net_arch)},
            history_length=args.history,
            efference_copy=args.efference_copy,
            deterministic=args.deterministic_evaluation,
            warm_start=args.warm_start,
            critic_information=args.critic_information,
            **{name: _limitation(flag, text) for name, (flag, text) in fields.items()},
        )
    except ValueError as error:
        text = str(error)
        renamed = {
            **fields,
            "history_length": ("--history", None),
            "efference_copy=True": ("--efference-copy", None),
            "efference_copy": ("--efference-copy", None),
            "warm_start=": ("--warm-start ", None),
            "warm_start": ("--warm-start", None),
            "critic_information": ("--critic-information", None),
            "env_kwargs include_rates=True": ("--env include_rates=true", None),
            "algorithm must be": ("--algorithm must be", None),
        }
        for name, (flag, _) in renamed.items():
            text = text.replace(name, flag)
        raise UsageError(_led_by_flag(text, "train")) from None
    warning = warm_start_warning(config)
    if warning is not None:  # said before the minutes of training, in the flags' words
        for name, flag in (
            ("warm_start='typical-pilot'", "--warm-start typical-pilot"),
            ("history_length=", "--history "),
            (
                "give algorithm_kwargs learning_rate below",
                "give --algorithm-option learning_rate=R, R below",
            ),
        ):
            warning = warning.replace(name, flag)
        print(f"manualcontrol train: warning: {warning}", file=sys.stderr)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", WarmStartWarning)
        _saved(train(config, args.out, report=report))
    return EXIT_OK


def _saved(agent: Any) -> None:
    """The line naming what ``train`` wrote."""
    files = "config.json, policy.pt, model.zip"
    if agent.config.select_every is not None:
        files += ", selection.json, policy_final.pt"
    print(f"saved agent to {agent.path} ({files})")


_NO_EPISODE_YET = "mean reward per step n/a"


def _training_report(line: str) -> None:
    """A progress line of the training, the reward left out until an episode has ended."""
    if line.endswith(_NO_EPISODE_YET):
        line = line[: -len(_NO_EPISODE_YET)] + "(no episode has ended yet: no mean reward)"
    print(line, flush=True)


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
    "--efference-copy": ("efference_copy", False),
    "--deterministic-evaluation": ("deterministic_evaluation", False),
    "--warm-start": ("warm_start", "none"),
    "--critic-information": ("critic_information", False),
    "--algorithm": ("algorithm", "sac"),
    "--envs": ("envs", 1),
    "--algorithm-option": ("algorithm_option", None),
    "--net-arch": ("net_arch", None),
    "--select-every": ("select_every", None),
    "--select-episodes": ("select_episodes", None),
}


def _recipe_config(args: argparse.Namespace) -> Any:
    from manualcontrol.agents.recipes import RECIPES, recipe

    if args.recipe not in RECIPES:
        names = ", ".join(RECIPES)
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


def _progress_line(line: str) -> None:
    """How a long computation goes: a line to stderr, indented under the command's own."""
    print(f"  {line}", file=sys.stderr, flush=True)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from manualcontrol.agents.evaluation import evaluate, write_report
    from manualcontrol.agents.training import load_agent
    from manualcontrol.estimators.protocol import reporting_progress

    if args.out is not None:
        _check_output("--out", args.out, folder=True)
    agent = load_agent(args.agent, trust_pickle=args.trust_pickle)
    if agent.config.task == "lane-keeping":
        return _evaluate_lane_keeping(agent, args)
    with reporting_progress(_progress_line):
        evaluation = evaluate(
            agent, seed=args.seed, deterministic=args.deterministic, periods=args.periods
        )
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


def _evaluate_lane_keeping(agent: Any, args: argparse.Namespace) -> int:
    """A lane-keeping agent beside the cybernetic driver on the evaluation roads."""
    from manualcontrol.agents.evaluation import (
        LANE_KEEPING_ROADS,
        evaluate_lane_keeping,
        write_lane_keeping_report,
    )
    from manualcontrol.estimators.protocol import reporting_progress

    # --seed shifts the five roads
    roads = tuple(road + args.seed for road in LANE_KEEPING_ROADS)
    with reporting_progress(_progress_line):
        evaluation = evaluate_lane_keeping(agent, roads=roads, deterministic=args.deterministic)
        path = write_lane_keeping_report(evaluation, args.out or Path(args.agent) / "evaluation")
    for line in evaluation.lines():
        print(line)
    print(f"report: {path}")
    return EXIT_OK


def _cmd_play(args: argparse.Namespace) -> int:
    from manualcontrol.human.cli import run_play

    return run_play(args)  # prints its own errors and returns its exit code


def _cmd_experiment(args: argparse.Namespace) -> int:
    from manualcontrol.human.session_cli import run_session_command

    return run_session_command(args)  # prints its own errors and returns its exit code


#: Set while ``compile`` runs: a process forked then leaves Ctrl-C to this one.
_QUIET_CHILDREN = False


def _quiet_child() -> None:
    if _QUIET_CHILDREN:
        import signal

        # the pool's workers die with the command, silently, instead of each printing a
        # traceback of the job it was compiling
        signal.signal(signal.SIGINT, lambda *frame: os._exit(EXIT_INTERRUPTED))


def _cmd_compile(args: argparse.Namespace) -> int:
    from manualcontrol.bench.compile_kernels import compile_kernels

    global _QUIET_CHILDREN
    if hasattr(os, "register_at_fork") and not getattr(_cmd_compile, "hooked", False):
        os.register_at_fork(after_in_child=_quiet_child)
        _cmd_compile.hooked = True  # type: ignore[attr-defined]
    print(
        "compiling the numba kernels the C ports replace (the tests' reference):"
        if args.numba_reference
        else "compiling the kernels into the kernel cache, C ports built (once per machine):",
        flush=True,
    )
    _QUIET_CHILDREN = True
    try:
        ok = compile_kernels(
            args.workers, lambda line: print(line, flush=True), args.numba_reference
        )
    finally:
        _QUIET_CHILDREN = False
    if not ok:
        print(
            "manualcontrol compile: some jobs did not compile (above); their kernels "
            "compile at first use instead",
            file=sys.stderr,
        )
    return EXIT_OK if ok else EXIT_RUNS_FAILED


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


def _count(text: str) -> int:
    """A whole number >= 0 (a seed, an index), read as the play commands read one."""
    from manualcontrol.human._arguments import whole_number

    return whole_number(text)


def _nonnegative_float(text: str) -> float:
    """A finite number >= 0 (a duration that may be none)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text!r}") from None
    if not (value >= 0.0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
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
        help="forcing the trial was run with, a preset or a .json file of its multisines "
        "(frequencies in rad/s, amplitudes, phases, measurement_time): its frequencies (the "
        "describing function) and the target ahead a preview fit reads",
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


class _Parser(argparse.ArgumentParser):
    """An argument parser whose flags may be added when it parses (``fill``).

    ``play``'s flags live with the play command (:mod:`manualcontrol.human.cli`); they are
    added only when ``play`` is the command, so that the other commands and ``--help``
    import nothing of it.
    """

    def __init__(
        self, *args: Any, fill: Callable[[argparse.ArgumentParser], None] | None = None, **kw: Any
    ) -> None:
        super().__init__(*args, **kw)
        self._fill = fill

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        if self._fill is not None:
            fill, self._fill = self._fill, None
            fill(self)
        return super().parse_known_args(args, namespace)


def _play_arguments(parser: argparse.ArgumentParser) -> None:
    from manualcontrol.human.cli import add_play_arguments

    add_play_arguments(parser)


def _experiment_arguments(parser: argparse.ArgumentParser) -> None:
    from manualcontrol.human.session_cli import add_session_arguments

    add_session_arguments(parser)


_IDENTIFY_EXIT_CODES = (
    "Exit codes: 0 identified and written; 2 a usage or input error (the message says what "
    "to fix; nothing is written); 3 written, but the filter diverged (the traces after the "
    "time said are not estimates) or the identified pilot closes an unstable loop with the "
    "element (--allow-unstable accepts it); 130 interrupted with Ctrl-C (an earlier result "
    "in --out is left whole); 1 an internal error."
)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``manualcontrol`` command."""
    parser = argparse.ArgumentParser(
        prog="manualcontrol",
        description="Tracking tasks, cybernetic pilots and online estimators of manual control.",
        epilog="Exit codes: 0 ok, 2 usage or input error, 3 some benchmark runs failed (or an "
        "identification diverged or closes an unstable loop), 130 interrupted (Ctrl-C), "
        "1 internal error.",
    )
    commands = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=_Parser
    )

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
        help="pilot model: precision, precision-lag, preview, schiess-roland, gain-delay; its "
        "parameters default to typical values for the element (thesis SI and DI pilots, ...)",
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
        type=positive_int,
        default=None,
        help="Padé order of the pilot delay, 1 to 12 (default exact)",
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
    p.add_argument("--realisation", type=_count, default=0, help="forcing realisation index")
    p.add_argument(
        "--task", default=None, help="compensatory, pursuit or preview (default: the model's)"
    )
    p.add_argument(
        "--available-preview",
        type=_nonnegative_float,
        default=None,
        help="preview shown (s), preview tasks",
    )
    p.add_argument("--dt", type=_positive_float, default=0.01, help="sample time (s)")
    p.add_argument(
        "--run-in", type=_nonnegative_float, default=60.0, help="run-in simulated and cut (s)"
    )
    p.add_argument(
        "--measurement-time",
        type=_positive_float,
        default=None,
        help="measured time (s), default T_m",
    )
    p.add_argument("--seed", type=_count, default=0, help="remnant seed")
    p.add_argument("--loop", default="continuous", help="continuous or sampled")
    p.add_argument(
        "--allow-unstable",
        action="store_true",
        help="keep a run whose loop diverges (a warning, flagged in the recording's "
        "metadata) instead of refusing it",
    )
    p.add_argument("--out", required=True, type=Path, help="recording file (.npz, .csv or .mat)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing file at --out")
    p.add_argument("--plot", type=Path, default=None, help="also draw the run to this PNG")
    p.set_defaults(run=_cmd_simulate)

    p = commands.add_parser(
        "play",
        help="fly a task yourself with a mouse, keyboard or joystick; save the recording",
        description="Fly one run of a task with a mouse, keyboard or joystick, in real time, "
        "and save the recording.",
        epilog="Exit codes: 0 saved, 1 aborted (nothing saved), 2 bad flag or missing "
        "device, 130 Ctrl-C.",
        fill=_play_arguments,
    )
    p.set_defaults(run=_cmd_play)

    p = commands.add_parser(
        "experiment",
        help="run an experiment session with a person from a protocol file; resumable",
        description="Run (or resume) a participant's session of an experiment protocol: "
        "practice and measurement runs per condition in the declared order, each saved "
        "as it ends, then a report identifying the participant (docs/experiments.md).",
        epilog="Exit codes: 0 done, 1 aborted (finished runs kept; the same command "
        "resumes), 2 bad protocol, flag or folder, or no input device, 130 Ctrl-C.",
        fill=_experiment_arguments,
    )
    p.set_defaults(run=_cmd_experiment)

    p = commands.add_parser(
        "identify",
        help="estimate pilot parameters from a recording or experiment file",
        epilog=_IDENTIFY_EXIT_CODES,
    )
    p.add_argument(
        "recording",
        type=Path,
        help="a Recording or an experiment file (.npz, .csv, .mat; text as .tsv, .txt, .dat)",
    )
    p.add_argument(
        "--estimator",
        default=IDENTIFY_ESTIMATOR,
        help=f"estimator name (default {IDENTIFY_ESTIMATOR}, the family's choice for a lab's "
        "trial; `manualcontrol estimators` lists the family)",
    )
    p.add_argument(
        "--model",
        default=None,
        help="pilot model structure of the pilot-model estimators (dekf, rml, joint-ukf, "
        "dual-ukf and their -smoothed twins): precision (default), precision-lag "
        "(McRuer's lag equaliser, which humans adopt on a pure gain) or preview",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="estimator setting, e.g. ce=DI, anticipation_time=0.9, r2=4, "
        "estimated=K_p,K_v (a bare name or comma-separated names give a setting that "
        'is a list of parameter names; JSON works too: estimated=\'["K_p","K_v"]\'), '
        'initial=\'{"K_p": 1.2}\' (JSON: double quotes, no nan; infinity as "inf"); '
        "repeatable",
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
    p.add_argument(
        "--out",
        type=Path,
        default=Path("results/identify"),
        help="output folder: estimation.npz, summary.json and parameters.png replace the "
        "ones there once all are written (default results/identify)",
    )
    p.add_argument(
        "--no-plot",
        action="store_true",
        help="skip parameters.png (an earlier one in --out is removed, as it would not match): "
        "drawing it is most of a warm identify's time, worth saving over many recordings",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a result of another estimator (or of describe) in --out",
    )
    p.set_defaults(run=_cmd_identify)

    p = commands.add_parser(
        "describe",
        help="measure the pilot's describing function at the forcing frequencies of a "
        "compensatory trial: crossover, phase margin and a fitted pilot model",
    )
    p.add_argument(
        "recording",
        type=Path,
        help="a Recording or an experiment file (.npz, .csv, .mat; text as .tsv, .txt, .dat)",
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
        "--method",
        choices=("fourier", "least-squares"),
        default="fourier",
        help="fourier (default): Fourier coefficients over the last whole forcing periods; "
        "least-squares: sinusoids at the forcing lines fitted to every sample, for a trial "
        "shorter than a period or cut mid-period (needs --forcing)",
    )
    p.add_argument(
        "--model",
        default=None,
        help="pilot model fitted to the describing function: precision (default on a "
        "compensatory display), precision-lag (McRuer's lag equaliser; the default on a "
        "pure gain, where humans lag), preview (pursuit and preview), gain-delay",
    )
    p.add_argument(
        "--fix",
        action="append",
        metavar="NAME=VALUE",
        help="hold a model parameter at a value in the fit, e.g. K_v=0; repeatable",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("results/describe"),
        help="output folder: summary.json and bode.png replace the ones there once all are "
        "written (default results/describe)",
    )
    p.add_argument(
        "--no-plot",
        action="store_true",
        help="skip bode.png (an earlier one in --out is removed, as it would not match): "
        "drawing it is most of a describe's time, worth saving over many recordings",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an identify result in --out")
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
        help="a measured training recipe (gain, si, di, lag: compensatory tracking of K, 1/s, "
        "1/s^2, 1/(s(s+1)) with the typical pilot's delay and neuromuscular system, motor "
        "and observation noise and effort cost, PPO started from the typical pilot's "
        "equaliser; lane-angle, lane-torque: lane keeping on random roads with a driver's "
        "delay, steering the wheel's angle or its torque); takes --seed, --steps and "
        "--checkpoint-every, nothing else that sets the training",
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
        type=_positive_float,
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
        type=positive_int,
        default=1,
        metavar="N",
        help="observations the policy sees side by side (N dt seconds of memory: a policy "
        "that can adapt); default 1, the current one",
    )
    p.add_argument(
        "--efference-copy",
        action="store_true",
        help="the policy also reads its own last command (not the ones still in the delay): "
        "the memory it needs to integrate, as humans do on a pure gain (lag equalisation)",
    )
    p.add_argument(
        "--deterministic-evaluation",
        action="store_true",
        help="evaluate this agent without the wrappers' noise by default (by default the "
        "noise stays on and makes the trial-to-trial variability)",
    )
    p.add_argument(
        "--warm-start",
        default="none",
        choices=("none", "typical-pilot"),
        help="how the policy starts: none (the algorithm's random weights, default) or "
        "typical-pilot (PPO's mean fitted to the typical precision pilot's equaliser "
        "K_p e + K_v e_dot, lagged on a pure gain with --efference-copy; compensatory "
        "tracking with --env include_rates=true)",
    )
    p.add_argument(
        "--critic-information",
        action="store_true",
        help="PPO's critic also reads the loop's hidden state (the forcing ahead, the "
        "element's state, the delayed commands, the noise's state), the policy still only "
        "the display: advantages that are not mostly the forcing's future (tracking tasks)",
    )
    p.add_argument("--algorithm", default="sac", choices=("sac", "ppo"), help="RL algorithm")
    p.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        help="environment steps (default 100000, or the recipe's)",
    )
    p.add_argument("--envs", type=positive_int, default=1, help="parallel environments")
    p.add_argument(
        "--algorithm-option",
        action="append",
        metavar="KEY=VALUE",
        help="keyword for the stable-baselines3 algorithm, e.g. n_steps=512; repeatable",
    )
    p.add_argument(
        "--net-arch",
        type=positive_int,
        nargs="+",
        metavar="UNITS",
        default=None,
        help="hidden layer sizes of the policy (and value) networks, e.g. 64 64",
    )
    p.add_argument("--seed", type=_count, default=0, help="seed")
    p.add_argument(
        "--checkpoint-every", type=positive_int, default=None, help="save weights every N steps"
    )
    p.add_argument(
        "--select-every",
        type=positive_int,
        default=None,
        metavar="N",
        help="validate the policy every N steps and keep the best weights, not the last "
        "(policy.pt; the final ones go to policy_final.pt)",
    )
    p.add_argument(
        "--select-episodes",
        type=positive_int,
        default=None,
        metavar="N",
        help="episodes each validation of --select-every flies (default 20)",
    )
    p.add_argument("--out", type=Path, required=True, help="output folder for the agent")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(run=_cmd_train)

    p = commands.add_parser("evaluate", help="evaluate a trained agent like a human operator")
    p.add_argument("agent", type=Path, help="folder written by `manualcontrol train`")
    p.add_argument(
        "--out", type=Path, default=None, help="report folder (default AGENT/evaluation)"
    )
    p.add_argument(
        "--seed",
        type=_count,
        default=0,
        help="seed of the evaluation run (lane keeping: the roads are random roads "
        "1000 + SEED to 1004 + SEED, each beside the cybernetic driver)",
    )
    p.add_argument(
        "--deterministic",
        action="store_const",
        const=True,
        default=None,
        help="run without the wrappers' observation and motor noise (default: as the agent "
        "was configured, noise on); a noise-free run has no remnant, which no human shows",
    )
    p.add_argument(
        "--periods",
        type=positive_int,
        default=1,
        help="forcing periods to fly and measure over (default 1); the describing function "
        "reads them together, as a laboratory averages a participant's repeated runs "
        "(tracking only)",
    )
    p.add_argument(
        "--trust-pickle",
        action="store_true",
        help="load model.zip (pickle: runs code from the file; only for files you trust)",
    )
    p.set_defaults(run=_cmd_evaluate)

    p = commands.add_parser(
        "compile",
        help="compile the kernels into numba's cache and build the C ports now (make does "
        "it at install)",
        description="Build the C ports of the estimators and the LPV toolkit (where a C "
        "compiler is at hand; they run instead of numba's kernels) and compile the other "
        "kernels into numba's on-disk cache, split across the cores, so that the first "
        "identify, bench or test loads them instead of compiling. The Makefile's install "
        "step runs this.",
        epilog="Exit codes: 0 all compiled; 3 some jobs failed (their kernels compile at "
        "first use instead); 130 Ctrl-C.",
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="processes compiling side by side (default: all cores)",
    )
    p.add_argument(
        "--numba-reference",
        action="store_true",
        help="compile only the numba kernels the C ports replace, which run where a C "
        "port does not build and are the reference the tests compare the ports with "
        "(make test runs this before pytest)",
    )
    p.set_defaults(run=_cmd_compile)
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
    except KeyboardInterrupt:
        print(f"manualcontrol {args.command}: {_interrupted(args)}", file=sys.stderr)
        return EXIT_INTERRUPTED
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
        if not isinstance(error, UsageError):  # the library's words, not yet the flags'
            message = _led_by_flag(cli_words(str(message), args.command), args.command)
        print(f"manualcontrol {args.command}: error: {message}", file=sys.stderr)
        return EXIT_USAGE


def _interrupted(args: argparse.Namespace) -> str:
    """The one line Ctrl-C leaves: what was kept."""
    command = args.command
    if command in ("identify", "describe"):
        kept = (
            f" (the earlier result in {args.out} is left as it was)"
            if (Path(args.out) / "summary.json").is_file()
            else ""
        )
        return f"interrupted (Ctrl-C); nothing was written{kept}"
    if command == "simulate":
        return f"interrupted (Ctrl-C); {args.out} was not written"
    if command == "train":
        checkpoints = Path(args.out) / "checkpoints"
        kept = (
            f"; the checkpoints so far are in {checkpoints}"
            if checkpoints.is_dir() and any(checkpoints.iterdir())
            else ""
        )
        return f"interrupted (Ctrl-C); the agent was not saved{kept}"
    if command == "compile":
        return "interrupted (Ctrl-C); the kernels compiled so far stay in numba's cache"
    if command == "play":
        return "interrupted (Ctrl-C); nothing was saved"
    if command == "experiment":
        return "interrupted (Ctrl-C); the finished runs are kept: the same command resumes"
    return "interrupted (Ctrl-C)"


def main_exit() -> None:
    """Console-script entry point: run and exit with the command's code."""
    sys.exit(main())


if __name__ == "__main__":  # pragma: no cover
    main_exit()
