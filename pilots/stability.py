"""Is the closed loop stable? Typical pilots per controlled element, and divergence checks.

A pilot model's nominal parameters suit one element; on another they can close an
unstable loop (the precision model's nominal lead K_v = 0.5 on a double integrator
diverges to 1e36 in two minutes). Two things follow:

- :func:`typical_parameters` gives a typical, stable pilot for the chosen element:
  the papers' pilots for their elements (thesis Table 6.1: SI Sims 2-7, DI Sim 8;
  Popovici et al. 2017 Sec. IV-A for ``K/(s(s + omega_b))``), their gains scaled
  inversely with the element gain so that the crossover frequency stays where the
  papers had it.
- :func:`check_stable` and :func:`check_growth` detect a diverging loop. With a
  constant pilot and a constant element the closed-loop poles decide (the pilot's
  delay as an order-6 Padé approximant: its phase is within 1 degree of the exact
  delay up to ``omega tau = 7``, far beyond crossover); with anything time-varying
  a growth check on the simulated run decides (frozen-time poles neither prove nor
  disprove stability of a time-varying loop). Divergence is an
  :class:`UnstableLoopError` by default; ``on_unstable="warn"`` turns it into an
  :class:`UnstableLoopWarning` and the caller flags the result.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_choice, check_real
from manualcontrol.envs.elements import ControlledElement, make_element
from manualcontrol.envs.tasks import task_named
from manualcontrol.pilots.loop import SimulationSetup, closed_loop
from manualcontrol.pilots.models import PilotModel, make_model
from manualcontrol.pilots.spec import HumanLimitWarning, PilotSpec

__all__ = [
    "ON_UNSTABLE",
    "UnstableLoopError",
    "UnstableLoopWarning",
    "check_growth",
    "check_stable",
    "closed_loop_poles",
    "report_unstable",
    "typical_parameters",
]

FloatArray = NDArray[np.float64]

#: What to do about a diverging loop.
ON_UNSTABLE: tuple[str, ...] = ("raise", "warn")

#: Padé order of the pilot delay in the pole computation (see the module docstring).
POLE_PADE_ORDER = 6

#: A run diverges when |e| exceeds this many times the forcing's peak (|ft| + |fd|).
GROWTH_LIMIT = 100.0


class UnstableLoopError(ValueError):
    """The pilot and the controlled element close an unstable (diverging) loop."""


class UnstableLoopWarning(UserWarning):
    """The loop diverges and the caller asked for a warning instead of an error."""


# Typical pilots, each for a reference element; the gains scale as reference K / K.
# precision and gain-delay: thesis Table 6.1 (SI: Sims 2-7's equalisation and
# neuromuscular values; DI: Sim 8), Popovici et al. 2017 Sec. IV-A for K/(s(s+omega_b)).
_EQUALISATION = {
    "integrator": (
        1.5,
        {"K_p": 1.3, "K_v": 0.0, "tau_v": 0.26, "omega_nms": 10.5, "zeta_nms": 0.35},
    ),
    "double_integrator": (
        5.0,
        {"K_p": 0.24, "K_v": 0.36, "tau_v": 0.3, "omega_nms": 8.0, "zeta_nms": 0.45},
    ),
    # Popovici's pilot on their 4/(s(s+3)); on another omega_b, typical_parameters sets
    # K_p and K_v by McRuer & Jex's rule, which gives these on theirs
    "integrator_with_lag": (
        4.0 / 3.0,  # low-frequency gain K/omega_b of Popovici's 4/(s(s+3))
        {"K_p": 1.5, "K_v": 0.5, "tau_v": 0.2, "omega_nms": 8.0, "zeta_nms": 0.3},
    ),
    # not from the papers: a proportional pilot on a pure gain (loop gain 0.5) and on
    # the critical task (loop gain 2 above lambda; unscaled, lambda is what rises)
    "gain": (1.0, {"K_p": 0.5, "K_v": 0.0, "tau_v": 0.2, "omega_nms": 10.5, "zeta_nms": 0.35}),
    "unstable_first_order": (
        math.nan,
        {"K_p": 2.0, "K_v": 0.0, "tau_v": 0.2, "omega_nms": 10.5, "zeta_nms": 0.35},
    ),
}
_PREVIEW_FAR = {
    "integrator": {"K_f": 1.0, "omega_f": 3.3, "tau_f": 0.6},
    "double_integrator": {"K_f": 0.9, "omega_f": 1.0, "tau_f": 0.6},
    "integrator_with_lag": {"K_f": 1.0, "omega_f": 3.3, "tau_f": 0.6},
    "gain": {"K_f": 1.0, "omega_f": 3.3, "tau_f": 0.6},
    "unstable_first_order": {"K_f": 1.0, "omega_f": 3.3, "tau_f": 0.6},
}
_GAINS = ("K_p", "K_v", "K_1")
#: The asymptotic crossover of the typical pilot on ``K/(s(s + omega_b))``, rad/s:
#: ``K_p K/omega_b`` (:func:`typical_parameters`), where Popovici et al.'s pilot puts it.
_LAG_ELEMENT_CROSSOVER = 2.0


def _reference_gain(element: ControlledElement, t: float = 0.0) -> tuple[str, float] | None:
    values = {name: float(v[0]) for name, v in element.parameters_at(np.array([t])).items()}
    if element.kind in ("integrator", "double_integrator", "gain"):
        return element.kind, values["K"]
    if element.kind == "unstable_first_order":
        return element.kind, math.nan
    if element.kind == "integrator_with_lag":
        return element.kind, values["K"] / values["omega_b"]
    return None


def typical_parameters(
    model: str | PilotModel,
    element: str | ControlledElement | Mapping[str, Any],
    t: float = 0.0,
) -> dict[str, float]:
    """Typical parameter values of ``model`` for ``element`` (a stable loop).

    Single integrators get the thesis's SI pilot (K_p 1.3 on 1.5/s, no lead, tau_v
    0.26 s, omega_nms 10.5 rad/s, zeta_nms 0.35), double integrators its DI pilot
    (K_p 0.24 and K_v 0.36 on 5/s^2, tau_v 0.3 s, omega_nms 8, zeta_nms 0.45),
    ``K/(s(s + omega_b))`` McRuer & Jex's (1967) rule, lead cancelling the lag
    (``T_L = 1/omega_b``, ``K_v = K_p T_L``) and the loop gain ``K_p K / omega_b`` at
    2 rad/s, with Popovici et al.'s (2017) delay and neuromuscular values (tau_v 0.2 s,
    omega_nms 8 rad/s, zeta_nms 0.3): on their 4/(s(s+3)) it is their pilot (K_p 1.5,
    K_v 0.5). The other gains are scaled by reference gain / element gain (a
    time-varying element's read at ``t``). A pure gain gets a proportional pilot of
    loop gain 0.5 from a model without McRuer's lag (our choice: the papers fly none;
    the lag model's pilot is below), the critical task one of gain 2. The preview model
    adds the far view of thesis Sims 2 and 8. The Schiess-Roland model's nominal values
    are their pilot for 10/s^2; its K_1 is scaled likewise on other double
    integrators. General transfer functions get the model's nominal values, and a
    gain-delay pilot cannot stabilise a double integrator at all; :func:`check_stable`
    says so.

    The precision model with McRuer's lag (``PrecisionModel(lag=True)``) on a pure gain
    ``K``: McRuer & Jex's (1967) lag equalisation, no lead, the lag's break a decade
    below crossover (``T_I = 10/omega_c``: the loop keeps an integrator's slope and,
    within 6 deg, its phase through the crossover region), the asymptotic loop gain
    ``K_p K / T_I`` at :data:`~manualcontrol.pilots.models.GAIN_CROSSOVER` (humans cross
    over higher on a gain than on ``K/s``): the model's nominal ``T_I`` and ``K_p``, the
    latter divided by ``K``. Delay and neuromuscular system are the SI pilot's, whose
    limitations leave 30 deg of phase margin only up to about that crossover. On a unit
    gain: K_p 10, T_I 3.33 s; the neuromuscular peak puts the measured crossover at
    3.2 rad/s with 34 deg of margin. On other elements humans adopt no lag, and the lag
    model has no typical pilot there: ``ValueError``, naming the plain model.

    ``t``: the time at which a time-varying element is read (default the start).
    """
    model = make_model(model)
    given, element = element, make_element(element)
    t = check_real("t", t)
    if getattr(model, "lag", False):
        if element.kind != "gain":
            raise ValueError(
                "the precision model's lag is McRuer's equalisation of a pure gain; on "
                f"element={given!r} humans adopt none, and the typical pilot is the "
                "precision model's without it (model='precision')"
            )
        _, gain = _reference_gain(element, t)
        si = _EQUALISATION["integrator"][1]
        return {  # the model's nominal values are this pilot on a unit gain
            "K_p": model.spec("K_p").nominal / gain,
            "K_v": 0.0,
            "T_I": model.spec("T_I").nominal,
            **{name: si[name] for name in ("tau_v", "omega_nms", "zeta_nms")},
        }
    values = {name: model.spec(name).nominal for name in model.parameter_names}
    reference = _reference_gain(element, t)
    if reference is None:
        return values
    kind, gain = reference
    if model.name == "schiess-roland":
        if kind == "double_integrator":
            values["K_1"] *= 10.0 / gain
        return values
    reference_gain, table = _EQUALISATION[kind]
    scale = 1.0 if math.isnan(gain) else reference_gain / gain
    for name, value in table.items():
        if name in values:
            values[name] = value * scale if name in _GAINS else value
    if kind == "integrator_with_lag" and "K_v" in values:
        read = element.parameters_at(np.array([t]))
        K, omega_b = float(read["K"][0]), float(read["omega_b"][0])
        values["K_p"] = _LAG_ELEMENT_CROSSOVER * omega_b / K
        values["K_v"] = values["K_p"] / omega_b
    if model.name == "preview":
        values.update(_PREVIEW_FAR[kind])
    return values


def closed_loop_poles(setup: Any, t: float = 0.0) -> NDArray[np.complex128]:
    """Poles of the continuous closed loop at time ``t`` (delay as order-6 Padé)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HumanLimitWarning)
        pilot = PilotSpec(
            setup.pilot.model,
            dict(setup.pilot.parameters),
            None,  # the remnant filter is an input to the loop, not part of it
            setup.pilot.delay_order or POLE_PADE_ORDER,
        )
    padé = SimulationSetup(
        pilot,
        setup.element,
        setup.forcing,
        setup.task,
        setup.available_preview,
        setup.dt,
        setup.run_in,
        setup.measurement_time,
    )
    return np.linalg.eigvals(closed_loop(padé, t).system.A)


