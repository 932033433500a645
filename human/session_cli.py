"""``manualcontrol experiment``: one participant's session of a protocol, resumable.

::

    manualcontrol experiment protocol.toml --participant P01 --out results/experiments
    python -m manualcontrol.human.session_cli protocol.toml --participant P01   # the same

It reads and checks the protocol (:func:`~manualcontrol.human.protocol.load_protocol`),
runs the session (:func:`~manualcontrol.human.session.run_session`: every run saved as
it ends, ``session.json`` updated after each), prints each run's RMS error and timing,
and at the end writes the participant's report
(:func:`~manualcontrol.human.report.write_session_report`). Run the same command again
after an interruption to continue at the run that was not finished. See
docs/experiments.md.

Exit codes: 0 the session is complete (or, with ``--plan``, the plan printed; with
``--report-only``, the report written); 1 aborted (window closed, Escape, device lost):
one line says what was kept and how to resume; 2 a bad protocol, flag or folder, or a
missing device; 130 Ctrl-C (one line, no traceback).

:func:`add_session_arguments` and :func:`run_session_command` let the ``manualcontrol``
command register ``experiment``; :func:`main` runs it on its own.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from manualcontrol.human._arguments import parse_dead_zone, parse_range, whole_number
from manualcontrol.human.devices import InputDeviceError, NoInputDevice, joystick_count

__all__ = ["add_session_arguments", "main", "run_session_command"]

EXIT_OK, EXIT_ABORTED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
_PROGRAM = "manualcontrol experiment"
_INPUTS = ("mouse", "keyboard", "joystick")


def add_session_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``experiment`` command's arguments, added to ``parser``."""
    parser.add_argument("protocol", type=Path, help="the experiment's protocol file (.toml)")
    parser.add_argument(
        "--participant",
        default=None,
        help="participant id: letters, digits, '-', '_' (default: the protocol's "
        "participant); their runs go to OUT/ID/",
    )
    parser.add_argument(
        "--participant-number",
        type=whole_number,
        default=None,
        help="row of the counterbalanced order (default: the last digits of the id, P07 -> 7)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("results") / "experiments",
        help="folder of the sessions (default results/experiments)",
    )
    parser.add_argument(
        "--input",
        choices=_INPUTS,
        default=None,
        help="the stick, instead of the protocol's [input] device",
    )
    parser.add_argument(
        "--joystick-axis", type=whole_number, default=None, help="joystick axis to read (default 0)"
    )
    parser.add_argument(
        "--dead-zone",
        type=parse_dead_zone,
        default=None,
        help="share of full deflection read as zero (default: the protocol's, else the "
        "device's: 0.05 joystick, 0 mouse and keyboard)",
    )
    parser.add_argument(
        "--range",
        type=parse_range,
        default=None,
        help="raw reading for full deflection: mouse pixels from the centre, joystick axis "
        "value (default: the protocol's, else the device's)",
    )
    parser.add_argument(
        "--plan", action="store_true", help="print the participant's runs in order and stop"
    )
    parser.add_argument(
        "--no-report", action="store_true", help="do not write the report at the end"
    )
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="write the report of the session in OUT/ID and stop (no runs flown)",
    )


class _UsageError(Exception):
    """A bad protocol, flag or folder: one message, exit code 2."""


def _resume_hint(args: argparse.Namespace, participant: str | None) -> str:
    """The command that resumes this session."""
    words = [*_PROGRAM.split(), str(args.protocol)]
    if participant is not None:
        words += ["--participant", participant]
    words += ["--out", str(args.out)]
    if args.participant_number is not None:
        words += ["--participant-number", str(args.participant_number)]
    for flag, value in (
        ("--input", args.input),
        ("--joystick-axis", args.joystick_axis),
        ("--dead-zone", args.dead_zone),
        ("--range", args.range),
    ):
        if value is not None:
            words += [flag, f"{value:g}" if isinstance(value, float) else str(value)]
    return " ".join(shlex.quote(word) for word in words)


