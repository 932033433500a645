"""Frequency-domain identification at the forcing frequencies: the laboratory's standard.

With multisine forcing functions on integer harmonics of their period, the Fourier
coefficients of a stretch that spans whole periods put every forcing component in one
bin (the Fourier-coefficient method of McRuer-type identification; van Paassen &
Mulder 1998). At a forcing frequency the signals are dominated by the forcing, and the
remnant, uncorrelated with it, averages out of the ratio of coefficients, so for a
compensatory task

    H_p(j w_k) = U(w_k) / E(w_k),      H_ol(j w_k) = H_p(j w_k) H_c(j w_k)

at every forcing frequency, target or disturbance, wherever the disturbance enters the
loop (at the element's output or its input). :func:`describing_function` estimates
``H_p`` there, its spread between periods, a per-frequency signal-to-noise ratio (u's
power at the forcing bin over its mean power at the neighbouring bins, which hold
remnant only), the element's response (the one the user gave, or measured from
``y``, ``u`` and the disturbance), the open loop, crossover frequency and phase margin
(interpolated between forcing frequencies: log-log in magnitude, log-linear in phase).
:func:`fit_describing_function` fits a compensatory pilot model's exact frequency
response to it, and :func:`response_error` scores any identified model against it,
which is how every time-domain identification is cross-checked.

:func:`forcing_frequency_response` is the older, narrower form (target frequencies
only, ``Y/E`` as the open loop) that the agents' evaluation uses.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_choice, check_int, check_positive
from manualcontrol.envs.elements import ControlledElement, make_element
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair, Multisine
from manualcontrol.envs.tasks import TASKS, task_named
from manualcontrol.pilots.models import PilotModel, make_model

__all__ = [
    "DESCRIBING_METHODS",
    "DISTURBANCE_POINTS",
    "SHARED_LINE",
    "TWO_CHANNEL_TASKS",
    "DescribingFunction",
    "ForcingLines",
    "FrequencyResponse",
    "ModelFit",
    "channel_responses",
    "describing_function",
    "fit_describing_function",
    "forcing_frequency_response",
    "loop_response",
    "model_crossover",
    "response_error",
]

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


def _crossover(
    frequencies: FloatArray,
    open_loop: NDArray[np.complex128],
    weights: FloatArray | None = None,
) -> tuple[float, float]:
    """A downward crossing of ``|H_ol| = 1`` and the phase margin there.

    The first, or with ``weights`` (a line's reliability, :func:`fit_weights`) the one
    read between the best-read pair of lines (the larger of their smaller weights; the
    first among equals): a slow remnant drives the lowest lines towards the loop's own
    ``|H_ol| = 1`` (the error the remnant drives is the loop's), which read first made
    a typical single-integrator pilot cross over at 0.2 rad/s instead of 2.
    """
    magnitude = np.log(np.abs(open_loop))
    phase = np.unwrap(np.angle(open_loop))
    logw = np.log(frequencies)
    downward = np.flatnonzero((magnitude[:-1] >= 0.0) & (magnitude[1:] < 0.0))
    if downward.size == 0:
        return math.nan, math.nan
    i = int(downward[0])
    if weights is not None:
        support = np.minimum(weights[downward], weights[downward + 1])
        i = int(downward[np.argmax(support)])  # argmax: the first of equals
    fraction = magnitude[i] / (magnitude[i] - magnitude[i + 1])
    log_crossover = logw[i] + fraction * (logw[i + 1] - logw[i])
    phase_at = phase[i] + fraction * (phase[i + 1] - phase[i])
    margin = math.degrees(phase_at) + 180.0
    # the margin in [-180, 180): a phase of -380 deg at crossover reads as +160,
    # the same point of the Nyquist plane (which encirclement it is, no one line says)
    margin = (margin + 180.0) % 360.0 - 180.0
    return math.exp(log_crossover), margin


#: Draws of :func:`_crossover_uncertainty`, and the seed of its fixed draw: the same
#: lines get the same statement in every process (400 draws: the deviation's own
#: sampling error about 5 %).
_UNCERTAINTY_DRAWS = 400
_UNCERTAINTY_SEED = 0


def _crossover_uncertainty(
    frequencies: FloatArray, open_loop: NDArray[np.complex128], snr_injected: FloatArray
) -> tuple[float, float]:
    """Standard deviations of :func:`_crossover`'s reading that the remnant implies.

    Of the crossover frequency's natural log (its relative error) and of the phase
    margin (degrees). At a line ``U/E = H_p + N/E`` errs by ``N/U`` relative, a
    circular error of mean square ``1/snr_injected`` (the ``snr_injected`` of
    :class:`DescribingFunction`): ``log|H_ol|`` and its phase each err by
    ``1/sqrt(2 snr_injected)``, independently between lines. The reading is redone on
    the lines so perturbed (a fixed draw of :data:`_UNCERTAINTY_DRAWS`), with its own
    choice of pair, and the deviation is half the spread between the draws' 16th and
    84th percentiles (one standard deviation of a normal spread; robust to the draws
    that cross between another pair). Sampled rather than carried to first order: the
    first order grows without bound where both lines of the pair lie near
    ``|H_ol| = 1``, while a redone reading stays between the lines it crosses between.
    NaN without a crossing, or where over half the draws have none.
    """
    weights = fit_weights(snr_injected)
    crossover, margin = _crossover(frequencies, open_loop, weights)
    if not math.isfinite(crossover):
        return math.nan, math.nan
    rng = np.random.default_rng(_UNCERTAINTY_SEED)
    shape = (_UNCERTAINTY_DRAWS, frequencies.size)
    errors = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / np.sqrt(
        2.0 * snr_injected
    )
    readings = np.array([_crossover(frequencies, open_loop * (1.0 + e), weights) for e in errors])
    crossed = np.isfinite(readings[:, 0])
    if np.count_nonzero(crossed) < _UNCERTAINTY_DRAWS / 2:
        return math.nan, math.nan
    # the margins about the reading's own, on the same turn: _crossover wraps them to
    # [-180, 180), and a reading near -180 would else spread over a whole turn
    margins = (readings[crossed, 1] - margin + 180.0) % 360.0 - 180.0
    low, high = np.percentile(
        np.column_stack([np.log(readings[crossed, 0]), margins]), [15.87, 84.13], axis=0
    )
    spread = 0.5 * (high - low)
    return float(spread[0]), float(spread[1])


# ------------------------------------------------------------------ describing function

#: Where a disturbance forcing function enters the loop: added to the element's output
#: (``y = H_c u + fd``, the default of the simulations and envs) or to its input
#: (``y = H_c (u + fd)``, e.g. a force on the stick or a gust on the aircraft).
DISTURBANCE_POINTS: tuple[str, ...] = ("output", "input")

#: Injected signal-to-noise ratio under which a line is left out of the measured
#: crossover: below 1 the remnant's power at the line exceeds the forcing's, ``U/E``
#: errs by more than its own size (``|N/U| > 1``), and one such line read as a dip of
#: ``|H_ol|`` below 1 made a spurious crossing (the weight :func:`fit_weights` gives it,
#: ``SNR/(1 + SNR)``, is below one half there).
_CROSSOVER_SNR = 1.0

#: Relative power below the strongest line under which a bin of a recorded forcing
#: signal is not a forcing line (60 dB: amplitude profiles of tracking experiments span
#: well under 30 dB; a signal that does not repeat over the stretch leaks far above it).
_LINE_POWER_FLOOR = 1e-6
#: Condition number of the least-squares sinusoid basis beyond which the lines are not
#: told apart (coefficients would be noise amplified a million-fold).
_SINUSOID_CONDITION_LIMIT = 1e6
#: How far (in samples) the period may be from a whole number of samples.
_PERIOD_SAMPLE_TOLERANCE = 1e-3


#: How :func:`describing_function` reads the lines. ``"fourier"``: the discrete Fourier
#: coefficients over the last whole periods, each line exactly one bin (the laboratory
#: standard). ``"least-squares"``: sinusoids at the forcing lines fitted to every sample
#: given, any length (a run cut mid-period, the samples so far of a running trial); on
#: whole periods the sinusoids are orthogonal and the two agree.
DESCRIBING_METHODS: tuple[str, ...] = ("fourier", "least-squares")

#: Displays on which the pilot sees the target and the output separately.
TWO_CHANNEL_TASKS: tuple[str, ...] = tuple(name for name in TASKS if task_named(name).shows_target)

#: The source of a forcing line both the target and the disturbance drive (one harmonic
#: of each): a compensatory display reads it as any line; a two-channel one cannot tell
#: its two responses apart there and leaves it out.
SHARED_LINE = "both"


@dataclass(frozen=True)
class ForcingLines:
    """Fourier coefficients of the recorded signals at every forcing line of a stretch.

    ``coefficients`` maps ``u``, ``e`` and, where recorded, ``y``, ``fd`` and ``ft`` to
    their coefficients at ``frequencies`` (rad/s, ascending, one per harmonic; ``source``
    says target, disturbance or both, :data:`SHARED_LINE`); ``snr`` is u's
    signal-to-noise ratio at each line (as :attr:`DescribingFunction.snr`). A model
    with any number of perception channels is fitted to these: its predicted ``U`` from
    the perceptions' coefficients against the measured ``U``.
    """

    frequencies: FloatArray
    source: tuple[str, ...]
    coefficients: Mapping[str, NDArray[np.complex128]]
    snr: FloatArray


@dataclass(frozen=True)
class DescribingFunction:
    """The pilot's describing function measured at the forcing frequencies of one run.

    Every array has one entry per forcing frequency, in ascending order.

    Attributes
    ----------
    frequencies
        Forcing frequencies (rad/s).
    source
        ``"target"``, ``"disturbance"`` or ``"both"`` (:data:`SHARED_LINE`, a harmonic
        both drive): which forcing function each belongs to. A two-channel display's
        function is read at the disturbance's lines alone, where the target is still.
    pilot
        ``H_p = U/E`` from the Fourier coefficients over the whole stretch.
    gain_spread_db, phase_spread_deg
        Standard deviation of the per-period estimates around ``pilot`` (gain in dB,
        phase in degrees); for a stretch of one period the spread the remnant implies,
        ``1/sqrt(2 snr_injected)`` (relative) in each of gain and phase.
    snr
        u's power at the forcing bin over its mean power at the ``neighbours`` nearest
        non-forcing bins each side (linear power ratio; those bins carry remnant only):
        the figure laboratories report.
    snr_injected
        u's power at the forcing bin over the power of the remnant as the pilot injects
        it, ``N = U - H_p E`` at the same neighbouring bins with ``H_p`` of the line.
        The loop shapes the remnant that reaches ``u`` by ``1/(1 + H_ol)``, so below
        crossover ``snr`` flatters the estimate; ``U/E = H_p + N/E`` errs by
        ``|N/U|``, about ``1/sqrt(snr_injected)`` (relative), which sets the fit's
        weights and, for a single period, the spread. It reads ``N`` with the line's own
        estimate of ``H_p``, so where that estimate is far off (a line with little forcing
        power under strong remnant) it can flatter the line.
    element
        ``H_c`` used for the open loop: the given element's, else the measured one.
    element_measured
        ``H_c`` measured from the signals (``Y/(U + Fd)`` with the disturbance at the
        input, ``(Y - Fd)/U`` at the output); NaN without ``y``.
    element_drift
        The part of ``element_measured`` that the given element's own response to a
        state that is not periodic over the stretch explains (:func:`_element_drift`),
        which :meth:`element_error` takes out: an element with a slow mode (an
        integrator) whose output wanders, as under a remnant's slow drift, does not
        repeat, and its Fourier coefficients hold that transient beside the forcing's
        response. Zeros on a gain (no state); None without a given element or with
        ``method="least-squares"``, whose stretch need not be whole periods.
    open_loop
        ``H_p H_c``.
    crossover_frequency, phase_margin
        A downward crossing of ``|H_ol| = 1`` (rad/s) and the margin there (degrees),
        read between the lines the remnant does not swamp (``snr_injected`` at least 1,
        :data:`_CROSSOVER_SNR`): of several, the one between the best-read pair of
        lines (:func:`_crossover` with :func:`fit_weights`); NaN when the open loop does
        not cross between them (:meth:`no_crossover_reason`).
    remnant_share
        Fraction of u's variance over the stretch that lies off the forcing frequencies.
    period, periods, window
        Forcing period (s), whole periods used, and the stretch ``(start, end)`` (s):
        the last whole periods of the run, so a run-in at the start is left out
        (``"least-squares"``: every sample given, ``periods`` the whole periods in it).
    disturbance_at, element_given
        Where the disturbance entered; whether ``element`` came from the user.
    element_transfer_function
        ``(num, den)`` of the given element (descending powers of ``s``), else None.
    task, lines
        The display (see ``task`` of :func:`describing_function`) and the Fourier
        coefficients at every forcing line (:class:`ForcingLines`), what a model is fitted
        to.
    method
        How the lines were read (:data:`DESCRIBING_METHODS`).

    """

    frequencies: FloatArray
    source: tuple[str, ...]
    pilot: NDArray[np.complex128]
    gain_spread_db: FloatArray
    phase_spread_deg: FloatArray
    snr: FloatArray
    snr_injected: FloatArray
    element: NDArray[np.complex128]
    element_measured: NDArray[np.complex128]
    open_loop: NDArray[np.complex128]
    crossover_frequency: float
    phase_margin: float
    remnant_share: float
    period: float
    periods: int
    window: tuple[float, float]
    disturbance_at: str
    element_given: bool
    element_transfer_function: tuple[FloatArray, FloatArray] | None = None
    task: str = "compensatory"
    element_drift: NDArray[np.complex128] | None = None
    lines: ForcingLines | None = None
    method: str = "fourier"

    @property
    def gain_db(self) -> FloatArray:
        """``20 log10 |H_p|``."""
        return 20.0 * np.log10(np.abs(self.pilot))

    @property
    def phase_deg(self) -> FloatArray:
        """Phase of ``H_p`` in degrees, unwrapped from the lowest frequency."""
        return np.degrees(np.unwrap(np.angle(self.pilot)))

    @property
    def readable_lines(self) -> NDArray[np.bool_]:
        """The lines the crossover is read between: the remnant does not swamp them."""
        return _readable(self.snr_injected)

    def crossover_uncertainty(self) -> tuple[float, float]:
        """Standard deviations the remnant implies for the crossover and phase margin.

        ``(relative, degrees)``: of ``log(crossover_frequency)`` (so 0.1 is about 10 %)
        and of ``phase_margin``, sampled from each line's ``snr_injected`` through the
        reading (:func:`_crossover_uncertainty`). NaN without a crossover, or where the
        lines leave it too uncertain to state.
        """
        if not math.isfinite(self.crossover_frequency):
            return math.nan, math.nan
        readable = self.readable_lines
        return _crossover_uncertainty(
            self.frequencies[readable], self.open_loop[readable], self.snr_injected[readable]
        )

    def no_crossover_reason(self) -> str:
        """Why ``crossover_frequency`` is NaN, in words (where the lines were read)."""
        band = f"{self.frequencies[0]:.2f}-{self.frequencies[-1]:.2f} rad/s"
        readable = int(np.count_nonzero(self.readable_lines))
        if readable == self.frequencies.size:
            return f"the open loop's gain does not cross 1 inside the forcing band ({band})"
        return (
            f"the open loop's gain does not cross 1 between the {readable} of "
            f"{self.frequencies.size} forcing lines in {band} the remnant does not swamp "
            f"(injected signal-to-noise ratio {_CROSSOVER_SNR:g} or more)"
        )

    def element_error(self) -> tuple[float, float]:
        """Mean absolute gap (dB, degrees) between the given and the measured element.

        Large values say the element or the disturbance's entry point given does not
        describe the experiment. The measured element is read less ``element_drift``:
        a wandering output is the element's own transient, not a different element.
        NaN when either is missing.
        """
        if not self.element_given or not np.all(np.isfinite(self.element_measured)):
            return math.nan, math.nan
        measured = self.element_measured
        if self.element_drift is not None:
            measured = measured - self.element_drift
        return _mean_errors(measured, self.element)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary: per-frequency table and the loop's figures."""
        crossover_spread, margin_spread = self.crossover_uncertainty()
        return {
            "frequencies": _listed(self.frequencies),
            "source": list(self.source),
            "gain_db": _listed(self.gain_db),
            "phase_deg": _listed(self.phase_deg),
            "gain_spread_db": _listed(self.gain_spread_db),
            "phase_spread_deg": _listed(self.phase_spread_deg),
            "snr": _listed(self.snr),
            "crossover_frequency": _finite_or_none(self.crossover_frequency),
            "phase_margin": _finite_or_none(self.phase_margin),
            # standard deviations (crossover_uncertainty): of the crossover's log, in deg
            "crossover_frequency_sd_log": _finite_or_none(crossover_spread),
            "phase_margin_sd": _finite_or_none(margin_spread),
            "remnant_share": _finite_or_none(self.remnant_share),
            "period": self.period,
            "periods": self.periods,
            "window": list(self.window),
            "disturbance_at": self.disturbance_at,
            "element_given": self.element_given,
            "element_error_db_deg": [_finite_or_none(v) for v in self.element_error()],
            "method": self.method,
        }


def _listed(values: FloatArray) -> list[float | None]:
    return [_finite_or_none(v) for v in np.asarray(values, dtype=np.float64)]


def _readable(snr_injected: FloatArray) -> NDArray[np.bool_]:
    """The lines the remnant does not swamp (:data:`_CROSSOVER_SNR`)."""
    return np.asarray(snr_injected >= _CROSSOVER_SNR)


def _finite_or_none(value: float) -> float | None:
    return round(float(value), 6) if math.isfinite(value) else None


def _element_drift(
    whole: Mapping[str, NDArray[np.complex128]],
    size: int,
    forcing_bins: NDArray[np.int64],
    bins: NDArray[np.int64],
    disturbance_at: str,
    transfer_function: tuple[FloatArray, FloatArray],
    dt: float,
) -> NDArray[np.complex128]:
    """The part of the measured element its own non-periodic state explains, at ``bins``.

    ``whole`` holds the discrete Fourier transforms of the stretch (whole periods,
    ``size`` samples; ``forcing_bins`` every forcing line's bin). The element
    ``num/den`` (order ``n``) takes ``X`` (``u + fd``, or ``u`` with the disturbance at
    the output) to ``Y`` (``y``, or ``y - fd``). Where ``y`` repeats over the stretch,
    ``Y = H X`` at every bin; where it wanders, each of the element's modes ``lambda``
    adds its non-periodic response, a sampled exponential whose transform over the
    stretch is ``c z/(z - exp(lambda dt))`` at ``z = exp(j omega dt)`` (a geometric
    sum; ``c`` real). Together they are ``z q(z)/den_d(z)``, ``den_d`` the element's
    poles mapped by ``exp(lambda dt)`` and ``q`` a real polynomial of degree below
    ``n``, whatever the realisation.

    ``q`` is fitted by real least squares to ``Y - H X`` at the bins that carry no
    forcing line, up to the highest line: the element relates ``x`` and ``y`` there too
    (both carry the remnant), and a wrong element's error at the forcing lines cannot
    steer the fit, as it could if fitted at the lines themselves (``n`` coefficients can
    match the lowest lines' error). Returned as ``z q/(den_d X)`` at ``bins``, the share
    of ``Y/X`` it takes; zeros for a gain (no state) or too few bins to fit. The element
    is read at the stretch's middle: a time-varying one's transient is not its own.
    """
    num, den = (
        np.trim_zeros(np.asarray(c, dtype=np.float64).reshape(-1), "f") for c in transfer_function
    )
    order = den.size - 1
    zero = np.zeros(bins.shape, dtype=np.complex128)
    if order < 1 or "y" not in whole:
        return zero
    fd = whole.get("fd", np.zeros_like(whole["u"]))
    if disturbance_at == "input":
        x, y = whole["u"] + fd, whole["y"]
    else:
        x, y = whole["u"], whole["y"] - fd
    quiet = np.zeros(x.size, dtype=np.bool_)
    quiet[1 : int(forcing_bins.max()) + 1] = True
    quiet[forcing_bins] = False
    quiet_bins = np.flatnonzero(quiet)
    if quiet_bins.size < 2 * order:
        return zero
    poles = np.real(np.poly(np.exp(np.roots(den) * dt)))

    def transient(at: NDArray[np.int64]) -> NDArray[np.complex128]:
        z = np.exp(2j * np.pi * at / size)  # exp(j omega dt) at those bins
        return np.column_stack([z ** (power + 1) / np.polyval(poles, z) for power in range(order)])

    s = 2j * np.pi * quiet_bins / (size * dt)
    residual = y[quiet_bins] - np.polyval(num, s) / np.polyval(den, s) * x[quiet_bins]
    fitted = transient(quiet_bins)
    scale = np.abs(fitted).max(axis=0)  # columns of one size for the solver
    coefficients = np.linalg.lstsq(
        np.vstack([fitted.real, fitted.imag]) / scale,
        np.concatenate([residual.real, residual.imag]),
        rcond=None,
    )[0]
    return (transient(bins) @ (coefficients / scale)) / x[bins]


def _mean_errors(
    measured: NDArray[np.complex128], model: NDArray[np.complex128]
) -> tuple[float, float]:
    """Mean absolute gain (dB) and phase (degrees, wrapped to +-180) of ``model/measured``."""
    ratio = model / measured
    return (
        float(np.mean(np.abs(20.0 * np.log10(np.abs(ratio))))),
        float(np.mean(np.abs(np.degrees(np.angle(ratio))))),
    )


def _forcing_lines(
    forcing: ForcingPair, period: float | None
) -> tuple[float, list[tuple[int, str]]]:
    """Period and ``(harmonic, source)`` of every periodic forcing line with power."""
    lines: list[tuple[int, str]] = []
    periods: list[float] = []
    for source, signal in (("target", forcing.target), ("disturbance", forcing.disturbance)):
        if signal is None:
            continue
        if not isinstance(signal, Multisine) or signal.measurement_time is None:
            raise ValueError(
                f"the forcing's {source} is not a periodic multisine (one with a "
                "measurement time): its frequencies are not forcing lines"
            )
        periods.append(signal.measurement_time)
        lines += [
            (int(h), source)
            for h, a in zip(signal.harmonics, signal.amplitudes, strict=True)
            if a > 0.0
        ]
    if not lines:
        raise ValueError("the forcing has neither a target nor a disturbance multisine")
    if max(periods) - min(periods) > 1e-9 * max(periods):
        raise ValueError(
            f"the target and disturbance repeat at different periods ({periods[0]:g} and "
            f"{periods[1]:g} s); give a forcing whose signals share one period"
        )
    if period is not None and abs(period - periods[0]) > 1e-9 * period:
        raise ValueError(f"period={period:g} s contradicts the forcing's {periods[0]:g} s")
    return periods[0], lines


def _recorded_lines(recording: Recording, per_period: int, first: int, count: int) -> list:
    """Forcing lines read off the recorded ``ft`` and ``fd`` over one period each."""
    lines: list[tuple[int, str]] = []
    for name, source in (("ft", "target"), ("fd", "disturbance")):
        if name not in recording:
            continue
        signal = recording[name][first : first + per_period * count]
        if not np.all(np.isfinite(signal)) or not np.any(signal):
            continue
        power = np.abs(np.fft.rfft(signal.reshape(count, per_period).mean(axis=0))) ** 2
        power[0] = 0.0
        found = np.flatnonzero(power > _LINE_POWER_FLOOR * power.max())
        if found.size > per_period // 8:
            raise ValueError(
                f"signal {name!r} does not repeat over the period given: {found.size} of "
                f"{power.size} frequency bins carry power (a multisine repeating every period "
                "puts it in a few); check the period"
            )
        lines += [(int(h), source) for h in found]
    if not lines:
        raise ValueError(
            "the recording has no forcing signal with power (ft or fd): the forcing "
            "frequencies cannot be found; give the forcing"
        )
    return lines


def describing_function(
    recording: Recording,
    forcing: ForcingPair | None = None,
    *,
    period: float | None = None,
    element: str | ControlledElement | Mapping[str, Any] | None = None,
    disturbance_at: str | None = None,
    neighbours: int = 2,
    task: str | None = None,
    method: str = "fourier",
) -> DescribingFunction:
    """Measure the pilot's describing function at the forcing frequencies of a run.

    Parameters
    ----------
    recording
        A compensatory run with ``u`` and ``e`` (or ``ft`` and ``y`` to form it).
    forcing
        The run's forcing functions (periodic multisines); defaults to
        ``recording.metadata["forcing"]``. Without one, give ``period``: the forcing
        lines are then read off the recorded ``ft`` and ``fd`` (bins with power within
        60 dB of the strongest, over one period).
    period
        The forcing's period (s), when no forcing is known.
    element
        The controlled element (preset, transfer function text as
        :func:`~manualcontrol.envs.elements.parse_element` reads it, element or dict);
        defaults to ``recording.metadata["controlled_element"]``, else the element is
        measured from the signals. A time-varying element is taken at the stretch's
        middle.
    disturbance_at
        ``"output"`` or ``"input"`` (see :data:`DISTURBANCE_POINTS`); defaults to
        ``recording.metadata["disturbance_at"]``, else ``"output"``. Only the measured
        element depends on it.
    neighbours
        Non-forcing bins each side of a forcing line whose mean u power is the remnant's
        in the signal-to-noise ratio.
    task
        ``"compensatory"`` (the pilot sees the error: ``U/E`` at every line),
        ``"pursuit"`` or ``"preview"`` (the pilot sees the target and ``y``, two
        channels: the arrays hold the disturbance lines, where the target is still and
        ``U/E`` is the pilot's response to ``y``, the loop that crosses over; every line's
        coefficients, the target's too, are in ``lines`` for a two-channel fit); defaults
        to ``recording.metadata["task"]``, else compensatory.
    method
        ``"fourier"`` (default): the stretch is the last whole number of periods of the
        run, each line one bin of its discrete Fourier transform. ``"least-squares"``:
        the stretch is every sample given, of any length, and the coefficients are those
        of sinusoids at every forcing line fitted together by least squares (the lines
        from ``forcing`` or the metadata, or with ``period`` read off a recording of at
        least one period). Its signal-to-noise ratios read the
        residual's spectrum beside each line, scaled by how much the fit's
        non-orthogonal sinusoids (lines closer than one bin of a short stretch) inflate
        the coefficient's variance; on whole periods the sinusoids are orthogonal and
        both methods give the same coefficients.

    Raises ``ValueError`` naming what is missing or inconsistent.
    """
    if not isinstance(recording, Recording):
        raise TypeError(f"recording must be a Recording, got {type(recording).__name__}")
    neighbours = check_int("neighbours", neighbours, minimum=1)
    check_choice("method", method, DESCRIBING_METHODS)
    if task is None:
        task = recording.metadata.get("task", "compensatory")
    check_choice("task", task, ("compensatory", *TWO_CHANNEL_TASKS))
    if forcing is None and period is None and recording.metadata.get("forcing") is not None:
        forcing = ForcingPair.from_dict(recording.metadata["forcing"])
    if period is not None:
        period = check_positive("period", period)
    if forcing is None and period is None:
        raise ValueError(
            "the forcing frequencies are unknown: give the forcing (forcing=) or its "
            "period (period=, seconds), the forcing signals being in the recording"
        )
    if disturbance_at is None:
        disturbance_at = recording.metadata.get("disturbance_at", "output")
    check_choice("disturbance_at", disturbance_at, DISTURBANCE_POINTS)
    if "e" not in recording and "ft" in recording and "y" in recording:
        recording = recording.with_error_signal()
    for name in ("e", "u"):
        if name not in recording:
            raise ValueError(f"the recording needs signal {name!r} for a describing function")
    lines: list[tuple[int, str]] | None = None
    if forcing is not None:
        period, lines = _forcing_lines(forcing, period)
    assert period is not None  # for the type checker; both branches set it
    dt = recording.dt
    exact = period / dt
    per_period = round(exact)
    fourier = method == "fourier"
    if fourier and (per_period < 4 or abs(exact - per_period) > _PERIOD_SAMPLE_TOLERANCE):
        raise ValueError(
            f"the forcing's period {period:g} s is {exact:.4f} samples at dt = {dt:g} s: it "
            "must be a whole number of samples for the Fourier coefficients to hold one "
            "forcing line each (method='least-squares' needs no such period)"
        )
    count = len(recording) // per_period
    if fourier and count < 1:
        raise ValueError(
            f"the recording ({recording.duration:g} s) is shorter than one forcing period "
            f"({period:g} s)"
        )
    if lines is None and count < 1:
        raise ValueError(
            f"method='least-squares' on a recording shorter than the period ({period:g} s) "
            "cannot read the forcing's lines off the recorded ft and fd: give the forcing "
            "(forcing=, or the recording's metadata)"
        )
    first = len(recording) - count * per_period if fourier else 0
    if lines is None:
        # the lines from the last whole periods, as the Fourier method reads them
        lines = _recorded_lines(recording, per_period, len(recording) - count * per_period, count)
    size = count * per_period if fourier else len(recording)
    stretch = slice(first, first + size)
    names = ["e", "u"] + [n for n in ("y", "fd", "ft") if n in recording]
    signals = {}
    for name in names:
        values = recording[name][stretch]
        if not np.all(np.isfinite(values)):
            where = f"the last {count} period(s)" if fourier else "the samples given"
            raise ValueError(
                f"signal {name!r} has dropped samples (NaN) in {where}; fill or cut them first"
            )
        signals[name] = values
    lines = _one_per_harmonic(lines)
    harmonics = np.array([h for h, _ in lines], dtype=np.int64)
    source = tuple(s for _, s in lines)
    frequencies = 2.0 * np.pi * harmonics / period
    if (harmonics.max() >= per_period // 2) if fourier else (frequencies.max() >= np.pi / dt):
        raise ValueError(f"a forcing line lies at or above the Nyquist frequency of dt = {dt:g} s")
    if fourier:
        whole = {name: np.fft.rfft(values) for name, values in signals.items()}
        every_bin = harmonics * count
        all_lines = ForcingLines(
            frequencies=frequencies,
            source=source,
            coefficients={name: values[every_bin] for name, values in whole.items()},
            snr=_signal_to_noise(
                np.abs(whole["u"]) ** 2, every_bin, set(every_bin.tolist()), neighbours
            ),
        )
        shown = _shown_lines(task, source)
        harmonics, frequencies = harmonics[shown], frequencies[shown]
        source = tuple(kind for kind, keep in zip(source, shown, strict=True) if keep)
        bins = harmonics * count
        spectra = {name: values[bins] for name, values in whole.items()}
        transforms = (whole, size, every_bin, bins)
        pilot = spectra["u"] / spectra["e"]
        lines_at = set(every_bin.tolist())  # no line of either forcing counts as a neighbour
        snr = _signal_to_noise(np.abs(whole["u"]) ** 2, bins, lines_at, neighbours)
        snr_injected = _injected_signal_to_noise(
            whole["u"], whole["e"], pilot, bins, lines_at, neighbours
        )
        if count >= 2:
            gain_spread, phase_spread = _period_spread(signals, count, per_period, harmonics, pilot)
        else:
            gain_spread, phase_spread = _remnant_spread(snr_injected)
        u_power = np.abs(whole["u"][1:]) ** 2
        at_lines = np.abs(all_lines.coefficients["u"])
        remnant_share = 1.0 - float(at_lines @ at_lines / u_power.sum())
    else:
        transforms = None  # the element's transient is read off whole periods' transforms
        try:
            fit = _SinusoidFit(signals, dt, frequencies)
        except ValueError as error:
            raise ValueError(
                f"{error}: half the forcing's period ({0.5 * period:g} s) tells lines one "
                "harmonic apart"
            ) from None
        all_lines = ForcingLines(
            frequencies=frequencies,
            source=source,
            coefficients=fit.coefficients,
            snr=fit.signal_to_noise(np.arange(frequencies.size), None, neighbours),
        )
        shown = _shown_lines(task, source)
        frequencies = frequencies[shown]
        source = tuple(kind for kind, keep in zip(source, shown, strict=True) if keep)
        spectra = {name: values[shown] for name, values in fit.coefficients.items()}
        pilot = spectra["u"] / spectra["e"]
        indices = np.flatnonzero(shown)
        snr = fit.signal_to_noise(indices, None, neighbours)
        snr_injected = fit.signal_to_noise(indices, pilot, neighbours)
        gain_spread, phase_spread = _remnant_spread(snr_injected)
        remnant_share = fit.remnant_share
    measured = _measured_element(spectra, disturbance_at)
    if element is None and recording.metadata.get("controlled_element") is not None:
        element = recording.metadata["controlled_element"]
    transfer_function = None
    if element is not None:
        plant = _as_element(element)
        half = 0.5 * count * period if fourier else 0.5 * size * dt
        t_middle = float(recording.t[first] + half)
        response = plant.frequency_response(frequencies, t_middle)
        transfer_function = tuple(
            np.asarray(c, dtype=np.float64).reshape(-1) for c in plant.transfer_function(t_middle)
        )
        drift = (
            None
            if transforms is None
            else _element_drift(*transforms, disturbance_at, transfer_function, dt)
        )
    else:
        response = measured
        drift = None
    open_loop = pilot * response
    # a line the remnant swamps says nothing of |H_ol|: read between it, one can cross 1
    # a decade below the loop's crossover (a DI pilot's 0.2 rad/s for 2)
    readable = _readable(snr_injected)
    if np.all(np.isfinite(open_loop)) and np.count_nonzero(readable) >= 2:
        crossover, margin = _crossover(
            frequencies[readable], open_loop[readable], fit_weights(snr_injected[readable])
        )
    else:
        crossover, margin = math.nan, math.nan
    start = float(recording.t[first])
    return DescribingFunction(
        frequencies=frequencies,
        source=source,
        pilot=pilot,
        gain_spread_db=gain_spread,
        phase_spread_deg=phase_spread,
        snr=snr,
        snr_injected=snr_injected,
        element=response,
        element_measured=measured,
        open_loop=open_loop,
        crossover_frequency=crossover,
        phase_margin=margin,
        remnant_share=remnant_share,
        period=float(period),
        periods=count,
        window=(start, start + size * dt),
        disturbance_at=disturbance_at,
        element_given=element is not None,
        element_transfer_function=transfer_function,
        element_drift=drift,
        task=task,
        lines=all_lines,
        method=method,
    )


def _one_per_harmonic(lines: Sequence[tuple[int, str]]) -> list[tuple[int, str]]:
    """``(harmonic, source)`` in ascending order, one per harmonic.

    A harmonic the target and the disturbance both drive is one bin of every signal:
    listed once for each, its power would count twice (a remnant share below zero) and
    its response twice in a fit. It is listed once, its source :data:`SHARED_LINE`.
    """
    sources: dict[int, set[str]] = {}
    for harmonic, source in lines:
        sources.setdefault(harmonic, set()).add(source)
    return [
        (harmonic, next(iter(kinds)) if len(kinds) == 1 else SHARED_LINE)
        for harmonic, kinds in sorted(sources.items())
    ]


def _shown_lines(task: str, source: tuple[str, ...]) -> NDArray[np.bool_]:
    """The lines the describing function is read at: all, or a two-channel task's disturbance's."""
    if task not in TWO_CHANNEL_TASKS:
        return np.ones(len(source), dtype=np.bool_)
    shown = np.array([kind == "disturbance" for kind in source])
    if not shown.any():
        shared = " line the target does not share" if SHARED_LINE in source else ""
        raise ValueError(
            f"a {task} task's describing function is read at the disturbance's lines, "
            f"where the target is still, and this forcing has no disturbance{shared}"
        )
    return shown


def _remnant_spread(snr_injected: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The spread the remnant implies (one period): ``|N/U|`` split over gain and phase."""
    relative = 1.0 / np.sqrt(2.0 * snr_injected)
    gain_spread = 20.0 / math.log(10.0) * relative
    phase_spread = np.degrees(np.minimum(relative, np.pi))
    return gain_spread, phase_spread


class _SinusoidFit:
    """Sinusoids at the forcing lines fitted to signals by least squares.

    ``coefficients`` are on the discrete Fourier transform's scale (``N/2`` times the
    complex amplitude ``a - i b`` of ``a cos wt + b sin wt``, time from the stretch's
    first sample), so on whole periods they equal the transform's bins. The residual
    (what the sinusoids and the mean leave) is the remnant; its transform beside each
    line is the line's noise, times the variance inflation of the line's coefficient:
    ``N/4`` times the sum of the cosine's and sine's diagonal entries of
    ``(X^T X)^-1`` (1 for orthogonal sinusoids, more where a short stretch leaves
    neighbouring lines less than a bin apart).
    """

    def __init__(
        self, signals: Mapping[str, FloatArray], dt: float, frequencies: FloatArray
    ) -> None:
        names = list(signals)
        values = np.column_stack([signals[name] for name in names])
        size, lines = values.shape[0], frequencies.size
        phase = np.outer(np.arange(size) * dt, frequencies)
        basis = np.hstack([np.ones((size, 1)), np.cos(phase), np.sin(phase)])
        # the normal equations: the columns are of one scale (unit sinusoids and the
        # mean), and a basis whose lines cannot be told apart is refused before its
        # squared condition number matters
        gram = basis.T @ basis
        if size <= basis.shape[1] or np.linalg.cond(gram) > _SINUSOID_CONDITION_LIMIT**2:
            raise ValueError(
                f"the stretch ({size * dt:g} s) is too short to tell the {lines} forcing lines "
                "apart by least squares"
            )
        inverse = np.linalg.inv(gram)
        solution = inverse @ (basis.T @ values)
        residual = values - basis @ solution
        cosine, sine = solution[1 : 1 + lines], solution[1 + lines :]
        self.coefficients = {
            name: 0.5 * size * (cosine[:, j] - 1j * sine[:, j]) for j, name in enumerate(names)
        }
        diagonal = np.diag(inverse)
        self.inflation = 0.25 * size * (diagonal[1 : 1 + lines] + diagonal[1 + lines :])
        self.residual = {name: np.fft.rfft(residual[:, j]) for j, name in enumerate(names)}
        self.bins = np.rint(frequencies * size * dt / (2.0 * np.pi)).astype(np.int64)
        u = values[:, names.index("u")]
        centred = u - u.mean()
        at_lines = basis[:, 1:] @ solution[1:, names.index("u")]
        power = float(centred @ centred)
        self.remnant_share = 1.0 - float(at_lines @ at_lines) / power if power > 0.0 else math.nan

    def signal_to_noise(
        self, indices: NDArray[np.int64], pilot: NDArray[np.complex128] | None, neighbours: int
    ) -> FloatArray:
        """The power of u at each line of ``indices`` over the noise beside it.

        The noise is the residual of u, or with ``pilot`` (``H_p`` at those lines) the
        injected remnant's ``U - H_p E``, as :func:`_injected_signal_to_noise` reads it.
        """
        u, e = self.residual["u"], self.residual["e"]
        lines_at = set(self.bins.tolist())
        ratios = np.empty(indices.size)
        for i, line in enumerate(indices):
            near = _neighbour_bins(int(self.bins[line]), lines_at, u.size, neighbours)
            noise_at = u[near] if pilot is None else u[near] - pilot[i] * e[near]
            noise = float(np.mean(np.abs(noise_at) ** 2)) * self.inflation[line] if near else 0.0
            signal = abs(self.coefficients["u"][line]) ** 2
            ratios[i] = signal / noise if noise > 0.0 else math.inf
        return ratios


def _as_element(element: Any) -> ControlledElement:
    return make_element(element)  # presets, written transfer functions, dicts


def _period_spread(
    signals: Mapping[str, FloatArray],
    count: int,
    per_period: int,
    harmonics: NDArray[np.int64],
    pilot: NDArray[np.complex128],
) -> tuple[FloatArray, FloatArray]:
    """Standard deviation of the per-period estimates around the whole-stretch one."""
    u = np.fft.rfft(signals["u"].reshape(count, per_period), axis=1)[:, harmonics]
    e = np.fft.rfft(signals["e"].reshape(count, per_period), axis=1)[:, harmonics]
    ratio = (u / e) / pilot
    gain = np.std(20.0 * np.log10(np.abs(ratio)), axis=0, ddof=1)
    phase = np.std(np.degrees(np.angle(ratio)), axis=0, ddof=1)
    return gain, phase


def _signal_to_noise(
    power: FloatArray, bins: NDArray[np.int64], forcing: set[int], neighbours: int
) -> FloatArray:
    """Power at each of ``bins`` over the mean power of its nearest bins not in ``forcing``."""
    ratios = np.empty(bins.shape)
    for i, b in enumerate(bins):
        near = _neighbour_bins(b, forcing, power.size, neighbours)
        noise = float(np.mean(power[near])) if near else 0.0
        ratios[i] = power[b] / noise if noise > 0.0 else math.inf
    return ratios


def _injected_signal_to_noise(
    u: NDArray[np.complex128],
    e: NDArray[np.complex128],
    pilot: NDArray[np.complex128],
    bins: NDArray[np.int64],
    forcing: set[int],
    neighbours: int,
) -> FloatArray:
    """Power of u at each forcing bin over the injected remnant's ``|U - H_p E|^2`` nearby."""
    ratios = np.empty(bins.shape)
    for i, b in enumerate(bins):
        near = _neighbour_bins(b, forcing, u.size, neighbours)
        noise = float(np.mean(np.abs(u[near] - pilot[i] * e[near]) ** 2)) if near else 0.0
        ratios[i] = abs(u[b]) ** 2 / noise if noise > 0.0 else math.inf
    return ratios


def _neighbour_bins(b: int, forcing: set[int], size: int, neighbours: int) -> list[int]:
    """The ``neighbours`` nearest bins each side of ``b`` that carry no forcing line."""
    near: list[int] = []
    for direction in (-1, 1):
        k, taken = b + direction, 0
        while 0 < k < size and taken < neighbours:
            if k not in forcing:
                near.append(k)
                taken += 1
            k += direction
    return near


def _measured_element(
    spectra: Mapping[str, NDArray[np.complex128]], disturbance_at: str
) -> NDArray[np.complex128]:
    """``H_c`` at the forcing lines from ``y``, ``u`` and the disturbance as recorded."""
    u = spectra["u"]
    if "y" not in spectra:
        return np.full(u.shape, complex(math.nan, math.nan))
    y = spectra["y"]
    fd = spectra.get("fd", np.zeros_like(u))
    if disturbance_at == "input":
        return y / (u + fd)
    return (y - fd) / u


# ----------------------------------------------------------------------- model fit

#: Bounds of the describing-function fit: the ranges human tracking experiments report
#: (delays 0.05-0.6 s, neuromuscular frequency 4-30 rad/s, damping 0.05-1.2; preview
#: times up to 2 s, the far view's break and gain within a factor 10 of what van der El
#: measured), gains of any size, which the plant decides, and a lag (McRuer's ``T_I``) of
#: any length but never negative, which would make the equaliser unstable. A fit that
#: ends on a bound says the model does not describe these data there
#: (``ModelFit.at_bounds``).
FIT_BOUNDS: dict[str, tuple[float, float]] = {
    "K_p": (1e-6, math.inf),
    "K_v": (0.0, math.inf),
    "tau_v": (0.05, 0.6),
    "omega_nms": (4.0, 30.0),
    "zeta_nms": (0.05, 1.2),
    "K_f": (0.1, 10.0),
    "omega_f": (0.1, 30.0),
    "tau_f": (0.0, 2.0),
    "T_I": (0.0, math.inf),
}
#: Starting values tried for the fitted parameters (every combination; ``K_p`` is then
#: solved for the mean gain of each start): the delays, neuromuscular modes and leads
#: humans show, so the multistart covers the basins the phase wrap makes. The two-channel
#: models, with three more parameters, take a coarser grid of the same span.
FIT_STARTS: dict[str, tuple[float, ...]] = {
    "tau_v": (0.12, 0.2, 0.3, 0.45),
    "omega_nms": (7.0, 12.0, 20.0),
    "zeta_nms": (0.2, 0.6),
    "T_L": (0.0, 0.5),
}
TWO_CHANNEL_STARTS: dict[str, tuple[float, ...]] = {
    "tau_v": (0.15, 0.3),
    "omega_nms": (8.0, 15.0),
    "zeta_nms": (0.4,),
    "T_L": (0.0,),
    "K_f": (1.0,),
    "omega_f": (1.0, 5.0),
    "tau_f": (0.3, 0.8),
}


@dataclass(frozen=True)
class ModelFit:
    """A pilot model fitted to a describing function.

    ``values`` holds every model parameter (fixed ones as given), ``standard_deviations``
    the fitted ones' (from the weighted residuals' Jacobian; NaN for one the fit left on
    a bound, held there for the others'), ``response`` the model's
    counterpart of :attr:`DescribingFunction.pilot` (``U/E``: the error channel, or
    minus the output channel of a two-channel model), ``gain_error_db`` and
    ``phase_error_deg`` the mean absolute gap of the model's predicted ``U`` to the
    measured one over the lines fitted, ``crossover_frequency`` and ``phase_margin`` the
    model's loop with the element (on a fine grid), ``at_bounds`` the fitted parameters
    that ended on a bound of :data:`FIT_BOUNDS`.
    """

    model: str
    values: dict[str, float]
    standard_deviations: dict[str, float]
    fitted: tuple[str, ...]
    response: NDArray[np.complex128]
    gain_error_db: float
    phase_error_deg: float
    crossover_frequency: float
    phase_margin: float
    cost: float
    at_bounds: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary."""
        return {
            "model": self.model,
            "values": {k: _finite_or_none(v) for k, v in self.values.items()},
            "standard_deviations": {
                k: _finite_or_none(v) for k, v in self.standard_deviations.items()
            },
            "fitted": list(self.fitted),
            "gain_error_db": _finite_or_none(self.gain_error_db),
            "phase_error_deg": _finite_or_none(self.phase_error_deg),
            "crossover_frequency": _finite_or_none(self.crossover_frequency),
            "phase_margin": _finite_or_none(self.phase_margin),
            "at_bounds": list(self.at_bounds),
        }


def fit_weights(snr: FloatArray) -> FloatArray:
    """Weight of each forcing frequency in a fit: ``SNR / (1 + SNR)``.

    The share of the line's power that is the forcing's: near 1 where the remnant is
    small, falling as it grows. Not the inverse variance (``~ SNR``), which would let the
    two or three lines of highest SNR decide the whole fit of a model that is only an
    approximation of a human. One-channel fits weigh by ``snr_injected``, two-channel
    fits by u's ``snr`` (the injected remnant needs the pilot's response to both
    perceptions, which is what is being fitted).
    """
    snr = np.asarray(snr, dtype=np.float64)
    return 1.0 - 1.0 / (1.0 + snr)


class _FitTarget:
    """What a model is fitted to: the predicted-over-measured ``U`` at the lines fitted."""

    def __init__(self, describing: DescribingFunction, model: str | PilotModel) -> None:
        structure = make_model(model)
        self.structure = structure
        if structure.perceptions == ("e",):
            if not task_named(describing.task).shows_error_only:
                raise ValueError(
                    f"the {structure.name} model responds to the error alone, and this is a "
                    f"{describing.task} task's describing function (the pilot sees the "
                    "target and y): fit the preview model"
                )
            self.omega = describing.frequencies
            self.weights = fit_weights(describing.snr_injected)
            measured = describing.pilot

            def ratio(values: Mapping[str, float]) -> NDArray[np.complex128]:
                return structure.frequency_response(values, self.omega, "e") / measured

        elif structure.perceptions == ("ft_far", "y"):
            lines = describing.lines
            if describing.task not in TWO_CHANNEL_TASKS or lines is None:
                raise ValueError(
                    f"the {structure.name} model reads the target and y: fit it to a pursuit "
                    "or preview task's describing function (task='pursuit' or 'preview')"
                )
            if "ft" not in lines.coefficients or "y" not in lines.coefficients:
                raise ValueError("a two-channel fit needs the recorded target ft and output y")
            self.omega = lines.frequencies
            self.weights = fit_weights(lines.snr)
            ft, y, u = (lines.coefficients[name] for name in ("ft", "y", "u"))

            def ratio(values: Mapping[str, float]) -> NDArray[np.complex128]:
                responses = channel_responses(structure, values, self.omega)
                return (responses["ft_far"] * ft + responses["y"] * y) / u

        else:
            raise ValueError(
                f"the {structure.name} model's perceptions ({', '.join(structure.perceptions)}) "
                "cannot be fitted to a describing function (error alone, or target and y)"
            )
        self.ratio = ratio

    def errors(self, values: Mapping[str, float], weighted: bool) -> tuple[float, float]:
        """Mean absolute gain (dB) and phase (degrees) gaps of the predicted ``U``."""
        ratio = self.ratio(values)
        weights = self.weights if weighted else np.ones(ratio.shape)
        weights = weights / weights.sum()
        return (
            float(weights @ np.abs(20.0 * np.log10(np.abs(ratio)))),
            float(weights @ np.abs(np.degrees(np.angle(ratio)))),
        )


def channel_responses(
    structure: PilotModel, values: Mapping[str, float], omega: FloatArray
) -> dict[str, NDArray[np.complex128]]:
    """The model's response to each perception, as the display shows it.

    ``{perception: response}``; the far view's (``ft_far``, the target ``tau_f`` ahead)
    times its preview ``exp(j w tau_f)``, so that it is the response to the recorded
    target ``ft`` and a preview time's error counts.
    """
    responses = {}
    for channel in structure.perceptions:
        response = structure.frequency_response(values, omega, channel)
        if channel == "ft_far":
            response = response * np.exp(1j * omega * values["tau_f"])
        responses[channel] = response
    return responses


def loop_response(
    structure: PilotModel, values: Mapping[str, float], omega: FloatArray
) -> NDArray[np.complex128]:
    """The pilot's part of the loop that crosses over.

    ``U/E`` of the error channel, or minus the response to ``y`` of a two-channel model
    (``u`` to ``y`` closes the loop).
    """
    if structure.perceptions == ("e",):
        return structure.frequency_response(values, omega, "e")
    return -structure.frequency_response(values, omega, "y")


def response_error(
    describing: DescribingFunction, model: str | PilotModel, values: Mapping[str, float]
) -> tuple[float, float]:
    """Gap of a model's predicted ``U`` to the measured one: (dB, degrees).

    Mean absolute gain and phase gaps over the lines a fit of that model reads (the
    error's ``U/E`` for a one-channel model, every line's ``U`` from the target and ``y``
    for a two-channel one), each weighted by :func:`fit_weights` (its share of forcing
    power), so lines the remnant swamps, on which even the true pilot misses the
    measurement, count little.
    """
    return _FitTarget(describing, model).errors(values, weighted=True)


def fit_describing_function(
    describing: DescribingFunction,
    model: str | PilotModel = "precision",
    *,
    fixed: Mapping[str, float] | None = None,
) -> ModelFit:
    """Fit a pilot model's exact frequency response to a describing function.

    Minimises ``sum_k w_k |ln(U_model,k / U_k)|^2`` (the complex logarithm: gain ratio
    and phase gap on one footing; for a one-channel model ``U_model/U`` is ``H_model /
    H_p``) with ``w_k`` from :func:`fit_weights`, by bounded least squares
    (:data:`FIT_BOUNDS`) from every start of :data:`FIT_STARTS` (two-channel models:
    :data:`TWO_CHANNEL_STARTS`), ``K_p`` of each start solved for the mean log gain.
    ``fixed`` holds parameters at given values (e.g. ``{"zeta_nms": 0.5}``), beside what
    is held by rule: ``K_v`` is held at 0 where the element is a single integrator ``K/s``, on which
    humans need no lead and the time-domain filters hold it at 0 too (a free lead there
    trades off against the neuromuscular lag along a ridge that remnant moves the fit
    along), or a pure gain, on which they lag instead (McRuer & Jex 1967; the lead traded
    against the delay there, to a delay on its lower bound), and a pursuit task's
    ``tau_f`` at 0 (nothing is shown ahead).
    """
    import scipy.optimize

    target = _FitTarget(describing, model)
    structure = target.structure
    names = structure.parameter_names
    held = {"K_v": 0.0} if _needs_no_lead(describing) and "K_v" in names else {}
    display = task_named(describing.task)
    if display.shows_target and not display.shows_preview and "tau_f" in names:
        held["tau_f"] = 0.0  # the target shown, nothing ahead of it
    fixed = {**held, **(fixed or {})}  # what the user holds adds to (or sets) the rules
    unknown = sorted(set(fixed) - set(names))
    if unknown:
        raise ValueError(
            f"fixed names {unknown}, which the {structure.name} model does not have "
            f"(its parameters: {', '.join(names)})"
        )
    fitted = tuple(n for n in names if n not in fixed)
    if not fitted:
        raise ValueError("every parameter is fixed: nothing to fit")
    if target.omega.size < len(fitted):
        raise ValueError(
            f"{target.omega.size} forcing frequencies cannot determine {len(fitted)} parameters"
        )
    weights = np.sqrt(target.weights)
    nominal = structure.nominal()
    bounds = [FIT_BOUNDS.get(n, (-math.inf, math.inf)) for n in fitted]
    lower = np.array([b[0] for b in bounds])
    upper = np.array([b[1] for b in bounds])

    def values_of(x: FloatArray) -> dict[str, float]:
        return {**nominal, **fixed, **dict(zip(fitted, map(float, x), strict=True))}

    def residuals(x: FloatArray) -> FloatArray:
        log_ratio = np.log(target.ratio(values_of(x)))
        return np.concatenate([weights * log_ratio.real, weights * _wrap(log_ratio.imag)])

    best = None
    for start in _starts(target, fitted, fixed, nominal):
        x0 = np.clip([start[n] for n in fitted], lower, upper)
        # a start on its finite lower bound moves just inside it (an unbounded one's
        # nudge is -inf + inf, never taken: its start is finite)
        with np.errstate(invalid="ignore"):
            x0 = np.where(x0 == lower, lower + 1e-6 * np.maximum(1.0, np.abs(lower)), x0)
        with np.errstate(all="ignore"):
            result = scipy.optimize.least_squares(
                residuals, x0, bounds=(lower, upper), x_scale="jac"
            )
        if np.isfinite(result.cost) and (best is None or result.cost < best.cost):
            best = result
    if best is None:
        raise ValueError("the fit found no finite solution from any start")
    values = values_of(best.x)
    gain_error, phase_error = target.errors(values, weighted=False)
    crossover, margin = model_crossover(structure, values, describing)
    span = upper - lower
    scale = np.where(np.isfinite(span), span, np.abs(best.x))
    near = (np.abs(best.x - lower) <= 1e-4 * scale) | (np.abs(best.x - upper) <= 1e-4 * scale)
    # K_v at 0 and tau_f at 0 are the lead-free and preview-free pilots, not a bound hit
    at_bounds = tuple(
        n
        for n, hit, x in zip(fitted, near, best.x, strict=True)
        if hit and not (n in ("K_v", "tau_f") and x <= 1e-4 * max(scale[fitted.index(n)], 1.0))
    )
    return ModelFit(
        model=structure.registered_name,
        values=values,
        standard_deviations=_standard_deviations(best, fitted, target.omega.size),
        fitted=fitted,
        response=loop_response(structure, values, describing.frequencies),
        gain_error_db=gain_error,
        phase_error_deg=phase_error,
        crossover_frequency=crossover,
        phase_margin=margin,
        cost=float(best.cost),
        at_bounds=at_bounds,
    )


def _needs_no_lead(describing: DescribingFunction) -> bool:
    """Whether the given element is ``K/s`` or a pure gain ``K``.

    McRuer's pilot leads on neither (on ``K`` it lags instead).
    """
    if describing.element_transfer_function is None:
        return False
    num, den = (np.trim_zeros(c, "f") for c in describing.element_transfer_function)
    return num.size == 1 and (den.size == 1 or (den.size == 2 and den[1] == 0.0))


def _wrap(phase: FloatArray) -> FloatArray:
    return (phase + np.pi) % (2.0 * np.pi) - np.pi


def _starts(
    target: _FitTarget,
    fitted: Sequence[str],
    fixed: Mapping[str, float],
    nominal: Mapping[str, float],
) -> list[dict[str, float]]:
    table = FIT_STARTS if target.structure.perceptions == ("e",) else TWO_CHANNEL_STARTS
    grid = [
        (name, options)
        for name, options in table.items()
        if (name in fitted) or (name == "T_L" and "K_v" in fitted)
    ]
    starts = []
    for combination in itertools.product(*(options for _, options in grid)):
        start = {**nominal, **fixed, **dict(zip((n for n, _ in grid), combination, strict=True))}
        lead = start.pop("T_L", 0.0)
        if "K_p" in fitted:
            start["K_p"] = 1.0
            if "K_v" in fitted:
                start["K_v"] = lead
            # K_p scales every channel (all pass the equalisation): solve it for the gain
            start["K_p"] = float(np.exp(-np.mean(np.log(np.abs(target.ratio(start))))))
            if "K_v" in fitted:
                start["K_v"] = lead * start["K_p"]
        starts.append(start)
    return starts


def _standard_deviations(result: Any, fitted: Sequence[str], count: int) -> dict[str, float]:
    """From ``(J'J)^-1`` scaled by the residual variance (Gauss-Newton, local).

    A parameter the fit left on a bound (``least_squares``' ``active_mask``) is held
    there for this, its own deviation NaN: the local covariance assumes the fit could
    move either way, and along a direction a bound closes it can be unbounded. A lead
    ``K_v`` at 0 is one: a small lead is, to first order, a shorter delay, so without
    the bound ``J'J`` is singular along that pair, and its pseudo-inverse puts an
    unbounded deviation on a delay the data pin tightly.
    """
    free = np.asarray(result.active_mask) == 0
    dof = 2 * count - int(free.sum())
    if dof <= 0:
        return dict.fromkeys(fitted, math.nan)
    jacobian = result.jac[:, free]
    variance = 2.0 * result.cost / dof
    try:
        covariance = np.linalg.pinv(jacobian.T @ jacobian) * variance
    except np.linalg.LinAlgError:
        return dict.fromkeys(fitted, math.nan)
    deviations = iter(np.sqrt(np.maximum(np.diag(covariance), 0.0)))
    return {
        n: float(next(deviations)) if f else math.nan for n, f in zip(fitted, free, strict=True)
    }


def model_crossover(
    structure: PilotModel, values: Mapping[str, float], describing: DescribingFunction
) -> tuple[float, float]:
    """Crossover and phase margin of the model's loop with the element, fine grid.

    The element's response between forcing frequencies needs its transfer function:
    with only a measured element the model's loop is read at the forcing frequencies.
    """
    if describing.element_transfer_function is not None:
        num, den = describing.element_transfer_function
        grid = np.geomspace(describing.frequencies[0] / 3.0, describing.frequencies[-1] * 3.0, 2000)
        element = np.polyval(num, 1j * grid) / np.polyval(den, 1j * grid)
        return _crossover(grid, loop_response(structure, values, grid) * element)
    loop = loop_response(structure, values, describing.frequencies) * describing.element
    if not np.all(np.isfinite(loop)):
        return math.nan, math.nan
    return _crossover(describing.frequencies, loop)
