"""Time-varying parameter schedules: how a pilot or controlled-element parameter moves in time.

A schedule is a frozen dataclass that maps time (s) to a parameter value. It is callable
on a scalar time (returns a ``float``) and on an array of times (returns a float64 array
of the same shape), so the same object drives a sample-by-sample simulation and a
vectorised one. Schedules add up (``a + b``, ``sum([...])``), chain in time
(:class:`Sequence`) and save to JSON-able dicts (:meth:`Schedule.to_dict`,
:meth:`Schedule.from_dict`).

* :class:`Constant` -- a fixed value.
* :class:`Sigmoid` -- smooth step written with its 99 % transition time (thesis Part I
  eq. 36, Part II eq. 4.2, Appendix A).
* :class:`Sine` -- ``mean + amplitude sin(2 pi (t - phase) / period)`` (thesis eq. 4.3).
* :class:`Step`, :class:`Ramp` -- abrupt and linear changes.
* :class:`RandomWalk` -- a seeded, optionally bounded Gaussian random walk.
* :class:`BandLimitedRandomWalk` -- a random walk whose increments are low-passed
  Gaussian noise (Boer & Kenyon 1998, Sec. IV-A): a smoothly wandering value.
* :class:`Sum`, :class:`Sequence` -- composition.

Example: the preview time of thesis Table 6.1, Sim 5, ``tau_f(sigm, 0.3, 0.6, 50, 10)``::

    tau_f = Sigmoid(start=0.3, end=0.6, t_mid=50.0, transition_time=10.0)
    tau_f(50.0)  # 0.45
"""

from __future__ import annotations

import abc
import math
import numbers
from collections.abc import Iterable, Mapping
from dataclasses import MISSING, dataclass, fields
from functools import cached_property
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._validation import (
    check_choice,
    check_int,
    check_positive,
    check_real,
    check_times,
    reject_unknown,
)

__all__ = [
    "BandLimitedRandomWalk",
    "Constant",
    "Ramp",
    "RandomWalk",
    "Schedule",
    "Sequence",
    "Sigmoid",
    "Sine",
    "Step",
    "Sum",
    "as_schedule",
]

FloatArray = NDArray[np.float64]

#: ``2 ln 199``: the logistic argument spanned by the central 99 % of a sigmoid (thesis
#: eq. A.2 with b = 0.99: ``2 ln((1 + b) / (1 - b))``).
_LOG_199_TWICE = 2.0 * math.log(199.0)


def _g(value: float) -> str:
    return f"{value:g}"


