"""Offline output-error fit of a pilot whose parameters change along one sigmoid.

The scheduling-function approach to time-varying identification (Zaal 2016, cited by
Popovici et al. 2017 as ref. 5 and by the thesis, Part II Sec. 4.1, for its sigmoids):
instead of letting every parameter wander as a random walk, the pilot is assumed to
adapt once, every varying parameter ``p`` following the thesis's sigmoid (Part II eq.
4.2, Appendix A eq. A.4; :class:`~manualcontrol.envs.schedules.Sigmoid`)::

    p(t) = p_start + (p_end - p_start) / (1 + exp(-(2 ln 199 / dT) (t - T)))

with one inflection time ``T`` and one 99-% transition time ``dT`` shared by all of
them (one adaptation changes the whole pilot together, as in Zaal's change of vehicle
dynamics). The start and end values, ``T`` and ``dT`` minimise the output error
``sum_k (u[k] - u_hat[k])^2`` of the isolated pilot model driven by the recorded
perceptions (:func:`~manualcontrol.pilots.simulation.isolated_pilot_output`, exact
delay), as :func:`~manualcontrol.estimators.offline.output_error.fit_pilot` does for constant
parameters: maximum likelihood for white output noise, and, with remnant, the usual
output-error estimate, biased where the remnant reaches the perceptions (in the
closed loop).

Why it is kept beside the random-walk filters: a random walk must stay free to follow
a change at any moment, so on a stationary stretch the remnant moves it as much as a
real change would; two numbers a parameter and two shared ones do not. Where the pilot
does change along one sigmoid, the gains come out closer than the smoothed and the
cross-validated RML's; the neuromuscular parameters and the delay, which the remnant's
band overlaps, come out worse.

On the double integrator the remnant drifts below the forcing band (van der El's
0.01-rad/s break, which the RML assumes), and the plain output error's closed-loop bias
took ``K_p`` to a fraction of its value. With ``ce="DI"`` the output error is therefore
high-passed at half the lowest forcing frequency before it is squared (``highpass``):
the fit is then as good as the filters there, and no better. The same high-pass on the
single integrator, whose remnant is broadband, raised the errors: it is not applied
there. A parameter that changes otherwise (a sine, two steps, a drift) gets the sigmoid
closest to it, and the filters follow it better. Use the fit where one transition is
what the experiment imposed (a change of controlled element, of task, of display);
otherwise the filters, whose cross-validated members (``rml-cv``) choose their own
pace. It is slow: every cost evaluation resimulates the model with a parameter set per
sample, and the finite-difference least squares take thousands of them (tens of
seconds to minutes a run).

The fit is local: it starts from the constant-parameter fit and from ``starts``
inflection times spread over the run, and keeps the best optimum. The standard
deviations reported are those of the least-squares estimate (the inverse of the
Gauss-Newton information, scaled by the residual variance), carried to each sample's
value; with remnant, whose residual is coloured, they are too small.

Measured figures, each with the command that reproduces it, are in
``docs/estimators.md`` (``sigmoid-fit``): ``manualcontrol bench remnant-robustness
--estimators rml-smoothed,rml-cv,sigmoid-fit`` sets the fit beside the filters.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize
import scipy.special
from numpy.typing import NDArray
from scipy.signal import butter, sosfiltfilt

from manualcontrol.envs._validation import (
    check_choice,
    check_int,
    check_positive,
    reject_unknown,
)
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.schedules import Constant, Schedule, Sigmoid
from manualcontrol.envs.signals import ForcingPair, Multisine
from manualcontrol.estimators.members.pilot_rules import (
    DI_FAR_BREAK,
    TABLE_I,
    TAU_F_MARGIN,
    held_by_design,
)
from manualcontrol.estimators.offline.output_error import fit_pilot, lower_bound, perception_signals
from manualcontrol.estimators.protocol import EstimationResult, report_progress, summarise_health
from manualcontrol.pilots.models import PilotModel, make_model
from manualcontrol.pilots.simulation import isolated_pilot_output

__all__ = ["SigmoidFit", "SigmoidFitEstimator", "fit_pilot_sigmoid"]

FloatArray = NDArray[np.float64]

#: ``2 ln 199``: the logistic rate is this over the 99-% transition time (eq. A.4).
_LOG_199_TWICE = 2.0 * math.log(199.0)
#: Shortest transition time, in samples (a step).
_SHORTEST_TRANSITION = 10
#: Longest transition time, in run durations (beyond it the change is a ramp).
_LONGEST_TRANSITION = 4.0
#: Closest the inflection time may come to either end of the fitted window, as a
#: fraction of the window.
_EDGE = 0.05
#: The starting inflection times span the window less this fraction at either end.
_START_MARGIN = 0.1
#: Fewest samples a fit takes (the prefilter and the bounds of the transition time need
#: a run much longer than the shortest transition).
_FEWEST_SAMPLES = 200
#: Perceptions the fit builds (the postview model's edge signals it does not).
_PERCEPTIONS = ("e", "y", "ft_far", "ft_near_rate")
#: Initial transition time, as a fraction of the run.
_INITIAL_TRANSITION = 0.1


@dataclass(frozen=True)
class SigmoidFit:
    """Result of :func:`fit_pilot_sigmoid`.

    ``start`` and ``end`` hold every parameter of the model (a constant one, fitted or
    held, has the same value in both); ``varying`` those that follow the sigmoid,
    ``fitted`` all that were fitted. ``vaf`` is the variance accounted for (%) of the
    measured ``u`` over the fitted window (thesis eq. 38), ``cost`` half the sum of
    squared output errors there (after the ``highpass`` prefilter, when there is one;
    ``vaf`` is of the unfiltered error). ``covariance`` is the least-squares covariance
    of the fitted vector ``x`` (constant values, start values, end values of the
    varying parameters in that order, then ``t_mid`` and ``log(transition_time)``);
    ``bounds`` the bounds each fitted value was held within. ``warnings`` says, in
    words, where the answer is not to be read as found: the optimiser stopped without
    converging, or the inflection or the transition time ended on its bound (see
    :func:`_fit_warnings`).
    """

    model: str
    start: Mapping[str, float]
    end: Mapping[str, float]
    t_mid: float
    transition_time: float
    varying: tuple[str, ...]
    fitted: tuple[str, ...]
    vaf: float
    cost: float
    success: bool
    message: str
    covariance: FloatArray
    highpass: float | None = None
    bounds: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    warnings: tuple[str, ...] = ()

    def schedules(self) -> dict[str, Schedule]:
        """Each parameter's schedule: a :class:`Sigmoid` if varying, else a constant."""
        return {
            name: Sigmoid(self.start[name], self.end[name], self.t_mid, self.transition_time)
            if name in self.varying
            else Constant(self.start[name])
            for name in self.start
        }

    def traces(self, t: Sequence[float] | FloatArray) -> dict[str, FloatArray]:
        """Every parameter's value at the times ``t``."""
        times = np.asarray(t, dtype=np.float64)
        return {name: schedule(times) for name, schedule in self.schedules().items()}