def report_unstable(message: str, on_unstable: str) -> None:
    """Raise :class:`UnstableLoopError`, or warn with :class:`UnstableLoopWarning`."""
    if on_unstable == "raise":
        raise UnstableLoopError(message)
    warnings.warn(message, UnstableLoopWarning, stacklevel=3)


_ADVICE = (
    "use typical parameters for the element (Pilot.typical(model, element); the "
    "`manualcontrol simulate` default), or pass on_unstable='warn' "
    "(--allow-unstable) to keep the run"
)


def check_stable(setup: Any, *, on_unstable: str = "raise") -> bool | None:
    """Closed-loop poles of a constant set-up: True when stable; None when time-varying.

    An unstable constant loop raises :class:`UnstableLoopError` naming the pole
    (or warns, ``on_unstable="warn"``, and returns False). Time-varying set-ups, and the
    gap-postview task, are left to :func:`check_growth` on the simulated run.
    """
    check_choice("on_unstable", on_unstable, ON_UNSTABLE)
    if setup.pilot.is_time_varying or setup.element.is_time_varying:
        return None
    if task_named(setup.task).shows_postview:
        # the postview operator extrapolates a displayed past track (no model delay of
        # its own): the pole analysis has no form for it; the growth check judges the run
        return None
    poles = closed_loop_poles(setup)
    worst = poles[np.argmax(poles.real)]
    if worst.real <= 1e-9:
        return True
    values = {name: float(s(0.0)) for name, s in setup.pilot.parameters.items()}
    shown = ", ".join(f"{name}={value:g}" for name, value in values.items())
    report_unstable(
        f"the {setup.pilot.model.name} pilot ({shown}) and the controlled element "
        f"{_describe(setup.element)} close an unstable loop: closed-loop pole at "
        f"{worst.real:.3g}{worst.imag:+.3g}j rad/s (time constant of growth "
        f"{1.0 / worst.real:.3g} s); {_ADVICE}",
        on_unstable,
    )
    return False


