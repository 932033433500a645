"""Offline time-domain output-error fit of a pilot model to a whole run.

The baseline against which the online filters are judged: constant parameters
``theta`` minimise ``sum_k (u[k] - u_hat[k; theta])^2`` where ``u_hat`` is the isolated
pilot model (:func:`~manualcontrol.pilots.simulation.isolated_pilot_output`, exact
delay) driven by the measured perceptions. With Gaussian white output noise this is
the maximum-likelihood estimate; with remnant it is the usual output-error estimate,
biased where the remnant correlates with the perceptions. The cost is not unimodal in
the delay (Boer & Kenyon 1998, Sec. III-F), so the fit starts from a grid of delays and
keeps the best local optimum (scipy's trust-region reflective least squares within the
model's valid bounds).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.optimize
from numpy.typing import NDArray

from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair
from manualcontrol.pilots.models import PilotModel, make_model
from manualcontrol.pilots.simulation import isolated_pilot_output

__all__ = ["OfflineFit", "fit_pilot", "lower_bound", "perception_signals"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class OfflineFit:
    """Result of :func:`fit_pilot`: every parameter (fitted or fixed) and the fit quality.

    ``vaf`` is the variance accounted for (%) of the measured ``u`` by the fitted
    model's output over the fitted window (thesis eq. 38).
    """

    model: str
    parameters: Mapping[str, float]
    fitted: tuple[str, ...]
    vaf: float
    cost: float
    success: bool
    message: str


def perception_signals(
    recording: Recording,
    model: PilotModel,
    values: Mapping[str, float],
    forcing: ForcingPair | None,
) -> dict[str, FloatArray]:
    """The signals ``model`` perceives in ``recording``.

    ``e`` and ``y`` as recorded; the previewed target from ``forcing`` at the model's
    look-ahead in ``values``.
    """
    signals = {}
    for name in model.perceptions:
        if name in ("e", "y"):
            signals[name] = np.asarray(recording[name])
        elif name == "ft_far":
            if forcing is None or forcing.target is None:
                raise ValueError(
                    "fitting a preview model needs the target: pass forcing= or record it"
                )
            signals[name] = forcing.target(recording.t + values["tau_f"])
        else:
            signals[name] = forcing.target.derivative(recording.t + values["tau_n"])
    return signals


def fit_pilot(
    recording: Recording,
    model: str | PilotModel = "precision",
    *,
    initial: Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    delay_grid: Sequence[float] = (0.1, 0.2, 0.3, 0.45),
    skip: float = 2.0,
    forcing: ForcingPair | None = None,
) -> OfflineFit:
    """Fit constant pilot parameters to a recording by output error.

    Parameters
    ----------
    recording
        A run with the model's perceptions (``e``; or ``y`` and a target) and ``u``.
    model
        Pilot model structure or name.
    initial
        Starting values (default: the model's nominal values).
    fixed
        Parameters held at given values (not fitted).
    delay_grid
        Starting values of the model delay; the best optimum over all is kept.
    skip
        Seconds at the start left out of the cost (the model starts at rest).
    forcing
        Target for preview models (default: the recording's metadata).

    """
    model = make_model(model)
    fixed = dict(fixed or {})
    start = {**model.nominal(), **dict(initial or {})}
    unknown = sorted((set(fixed) | set(start)) - set(model.parameter_names))
    if unknown:
        raise ValueError(f"{model.name} model has no parameter(s) {unknown}")
    if forcing is None and "forcing" in recording.metadata:
        forcing = ForcingPair.from_dict(recording.metadata["forcing"])
    names = tuple(name for name in model.parameter_names if name not in fixed)
    lower = np.array([lower_bound(model, name) for name in names])
    upper = np.array([model.spec(name).valid[1] for name in names])
    upper = np.where(np.isinf(upper), 1e3, upper)
    window = slice(min(round(skip / recording.dt), len(recording) - 2), None)
    u = np.asarray(recording.u)
    if np.isnan(u[window]).any():
        raise ValueError("u has dropped samples (NaN) inside the fitted window")

    def values_of(theta: FloatArray) -> dict[str, float]:
        return {**fixed, **dict(zip(names, map(float, theta), strict=True))}

    def residual(theta: FloatArray) -> FloatArray:
        values = values_of(theta)
        perceptions = perception_signals(recording, model, values, forcing)
        u_hat = isolated_pilot_output(model, values, perceptions, recording.dt)
        return (u - u_hat)[window]

    best = None
    delay = model.delay_parameter
    grid = [start.get(delay)] if delay in fixed else list(delay_grid)
    for tau in grid:
        guess = dict(start)
        if delay not in fixed:
            guess[delay] = tau
        theta0 = np.clip([guess[name] for name in names], lower + 1e-9, upper - 1e-9)
        result = scipy.optimize.least_squares(
            residual, theta0, bounds=(lower, upper), x_scale="jac"
        )
        if best is None or result.cost < best.cost:
            best = result
    values = values_of(best.x)
    error = residual(best.x)
    measured = u[window]
    vaf = 100.0 * (1.0 - float(np.sum(error**2)) / float(np.sum(measured**2)))
    return OfflineFit(
        model.registered_name,
        values,
        names,
        vaf,
        float(best.cost),
        bool(best.success),
        str(best.message),
    )


def lower_bound(model: PilotModel, name: str) -> float:
    """The lowest value a fit may give parameter ``name``: its validity, kept off zero."""
    spec = model.spec(name)
    low = spec.valid[0]
    if math.isinf(low):
        return -1e3
    return low + (1e-6 if spec.positive or name == model.delay_parameter else 0.0)