@dataclass(frozen=True)
class Schedule(abc.ABC):
    """Base class of all schedules: a parameter value as a function of time.

    Subclasses implement :meth:`_evaluate` on a 1-D array of finite times and
    :meth:`describe`; calling, adding, saving and loading are shared.
    """

    #: Name under which the schedule is saved (the ``"kind"`` key of :meth:`to_dict`).
    kind: ClassVar[str] = ""

    def __call__(self, t: ArrayLike) -> Any:
        """Value at time ``t`` (s): a ``float`` for a scalar, an array shaped like ``t``.

        Raises ``ValueError`` when any time is NaN or infinite.
        """
        times = check_times(t)
        values = self._evaluate(times.ravel()).reshape(times.shape)
        if times.ndim == 0:
            return float(values)
        return values

    @abc.abstractmethod
    def _evaluate(self, t: FloatArray) -> FloatArray:
        """Values at the finite times ``t``, shape ``(n,)`` in and out."""

    @abc.abstractmethod
    def describe(self) -> str:
        """Short human-readable form for plot legends and logs."""

    @property
    def is_constant(self) -> bool:
        """True only for :class:`Constant` and sums of constants."""
        return False

    def __add__(self, other: object) -> Schedule:
        if isinstance(other, Schedule):
            return Sum((self, other))
        if isinstance(other, numbers.Real) and not isinstance(other, bool):
            return Sum((self, Constant(other)))
        return NotImplemented

    def __radd__(self, other: object) -> Schedule:
        # ``sum([...])`` starts from the integer 0, the additive identity.
        if isinstance(other, numbers.Real) and not isinstance(other, bool):
            return self if other == 0 else Sum((Constant(other), self))
        return NotImplemented

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description; :meth:`Schedule.from_dict` rebuilds the schedule."""
        return {"kind": self.kind, **{f.name: getattr(self, f.name) for f in fields(self)}}

    @classmethod
    def _from_fields(cls, data: dict[str, Any]) -> Schedule:
        return cls(**data)

    @staticmethod
    def from_dict(data: Mapping[str, Any] | float) -> Schedule:
        """Rebuild a schedule from :meth:`to_dict` output.

        A bare number is read as a :class:`Constant` (handy in hand-written suite files).
        Unknown kinds or keys and missing keys raise with the allowed names listed.
        """
        if isinstance(data, numbers.Real) and not isinstance(data, bool):
            return Constant(data)
        if not isinstance(data, Mapping):
            raise TypeError(f"schedule must be a number or a dict with a 'kind' key, got {data!r}")
        items = dict(data)
        kind = check_choice("schedule kind", items.pop("kind", None), _KINDS)
        cls = _KINDS[kind]
        names = [f.name for f in fields(cls)]
        reject_unknown(f"{cls.__name__}.from_dict", items, names)
        required = [
            f.name
            for f in fields(cls)
            if f.default is MISSING and f.default_factory is MISSING and f.name not in items
        ]
        if required:
            raise TypeError(f"{cls.__name__}.from_dict is missing key(s) {', '.join(required)}")
        return cls._from_fields(items)


@dataclass(frozen=True)
class Constant(Schedule):
    """A value that does not change: ``value`` at every time."""

    kind: ClassVar[str] = "constant"
    value: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "value", check_real("value", self.value))

    @property
    def is_constant(self) -> bool:  # noqa: D102
        return True

    def _evaluate(self, t: FloatArray) -> FloatArray:
        return np.full(t.shape, self.value)

    def describe(self) -> str:  # noqa: D102
        return _g(self.value)


@dataclass(frozen=True)
class Sigmoid(Schedule):
    """Smooth step from ``start`` to ``end``, 99 % of it within ``transition_time``.

    Thesis Part II eq. 4.2 (Part I eq. 36, Appendix A eq. A.4)::

        y(t) = start + (end - start) / (1 + exp(-(2 ln 199 / ΔT) (t - t_mid)))

    so ``y(t_mid)`` is the midpoint and ``y(t_mid ± ΔT/2)`` are the 0.5 % and 99.5 %
    points of the change. (Part I eq. 36 prints ``(T - t)`` in its second form, which
    would run the step backwards; eq. 4.2 and the derivation A.4 have ``(t - T)``, used
    here.) Evaluated with :func:`scipy.special.expit`, so far tails neither overflow
    nor warn.

    Parameters
    ----------
    start, end
        Values long before and long after ``t_mid``.
    t_mid
        Inflection time ``T_inflect`` (s).
    transition_time
        ``ΔT_inflect`` (s), > 0: duration of the central 99 % of the change.

    """

    kind: ClassVar[str] = "sigmoid"
    start: float
    end: float
    t_mid: float
    transition_time: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", check_real("start", self.start))
        object.__setattr__(self, "end", check_real("end", self.end))
        object.__setattr__(self, "t_mid", check_real("t_mid", self.t_mid))
        object.__setattr__(
            self, "transition_time", check_positive("transition_time", self.transition_time)
        )

    @classmethod
    def from_max_rate(cls, start: float, end: float, t_mid: float, rate_g: float) -> Sigmoid:
        """Sigmoid in the earlier form with rate ``G`` (thesis eq. A.1).

        ``y = start + (end - start) / (1 + exp(-G (t - t_mid)))``, i.e. the same curve
        with ``transition_time = 2 ln 199 / G`` (eq. A.4). ``G`` (1/s, > 0) is the
        logistic rate; the steepest slope of ``y`` is ``G (end - start) / 4``.
        """
        rate_g = check_positive("rate_g", rate_g)
        return cls(start, end, t_mid, _LOG_199_TWICE / rate_g)

    @property
    def rate_g(self) -> float:
        """Logistic rate ``G = 2 ln 199 / transition_time`` (1/s) of thesis eq. A.1."""
        return _LOG_199_TWICE / self.transition_time

    def _evaluate(self, t: FloatArray) -> FloatArray:
        import scipy.special  # a sixth of a second at import, for the first sigmoid only

        return self.start + (self.end - self.start) * scipy.special.expit(
            self.rate_g * (t - self.t_mid)
        )

    def describe(self) -> str:  # noqa: D102
        return (
            f"sigmoid({_g(self.start)} -> {_g(self.end)} at {_g(self.t_mid)} s, "
            f"99 % in {_g(self.transition_time)} s)"
        )


@dataclass(frozen=True)
class Sine(Schedule):
    """Sinusoidal variation, thesis Part II eq. 4.3 (after Popovici et al. 2017).

    ``y(t) = mean + amplitude sin(2 pi (t - phase) / period)`` with ``period`` (> 0)
    and ``phase`` both in seconds: the sine crosses ``mean`` upwards at ``t = phase``.
    """

    kind: ClassVar[str] = "sine"
    mean: float
    amplitude: float
    period: float
    phase: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean", check_real("mean", self.mean))
        object.__setattr__(self, "amplitude", check_real("amplitude", self.amplitude))
        object.__setattr__(self, "period", check_positive("period", self.period))
        object.__setattr__(self, "phase", check_real("phase", self.phase))

    def _evaluate(self, t: FloatArray) -> FloatArray:
        return self.mean + self.amplitude * np.sin(2.0 * np.pi * (t - self.phase) / self.period)

    def describe(self) -> str:  # noqa: D102
        return (
            f"sine(mean {_g(self.mean)}, amplitude {_g(self.amplitude)}, "
            f"period {_g(self.period)} s, phase {_g(self.phase)} s)"
        )


@dataclass(frozen=True)
class Step(Schedule):
    """Abrupt change: ``before`` for ``t < t_step``, ``after`` for ``t >= t_step``."""

    kind: ClassVar[str] = "step"
    before: float
    after: float
    t_step: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "before", check_real("before", self.before))
        object.__setattr__(self, "after", check_real("after", self.after))
        object.__setattr__(self, "t_step", check_real("t_step", self.t_step))

    def _evaluate(self, t: FloatArray) -> FloatArray:
        return np.where(t >= self.t_step, self.after, self.before)

    def describe(self) -> str:  # noqa: D102
        return f"step({_g(self.before)} -> {_g(self.after)} at {_g(self.t_step)} s)"


@dataclass(frozen=True)
class Ramp(Schedule):
    """Linear change from ``start`` at ``t_start`` to ``end`` at ``t_end``, constant outside."""

    kind: ClassVar[str] = "ramp"
    start: float
    end: float
    t_start: float
    t_end: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", check_real("start", self.start))
        object.__setattr__(self, "end", check_real("end", self.end))
        object.__setattr__(self, "t_start", check_real("t_start", self.t_start))
        object.__setattr__(self, "t_end", check_real("t_end", self.t_end))
        if self.t_end <= self.t_start:
            raise ValueError(
                f"t_end must be > t_start = {self.t_start!r}, got t_end = {self.t_end!r}"
            )

    def _evaluate(self, t: FloatArray) -> FloatArray:
        return np.interp(t, [self.t_start, self.t_end], [self.start, self.end])

    def describe(self) -> str:  # noqa: D102
        return (
            f"ramp({_g(self.start)} -> {_g(self.end)} "
            f"from {_g(self.t_start)} to {_g(self.t_end)} s)"
        )


@dataclass(frozen=True)
class RandomWalk(Schedule):
    """Seeded Gaussian random walk, optionally reflected at bounds.

    The walk is generated once on the grid ``0, h, 2h, ..., duration`` with
    ``h = duration / ceil(duration / dt)`` (``h = dt`` when ``duration`` is a multiple
    of ``dt``) from ``numpy.random.default_rng(seed)``: it starts at ``initial`` and
    takes increments ``N(0, std_per_sqrt_s**2 h)``. Between grid points it is linearly
    interpolated; before 0 it holds ``initial`` and after ``duration`` its final value.
    The same seed gives the same walk whatever times it is evaluated at.

    Bounds: the free walk is *reflected* (folded back) into ``[lower, upper]``, like a
    ball bouncing off the walls, so it keeps moving along a bound instead of sticking
    to it as clipping would; either bound may be ``None`` (unbounded on that side).

    Parameters
    ----------
    initial
        Value at ``t = 0``; must lie within the bounds.
    std_per_sqrt_s
        Diffusion ``sigma`` (value units per sqrt(s)), ``>= 0``; the spread after
        ``T`` seconds (unbounded) is ``sigma sqrt(T)``.
    duration
        Length of the generated walk (s), > 0.
    seed
        Non-negative integer seed of :func:`numpy.random.default_rng`.
    dt
        Largest grid step (s), in ``(0, duration]``.
    lower, upper
        Optional reflecting bounds, ``lower < upper``.

    """

    kind: ClassVar[str] = "random_walk"
    initial: float
    std_per_sqrt_s: float
    duration: float
    seed: int
    dt: float = 0.01
    lower: float | None = None
    upper: float | None = None

    def __post_init__(self) -> None:
        _check_walk(self, "std_per_sqrt_s")

    @cached_property
    def grid(self) -> tuple[FloatArray, FloatArray]:
        """Generation grid times (s) and walk values there, both shape ``(n + 1,)``."""
        steps = _walk_steps(self)
        h = self.duration / steps
        rng = np.random.default_rng(self.seed)
        return _walk_grid(self, rng.normal(0.0, self.std_per_sqrt_s * math.sqrt(h), steps))

    def _evaluate(self, t: FloatArray) -> FloatArray:
        times, values = self.grid
        return np.interp(t, times, values)

    def describe(self) -> str:  # noqa: D102
        return (
            f"random walk(from {_g(self.initial)}, {_g(self.std_per_sqrt_s)}/sqrt(s), "
            f"seed {self.seed}{_describe_bounds(self)})"
        )


def _check_walk(walk: Any, spread: str) -> None:
    """Validate a walk's start, spread (>= 0), duration, seed, grid step and bounds."""
    object.__setattr__(walk, "initial", check_real("initial", walk.initial))
    object.__setattr__(walk, spread, check_positive(spread, getattr(walk, spread), allow_zero=True))
    object.__setattr__(walk, "duration", check_positive("duration", walk.duration))
    object.__setattr__(walk, "seed", check_int("seed", walk.seed, minimum=0))
    object.__setattr__(walk, "dt", check_positive("dt", walk.dt))
    if walk.dt > walk.duration:
        raise ValueError(f"dt must be <= duration = {walk.duration!r} s, got dt = {walk.dt!r}")
    for name in ("lower", "upper"):
        value = getattr(walk, name)
        if value is not None:
            object.__setattr__(walk, name, check_real(name, value))
    if walk.lower is not None and walk.upper is not None and walk.lower >= walk.upper:
        raise ValueError(f"upper must be > lower = {walk.lower!r}, got upper = {walk.upper!r}")
    if (walk.lower is not None and walk.initial < walk.lower) or (
        walk.upper is not None and walk.initial > walk.upper
    ):
        raise ValueError(f"initial must lie in [{walk.lower}, {walk.upper}], got {walk.initial!r}")


