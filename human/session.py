"""Running an experiment session: every planned run flown, saved as it ends, resumable.

:func:`run_session` takes a :class:`~manualcontrol.human.protocol.Protocol` and a
participant and flies the plan (:meth:`~manualcontrol.human.protocol.Protocol.runs`)
in order. Before each run it shows what the protocol says (a break, the condition's
instructions, the run's own line over the task's first frame, waiting for space), flies
the run in real time with :func:`~manualcontrol.human.realtime.fly`, saves its
recording and updates the session's manifest.

What is saved, in ``<out>/<participant>/``:

``NN-<condition>-<kind>-<i>.npz``
    One recording per finished run (``NN`` its place in the session), written
    atomically (complete or absent). Its metadata hold the env's description, the
    device's calibration, the action scale and the timing (as ``manualcontrol play``
    writes them) and ``"session"``: protocol, digest, participant and the run's place.
``session.json``
    The manifest, rewritten atomically after every run: the protocol (every setting,
    :meth:`~manualcontrol.human.protocol.Protocol.to_dict`, its digest and the file's
    text), the participant and their number, the condition order and why, the plan,
    each finished run (file, RMS error, timing summary and warning, device calibration,
    action scale, when), the practice slots skipped, every interruption, each sitting's
    software versions and the status (``"in progress"``, ``"complete"``).

Resuming
--------
Running again with the same protocol, participant and folder continues where the
session stopped: a run counts as done when the manifest lists it and its file exists,
loads and names that run; anything else (a run in progress when the window was closed,
a file removed) is flown again. Another protocol (another :attr:`digest
<manualcontrol.human.protocol.Protocol.digest>`), another participant number's plan or
a folder that holds recordings but no manifest is refused (:class:`SessionError`),
naming the settings that differ.

Interruptions
-------------
A closed window, Escape or a lost device, during a run or on a screen between runs,
raises :class:`SessionAborted` (what was kept, where to resume); Ctrl-C raises
``KeyboardInterrupt`` as usual. Either way the manifest records the interruption,
every finished run is on disk, and the run in progress left nothing: it is flown again
on resume.

Screens
-------
:class:`Screen` is what a session shows between runs; the base class shows nothing
(``show=False``: no window, breaks in seconds still kept, no waiting for keys).
:class:`PygameScreen` draws in the task's window and reads the keyboard: space (or
Enter) continues, Escape or closing the window aborts. Its key source can be
:class:`ScriptedKeys`, which answers every wait without a person (tests, demos).
"""

from __future__ import annotations

import contextlib
import datetime
import importlib.metadata
import json
import math
import os
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from manualcontrol.envs._files import atomic_write
from manualcontrol.envs.recording import Recording
from manualcontrol.human.devices import (
    DeviceAction,
    JoystickInput,
    MouseInput,
    draw_stick_gauge,
    load_pygame,
)
from manualcontrol.human.protocol import (
    Condition,
    PlannedRun,
    Protocol,
    check_participant,
    protocol_differences,
)
from manualcontrol.human.realtime import RealClock, RunAborted, fly
from manualcontrol.human.tasks import HOW_TO_MOVE, TASK_GOALS

__all__ = [
    "DEFAULT_OUT",
    "SESSION_FILE",
    "PygameScreen",
    "Screen",
    "ScriptedKeys",
    "SessionAborted",
    "SessionError",
    "SessionEvent",
    "SessionResult",
    "load_manifest",
    "rms_error",
    "rms_error_of",
    "run_session",
]

#: Where sessions go by default (one folder per participant under it).
DEFAULT_OUT = Path("results") / "experiments"
#: The manifest's file name in a participant's folder.
SESSION_FILE = "session.json"
_FORMAT = "manualcontrol-session"
_VERSION = 1


class SessionError(ValueError):
    """A session that cannot start or resume here (another protocol, no participant...)."""


