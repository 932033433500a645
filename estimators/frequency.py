"""Frequency-domain identification at the forcing frequencies (non-parametric).

With multisine forcing functions on integer harmonics of the measurement time, the
discrete Fourier transform of a run that spans whole periods puts every forcing
component in one bin. At the target frequencies the disturbance has no power
(interleaved sets), so for a compensatory task

    H_p(j w_t) = U(w_t) / E(w_t),      H_ol(j w_t) = Y(w_t) / E(w_t) = H_p H_c

(the classic estimators of McRuer-type identification). Crossover frequency and phase
margin follow from the open loop by interpolation between forcing frequencies
(log-log in magnitude, log-linear in phase).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair

__all__ = ["FrequencyResponse", "forcing_frequency_response"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class FrequencyResponse:
    """Non-parametric responses at the target forcing frequencies.

    ``pilot`` is ``U/E`` and ``open_loop`` ``Y/E``; ``crossover_frequency`` (rad/s,
    NaN when ``|H_ol|`` does not cross 1 inside the forcing band) and
    ``phase_margin`` (degrees) are read from ``open_loop``.
    """

    frequencies: FloatArray
    pilot: NDArray[np.complex128]
    open_loop: NDArray[np.complex128]
    crossover_frequency: float
    phase_margin: float


def forcing_frequency_response(
    recording: Recording, forcing: ForcingPair | None = None
) -> FrequencyResponse:
    """Estimate pilot and open-loop responses at the target frequencies of a run.

    ``forcing`` defaults to ``recording.metadata["forcing"]``. The recording must
    span a whole number of forcing periods (the measurement time of the target).
    """
    if forcing is None:
        if "forcing" not in recording.metadata:
            raise ValueError("recording has no 'forcing' in its metadata: pass forcing=")
        forcing = ForcingPair.from_dict(recording.metadata["forcing"])
    target = forcing.target
    if target is None or target.measurement_time is None:
        raise ValueError(
            "the forcing needs a periodic target (a multisine with a measurement time)"
        )
    for name in ("e", "u", "y"):
        if name not in recording:
            raise ValueError(f"recording needs signal {name!r} for a frequency response")
        if np.isnan(recording[name]).any():
            raise ValueError(f"signal {name!r} has dropped samples (NaN); fill or cut them first")
    periods = recording.duration / target.measurement_time
    if abs(periods - round(periods)) > 1e-6 or round(periods) < 1:
        raise ValueError(
            "recording must span a whole number of target periods "
            f"({target.measurement_time:g} s), got {recording.duration:g} s"
        )
    bins = (np.asarray(target.harmonics) * round(periods)).astype(int)
    spectra = {name: np.fft.rfft(recording[name])[bins] for name in ("e", "u", "y")}
    pilot = spectra["u"] / spectra["e"]
    open_loop = spectra["y"] / spectra["e"]
    frequencies = np.asarray(target.frequencies, dtype=np.float64)
    crossover, margin = _crossover(frequencies, open_loop)
    return FrequencyResponse(frequencies, pilot, open_loop, crossover, margin)


def _crossover(frequencies: FloatArray, open_loop: NDArray[np.complex128]) -> tuple[float, float]:
    """First downward crossing of ``|H_ol| = 1`` and the phase margin there."""
    magnitude = np.log(np.abs(open_loop))
    phase = np.unwrap(np.angle(open_loop))
    logw = np.log(frequencies)
    for i in range(len(frequencies) - 1):
        if magnitude[i] >= 0.0 > magnitude[i + 1]:
            fraction = magnitude[i] / (magnitude[i] - magnitude[i + 1])
            log_crossover = logw[i] + fraction * (logw[i + 1] - logw[i])
            phase_at = phase[i] + fraction * (phase[i + 1] - phase[i])
            margin = math.degrees(phase_at) + 180.0
            # report the margin in (-180, 180]
            margin = (margin + 180.0) % 360.0 - 180.0
            return math.exp(log_crossover), margin
    return math.nan, math.nan
