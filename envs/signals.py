"""Forcing functions: the target and disturbance signals a tracking task is driven by.

Time in seconds, frequencies in rad/s, float64 throughout.

* :class:`Multisine` -- ``f(t) = Σ A_i sin(ω_i t + φ_i)`` (thesis Part I eq. 35), with
  analytic derivative, variance and crest factor; periodic over its measurement time
  ``T_m`` when every ``ω_i`` is an integer multiple of ``2π/T_m``.
* Design: :func:`multisine_frequencies` (log-spread harmonics), :func:`amplitude_profile`
  (TU Delft low-pass shaping), :func:`design_multisine`, :func:`realisations`
  (random-phase candidates selected by crest factor, thesis App. H.4.4) and
  :func:`interleaved_harmonics` (disturbance on harmonics adjacent to the target's,
  thesis Sec. IV-B).
* :class:`ForcingPair` -- a target and a disturbance (multisines or band-limited noise)
  that belong together.
* :class:`SampledSignal` -- a forcing function given as samples, read with bicubic
  interpolation (Boer & Kenyon 1998, Appendix).
* :func:`band_limited_noise` -- ideal FFT low-pass of Gaussian noise (Boer & Kenyon
  1998, Sec. IV-A), and :class:`BandLimitedNoise`, a seeded forcing function made of it.
* Presets: :func:`forcing_preset` by name, see :data:`FORCING_PRESETS`.

Anything with ``__call__(t)`` and ``derivative(t)`` is a :class:`ForcingFunction`.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.resources
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._validation import (
    check_choice,
    check_int,
    check_positive,
    check_range,
    check_real,
    check_times,
    check_vector,
    reject_unknown,
)

__all__ = [
    "FORCING_PRESETS",
    "BandLimitedNoise",
    "ForcingFunction",
    "ForcingPair",
    "Multisine",
    "SampledSignal",
    "amplitude_profile",
    "band_limited_noise",
    "design_multisine",
    "forcing_preset",
    "interleaved_harmonics",
    "multisine_frequencies",
    "preset_realisation_count",
    "realisations",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def __getattr__(name: str) -> object:
    """``interpolate_many``, the numba kernel, imported on first use (PEP 562).

    A sampled signal reads itself through it; the other forcing functions never do, so
    a process that uses them alone never imports numba.
    """
    if name == "interpolate_many":
        from manualcontrol.envs._interpolation import interpolate_many

        globals()[name] = interpolate_many
        return interpolate_many
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: Harmonic numbers ``ω T_m / 2π`` must be this close to integers.
_HARMONIC_TOLERANCE = 1e-6
#: Multisine evaluations on at least ``_REMEMBERED_LENGTH[0]`` and at most
#: ``_REMEMBERED_LENGTH[1]`` times are remembered, the last ``_REMEMBERED_EVALUATIONS``
#: of them (keyed by the signal and the exact times; at most about 19 MB): a benchmark run
#: evaluates its forcing on the same grids six to eight times, each a sine per component
#: and sample (about a twentieth of the run), and the runs of a batch share them.
_REMEMBERED_LENGTH = (1024, 100_000)
_REMEMBERED_EVALUATIONS = 12
_EVALUATIONS: dict[tuple[Any, ...], tuple[FloatArray, FloatArray]] = {}


# ------------------------------------------------------------------------- helpers


@runtime_checkable
class ForcingFunction(Protocol):
    """Anything usable as a forcing function: value and time derivative at time ``t``.

    Both take a scalar time (s) and return a ``float``, or an array of times and
    return a float64 array of the same shape.
    """

    def __call__(self, t: ArrayLike) -> float | FloatArray:
        """Value at time(s) ``t``."""
        ...

    def derivative(self, t: ArrayLike) -> float | FloatArray:
        """Time derivative (per second) at time(s) ``t``."""
        ...


def _scalar_or_array(times: FloatArray, values: FloatArray) -> float | FloatArray:
    return float(values) if times.ndim == 0 else values


def _frozen(name: str, value: Any, *, length: int | None = None) -> FloatArray:
    """A read-only float64 copy of a finite 1-D array; lengths compared to frequencies."""
    array = np.array(check_vector(name, value, min_length=1), dtype=np.float64, copy=True)
    if length is not None and array.shape[0] != length:
        raise ValueError(
            f"{name} must have one entry per frequency ({length}), got length {array.shape[0]}"
        )
    array.setflags(write=False)
    return array


def _check_rng(rng: Any) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"rng must be a numpy.random.Generator (numpy.random.default_rng(seed)), got {rng!r}"
        )
    return rng


def _time_grid(duration: float, dt: float, t0: float) -> FloatArray:
    """``t0 + k dt`` for ``k = 0 .. round(duration / dt) - 1``."""
    duration = check_positive("duration", duration)
    dt = check_positive("dt", dt)
    t0 = check_real("t0", t0)
    n = round(duration / dt)
    if n < 1:
        raise ValueError(f"duration must hold at least one sample of dt = {dt!r}, got {duration!r}")
    return t0 + np.arange(n) * dt


# ----------------------------------------------------------------------- multisine


@dataclass(frozen=True, eq=False)
class Multisine:
    """Sum of sines ``f(t) = Σ A_i sin(ω_i t + φ_i)`` (thesis Part I eq. 35).

    Parameters
    ----------
    frequencies
        ``ω_i`` (rad/s), > 0 and distinct, shape ``(n,)``.
    amplitudes
        ``A_i``, >= 0, shape ``(n,)``.
    phases
        ``φ_i`` (rad), shape ``(n,)``.
    measurement_time
        ``T_m`` (s), > 0, or None. When given, every ``ω_i`` must be an integer multiple
        ``n_i 2π / T_m`` (within 1e-6 in ``n_i``), so the signal repeats every ``T_m``.

    The arrays are stored as read-only float64 copies; equality and hashing compare
    their values, so a multisine can be a dict key or a cached preset.

    """

    frequencies: FloatArray
    amplitudes: FloatArray
    phases: FloatArray
    measurement_time: float | None = None

    def __post_init__(self) -> None:
        frequencies = _frozen("frequencies", self.frequencies)
        n = frequencies.shape[0]
        amplitudes = _frozen("amplitudes", self.amplitudes, length=n)
        phases = _frozen("phases", self.phases, length=n)
        if np.any(frequencies <= 0.0):
            index = int(np.flatnonzero(frequencies <= 0.0)[0])
            raise ValueError(
                f"frequencies must be > 0 rad/s, got {float(frequencies[index])!r} at index {index}"
            )
        values, counts = np.unique(frequencies, return_counts=True)
        if np.any(counts > 1):
            repeated = float(values[counts > 1][0])
            raise ValueError(f"frequencies must be distinct, got {repeated!r} rad/s more than once")
        if np.any(amplitudes < 0.0):
            index = int(np.flatnonzero(amplitudes < 0.0)[0])
            raise ValueError(
                f"amplitudes must be >= 0 (shift the phase by pi instead), "
                f"got {float(amplitudes[index])!r} at index {index}"
            )
        object.__setattr__(self, "frequencies", frequencies)
        object.__setattr__(self, "amplitudes", amplitudes)
        object.__setattr__(self, "phases", phases)
        if self.measurement_time is not None:
            measurement_time = check_positive("measurement_time", self.measurement_time)
            object.__setattr__(self, "measurement_time", measurement_time)
            ratio = frequencies * measurement_time / (2.0 * np.pi)
            off = np.abs(ratio - np.rint(ratio)) > _HARMONIC_TOLERANCE
            if off.any():
                index = int(np.flatnonzero(off)[0])
                raise ValueError(
                    f"frequencies must be integer multiples of 2*pi/measurement_time = "
                    f"{2.0 * np.pi / measurement_time:.6g} rad/s (measurement_time "
                    f"{measurement_time!r} s); frequency {float(frequencies[index])!r} rad/s at "
                    f"index {index} is {ratio[index]:.6f} times that"
                )

    @classmethod
    def sine(cls, amplitude: float, frequency: float, phase: float = 0.0) -> Multisine:
        """A single sine ``amplitude sin(frequency t + phase)``, periodic over ``2π/frequency``."""
        frequency = check_positive("frequency", frequency)
        return cls([frequency], [amplitude], [phase], measurement_time=2.0 * np.pi / frequency)

    # -- evaluation

    def _series(self, t: FloatArray, weights: FloatArray, wave: np.ufunc) -> FloatArray:
        if not _REMEMBERED_LENGTH[0] <= t.size <= _REMEMBERED_LENGTH[1]:
            return self._sum(t, weights, wave)
        # the same forcing at the same times: a run's simulation, its filter and its
        # scoring each evaluate it, and so does every run of a batch
        key = (
            wave.__name__,
            self.frequencies.tobytes(),
            weights.tobytes(),
            self.phases.tobytes(),
            t.shape,
            float(t.flat[0]),
            float(t.flat[t.size // 2]),
            float(t.flat[-1]),
        )
        kept = _EVALUATIONS.pop(key, None)
        if kept is None or not np.array_equal(kept[0], t):  # only the very same times
            kept = (t.copy(), self._sum(t, weights, wave))
            while len(_EVALUATIONS) >= _REMEMBERED_EVALUATIONS:
                _EVALUATIONS.pop(next(iter(_EVALUATIONS)), None)
        _EVALUATIONS[key] = kept  # the most recently used last
        return kept[1].copy()

    def _sum(self, t: FloatArray, weights: FloatArray, wave: np.ufunc) -> FloatArray:
        # One sine at a time: memory O(len(t)), never an (n_times, n_sines) matrix.
        out = np.zeros_like(t)
        work = np.empty_like(t)
        for omega, weight, phase in zip(self.frequencies, weights, self.phases, strict=True):
            np.multiply(t, omega, out=work)
            work += phase
            wave(work, out=work)
            work *= weight
            out += work
        return out

    def __call__(self, t: ArrayLike) -> float | FloatArray:
        """``f(t)`` at a scalar time or an array of times (s), eq. 35."""
        times = check_times(t)
        return _scalar_or_array(times, self._series(times, self.amplitudes, np.sin))

    def derivative(self, t: ArrayLike) -> float | FloatArray:
        """Analytic time derivative ``Σ A_i ω_i cos(ω_i t + φ_i)``."""
        times = check_times(t)
        weights = self.amplitudes * self.frequencies
        return _scalar_or_array(times, self._series(times, weights, np.cos))

    def sample(self, duration: float, dt: float, t0: float = 0.0) -> FloatArray:
        """Values at ``t0 + k dt``, ``k = 0 .. round(duration / dt) - 1``."""
        return self._series(_time_grid(duration, dt, t0), self.amplitudes, np.sin)

    # -- properties

    @property
    def variance(self) -> float:
        """Power ``Σ A_i² / 2``: the variance over one period (distinct frequencies)."""
        return float(np.sum(self.amplitudes**2) / 2.0)

    @property
    def harmonics(self) -> IntArray:
        """Integer multiples ``n_i = ω_i T_m / 2π`` of the base frequency.

        Raises ``ValueError`` when the multisine has no ``measurement_time``.
        """
        if self.measurement_time is None:
            raise ValueError("harmonics need a measurement_time; this Multisine has None")
        ratio = self.frequencies * self.measurement_time / (2.0 * np.pi)
        harmonics = np.rint(ratio).astype(np.int64)
        harmonics.setflags(write=False)
        return harmonics

    def _duration_or_period(self, duration: float | None, what: str) -> float:
        if duration is not None:
            return check_positive("duration", duration)
        if self.measurement_time is None:
            raise ValueError(f"{what} needs a duration when measurement_time is None")
        return self.measurement_time

    def crest_factor(self, dt: float = 0.01, duration: float | None = None) -> float:
        """``max |f| / rms(f)`` of the samples over one period ``T_m`` (or ``duration``).

        The ratio of the forcing function's maximum and root mean square used to select
        realisations (thesis App. H.4.4); a lower crest factor means fewer peaks.
        """
        samples = self.sample(self._duration_or_period(duration, "crest_factor"), dt)
        rms = math.sqrt(float(np.mean(samples**2)))
        if rms == 0.0:
            raise ValueError("crest_factor is undefined for a signal that is zero everywhere")
        return float(np.max(np.abs(samples))) / rms

    # -- variants

    def with_phases(self, phases: ArrayLike) -> Multisine:
        """The same frequencies and amplitudes with other phases (rad)."""
        return dataclasses.replace(self, phases=phases)

    def scaled_to_variance(self, variance: float) -> Multisine:
        """Amplitudes scaled by one factor so that :attr:`variance` equals ``variance`` (> 0)."""
        variance = check_positive("variance", variance)
        if self.variance == 0.0:
            raise ValueError("scaled_to_variance needs a non-zero amplitude; all are 0")
        factor = math.sqrt(variance / self.variance)
        return dataclasses.replace(self, amplitudes=self.amplitudes * factor)

    # -- identity and saving

    def _key(self) -> tuple[Any, ...]:
        return (
            tuple(self.frequencies.tolist()),
            tuple(self.amplitudes.tolist()),
            tuple(self.phases.tolist()),
            self.measurement_time,
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Multisine):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __reduce__(self) -> tuple[Any, ...]:
        return (
            type(self),
            (self.frequencies, self.amplitudes, self.phases, self.measurement_time),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description; :meth:`from_dict` rebuilds an equal multisine."""
        return {
            "kind": "multisine",
            "frequencies": self.frequencies.tolist(),
            "amplitudes": self.amplitudes.tolist(),
            "phases": self.phases.tolist(),
            "measurement_time": self.measurement_time,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Multisine:
        """Inverse of :meth:`to_dict`; unknown keys or another ``kind`` raise."""
        items = dict(data)
        check_choice("Multisine.from_dict kind", items.pop("kind", None), ("multisine",))
        reject_unknown(
            "Multisine.from_dict",
            items,
            ("frequencies", "amplitudes", "phases", "measurement_time"),
        )
        return cls(
            items["frequencies"],
            items["amplitudes"],
            items["phases"],
            items.get("measurement_time"),
        )


# -------------------------------------------------------------------------- design


def _band_harmonics(measurement_time: float, low: float, high: float) -> tuple[float, int, int]:
    """Base frequency and the first and last harmonic inside ``[low, high]`` rad/s."""
    measurement_time = check_positive("measurement_time", measurement_time)
    low = check_positive("low", low)
    high = check_positive("high", high)
    if high <= low:
        raise ValueError(f"high must be > low = {low!r} rad/s, got high = {high!r}")
    base = 2.0 * np.pi / measurement_time
    first = max(1, math.ceil(low / base - _HARMONIC_TOLERANCE))
    last = math.floor(high / base + _HARMONIC_TOLERANCE)
    return base, first, last


def _spread(n_sines: int, first: int, last: int, gap: int) -> IntArray:
    """``n_sines`` integers in ``[first, last]``, near-geometric, consecutive ones >= gap apart."""
    harmonics = np.rint(np.geomspace(first, last, n_sines)).astype(np.int64)
    for i in range(1, n_sines):  # push up to keep the gaps ...
        harmonics[i] = max(harmonics[i], harmonics[i - 1] + gap)
    harmonics[-1] = min(harmonics[-1], last)
    for i in range(n_sines - 2, -1, -1):  # ... and back down below ``last``
        harmonics[i] = min(harmonics[i], harmonics[i + 1] - gap)
    return harmonics


def _log_harmonics(
    n_sines: int, measurement_time: float, low: float, high: float, *, gap: int, reserve: int
) -> IntArray:
    n_sines = check_int("n_sines", n_sines, minimum=1)
    base, first, last = _band_harmonics(measurement_time, low, high)
    last -= reserve
    if first + (n_sines - 1) * gap > last:
        raise ValueError(
            f"cannot place {n_sines} harmonics of 2*pi/measurement_time = {base:.6g} rad/s "
            f"between low = {low!r} and high = {high!r} rad/s (harmonics {first} to "
            f"{last + reserve}); widen the band, lengthen measurement_time or use fewer sines"
        )
    return _spread(n_sines, first, last, gap)


def multisine_frequencies(
    n_sines: int, measurement_time: float, low: float, high: float
) -> FloatArray:
    """Distinct integer multiples of ``2π/T_m`` spread roughly logarithmically in a band.

    Parameters
    ----------
    n_sines
        Number of frequencies, >= 1.
    measurement_time
        ``T_m`` (s), > 0.
    low, high
        Band edges (rad/s), ``0 < low < high``; every frequency lies inside.

    Returns
    -------
    ndarray
        ``n_i 2π / T_m`` (rad/s), increasing, shape ``(n_sines,)``; ``n_i`` are the
        geometric sequence from the first to the last harmonic in the band, rounded and
        nudged apart where rounding would merge neighbours.

    """
    harmonics = _log_harmonics(n_sines, measurement_time, low, high, gap=1, reserve=0)
    return harmonics * (2.0 * np.pi / measurement_time)


def interleaved_harmonics(
    n_sines: int, measurement_time: float, low: float, high: float
) -> tuple[IntArray, IntArray]:
    """Target and disturbance harmonics on adjacent, non-overlapping integers.

    The disturbance is "built up of frequencies adjacent to those in the target"
    (thesis Part I Sec. IV-B): the target takes a log spread of harmonics at least two
    apart and each disturbance harmonic is the next integer above a target harmonic, so
    the two interleave ``t_1 < d_1 < t_2 < d_2 < ...`` and every frequency lies in
    ``[low, high]``.

    Returns
    -------
    target, disturbance
        Integer arrays of shape ``(n_sines,)``; ``disturbance = target + 1``.

    """
    target = _log_harmonics(n_sines, measurement_time, low, high, gap=2, reserve=1)
    return target, target + 1


def amplitude_profile(
    frequencies: ArrayLike, bandwidth: float, lead_frequency: float = 10.0
) -> FloatArray:
    """Low-pass amplitude shaping of TU Delft forcing functions.

    ``|(1 + jω/ω_lead)² / (1 + jω/ω_b)²| = (1 + (ω/ω_lead)²) / (1 + (ω/ω_b)²)``: flat
    below the bandwidth ``ω_b``, falling 40 dB/decade above it and levelling off again
    above ``ω_lead``, which keeps the high-frequency sines measurable. The Plaetinck
    et al. (2018) table follows it with ``ω_b = 1.25`` rad/s, ``ω_lead = 10`` rad/s.

    Parameters
    ----------
    frequencies
        ``ω`` (rad/s), >= 0, 1-D.
    bandwidth, lead_frequency
        ``ω_b`` and ``ω_lead`` (rad/s), > 0.

    """
    omega = check_vector("frequencies", frequencies)
    if np.any(omega < 0.0):
        raise ValueError(f"frequencies must be >= 0 rad/s, got minimum {float(omega.min())!r}")
    bandwidth = check_positive("bandwidth", bandwidth)
    lead_frequency = check_positive("lead_frequency", lead_frequency)
    return (1.0 + (omega / lead_frequency) ** 2) / (1.0 + (omega / bandwidth) ** 2)


def design_multisine(
    n_sines: int,
    measurement_time: float,
    bandwidth: float,
    variance: float,
    low: float,
    high: float,
    rng: np.random.Generator,
    harmonics: ArrayLike | None = None,
    lead_frequency: float = 10.0,
) -> Multisine:
    """A multisine with shaped amplitudes, scaled variance and uniform random phases.

    Parameters
    ----------
    n_sines
        Number of sines, >= 1.
    measurement_time
        ``T_m`` (s): every frequency is an integer multiple of ``2π/T_m``.
    bandwidth, lead_frequency
        Shape of :func:`amplitude_profile` (rad/s).
    variance
        Power ``Σ A_i²/2`` of the result, > 0.
    low, high
        Band (rad/s) for the log spread of :func:`multisine_frequencies`.
    rng
        Source of the phases, drawn uniformly in ``[0, 2π)``.
    harmonics
        Explicit integer multiples to use instead of the log spread (e.g. from
        :func:`interleaved_harmonics`): ``n_sines`` distinct positive integers whose
        frequencies lie in ``[low, high]``.

    """
    rng = _check_rng(rng)
    n_sines = check_int("n_sines", n_sines, minimum=1)
    variance = check_positive("variance", variance)
    if harmonics is None:
        frequencies = multisine_frequencies(n_sines, measurement_time, low, high)
    else:
        base, first, last = _band_harmonics(measurement_time, low, high)
        given = check_vector("harmonics", harmonics, length=n_sines)
        if np.any(given != np.rint(given)) or np.any(given < first) or np.any(given > last):
            raise ValueError(
                f"harmonics must be integers in [{first}, {last}] (the band [{low!r}, {high!r}] "
                f"rad/s), got {given.tolist()}"
            )
        frequencies = given * base
    amplitudes = amplitude_profile(frequencies, bandwidth, lead_frequency)
    phases = rng.uniform(0.0, 2.0 * np.pi, n_sines)
    shaped = Multisine(frequencies, amplitudes, phases, measurement_time)
    return shaped.scaled_to_variance(variance)


def realisations(
    base: Multisine,
    n: int,
    rng: np.random.Generator,
    n_candidates: int = 500,
    select: str | float = "lowest",
    dt: float = 0.05,
    duration: float | None = None,
) -> list[Multisine]:
    """Equivalent realisations of ``base``: same frequencies and amplitudes, new phases.

    Thesis App. H.4.4 (``MakeFoFu``): draw ``n_candidates`` sets of uniform random phases,
    compute each candidate's crest factor ``max|f| / rms(f)`` and keep ``n`` of them.
    The crest factors come from one vectorised evaluation on a coarse grid (``dt``) over
    one period, ``f = sin(ωt) (A cos φ) + cos(ωt) (A sin φ)`` for all candidates at once.

    Parameters
    ----------
    base
        Frequencies, amplitudes and measurement time to keep; its phases are ignored.
    n
        Number of realisations to return, ``1 <= n <= n_candidates``.
    rng
        Source of the candidate phases.
    n_candidates
        Number of random-phase candidates to choose from, >= ``n``.
    select
        ``"lowest"`` keeps the ``n`` lowest crest factors; a number (>= 1) keeps the ``n``
        closest to that target crest factor.
    dt
        Grid step (s) of the crest-factor evaluation.
    duration
        Evaluation length (s); defaults to ``base.measurement_time``.

    Returns
    -------
    list of Multisine
        Ordered by selection rank (lowest or closest crest factor first).

    """
    if not isinstance(base, Multisine):
        raise TypeError(f"base must be a Multisine, got {base!r}")
    rng = _check_rng(rng)
    n = check_int("n", n, minimum=1)
    n_candidates = check_int("n_candidates", n_candidates, minimum=n)
    if isinstance(select, str):
        check_choice("select", select, ("lowest",))
        target = None
    else:
        target = check_range("select (target crest factor)", select, 1.0)
    times = _time_grid(base._duration_or_period(duration, "realisations"), dt, 0.0)
    phases = rng.uniform(0.0, 2.0 * np.pi, (n_candidates, base.frequencies.shape[0]))
    angle = np.outer(times, base.frequencies)
    signals = np.sin(angle) @ (base.amplitudes * np.cos(phases)).T
    signals += np.cos(angle) @ (base.amplitudes * np.sin(phases)).T
    rms = np.sqrt(np.mean(signals**2, axis=0))
    if np.any(rms == 0.0):
        raise ValueError("realisations need a base with a non-zero amplitude; all are 0")
    crest = np.max(np.abs(signals), axis=0) / rms
    score = crest if target is None else np.abs(crest - target)
    order = np.argsort(score, kind="stable")[:n]
    return [base.with_phases(phases[i]) for i in order]


# --------------------------------------------------------------------- forcing pair


@dataclass(frozen=True)
class ForcingPair:
    """The target and disturbance forcing functions of one tracking run.

    Parameters
    ----------
    target
        ``ft``, the signal the controlled element should follow, or None (zero): a
        :class:`Multisine` or a :class:`BandLimitedNoise`.
    disturbance
        ``fd``, added at the controlled-element output, or None (zero); the same kinds.
    name
        Preset or design name, for logs and saved results.
    realisation
        Index of the phase realisation, >= 0.

    """

    target: Multisine | BandLimitedNoise | None
    disturbance: Multisine | BandLimitedNoise | None
    name: str = "custom"
    realisation: int = 0

    def __post_init__(self) -> None:
        for field in ("target", "disturbance"):
            value = getattr(self, field)
            if value is not None and not isinstance(value, (Multisine, BandLimitedNoise)):
                raise TypeError(
                    f"{field} must be a Multisine, a BandLimitedNoise or None, got {value!r}"
                )
        if not isinstance(self.name, str) or not self.name:
            raise TypeError(f"name must be a non-empty string, got {self.name!r}")
        object.__setattr__(
            self, "realisation", check_int("realisation", self.realisation, minimum=0)
        )

    def sample(self, duration: float, dt: float, t0: float = 0.0) -> tuple[FloatArray, FloatArray]:
        """``(ft, fd)`` at ``t0 + k dt``, ``k = 0 .. round(duration / dt) - 1``; zeros if absent."""
        times = _time_grid(duration, dt, t0)
        ft = np.zeros_like(times) if self.target is None else self.target(times)
        fd = np.zeros_like(times) if self.disturbance is None else self.disturbance(times)
        return ft, fd

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description; :meth:`from_dict` rebuilds an equal pair."""
        return {
            "kind": "forcing_pair",
            "name": self.name,
            "realisation": self.realisation,
            "target": None if self.target is None else self.target.to_dict(),
            "disturbance": None if self.disturbance is None else self.disturbance.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ForcingPair:
        """Inverse of :meth:`to_dict`; unknown keys or another ``kind`` raise."""
        items = dict(data)
        check_choice("ForcingPair.from_dict kind", items.pop("kind", None), ("forcing_pair",))
        reject_unknown(
            "ForcingPair.from_dict", items, ("name", "realisation", "target", "disturbance")
        )

        def signal(key: str) -> Multisine | BandLimitedNoise | None:
            value = items.get(key)
            if value is None:
                return None
            if isinstance(value, Mapping) and value.get("kind") == BandLimitedNoise.kind:
                return BandLimitedNoise.from_dict(value)
            return Multisine.from_dict(value)

        return cls(
            signal("target"),
            signal("disturbance"),
            items.get("name", "custom"),
            items.get("realisation", 0),
        )


# ------------------------------------------------------------------ sampled signal


@dataclass(frozen=True, eq=False)
class SampledSignal:
    """A forcing function given as samples ``values[k]`` at ``t0 + k dt``.

    Values and derivatives between samples come from the four-sample bicubic kernel
    of Boer & Kenyon (1998, Appendix), accurate to third order in ``dt`` for smooth
    signals. ``periodic=True`` treats the samples as one period of length
    ``len(values) dt`` (``values[0]`` follows ``values[-1]``) and wraps any time into it;
    otherwise times before the first or after the last sample read the end value with
    zero derivative, and the kernel repeats the end samples near the ends.

    Parameters
    ----------
    values
        Finite samples, shape ``(n,)``, ``n >= 2``; stored as a read-only copy.
    dt
        Sample time (s), > 0.
    t0
        Time of ``values[0]`` (s).
    periodic
        Wrap around the period ``n dt`` instead of clamping at the ends.

    """

    values: FloatArray
    dt: float
    t0: float = 0.0
    periodic: bool = False

    def __post_init__(self) -> None:
        values = np.array(check_vector("values", self.values, min_length=2), copy=True)
        values.setflags(write=False)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "dt", check_positive("dt", self.dt))
        object.__setattr__(self, "t0", check_real("t0", self.t0))
        if not isinstance(self.periodic, (bool, np.bool_)):
            raise TypeError(f"periodic must be True or False, got {self.periodic!r}")
        object.__setattr__(self, "periodic", bool(self.periodic))

    @functools.cached_property
    def _padded(self) -> FloatArray:
        # Periodic: one sample of the previous period before, two of the next after,
        # so the kernel's neighbours n-1 .. n+2 always exist at position p + 1.
        if self.periodic:
            return np.concatenate((self.values[-1:], self.values, self.values[:2]))
        return np.ascontiguousarray(self.values)

    def _interpolate(self, t: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        times = check_times(t)
        positions = (times.ravel() - self.t0) / self.dt
        if self.periodic:
            positions = np.mod(positions, self.values.shape[0]) + 1.0
        from manualcontrol.envs._interpolation import interpolate_many

        values, slopes = interpolate_many(self._padded, np.ascontiguousarray(positions))
        return times, values.reshape(times.shape), slopes.reshape(times.shape)

    def __call__(self, t: ArrayLike) -> float | FloatArray:
        """Interpolated value at time(s) ``t`` (s)."""
        times, values, _ = self._interpolate(t)
        return _scalar_or_array(times, values)

    def derivative(self, t: ArrayLike) -> float | FloatArray:
        """Time derivative (per second) of the interpolant at time(s) ``t``."""
        times, _, slopes = self._interpolate(t)
        return _scalar_or_array(times, slopes / self.dt)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, SampledSignal):
            return NotImplemented
        return (self.dt, self.t0, self.periodic) == (other.dt, other.t0, other.periodic) and (
            np.array_equal(self.values, other.values)
        )

    def __hash__(self) -> int:
        return hash((tuple(self.values.tolist()), self.dt, self.t0, self.periodic))

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (self.values, self.dt, self.t0, self.periodic))


# ---------------------------------------------------------------------- noise


def band_limited_noise(
    n_samples: int, dt: float, cutoff_hz: float, std: float, rng: np.random.Generator
) -> FloatArray:
    """Gaussian noise through an ideal low-pass filter (Boer & Kenyon 1998, Sec. IV-A).

    White Gaussian samples are transformed with :func:`numpy.fft.rfft`, every bin above
    ``cutoff_hz`` is set to zero, the result is transformed back and scaled so that its
    sample standard deviation (``ddof=0``) is exactly ``std``. The DC bin lies in the
    pass band, so the sample mean is not removed.

    Parameters
    ----------
    n_samples
        Length, >= 2.
    dt
        Sample time (s), > 0.
    cutoff_hz
        Cut-off frequency (Hz), from the frequency resolution ``1 / (n_samples dt)`` up
        to the Nyquist frequency ``1 / (2 dt)``.
    std
        Standard deviation of the result, >= 0.
    rng
        Source of the white noise.

    """
    n_samples = check_int("n_samples", n_samples, minimum=2)
    dt = check_positive("dt", dt)
    cutoff_hz = check_range("cutoff_hz", cutoff_hz, 1.0 / (n_samples * dt), 0.5 / dt)
    std = check_positive("std", std, allow_zero=True)
    rng = _check_rng(rng)
    spectrum = np.fft.rfft(rng.standard_normal(n_samples))
    spectrum[np.fft.rfftfreq(n_samples, dt) > cutoff_hz] = 0.0
    noise = np.fft.irfft(spectrum, n_samples)
    return noise * (std / np.std(noise))


@dataclass(frozen=True, eq=False)
class BandLimitedNoise:
    """A forcing function of seeded band-limited Gaussian noise, periodic over ``duration``.

    One realisation of :func:`band_limited_noise` (ideal FFT low-pass, Boer & Kenyon
    1998, Sec. IV-A) on the grid ``k dt``, ``k = 0 .. round(duration/dt) - 1``, drawn
    from ``numpy.random.default_rng(seed)``. The inverse FFT makes the samples one period
    of a periodic signal, so the noise repeats every ``duration`` without a jump and is
    read at any time, and differentiated, by the periodic bicubic interpolation of
    :class:`SampledSignal` (exact at the grid points). Its variance over one period is
    exactly ``std**2``; ``measurement_time`` is the period, so environments and
    simulations measure one period by default, as with a multisine.

    Parameters
    ----------
    cutoff_hz
        Cut-off frequency (Hz), between ``1/duration`` and the Nyquist frequency of ``dt``.
    std
        Standard deviation (>= 0).
    duration
        Period (s), > 0.
    seed
        Non-negative integer seed.
    dt
        Grid step (s), > 0; finer than the sample times it is read at keeps the
        interpolation error small (0.01 s: 2e-4 of the signal at 1 Hz).

    """

    kind: ClassVar[str] = "band_limited_noise"
    cutoff_hz: float
    std: float
    duration: float
    seed: int
    dt: float = 0.01

    def __post_init__(self) -> None:
        object.__setattr__(self, "std", check_positive("std", self.std, allow_zero=True))
        object.__setattr__(self, "duration", check_positive("duration", self.duration))
        object.__setattr__(self, "seed", check_int("seed", self.seed, minimum=0))
        object.__setattr__(self, "dt", check_positive("dt", self.dt))
        count = round(self.duration / self.dt)
        if count < 2 or abs(count * self.dt - self.duration) > 1e-9 * self.duration:
            raise ValueError(
                f"duration must be a whole number (>= 2) of dt = {self.dt!r} s steps, "
                f"got duration = {self.duration!r} s"
            )
        object.__setattr__(
            self,
            "cutoff_hz",
            check_range("cutoff_hz", self.cutoff_hz, 1.0 / self.duration, 0.5 / self.dt),
        )

    @functools.cached_property
    def signal(self) -> SampledSignal:
        """The samples of one period as a periodic :class:`SampledSignal`."""
        rng = np.random.default_rng(self.seed)
        values = band_limited_noise(
            round(self.duration / self.dt), self.dt, self.cutoff_hz, self.std, rng
        )
        return SampledSignal(values, self.dt, 0.0, periodic=True)

    def __call__(self, t: ArrayLike) -> float | FloatArray:
        """Value at time(s) ``t`` (s)."""
        return self.signal(t)

    def derivative(self, t: ArrayLike) -> float | FloatArray:
        """Time derivative (per second) at time(s) ``t``."""
        return self.signal.derivative(t)

    @property
    def measurement_time(self) -> float:
        """The period ``duration`` (s)."""
        return self.duration

    @property
    def variance(self) -> float:
        """``std**2``: the variance of the samples over one period."""
        return self.std**2

    def scaled(self, factor: float) -> BandLimitedNoise:
        """The same realisation multiplied by ``factor`` (> 0)."""
        factor = check_positive("factor", factor)
        return dataclasses.replace(self, std=self.std * factor)

    def _key(self) -> tuple[Any, ...]:
        return (self.cutoff_hz, self.std, self.duration, self.seed, self.dt)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BandLimitedNoise):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), self._key())

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description; :meth:`from_dict` rebuilds an equal signal."""
        return {
            "kind": self.kind,
            "cutoff_hz": self.cutoff_hz,
            "std": self.std,
            "duration": self.duration,
            "seed": self.seed,
            "dt": self.dt,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BandLimitedNoise:
        """Inverse of :meth:`to_dict`; unknown keys or another ``kind`` raise."""
        items = dict(data)
        check_choice("BandLimitedNoise.from_dict kind", items.pop("kind", None), (cls.kind,))
        reject_unknown(
            "BandLimitedNoise.from_dict", items, ("cutoff_hz", "std", "duration", "seed", "dt")
        )
        missing = [key for key in ("cutoff_hz", "std", "duration", "seed") if key not in items]
        if missing:
            raise TypeError(f"BandLimitedNoise.from_dict is missing key(s) {', '.join(missing)}")
        return cls(**items)


# -------------------------------------------------------------------------- presets

_PLAETINCK_FILE = "data/plaetinck2018-multisine.csv"
_PLAETINCK_MEASUREMENT_TIME = 81.92  # 8192 samples at 100 Hz


def _plaetinck_multisine() -> Multisine:
    """The Plaetinck et al. (2018) table shipped in ``manualcontrol.envs/data``."""
    text = importlib.resources.files("manualcontrol.envs").joinpath(_PLAETINCK_FILE).read_text()
    lines = [line.split(",") for line in text.splitlines() if line.strip()]
    header = [name.strip() for name in lines[0]]
    table = np.array([[float(cell) for cell in line] for line in lines[1:]])
    column = dict(zip(header, table.T, strict=True))
    base = 2.0 * np.pi / _PLAETINCK_MEASUREMENT_TIME
    return Multisine(
        column["nf"] * base, column["Af"], column["phi_f"], _PLAETINCK_MEASUREMENT_TIME
    )


def _preset_plaetinck2018() -> tuple[ForcingPair, ...]:
    return (ForcingPair(_plaetinck_multisine(), None, "plaetinck2018", 0),)


def _preset_popovici2017() -> tuple[ForcingPair, ...]:
    table = _plaetinck_multisine()
    rng = np.random.default_rng(2017)
    base = design_multisine(
        n_sines=10,
        measurement_time=90.0,
        bandwidth=1.25,
        variance=table.variance,
        low=float(table.frequencies.min()),
        high=float(table.frequencies.max()),
        rng=rng,
    )
    return tuple(
        ForcingPair(target, None, "popovici2017", index)
        for index, target in enumerate(realisations(base, 5, rng))
    )


def _preset_vanderel_bw4() -> tuple[ForcingPair, ...]:
    measurement_time, low, high = 120.0, 0.1, 20.0
    target_harmonics, disturbance_harmonics = interleaved_harmonics(10, measurement_time, low, high)
    rng = np.random.default_rng(2020)
    target = design_multisine(
        10, measurement_time, 4.0, 1.0, low, high, rng, harmonics=target_harmonics
    )
    disturbance = design_multisine(
        10, measurement_time, 4.0, 0.25, low, high, rng, harmonics=disturbance_harmonics
    )
    pairs = zip(realisations(target, 10, rng), realisations(disturbance, 10, rng), strict=True)
    return tuple(ForcingPair(ft, fd, "vanderel-bw4", index) for index, (ft, fd) in enumerate(pairs))


def _preset_schiess_roland1975() -> tuple[ForcingPair, ...]:
    return (ForcingPair(Multisine.sine(0.25, 1.0), None, "schiess-roland1975", 0),)


#: Realisations of the Boer-Kenyon noise presets (seeds ``_BOER_KENYON_SEED + i``).
_BOER_KENYON_REALISATIONS = 10
_BOER_KENYON_SEED = 1998


def _boer_kenyon_pairs(
    name: str, cutoff_hz: float, std: float, dt: float, *, disturbance: bool = False
) -> tuple[ForcingPair, ...]:
    pairs = []
    for index in range(_BOER_KENYON_REALISATIONS):
        noise = BandLimitedNoise(cutoff_hz, std, 120.0, _BOER_KENYON_SEED + index, dt)
        target, other = (None, noise) if disturbance else (noise, None)
        pairs.append(ForcingPair(target, other, name, index))
    return tuple(pairs)


def _preset_boer_kenyon1998() -> tuple[ForcingPair, ...]:
    return _boer_kenyon_pairs("boer-kenyon1998", 1.0, 2.0, 1.0 / 600.0)


def _preset_boer_kenyon1998_postview() -> tuple[ForcingPair, ...]:
    return _boer_kenyon_pairs("boer-kenyon1998-postview", 0.6, 2.0, 0.01)


def _preset_boer_kenyon1998_critical() -> tuple[ForcingPair, ...]:
    return _boer_kenyon_pairs("boer-kenyon1998-critical", 1.0, 2.0 / 100.0, 0.01, disturbance=True)


_PRESET_BUILDERS: dict[str, Callable[[], tuple[ForcingPair, ...]]] = {
    "vanderel-bw4": _preset_vanderel_bw4,
    "popovici2017": _preset_popovici2017,
    "schiess-roland1975": _preset_schiess_roland1975,
    "plaetinck2018": _preset_plaetinck2018,
    "boer-kenyon1998": _preset_boer_kenyon1998,
    "boer-kenyon1998-postview": _preset_boer_kenyon1998_postview,
    "boer-kenyon1998-critical": _preset_boer_kenyon1998_critical,
}

#: Names accepted by :func:`forcing_preset`.
FORCING_PRESETS: tuple[str, ...] = tuple(_PRESET_BUILDERS)


@functools.cache
def _preset_pairs(name: str) -> tuple[ForcingPair, ...]:
    return _PRESET_BUILDERS[name]()


def preset_realisation_count(name: str) -> int:
    """Number of realisations of the forcing preset ``name``."""
    check_choice("forcing preset", name, FORCING_PRESETS)
    return len(_preset_pairs(name))


def forcing_preset(name: str, realisation: int = 0) -> ForcingPair:
    """A named forcing function pair from the papers, built once and cached.

    ``"vanderel-bw4"``
        Resembles the 4 rad/s bandwidth signals of van der El et al. used in the thesis
        (Part I Sec. IV-B): the paper's amplitude table is not in our references, so this
        is a resemblance, not a copy. Target: 10 sines on log-spread harmonics of
        ``2π/120`` rad/s between 0.1 and 20 rad/s, :func:`amplitude_profile` with
        bandwidth 4 rad/s (lead 10 rad/s), variance 1.0. Disturbance: the same profile on
        the adjacent harmonics (:func:`interleaved_harmonics`), variance 0.25. 10
        realisations, phases chosen by lowest crest factor from 500 candidates each
        (seed 2020).
    ``"popovici2017"``
        Compensatory, target only: 10 sines, ``T_m = 90`` s (the paper's 90-s runs),
        log-spread over the Plaetinck band (0.23-17.6 rad/s), profile bandwidth
        1.25 rad/s and lead 10 rad/s, variance of the Plaetinck table; 5 realisations by
        lowest crest factor (seed 2017).
    ``"schiess-roland1975"``
        Target ``D(t) = 0.25 sin t`` (Schiess & Roland 1975), one period ``T_m = 2π`` s;
        1 realisation.
    ``"plaetinck2018"``
        The real 10-sine table of Plaetinck et al. (2018), ``T_m = 81.92`` s, phases as
        published, frequencies ``nf 2π/81.92`` from the integer column; 1 realisation.
    ``"boer-kenyon1998"``
        Target only: the input ``r`` of Boer & Kenyon's simulation (Sec. IV-A), Gaussian
        noise through an ideal 1.0-Hz low-pass, standard deviation 2.0
        (:class:`BandLimitedNoise`, 120-s period on a 1/600-s grid, the paper's
        simulation rate); 10 realisations (seeds 1998-2007).
    ``"boer-kenyon1998-postview"``
        Target only: the gap-postview track (Sec. V-A), the same kind of signal at
        0.6 Hz (the paper replayed its 1.0-Hz signal, made for 60 Hz, at 36 Hz),
        standard deviation 2.0, 0.01-s grid; 10 realisations.
    ``"boer-kenyon1998-critical"``
        Disturbance only: the critical tracking task's (Sec. VI-A), the 1.0-Hz signal
        divided by 100 (standard deviation 0.02), 0.01-s grid; 10 realisations.

    Seeds are fixed and every draw uses :func:`numpy.random.default_rng`, so every user
    and process gets identical numbers.

    Raises
    ------
    ValueError
        For an unknown name (the message lists :data:`FORCING_PRESETS`) or a
        realisation outside ``[0, preset_realisation_count(name) - 1]``.

    """
    count = preset_realisation_count(name)
    realisation = check_int("realisation", realisation)
    if not 0 <= realisation < count:
        raise ValueError(
            f"realisation must lie in [0, {count - 1}] for forcing preset {name!r}, "
            f"got {realisation!r}"
        )
    return _preset_pairs(name)[realisation]