class SessionAborted(Exception):  # noqa: N818 - reads as what happened
    """The session stopped before its end: a closed window, Escape, a lost device.

    Attributes
    ----------
    reason
        What happened, one phrase.
    run
        The run in progress or about to start (None if none).
    kept
        Numbers of the runs finished and on disk.
    folder
        The participant's folder.
    total
        Runs in the plan.
    """

    def __init__(
        self,
        reason: str,
        *,
        run: PlannedRun | None,
        kept: Sequence[int],
        folder: Path,
        total: int,
        during: bool = True,
    ) -> None:
        self.reason = reason
        self.run = run
        self.kept = tuple(kept)
        self.folder = folder
        self.total = total
        where = ""
        if run is not None:
            where = f" {'during' if during else 'before'} {run.label(total)}"
        super().__init__(f"{reason}{where}; {kept_phrase(self.kept, folder)}")


def kept_phrase(kept: Sequence[int], folder: Path) -> str:
    """``kept runs 1-3 in DIR`` (or ``no run finished yet``)."""
    if not kept:
        return f"no run finished yet ({folder})"
    return f"kept run{'s' if len(kept) > 1 else ''} {_ranges(kept)} in {folder}"


def _ranges(numbers: Iterable[int]) -> str:
    """``1-3, 5`` for ``[1, 2, 3, 5]``."""
    values = sorted(set(numbers))
    parts: list[str] = []
    start = previous = None
    for value in values:
        if start is None:
            start = previous = value
        elif value == previous + 1:  # type: ignore[operator]
            previous = value
        else:
            parts.append(f"{start}" if start == previous else f"{start}-{previous}")
            start = previous = value
    if start is not None:
        parts.append(f"{start}" if start == previous else f"{start}-{previous}")
    return ", ".join(parts)


@dataclass(frozen=True)
class SessionEvent:
    """What :func:`run_session` hands ``on_event``: one thing that happened.

    ``kind`` is one of ``"session"`` (the plan, at the start), ``"resume"`` (runs kept
    from before), ``"redo"`` (a listed run whose file is missing or unreadable),
    ``"break"``, ``"start"`` (a run begins), ``"finished"`` (a run saved: ``data`` has
    ``rms_error``, ``timing``, ``warning``, ``file``), ``"warning"`` (the run's timing
    is not good enough for identification), ``"practice"`` (practice ended early on
    its criterion, or at its cap without meeting it), ``"skipped"`` (a practice slot not
    needed), ``"interrupted"`` and ``"complete"``. ``message`` says it in a line.
    """

    kind: str
    message: str
    run: PlannedRun | None = None
    data: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class SessionResult:
    """A finished session: where it is, its manifest and plan."""

    folder: Path
    manifest: Mapping[str, Any]
    plan: tuple[PlannedRun, ...]

    @property
    def complete(self) -> bool:
        """Every planned run flown or skipped."""
        return self.manifest.get("status") == "complete"

    @property
    def runs(self) -> list[Mapping[str, Any]]:
        """The finished runs' records, in order."""
        return list(self.manifest["runs"])

    @property
    def files(self) -> list[Path]:
        """The finished runs' recordings, in order."""
        return [self.folder / record["file"] for record in self.runs]


# ------------------------------------------------------------------ screens


class Screen:
    """What a session shows between runs; this base class shows nothing.

    Subclasses draw (:class:`PygameScreen`). ``window`` says whether runs are shown
    too (the environment drawn in its window); without one they fly undrawn.
    """

    window: bool = False

    def open(self) -> None:
        """Get ready to show (open the window)."""

    def message(
        self,
        lines: Sequence[str],
        *,
        wait: bool = True,
        overlay: bool = False,
        device: Any = None,
    ) -> None:
        """Show ``lines``; with ``wait``, return when the participant presses space.

        ``overlay`` draws them over what the window shows (the task's first frame);
        ``device`` (a mouse or joystick) is read meanwhile and shown as a gauge. Raises
        :class:`~manualcontrol.human.realtime.RunAborted` on Escape or a closed window.
        """

    def pause(self, seconds: float, clock: Any, lines: Sequence[str]) -> None:
        """A break of ``seconds`` on ``clock``, counting down under ``lines``."""
        clock.sleep_until(clock.now() + seconds)

    def close(self) -> None:
        """Close the window, if any."""


