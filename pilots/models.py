"""Pilot model structures: parameters, human limits and transfer functions.

A structure is the one definition of a cybernetic pilot model that both the synthetic
pilot (:mod:`manualcontrol.pilots.simulation`) and the estimators' internal models are
built from. Every model has the same shape:

    u = sum over channels c of  post_c(s) e^{-tau s} [ sum over branches b of  pre_b(s) x_b ]

where ``x_b`` are the pilot's perceptions (the error ``e``; or the previewed target
``ft_far`` and the output ``y``), ``tau`` is the model's delay parameter, and the pre-
and post-delay transfer functions are polynomials in ``s`` whose coefficients are
functions of the parameters (arrays: one value per sample of an LPV trajectory). The
delay is applied exactly by a delay line or as a Padé approximant, as the caller asks.

Parameters have one spelling across the package: ``K_p, K_v, tau_v, omega_nms, zeta_nms``,
``K_f, omega_f, tau_f``, ``K_n, tau_n``, ``K_1, tau_1, tau_2, tau_3, theta``.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._validation import check_choice
from manualcontrol.envs.dynamics import pade, poly_multiply
from manualcontrol.envs.elements import make_element

__all__ = [
    "CROSSOVER_RANGE",
    "ELEMENT_SCALED",
    "GAIN_CROSSOVER",
    "LAGGED_PRECISION",
    "MODEL_NAMES",
    "Branch",
    "Channel",
    "GainDelayModel",
    "ParameterSpec",
    "PilotModel",
    "PostviewModel",
    "PrecisionModel",
    "PreviewModel",
    "SchiessRolandModel",
    "element_gain_ranges",
    "make_model",
    "model_for_element",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ParameterSpec:
    """One pilot parameter: its name, nominal value and ranges.

    ``valid`` is where the model is defined at all (outside it simulation raises; a
    valid lower bound of 0 excludes 0 itself when ``positive``); ``human`` is where
    humans have been observed (outside it simulation warns). Human
    ranges follow thesis Table I where it gives one; elsewhere wider bounds chosen
    from the cited experiments, as documented per model.
    """

    name: str
    nominal: float
    human: tuple[float, float]
    valid: tuple[float, float]
    unit: str
    description: str
    positive: bool = False


@dataclass(frozen=True)
class Branch:
    """A pre-delay path: perception ``signal`` through ``num(s)/den(s)``."""

    signal: str
    num: FloatArray
    den: FloatArray


@dataclass(frozen=True)
class Channel:
    """Branches summed, delayed by the model delay, then through ``num(s)/den(s)``."""

    branches: tuple[Branch, ...]
    num: FloatArray
    den: FloatArray


def _ones_like(values: Mapping[str, FloatArray]) -> FloatArray:
    shape = np.broadcast_shapes(*(np.shape(v) for v in values.values()))
    return np.ones(shape)


def _stack(*columns: ArrayLike) -> FloatArray:
    arrays = np.broadcast_arrays(*(np.asarray(c, dtype=np.float64) for c in columns))
    return np.stack(arrays, axis=-1)


class PilotModel(abc.ABC):
    """Base class of the pilot model structures."""

    #: Registry name (see :func:`make_model`).
    name: ClassVar[str]
    #: Display type the model belongs to: "compensatory", "preview" or "postview".
    task: ClassVar[str]
    #: Name of the parameter that is the model's delay.
    delay_parameter: ClassVar[str]
    #: Perception signals the model reads.
    perceptions: ClassVar[tuple[str, ...]]

    @property
    @abc.abstractmethod
    def parameters(self) -> tuple[ParameterSpec, ...]:
        """The model's parameters, in a fixed order."""

    @abc.abstractmethod
    def channels(self, values: Mapping[str, FloatArray]) -> tuple[Channel, ...]:
        """Pre- and post-delay transfer functions for the given parameter values.

        ``values`` maps every parameter name to an array (all of one shape, e.g. one
        entry per sample); coefficient arrays come back with that shape plus one axis.
        """

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of :attr:`parameters` in order."""
        return tuple(spec.name for spec in self.parameters)

    def spec(self, name: str) -> ParameterSpec:
        """The :class:`ParameterSpec` called ``name``."""
        check_choice(f"{type(self).__name__} parameter", name, self.parameter_names)
        return next(spec for spec in self.parameters if spec.name == name)

    def nominal(self) -> dict[str, float]:
        """Nominal value of every parameter."""
        return {spec.name: spec.nominal for spec in self.parameters}

    @property
    def registered_name(self) -> str:
        """The name that names this structure in settings and files.

        The class's registry name, and ``"precision-lag"`` for the precision model with
        McRuer's lag (whose class is ``"precision"``), so that a setting or a result
        saying it rebuilds the lag. Other constructor options (the preview model's near
        view) are not part of it.
        """
        return self.name

    def frequency_response(
        self, values: Mapping[str, float], omega: ArrayLike, signal: str
    ) -> NDArray[np.complex128]:
        """Response ``u/signal`` at ``omega`` (rad/s) with the delay exact.

        ``signal`` is one of :attr:`perceptions`; the other perceptions are held at 0.
        """
        check_choice("signal", signal, self.perceptions)
        omega = np.asarray(omega, dtype=np.float64)
        s = 1j * omega
        arrays = {name: np.asarray(float(value)) for name, value in values.items()}
        delay = np.exp(-s * float(values[self.delay_parameter]))
        total = np.zeros(omega.shape, dtype=np.complex128)
        for channel in self.channels(arrays):
            post = np.polyval(channel.num, s) / np.polyval(channel.den, s)
            for branch in channel.branches:
                if branch.signal == signal:
                    total += post * delay * np.polyval(branch.num, s) / np.polyval(branch.den, s)
        return total

    def transfer_function(
        self, values: Mapping[str, float], signal: str, delay_order: int
    ) -> tuple[FloatArray, FloatArray]:
        """Rational ``u/signal`` with the delay as an order-``delay_order`` Padé approximant.

        Channels are brought onto one common denominator, so the result is the
        exact sum of the channel transfer functions (not reduced).
        """
        check_choice("signal", signal, self.perceptions)
        arrays = {name: np.asarray(float(value)) for name, value in values.items()}
        pade_num, pade_den = pade(float(values[self.delay_parameter]), delay_order)
        num_total, den_total = np.zeros(1), np.ones(1)
        for channel in self.channels(arrays):
            for branch in channel.branches:
                if branch.signal != signal:
                    continue
                num = poly_multiply(poly_multiply(channel.num, branch.num), pade_num)
                den = poly_multiply(poly_multiply(channel.den, branch.den), pade_den)
                num_total = np.polyadd(poly_multiply(num_total, den), poly_multiply(num, den_total))
                den_total = poly_multiply(den_total, den)
        return num_total, den_total

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


# ------------------------------------------------------------------- shared specs

#: Where humans put the crossover frequency (rad/s, McRuer's crossover model and the
#: tracking experiments since): the gains humans use on an element are those that put
#: the loop's crossover in this range.
CROSSOVER_RANGE: tuple[float, float] = (0.5, 8.0)
#: Parameters whose human values depend on the element's gain and order (``K_p`` on a
#: plant of gain 1 is three times ``K_p`` on 3/s): their ranges come from the element
#: (:func:`element_gain_ranges`), not from one experiment's table.
ELEMENT_SCALED: tuple[str, ...] = ("K_p", "K_v")


def element_gain_ranges(element: Any, t: float = 0.0) -> dict[str, tuple[float, float]]:
    """The pilot gains that put the crossover anywhere in :data:`CROSSOVER_RANGE`.

    ``K_p`` between the smallest and the largest ``1/|H_c(j w)|`` over the range (a
    proportional pilot crossing over there); ``K_v`` (lead, ``K_p T_L``) from 0 to the
    largest ``1/(w |H_c(j w)|)`` (a lead pilot crossing over there). ``element`` is a
    controlled element (or anything :func:`~manualcontrol.envs.elements.make_element`
    reads), taken at time ``t``. Empty for an element that does not integrate (no pole at
    the origin: a pure gain, a lag), where a proportional pilot's loop has no crossover to
    place (humans equalise it with a lag instead), and where the element passes nothing
    at some frequency of the range (the critical task's element at zero instability).
    """
    plant = make_element(element)
    _, den = (np.asarray(c, dtype=np.float64).reshape(-1) for c in plant.transfer_function(t))
    if den[-1] != 0.0:
        return {}
    omega = np.geomspace(*CROSSOVER_RANGE, 200)
    magnitude = np.abs(plant.frequency_response(omega, t))
    if not np.all(magnitude > 0.0):
        return {}
    proportional = 1.0 / magnitude
    lead = 1.0 / (omega * magnitude)
    return {
        "K_p": (float(proportional.min()), float(proportional.max())),
        "K_v": (0.0, float(lead.max())),
    }


_K_P = ParameterSpec("K_p", 1.5, (0.05, 2.5), (-math.inf, math.inf), "-", "visual position gain")
_K_V = ParameterSpec("K_v", 0.5, (0.0, 1.5), (-math.inf, math.inf), "s", "visual rate gain K_p T_L")
_TAU_V = ParameterSpec("tau_v", 0.2, (0.1, 0.8), (0.0, math.inf), "s", "visual time delay")
_OMEGA_NMS = ParameterSpec(
    "omega_nms", 8.0, (6.0, 15.0), (0.0, math.inf), "rad/s", "neuromuscular frequency", True
)
_ZETA_NMS = ParameterSpec(
    "zeta_nms", 0.3, (0.1, 0.8), (0.0, math.inf), "-", "neuromuscular damping"
)


#: The typical lag-equalised pilot's asymptotic crossover on a pure gain, rad/s: the
#: low end of McRuer's 3-5 rad/s on ``K`` (humans cross over higher on a gain than on
#: ``K/s``). Its lag breaks a decade below (the nominal ``T_I``), and its ``K_p`` on a
#: unit gain puts ``K_p K/T_I`` there (the nominal ``K_p``).
GAIN_CROSSOVER = 3.0
#: The lag equaliser's time constant: its break ``1/T_I`` below the crossover range
#: (humans' lag on a pure gain leaves the loop an integrator's slope through crossover).
_T_I = ParameterSpec(
    "T_I", 10.0 / GAIN_CROSSOVER, (1.0, 20.0), (0.0, math.inf), "s", "lag time constant", True
)
#: ``K_p`` of the lag-equalised pilot: crossover near ``K_p K/T_I``, so ``K_p K`` spans
#: :data:`CROSSOVER_RANGE` times the human range of ``T_I``.
_K_P_LAG = ParameterSpec(
    "K_p",
    GAIN_CROSSOVER * _T_I.nominal,
    (CROSSOVER_RANGE[0] * _T_I.human[0], CROSSOVER_RANGE[1] * _T_I.human[1]),
    (-math.inf, math.inf),
    "-",
    "static gain of the lag equaliser",
)
_K_V_LAG = ParameterSpec(
    "K_v", 0.0, (0.0, 1.5), (-math.inf, math.inf), "s", "visual rate gain K_p T_L"
)


def _equalised_nms(values: Mapping[str, FloatArray]) -> tuple[FloatArray, FloatArray]:
    """``(K_p + K_v s) omega^2 / (s^2 + 2 zeta omega s + omega^2)`` (Popovici eq. 1)."""
    omega = values["omega_nms"]
    zeta = values["zeta_nms"]
    omega2 = omega * omega
    num = _stack(values["K_v"] * omega2, values["K_p"] * omega2)
    den = _stack(np.ones_like(omega), 2.0 * zeta * omega, omega2)
    return num, den


def _unity(values: Mapping[str, FloatArray]) -> tuple[FloatArray, FloatArray]:
    one = _ones_like(values)
    return one[..., None], one[..., None]


@dataclass(frozen=True, repr=False)
class PrecisionModel(PilotModel):
    """McRuer's precision (crossover) model for compensatory tracking, Popovici eq. 1.

    ``H_p(s) = (K_p + K_v s) e^{-tau_v s} omega_nms^2 / (s^2 + 2 zeta_nms omega_nms s
    + omega_nms^2)``, perception: the displayed error ``e``. Nominal values are the
    Popovici-type compensatory pilot (K_p 1.5, K_v 0.5, tau_v 0.2 s, omega_nms 8 rad/s,
    zeta_nms 0.3); human ranges are thesis Table I (union of its SI and DI columns;
    K_v from 0 because single-integrator pilots use none).

    ``lag=True`` adds McRuer's lag equaliser, ``(K_p + K_v s)/(T_I s + 1)`` (McRuer &
    Jex 1967, the precision model's ``K_p (T_L s + 1)/(T_I s + 1)`` with ``K_v = K_p
    T_L``): the equalisation humans adopt on a pure gain, where the loop needs an
    integrator's slope near crossover that the element does not give. Popovici's eq. 1
    is its ``T_I = 0`` form, which is why the estimators identify the model without
    it. With the lag, ``K_p`` is the static gain of a loop that crosses over near
    ``K_p K/T_I`` on a gain ``K``, so its human range follows from
    :data:`CROSSOVER_RANGE` and ``T_I``'s (a lag whose break lies below the crossover
    range); its nominal ``K_p`` and ``T_I`` are the typical pilot's on a unit gain
    (:func:`~manualcontrol.pilots.stability.typical_parameters`).
    """

    lag: bool = False

    name: ClassVar[str] = "precision"
    task: ClassVar[str] = "compensatory"
    delay_parameter: ClassVar[str] = "tau_v"
    perceptions: ClassVar[tuple[str, ...]] = ("e",)

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:  # noqa: D102
        if self.lag:
            return (_K_P_LAG, _K_V_LAG, _T_I, _TAU_V, _OMEGA_NMS, _ZETA_NMS)
        return (_K_P, _K_V, _TAU_V, _OMEGA_NMS, _ZETA_NMS)

    def channels(self, values: Mapping[str, FloatArray]) -> tuple[Channel, ...]:  # noqa: D102
        num, den = _unity(values)
        if self.lag:
            den = _stack(values["T_I"], _ones_like(values))
        return (Channel((Branch("e", num, den),), *_equalised_nms(values)),)

    def __post_init__(self) -> None:
        if self.lag not in (True, False):
            raise TypeError(f"lag must be True or False, got {self.lag!r}")

    @property
    def registered_name(self) -> str:  # noqa: D102
        return LAGGED_PRECISION if self.lag else self.name

    def __repr__(self) -> str:
        return "PrecisionModel(lag=True)" if self.lag else "PrecisionModel()"


@dataclass(frozen=True, repr=False)
class PreviewModel(PilotModel):
    """Van der El et al.'s preview model (thesis Part I Sec. II-A, Fig. 1; Part II Fig. 4.2).

    Far view: the target previewed ``tau_f`` ahead, ``ft_far(t) = ft(t + tau_f)``, is
    low-pass filtered by ``K_f omega_f/(s + omega_f)`` (thesis eq. 1); the internal
    error ``e* = ft_f - y`` goes through the compensatory equalisation ``K_p + K_v s``
    (eq. 2), the visual delay and the neuromuscular system (eq. 3). With
    ``near_view=True`` a near-viewpoint response ``K_n`` on the target rate at
    ``t + tau_n`` (perception ``ft_near_rate``) is added before the delay, bypassing
    the equalisation (van der El et al. 2016; the thesis leaves it out as small).
    Pursuit tracking is this model with no preview available: ``tau_f = 0``.

    Nominal values: thesis Table 6.1 Sim 2 (SI): tau_f 0.6 s, K_f 1, omega_f 3.3 rad/s,
    K_p 1.3, K_v 0, omega_nms 10.5 rad/s, zeta_nms 0.35, tau_v 0.26 s. Human ranges:
    thesis Table I (union of SI and DI columns); tau_f up to 2 s (the longest preview
    of van der El's experiments).
    """

    near_view: bool = False

    name: ClassVar[str] = "preview"
    task: ClassVar[str] = "preview"
    delay_parameter: ClassVar[str] = "tau_v"

    @property
    def perceptions(self) -> tuple[str, ...]:  # type: ignore[override]  # noqa: D102
        return ("ft_far", "y", "ft_near_rate") if self.near_view else ("ft_far", "y")

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:  # noqa: D102
        specs = (
            ParameterSpec("K_f", 1.0, (0.2, 2.5), (-math.inf, math.inf), "-", "far-view gain"),
            ParameterSpec(
                "omega_f",
                3.3,
                (0.1, 10.0),
                (0.0, math.inf),
                "rad/s",
                "far-view break frequency",
                True,
            ),
            ParameterSpec("tau_f", 0.6, (0.0, 2.0), (0.0, math.inf), "s", "far-view preview time"),
            ParameterSpec(
                "K_p", 1.3, (0.05, 2.5), (-math.inf, math.inf), "-", "visual position gain"
            ),
            ParameterSpec("K_v", 0.0, (0.0, 1.5), (-math.inf, math.inf), "s", "visual rate gain"),
            ParameterSpec("tau_v", 0.26, (0.1, 0.8), (0.0, math.inf), "s", "visual time delay"),
            ParameterSpec(
                "omega_nms",
                10.5,
                (6.0, 15.0),
                (0.0, math.inf),
                "rad/s",
                "neuromuscular frequency",
                True,
            ),
            ParameterSpec(
                "zeta_nms", 0.35, (0.1, 0.8), (0.0, math.inf), "-", "neuromuscular damping"
            ),
        )
        if self.near_view:
            specs += (
                ParameterSpec("K_n", 0.1, (0.0, 1.0), (-math.inf, math.inf), "s", "near-view gain"),
                ParameterSpec(
                    "tau_n", 0.2, (0.0, 1.0), (0.0, math.inf), "s", "near-view preview time"
                ),
            )
        return specs

    def channels(self, values: Mapping[str, FloatArray]) -> tuple[Channel, ...]:  # noqa: D102
        one = _ones_like(values)
        omega_f = values["omega_f"]
        far = Branch("ft_far", (values["K_f"] * omega_f)[..., None], _stack(one, omega_f))
        feedback = Branch("y", -one[..., None], one[..., None])
        channels = (Channel((far, feedback), *_equalised_nms(values)),)
        if self.near_view:
            omega = values["omega_nms"]
            omega2 = omega * omega
            near = Branch("ft_near_rate", values["K_n"][..., None] * one[..., None], one[..., None])
            nms = (omega2[..., None], _stack(one, 2.0 * values["zeta_nms"] * omega, omega2))
            channels += (Channel((near,), *nms),)
        return channels

    def __repr__(self) -> str:
        return f"PreviewModel(near_view={self.near_view})"


class SchiessRolandModel(PilotModel):
    """Schiess & Roland (1975) eq. 1, the delayed lead-lag pilot.

    ``K_1 (tau_3 s + 1) e^{-theta s} / ((tau_1 s + 1)(tau_2 s + 1))``.

    Nominal values: their Table I true values (K_1 1, tau_1 0.1 s, tau_2 0.1 s,
    tau_3 0.5 s, theta 0.05 s). The paper gives no human ranges; the wide bounds here
    only flag implausible values.
    """

    name: ClassVar[str] = "schiess-roland"
    task: ClassVar[str] = "compensatory"
    delay_parameter: ClassVar[str] = "theta"
    perceptions: ClassVar[tuple[str, ...]] = ("e",)

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:  # noqa: D102
        return (
            ParameterSpec("K_1", 1.0, (0.01, 100.0), (-math.inf, math.inf), "-", "static gain"),
            ParameterSpec(
                "tau_1", 0.1, (0.0, 10.0), (0.0, math.inf), "s", "pilot lag time constant", True
            ),
            ParameterSpec(
                "tau_2", 0.1, (0.0, 10.0), (0.0, math.inf), "s", "pilot lag time constant", True
            ),
            ParameterSpec(
                "tau_3", 0.5, (0.0, 10.0), (0.0, math.inf), "s", "pilot lead time constant"
            ),
            ParameterSpec("theta", 0.05, (0.0, 1.0), (0.0, math.inf), "s", "effective time delay"),
        )

    def channels(self, values: Mapping[str, FloatArray]) -> tuple[Channel, ...]:  # noqa: D102
        one = _ones_like(values)
        num = values["K_1"][..., None] * _stack(values["tau_3"], one)
        den = poly_multiply(_stack(values["tau_1"], one), _stack(values["tau_2"], one))
        unity_num, unity_den = _unity(values)
        return (Channel((Branch("e", unity_num, unity_den),), num, den),)


class GainDelayModel(PilotModel):
    """Pure gain, pure delay pilot ``K_p e^{-tau_v s}`` (Boer & Kenyon 1998, Sec. V-VI).

    The model of their gap-postview and critical tracking experiments. Nominal K_p 1,
    tau_v 0.2 s; human ranges are wide (their identified delays stay within 0-1 s).
    """

    name: ClassVar[str] = "gain-delay"
    task: ClassVar[str] = "compensatory"
    delay_parameter: ClassVar[str] = "tau_v"
    perceptions: ClassVar[tuple[str, ...]] = ("e",)

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:  # noqa: D102
        return (
            ParameterSpec("K_p", 1.0, (0.01, 20.0), (-math.inf, math.inf), "-", "pilot gain"),
            ParameterSpec("tau_v", 0.2, (0.0, 1.0), (0.0, math.inf), "s", "pilot delay"),
        )

    def channels(self, values: Mapping[str, FloatArray]) -> tuple[Channel, ...]:  # noqa: D102
        num, den = _unity(values)
        return (Channel((Branch("e", num, den),), values["K_p"][..., None] * num, den),)


class PostviewModel(PilotModel):
    """Gap-postview operator: extrapolates the visible end of the past track (Boer & Kenyon).

    In Boer & Kenyon's gap-postview task (1998, Sec. V) the track is shown from ``t - 1 s``
    down to ``t - gap``; the operator must place a pure-gain marker where the track meets
    the present. This operator reads the visible end of the track, its value
    ``ft_edge(t) = ft(t - gap)`` and slope ``ft_edge_rate`` (perceptions the display
    gives, :mod:`manualcontrol.envs.postview`), and extrapolates linearly::

        u = e^{-tau_v s} (K_p ft_edge + K_v ft_edge_rate)

    i.e. ``K_p`` times the track extrapolated ``K_v/K_p`` seconds across the gap: the
    simple linear extrapolation the paper proposes (Sec. V-C). For a band-limited track
    this acts as a gain and delay of about ``gap + tau_v - K_v/K_p``; the nominal
    ``K_p`` 1, ``K_v`` 0.2 s, ``tau_v`` 0 give the paper's finding, delay = gap - 0.2 s.
    A pure time advance it is not: against a 0.6-Hz band-limited track the best pure
    gain and delay fit is about 1.08 and ``gap - 0.18`` s (the extrapolation falls
    short of the advance at the higher frequencies).
    """

    name: ClassVar[str] = "postview"
    task: ClassVar[str] = "postview"
    delay_parameter: ClassVar[str] = "tau_v"
    perceptions: ClassVar[tuple[str, ...]] = ("ft_edge", "ft_edge_rate")

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:  # noqa: D102
        return (
            ParameterSpec("K_p", 1.0, (0.01, 20.0), (-math.inf, math.inf), "-", "pilot gain"),
            ParameterSpec(
                "K_v",
                0.2,
                (0.0, 1.0),
                (-math.inf, math.inf),
                "s",
                "gain on the visible track's end slope (extrapolation K_v/K_p s)",
            ),
            ParameterSpec("tau_v", 0.0, (0.0, 0.5), (0.0, math.inf), "s", "pilot delay"),
        )

    def channels(self, values: Mapping[str, FloatArray]) -> tuple[Channel, ...]:  # noqa: D102
        num, den = _unity(values)
        edge = Branch("ft_edge", values["K_p"][..., None] * num, den)
        slope = Branch("ft_edge_rate", values["K_v"][..., None] * num, den)
        return (Channel((edge, slope), num, den),)


_MODELS: dict[str, type[PilotModel]] = {
    cls.name: cls
    for cls in (PrecisionModel, PreviewModel, SchiessRolandModel, GainDelayModel, PostviewModel)
}

#: The precision model with McRuer's lag equaliser (``PrecisionModel(lag=True)``) by
#: name: what a file, a setting or a command line names it by, since humans adopt that
#: lag on a pure gain and a lab's trial there is described and identified with it.
LAGGED_PRECISION = "precision-lag"

#: Names accepted by :func:`make_model`.
MODEL_NAMES: tuple[str, ...] = (*_MODELS, LAGGED_PRECISION)


def model_for_element(model: str, element: Any) -> str:
    """``model`` as humans fly ``element``: the precision model with McRuer's lag on a gain.

    Humans equalise a pure gain with a lag (McRuer & Jex 1967): there the loop needs an
    integrator's slope near crossover that the element does not give. The precision
    model without its lag cannot integrate, and its fit of a lagging operator ends on
    its bounds and says nothing about what the operator does. ``element`` is anything
    :func:`~manualcontrol.envs.elements.make_element` reads, or None (no rule applies).
    """
    if model == PrecisionModel.name and element is not None:
        if make_element(element).kind == "gain":
            return LAGGED_PRECISION
    return model


def make_model(spec: str | PilotModel, **options: bool) -> PilotModel:
    """Return a pilot model structure from its name (``options`` go to its constructor)."""
    if isinstance(spec, PilotModel):
        return spec
    name = check_choice("pilot model", spec, MODEL_NAMES)
    if name == LAGGED_PRECISION:
        if options.get("lag", True) is not True:
            raise ValueError(
                f"the {LAGGED_PRECISION!r} model has its lag; got lag={options['lag']!r}"
            )
        return PrecisionModel(**{**options, "lag": True})
    return _MODELS[name](**options)
