"""The target signal at any time, for estimators that need it ahead of the samples.

Preview estimation feeds the filter the *anticipated* target ``ft(t + tau_a)`` (thesis
Part I Sec. III-B), which a recording of ``ft`` alone does not hold near its end.
:func:`target_function` finds the target as a function of time, in this order:

1. an explicit ``forcing`` argument (a :class:`~manualcontrol.envs.signals.ForcingPair`,
   whose ``target`` is used, or any callable of an array of times);
2. the recording's ``metadata["forcing"]`` (what :func:`~manualcontrol.pilots.simulate`
   stores), rebuilt with :meth:`ForcingPair.from_dict`;
3. the periodic extension of the recorded ``ft`` when ``target_period`` is given and
   the recording lasts a whole number of periods: the recorded samples are one period
   of a trigonometric polynomial (their discrete Fourier series), evaluated exactly at
   any time, so a multisine on the period's harmonics is reproduced to rounding.

Anything else raises ``ValueError`` saying what to pass.

:func:`previewed_target` gives the target a preview model's far view perceives,
``ft(t + tau_f)`` (thesis Part I eq. 26 with ``tau_f* = tau_a - tau_f``): ahead of the
samples only where ``tau_f > 0``. With ``tau_f = 0`` throughout, the pursuit form of the
preview model (van der El et al.'s pursuit display: the current target, nothing ahead),
it is the recorded ``ft`` and needs none of the sources above.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._validation import check_positive
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair

FloatArray = NDArray[np.float64]
TargetFunction = Callable[[FloatArray], FloatArray]

#: Largest deviation of a given forcing from the recorded ft, relative to ft's RMS.
MATCH_TOLERANCE = 1e-6


class PeriodicExtension:
    """One recorded period (or several) of a signal, extended periodically.

    The samples ``values[k]`` at ``t0 + k dt`` are interpolated by their discrete
    Fourier series, which for a signal made of the record's harmonics (a multisine
    whose period divides the record) is exact at every time.
    """

    def __init__(self, values: ArrayLike, dt: float, t0: float = 0.0) -> None:
        values = np.asarray(values, dtype=np.float64)
        if values.ndim != 1 or values.shape[0] < 2 or not np.all(np.isfinite(values)):
            raise ValueError("the periodic extension needs at least 2 finite samples")
        n = values.shape[0]
        spectrum = np.fft.rfft(values) / n
        weights = np.full(spectrum.shape[0], 2.0)
        weights[0] = 1.0
        if n % 2 == 0:
            weights[-1] = 1.0
        magnitude = np.abs(spectrum) * weights
        keep = np.flatnonzero(magnitude > 1e-13 * max(float(magnitude.max()), 1e-300))
        keep = keep[keep > 0]
        self.mean = float(spectrum[0].real)
        self.omega = 2.0 * np.pi * keep / (n * dt)
        self.amplitude = magnitude[keep]
        self.phase = np.angle(spectrum[keep])
        self.t0 = float(t0)

    def __call__(self, t: ArrayLike) -> FloatArray:
        times = np.asarray(t, dtype=np.float64) - self.t0
        out = np.full(times.shape, self.mean)
        for omega, amplitude, phase in zip(self.omega, self.amplitude, self.phase, strict=True):
            out += amplitude * np.cos(omega * times + phase)
        return out


def _zero(t: FloatArray) -> FloatArray:
    return np.zeros_like(np.asarray(t, dtype=np.float64))


def _from_forcing(forcing: Any) -> TargetFunction:
    if isinstance(forcing, ForcingPair):
        return _zero if forcing.target is None else forcing.target
    if callable(forcing):
        return forcing
    raise TypeError(
        f"forcing must be a ForcingPair or a callable of times (e.g. a Multisine), got {forcing!r}"
    )


def _check_match(target: TargetFunction, recording: Recording, source: str) -> None:
    if "ft" not in recording:
        return
    ft = recording.ft
    deviation = float(np.max(np.abs(np.asarray(target(recording.t)) - ft)))
    scale = float(np.sqrt(np.mean(ft * ft)))
    if deviation > MATCH_TOLERANCE * max(scale, 1e-12):
        raise ValueError(
            f"the target from {source} does not reproduce the recording's ft: largest "
            f"deviation {deviation:.3g} (RMS of ft {scale:.3g}); pass the forcing the "
            "recording was made with"
        )


def target_function(
    recording: Recording,
    forcing: Any = None,
    target_period: float | None = None,
) -> TargetFunction:
    """The recording's target ``ft`` as a function of time (see the module docstring).

    Raises
    ------
    ValueError
        When none of the sources applies, when a given forcing does not reproduce the
        recorded ``ft`` (relative RMS tolerance :data:`MATCH_TOLERANCE`), or when the
        recording is not a whole number of ``target_period`` long.

    """
    if forcing is not None:
        target = _from_forcing(forcing)
        _check_match(target, recording, "the forcing argument")
        return target
    if "forcing" in recording.metadata:
        pair = ForcingPair.from_dict(recording.metadata["forcing"])
        target = _from_forcing(pair)
        _check_match(target, recording, "metadata['forcing']")
        return target
    if target_period is not None:
        period = check_positive("target_period", target_period)
        if "ft" not in recording:
            raise ValueError("the periodic extension needs the recorded target ft")
        periods = recording.duration / period
        if abs(periods - round(periods)) > 1e-6 or round(periods) < 1:
            raise ValueError(
                f"target_period: the recording lasts {recording.duration:g} s, which is not a "
                f"whole number of periods of {period:g} s"
            )
        return PeriodicExtension(recording.ft, recording.dt, float(recording.t[0]))
    raise ValueError(
        "the target ahead of the samples is unknown: pass forcing= (a ForcingPair or a "
        "callable of time), record metadata['forcing'], or pass target_period= for a "
        "recording that lasts a whole number of forcing periods"
    )


def previewed_target(
    recording: Recording,
    tau_f: ArrayLike,
    forcing: Any = None,
    target_period: float | None = None,
) -> FloatArray:
    """The target the far view perceives, ``ft(t + tau_f)``, at every sample.

    ``tau_f`` is the preview time, a constant or one value per sample. Where it is 0 at
    every sample (the pursuit form: the model reads no future target) and the
    recording holds ``ft``, the answer is the recorded ``ft`` itself: no forcing,
    metadata or period is needed, and a ``forcing`` given is not consulted. Otherwise
    the target ahead comes from :func:`target_function`, with its sources and its
    ``ValueError`` when none applies.
    """
    t = np.asarray(recording.t, dtype=np.float64)
    preview = np.broadcast_to(np.asarray(tau_f, dtype=np.float64), t.shape)
    if "ft" in recording and not np.any(preview):
        return np.array(recording.ft, dtype=np.float64)
    target = target_function(recording, forcing, target_period)
    return np.asarray(target(t + preview), dtype=np.float64)