_INPUT_FLAGS = (
    ("input.dead_zone", "--dead-zone"),
    ("input.range", "--range"),
    ("input.joystick_axis", "--joystick-axis"),
    ("input.device", "--input"),
)


def _flag_message(message: str, source: str) -> str:
    """A complaint about the protocol's ``[input]`` made by the flags, said with them."""
    prefix = f"{source}: input: "
    if message.startswith(prefix):
        message = message[len(prefix) :]
    if message.startswith("input: "):
        message = message[len("input: ") :]
    for key, flag in _INPUT_FLAGS:
        message = message.replace(key, flag)
    return message


def run_session_command(
    args: argparse.Namespace,
    *,
    device_factory: Callable[[Any], Any] | None = None,
    clock: Any = None,
    show: Any = None,
) -> int:
    """Run (or resume) the session of parsed ``experiment`` arguments; the exit code.

    ``device_factory``, ``clock`` and ``show`` are for tests and programs that drive the
    command (a scripted stick, a manual clock, scripted keys); the command line always
    uses the protocol's device (or ``--input``), the real clock and the keyboard.
    """
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    state: dict[str, Any] = {"kept": [], "run": None, "folder": None, "total": None}
    try:
        return _command(args, device_factory, clock, show, state)
    except _UsageError as error:
        print(f"{_PROGRAM}: error: {error}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        from manualcontrol.human.session import kept_phrase  # as in _session, not for --help

        run = state["run"]
        during = f" during {run.label(state['total'])}" if run is not None else ""
        if state["folder"] is None:
            print(f"{_PROGRAM}: interrupted (Ctrl-C); no run was flown", file=sys.stderr)
        else:
            print(
                f"{_PROGRAM}: interrupted (Ctrl-C){during}; "
                f"{kept_phrase(state['kept'], state['folder'])}; to resume, run again: "
                f"{_resume_hint(args, state['participant'])}",
                file=sys.stderr,
            )
        return EXIT_INTERRUPTED


def _command(
    args: argparse.Namespace,
    device_factory: Any,
    clock: Any,
    show: Any,
    state: dict[str, Any],
) -> int:
    # the protocol, the session and the report load the environments' kernels (numba,
    # scipy): imported when the command runs, so that ``--help`` stays light
    from manualcontrol.human.protocol import ProtocolError, check_participant, load_protocol

    if args.plan and args.report_only:
        raise _UsageError(
            "--plan prints the runs to come and --report-only writes the report of those "
            "done: give one of them"
        )
    if args.out is not None and Path(args.out).exists() and not Path(args.out).is_dir():
        raise _UsageError(f"--out {args.out}: a file, not a folder; give a folder for the session")
    try:
        protocol = load_protocol(args.protocol)
    except ProtocolError as error:
        raise _UsageError(str(error)) from None
    overrides = {
        "device": args.input,
        "range": args.range,
        "dead_zone": args.dead_zone,
        "joystick_axis": args.joystick_axis,
    }
    if any(value is not None for value in overrides.values()):
        try:
            protocol = protocol.with_input(**overrides)
        except ProtocolError as error:
            raise _UsageError(_flag_message(str(error), protocol.source)) from None
    participant = args.participant if args.participant is not None else protocol.participant
    state["participant"] = participant
    if participant is None:
        raise _UsageError(
            "no participant: give --participant ID (or participant = ... in the protocol)"
        )
    try:
        check_participant(participant, "--participant")
        plan = protocol.runs(participant, args.participant_number)
    except ValueError as error:
        raise _UsageError(str(error)) from None
    if args.plan:
        _print_plan(protocol, participant, args, plan)
        return EXIT_OK
    if args.report_only:
        return _report(args, participant, required=True)
    if device_factory is None and protocol.input.device == "joystick":
        if joystick_count() == 0:  # before a window opens for nothing
            raise _UsageError(
                "no joystick or gamepad found (pygame sees 0); plug one in or use "
                "--input mouse/keyboard"
            )
    return _session(args, protocol, participant, device_factory, clock, show, state)


def _print_plan(protocol: Any, participant: str, args: argparse.Namespace, plan: list) -> None:
    order, why = protocol.condition_order(participant, args.participant_number)
    print(
        f"{protocol.name} for {participant}: {len(plan)} runs; conditions "
        f"{', '.join(order)} ({why})"
    )
    for run in plan:
        realisation = "" if run.realisation is None else f", realisation {run.realisation}"
        print(
            f"{run.number:3d}  {run.file_name}  ({run.condition} {run.kind} {run.index} of "
            f"{run.count}{realisation})"
        )


def _session(
    args: argparse.Namespace,
    protocol: Any,
    participant: str,
    device_factory: Any,
    clock: Any,
    show: Any,
    state: dict[str, Any],
) -> int:
    from manualcontrol.human.session import (
        SessionAborted,
        SessionError,
        SessionEvent,
        kept_phrase,
        run_session,
    )

    def on_event(event: SessionEvent) -> None:
        if event.kind == "session":
            state["folder"] = Path(event.data["folder"])
            state["total"] = event.data["total"]
        elif event.kind == "resume":
            state["kept"] = list(event.data["kept"])
        elif event.kind == "start":
            state["run"] = event.run
        elif event.kind == "finished":
            state["kept"].append(event.run.number)
            state["run"] = None
        if event.kind in ("warning", "redo"):
            print(f"{_PROGRAM}: warning: {event.message}", file=sys.stderr)
        elif event.kind not in ("start", "interrupted"):
            print(event.message)

    try:
        result = run_session(
            protocol,
            participant,
            args.out,
            device_factory=device_factory,
            clock=clock,
            show=show,
            on_event=on_event,
            participant_number=args.participant_number,
        )
    except SessionError as error:
        raise _UsageError(str(error)) from None
    except SessionAborted as error:
        resume = (
            f"to resume at run {error.run.number}, run again: "
            if error.run is not None
            else "to resume, run again: "
        )
        print(f"{_PROGRAM}: {error}; {resume}{_resume_hint(args, participant)}", file=sys.stderr)
        return EXIT_ABORTED
    except NoInputDevice as error:
        print(f"{_PROGRAM}: error: {error}", file=sys.stderr)
        return EXIT_USAGE
    except InputDeviceError as error:
        folder = state["folder"] or Path(args.out) / participant
        print(
            f"{_PROGRAM}: {error}; {kept_phrase(state['kept'], folder)}; to resume, run again: "
            f"{_resume_hint(args, participant)}",
            file=sys.stderr,
        )
        return EXIT_ABORTED
    if not args.no_report:
        _report(args, participant, required=False)
    del result
    return EXIT_OK


def _report(args: argparse.Namespace, participant: str, *, required: bool) -> int:
    """Write the report; a failure after a finished session is a warning, not an error."""
    from manualcontrol.human.report import write_session_report
    from manualcontrol.human.session import SessionError

    try:
        report = write_session_report(args.out, participant)
    except SessionError as error:
        raise _UsageError(str(error)) from None
    except (ImportError, OSError, ValueError) as error:
        if required:
            raise _UsageError(f"the report could not be written: {error}") from None
        print(
            f"{_PROGRAM}: warning: the report could not be written ({error}); the runs are "
            f"saved; write it later with --report-only",
            file=sys.stderr,
        )
        return EXIT_OK
    print(f"wrote {report.markdown}")
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m manualcontrol.human.session_cli PROTOCOL [flags]``: the exit code."""
    parser = argparse.ArgumentParser(
        prog=_PROGRAM,
        description="Run one participant's session of an experiment protocol, in real time: "
        "every run saved as it ends, resumable, then a report.",
        epilog="Exit codes: 0 done, 1 aborted (finished runs kept; run again to resume), "
        "2 bad protocol, flag or folder, or missing device, 130 Ctrl-C.",
    )
    add_session_arguments(parser)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # argparse has printed its message (or the help)
        return exit_.code if isinstance(exit_.code, int) else EXIT_USAGE
    return run_session_command(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