class _Layout:
    """Where each number sits in the fitted vector, and the traces it describes."""

    def __init__(self, names: tuple[str, ...], varying: tuple[str, ...], held: dict) -> None:
        self.constant = tuple(name for name in names if name not in varying)
        self.varying = varying
        self.held = held
        self.n_c = len(self.constant)
        self.n_v = len(varying)

    def size(self) -> int:
        return self.n_c + 2 * self.n_v + 2

    def pack(
        self,
        start: Mapping[str, float],
        end: Mapping[str, float],
        t_mid: float,
        log_transition: float,
    ) -> FloatArray:
        """The vector of these values (a constant parameter's from ``start``)."""
        return np.array(
            [start[n] for n in self.constant]
            + [start[n] for n in self.varying]
            + [end[n] for n in self.varying]
            + [t_mid, log_transition]
        )

    def split(self, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, float, float]:
        c, v = self.n_c, self.n_v
        return x[:c], x[c : c + v], x[c + v : c + 2 * v], float(x[-2]), math.exp(float(x[-1]))

    def step(self, x: FloatArray, t: FloatArray) -> FloatArray:
        _, _, _, t_mid, transition = self.split(x)
        return scipy.special.expit(_LOG_199_TWICE / transition * (t - t_mid))

    def traces(self, x: FloatArray, t: FloatArray) -> dict[str, Any]:
        constant, start, end, _, _ = self.split(x)
        s = self.step(x, t)
        values: dict[str, Any] = dict(self.held)
        values.update({name: float(constant[i]) for i, name in enumerate(self.constant)})
        for i, name in enumerate(self.varying):
            values[name] = start[i] + (end[i] - start[i]) * s
        return values

    def gradients(self, x: FloatArray, t: FloatArray) -> dict[str, FloatArray]:
        """d(trace)/dx for each fitted parameter: (n, len(x)) per name."""
        _, start, end, t_mid, transition = self.split(x)
        s = self.step(x, t)
        slope = s * (1.0 - s)
        rate = _LOG_199_TWICE / transition
        out = {}
        for i, name in enumerate(self.constant):
            g = np.zeros((len(t), self.size()))
            g[:, i] = 1.0
            out[name] = g
        for i, name in enumerate(self.varying):
            g = np.zeros((len(t), self.size()))
            span = end[i] - start[i]
            g[:, self.n_c + i] = 1.0 - s
            g[:, self.n_c + self.n_v + i] = s
            g[:, -2] = -span * slope * rate
            g[:, -1] = -span * slope * rate * (t - t_mid)
            out[name] = g
        return out