def _key_event(name: str) -> Any:
    pygame = load_pygame()
    if name == "quit":
        return pygame.event.Event(pygame.QUIT)
    keys = {"space": pygame.K_SPACE, "escape": pygame.K_ESCAPE, "return": pygame.K_RETURN}
    if name not in keys:
        raise ValueError(f"scripted key must be one of space, return, escape, quit; got {name!r}")
    return pygame.event.Event(pygame.KEYDOWN, key=keys[name])


class ScriptedKeys:
    """Key presses for a :class:`PygameScreen` without a person: one per wait.

    Each time the screen waits for a key it gets the next of ``keys`` (``"space"``,
    ``"return"``, ``"escape"`` or ``"quit"``, the window closed), then ``then`` for
    every later wait (None: running out is an error). ``presses`` lists what was
    handed out.
    """

    def __init__(self, keys: Iterable[str] = (), *, then: str | None = "space") -> None:
        self.keys = list(keys)
        self.then = then
        self.presses: list[str] = []
        for name in [*self.keys, *([then] if then is not None else [])]:
            if name not in ("space", "return", "escape", "quit"):
                raise ValueError(
                    f"scripted key must be one of space, return, escape, quit; got {name!r}"
                )

    def __call__(self) -> list[Any]:
        """The events of one wait: the next key."""
        if self.keys:
            name = self.keys.pop(0)
        elif self.then is not None:
            name = self.then
        else:
            raise RuntimeError(f"ScriptedKeys ran out after {len(self.presses)} key presses")
        self.presses.append(name)
        return [_key_event(name)]


