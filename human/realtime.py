"""The real-time loop: one episode flown by a person, one step per sample time.

:func:`fly` runs an episode at the environment's ``dt`` in wall-clock time. Each step
it waits for the step's deadline, pumps the window's events (a closed window or
Escape aborts the run, a lost device too: :class:`RunAborted`), reads the device once,
steps the environment with the resulting action (the environment draws its display
in ``step`` when its ``render_mode`` is ``"human"``) and measures how late the step
started and how long its work took.

Schedule
--------
Step ``k`` is due at its deadline; the first deadline is when the loop starts (after
``on_ready``), each next one a sample time later. A step that starts late is not
skipped: the environment's time stays on its grid (the recording is uniform, one
sample per step, whatever the wall clock did), only the wall-clock schedule slips. A
step more than half a sample late (see :data:`LATE_THRESHOLD`) moves the schedule: the
next step is due a sample time after it started, so the display does not run fast to
catch up (which would show the person a different task); lateness below that is
absorbed by the grid, so small delays do not add up into drift.

Timing
------
:class:`Timing` summarises the run: lateness of each step's start against its deadline
(median, 99th percentile, maximum), late steps, the jitter of the interval between step
starts (``|interval - dt|``, median and 99th percentile) and the work of each step (the
frame time: events, device, step and drawing). Identification assumes uniform sampling:
the stick recorded at sample ``k`` is taken to have been read at ``t_k``. A run is
good enough for identification (:attr:`Timing.good_enough_for_identification`) when at
most :data:`LATE_FRACTION_LIMIT` of its steps were late and the 99th percentile of
lateness is at most one sample; otherwise :attr:`Flight.warning` says what went wrong.

Clocks
------
:class:`RealClock` (``time.perf_counter``) sleeps most of a wait and spins the last
millisecond; :class:`ManualClock` advances only when told to, with lateness injected on
demand, so tests fly whole episodes without sleeping.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs.recording import Recording
from manualcontrol.human.devices import DeviceAction, DeviceLost, InputDevice

__all__ = [
    "LATE_FRACTION_LIMIT",
    "LATE_THRESHOLD",
    "P99_LATENESS_LIMIT",
    "Clock",
    "Flight",
    "ManualClock",
    "RealClock",
    "RunAborted",
    "StepReport",
    "Timing",
    "fly",
]

FloatArray = NDArray[np.float64]

#: A step is late when it starts more than this many sample times after its deadline:
#: past half a sample its stick is nearer the next grid time than its own, so the
#: recording would date it to the wrong sample.
LATE_THRESHOLD = 0.5
#: At most this share of late steps for identification: an occasional late step (a
#: page fault, a busy compositor) shifts one sample in a hundred and barely changes an
#: estimate; more and the sampling is no longer uniform.
LATE_FRACTION_LIMIT = 0.01
#: The 99th percentile of lateness may be at most this many sample times.
P99_LATENESS_LIMIT = 1.0


# ------------------------------------------------------------------ clocks


@runtime_checkable
class Clock(Protocol):
    """Where :func:`fly` reads the time and waits: seconds on a monotonic clock."""

    def now(self) -> float:
        """The time now (s)."""
        ...

    def sleep_until(self, t: float) -> None:
        """Return at time ``t`` (or at once, if it has passed)."""
        ...


class RealClock:
    """Wall-clock time, ``time.perf_counter``, with waits precise to microseconds.

    ``sleep_until`` sleeps all but the last ``spin`` seconds of a wait and spins (reads
    the clock in a loop) for the rest: ``time.sleep`` returns late by the operating
    system's timer slack (about 0.05-0.1 ms on Linux, up to 1-16 ms on Windows), a
    tenth of a 100-Hz sample or more; spinning the last millisecond lands within
    microseconds of the deadline for at most a millisecond of one core per step.

    Parameters
    ----------
    spin
        Seconds spun at the end of each wait (default 0.001).
    """

    def __init__(self, spin: float = 0.001) -> None:
        if not (isinstance(spin, (int, float)) and math.isfinite(spin) and spin >= 0.0):
            raise ValueError(f"spin must be a finite number of seconds >= 0, got {spin!r}")
        self.spin = float(spin)

    def now(self) -> float:
        """``time.perf_counter()``."""
        return time.perf_counter()

    def sleep_until(self, t: float) -> None:
        """Sleep until ``spin`` before ``t``, then spin to ``t``."""
        clock = time.perf_counter
        remaining = t - clock()
        if remaining > self.spin:
            time.sleep(remaining - self.spin)
        while clock() < t:
            pass

    def __repr__(self) -> str:
        return f"RealClock(spin={self.spin!r})"


class ManualClock:
    """A clock for tests: time moves only through :meth:`sleep_until` and :meth:`advance`.

    ``sleep_until(t)`` sets the time to ``t`` (if it is ahead) plus the next injected
    lateness, so a step can be made to start late by a known amount.

    Parameters
    ----------
    start
        The time at first (s).
    lateness
        Extra seconds for each call of :meth:`sleep_until`, in order (a sequence,
        zero past its end) or as a function of the call's index.
    """

    def __init__(
        self,
        start: float = 0.0,
        lateness: Sequence[float] | Callable[[int], float] | None = None,
    ) -> None:
        self.time = float(start)
        self.lateness = lateness
        self.sleeps = 0

    def now(self) -> float:
        """The current (manual) time."""
        return self.time

    def _late(self, i: int) -> float:
        lateness = self.lateness
        if lateness is None:
            return 0.0
        if callable(lateness):
            return float(lateness(i))
        return float(lateness[i]) if i < len(lateness) else 0.0

    def sleep_until(self, t: float) -> None:
        """Move to ``t`` (if ahead) plus this call's injected lateness."""
        late = self._late(self.sleeps)
        self.sleeps += 1
        self.time = max(self.time, float(t)) + late

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` pass (work done between waits)."""
        self.time += float(seconds)

    def __repr__(self) -> str:
        return f"ManualClock(time={self.time!r}, sleeps={self.sleeps})"


# ------------------------------------------------------------------ timing


def _percentile(values: FloatArray, q: float) -> float:
    return float(np.percentile(values, q)) if values.size else 0.0


@dataclass(frozen=True)
class Timing:
    """How well a run kept to its schedule (seconds throughout); see the module docstring.

    Attributes
    ----------
    steps, dt
        Steps flown and the sample time.
    late_steps
        Steps that started more than :data:`LATE_THRESHOLD` sample times late.
    max_lateness, median_lateness, p99_lateness
        Lateness of the steps' starts against their deadlines.
    median_jitter, p99_jitter
        ``|interval - dt|`` of the intervals between consecutive step starts.
    median_frame_time, p99_frame_time, max_frame_time
        Work of a step: events, the device, the environment's step and its drawing.
    wall_time
        From the first deadline to the end of the last step's work.
    clock
        The clock's class name.
    """

    steps: int
    dt: float
    late_steps: int
    max_lateness: float
    median_lateness: float
    p99_lateness: float
    median_jitter: float
    p99_jitter: float
    median_frame_time: float
    p99_frame_time: float
    max_frame_time: float
    wall_time: float
    clock: str = ""

    @classmethod
    def from_steps(
        cls,
        dt: float,
        deadlines: Sequence[float],
        starts: Sequence[float],
        frame_times: Sequence[float],
        clock: str = "",
    ) -> Timing:
        """The summary of steps due at ``deadlines`` that began at ``starts``."""
        deadline = np.asarray(deadlines, dtype=np.float64)
        start = np.asarray(starts, dtype=np.float64)
        frame = np.asarray(frame_times, dtype=np.float64)
        lateness = start - deadline
        jitter = np.abs(np.diff(start) - dt)
        return cls(
            steps=int(start.size),
            dt=float(dt),
            late_steps=int(np.count_nonzero(lateness > LATE_THRESHOLD * dt)),
            max_lateness=float(lateness.max()) if lateness.size else 0.0,
            median_lateness=_percentile(lateness, 50.0),
            p99_lateness=_percentile(lateness, 99.0),
            median_jitter=_percentile(jitter, 50.0),
            p99_jitter=_percentile(jitter, 99.0),
            median_frame_time=_percentile(frame, 50.0),
            p99_frame_time=_percentile(frame, 99.0),
            max_frame_time=float(frame.max()) if frame.size else 0.0,
            wall_time=float(start[-1] + frame[-1] - deadline[0]) if start.size else 0.0,
            clock=clock,
        )

    @property
    def late_threshold(self) -> float:
        """Lateness (s) beyond which a step counts as late: half a sample time."""
        return LATE_THRESHOLD * self.dt

    @property
    def late_fraction(self) -> float:
        """Share of the steps that were late."""
        return self.late_steps / self.steps if self.steps else 0.0

    def problems(self) -> list[str]:
        """What breaks the identification criterion, one phrase each (empty if none)."""
        found = []
        if self.late_fraction > LATE_FRACTION_LIMIT:
            found.append(
                f"{self.late_steps} of {self.steps} steps ({100 * self.late_fraction:.1f} %) "
                f"started more than half a step ({1e3 * self.late_threshold:.3g} ms) late, "
                f"more than {100 * LATE_FRACTION_LIMIT:g} %"
            )
        if self.p99_lateness > P99_LATENESS_LIMIT * self.dt:
            found.append(
                f"the 99th percentile of lateness is {1e3 * self.p99_lateness:.3g} ms, more "
                f"than one step ({1e3 * self.dt:.3g} ms)"
            )
        return found

    @property
    def good_enough_for_identification(self) -> bool:
        """At most 1 % late steps and a 99th percentile of lateness within one step."""
        return not self.problems()

    @property
    def warning(self) -> str | None:
        """Why the timing is not good enough for identification, or None when it is."""
        found = self.problems()
        if not found:
            return None
        return (
            "timing not good enough for identification: "
            + "; ".join(found)
            + ". Identification assumes the stick was sampled every "
            f"{1e3 * self.dt:.3g} ms, and here it was not: close other programs, keep the "
            "window in front and fly again"
        )

    def summary(self) -> str:
        """One line for people: late steps, lateness, jitter, frame time (ms)."""
        return (
            f"{self.steps} steps, {self.late_steps} late (> {1e3 * self.late_threshold:.3g} ms); "
            f"lateness median {1e3 * self.median_lateness:.3f} ms, p99 "
            f"{1e3 * self.p99_lateness:.3f} ms, max {1e3 * self.max_lateness:.3f} ms; jitter "
            f"median {1e3 * self.median_jitter:.3f} ms, p99 {1e3 * self.p99_jitter:.3f} ms; "
            f"frame time median {1e3 * self.median_frame_time:.3f} ms, max "
            f"{1e3 * self.max_frame_time:.3f} ms"
        )

    def as_metadata(self) -> dict[str, Any]:
        """The summary for a recording's metadata (JSON-able; times in seconds)."""
        return {
            "clock": self.clock,
            "steps": self.steps,
            "dt": self.dt,
            "late_threshold_s": self.late_threshold,
            "late_steps": self.late_steps,
            "late_fraction": self.late_fraction,
            "lateness_s": {
                "median": self.median_lateness,
                "p99": self.p99_lateness,
                "max": self.max_lateness,
            },
            "jitter_s": {"median": self.median_jitter, "p99": self.p99_jitter},
            "frame_time_s": {
                "median": self.median_frame_time,
                "p99": self.p99_frame_time,
                "max": self.max_frame_time,
            },
            "wall_time_s": self.wall_time,
            "good_enough_for_identification": self.good_enough_for_identification,
            "criterion": (
                f"late steps (> {LATE_THRESHOLD:g} step) at most "
                f"{100 * LATE_FRACTION_LIMIT:g} % and p99 lateness at most "
                f"{P99_LATENESS_LIMIT:g} step"
            ),
        }


# ------------------------------------------------------------------ results


class StepReport(NamedTuple):
    """What :func:`fly` hands ``on_step`` after each step."""

    #: Steps taken so far, this one included (1 after the first).
    index: int
    #: The device's reading in ``[-1, 1]``.
    stick: float
    #: The action the environment received (``scale * stick``).
    action: float
    observation: Any
    reward: float
    terminated: bool
    truncated: bool
    info: Mapping[str, Any]
    #: How late the step started (s).
    lateness: float
    #: The step's work (s).
    frame_time: float
    #: The drawn frame for an ``"rgb_array"`` environment, else None.
    frame: Any = None


class RunAborted(Exception):  # noqa: N818 - reads as what happened
    """A run stopped before its end: the window was closed, Escape pressed, a device lost.

    Attributes
    ----------
    reason
        What happened, one phrase (``"the window was closed"``).
    steps
        Steps flown before it happened.
    total
        Steps the run was to have (None when unknown).
    elapsed
        Environment time flown (s): ``steps * dt``.
    recording
        The steps flown, or None when there were none (not saved by :func:`fly`).
    """

    def __init__(
        self,
        reason: str,
        *,
        steps: int = 0,
        total: int | None = None,
        dt: float = 0.0,
        recording: Recording | None = None,
    ) -> None:
        self.reason = reason
        self.steps = steps
        self.total = total
        self.dt = dt
        self.elapsed = steps * dt
        self.recording = recording
        of = f" of {total}" if total is not None else ""
        super().__init__(f"{reason} at step {steps}{of} ({self.elapsed:.2f} s flown)")


@dataclass(frozen=True, eq=False)
class Flight:
    """One flown episode: its recording, timing and how the stick was read.

    The recording's metadata carry ``"input"`` (the device's calibration),
    ``"action_scale"`` (action at full deflection and the rule that chose it) and
    ``"timing"`` (:meth:`Timing.as_metadata`).

    Attributes
    ----------
    recording, timing
        The episode and its schedule's summary.
    calibration
        The device's calibration.
    action_scale
        Action at full stick deflection.
    lateness, frame_times
        Per step (s).
    ended
        ``"truncated"`` (the episode ran its length), ``"terminated"`` (loss of control)
        or ``"max_steps"`` (stopped at ``max_steps``).
    """

    recording: Recording
    timing: Timing
    calibration: Mapping[str, Any]
    action_scale: float
    lateness: FloatArray = field(repr=False)
    frame_times: FloatArray = field(repr=False)
    ended: str = "truncated"

    @property
    def good_enough_for_identification(self) -> bool:
        """:attr:`Timing.good_enough_for_identification` of this run."""
        return self.timing.good_enough_for_identification

    @property
    def warning(self) -> str | None:
        """:attr:`Timing.warning` of this run: None when the timing was good enough."""
        return self.timing.warning


# ------------------------------------------------------------------ the loop


class _NoTick:
    """Stands in for the env's ``pygame.time.Clock`` while :func:`fly` keeps time."""

    def tick(self, framerate: float = 0.0) -> int:
        del framerate
        return 0


class _Pacing:
    """Take the frame pacing from the env's own window for the length of a run.

    The envs' ``"human"`` rendering ends each frame with ``pygame.time.Clock.tick``,
    which waits in whole milliseconds on its own schedule; with :func:`fly` keeping
    the schedule that would only add up to a millisecond of lateness a step (and real
    sleeping under a :class:`ManualClock`). The env's clock is put back afterwards.
    """

    def __init__(self, base: Any) -> None:
        self.base = base
        self.saved = getattr(base, "_clock", None)
        self.swapped = self.saved is not None and not isinstance(self.saved, _NoTick)
        if self.swapped:
            base._clock = _NoTick()

    def restore(self) -> None:
        if self.swapped and getattr(self.base, "_clock", None) is not None:
            self.base._clock = self.saved


def _events() -> list[Any]:
    """The pygame events of this step, or none when no pygame display is up."""
    pygame = sys.modules.get("pygame")
    if pygame is None or not pygame.display.get_init():
        return []
    return pygame.event.get()


def _find_device_action(env: gym.Env) -> DeviceAction | None:
    current: Any = env
    while isinstance(current, gym.Wrapper):
        if isinstance(current, DeviceAction):
            return current
        current = current.env
    return None


def fly(
    env: gym.Env,
    device: InputDevice,
    *,
    clock: Clock | None = None,
    render: bool = True,
    max_steps: int | None = None,
    on_step: Callable[[StepReport], None] | None = None,
    seed: int | None = None,
    options: Mapping[str, Any] | None = None,
    scale: float | None = None,
    on_ready: Callable[[gym.Env], None] | None = None,
) -> Flight:
    """Fly one episode of ``env`` with ``device`` in real time; see the module docstring.

    Parameters
    ----------
    env
        A tracking or lane-keeping environment (possibly wrapped). It is acted on
        through :class:`~manualcontrol.human.devices.DeviceAction`: ``env`` itself if
        it is one (its scale holds), else ``env`` wrapped in one with ``scale``.
    device
        The stick: opened after ``env.reset`` (its window is up then), read once per
        step, closed at the end.
    clock
        Where time is read and waited for; default :class:`RealClock`.
    render
        Show the display every step. An environment made with ``render_mode="human"``
        draws it in ``step`` itself (gymnasium's rule for that mode), which
        ``render=False`` cannot stop: it is refused there. With ``"rgb_array"`` the
        frame is drawn each step (its cost counts in the timing) and handed to
        ``on_step``; without a render mode nothing is drawn.
    max_steps
        Stop after this many steps (default: the episode's end).
    on_step
        Called with a :class:`StepReport` after each step, before the wait for the next.
    seed, options
        Passed to ``env.reset``.
    scale
        Action at full deflection when ``env`` is not already a ``DeviceAction``
        (default :func:`~manualcontrol.human.devices.default_action_scale`).
    on_ready
        Called once with the wrapped env after the reset and the device's opening,
        before the first step (the play command's "press space to start"); the
        schedule begins when it returns.

    Returns
    -------
    Flight
        The recording (with the device's calibration, the action scale and the timing
        in its metadata) and the timing.

    Raises
    ------
    RunAborted
        The window was closed, Escape pressed, or the device lost (its reason says
        which); it carries the steps flown.
    """
    clock = RealClock() if clock is None else clock
    wrapped = _find_device_action(env)
    if wrapped is None:
        wrapped = DeviceAction(env, scale)
    elif scale is not None and float(scale) != wrapped.scale:
        raise ValueError(
            f"env is a DeviceAction with scale {wrapped.scale:g}; scale={scale!r} disagrees"
        )
    base = wrapped.unwrapped
    dt = float(base.dt)
    mode = getattr(base, "render_mode", None)
    if mode == "human" and not render:
        raise ValueError(
            'render=False needs an env made without render_mode="human": such an env '
            "draws its display in step() itself"
        )
    if max_steps is not None and (isinstance(max_steps, bool) or int(max_steps) < 1):
        raise ValueError(f"max_steps must be a whole number >= 1, got {max_steps!r}")
    draw_frames = render and mode == "rgb_array"
    total = getattr(base, "episode_steps", None)
    limit = total if max_steps is None else max_steps if total is None else min(total, max_steps)

    wrapped.reset(seed=seed, options=None if options is None else dict(options))
    pacing = _Pacing(base) if mode == "human" else None
    deadlines: list[float] = []
    starts: list[float] = []
    frame_times: list[float] = []
    threshold = LATE_THRESHOLD * dt
    steps = 0

    def aborted(reason: str) -> RunAborted:
        recording = _decorated(base, wrapped, device, timing()) if steps else None
        return RunAborted(reason, steps=steps, total=limit, dt=dt, recording=recording)

    def timing() -> Timing:
        return Timing.from_steps(dt, deadlines, starts, frame_times, type(clock).__name__)

    try:
        device.open(wrapped)
        try:
            if on_ready is not None:
                on_ready(wrapped)
            ended = "max_steps"
            deadline = clock.now()
            action = np.zeros(1)
            while limit is None or steps < limit:
                clock.sleep_until(deadline)
                start = clock.now()
                try:
                    for event in _events():
                        reason = _abort_reason(event)
                        if reason is not None:
                            raise aborted(reason)
                        device.handle_event(event)
                    stick = device.read()
                except DeviceLost as error:
                    raise aborted(str(error)) from error
                action[0] = stick
                observation, reward, terminated, truncated, info = wrapped.step(action)
                frame = wrapped.render() if draw_frames else None
                end = clock.now()
                deadlines.append(deadline)
                starts.append(start)
                frame_times.append(end - start)
                steps += 1
                lateness = start - deadline
                if on_step is not None:
                    on_step(
                        StepReport(
                            steps,
                            stick,
                            float(wrapped.action(action)[0]),
                            observation,
                            float(reward),
                            bool(terminated),
                            bool(truncated),
                            info,
                            lateness,
                            end - start,
                            frame,
                        )
                    )
                if terminated or truncated:
                    ended = "terminated" if terminated else "truncated"
                    break
                # on the grid unless more than half a step late: then the schedule slips
                deadline = deadline + dt if lateness <= threshold else start + dt
        finally:
            device.close()
    finally:
        if pacing is not None:
            pacing.restore()
    summary = timing()
    recording = _decorated(base, wrapped, device, summary)
    return Flight(
        recording=recording,
        timing=summary,
        calibration=device.calibration,
        action_scale=wrapped.scale,
        lateness=np.asarray(starts) - np.asarray(deadlines),
        frame_times=np.asarray(frame_times),
        ended=ended,
    )


def _abort_reason(event: Any) -> str | None:
    """Why ``event`` ends the run (a closed window, Escape), or None."""
    pygame = sys.modules["pygame"]
    if event.type == pygame.QUIT:
        return "the window was closed"
    if event.type == pygame.KEYDOWN and event.key == pygame.K_ESCAPE:
        return "Escape was pressed"
    return None


def _decorated(base: Any, wrapped: DeviceAction, device: InputDevice, timing: Timing) -> Recording:
    """The env's recording with the device's calibration, action scale and timing."""
    return base.recording().with_metadata(
        input=device.calibration,
        action_scale=dict(wrapped.describe()),
        timing=timing.as_metadata(),
    )