def _check_model(model: PilotModel) -> None:
    unsupported = [name for name in model.perceptions if name not in _PERCEPTIONS]
    if unsupported:
        raise ValueError(
            f"the sigmoid fit builds the perceptions {', '.join(_PERCEPTIONS)}; the "
            f"{model.name} model perceives {', '.join(unsupported)}"
        )


def _check_names(label: str, names: Any, allowed: Sequence[str]) -> tuple[str, ...]:
    if isinstance(names, str) or not isinstance(names, Sequence):
        raise TypeError(f"{label} must be a sequence of parameter names, got {names!r}")
    names = tuple(names)
    unknown = [name for name in names if name not in allowed]
    if unknown:
        raise ValueError(
            f"{label} names {unknown}, which are not among {', '.join(allowed)}; "
            f"{label} = {list(names)!r}"
        )
    if len(set(names)) != len(names):
        raise ValueError(f"{label} names a parameter twice: {list(names)!r}")
    if not names:
        raise ValueError(f"{label} must name at least one parameter, got []")
    return names


def fit_pilot_sigmoid(
    recording: Recording,
    model: str | PilotModel = "precision",
    *,
    initial: Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    varying: Sequence[str] | None = None,
    starts: int = 5,
    skip: float = 2.0,
    forcing: ForcingPair | None = None,
    limits: Mapping[str, tuple[float, float]] | None = None,
    highpass: float | None = None,
) -> SigmoidFit:
    """Fit a pilot whose parameters change along one shared sigmoid (module docstring).

    Parameters
    ----------
    recording
        A run with the model's perceptions (``e``; or ``y`` and a target) and ``u``.
    model
        Pilot model structure or name.
    initial
        Starting values of the constant fit that every start begins from (default: the
        model's nominal values; the delay is tried over a grid, as
        :func:`~manualcontrol.estimators.offline.output_error.fit_pilot` does).
    fixed
        Parameters held at given values (not fitted).
    varying
        The fitted parameters that follow the sigmoid (default: all of them); the
        others are fitted as constants.
    starts
        Inflection times tried as starting points (each from the constant fit's
        values), spread evenly over the middle 80 % of the fitted window; the
        inflection is kept within the window's middle 90 %.
    skip
        Seconds at the start left out of the cost (the model starts at rest).
    forcing
        Target for preview models (default: the recording's metadata).
    limits
        ``{name: (low, high)}`` bounds of the start and end values, within the model's
        validity (default: the model's validity alone). Output error with remnant can
        run a parameter far past anything human (the preview model's ``omega_nms`` to
        four times its value with 30 % remnant): the estimator passes the family's
        limits (thesis Table I).
    highpass
        Cut-off (rad/s) of a zero-phase second-order Butterworth high-pass applied to
        the output error before it is squared (a prefiltered output error, Ljung's
        ``L(q)``): what lies below it leaves the cost. For remnant that drifts below the
        forcing band (the double integrator's): there output error's closed-loop bias
        took ``K_p`` to a fifth of its value, and half the lowest forcing frequency
        brings it back to the filters' error (module docstring). Default: none.

    """
    model = make_model(model)
    _check_model(model)
    fixed = dict(fixed or {})
    initial = dict(initial or {})
    limits = dict(limits or {})
    unknown = sorted((set(fixed) | set(initial) | set(limits)) - set(model.parameter_names))
    if unknown:
        raise ValueError(f"{model.name} model has no parameter(s) {unknown}")
    names = tuple(name for name in model.parameter_names if name not in fixed)
    if not names:
        raise ValueError("every parameter is fixed: nothing to fit")
    varying = names if varying is None else _check_names("varying", varying, names)
    starts = check_int("starts", starts, minimum=1)
    skip = check_positive("skip", skip, allow_zero=True)
    t = np.asarray(recording.t, dtype=np.float64)
    duration = float(t[-1] - t[0])
    if len(t) < _FEWEST_SAMPLES:
        raise ValueError(
            f"the recording has {len(t)} samples; a sigmoid fit needs at least {_FEWEST_SAMPLES}"
        )
    if skip >= duration / 2:
        raise ValueError(
            f"skip = {skip:g} s leaves less than half of the {duration:g}-s run to fit"
        )
    if forcing is None and "forcing" in recording.metadata:
        forcing = ForcingPair.from_dict(recording.metadata["forcing"])
    if highpass is not None:
        highpass = check_positive("highpass", highpass)
        if not highpass < math.pi / recording.dt:
            raise ValueError(
                f"highpass must lie below the Nyquist frequency {math.pi / recording.dt:g} "
                f"rad/s, got {highpass:g}"
            )
    window = t >= t[0] + skip - 1e-9
    u = np.asarray(recording.u, dtype=np.float64)
    for name in model.perceptions:
        if name in ("e", "y") and not np.all(np.isfinite(np.asarray(recording[name]))):
            # the model is resimulated from the first sample: one gap spoils every sample
            raise ValueError(
                f"{name} has dropped samples (NaN); the model resimulated from it needs "
                "every sample"
            )

    # the constant fit (it refuses a u with gaps in the window): where every start begins
    constant = fit_pilot(
        recording, model, initial=initial, fixed=fixed, skip=skip, forcing=forcing
    ).parameters
    layout = _Layout(names, varying, fixed)
    low = {name: lower_bound(model, name) for name in names}
    high = {name: min(model.spec(name).valid[1], 1e3) for name in names}
    for name, bounds in limits.items():
        if name in low:
            low[name] = max(low[name], float(bounds[0]))
            high[name] = min(high[name], float(bounds[1]))
            if not low[name] < high[name]:
                raise ValueError(
                    f"limits of {name} must leave a range within the model's validity, "
                    f"got {tuple(bounds)!r}"
                )
    shortest = _SHORTEST_TRANSITION * recording.dt
    # the inflection stays inside the fitted window, away from its edges: a change that
    # ends before the window (or starts after it) leaves its start (end) value free
    first = float(t[0]) + skip
    edge = _EDGE * (float(t[-1]) - first)
    lower = layout.pack(low, low, first + edge, math.log(shortest))
    upper = layout.pack(high, high, float(t[-1]) - edge, math.log(_LONGEST_TRANSITION * duration))

    sos = (
        None
        if highpass is None
        else butter(2, highpass, btype="highpass", fs=2.0 * math.pi / recording.dt, output="sos")
    )

    def output_error(x: FloatArray) -> FloatArray:
        values = layout.traces(x, t)
        perceptions = perception_signals(recording, model, values, forcing)
        u_hat = isolated_pilot_output(model, values, perceptions, recording.dt)
        return (u - u_hat)[window]

    def residual(x: FloatArray) -> FloatArray:
        error = output_error(x)
        if not np.all(np.isfinite(error)):
            # a diverging candidate (an unstable parameter set) costs more than any other
            return np.full(error.shape, 1e6)
        return error if sos is None else sosfiltfilt(sos, error)

    margin = _START_MARGIN * (float(t[-1]) - first)
    span = float(t[-1]) - first - 2.0 * margin
    # the centres of equal parts: one start sits mid-window
    mids = first + margin + (np.arange(starts) + 0.5) * span / starts
    best = None
    for index, t_mid in enumerate(mids):
        report_progress(
            f"sigmoid fit: start {index + 1} of {len(mids)} (change at t = {t_mid:.1f} s)"
        )
        x0 = layout.pack(constant, constant, t_mid, math.log(_INITIAL_TRANSITION * duration))
        x0 = np.clip(x0, lower + 1e-9, upper - 1e-9)
        result = scipy.optimize.least_squares(
            residual, x0, bounds=(lower, upper), x_scale="jac", max_nfev=100 * len(x0)
        )
        if best is None or result.cost < best.cost:
            best = result
    assert best is not None
    error = output_error(best.x)
    measured = u[window]
    vaf = 100.0 * (1.0 - float(np.sum(error**2)) / float(np.sum(measured**2)))
    dof = max(int(window.sum()) - len(best.x), 1)
    information = best.jac.T @ best.jac
    covariance = np.linalg.pinv(information) * (2.0 * float(best.cost) / dof)
    values, at_start, at_end, t_mid, transition = layout.split(best.x)
    start = {**fixed, **{n: float(values[i]) for i, n in enumerate(layout.constant)}}
    end = dict(start)
    start.update({n: float(at_start[i]) for i, n in enumerate(varying)})
    end.update({n: float(at_end[i]) for i, n in enumerate(varying)})
    order = model.parameter_names
    # a change of under 1 % of the value is no change to speak of (a constant pilot's
    # fit moves 0.2 % from the model's start at rest), and has no inflection to report
    changed = any(abs(end[n] - start[n]) > 0.01 * max(abs(end[n]), abs(start[n])) for n in varying)
    return SigmoidFit(
        model=model.registered_name,
        start={n: start[n] for n in order},
        end={n: end[n] for n in order},
        t_mid=t_mid,
        transition_time=transition,
        varying=tuple(varying),
        fitted=names,
        vaf=vaf,
        cost=float(best.cost),
        success=bool(best.success),
        message=str(best.message),
        covariance=covariance,
        highpass=highpass,
        bounds={n: (low[n], high[n]) for n in names},
        warnings=_fit_warnings(
            best,
            t_mid=(t_mid, first + edge, float(t[-1]) - edge),
            transition=(transition, shortest, _LONGEST_TRANSITION * duration),
            changed=changed,
        ),
    )