class PygameScreen(Screen):
    """Screens drawn with pygame in the task's window (opened here if none is up).

    Parameters
    ----------
    keys
        Where key presses come from: None reads the keyboard (pygame's events);
        a callable (:class:`ScriptedKeys`) is asked once per wait, and pygame's own
        queue is read too, so a closed window still aborts.
    size
        The window's size when this screen opens it (the tasks' displays are 600 x 400).
    fps
        How often a wait redraws (the gauge) while reading the keyboard.
    """

    window = True

    def __init__(
        self,
        keys: Callable[[], Sequence[Any]] | None = None,
        *,
        size: tuple[int, int] = (600, 400),
        fps: float = 30.0,
    ) -> None:
        self.keys = keys
        self.size = size
        self.fps = float(fps)
        self._font: Any = None
        self._small: Any = None

    def open(self) -> None:  # noqa: D102
        pygame = load_pygame()
        pygame.display.init()
        if pygame.display.get_surface() is None:
            pygame.display.set_mode(self.size)
        pygame.display.set_caption("manualcontrol experiment")
        pygame.font.init()
        self._font = pygame.font.Font(None, 30)
        self._small = pygame.font.Font(None, 24)

    def _surface(self) -> Any:
        pygame = load_pygame()
        surface = pygame.display.get_surface() if pygame.display.get_init() else None
        if surface is None:
            self.open()
            surface = pygame.display.get_surface()
        return surface

    def _wrap(self, text: str, width: int) -> list[str]:
        out: list[str] = []
        for paragraph in text.split("\n"):
            line = ""
            for word in paragraph.split():
                trial = f"{line} {word}".strip()
                if line and self._font.size(trial)[0] > width:
                    out.append(line)
                    line = word
                else:
                    line = trial
            out.append(line)
        return out

    def _draw(
        self, lines: Sequence[str], footer: str, background: Any = None, stick: float | None = None
    ) -> None:
        pygame = load_pygame()
        surface = self._surface()
        width, height = surface.get_size()
        wrapped = [row for line in lines for row in self._wrap(line, width - 60)]
        if background is not None:
            surface.blit(background, (0, 0))
            panel = pygame.Surface((width, 40 + 30 * len(wrapped)), pygame.SRCALPHA)
            panel.fill((0, 0, 0, 190))
            surface.blit(panel, (0, 20))
            top = 32
        else:
            surface.fill((25, 25, 30))
            top = max(20, (height - 30 * len(wrapped)) // 2 - 30)
        for i, line in enumerate(wrapped):
            text = self._font.render(line, True, (235, 235, 235))
            surface.blit(text, ((width - text.get_width()) // 2, top + 30 * i))
        if footer:
            text = self._small.render(footer, True, (170, 200, 255))
            surface.blit(text, ((width - text.get_width()) // 2, height - 70))
        if stick is not None:
            draw_stick_gauge(surface, stick)
        pygame.display.flip()

    def _events(self, waiting: bool) -> list[Any]:
        pygame = load_pygame()
        events = list(pygame.event.get())
        if waiting and self.keys is not None:
            events += list(self.keys())
        return events

    @staticmethod
    def _abort(event: Any, pygame: Any) -> None:
        if event.type == pygame.QUIT:
            raise RunAborted("the window was closed")
        if event.type == pygame.KEYDOWN and event.key == pygame.K_ESCAPE:
            raise RunAborted("Escape was pressed")

    def message(  # noqa: D102
        self,
        lines: Sequence[str],
        *,
        wait: bool = True,
        overlay: bool = False,
        device: Any = None,
    ) -> None:
        pygame = load_pygame()
        surface = self._surface()
        background = surface.copy() if overlay else None
        gauge = isinstance(device, (MouseInput, JoystickInput))
        footer = "press space to continue, Esc to stop" if wait else ""
        ticker = pygame.time.Clock() if self.keys is None else None
        while True:
            self._draw(lines, footer, background, device.read() if gauge else None)
            if not wait:
                return
            for event in self._events(True):
                self._abort(event, pygame)
                if event.type == pygame.KEYDOWN and event.key in (pygame.K_SPACE, pygame.K_RETURN):
                    if background is not None:  # the task's frame again, unmarked
                        surface.blit(background, (0, 0))
                        pygame.display.flip()
                    return
                if device is not None:
                    device.handle_event(event)
            if ticker is not None:
                ticker.tick(self.fps)

    def pause(self, seconds: float, clock: Any, lines: Sequence[str]) -> None:  # noqa: D102
        pygame = load_pygame()
        end = clock.now() + seconds
        while True:
            remaining = end - clock.now()
            if remaining <= 0.0:
                return
            for event in self._events(False):
                self._abort(event, pygame)
            self._draw(lines, f"the next run starts in {math.ceil(remaining - 1e-9):d} s")
            clock.sleep_until(min(end, clock.now() + 0.1))

    def close(self) -> None:  # noqa: D102
        pygame = load_pygame()
        if pygame.display.get_init():
            pygame.display.quit()


def _screen(show: Any) -> Screen:
    if show is None or show is True:
        return PygameScreen()
    if show is False:
        return Screen()
    if isinstance(show, Screen):
        return show
    raise TypeError(f"show must be a Screen, True, False or None, got {show!r}")


# ------------------------------------------------------------------ manifest


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _software() -> dict[str, str]:
    versions = {"python": sys.version.split()[0]}
    for package in ("manualcontrol", "numpy", "scipy", "gymnasium", "pygame"):
        with contextlib.suppress(importlib.metadata.PackageNotFoundError):
            versions[package] = importlib.metadata.version(package)
    return versions


def load_manifest(folder: str | Path) -> dict[str, Any]:
    """The ``session.json`` of a participant's folder, or :class:`SessionError`."""
    path = Path(folder) / SESSION_FILE
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SessionError(f"{path}: no session here (no {SESSION_FILE})") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise SessionError(f"{path}: not a readable session manifest: {error}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != _FORMAT:
        raise SessionError(f"{path}: not a session manifest (format is not {_FORMAT!r})")
    if manifest.get("version") != _VERSION:
        raise SessionError(
            f"{path}: session manifest version {manifest.get('version')!r}; this version of "
            f"manualcontrol reads version {_VERSION}"
        )
    return manifest


def _write_manifest(folder: Path, manifest: dict[str, Any]) -> None:
    manifest["updated_at"] = _now()
    text = json.dumps(manifest, indent=2, allow_nan=False)
    atomic_write(folder / SESSION_FILE, lambda path: path.write_text(text, encoding="utf-8"))


def _new_manifest(
    protocol: Protocol,
    participant: str,
    number: int | None,
    plan: Sequence[PlannedRun],
    order: Sequence[str],
    why: str,
) -> dict[str, Any]:
    return {
        "format": _FORMAT,
        "version": _VERSION,
        "participant": participant,
        "participant_number": number,
        "protocol": protocol.to_dict(),
        "protocol_digest": protocol.digest,
        "protocol_source": protocol.source,
        "protocol_text": protocol.text,
        "order": {"rule": protocol.order, "conditions": list(order), "why": why},
        "input": protocol.input.to_dict(),
        "plan": [run.to_dict() for run in plan],
        "runs": [],
        "skipped": [],
        "interruptions": [],
        "sittings": [],
        "status": "in progress",
        "started_at": _now(),
        "updated_at": _now(),
    }


def _check_manifest(
    manifest: Mapping[str, Any],
    folder: Path,
    protocol: Protocol,
    participant: str,
    plan: Sequence[PlannedRun],
) -> None:
    """Refuse to resume a session of another protocol, participant or plan."""
    path = folder / SESSION_FILE
    if manifest.get("participant") != participant:
        raise SessionError(
            f"{path}: this folder holds the session of participant "
            f"{manifest.get('participant')!r}, not {participant!r}"
        )
    if manifest.get("protocol_digest") != protocol.digest:
        differences = protocol_differences(manifest.get("protocol", {}), protocol.to_dict())
        listed = "; ".join(differences[:4]) + ("; ..." if len(differences) > 4 else "")
        raise SessionError(
            f"{path}: this folder holds a session of another protocol "
            f"({manifest.get('protocol_source')!r}, digest {manifest.get('protocol_digest')}); "
            f"{protocol.source!r} (digest {protocol.digest}) differs in {listed or 'its settings'}."
            " A session is resumed with the protocol it began with: give that protocol, or "
            "another --out folder for a new session"
        )
    if manifest.get("plan") != [run.to_dict() for run in plan]:
        before = manifest.get("order", {}).get("conditions")
        raise SessionError(
            f"{path}: this session's plan differs from the one for participant "
            f"{participant!r} now (conditions in the order {before} before); give the same "
            "--participant-number as when it began"
        )


def _verified_runs(
    folder: Path, manifest: dict[str, Any], plan: Sequence[PlannedRun], emit: Callable
) -> dict[int, dict[str, Any]]:
    """The manifest's finished runs whose file exists, loads and names that run."""
    planned = {run.number: run for run in plan}
    kept: dict[int, dict[str, Any]] = {}
    for record in manifest["runs"]:
        run = planned.get(record.get("number"))
        problem = None
        if run is None or record.get("file") != run.file_name:
            problem = "is not in the plan"
        else:
            path = folder / run.file_name
            if not path.is_file():
                problem = "its file is missing"
            else:
                try:
                    recording = Recording.load(path)
                    session = recording.metadata.get("session", {})
                    if session.get("number") != run.number:
                        problem = "its file names another run"
                except (OSError, ValueError, KeyError) as error:
                    problem = f"its file does not load ({error})"
        if problem is None and run is not None:
            kept[run.number] = record
        else:
            label = run.label(len(plan)) if run is not None else f"run {record.get('number')}"
            emit(SessionEvent("redo", f"{label}: {problem}; it is flown again", run))
    manifest["runs"] = [kept[number] for number in sorted(kept)]
    return kept


def _clean_temporaries(folder: Path) -> None:
    """Remove half-written files a killed process left (atomic writes' temporaries)."""
    for path in folder.glob(".*.part.*"):
        with contextlib.suppress(OSError):
            path.unlink()


# ------------------------------------------------------------------ the session


def rms_error(recording: Any, condition: Condition) -> tuple[float, str]:
    """The run's RMS error and its signal: ``e`` (tracking) or ``y_L`` (lane keeping)."""
    name = "e" if condition.tracking else "y_L"
    values = np.asarray(recording[name], dtype=np.float64)
    values = values[np.isfinite(values)]
    return (float(np.sqrt(np.mean(values * values))) if values.size else math.nan), name


def rms_error_of(record: Mapping[str, Any]) -> float:
    """A manifest record's RMS error (NaN where none could be computed)."""
    value = record.get("rms_error")
    return math.nan if value is None else float(value)


def _fields(protocol: Protocol, condition: Condition) -> dict[str, Any]:
    return {
        "condition": condition.name,
        "task": condition.task,
        "goal": TASK_GOALS.get(condition.task, "track the target"),
        "how": HOW_TO_MOVE.get(protocol.input.device, "move the stick left and right").capitalize(),
    }


def run_session(
    protocol: Protocol,
    participant: str | None = None,
    out: str | os.PathLike[str] = DEFAULT_OUT,
    *,
    device_factory: Callable[[PlannedRun], Any] | None = None,
    clock: Any = None,
    show: Screen | bool | None = None,
    on_event: Callable[[SessionEvent], None] | None = None,
    participant_number: int | None = None,
) -> SessionResult:
    """Fly ``participant``'s session of ``protocol``, or resume it (module docstring).

    Parameters
    ----------
    protocol
        The experiment (:func:`~manualcontrol.human.protocol.load_protocol`).
    participant
        The participant's id (names their folder); default the protocol's.
    out
        The folder of sessions; the participant's is ``out/participant``.
    device_factory
        The stick for a run: called with each :class:`PlannedRun` before it is flown;
        default the protocol's ``[input]`` device.
    clock
        Where runs and breaks keep time; default
        :class:`~manualcontrol.human.realtime.RealClock`.
    show
        A :class:`Screen`; None or True: :class:`PygameScreen` reading the keyboard;
        False: no window (no screens, runs undrawn).
    on_event
        Called with each :class:`SessionEvent` (what the command prints).
    participant_number
        For a counterbalanced order, instead of the id's digits.

    Returns
    -------
    SessionResult
        The folder, manifest and plan of the complete session.

    Raises
    ------
    SessionAborted
        The window was closed, Escape pressed or the device lost; finished runs kept.
    SessionError
        No participant, or the folder holds another protocol's session.
    KeyboardInterrupt
        Ctrl-C; finished runs kept, the interruption recorded.
    """
    if participant is None:
        participant = protocol.participant
    if participant is None:
        raise SessionError(
            "no participant: give one (--participant ID) or set participant = ... in the protocol"
        )
    try:
        participant = check_participant(participant)
    except ValueError as error:
        raise SessionError(str(error)) from None
    try:
        plan = protocol.runs(participant, participant_number)
        order, why = protocol.condition_order(participant, participant_number)
    except ValueError as error:
        raise SessionError(str(error)) from None
    number = protocol.participant_number(participant, participant_number)
    total = len(plan)
    folder = Path(out) / participant
    emit = on_event if on_event is not None else (lambda event: None)
    clock = RealClock() if clock is None else clock
    if device_factory is None:
        settings = protocol.input

        def device_factory(run: PlannedRun) -> Any:
            return settings.make()

    if (folder / SESSION_FILE).exists():
        manifest = load_manifest(folder)
        _check_manifest(manifest, folder, protocol, participant, plan)
    else:
        if folder.is_dir() and any(folder.glob("*.npz")):
            raise SessionError(
                f"{folder} holds recordings but no {SESSION_FILE}: it is not a session "
                "folder this command began; choose another --out folder"
            )
        manifest = _new_manifest(protocol, participant, number, plan, order, why)
    folder.mkdir(parents=True, exist_ok=True)
    _clean_temporaries(folder)
    finished = _verified_runs(folder, manifest, plan, emit)
    first_pending = next((run for run in plan if run.number not in finished), None)
    manifest["sittings"].append(
        {
            "started_at": _now(),
            "from_run": None if first_pending is None else first_pending.number,
            "software": _software(),
        }
    )
    manifest["status"] = "in progress" if first_pending is not None else manifest["status"]
    _write_manifest(folder, manifest)
    emit(
        SessionEvent(
            "session",
            f"session of {participant} ({protocol.name}): {total} runs, conditions "
            f"{', '.join(order)} ({why}), in {folder}",
            data={"folder": str(folder), "order": list(order), "total": total},
        )
    )
    if finished:
        pending = "" if first_pending is None else f", continuing at run {first_pending.number}"
        emit(
            SessionEvent(
                "resume",
                f"resuming: {kept_phrase(sorted(finished), folder)}{pending}",
                first_pending,
                {"kept": sorted(finished)},
            )
        )

    screen = _screen(show)
    envs: dict[str, Any] = {}
    practice_over: dict[str, bool] = {}
    shown: set[str] = set()
    previous: str | None = None  # condition of the last run flown in this sitting
    last_score: str | None = None
    current: PlannedRun | None = None
    flying = False

    def interrupted(reason: str, steps: int = 0, during: bool = False) -> None:
        manifest["interruptions"].append(
            {
                "at": _now(),
                "run": None if current is None else current.number,
                "during_run": during,
                "reason": reason,
                "steps_flown": steps,
            }
        )
        _write_manifest(folder, manifest)
        emit(SessionEvent("interrupted", reason, current, {"steps_flown": steps}))

    def skip(run: PlannedRun, reason: str) -> None:
        if all(entry["number"] != run.number for entry in manifest["skipped"]):
            manifest["skipped"].append({"number": run.number, "file": None, "reason": reason})
            _write_manifest(folder, manifest)
        emit(SessionEvent("skipped", f"{run.label(total)} skipped: {reason}", run))

    try:
        screen.open()
        for run in plan:
            condition = protocol.condition(run.condition)
            practice = condition.practice
            if run.number in finished:
                kept_rms = finished[run.number]["rms_error"]
                if run.kind == "practice" and practice.met(
                    run.index, math.nan if kept_rms is None else kept_rms
                ):
                    practice_over[run.condition] = True
                continue
            if run.kind == "practice" and practice_over.get(run.condition):
                skip(run, "practice ended on its criterion")
                continue
            current = run
            fields = _fields(protocol, condition)
            if previous is not None:
                pause = (
                    protocol.breaks.between_runs
                    if previous == run.condition
                    else protocol.breaks.between_conditions
                )
                lines = ["Break."] + ([last_score] if last_score else [])
                lines.append(f"Next: {run.condition}, {run.kind} run {run.index} of {run.count}.")
                if pause == "key":
                    emit(SessionEvent("break", "break: waiting for a key", run))
                    screen.message(lines)
                elif pause > 0.0:
                    emit(SessionEvent("break", f"break: {pause:g} s", run))
                    screen.pause(float(pause), clock, lines)
            if run.condition not in shown:
                text = (condition.instructions or protocol.instructions.before_condition).format(
                    **fields,
                    practice=practice.describe(),
                    measurement_runs=condition.measurement_runs,
                )
                lines = ([last_score] if last_score and previous is None else []) + [text]
                screen.message(lines)
                shown.add(run.condition)
            if run.condition not in envs:
                env = condition.make_env("human" if screen.window else None)
                envs[run.condition] = DeviceAction(env, condition.scale)
            wrapped = envs[run.condition]
            device = device_factory(run)
            line = protocol.instructions.before_run.format(
                **fields,
                kind=run.kind,
                index=run.index,
                count=run.count,
                number=run.number,
                total=total,
            )

            def ready(env: Any, device: Any = device, line: str = line) -> None:
                screen.message([line], overlay=True, device=device)

            emit(SessionEvent("start", f"{run.label(total)}: starting", run))
            flying = True
            try:
                flight = fly(
                    wrapped,
                    device,
                    clock=clock,
                    render=screen.window,
                    seed=run.seed,
                    options={"realisation": run.realisation} if condition.tracking else None,
                    on_ready=ready if screen.window else None,
                )
            except RunAborted as error:
                interrupted(error.reason, error.steps, error.steps > 0)
                raise SessionAborted(
                    error.reason,
                    run=run,
                    kept=sorted(finished),
                    folder=folder,
                    total=total,
                    during=error.steps > 0,
                ) from None
            flying = False
            record = _save_run(folder, protocol, participant, run, condition, flight)
            finished[run.number] = record
            manifest["runs"] = [finished[n] for n in sorted(finished)]
            _write_manifest(folder, manifest)
            previous = run.condition
            rms, signal = rms_error_of(record), record["rms_of"]
            last_score = f"Last run: RMS error {rms:.3g}" if protocol.show_score else None
            ended = (
                " (control was lost: the run ended early)" if flight.ended == "terminated" else ""
            )
            emit(
                SessionEvent(
                    "finished",
                    f"{run.label(total)}: RMS {'error' if signal == 'e' else 'lateral offset'} "
                    f"{rms:.4g}{ended}; timing: {flight.timing.summary()}; wrote "
                    f"{folder / run.file_name}",
                    run,
                    {
                        "rms_error": rms,
                        "timing": record["timing"],
                        "warning": flight.warning,
                        "file": str(folder / run.file_name),
                    },
                )
            )
            if flight.warning is not None:
                emit(SessionEvent("warning", f"{run.label(total)}: {flight.warning}", run))
            if run.kind == "practice" and practice.has_criterion:
                assert practice.until_rms_below is not None
                if practice.met(run.index, rms):
                    practice_over[run.condition] = True
                    if rms < practice.until_rms_below and run.index >= practice.min_runs:
                        left = run.count - run.index
                        message = (
                            f"{run.condition}: practice criterion met after {run.index} run(s) "
                            f"(RMS {rms:.4g} < {practice.until_rms_below:g})"
                            + (f"; the other {left} practice slot(s) skipped" if left else "")
                        )
                    else:
                        message = (
                            f"{run.condition}: practice stopped at its cap of {run.count} runs "
                            f"without meeting the criterion (last RMS {rms:.4g}, needed below "
                            f"{practice.until_rms_below:g})"
                        )
                    emit(SessionEvent("practice", message, run, {"rms_error": rms}))
        current = None
        manifest["status"] = "complete"
        manifest["completed_at"] = manifest.get("completed_at") or _now()
        _write_manifest(folder, manifest)
        emit(
            SessionEvent(
                "complete",
                f"session complete: {len(finished)} runs in {folder}",
                data={"folder": str(folder)},
            )
        )
        with contextlib.suppress(RunAborted):
            screen.message(
                ([last_score] if last_score else []) + ["The session is complete. Thank you!"]
            )
    except RunAborted as error:  # on a screen between runs
        interrupted(error.reason)
        raise SessionAborted(
            error.reason,
            run=current,
            kept=sorted(finished),
            folder=folder,
            total=total,
            during=False,
        ) from None
    except KeyboardInterrupt:
        interrupted("interrupted (Ctrl-C)", during=flying)
        raise
    finally:
        for env in envs.values():
            with contextlib.suppress(Exception):
                env.close()
        screen.close()
    return SessionResult(folder, manifest, tuple(plan))


def _save_run(
    folder: Path,
    protocol: Protocol,
    participant: str,
    run: PlannedRun,
    condition: Condition,
    flight: Any,
) -> dict[str, Any]:
    """Save the run's recording (atomically) and return its manifest record."""
    recording = flight.recording.with_metadata(
        session={
            "protocol": protocol.name,
            "protocol_digest": protocol.digest,
            "participant": participant,
            "number": run.number,
            "condition": run.condition,
            "kind": run.kind,
            "index": run.index,
            "count": run.count,
            "realisation": run.realisation,
            "seed": run.seed,
        }
    )
    recording.save(folder / run.file_name)
    rms, signal = rms_error(recording, condition)
    return {
        **run.to_dict(),
        "rms_error": rms if math.isfinite(rms) else None,
        "rms_of": signal,
        "steps": len(recording),
        "duration_s": len(recording) * recording.dt,
        "ended": flight.ended,
        "timing": flight.timing.as_metadata(),
        "timing_summary": flight.timing.summary(),
        "timing_warning": flight.warning,
        "input": dict(flight.calibration),
        "action_scale": dict(recording.metadata["action_scale"]),
        "finished_at": _now(),
    }