def check_growth(
    t: FloatArray,
    e: FloatArray,
    forcing_peak: float,
    *,
    what: str,
    on_unstable: str = "raise",
) -> bool:
    """True when the run stays bounded: ``|e|`` within 100 forcing peaks, all finite.

    A stable loop, however poor, keeps the error of the order of the forcing; an
    unstable one grows exponentially and passes 100 peaks within a few time
    constants. Otherwise raises :class:`UnstableLoopError` (or warns and returns False).
    """
    check_choice("on_unstable", on_unstable, ON_UNSTABLE)
    limit = GROWTH_LIMIT * (forcing_peak if forcing_peak > 0.0 else 1.0)
    bad = ~np.isfinite(e) | (np.abs(np.nan_to_num(e, nan=np.inf)) > limit)
    if not bad.any():
        return True
    first = int(np.flatnonzero(bad)[0])
    report_unstable(
        f"{what} diverges: |e| passes {GROWTH_LIMIT:g} times the forcing's peak "
        f"({limit:.3g}) at t = {float(t[first]):.2f} s; {_ADVICE}",
        on_unstable,
    )
    return False


def _describe(element: ControlledElement) -> str:
    values = {name: float(v[0]) for name, v in element.parameters_at(np.zeros(1)).items()}
    shown = ", ".join(f"{name}={value:g}" for name, value in values.items())
    return f"{element.kind} ({shown})" if math.isfinite(sum(values.values())) else element.kind