def _fit_warnings(
    best: Any,
    *,
    t_mid: tuple[float, float, float],
    transition: tuple[float, float, float],
    changed: bool,
) -> tuple[str, ...]:
    """What a user should know before reading the fit: ``(value, low, high)`` of each.

    A bound counts as reached within 0.1 % of the range (``t_mid``) or of the
    logarithm's range (the transition time, fitted in logarithms).
    """
    out = []
    if not best.success:
        out.append(f"the optimiser stopped without converging ({best.message})")
    if changed:
        value, low, high = t_mid
        if min(value - low, high - value) <= 1e-3 * (high - low):
            out.append(
                f"the inflection ({value:.2f} s) is at the edge of the window it may lie "
                f"in ([{low:.2f}, {high:.2f}] s): the change may lie outside the run"
            )
        value, low, high = (math.log(v) for v in transition)
        if value - low <= 1e-3 * (high - low):
            out.append(
                f"the transition time is at its shortest ({transition[1]:.2f} s): a step, "
                "or a transient the fit follows"
            )
        elif high - value <= 1e-3 * (high - low):
            out.append(
                f"the transition time is at its longest ({transition[2]:.0f} s): a drift "
                "rather than one change; a filter (rml-smoothed) may describe it better"
            )
    return tuple(out)


