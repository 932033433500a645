"""Identify a pilot from one recording, with every cross-check a laboratory wants.

:func:`identify` is what ``manualcontrol identify`` runs (the command only reads the
file, prints and writes what this returns). :func:`build_estimator` builds the member
of the family from its name and settings, given the experiment's controlled element
where the member takes one, so that limits and rules come from the real plant.
:func:`identify` runs it over the recording, resimulates the identified model,
measures the describing function at the forcing frequencies when they are known and
checks the fit against it (:func:`~manualcontrol.estimators.analysis.fit_check.check_fit`),
checks that the identified pilot closes a stable loop with the element, lists the
parameters held at generic values nobody measured and, on a simulation that carries its
true parameter traces, scores the estimate against them (NRMSE and relative bias,
thesis eq. 37, as the benchmark does). :class:`Identification` holds it all, with the
JSON-able :attr:`Identification.summary`.

A control signal that never moves is refused before any estimator runs
(:func:`control_never_moves`): nothing can be identified from it. Messages name the
keywords of these functions (``forcing=``, ``period=``, ``element=``); the command line
words them as its flags.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs.recording import Recording
from manualcontrol.envs.tasks import task_named
from manualcontrol.estimators.analysis.fit_check import FitCheck, check_fit
from manualcontrol.estimators.analysis.frequency import DescribingFunction, describing_function
from manualcontrol.estimators.analysis.metrics import (
    NEAR_ZERO,
    nrmse,
    pilot_model_of,
    relative_bias,
    resimulate,
)
from manualcontrol.estimators.members.pilot_rules import (
    GenericValuesWarning,
    element_type,
    held_without_values,
)
from manualcontrol.estimators.protocol import EstimationResult
from manualcontrol.estimators.registry import ESTIMATORS, make_estimator
from manualcontrol.pilots import Pilot, SimulationSetup
from manualcontrol.pilots.stability import UnstableLoopError, check_stable

__all__ = [
    "Identification",
    "build_estimator",
    "control_never_moves",
    "held_by_rule",
    "identified_loop",
    "identify",
    "trial_describing_function",
    "truth_errors",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Identification:
    """One recording identified and checked (see :func:`identify`).

    Attributes
    ----------
    result
        The estimator's run.
    model_output
        The identified model resimulated from the recorded inputs (None where it could
        not be: a diverged fit).
    check
        VAFs, innovation whiteness, the frequency-domain cross-check and warnings.
    closed_loop
        ``stable`` (True, False, or None where nothing can be said) and ``message``.
    held_at_generic_values
        Parameters held at a generic rule's value, neither given nor estimated.
    truth
        The estimate against the recording's true parameter traces (a simulation's):
        see :func:`truth_errors`; None where the recording carries none.
    name
        The estimator's name as it was asked for (``"dekf-smoothed"``); None: the
        result's own (``result.estimator``, the filter's).
    """

    result: EstimationResult
    model_output: FloatArray | None
    check: FitCheck
    closed_loop: dict[str, Any]
    held_at_generic_values: dict[str, float]
    truth: dict[str, Any] | None = None
    name: str | None = None

    @property
    def final(self) -> dict[str, float]:
        """The last estimate of every parameter, rounded to 5 decimals."""
        return {name: round(float(value), 5) for name, value in self.result.final().items()}

    @property
    def summary(self) -> dict[str, Any]:
        """The JSON-able summary ``manualcontrol identify`` writes.

        Estimator and its settings, final values, fit, closed loop, health, the errors
        against the true parameters where the recording has them, and the member's own
        record where it has one (cross-validation, sigmoid, restarts, remnant choice).
        """
        result = self.result
        settings = result.settings.get("settings")
        summary: dict[str, Any] = {
            "estimator": self.name or result.estimator,
            "settings": _json_safe(settings) if isinstance(settings, Mapping) else None,
            "final": self.final,
            "estimated": list(result.estimated),
            "fit": self.check.to_dict(),
            "closed_loop": self.closed_loop,
            "health": result.health.to_dict(),
        }
        for key in ("cross_validation", "sigmoid", "restarts"):
            record = result.settings.get(key)
            if record is not None:
                summary[key] = record
        injection = result.settings.get("remnant_injection")
        if isinstance(injection, Mapping):  # the RML's "choose": the remnant model kept
            summary["remnant_injection"] = injection
        if self.held_at_generic_values:
            summary["held_at_generic_values"] = self.held_at_generic_values
        if self.truth is not None:
            summary["truth"] = self.truth
        return summary


def _json_safe(value: Any) -> Any:
    """``value`` as JSON data: tables as dicts, tuples as lists, non-finite numbers None."""
    if isinstance(value, Mapping):
        return {str(key): _json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(item) for item in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None if np.isnan(value) else ("inf" if value > 0 else "-inf")
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def build_estimator(
    name: str,
    settings: Mapping[str, Any] | None = None,
    *,
    model: str | None = None,
    element: Any = None,
) -> Any:
    """The member ``name`` with ``settings``, on ``model`` and ``element`` where it takes them.

    A member on a pilot model runs ``model`` (default ``"precision"``; a ``model`` in
    ``settings`` wins); ``model`` for another member is an error. The experiment's
    ``element`` sets the limits and the element-type rules of the members that take one
    (unless ``settings`` name ``ce`` or ``element``). Generic-values warnings are left to
    the caller (:func:`held_by_rule` lists those values).
    """
    settings = dict(settings or {})
    entry = ESTIMATORS.get(name)
    if entry is None:
        raise ValueError(
            f"estimator must be one of {', '.join(ESTIMATORS)} (`manualcontrol estimators`), "
            f"got {name!r}"
        )
    spec = {"name": name, **settings}
    if entry.pilot_model:
        spec.setdefault("model", model or "precision")
    elif model is not None:
        structured = ", ".join(n for n, e in ESTIMATORS.items() if e.pilot_model)
        raise ValueError(
            f"model names the pilot structure of {structured}; the {name} estimator has "
            "its own model (set it in its settings)"
        )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GenericValuesWarning)
        if element is not None and "ce" not in settings and "element" not in settings:
            try:
                return make_estimator({**spec, "element": element})
            except (TypeError, ValueError) as error:
                if "'element'" not in str(error):  # a member without an element setting
                    raise _unknown_settings(name, error) from None
        try:
            return make_estimator(spec)
        except (TypeError, ValueError) as error:
            raise _unknown_settings(name, error) from None


def _unknown_settings(name: str, error: Exception) -> Exception:
    """A settings class's unknown-key error, said of the member ``name`` with all its keys.

    The settings class's message names the class (``DEKFSettings.from_dict got unknown
    key(s) 'x'; known: ...``); a ``-cv`` twin's list lacks the cross-validation's own
    ``cv_*`` keys, which it takes too. Any other error is returned as it is.
    """
    import re

    found = re.fullmatch(
        r"\w+\.from_dict got unknown key\(s\) (.+?); known: (.*)", str(error), re.DOTALL
    )
    if found is None:
        return error
    known = found.group(2)
    entry = ESTIMATORS.get(name)
    if entry is not None and entry.twin == "cross-validated":
        from manualcontrol.estimators.offline.cross_validation import OPTION_KEYS

        known += ", " + ", ".join(repr(key) for key in OPTION_KEYS)
    return ValueError(
        f"the {name} estimator has no setting {found.group(1)}; its settings: {known}"
    )


def trial_describing_function(
    recording: Recording,
    result: EstimationResult,
    *,
    forcing: Any = None,
    period: float | None = None,
    element: Any = None,
    disturbance_at: str = "output",
) -> tuple[DescribingFunction | None, str]:
    """The trial's describing function for the cross-check, or None and why not.

    The forcing frequencies come from ``forcing`` (a ForcingPair), ``period`` (the
    forcing's period, its signals in the recording) or the recording's metadata.
    """
    if forcing is None and period is None and recording.metadata.get("forcing") is None:
        return None, (
            "not checked: the forcing frequencies are unknown (give forcing= or period=, "
            "the forcing signals being in the recording)"
        )
    model = pilot_model_of(result)
    if model is None:
        return None, f"not checked: the {result.estimator} model is not a pilot model structure"
    # the display the fitted model belongs to, where the recording does not say
    task = "compensatory"
    if model.perceptions != ("e",):
        settings = result.settings.get("settings", result.settings)
        task = "pursuit" if settings.get("anticipation_time") == 0.0 else "preview"
    try:
        describing = describing_function(
            recording,
            forcing,
            period=period,
            element=element,
            disturbance_at=disturbance_at,
            task=recording.metadata.get("task", task),
        )
    except ValueError as error:
        return None, f"not checked: {error}"
    return describing, ""


def held_by_rule(result: EstimationResult) -> dict[str, float]:
    """Parameters a filter held at a generic rule's value (not given, not estimated).

    What the family holds by design (the single integrator's ``K_v = 0`` and constant
    ``omega_f``, the pursuit form's ``tau_f = 0``) is no assumption about this pilot:
    left out.
    """
    resolved = result.settings.get("resolved")
    settings = result.settings.get("settings")
    if not isinstance(resolved, Mapping) or not isinstance(settings, Mapping):
        return {}
    values = resolved.get("initial", {})
    kind = settings.get("ce")
    if kind is None and settings.get("element") is not None:
        kind = element_type(settings["element"])
    assumed = held_without_values(
        values,
        result.estimated,
        settings.get("initial") or {},
        kind,
        settings.get("anticipation_time") == 0.0,
    )
    return {name: float(values[name]) for name in assumed}


def identified_loop(result: EstimationResult, element: Any = None) -> dict[str, Any]:
    """Whether the identified pilot (final values) closes a stable loop with the element.

    The element is ``element`` or else the estimator's ``ce`` setting; without either
    nothing can be said.
    """
    settings = dict(result.settings.get("settings", result.settings))
    element = element or settings.get("ce")
    if element is None:
        return {
            "stable": None,
            "message": "not checked: no controlled element known (give element=)",
        }
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pilot = Pilot(settings["model"], dict(result.final()))
            error_only = task_named(pilot.model.task).shows_error_only
            task = "compensatory" if error_only else "preview"
            preview = None if error_only else 5.0  # room for any identified tau_f
            setup = SimulationSetup.create(pilot, element, task=task, available_preview=preview)
            check_stable(setup)
    except UnstableLoopError as error:
        message = str(error).split("; use typical")[0]
        message = message[len("the ") :] if message.startswith("the ") else message
        return {"stable": False, "message": f"the identified {message}: the fit is not credible"}
    except (TypeError, ValueError, KeyError) as error:
        return {"stable": None, "message": f"not checked: {error}"}
    return {"stable": True, "message": "the identified pilot closes a stable loop"}


def control_never_moves(recording: Recording) -> str | None:
    """Why ``recording``'s control ``u`` identifies nothing, or None when it moves.

    A stick that never moved (every finite sample the same) or a ``u`` with no finite
    sample leaves no input-output relation to identify: every estimator would only
    fail on it later, in its own words.
    """
    if "u" not in recording:
        return None
    u = np.asarray(recording.u, dtype=np.float64)
    finite = u[np.isfinite(u)]
    if finite.size == 0:
        return "u holds no finite sample: the stick was not recorded; nothing can be identified"
    if float(finite.max()) == float(finite.min()):
        return (
            f"u is constant ({float(finite[0]):g} in all {finite.size} samples): the stick "
            "never moved; nothing can be identified (check that the column read as u is "
            "the stick's and that the trial was flown)"
        )
    return None


def truth_errors(
    result: EstimationResult, recording: Recording, *, start: float = 0.0
) -> dict[str, Any] | None:
    """The estimate against the recording's true parameter traces (simulations).

    Per estimated parameter with a true trace, from time ``start`` on: the NRMSE (thesis
    eq. 37; the plain RMSE where the true mean is within :data:`NEAR_ZERO` of zero,
    ``error_kind`` says which) and the relative bias, as
    :func:`~manualcontrol.estimators.analysis.metrics.evaluate` and the benchmark
    compute them. None when the recording carries no true trace of any of them.
    """
    truth = recording.parameters
    names = [name for name in result.estimated if name in truth]
    if not names:
        return None
    mask = np.asarray(recording.t) >= start
    errors, biases, kinds = {}, {}, {}
    for name in names:
        true_trace = np.asarray(truth[name])[mask]
        estimate = result.mean_of(name)[mask]
        errors[name] = _finite_or_none(nrmse(estimate, true_trace))
        biases[name] = _finite_or_none(relative_bias(estimate, true_trace))
        kinds[name] = "rmse" if abs(float(np.mean(true_trace))) < NEAR_ZERO else "nrmse"
    return {
        "scored_from_s": float(start),
        "nrmse": errors,
        "relative_bias": biases,
        "error_kind": kinds,
    }


def _finite_or_none(value: float) -> float | None:
    return round(float(value), 5) if np.isfinite(value) else None


def identify(
    recording: Recording,
    estimator: Any,
    *,
    element: Any = None,
    target: Mapping[str, Any] | None = None,
    forcing: Any = None,
    period: float | None = None,
    disturbance_at: str = "output",
    name: str | None = None,
) -> Identification:
    """Identify ``recording`` with ``estimator`` and check the fit (module docstring).

    Parameters
    ----------
    recording
        The trial.
    estimator
        A member of the family (:func:`build_estimator` builds one by name).
    element
        The experiment's controlled element (the stability check, the describing
        function's loop); None: the estimator's ``ce`` setting, if any.
    target
        Where a preview model reads the target ahead (``forcing=`` or
        ``target_period=``, passed to ``estimate`` and the resimulation).
    forcing, period
        The forcing frequencies of the describing function (a ForcingPair, or the
        forcing's period with its signals in the recording).
    disturbance_at
        Where the disturbance entered: ``"output"`` or ``"input"`` of the element.
    name
        The estimator's name for the summary (``"dekf-smoothed"``; default the
        result's own).

    Raises ``ValueError`` before any estimation when the control never moves
    (:func:`control_never_moves`).
    """
    still = control_never_moves(recording)
    if still is not None:
        raise ValueError(still)
    target = dict(target or {})
    result = estimator.estimate(recording, **target)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a diverged fit may overflow its resimulation
        try:
            model_output = resimulate(result, recording, **target)
        except (ValueError, FloatingPointError):
            model_output = None
    describing, note = trial_describing_function(
        recording,
        result,
        forcing=forcing,
        period=period,
        element=element,
        disturbance_at=disturbance_at,
    )
    check = check_fit(
        recording, result, model_output=model_output, describing=describing, frequency_note=note
    )
    return Identification(
        result=result,
        model_output=model_output,
        check=check,
        closed_loop=identified_loop(result, element),
        held_at_generic_values=held_by_rule(result),
        truth=truth_errors(result, recording),
        name=name,
    )
