"""How well an identification holds: the checks every time-domain fit of a trial gets.

A filter's one-step VAF can read 94 % while its parameters sit on limits and its model
misses the human's frequency response by tens of degrees; a trial in which the cursor
never moves identifies without a word. :func:`check_fit` therefore reports, beside the
one-step and resimulated VAF, what an independent measurement says:

* the identified model's frequency response, with its parameters at their medians over
  the second half of the run, against the describing function measured at the forcing
  frequencies (:mod:`~manualcontrol.estimators.analysis.frequency`): mean absolute gain gap
  (dB) and phase gap (degrees), and the identified loop's crossover and phase margin;
* the innovations' whiteness (white only when ``u`` is the model's output plus the white
  noise the filter assumes; warned where no describing function vouches for the model,
  since a human's coloured remnant, dynamics the model lacks, or noise-free data, where
  the small residue left is smooth, all colour them);
* signals that barely move (nothing to identify);
* parameters that sit at a limit of the filter's projection for more than
  :data:`PINNED_SHARE` of the run: the value there is the limit's, not the pilot's.

The one-step VAF leaves out the filter's start-up: the samples before its innovation
variance first comes within a factor :data:`SETTLED_FACTOR` of its median over the
second half of the run, when its own uncertainty says it has settled. A joint filter
started far from the pilot otherwise scores a transient of thousands of per cent.

Each finding that should stop a user reading the numbers as found becomes a sentence in
``FitCheck.warnings``, saying what was seen and what to do, with the settings and
keywords named as Python names them (``limits=``, ``element=``; the command line prints
them as its flags).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.analysis.frequency import (
    DescribingFunction,
    fit_describing_function,
    model_crossover,
    response_error,
)
from manualcontrol.estimators.analysis.metrics import innovation_whiteness, pilot_model_of, vaf
from manualcontrol.estimators.protocol import EstimationResult

__all__ = [
    "PINNED_SHARE",
    "SETTLED_FACTOR",
    "FitCheck",
    "check_fit",
    "column_medians",
    "limit_shares",
    "second_half_values",
    "time_at_limits",
]

FloatArray = NDArray[np.float64]

#: The filter has settled once its innovation variance is within this factor of its
#: second-half median (a variance still twice its working level is start-up).
SETTLED_FACTOR = 2.0
#: Innovation autocorrelation lags tested for whiteness, in seconds (0.5 s: the 50 lags of
#: a 100-Hz run; counted in seconds so that a 60-Hz and a 1-kHz run test the same span).
WHITENESS_SPAN = 0.5
#: Share of innovation autocorrelation lags outside the 95 % white-noise band above
#: which the model is said to leave structure in the data (white innovations: about 5 %;
#: four times that is no chance outcome over that many lags).
WHITENESS_LIMIT = 0.2
#: A signal whose standard deviation is below this share of the forcing's barely moves.
BARELY_MOVES = 0.01
#: Share of the run a parameter may spend at a limit before it is reported: a filter
#: touches a limit in passing; one that stays there has been stopped by it.
PINNED_SHARE = 0.05


@dataclass(frozen=True)
class FitCheck:
    """The checks of one identification; see the module docstring.

    ``frequency`` holds ``gain_error_db``, ``phase_error_deg``, ``crossover_frequency``
    and ``phase_margin`` of the identified model (second-half medians, ``values``) and
    the measured loop's ``measured_crossover_frequency`` and ``measured_phase_margin``;
    None where no describing function could be measured (``frequency_note`` says why).
    """

    one_step_vaf: float
    scored_from: float
    resimulated_vaf: float
    innovation_lag1: float
    innovation_outside: float
    frequency: dict[str, Any] | None
    frequency_note: str
    at_limits: dict[str, dict[str, float]] = field(default_factory=dict)
    warnings: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form for a summary file."""
        return {
            "vaf_one_step_percent": _rounded(self.one_step_vaf),
            "one_step_scored_from_s": _rounded(self.scored_from),
            "vaf_resimulated_percent": _rounded(self.resimulated_vaf),
            "innovation_lag1_autocorrelation": _rounded(self.innovation_lag1),
            "innovation_lags_outside_95_percent": _rounded(self.innovation_outside),
            "frequency_check": self.frequency,
            "frequency_note": self.frequency_note,
            "at_limits": self.at_limits,
            "warnings": list(self.warnings),
        }


def _rounded(value: float) -> float | None:
    return round(float(value), 4) if math.isfinite(value) else None