#: The settings :class:`SigmoidFitEstimator` reads.
OWN_KEYS: tuple[str, ...] = (
    "model",
    "ce",
    "anticipation_time",
    "initial",
    "estimated",
    "limits",
    "varying",
    "highpass",
    "starts",
    "skip",
)
#: The pilot filters' tuning settings: accepted so that a bench batch's shared estimator
#: settings serve this member too, and not used (an output-error fit has no noise model
#: or random walk).
FILTER_KEYS: tuple[str, ...] = (
    "preset",
    "q2",
    "r2",
    "r2_parameter",
    "window",
    "P0",
    "Q",
    "P0_fraction",
    "Q_fraction",
)


class SigmoidFitEstimator:
    """:func:`fit_pilot_sigmoid` behind the estimators' ``estimate`` (offline only).

    ``estimated`` names the fitted parameters (the others are held at ``initial``, else
    the model's nominal values, ``K_v = 0`` for ``ce="SI"`` and ``omega_f`` 1 rad/s for
    ``ce="DI"`` as the filters start it; by default all are fitted,
    less ``K_v`` and ``omega_f`` for ``ce="SI"``, as the filters hold them), ``varying``
    those of them that follow the sigmoid. ``limits`` bound the fitted values as the
    filters' do: ``"table-I"`` (default: thesis Table I for ``ce``, else the model's
    human ranges, and ``tau_f`` within 0.1 s of 0 and of ``anticipation_time`` when that
    is given), ``"none"`` (the model's validity) or ``{name: (low, high)}``.
    ``highpass`` (rad/s) prefilters the output error (see :func:`fit_pilot_sigmoid`):
    ``"auto"`` (default) at half the lowest forcing frequency for ``ce="DI"``, whose
    remnant the family takes to drift below the forcing band (the RML's 0.01-rad/s
    break), and none otherwise; a number; or None.
    """

    name = "sigmoid-fit"

    def __init__(
        self,
        model: str = "precision",
        *,
        ce: str | None = None,
        anticipation_time: float | None = None,
        initial: Mapping[str, float] | None = None,
        estimated: Sequence[str] | None = None,
        limits: str | Mapping[str, Sequence[float]] = "table-I",
        varying: Sequence[str] | None = None,
        highpass: str | float | None = "auto",
        starts: int = 5,
        skip: float = 2.0,
    ) -> None:
        self._model = make_model(model)
        _check_model(self._model)
        if isinstance(highpass, str):
            check_choice("highpass", highpass, ("auto",))
        elif highpass is not None:
            highpass = check_positive("highpass", highpass)
        self._highpass = highpass
        names = self._model.parameter_names
        self._ce = None if ce is None else check_choice("ce", ce, tuple(TABLE_I))
        self._anticipation_time = (
            None
            if anticipation_time is None
            else check_positive("anticipation_time", anticipation_time)
        )
        if self._anticipation_time is not None and self._anticipation_time <= 2 * TAU_F_MARGIN:
            raise ValueError(
                f"anticipation_time must exceed {2 * TAU_F_MARGIN:g} s (tau_f is kept "
                f"{TAU_F_MARGIN:g} s from 0 and from it), got {self._anticipation_time:g}"
            )
        self._initial = dict(initial or {})
        unknown = sorted(set(self._initial) - set(names))
        if unknown:
            raise ValueError(f"initial names {unknown}, which the {model} model does not have")
        if estimated is None:
            held = held_by_design(self._ce, pursuit=False)  # a fit has no pursuit form
            self._estimated = tuple(name for name in names if name not in held)
        else:
            self._estimated = _check_names("estimated", estimated, names)
        self._limits = self._resolve_limits(limits)
        self._varying = (
            None if varying is None else _check_names("varying", varying, self._estimated)
        )
        self._starts = check_int("starts", starts, minimum=1)
        self._skip = check_positive("skip", skip, allow_zero=True)

    @property
    def settings(self) -> dict[str, Any]:
        """The settings this estimator was built with."""
        return {
            "model": self._model.registered_name,
            "ce": self._ce,
            "anticipation_time": self._anticipation_time,
            "limits": {name: list(bounds) for name, bounds in self._limits.items()},
            "initial": dict(self._initial),
            "estimated": list(self._estimated),
            "varying": None if self._varying is None else list(self._varying),
            "highpass": self._highpass,
            "starts": self._starts,
            "skip": self._skip,
        }

    def fit(self, recording: Recording, *, forcing: Any = None) -> SigmoidFit:
        """The :class:`SigmoidFit` of ``recording``."""
        nominal = self._model.nominal()
        if self._ce == "SI" and "K_v" in nominal:
            nominal["K_v"] = 0.0  # the single integrator needs no lead (Popovici eq. 28)
        if self._ce == "DI" and "omega_f" in nominal:
            nominal["omega_f"] = DI_FAR_BREAK  # the filters' DI start (thesis Table 6.3)
        nominal.update(self._initial)
        fixed = {n: nominal[n] for n in self._model.parameter_names if n not in self._estimated}
        return fit_pilot_sigmoid(
            recording,
            self._model,
            initial={n: nominal[n] for n in self._estimated},
            fixed=fixed,
            varying=self._varying,
            starts=self._starts,
            skip=self._skip,
            forcing=forcing,
            limits={n: b for n, b in self._limits.items() if n in self._estimated},
            highpass=self._cutoff(recording, forcing),
        )

    def _cutoff(self, recording: Recording, forcing: ForcingPair | None) -> float | None:
        """The high-pass cut-off (rad/s) for this recording (None: no prefilter)."""
        if self._highpass != "auto":
            return self._highpass
        if self._ce != "DI":
            return None
        if forcing is None and "forcing" in recording.metadata:
            forcing = ForcingPair.from_dict(recording.metadata["forcing"])
        parts = [] if forcing is None else [forcing.target, forcing.disturbance]
        frequencies = [f.frequencies for f in parts if isinstance(f, Multisine)]
        if not frequencies:
            raise ValueError(
                "highpass='auto' on the double integrator sits at half the lowest forcing "
                "frequency, and this recording has no multisine forcing (pass forcing=, "
                "`--forcing PRESET`), or set highpass to a cut-off in rad/s or None"
            )
        return float(np.concatenate(frequencies).min()) / 2.0

    def _resolve_limits(self, limits: Any) -> dict[str, tuple[float, float]]:
        names = self._model.parameter_names
        if isinstance(limits, str):
            check_choice("limits", limits, ("table-I", "none"))
            if limits == "none":
                return {}
            if self._ce is not None:
                table = dict(TABLE_I[self._ce])
            else:
                table = {spec.name: spec.human for spec in self._model.parameters}
            if "tau_f" in names and self._anticipation_time is not None:
                table["tau_f"] = (TAU_F_MARGIN, self._anticipation_time - TAU_F_MARGIN)
            return {name: table[name] for name in names if name in table}
        if not isinstance(limits, Mapping):
            raise TypeError(
                f"limits must be 'table-I', 'none' or {{name: (low, high)}}, got {limits!r}"
            )
        resolved = {}
        for name, bounds in limits.items():
            _check_names("limits", [name], names)
            if isinstance(bounds, str) or len(bounds) != 2:
                raise ValueError(f"limits of {name} must be (low, high), got {bounds!r}")
            low, high = (float(b) for b in bounds)
            if not low < high:
                raise ValueError(f"limits of {name} must satisfy low < high, got {bounds!r}")
            resolved[name] = (low, high)
        return resolved

    def estimate(self, recording: Recording, **options: Any) -> EstimationResult:
        """The fitted traces as an offline :class:`EstimationResult` (``options``: ``forcing``).

        ``mean`` holds the sigmoids (constants for the others), ``std`` their
        least-squares standard deviations; there is no one-step prediction (NaN).
        """
        unknown = set(options) - {"forcing", "target_period"}
        if unknown:
            raise TypeError(
                f"the sigmoid fit takes forcing= (and target_period=), got "
                f"{', '.join(sorted(unknown))}"
            )
        if options.get("target_period") is not None:
            raise ValueError(
                "the sigmoid fit reads the target from the forcing, not from the recorded "
                "target's periodic extension: pass forcing= (`--forcing PRESET`) instead of "
                "target_period="
            )
        forcing = options.get("forcing")
        if forcing is not None and not isinstance(forcing, ForcingPair):
            raise TypeError(
                f"forcing must be a ForcingPair (a preset's: forcing_preset(name, "
                f"realisation)), got {type(forcing).__name__}"
            )
        fit = self.fit(recording, forcing=forcing)
        t = np.asarray(recording.t, dtype=np.float64)
        names = self._model.parameter_names
        traces = fit.traces(t)
        layout = _Layout(fit.fitted, fit.varying, {})
        x = layout.pack(fit.start, fit.end, fit.t_mid, math.log(fit.transition_time))
        gradients = layout.gradients(x, t)
        mean = np.column_stack([traces[n] for n in names])
        std = np.zeros_like(mean)
        for j, name in enumerate(names):
            if name in gradients:
                g = gradients[name]
                variance = np.einsum("ki,ij,kj->k", g, fit.covariance, g)
                std[:, j] = np.sqrt(np.maximum(variance, 0.0))
        n = len(t)
        bounds = {name: fit.bounds.get(name, (-np.inf, np.inf)) for name in names}
        lows = np.array([bounds[name][0] for name in names])
        highs = np.array([bounds[name][1] for name in names])
        pinned = (mean <= lows + 1e-6) | (mean >= highs - 1e-6)
        pinned[:, [name not in fit.fitted for name in names]] = False
        no = np.zeros(n, dtype=np.bool_)
        return EstimationResult(
            estimator=self.name,
            t=t,
            parameter_names=names,
            estimated=fit.fitted,
            mean=mean,
            std=std,
            outputs=("u",),
            predictions=np.full((n, 1), np.nan),
            innovations=np.full((n, 1), np.nan),
            innovation_covariance=np.full((n, 1, 1), np.nan),
            finite=np.ones(n, dtype=np.bool_),
            covariance_ok=np.ones(n, dtype=np.bool_),
            dropped=np.isnan(np.asarray(recording.u)),
            diverged=no,
            pinned=pinned,
            settings={
                "settings": self.settings,
                "sigmoid": {
                    "highpass": fit.highpass,
                    "t_mid": fit.t_mid,
                    "transition_time": fit.transition_time,
                    "varying": list(fit.varying),
                    "start": dict(fit.start),
                    "end": dict(fit.end),
                    "vaf": fit.vaf,
                    "success": fit.success,
                    "warnings": list(fit.warnings),
                },
            },
            health=summarise_health(
                t,
                recording.dt,
                np.isnan(np.asarray(recording.u)),
                pinned,
                names,
                reason="",
                divergence_index=-1,
                stopped=False,
            ),
            smoothed=True,
        )

    def reset(self, *args: Any, **kwargs: Any) -> None:
        """Not available: the fit needs the whole run."""
        raise TypeError(
            "the sigmoid fit works on whole recordings (estimate); for online estimation "
            "use a filter of the family"
        )

    update = reset

    def __repr__(self) -> str:
        return f"SigmoidFitEstimator({self.settings!r})"

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> SigmoidFitEstimator:
        """The fit from a suite file's settings table.

        The filters' keys (:data:`FILTER_KEYS`) are accepted and ignored, so one table
        of shared settings serves a batch of filters and the fit.
        """
        settings = {k: v for k, v in settings.items() if k != "name"}
        reject_unknown("sigmoid-fit settings", settings, OWN_KEYS + FILTER_KEYS)
        return cls(**{k: v for k, v in settings.items() if k in OWN_KEYS})
