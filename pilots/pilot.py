"""A synthetic pilot: a model structure with parameter schedules, remnant and delay mode.

Its data and checks are :class:`~manualcontrol.pilots.spec.PilotSpec`'s (what the
simulation reads); :class:`Pilot` adds acting in a tracking environment through a
:class:`~manualcontrol.pilots.controller.PilotController` and typical pilots per
element.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs.schedules import Schedule
from manualcontrol.pilots.controller import PilotController
from manualcontrol.pilots.models import PilotModel
from manualcontrol.pilots.remnant import Remnant
from manualcontrol.pilots.spec import HumanLimitWarning, PilotSpec
from manualcontrol.pilots.stability import typical_parameters

__all__ = ["HumanLimitWarning", "Pilot"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Pilot(PilotSpec):
    """A cybernetic pilot: model structure, parameter values or schedules, remnant.

    Parameters
    ----------
    model
        A :class:`~manualcontrol.pilots.models.PilotModel` or its name
        (``"precision"``, ``"precision-lag"``, ``"preview"``, ``"schiess-roland"``,
        ``"gain-delay"``).
    parameters
        Values (floats) or :mod:`~manualcontrol.envs.schedules` for any of the model's
        parameters; the others take the model's nominal values. Unknown names raise.
    remnant
        A :class:`~manualcontrol.pilots.remnant.Remnant`, a preset name, or None.
    delay_order
        None (default) simulates the model delay exactly with a fractional delay line;
        an integer ``m >= 1`` uses the order-``m`` Padé approximant instead.

    Values outside a parameter's valid range (e.g. a negative delay or neuromuscular
    frequency) raise ``ValueError``; values outside the human range warn with
    :class:`HumanLimitWarning`. Constant values are checked here, schedules wherever
    they are evaluated (:meth:`parameter_traces`). The gains ``K_p`` and ``K_v``, whose
    human values depend on the element, are checked where the element is known (the
    simulation's setup: :func:`~manualcontrol.pilots.models.element_gain_ranges`).

    """

    _controller: Any = field(default=None, init=False, repr=False, compare=False)

    def reset(
        self,
        seed: int | np.random.Generator | None = None,
        *,
        env: Any,
        on_unstable: str = "raise",
    ) -> None:
        """Start acting in ``env``'s current episode (call after ``env.reset()``).

        ``seed`` drives the remnant exactly as in :func:`~manualcontrol.pilots.simulate`:
        the same seed in both gives the same recording (``loop="sampled"``). A pilot
        that would close a diverging loop with the env's element raises
        :class:`~manualcontrol.pilots.stability.UnstableLoopError` here (closed-loop
        poles; a growth check of the episode when something varies), or warns with
        ``on_unstable="warn"``.
        """
        controller = PilotController(self, env, seed, on_unstable)
        object.__setattr__(self, "_controller", controller)

    def act(self, observation: ArrayLike) -> FloatArray:
        """The pilot's stick for an environment observation, shape ``(1,)``."""
        if self._controller is None:
            raise RuntimeError("call pilot.reset(seed, env=env) after env.reset() before act()")
        return self._controller.act(observation)

    @classmethod
    def typical(
        cls,
        model: PilotModel | str,
        element: Any,
        parameters: Mapping[str, float | Schedule] | None = None,
        remnant: Remnant | str | None = None,
        delay_order: int | None = None,
    ) -> Pilot:
        """A pilot with typical parameters for ``element`` (a stable loop), some replaced.

        ``Pilot.typical("precision", "DI")`` is the thesis's DI pilot; see
        :func:`~manualcontrol.pilots.stability.typical_parameters` for the table.
        """
        values: dict[str, Any] = dict(typical_parameters(model, element))
        values.update(parameters or {})
        return cls(model, values, remnant, delay_order)
