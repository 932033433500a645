"""``manualcontrol play``: a person flies one run of a task and it is saved.

::

    manualcontrol play --task compensatory --element SI --input mouse
    python -m manualcontrol.human.cli --task pursuit --input joystick --dead-zone 0.08

It opens the task's window, shows "press space to start", flies the run in real time
(:func:`~manualcontrol.human.realtime.fly`), saves the recording (atomically; an
existing file is refused unless ``--overwrite``) and prints the RMS error, the timing
summary and the file. See docs/play.md.

Exit codes: 0 saved; 1 the run was aborted (window closed, Escape, device lost):
nothing is saved; 2 a bad flag or a missing device (the message names the flag, the
value and what is allowed); 130 interrupted with Ctrl-C.

:func:`add_play_arguments` and :func:`run_play` let the ``manualcontrol`` command
register ``play``; :func:`main` runs it on its own.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import manualcontrol.envs  # noqa: F401 - registers the environments
from manualcontrol.human._arguments import number, parse_dead_zone, parse_range, whole_number
from manualcontrol.human.devices import (
    InputDeviceError,
    JoystickInput,
    MouseInput,
    NoInputDevice,
    draw_stick_gauge,
    joystick_count,
    load_pygame,
    make_device,
)
from manualcontrol.human.tasks import HOW_TO_MOVE, TASK_GOALS, TASKS

__all__ = ["EXIT_ABORTED", "add_play_arguments", "main", "run_play"]

EXIT_OK, EXIT_ABORTED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130

_INPUTS = ("mouse", "keyboard", "joystick")
_FORMATS = (".npz", ".csv", ".mat")


class _UsageError(Exception):
    """A bad flag or value: one line naming it, exit code 2."""


# ---------------------------------------------------------------- arguments


def add_play_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``play`` command's flags, added to ``parser``."""
    parser.add_argument(
        "--task",
        choices=tuple(TASKS),
        default="compensatory",
        help="the task to fly (default compensatory)",
    )
    parser.add_argument(
        "--element",
        default=None,
        help="controlled element of a tracking task: a preset (SI, DI, gain, popovici2017, "
        "critical-task, ...) or a transfer function in s such as 1/s, 2.5/s^2, "
        "'1/(s(s+1))' (default: the task's, SI; gain for postview)",
    )
    parser.add_argument(
        "--forcing",
        default=None,
        help="forcing preset of a tracking task (default: the task's, vanderel-bw4; "
        "boer-kenyon1998-postview for postview)",
    )
    parser.add_argument(
        "--realisation",
        type=whole_number,
        default=None,
        help="realisation of the forcing (default 0)",
    )
    parser.add_argument(
        "--measurement-time",
        type=number("--measurement-time", "a number of seconds > 0", lambda v: v > 0.0),
        default=90.0,
        help="length of the run (s, default 90)",
    )
    parser.add_argument(
        "--input",
        choices=_INPUTS,
        default="mouse",
        help="the stick: mouse (horizontal position), keyboard (left/right arrows) or "
        "joystick (default mouse)",
    )
    parser.add_argument(
        "--joystick-axis",
        type=whole_number,
        default=0,
        help="joystick axis to read (default 0, usually the left stick's horizontal axis)",
    )
    parser.add_argument(
        "--dead-zone",
        type=parse_dead_zone,
        default=None,
        help="share of full deflection around the centre read as zero (default 0.05 for a "
        "joystick, 0 for mouse and keyboard)",
    )
    parser.add_argument(
        "--range",
        type=parse_range,
        default=None,
        help="raw reading for full deflection: pixels from the window's centre for the "
        "mouse (default 240, 40 %% of the width), the axis value for a joystick (default 1)",
    )
    parser.add_argument(
        "--scale",
        type=number("--scale", "a number > 0", lambda v: v > 0.0),
        default=None,
        help="the task's action at full deflection (default: sized to the forcing and "
        "the element, see docs/play.md)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="recording file, .npz, .csv or .mat (default results/play/TASK-DATE-TIME.npz)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    parser.add_argument("--seed", type=int, default=None, help="seed of the environment's reset")


# ---------------------------------------------------------------- the command


def _checked_options(args: argparse.Namespace) -> dict[str, Any]:
    """Environment keywords from the flags, each checked against its flag's name."""
    task = args.task
    if task not in TASKS:
        raise _UsageError(f"--task {task!r}: choose from {', '.join(TASKS)}")
    if args.input not in _INPUTS:
        raise _UsageError(f"--input {args.input!r}: choose from {', '.join(_INPUTS)}")
    if not (math.isfinite(args.measurement_time) and args.measurement_time > 0.0):
        raise _UsageError(f"--measurement-time must be > 0 s, got {args.measurement_time!r}")
    if args.dead_zone is not None and not 0.0 <= args.dead_zone < 1.0:
        raise _UsageError(f"--dead-zone must be a number in [0, 1), got {args.dead_zone!r}")
    if args.range is not None and args.input == "keyboard":
        raise _UsageError("--range applies to --input mouse or joystick, not keyboard")
    options: dict[str, Any] = {"measurement_time": float(args.measurement_time)}
    if task == "lane-keeping":
        for flag, value in (
            ("--element", args.element),
            ("--forcing", args.forcing),
            ("--realisation", args.realisation),
        ):
            if value is not None:
                raise _UsageError(f"{flag} applies to the tracking tasks, not lane-keeping")
        return options
    # loaded when the command runs: they load numba, which ``play --help`` does not need
    from manualcontrol.envs.elements import make_element
    from manualcontrol.envs.tasks import resolve_forcing

    if args.element is not None:
        try:
            options["controlled_element"] = make_element(args.element)
        except (ValueError, TypeError) as error:
            raise _UsageError(f"--element {args.element!r}: {error}") from None
    if args.forcing is not None:
        try:
            resolve_forcing(args.forcing)
        except (ValueError, TypeError, KeyError) as error:
            message = error.args[0] if isinstance(error, KeyError) and error.args else error
            raise _UsageError(f"--forcing {args.forcing!r}: {message}") from None
        options["forcing"] = args.forcing
    options["realisation"] = 0 if args.realisation is None else args.realisation
    return options


def _output_path(args: argparse.Namespace) -> Path:
    """``--out``, checked, or a new timestamped file under results/play/."""
    if args.out is None:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        path = Path("results") / "play" / f"{args.task}-{stamp}.npz"
        number = 2
        while path.exists():
            path = path.with_name(f"{args.task}-{stamp}-{number}.npz")
            number += 1
        return path
    path = Path(args.out)
    if path.suffix.lower() not in _FORMATS:
        raise _UsageError(
            f"--out {str(path)!r}: the name must end in {', '.join(_FORMATS)} (the file format)"
        )
    if path.is_dir():
        raise _UsageError(f"--out {str(path)!r}: is a folder; give a file name")
    if path.exists() and not args.overwrite:
        raise _UsageError(f"--out {str(path)!r}: the file exists; pass --overwrite to replace it")
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise _UsageError(f"--out {str(path)!r}: {parent} is a file, not a folder")
            # found now, not after the run: a person's run cannot be flown again as it was
            if not os.access(parent, os.W_OK | os.X_OK):
                raise _UsageError(f"--out {str(path)!r}: cannot write in {parent}")
            break
    return path


def _save_new(recording: Any, path: Path, overwrite: bool) -> Path:
    """Write ``recording`` to ``path`` atomically; never over a file that appeared meanwhile.

    The recording is written complete beside ``path`` first; then it is linked to
    ``path``, which fails if a file of that name exists (unless ``overwrite``, when it
    is renamed over it), so a half-written or replaced file is never left behind.
    """
    if overwrite:
        return recording.save(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(handle)
    temporary = Path(name)
    try:
        recording.save(temporary, format=path.suffix.lower().lstrip("."))
        try:
            os.link(temporary, path)
        except FileExistsError:
            raise _UsageError(
                f"--out {str(path)!r}: a file of that name appeared during the run; "
                "nothing was written over it"
            ) from None
        except OSError:  # a file system without hard links
            if path.exists():
                raise _UsageError(
                    f"--out {str(path)!r}: a file of that name appeared during the run"
                ) from None
            os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
    return path


def _start_screen(env: Any, device: Any, task: str, input_name: str) -> None:
    """Show what to do over the first frame; return when space is pressed.

    The device sees the events meanwhile, so the mouse or stick can be centred; a
    gauge at the bottom shows the stick (mouse and joystick; the keyboard's stick
    moves only while flying).
    """
    from manualcontrol.human.realtime import RunAborted  # the run's (scipy), as in _play

    pygame = load_pygame()
    surface = pygame.display.get_surface()
    if surface is None:
        return
    pygame.font.init()
    font = pygame.font.Font(None, 30)
    background = surface.copy()
    width = surface.get_width()
    lines = [
        f"{task}: {TASK_GOALS.get(task, 'track the target')}",
        f"{HOW_TO_MOVE.get(input_name, 'move the stick')}",
        "press space to start, Esc to quit",
    ]
    gauge = isinstance(device, (MouseInput, JoystickInput))
    ticker = pygame.time.Clock()
    while True:
        for event in pygame.event.get():
            if event.type == pygame.QUIT:
                raise RunAborted("the window was closed before the start")
            if event.type == pygame.KEYDOWN:
                if event.key == pygame.K_ESCAPE:
                    raise RunAborted("Escape was pressed before the start")
                if event.key == pygame.K_SPACE:
                    surface.blit(background, (0, 0))
                    pygame.display.flip()
                    return
            device.handle_event(event)
        surface.blit(background, (0, 0))
        panel = pygame.Surface((width, 110), pygame.SRCALPHA)
        panel.fill((0, 0, 0, 190))
        surface.blit(panel, (0, 20))
        for i, line in enumerate(lines):
            text = font.render(line, True, (235, 235, 235))
            surface.blit(text, ((width - text.get_width()) // 2, 32 + 32 * i))
        if gauge:
            draw_stick_gauge(surface, device.read())
        pygame.display.flip()
        ticker.tick(30)


def _rms(values: Any) -> float:
    values = np.asarray(values, dtype=np.float64)
    return float(np.sqrt(np.mean(values * values)))


def _report(flight: Any, base: Any, args: argparse.Namespace) -> None:
    """What was flown, how well, and how well the schedule was kept."""
    recording = flight.recording
    flown = len(recording) * recording.dt
    if args.task == "lane-keeping":
        what = f"{base.steering} steering"
        score = f"RMS lateral offset {_rms(recording['y_L']):.3g} m"
    else:
        forcing = base.forcing
        what = f"{base.element.describe()}, {forcing.name} realisation {forcing.realisation}"
        signal = forcing.target if forcing.target is not None else forcing.disturbance
        std = math.sqrt(float(signal.variance)) if signal is not None else float("nan")
        score = f"RMS error {_rms(recording.e):.3g} (forcing std {std:.3g})"
    print(f"flew {args.task} ({what}) for {flown:.4g} s with the {args.input}")
    if flight.ended == "terminated":
        print(f"control was lost at t = {float(recording.t[-1]):.2f} s: the recording ends there")
    print(score)
    print(f"timing: {flight.timing.summary()}")


def run_play(
    args: argparse.Namespace,
    *,
    device: Any = None,
    clock: Any = None,
    wait_for_start: bool | None = None,
) -> int:
    """Fly and save one run from parsed ``play`` flags; return the exit code.

    ``device``, ``clock`` and ``wait_for_start`` are for tests and for programs that
    drive the command (a scripted stick, a manual clock, no start screen); the
    command line always uses the device of ``--input``, the real clock and the start
    screen.
    """
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        return _play(
            args, device, clock, device is None if wait_for_start is None else wait_for_start
        )
    except _UsageError as error:
        print(f"manualcontrol play: error: {error}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("manualcontrol play: interrupted (Ctrl-C); nothing was saved", file=sys.stderr)
        return EXIT_INTERRUPTED


def _play(args: argparse.Namespace, device: Any, clock: Any, wait_for_start: bool) -> int:
    # the real-time loop loads scipy (recordings): imported when a run is flown, not for
    # ``play --help``, and looked up then (tests wrap ``realtime.fly``)
    from manualcontrol.human.realtime import RunAborted, fly

    options = _checked_options(args)
    path = _output_path(args)
    if device is None:
        try:
            device = make_device(
                args.input,
                dead_zone=args.dead_zone,
                range=args.range,
                joystick_axis=args.joystick_axis,
            )
        except ValueError as error:
            raise _UsageError(str(error)) from None
        if args.input == "joystick":
            if joystick_count() == 0:  # before a window opens for nothing
                print(
                    "manualcontrol play: error: no joystick or gamepad found (pygame sees 0); "
                    "plug one in or use --input mouse/keyboard",
                    file=sys.stderr,
                )
                return EXIT_USAGE
    try:
        env = gym.make(TASKS[args.task], render_mode="human", disable_env_checker=True, **options)
    except (ValueError, TypeError) as error:
        raise _UsageError(_flag_message(str(error))) from None
    try:
        ready = None
        if wait_for_start:

            def ready(wrapped: Any) -> None:
                _start_screen(wrapped, device, args.task, args.input)

        try:
            flight = fly(env, device, clock=clock, seed=args.seed, scale=args.scale, on_ready=ready)
        except RunAborted as error:
            flown = f" after {error.elapsed:.1f} s" if error.steps else ""
            print(f"manualcontrol play: {error.reason}{flown}; nothing was saved", file=sys.stderr)
            return EXIT_ABORTED
        except NoInputDevice as error:
            print(f"manualcontrol play: error: {error}", file=sys.stderr)
            return EXIT_USAGE
        except InputDeviceError as error:
            print(f"manualcontrol play: {error}; nothing was saved", file=sys.stderr)
            return EXIT_ABORTED
    finally:
        with contextlib.suppress(Exception):
            env.close()
    _report(flight, env.unwrapped, args)
    if flight.warning is not None:
        print(f"manualcontrol play: warning: {flight.warning}", file=sys.stderr)
    written = _save_new(flight.recording, path, args.overwrite)
    print(f"wrote {written}")
    return EXIT_OK


_KEYWORD_FLAGS = {
    "measurement_time": "--measurement-time",
    "realisation": "--realisation",
    "controlled_element": "--element",
    "forcing": "--forcing",
}


def _flag_message(message: str) -> str:
    """An environment's complaint about a keyword, said with the flag's name."""
    for keyword, flag in _KEYWORD_FLAGS.items():
        if message.startswith(keyword):
            return flag + message[len(keyword) :]
    return message


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m manualcontrol.human.cli [flags]``: parse, fly, return the exit code."""
    parser = argparse.ArgumentParser(
        prog="manualcontrol play",
        description="Fly one run of a task with a mouse, keyboard or joystick, in real time, "
        "and save the recording.",
        epilog="Exit codes: 0 saved, 1 aborted (nothing saved), 2 bad flag or missing "
        "device, 130 Ctrl-C.",
    )
    add_play_arguments(parser)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # argparse has printed its message (or the help)
        return exit_.code if isinstance(exit_.code, int) else EXIT_USAGE
    return run_play(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
