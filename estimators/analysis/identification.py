"""Identify a pilot from one recording, with every cross-check a laboratory wants.

:func:`identify` is what ``manualcontrol identify`` runs (the command only reads the
file, prints and writes what this returns). :func:`build_estimator` builds the member
of the family from its name and settings, given the experiment's controlled element
where the member takes one, so that limits and rules come from the real plant.
:func:`identify` runs it over the recording, resimulates the identified model,
measures the describing function at the forcing frequencies when they are known and
checks the fit against it (:func:`~manualcontrol.estimators.analysis.fit_check.check_fit`),
checks that the identified pilot closes a stable loop with the element, and lists the
parameters held at generic values nobody measured. :class:`Identification` holds it
all, with the JSON-able :attr:`Identification.summary`.
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
from manualcontrol.estimators.analysis.metrics import pilot_model_of, resimulate
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
    "held_by_rule",
    "identified_loop",
    "identify",
    "trial_describing_function",
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
    """

    result: EstimationResult
    model_output: FloatArray | None
    check: FitCheck
    closed_loop: dict[str, Any]
    held_at_generic_values: dict[str, float]

    @property
    def final(self) -> dict[str, float]:
        """The last estimate of every parameter, rounded to 5 decimals."""
        return {name: round(float(value), 5) for name, value in self.result.final().items()}

    @property
    def summary(self) -> dict[str, Any]:
        """The JSON-able summary ``manualcontrol identify`` writes.

        Estimator, final values, fit, closed loop, health, and the member's own record
        where it has one (cross-validation, sigmoid, restarts, remnant choice).
        """
        result = self.result
        summary: dict[str, Any] = {
            "estimator": result.estimator,
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
        return summary


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
                    raise
        return make_estimator(spec)


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
            "not checked: the forcing frequencies are unknown (give --forcing PRESET or "
            "--period SECONDS, the forcing signals being in the file)"
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
        return {"stable": None, "message": "no controlled element known (--element ...)"}
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
        return {"stable": False, "message": f"the identified {message}: the fit is not credible"}
    except (TypeError, ValueError, KeyError) as error:
        return {"stable": None, "message": f"not checked: {error}"}
    return {"stable": True, "message": "the identified pilot closes a stable loop"}


def identify(
    recording: Recording,
    estimator: Any,
    *,
    element: Any = None,
    target: Mapping[str, Any] | None = None,
    forcing: Any = None,
    period: float | None = None,
    disturbance_at: str = "output",
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
    """
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
    )
