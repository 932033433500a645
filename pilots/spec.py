"""A pilot as data: model structure, parameter values or schedules, remnant, delay mode.

:class:`PilotSpec` is what the simulation, its stability checks and the controller read
of a pilot, checked where it is built. The :class:`~manualcontrol.pilots.pilot.Pilot`
users build is a PilotSpec that also acts in a tracking environment (through the
controller, which simulates the loop), so those modules import this one, and
:mod:`~manualcontrol.pilots.pilot` imports them.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._validation import check_int
from manualcontrol.envs.schedules import Schedule, as_schedule
from manualcontrol.pilots.models import ELEMENT_SCALED, PilotModel, make_model
from manualcontrol.pilots.remnant import Remnant, make_remnant

__all__ = ["HumanLimitWarning", "PilotSpec", "check_parameter_values"]

FloatArray = NDArray[np.float64]


class HumanLimitWarning(UserWarning):
    """A pilot parameter leaves the range observed in humans (the model still works)."""


def check_parameter_values(
    who: str,
    name: str,
    spec: Any,
    values: FloatArray,
    *,
    positive: bool,
    flagged: str = "human range",
) -> None:
    """Raise if ``values`` leave ``spec.valid``; warn if they leave ``spec.human``.

    ``who`` names the owner in the messages ("pilot", "driver"); ``positive`` makes the
    lower bound exclusive; ``flagged`` names the warning range. Called from an owner's
    ``_check``, the warning points at the code that called the owner's method.
    """
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{who} parameter {name} must be finite, got non-finite values")
    low, high = spec.valid
    outside = (values <= low if positive else values < low) | (values > high)
    if np.any(outside):
        left = "(" if positive else "["
        raise ValueError(
            f"{who} parameter {name} must lie in {left}{low:g}, {high:g}] {spec.unit}, "
            f"got {float(values[outside][0])!r}"
        )
    low, high = spec.human
    if np.any(values < low) or np.any(values > high):
        extreme = float(values.min() if np.any(values < low) else values.max())
        warnings.warn(
            f"{who} parameter {name} = {extreme:g} {spec.unit} is outside the {flagged} "
            f"[{low:g}, {high:g}] ({spec.description})",
            HumanLimitWarning,
            stacklevel=4,
        )


#: The highest Padé order of the pilot's delay: at 12 the highest coefficient of the
#: polynomial (``12! / 24!`` of the first, thesis eq. 4) reaches double precision's
#: 1e-16, so a higher order adds nothing a float can hold.
MAX_DELAY_ORDER = 12


@dataclass(frozen=True)
class PilotSpec:
    """A pilot's model structure, parameter values or schedules, remnant and delay mode.

    The arguments, their checks and their warnings are those of
    :class:`~manualcontrol.pilots.pilot.Pilot`, which adds acting in an environment
    (``reset``, ``act``) and typical pilots per element; copies and
    :meth:`from_dict` keep the class they are called on.
    """

    model: PilotModel | str
    parameters: Mapping[str, float | Schedule] = field(default_factory=dict)
    remnant: Remnant | str | None = None
    delay_order: int | None = None

    def __post_init__(self) -> None:
        model = make_model(self.model)
        object.__setattr__(self, "model", model)
        unknown = sorted(set(self.parameters) - set(model.parameter_names))
        if unknown:
            raise ValueError(
                f"{type(model).__name__} has no parameter(s) {', '.join(map(repr, unknown))}; "
                f"its parameters are {', '.join(model.parameter_names)}"
            )
        schedules: dict[str, Schedule] = {}
        for name in model.parameter_names:
            value = self.parameters.get(name, model.spec(name).nominal)
            try:
                schedules[name] = as_schedule(value)
            except (TypeError, ValueError) as error:
                raise type(error)(f"pilot parameter {name}: {error}") from None
        object.__setattr__(self, "parameters", MappingProxyType(schedules))
        object.__setattr__(self, "remnant", make_remnant(self.remnant))
        if self.delay_order is not None:
            object.__setattr__(
                self,
                "delay_order",
                check_int("delay_order", self.delay_order, minimum=1, maximum=MAX_DELAY_ORDER),
            )
        for name, schedule in schedules.items():
            if schedule.is_constant:
                self._check(name, np.atleast_1d(schedule(0.0)))

    def _check_delay(self, values: FloatArray) -> None:
        # a Padé approximant of a zero delay has a vanishing leading coefficient
        if self.delay_order is not None and np.any(values <= 0.0):
            raise ValueError(
                f"pilot parameter {self.model.delay_parameter} must be > 0 s with a Padé delay "
                f"(delay_order={self.delay_order}), got {float(values.min())!r}"
            )

    def _check(self, name: str, values: FloatArray) -> None:
        spec = self.model.spec(name)
        if name in ELEMENT_SCALED:
            # the gains humans use depend on the element, which the simulation checks
            spec = dataclasses.replace(spec, human=(-math.inf, math.inf))
        check_parameter_values("pilot", name, spec, values, positive=spec.positive)

    @property
    def is_time_varying(self) -> bool:
        """True when any parameter is a non-constant schedule."""
        return not all(schedule.is_constant for schedule in self.parameters.values())

    def parameter_traces(self, t: ArrayLike) -> dict[str, FloatArray]:
        """Every parameter evaluated at the times ``t`` (s), checked against its ranges."""
        t = np.asarray(t, dtype=np.float64)
        traces = {}
        for name, schedule in self.parameters.items():
            values = np.broadcast_to(np.asarray(schedule(t), dtype=np.float64), t.shape).copy()
            self._check(name, values)
            if name == self.model.delay_parameter:
                self._check_delay(values)
            traces[name] = values
        return traces

    def with_parameters(self, **values: float | Schedule) -> PilotSpec:
        """Copy with some parameters replaced."""
        return type(self)(self.model, {**self.parameters, **values}, self.remnant, self.delay_order)

    def with_remnant(self, remnant: Remnant | str | None) -> PilotSpec:
        """Copy with another remnant."""
        return type(self)(self.model, dict(self.parameters), remnant, self.delay_order)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description (model, schedules, remnant, delay order)."""
        options = {"near_view": self.model.near_view} if hasattr(self.model, "near_view") else {}
        if getattr(self.model, "lag", False):
            # written only when on: a plain precision pilot's dict stays as it was
            options["lag"] = True
        return {
            "model": self.model.name,
            "model_options": options,
            "parameters": {name: schedule.to_dict() for name, schedule in self.parameters.items()},
            "remnant": None if self.remnant is None else self.remnant.to_dict(),
            "delay_order": self.delay_order,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PilotSpec:
        """Inverse of :meth:`to_dict`."""
        options = data.get("model_options") or {}
        if not isinstance(options, Mapping):
            raise TypeError(f"model_options must be a dict, got {options!r}")
        model = make_model(data["model"], **dict(options))
        raw = data.get("parameters") or {}
        if not isinstance(raw, Mapping):
            raise TypeError(f"parameters must be a dict of name: value or schedule, got {raw!r}")
        parameters = {}
        for name, value in raw.items():
            try:
                parameters[name] = Schedule.from_dict(value)
            except (TypeError, ValueError) as error:
                raise type(error)(f"pilot parameter {name}: {error}") from None
        return cls(model, parameters, make_remnant(data.get("remnant")), data.get("delay_order"))
