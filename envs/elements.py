"""Controlled elements (the vehicle dynamics a pilot controls) with schedulable parameters.

Every element is a proper transfer function whose parameters may be constants or
:mod:`~manualcontrol.envs.schedules` (time-varying dynamics, e.g. the break frequency
going from 3 to 1 rad/s in Popovici et al. 2017, Sec. IV-A-2). An element turns into
a (batched) state-space model in controllable canonical form for any array of times,
which is what the simulations, the environments and the estimators step.

Presets (:func:`make_element`) carry the papers' values: ``"SI"`` = 1.5/s and
``"DI"`` = 5/s^2 (thesis Sec. IV-B), ``"schiess-roland1975"`` = 10/s^2, and the
Popovici compensatory dynamics 4/(s(s + 3)), constant and time-varying.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._validation import check_choice, check_positive, reject_unknown
from manualcontrol.envs.dynamics import Discretization, StateSpace, discretize, tf_to_ccf
from manualcontrol.envs.schedules import Ramp, Schedule, Sigmoid, as_schedule

__all__ = [
    "ELEMENT_PRESETS",
    "ControlledElement",
    "DoubleIntegrator",
    "Gain",
    "Integrator",
    "IntegratorWithLag",
    "TransferFunctionElement",
    "UnstableFirstOrder",
    "critical_task",
    "make_element",
    "parse_element",
]

FloatArray = NDArray[np.float64]
ParameterValue = float | Schedule


@dataclass(frozen=True)
class ControlledElement:
    """Base class: a transfer function ``num(s)/den(s)`` with named, schedulable parameters.

    Subclasses declare their parameters as dataclass fields (floats or schedules) and
    implement :meth:`coefficients`; everything else (evaluation on time arrays,
    state-space form, discretisation, saving) is shared.
    """

    kind: ClassVar[str] = "element"
    #: Parameters that must stay strictly positive along the whole schedule.
    positive: ClassVar[tuple[str, ...]] = ()
    #: Parameters that must stay non-zero along the whole schedule.
    nonzero: ClassVar[tuple[str, ...]] = ()
    #: Parameters that must stay >= 0 along the whole schedule.
    nonnegative: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        for name in self.parameter_names:
            try:
                schedule = as_schedule(getattr(self, name))
            except (TypeError, ValueError) as error:
                raise type(error)(f"{type(self).__name__} parameter {name}: {error}") from None
            object.__setattr__(self, name, schedule)
        # Check the constant values now; schedules are checked where they are evaluated.
        for name in self.parameter_names:
            schedule = getattr(self, name)
            if schedule.is_constant:
                self._check_values(name, np.atleast_1d(schedule(0.0)))

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the element's parameters, in declaration order."""
        return tuple(f.name for f in fields(self))

    @property
    def is_time_varying(self) -> bool:
        """True when any parameter is a non-constant schedule."""
        return not all(getattr(self, name).is_constant for name in self.parameter_names)

    def _check_values(self, name: str, values: FloatArray) -> None:
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{type(self).__name__} parameter {name} must be finite, got {values}")
        if name in self.positive and np.any(values <= 0.0):
            raise ValueError(
                f"{type(self).__name__} parameter {name} must be > 0, "
                f"got minimum {float(values.min())!r}"
            )
        if name in self.nonnegative and np.any(values < 0.0):
            raise ValueError(
                f"{type(self).__name__} parameter {name} must be >= 0, "
                f"got minimum {float(values.min())!r}"
            )
        if name in self.nonzero and np.any(values == 0.0):
            raise ValueError(f"{type(self).__name__} parameter {name} must be non-zero, got 0.0")

    def parameters_at(self, t: ArrayLike) -> dict[str, FloatArray]:
        """Parameter values at the times ``t`` (s), each an array shaped like ``t``."""
        t = np.asarray(t, dtype=np.float64)
        values = {}
        for name in self.parameter_names:
            value = np.asarray(getattr(self, name)(t), dtype=np.float64)
            self._check_values(name, value)
            values[name] = np.broadcast_to(value, t.shape).copy()
        return values

    def coefficients(self, **values: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Numerator and denominator (descending powers) for the given parameter values."""
        raise NotImplementedError

    def transfer_function(self, t: ArrayLike = 0.0) -> tuple[FloatArray, FloatArray]:
        """Coefficients at time(s) ``t``: shapes ``(*t.shape, degree + 1)``."""
        return self.coefficients(**self.parameters_at(t))

    def frequency_response(self, omega: ArrayLike, t: float = 0.0) -> NDArray[np.complex128]:
        """``H_c(j omega)`` with the parameters at time ``t``, one value per ``omega``."""
        s = 1j * np.asarray(omega, dtype=np.float64)
        num, den = (np.asarray(c, dtype=np.float64).reshape(-1) for c in self.transfer_function(t))
        return np.polyval(num, s) / np.polyval(den, s)

    def state_space(self, t: ArrayLike = 0.0) -> StateSpace:
        """Controllable canonical form (thesis eq. 4.7) at time(s) ``t``, batched over ``t``."""
        return tf_to_ccf(*self.transfer_function(t))

    def discretize(self, dt: float, t: ArrayLike = 0.0) -> tuple[Discretization, StateSpace]:
        """Zero-order-hold discretisation at the times ``t`` and the continuous model."""
        model = self.state_space(t)
        return discretize(model.A, model.B, dt), model

    @property
    def order(self) -> int:
        """Number of states of the canonical realisation."""
        return self.transfer_function(0.0)[1].shape[-1] - 1

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description, inverse of :func:`make_element` on a dict."""
        return {
            "kind": self.kind,
            **{name: getattr(self, name).to_dict() for name in self.parameter_names},
        }

    def describe(self) -> str:
        """Short human-readable form for plots and logs."""
        parts = ", ".join(
            f"{name}={getattr(self, name).describe()}" for name in self.parameter_names
        )
        return f"{type(self).__name__}({parts})"


@dataclass(frozen=True)
class Gain(ControlledElement):
    """Pure gain ``K`` (position control; Boer & Kenyon's gap-postview task)."""

    kind: ClassVar[str] = "gain"
    nonzero: ClassVar[tuple[str, ...]] = ("K",)
    K: ParameterValue = 1.0

    def coefficients(self, K: FloatArray) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        return np.asarray(K)[..., None], np.ones((*np.shape(K), 1))


@dataclass(frozen=True)
class Integrator(ControlledElement):
    """Single integrator ``K/s`` (velocity control); thesis SI preset ``K = 1.5``."""

    kind: ClassVar[str] = "integrator"
    nonzero: ClassVar[tuple[str, ...]] = ("K",)
    K: ParameterValue = 1.5

    def coefficients(self, K: FloatArray) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        shape = np.shape(K)
        den = np.zeros((*shape, 2))
        den[..., 0] = 1.0
        return np.asarray(K)[..., None], den


@dataclass(frozen=True)
class DoubleIntegrator(ControlledElement):
    """Double integrator ``K/s^2`` (acceleration control); thesis DI preset ``K = 5``."""

    kind: ClassVar[str] = "double_integrator"
    nonzero: ClassVar[tuple[str, ...]] = ("K",)
    K: ParameterValue = 5.0

    def coefficients(self, K: FloatArray) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        shape = np.shape(K)
        den = np.zeros((*shape, 3))
        den[..., 0] = 1.0
        return np.asarray(K)[..., None], den


@dataclass(frozen=True)
class IntegratorWithLag(ControlledElement):
    """``K/(s (s + omega_b))``: integrator-like below, double-integrator-like above ``omega_b``.

    Popovici et al. (2017), Sec. IV-A, with ``omega_b`` going from 3 to 1 rad/s in
    the time-varying case. ``omega_b`` must stay > 0 (use :class:`DoubleIntegrator`
    for the limit).
    """

    kind: ClassVar[str] = "integrator_with_lag"
    nonzero: ClassVar[tuple[str, ...]] = ("K",)
    positive: ClassVar[tuple[str, ...]] = ("omega_b",)
    K: ParameterValue = 4.0
    omega_b: ParameterValue = 3.0

    def coefficients(self, K: FloatArray, omega_b: FloatArray) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        shape = np.broadcast_shapes(np.shape(K), np.shape(omega_b))
        den = np.zeros((*shape, 3))
        den[..., 0] = 1.0
        den[..., 1] = omega_b
        return np.broadcast_to(np.asarray(K)[..., None], (*shape, 1)).copy(), den


@dataclass(frozen=True)
class UnstableFirstOrder(ControlledElement):
    """``instability/(s - instability)``: Jex's critical tracking task dynamics.

    ``instability`` (lambda, rad/s, >= 0) is usually ramped up until the pilot loses
    control; the environments end the episode at a loss-of-control limit. At
    ``lambda = 0`` the element is ``0/s``: the output holds still whatever the stick
    (Boer & Kenyon's task starts there, Sec. VI-A).
    """

    kind: ClassVar[str] = "unstable_first_order"
    nonnegative: ClassVar[tuple[str, ...]] = ("instability",)
    instability: ParameterValue = 1.0

    def coefficients(self, instability: FloatArray) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        lam = np.asarray(instability)
        den = np.stack([np.ones_like(lam), -lam], axis=-1)
        return lam[..., None], den


@dataclass(frozen=True, init=False)
class TransferFunctionElement(ControlledElement):
    """Any proper transfer function; each coefficient may be a schedule.

    ``TransferFunctionElement(num=[4.0], den=[1.0, Sigmoid(3, 1, 40, 10), 0.0])``.
    The leading denominator coefficient must stay non-zero.
    """

    kind: ClassVar[str] = "transfer_function"
    num: tuple[Schedule, ...]
    den: tuple[Schedule, ...]

    def __init__(self, num: Any, den: Any) -> None:
        num_terms = tuple(as_schedule(c) for c in np.atleast_1d(np.asarray(num, dtype=object)))
        den_terms = tuple(as_schedule(c) for c in np.atleast_1d(np.asarray(den, dtype=object)))
        if len(den_terms) == 0 or len(num_terms) == 0:
            raise ValueError("num and den must each have at least one coefficient")
        if len(num_terms) > len(den_terms):
            raise ValueError(
                f"transfer function must be proper: num has {len(num_terms)} coefficients, "
                f"den has {len(den_terms)}"
            )
        object.__setattr__(self, "num", num_terms)
        object.__setattr__(self, "den", den_terms)
        if den_terms[0].is_constant and den_terms[0](0.0) == 0.0:
            raise ValueError("den must have a non-zero leading coefficient (descending powers)")

    @property
    def parameter_names(self) -> tuple[str, ...]:  # noqa: D102
        return tuple(f"num{i}" for i in range(len(self.num))) + tuple(
            f"den{i}" for i in range(len(self.den))
        )

    @property
    def is_time_varying(self) -> bool:  # noqa: D102
        return not all(c.is_constant for c in (*self.num, *self.den))

    def parameters_at(self, t: ArrayLike) -> dict[str, FloatArray]:  # noqa: D102
        t = np.asarray(t, dtype=np.float64)
        values = {}
        for name, schedule in zip(self.parameter_names, (*self.num, *self.den), strict=True):
            value = np.broadcast_to(np.asarray(schedule(t), dtype=np.float64), t.shape).copy()
            self._check_values(name, value)
            values[name] = value
        if np.any(values["den0"] == 0.0):
            raise ValueError("den0 (leading denominator coefficient) must stay non-zero")
        return values

    def coefficients(self, **values: FloatArray) -> tuple[FloatArray, FloatArray]:  # noqa: D102
        num = np.stack([values[f"num{i}"] for i in range(len(self.num))], axis=-1)
        den = np.stack([values[f"den{i}"] for i in range(len(self.den))], axis=-1)
        return num, den

    def to_dict(self) -> dict[str, Any]:  # noqa: D102
        return {
            "kind": self.kind,
            "num": [c.to_dict() for c in self.num],
            "den": [c.to_dict() for c in self.den],
        }

    def describe(self) -> str:  # noqa: D102
        num = ", ".join(c.describe() for c in self.num)
        den = ", ".join(c.describe() for c in self.den)
        return f"TransferFunctionElement(num=[{num}], den=[{den}])"


def critical_task(start: float = 1.0, rate: float = 0.05) -> UnstableFirstOrder:
    """Critical tracking task: ``instability`` rising linearly from ``start`` at ``t = 0``.

    ``start`` in rad/s (>= 0), ``rate`` in rad/s per s (> 0). The preset
    ``"critical-task"`` is ``critical_task(1.0, 0.05)``; Boer & Kenyon (1998, Sec. VI-A)
    started at 0 and rose at 0.11/s: ``critical_task(0.0, 0.11)``, or
    ``{"kind": "critical_task", "start": 0.0, "rate": 0.11}`` wherever an element is
    given as a dict (:func:`make_element`, suite files, environment keywords).
    """
    start = check_positive("start", start, allow_zero=True)
    rate = check_positive("rate", rate)
    # A ramp over a long horizon; the episode ends at loss of control long before.
    horizon = 3600.0
    return UnstableFirstOrder(Ramp(start, start + rate * horizon, 0.0, horizon))


_KINDS: dict[str, type[ControlledElement]] = {
    cls.kind: cls
    for cls in (
        Gain,
        Integrator,
        DoubleIntegrator,
        IntegratorWithLag,
        UnstableFirstOrder,
        TransferFunctionElement,
    )
}


def _presets() -> dict[str, ControlledElement]:
    return {
        "gain": Gain(1.0),
        "SI": Integrator(1.5),
        "DI": DoubleIntegrator(5.0),
        "schiess-roland1975": DoubleIntegrator(10.0),
        "popovici2017": IntegratorWithLag(4.0, 3.0),
        # Popovici Sec. IV-A-2: omega_b from 3 towards 1 rad/s starting around 40 s
        "popovici2017-tv": IntegratorWithLag(4.0, Sigmoid(3.0, 1.0, 45.0, 10.0)),
        "critical-task": critical_task(),
    }


#: ``kind`` of the dict form of :func:`critical_task` (lambda start and rate).
CRITICAL_TASK_KIND = "critical_task"

#: Names accepted by :func:`make_element`.
ELEMENT_PRESETS: tuple[str, ...] = tuple(_presets())


def make_element(spec: str | ControlledElement | Mapping[str, Any]) -> ControlledElement:
    """Return a controlled element from a name or written transfer function, or a dict.

    An element is returned as it is. Preset names: see :data:`ELEMENT_PRESETS`. Any
    other string is read by :func:`parse_element` (``"1/s"``, ``"1/(s(s+1))"``,
    ``"num=[1]; den=[1, 1, 0]"``), so every place that takes an element by name (suite
    files, env keywords, the command line) takes a lab's written transfer function
    too. Dicts are those of :meth:`ControlledElement.to_dict`, or ``{"kind":
    "critical_task", "start": ..., "rate": ...}`` for :func:`critical_task` with its
    two settings.

    A string that is neither raises ``ValueError`` listing the presets, then why it
    cannot be read as a transfer function and how to write one.
    """
    if isinstance(spec, ControlledElement):
        return spec
    if isinstance(spec, str):
        if spec in ELEMENT_PRESETS:
            return _presets()[spec]
        try:
            return parse_element(spec)
        except ValueError as error:
            listed = ", ".join(repr(name) for name in ELEMENT_PRESETS)
            # the presets are listed here already; an empty text has nothing to read
            reason = str(error).split("; allowed: ")[0] if spec.strip() else "it is empty"
            raise ValueError(
                f"controlled element must be one of {listed}, got {spec!r}; read as a "
                f"transfer function in s, {reason}; write one as '1/s', '2.5/s^2', "
                "'1/(s(s+1))', '(s+2)/(s^2+0.5s+4)' or 'num=[1]; den=[1, 1, 0]'"
            ) from None
    if isinstance(spec, Mapping):
        data = dict(spec)
        if data.get("kind") == CRITICAL_TASK_KIND:
            data.pop("kind")
            reject_unknown("critical_task", data, ("start", "rate"))
            return critical_task(**data)
        kind = check_choice(
            "controlled element kind", data.pop("kind", None), (*_KINDS, CRITICAL_TASK_KIND)
        )
        cls = _KINDS[kind]
        if cls is TransferFunctionElement:
            return TransferFunctionElement(
                [Schedule.from_dict(c) for c in data.get("num", [])],
                [Schedule.from_dict(c) for c in data.get("den", [])],
            )
        allowed = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise TypeError(
                f"{cls.__name__} got unknown parameter(s) {unknown}; allowed: {sorted(allowed)}"
            )
        return cls(**{name: Schedule.from_dict(value) for name, value in data.items()})
    raise TypeError(
        f"controlled element must be a preset name, a ControlledElement or a dict, got {spec!r}"
    )


# ------------------------------------------------------------- written transfer functions


class _Rational:
    """``num(s)/den(s)`` with exact polynomial arithmetic, for :func:`parse_element`."""

    def __init__(self, num: Any, den: Any = (1.0,)) -> None:
        self.num = np.trim_zeros(np.atleast_1d(np.asarray(num, dtype=np.float64)), "f")
        self.den = np.trim_zeros(np.atleast_1d(np.asarray(den, dtype=np.float64)), "f")
        if self.num.size == 0:
            self.num = np.zeros(1)

    def __add__(self, other: _Rational) -> _Rational:
        return _Rational(
            np.polyadd(np.polymul(self.num, other.den), np.polymul(other.num, self.den)),
            np.polymul(self.den, other.den),
        )

    def __neg__(self) -> _Rational:
        return _Rational(-self.num, self.den)

    def __mul__(self, other: _Rational) -> _Rational:
        return _Rational(np.polymul(self.num, other.num), np.polymul(self.den, other.den))

    def __truediv__(self, other: _Rational) -> _Rational:
        if not np.any(other.num):
            raise ZeroDivisionError("division by zero")
        return _Rational(np.polymul(self.num, other.den), np.polymul(self.den, other.num))


_TOKEN = re.compile(r"\s*(?:(\d+\.?\d*(?:[eE][-+]?\d+)?|\.\d+(?:[eE][-+]?\d+)?)|(s)|([-+*/^()]))")


class _ExpressionParser:
    """Recursive descent over ``+ - * / ^ ( )``, numbers and ``s``.

    ``2s`` and ``s(s+1)`` multiply implicitly; ``^`` takes a non-negative integer exponent.
    """

    def __init__(self, text: str) -> None:
        self.tokens: list[tuple[str, str]] = []
        position = 0
        stripped = text.rstrip()
        while position < len(stripped):
            match = _TOKEN.match(stripped, position)
            if match is None:
                bad = stripped[position:].lstrip()[:1]
                raise ValueError(f"unexpected character {bad!r}")
            number, variable, operator = match.groups()
            if number is not None:
                self.tokens.append(("number", number))
            elif variable is not None:
                self.tokens.append(("s", variable))
            else:
                self.tokens.append(("op", operator))
            position = match.end()
        self.index = 0

    def peek(self) -> tuple[str, str] | None:
        return self.tokens[self.index] if self.index < len(self.tokens) else None

    def take(self) -> tuple[str, str]:
        token = self.peek()
        if token is None:
            raise ValueError("the expression ends too early")
        self.index += 1
        return token

    def parse(self) -> _Rational:
        value = self.sum()
        if self.peek() is not None:
            raise ValueError(f"unexpected {self.peek()[1]!r}")  # type: ignore[index]
        return value

    def sum(self) -> _Rational:
        value = self.product()
        while self.peek() in (("op", "+"), ("op", "-")):
            sign = self.take()[1]
            term = self.product()
            value = value + (term if sign == "+" else -term)
        return value

    def product(self) -> _Rational:
        value = self.signed()
        while True:
            token = self.peek()
            if token in (("op", "*"), ("op", "/")):
                self.take()
                factor = self.signed()
                value = value * factor if token[1] == "*" else value / factor  # type: ignore[index]
            elif token is not None and (token[0] in ("number", "s") or token == ("op", "(")):
                value = value * self.power()  # implicit multiplication: 2s, s(s+1)
            else:
                return value

    def signed(self) -> _Rational:
        if self.peek() in (("op", "-"), ("op", "+")):
            sign = self.take()[1]
            value = self.signed()
            return -value if sign == "-" else value
        return self.power()

    def power(self) -> _Rational:
        base = self.atom()
        if self.peek() == ("op", "^"):
            self.take()
            kind, text = self.take()
            if kind != "number" or not text.isdigit():
                raise ValueError(f"an exponent must be a non-negative integer, got {text!r}")
            result = _Rational(1.0)
            for _ in range(int(text)):
                result = result * base
            return result
        return base

    def atom(self) -> _Rational:
        kind, text = self.take()
        if kind == "number":
            return _Rational(float(text))
        if kind == "s":
            return _Rational([1.0, 0.0])
        if text == "(":
            value = self.sum()
            if self.take() != ("op", ")"):
                raise ValueError("a '(' is not closed")
            return value
        raise ValueError(f"unexpected {text!r}")


def _cancel_common_s(num: FloatArray, den: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Strip factors of ``s`` shared by numerator and denominator (``s/s^2`` is ``1/s``)."""
    while num.size > 1 and den.size > 1 and num[-1] == 0.0 and den[-1] == 0.0:
        num, den = num[:-1], den[:-1]
    return num, den


def parse_element(text: str) -> ControlledElement:
    """A constant controlled element written as a preset name or a transfer function in ``s``.

    Accepted: the presets of :data:`ELEMENT_PRESETS`; expressions such as ``"1"``,
    ``"1/s"``, ``"2.5/s^2"``, ``"1/(s(s+1))"``, ``"4/(s^2 + 3s)"`` or
    ``"(s + 2)/(s^2 + 0.5 s + 4)"`` (numbers, ``s``, ``+ - * / ^`` and brackets;
    ``2s`` and ``s(s+1)`` multiply); and coefficient lists ``"num=[1]; den=[1, 1, 0]"``
    (descending powers, as :class:`TransferFunctionElement`). The written forms become
    the named element where one fits (``K`` :class:`Gain`, ``K/s`` :class:`Integrator`,
    ``K/s^2`` :class:`DoubleIntegrator`, ``K/(s(s+a))`` :class:`IntegratorWithLag`), so
    the element's type, which the estimators and envs read, does not depend on how it
    was written; anything else is a :class:`TransferFunctionElement`.

    Raises ``ValueError`` naming the text, what is wrong and what is accepted.
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"element must be a preset name or a transfer function, got {text!r}")
    spec = text.strip()
    if spec in ELEMENT_PRESETS:
        return make_element(spec)
    accepted = (
        f"a preset ({', '.join(ELEMENT_PRESETS)}), a transfer function in s such as "
        "'1/s', '2.5/s^2', '1/(s(s+1))', '(s+2)/(s^2+0.5s+4)', or 'num=[1]; den=[1, 1, 0]'"
    )
    try:
        if spec.startswith("num"):
            parts = dict(part.split("=", 1) for part in spec.split(";"))
            parts = {key.strip(): value for key, value in parts.items()}
            if set(parts) != {"num", "den"}:
                raise ValueError("give exactly num=[...] and den=[...]")
            lists = [json.loads(parts[key]) for key in ("num", "den")]
            num, den = (np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in lists)
        else:
            value = _ExpressionParser(spec).parse()
            num, den = value.num, value.den
    except (ValueError, ZeroDivisionError, TypeError, json.JSONDecodeError) as error:
        raise ValueError(
            f"element {spec!r} cannot be read ({error}); allowed: {accepted}"
        ) from None
    num = np.trim_zeros(num, "f")
    den = np.trim_zeros(den, "f")
    if num.size == 0 or den.size == 0 or not (np.isfinite(num).all() and np.isfinite(den).all()):
        raise ValueError(f"element {spec!r} is zero or not finite; allowed: {accepted}")
    num, den = _cancel_common_s(num, den)
    num, den = num / den[0], den / den[0]
    if num.size > den.size:
        raise ValueError(
            f"element {spec!r} is not proper (numerator degree {num.size - 1} > denominator "
            f"degree {den.size - 1}): a controlled element cannot differentiate its input"
        )
    if num.size == 1:
        gain = float(num[0])
        if den.size == 1:
            return Gain(gain)
        if den.size == 2 and den[1] == 0.0:
            return Integrator(gain)
        if den.size == 3 and den[2] == 0.0:
            return DoubleIntegrator(gain) if den[1] == 0.0 else _with_lag(gain, float(den[1]))
    return TransferFunctionElement(num, den)


def _with_lag(gain: float, omega_b: float) -> ControlledElement:
    """``K/(s(s + a))`` as :class:`IntegratorWithLag` where ``a > 0`` (its allowed range)."""
    if omega_b > 0.0:
        return IntegratorWithLag(gain, omega_b)
    return TransferFunctionElement([gain], [1.0, omega_b, 0.0])