def _describe_bounds(walk: Any) -> str:
    if walk.lower is None and walk.upper is None:
        return ""
    low = "-inf" if walk.lower is None else _g(walk.lower)
    high = "inf" if walk.upper is None else _g(walk.upper)
    return f", in [{low}, {high}]"


def _walk_steps(walk: Any) -> int:
    """Grid steps of a walk: ``ceil(duration / dt)``, at least one."""
    return max(1, math.ceil(walk.duration / walk.dt - 1e-9))


def _walk_grid(walk: Any, increments: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Grid times and the walk summed from ``initial`` over ``increments``, reflected."""
    free = walk.initial + np.concatenate(([0.0], np.cumsum(increments)))
    times = np.linspace(0.0, walk.duration, increments.shape[0] + 1)
    values = _reflect(free, walk.lower, walk.upper)
    times.setflags(write=False)
    values.setflags(write=False)
    return times, values


def _reflect(x: FloatArray, lower: float | None, upper: float | None) -> FloatArray:
    """Fold the free walk ``x`` back into ``[lower, upper]`` (either bound may be None)."""
    if lower is not None and upper is not None:
        width = upper - lower
        folded = np.mod(x - lower, 2.0 * width)
        return lower + np.where(folded > width, 2.0 * width - folded, folded)
    if lower is not None:
        return lower + np.abs(x - lower)
    if upper is not None:
        return upper - np.abs(upper - x)
    return x


@dataclass(frozen=True)
class BandLimitedRandomWalk(Schedule):
    """Random walk with low-passed increments: Boer & Kenyon (1998), Sec. IV-A.

    ``x[0] = initial`` and ``x[j + 1] = x[j] + w[j]`` on the grid ``j h``, where the
    increments ``w`` are Gaussian noise through an ideal low-pass filter of cut-off
    ``cutoff_hz`` with standard deviation ``increment_std`` per step
    (:func:`~manualcontrol.envs.signals.band_limited_noise`, seeded by ``seed``). The
    increments change slowly, so the walk drifts smoothly, at a rate of about
    ``increment_std / h`` per second, instead of jittering like :class:`RandomWalk`.
    The paper's time-varying delay is this walk at ``h = 1/600`` s with
    ``increment_std`` 0.1 samples (1/6000 s) and ``cutoff_hz`` 0.3. The ideal filter
    keeps the zero-frequency bin, so a realisation may drift steadily one way.

    The grid step is ``h = duration / ceil(duration / dt)`` (``dt`` when it divides
    ``duration``); the walk is linear between grid points, ``initial`` before 0 and
    its last value after ``duration``. Optional ``lower``/``upper`` bounds reflect the
    walk as in :class:`RandomWalk` (a reflection reverses the rate abruptly).

    Parameters
    ----------
    initial
        Value at ``t = 0``, within the bounds.
    increment_std
        Standard deviation of one increment (value units per step), ``>= 0``.
    cutoff_hz
        Cut-off of the increments' low-pass filter (Hz), between ``1/duration`` and
        the Nyquist frequency ``1/(2 h)``.
    duration
        Length of the generated walk (s), > 0.
    seed
        Non-negative integer seed of :func:`numpy.random.default_rng`.
    dt
        Largest grid step (s), in ``(0, duration]``; default 1/600 s (the paper's).
    lower, upper
        Optional reflecting bounds, ``lower < upper``.

    """

    kind: ClassVar[str] = "band_limited_random_walk"
    initial: float
    increment_std: float
    cutoff_hz: float
    duration: float
    seed: int
    dt: float = 1.0 / 600.0
    lower: float | None = None
    upper: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "cutoff_hz", check_positive("cutoff_hz", self.cutoff_hz))
        _check_walk(self, "increment_std")
        h = self.duration / _walk_steps(self)
        if not 1.0 / self.duration <= self.cutoff_hz <= 0.5 / h:
            raise ValueError(
                f"cutoff_hz must lie in [{1.0 / self.duration:g}, {0.5 / h:g}] Hz (from one "
                f"cycle per duration to the Nyquist frequency of the grid), got {self.cutoff_hz!r}"
            )

    @cached_property
    def grid(self) -> tuple[FloatArray, FloatArray]:
        """Generation grid times (s) and walk values there, both shape ``(n + 1,)``."""
        from manualcontrol.envs.signals import band_limited_noise

        steps = _walk_steps(self)
        h = self.duration / steps
        if steps < 2 or self.increment_std == 0.0:
            return _walk_grid(self, np.zeros(steps))
        rng = np.random.default_rng(self.seed)
        return _walk_grid(
            self, band_limited_noise(steps, h, self.cutoff_hz, self.increment_std, rng)
        )

    def _evaluate(self, t: FloatArray) -> FloatArray:
        times, values = self.grid
        return np.interp(t, times, values)

    def describe(self) -> str:  # noqa: D102
        return (
            f"band-limited random walk(from {_g(self.initial)}, {_g(self.increment_std)} per "
            f"step of {_g(self.duration / _walk_steps(self))} s below {_g(self.cutoff_hz)} Hz, "
            f"seed {self.seed}{_describe_bounds(self)})"
        )


@dataclass(frozen=True, init=False)
class Sum(Schedule):
    """Pointwise sum of schedules, e.g. ``Sigmoid(...) + Sine(...)``.

    ``terms`` accepts schedules and numbers (read as :class:`Constant`); nested sums
    are flattened. At least one term is required.
    """

    kind: ClassVar[str] = "sum"
    terms: tuple[Schedule, ...]

    def __init__(self, terms: Iterable[Schedule | float]) -> None:
        if isinstance(terms, Schedule) or not isinstance(terms, Iterable):
            raise TypeError(f"terms must be an iterable of schedules, got {terms!r}")
        flat: list[Schedule] = []
        for term in terms:
            schedule = as_schedule(term)
            flat.extend(schedule.terms if isinstance(schedule, Sum) else (schedule,))
        if not flat:
            raise ValueError("terms must hold at least one schedule, got none")
        object.__setattr__(self, "terms", tuple(flat))

    @property
    def is_constant(self) -> bool:  # noqa: D102
        return all(term.is_constant for term in self.terms)

    def _evaluate(self, t: FloatArray) -> FloatArray:
        total = self.terms[0]._evaluate(t)
        for term in self.terms[1:]:
            total = total + term._evaluate(t)
        return total

    def describe(self) -> str:  # noqa: D102
        return " + ".join(term.describe() for term in self.terms)

    def to_dict(self) -> dict[str, Any]:  # noqa: D102
        return {"kind": self.kind, "terms": [term.to_dict() for term in self.terms]}

    @classmethod
    def _from_fields(cls, data: dict[str, Any]) -> Sum:
        return cls([Schedule.from_dict(term) for term in data["terms"]])


@dataclass(frozen=True, init=False)
class Sequence(Schedule):
    """Schedules one after another in time.

    ``segments`` is a sequence of ``(t_start, schedule)`` pairs with strictly
    increasing ``t_start``: schedule ``i`` applies for ``t_start_i <= t < t_start_{i+1}``,
    the first one also before its start and the last one ever after. Each schedule sees
    absolute time (a :class:`Sigmoid` inside keeps its own ``t_mid``). Numbers are read
    as :class:`Constant`.
    """

    kind: ClassVar[str] = "sequence"
    segments: tuple[tuple[float, Schedule], ...]

    def __init__(self, segments: Iterable[tuple[float, Schedule | float]]) -> None:
        checked: list[tuple[float, Schedule]] = []
        for index, segment in enumerate(segments):
            if not isinstance(segment, (tuple, list)) or len(segment) != 2:
                raise TypeError(
                    f"segments[{index}] must be a (t_start, schedule) pair, got {segment!r}"
                )
            t_start = check_real(f"segments[{index}] t_start", segment[0])
            if checked and t_start <= checked[-1][0]:
                raise ValueError(
                    f"segments[{index}] t_start must be > {checked[-1][0]!r} (the start of "
                    f"segments[{index - 1}]; starts must strictly increase), got {t_start!r}"
                )
            checked.append((t_start, as_schedule(segment[1])))
        if not checked:
            raise ValueError("segments must hold at least one (t_start, schedule) pair, got none")
        object.__setattr__(self, "segments", tuple(checked))

    def _evaluate(self, t: FloatArray) -> FloatArray:
        starts = np.array([start for start, _ in self.segments])
        which = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, None)
        out = np.empty_like(t)
        for index, (_, schedule) in enumerate(self.segments):
            mask = which == index
            if mask.any():
                out[mask] = schedule._evaluate(t[mask])
        return out

    def describe(self) -> str:  # noqa: D102
        parts = "; ".join(f"from {_g(start)} s: {s.describe()}" for start, s in self.segments)
        return f"sequence({parts})"

    def to_dict(self) -> dict[str, Any]:  # noqa: D102
        return {
            "kind": self.kind,
            "segments": [
                {"t_start": start, "schedule": schedule.to_dict()}
                for start, schedule in self.segments
            ],
        }

    @classmethod
    def _from_fields(cls, data: dict[str, Any]) -> Sequence:
        segments = []
        for index, segment in enumerate(data["segments"]):
            if not isinstance(segment, Mapping):
                raise TypeError(
                    f"Sequence.from_dict segments[{index}] must be a dict with keys "
                    f"'t_start' and 'schedule', got {segment!r}"
                )
            where = f"Sequence.from_dict segments[{index}]"
            reject_unknown(where, segment, ("t_start", "schedule"))
            if "t_start" not in segment or "schedule" not in segment:
                raise TypeError(f"{where} needs keys 't_start' and 'schedule', got {segment!r}")
            segments.append((segment["t_start"], Schedule.from_dict(segment["schedule"])))
        return cls(segments)


def as_schedule(value: Schedule | float) -> Schedule:
    """Return ``value`` as a schedule: numbers become :class:`Constant`, schedules pass.

    Raises ``TypeError`` naming the value for anything else (strings, arrays, None).
    """
    if isinstance(value, Schedule):
        return value
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return Constant(value)
    raise TypeError(f"a schedule or a real number is required, got {value!r}")


_KINDS: dict[str, type[Schedule]] = {
    cls.kind: cls
    for cls in (
        Constant,
        Sigmoid,
        Sine,
        Step,
        Ramp,
        RandomWalk,
        BandLimitedRandomWalk,
        Sum,
        Sequence,
    )
}