def second_half_values(result: EstimationResult, samples: int | None = None) -> dict[str, float]:
    """Median of every parameter's estimate over the second half of the run.

    With ``samples``, of its first ``samples`` rows (the run so far, for a causal choice).
    """
    stop = len(result) if samples is None else samples
    return column_medians(result.mean[stop // 2 : stop], result.parameter_names)


def column_medians(rows: FloatArray, names: tuple[str, ...]) -> dict[str, float]:
    """Median of each column of ``rows`` (one per name) over its finite values."""
    return {name: _median(rows[:, j]) for j, name in enumerate(names)}


def _median(values: FloatArray) -> float:
    """Median of the finite values; NaN when there are none (a diverged filter)."""
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else math.nan


def settled_index(variance: FloatArray) -> int:
    """First sample whose innovation variance is within :data:`SETTLED_FACTOR` of the median.

    The median over the second half of the run; 0 when no sample is (or none is finite).
    """
    variance = np.asarray(variance, dtype=np.float64)
    finite = np.isfinite(variance)
    if not finite.any():
        return 0
    level = _median(variance[len(variance) // 2 :])
    settled = np.flatnonzero(finite & (variance <= SETTLED_FACTOR * level))
    return int(settled[0]) if settled.size else 0


def check_fit(
    recording: Recording,
    result: EstimationResult,
    *,
    model_output: FloatArray | None = None,
    describing: DescribingFunction | None = None,
    frequency_note: str = "",
) -> FitCheck:
    """Score an identification of ``recording`` and say where it should not be trusted.

    ``model_output`` is the identified model resimulated (its VAF against ``u``);
    ``describing`` the trial's measured describing function (the frequency-domain
    cross-check; ``frequency_note`` says why there is none when it is None).
    """
    u = recording.u
    prediction = result.prediction
    start = settled_index(result.innovation_variance)
    finite = np.isfinite(u) & np.isfinite(prediction)
    finite[:start] = False
    one_step = vaf(u[finite], prediction[finite]) if finite.any() else math.nan
    scored = np.isfinite(u) if not np.isfinite(prediction).any() else finite
    resimulated = math.nan
    if model_output is not None:
        with np.errstate(all="ignore"):
            resimulated = vaf(u[scored], np.asarray(model_output)[scored])
    lags = max(round(WHITENESS_SPAN / recording.dt), 1)
    r_1, outside = innovation_whiteness(result.innovation, result.innovation_variance, max_lag=lags)
    warnings = _movement_warnings(recording)
    frequency = None
    frequency_warnings: list[str] = []
    if describing is not None:
        frequency, note = _frequency_check(result, describing)
        if note:
            frequency_note = note
        if frequency is not None:
            frequency_warnings = _frequency_warnings(frequency)
    # coloured innovations are the rule for a model of a human (and for the RML, whose R
    # is a weighting): a warning only where the describing function cannot vouch for the
    # model, or does not; the figures are in the summary either way
    if (
        math.isfinite(outside)
        and outside > WHITENESS_LIMIT
        and (frequency is None or frequency_warnings)
    ):
        warnings.append(
            f"the innovations are not white: {100 * outside:.0f} % of lags up to "
            f"{WHITENESS_SPAN:g} s lie outside "
            "the 95 % white-noise band (white: about 5 %), so the model leaves structure "
            "in u unexplained; read the parameters with care"
            + ("" if frequency is not None else " (no describing function to check them by)")
        )
    at_limits = time_at_limits(result)
    for name, where in at_limits.items():
        side = "lower" if where["side"] == "lower" else "upper"
        warnings.append(
            f"{name} sits at its {side} limit {where['limit']:g} for "
            f"{100 * where['share']:.0f} % of the run: there it reports the limit, not the "
            f"pilot; widen it (limits={{'{name}': [low, high]}}), give the experiment's "
            "element (element=) if the limits are a thesis's, or hold the parameter at a "
            "known value"
        )
    warnings += frequency_warnings
    return FitCheck(
        one_step_vaf=one_step,
        scored_from=float(result.t[start]) if len(result) else math.nan,
        resimulated_vaf=resimulated,
        innovation_lag1=r_1,
        innovation_outside=outside,
        frequency=frequency,
        frequency_note=frequency_note,
        at_limits=at_limits,
        warnings=tuple(warnings),
    )


def limit_shares(result: EstimationResult) -> dict[str, tuple[float, str, float]]:
    """Share of the run each limited parameter spends at a limit: ``(share, side, limit)``.

    From the limits the filter resolved (``result.settings["resolved"]["limits"]``); a
    sample is at a limit within 1e-6 of the limits' span; the side with the larger share.
    """
    resolved = result.settings.get("resolved")
    limits = resolved.get("limits", {}) if isinstance(resolved, Mapping) else {}
    shares: dict[str, tuple[float, str, float]] = {}
    for name, pair in limits.items():
        if name not in result.parameter_names:
            continue
        low, high = (float(v) for v in pair)
        values = result.mean_of(name)
        values = values[np.isfinite(values)]
        if not values.size:
            continue
        tolerance = 1e-6 * (high - low) if math.isfinite(high - low) else 1e-9
        best = (0.0, "lower", low)
        for side, limit in (("lower", low), ("upper", high)):
            if math.isfinite(limit):
                share = float(np.mean(np.abs(values - limit) <= tolerance))
                if share > best[0]:
                    best = (share, side, limit)
        shares[name] = best
    return shares


def time_at_limits(result: EstimationResult) -> dict[str, dict[str, Any]]:
    """Estimated parameters at a limit for more than :data:`PINNED_SHARE` of the run.

    ``{name: {"limit": value, "side": "lower"|"upper", "share": fraction}}``, from
    :func:`limit_shares`.
    """
    return {
        name: {"limit": limit, "side": side, "share": round(share, 4)}
        for name, (share, side, limit) in limit_shares(result).items()
        # a lead of 0 is the lead-free pilot, the structure's edge, not a range's end
        if share > PINNED_SHARE and not (name == "K_v" and side == "lower" and limit == 0.0)
    }


def _movement_warnings(recording: Recording) -> list[str]:
    """A control or a cursor that never (or barely) moves leaves nothing to identify."""
    forcing = [recording[n] for n in ("ft", "fd") if n in recording]
    scale = max((float(np.nanstd(f)) for f in forcing), default=math.nan)
    found = []
    for name, what in (("u", "the control u"), ("y", "the output y"), ("e", "the error e")):
        if name not in recording:
            continue
        spread = float(np.nanstd(recording[name]))
        if np.nanmax(recording[name]) == np.nanmin(recording[name]):
            found.append(f"{what} never moves (constant {float(np.nanmean(recording[name])):g})")
        elif math.isfinite(scale) and scale > 0.0 and spread < BARELY_MOVES * scale:
            found.append(
                f"{what} barely moves (standard deviation {spread:.3g}, "
                f"{100 * spread / scale:.2g} % of the forcing's)"
            )
    if found:
        return [
            "; ".join(found) + ": there is little or nothing to identify; check the column "
            "mapping and that the trial was flown"
        ]
    return []


def _frequency_check(
    result: EstimationResult, describing: DescribingFunction
) -> tuple[dict[str, Any] | None, str]:
    """The identified model (second-half medians) against the measured describing function."""
    model = pilot_model_of(result)
    if model is None:
        return None, f"not checked: the {result.estimator} model is not a pilot model structure"
    values = second_half_values(result)
    if not all(math.isfinite(v) for v in values.values()):
        return None, "not checked: the estimate has no finite values over the second half"
    try:
        gain_error, phase_error = response_error(describing, model, values)
    except ValueError as error:  # a model that does not read this display's perceptions
        return None, f"not checked: {error}"
    crossover, margin = model_crossover(model, values, describing)
    try:  # every parameter free (but what the family holds by design): the floor
        best = fit_describing_function(describing, model)
        best_gain, best_phase = response_error(describing, model, best.values)
    except ValueError:  # too few forcing lines for the parameters: no floor to compare
        best_gain, best_phase = math.nan, math.nan
    return {
        "values": {name: round(value, 5) for name, value in values.items()},
        "gain_error_db": _rounded(gain_error),
        "phase_error_deg": _rounded(phase_error),
        "best_gain_error_db": _rounded(best_gain),
        "best_phase_error_deg": _rounded(best_phase),
        "crossover_frequency": _rounded(crossover),
        "phase_margin": _rounded(margin),
        "measured_crossover_frequency": _rounded(describing.crossover_frequency),
        "measured_phase_margin": _rounded(describing.phase_margin),
    }, ""


#: Excess gaps (dB, degrees) of a time-domain model over the describing function's own
#: fit of the same structure beyond which the model is said to miss the measured pilot:
#: the pass mark of the frequency-domain benchmark. The fit's gap is the floor the
#: measurement's remnant and the structure leave; only the excess is the estimate's.
FAR_GAIN_DB = 2.0
FAR_PHASE_DEG = 10.0


def _frequency_warnings(frequency: Mapping[str, Any]) -> list[str]:
    """Warn where the model's gap exceeds the describing-function fit's by the pass mark."""
    gain, phase = frequency["gain_error_db"], frequency["phase_error_deg"]
    best_gain = frequency["best_gain_error_db"] or 0.0
    best_phase = frequency["best_phase_error_deg"] or 0.0
    far_gain = gain is not None and gain - best_gain > FAR_GAIN_DB
    far_phase = phase is not None and phase - best_phase > FAR_PHASE_DEG
    if not (far_gain or far_phase):
        return []
    floor = (
        f", where the same model fitted to it misses by {best_gain:.1f} dB and {best_phase:.0f} deg"
        if frequency["best_gain_error_db"] is not None
        else ""
    )
    return [
        f"the identified model's frequency response misses the measured describing function "
        f"by {gain:.1f} dB and {phase:.0f} deg{floor} (mean absolute at the forcing "
        "frequencies, weighted by their share of forcing power): the time-domain parameters "
        "do not describe this pilot's response; compare `manualcontrol describe`"
    ]
