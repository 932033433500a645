"""The cybernetic driver model of Zhao et al. (2019) eq. 2, after Saleh et al. (2011).

Symbols are the paper's, kept inside the driver model's own module.
The driver reads two visual angles and feels the steering wheel (Zhao Fig. 1, Tables 1-2):

====================  ============================================  =================
input                 meaning                                       unit
====================  ============================================  =================
``theta_far``         visual anticipation angle (far point)         rad
``theta_near``        visual compensation angle (near point)        rad
``delta_d``           steering-wheel angle                          rad
``Gamma_s``           self-aligning torque at the wheel             N m
====================  ============================================  =================

and produces the torque ``Gamma_d`` on the wheel (N m) through its intended wheel angle
``delta_sw`` (rad)::

    delta_sw = e^{-tau_p s} [ K_p theta_far + (K_c / v_x) (1 + T_L s)/(1 + T_I s) theta_near ]
    Gamma_d  = [ (K_r v_x + K_t) delta_sw - K_t delta_d - Gamma_s ] / (1 + T_N s)

(visual anticipation and compensation, processing delay, then the neuromuscular system:
an internal model ``K_r v_x`` of the steering column's stiffness, the stretch reflex
``K_t`` on the difference between intended and actual wheel angle, and compensation of
the felt self-aligning torque). Parameters (Table 2, nominal): ``K_p`` 3.4, ``K_c`` 15,
``T_I`` 1 s, ``T_L`` 3 s, ``tau_p`` 0.04 s, ``K_r`` 1, ``K_t`` 12, ``T_N`` 0.1 s; ``v_x``
is the car's speed (18 m/s in Table 2), known, not a parameter.

State space (eq. 2, the delay as the first-order Padé approximant of eq. 1), states
``x = [x_1, x_2, Gamma_d]``: ``x_1`` the lag ``1/(1 + T_I s)`` of ``theta_near``,
``x_2`` the Padé state, ``delta_sw = 2 x_2 - w`` with ``w`` the undelayed visual signal.
The paper prints two entries of the third row wrongly::

    printed   A(3,1) = -(K_r v_x + K_t K_c)/T_N (1/v_x)(1 - T_L/T_I)
              B(3,2) = -(K_r v_x + K_t K_c T_L)/(v_x T_I T_N)
    correct   A(3,1) = -(K_r v_x + K_t) K_c (1 - T_L/T_I)/(v_x T_N)
              B(3,2) = -(K_r v_x + K_t) K_c T_L/(v_x T_I T_N)

Derivation: ``T_N Gamma_d' = -Gamma_d + G delta_sw - K_t delta_d - Gamma_s`` with
``G = K_r v_x + K_t`` and ``delta_sw = 2 x_2 - K_p theta_far - (K_c/v_x)[(T_L/T_I)
theta_near + (1 - T_L/T_I) x_1]``; the ``x_1`` and ``theta_near`` coefficients are ``-G
K_c (1 - T_L/T_I)/(v_x T_N)`` and ``-G K_c T_L/(v_x T_I T_N)``: the printed forms
misplace the parenthesis (``K_t K_c`` instead of ``(K_r v_x + K_t) K_c``). With the
nominal values the printed form gives a DC gain ``Gamma_d/theta_near`` of 41 instead
of ``G K_c/v_x = 25`` (tests/pilots/test_driver.py derives both from the transfer
functions above). ``_eq2_matrices`` is the one definition of eq. 2 (corrected):
:func:`~manualcontrol.pilots._driver_kernels.driver_matrices` is it compiled, which the
estimators' kernels and the simulation call, and the structure's Python API
(:meth:`CyberneticDriverModel.state_space`) runs it without numba.

Simulation (:class:`Driver`, :mod:`manualcontrol.pilots.driving`) uses the exact delay
(``delay_order=None``: a delay line, the same conventions as the tracking pilots: the
delayed signal's part held over each sample, ``K_p theta_far + (K_c/v_x)(T_L/T_I)
theta_near``, delayed as a staircase, its smooth part ``(K_c/v_x)(1 - T_L/T_I) x_1``
read bicubically and taken linear over the sample; the two lags are integrated exactly
over the sample) or eq. 2 itself (``delay_order=1``, exact zero-order hold). Remnant:
any :class:`~manualcontrol.pilots.remnant.Remnant` injected at ``"output"`` (added to
the wheel torque, or to the wheel angle with angle steering) or ``"input"`` (added to
the visual signal ``w`` before the delay).

The driver in an episode (:class:`DriverController`, behind :meth:`Driver.reset` and
:meth:`Driver.act`) and :func:`~manualcontrol.pilots.driving.simulate_driving` run one
compiled closed loop, kept here (:func:`drive_episode`): the controller calibrates its
remnant on it, so both give the same gain.

The compiled steps and eq. 2 live in :mod:`~manualcontrol.pilots._driver_kernels`,
exported here by name on first use: this module holds the parameters, the records and
the structure the Zhao filters read, and an identification through their C port
imports it without importing numba.
"""

from __future__ import annotations

import math
from collections import namedtuple
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._lazy import LazyKernel, kernels_on_first_use
from manualcontrol.envs._validation import check_choice, check_positive
from manualcontrol.envs.driving import LaneKeeping
from manualcontrol.envs.dynamics import StateSpace, discretize, pade, poly_multiply
from manualcontrol.envs.schedules import Schedule, as_schedule
from manualcontrol.pilots._random import as_generator
from manualcontrol.pilots.models import ParameterSpec
from manualcontrol.pilots.remnant import Remnant, make_remnant
from manualcontrol.pilots.simulation import gain_for_ratio
from manualcontrol.pilots.spec import check_parameter_values

if TYPE_CHECKING:
    from manualcontrol.pilots._driver_kernels import driver_matrices, driver_sample

__all__ = [
    "DRIVER_INPUTS",
    "DRIVER_OUTPUTS",
    "DRIVER_PARAMETERS",
    "INJECT_CODES",
    "CyberneticDriverModel",
    "Driver",
    "DriverController",
    "calibrated_gain",
    "drive_episode",
    "driver_matrices",
    "driver_record",
    "driver_sample",
    "printed_driver_matrices",
    "remnant_noise",
]

FloatArray = NDArray[np.float64]

#: The model's inputs ``u`` and outputs ``y`` (Zhao eq. 2).
DRIVER_INPUTS: tuple[str, ...] = ("theta_far", "theta_near", "delta_d", "Gamma_s")
DRIVER_OUTPUTS: tuple[str, ...] = ("Gamma_d", "delta_sw")


def _spec(name, nominal, human, valid, unit, description, positive=False):
    return ParameterSpec(name, nominal, human, valid, unit, description, positive)


#: Zhao Table 2. The paper gives no human ranges: the bounds here (a third to three
#: times the nominal value) only flag implausible values.
DRIVER_PARAMETERS: tuple[ParameterSpec, ...] = (
    _spec("K_p", 3.4, (1.1, 10.2), (-math.inf, math.inf), "-", "visual anticipation gain"),
    _spec("K_c", 15.0, (5.0, 45.0), (-math.inf, math.inf), "-", "visual compensation gain"),
    _spec("T_I", 1.0, (0.33, 3.0), (0.0, math.inf), "s", "compensation lag time constant", True),
    _spec("T_L", 3.0, (1.0, 9.0), (0.0, math.inf), "s", "compensation lead time constant"),
    _spec("tau_p", 0.04, (0.013, 0.12), (0.0, math.inf), "s", "processing delay"),
    _spec("K_r", 1.0, (0.33, 3.0), (-math.inf, math.inf), "-", "internal gain of column stiffness"),
    _spec("K_t", 12.0, (4.0, 36.0), (-math.inf, math.inf), "-", "gain of stretch reflex"),
    _spec("T_N", 0.1, (0.033, 0.3), (0.0, math.inf), "s", "neuromuscular time constant", True),
)
_NAMES = tuple(spec.name for spec in DRIVER_PARAMETERS)
_INJECTIONS = ("output", "input")


# numba kernels read this module's constants
# (and compile its eq. 2, _eq2_matrices: pilots/_driver_kernels.py's driver_matrices)


def _eq2_matrices(p, v_x, A, B, C, D):
    """Zhao eq. 2 (corrected, module docstring) into ``A`` (3, 3), ``B`` (3, 4), ``C``, ``D``.

    ``p`` holds ``K_p, K_c, T_I, T_L, tau_p, K_r, K_t, T_N``; ``v_x`` the speed (m/s).
    ``B`` and ``D`` may have a fifth column: it receives the input that adds to the
    visual signal ``w`` before the delay (remnant at ``"input"``).

    The one definition of eq. 2: :func:`driver_matrices` is this function compiled by
    numba (the estimators' kernels and the simulation call it), and
    :meth:`CyberneticDriverModel.state_space` runs it as Python, so that the Zhao
    filters' tuning, on a path that runs in C, never imports numba. Both give the same
    bytes: the same IEEE-754 double operations on the same operands in the same order
    (numba compiles without fastmath, so LLVM neither reorders them nor fuses a multiply
    and an add; the parameters are read as floats, so a zero divides as in numba);
    tests/pilots/test_driver.py compares them byte for byte.
    """
    K_p, K_c, T_I, T_L = float(p[0]), float(p[1]), float(p[2]), float(p[3])
    tau_p, K_r, K_t, T_N = float(p[4]), float(p[5]), float(p[6]), float(p[7])
    G = K_r * v_x + K_t
    lead = T_L / T_I
    c = K_c / v_x
    pade_rate = 2.0 / tau_p
    for i in range(3):
        for j in range(3):
            A[i, j] = 0.0
        for j in range(B.shape[1]):
            B[i, j] = 0.0
    for i in range(2):
        for j in range(3):
            C[i, j] = 0.0
        for j in range(D.shape[1]):
            D[i, j] = 0.0
    A[0, 0] = -1.0 / T_I
    A[1, 0] = c * pade_rate * (1.0 - lead)
    A[1, 1] = -pade_rate
    A[2, 0] = -G * c * (1.0 - lead) / T_N
    A[2, 1] = 2.0 * G / T_N
    A[2, 2] = -1.0 / T_N
    B[0, 1] = 1.0 / T_I
    B[1, 0] = K_p * pade_rate
    B[1, 1] = c * pade_rate * lead
    B[2, 0] = -K_p * G / T_N
    B[2, 1] = -G * c * lead / T_N
    B[2, 2] = -K_t / T_N
    B[2, 3] = -1.0 / T_N
    C[0, 2] = 1.0
    C[1, 0] = -c * (1.0 - lead)
    C[1, 1] = 2.0
    D[1, 0] = -K_p
    D[1, 1] = -c * lead
    if B.shape[1] > 4:
        B[1, 4] = pade_rate
        B[2, 4] = -G / T_N
        D[1, 4] = -1.0


def printed_driver_matrices(values: Mapping[str, float], v_x: float) -> StateSpace:
    """Eq. 2 exactly as printed (two entries wrong; kept to show the difference)."""
    model = CyberneticDriverModel()
    system = model.state_space(values, v_x)
    K_c, T_I, T_L = (float(values.get(n, model.spec(n).nominal)) for n in ("K_c", "T_I", "T_L"))
    K_r, K_t, T_N = (float(values.get(n, model.spec(n).nominal)) for n in ("K_r", "K_t", "T_N"))
    A = system.A.copy()
    B = system.B.copy()
    A[2, 0] = -(K_r * v_x + K_t * K_c) / T_N / v_x * (1.0 - T_L / T_I)
    B[2, 1] = -(K_r * v_x + K_t * K_c * T_L) / (v_x * T_I * T_N)
    return StateSpace(A, B, system.C, system.D)


class CyberneticDriverModel:
    """The driver model's structure: parameters, eq. 2, transfer functions (module doc)."""

    name: ClassVar[str] = "cybernetic-driver"
    inputs: ClassVar[tuple[str, ...]] = DRIVER_INPUTS
    outputs: ClassVar[tuple[str, ...]] = DRIVER_OUTPUTS
    delay_parameter: ClassVar[str] = "tau_p"

    @property
    def parameters(self) -> tuple[ParameterSpec, ...]:
        """Zhao Table 2, in the order of the paper's parameter vector ``theta``."""
        return DRIVER_PARAMETERS

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """``K_p, K_c, T_I, T_L, tau_p, K_r, K_t, T_N``."""
        return _NAMES

    def spec(self, name: str) -> ParameterSpec:
        """The :class:`~manualcontrol.pilots.models.ParameterSpec` called ``name``."""
        check_choice("cybernetic driver parameter", name, _NAMES)
        return DRIVER_PARAMETERS[_NAMES.index(name)]

    def nominal(self) -> dict[str, float]:
        """Table 2's values."""
        return {spec.name: spec.nominal for spec in DRIVER_PARAMETERS}

    def vector(self, values: Mapping[str, float]) -> FloatArray:
        """The parameter vector ``theta`` (model order); missing names take nominal values."""
        unknown = sorted(set(values) - set(_NAMES))
        if unknown:
            raise ValueError(
                f"the cybernetic driver model has no parameter(s) {unknown}; "
                f"its parameters are {', '.join(_NAMES)}"
            )
        return np.array([float(values.get(s.name, s.nominal)) for s in DRIVER_PARAMETERS])

    def state_space(self, values: Mapping[str, float], v_x: float) -> StateSpace:
        """Eq. 2 (Padé-1 delay, corrected entries) at these parameter values and speed."""
        v_x = check_positive("v_x", v_x)
        p = self.vector(values)
        if p[4] <= 0.0:
            raise ValueError(f"tau_p must be > 0 for the Padé form, got {p[4]!r}")
        A, B, C, D = np.zeros((3, 3)), np.zeros((3, 4)), np.zeros((2, 3)), np.zeros((2, 4))
        _eq2_matrices(p, v_x, A, B, C, D)
        return StateSpace(A, B, C, D)

    def transfer_function(
        self,
        values: Mapping[str, float],
        v_x: float,
        output: str,
        input: str,
        delay_order: int = 1,
    ) -> tuple[FloatArray, FloatArray]:
        """``output/input`` from the block diagram (module docstring), Padé delay.

        Built from the blocks, independently of :func:`driver_matrices`.
        """
        check_choice("output", output, DRIVER_OUTPUTS)
        check_choice("input", input, DRIVER_INPUTS)
        p = dict(zip(_NAMES, self.vector(values), strict=True))
        v_x = check_positive("v_x", v_x)
        delay_num, delay_den = pade(p["tau_p"], delay_order)
        G = p["K_r"] * v_x + p["K_t"]
        nms = (np.array([1.0]), np.array([p["T_N"], 1.0]))
        if input == "theta_far":
            num, den = p["K_p"] * delay_num, delay_den
        elif input == "theta_near":
            num = poly_multiply(p["K_c"] / v_x * np.array([p["T_L"], 1.0]), delay_num)
            den = poly_multiply(np.array([p["T_I"], 1.0]), delay_den)
        else:
            if output == "delta_sw":
                return np.array([0.0]), np.array([1.0])
            gain = -p["K_t"] if input == "delta_d" else -1.0
            return gain * nms[0], nms[1]
        if output == "Gamma_d":
            num, den = G * poly_multiply(num, nms[0]), poly_multiply(den, nms[1])
        return num, den

    def frequency_response(
        self,
        values: Mapping[str, float],
        v_x: float,
        omega: ArrayLike,
        output: str,
        input: str,
    ) -> NDArray[np.complex128]:
        """``output/input`` at ``omega`` (rad/s) with the delay exact."""
        omega = np.asarray(omega, dtype=np.float64)
        s = 1j * omega
        p = dict(zip(_NAMES, self.vector(values), strict=True))
        tau = p["tau_p"]
        rational = self.transfer_function(values, v_x, output, input, delay_order=0)
        # order 0 is the unit "delay": put the exact one in where the model has it
        response = np.polyval(rational[0], s) / np.polyval(rational[1], s)
        if input in ("theta_far", "theta_near"):
            response = response * np.exp(-tau * s)
        return response

    def __repr__(self) -> str:
        return "CyberneticDriverModel()"


# ------------------------------------------------------------------ the synthetic driver


@dataclass(frozen=True)
class Driver:
    """A synthetic driver: parameter values or schedules, remnant and delay mode.

    Parameters
    ----------
    parameters
        Values (floats) or :mod:`~manualcontrol.envs.schedules` for any of ``K_p, K_c,
        T_I, T_L, tau_p, K_r, K_t, T_N``; the others take Table 2's values.
    remnant
        A :class:`~manualcontrol.pilots.remnant.Remnant` (or its dict) injected at
        ``"output"`` or ``"input"`` (module docstring), or None.
    delay_order
        None (exact delay, default) or 1 (eq. 2's Padé form).

    Values outside a parameter's valid range raise ``ValueError``; outside the flagged
    range they warn with :class:`~manualcontrol.pilots.pilot.HumanLimitWarning`.
    ``reset(seed, env=env)`` and ``act(observation)`` drive a
    :class:`~manualcontrol.envs.driving.LaneKeeping` environment exactly as
    :func:`~manualcontrol.pilots.driving.simulate_driving` does.
    """

    parameters: Mapping[str, float | Schedule] = field(default_factory=dict)
    remnant: Remnant | str | Mapping[str, Any] | None = None
    delay_order: int | None = None
    _controller: Any = field(default=None, init=False, repr=False, compare=False)

    model: ClassVar[CyberneticDriverModel] = CyberneticDriverModel()

    def __post_init__(self) -> None:
        if not isinstance(self.parameters, Mapping):
            raise TypeError(f"parameters must be a mapping of names, got {self.parameters!r}")
        unknown = sorted(set(self.parameters) - set(_NAMES))
        if unknown:
            raise ValueError(
                f"the cybernetic driver has no parameter(s) {', '.join(map(repr, unknown))}; "
                f"its parameters are {', '.join(_NAMES)}"
            )
        schedules: dict[str, Schedule] = {}
        for spec in DRIVER_PARAMETERS:
            value = self.parameters.get(spec.name, spec.nominal)
            if isinstance(value, Mapping):
                value = Schedule.from_dict(value)
            try:
                schedules[spec.name] = as_schedule(value)
            except (TypeError, ValueError) as error:
                raise type(error)(f"driver parameter {spec.name}: {error}") from None
        object.__setattr__(self, "parameters", MappingProxyType(schedules))
        remnant = make_remnant(self.remnant)
        if remnant is not None:
            check_choice("driver remnant injection", remnant.injection, _INJECTIONS)
        object.__setattr__(self, "remnant", remnant)
        if self.delay_order not in (None, 1) or isinstance(self.delay_order, bool):
            raise ValueError(
                "delay_order must be None (exact delay) or 1 (Zhao eq. 1), "
                f"got {self.delay_order!r}"
            )
        for name, schedule in schedules.items():
            if schedule.is_constant:
                self._check(name, np.atleast_1d(schedule(0.0)))

    def _check(self, name: str, values: FloatArray) -> None:
        spec = self.model.spec(name)
        # a Padé-1 delay of zero has a vanishing leading coefficient
        positive = spec.positive or (name == "tau_p" and self.delay_order == 1)
        check_parameter_values(
            "driver", name, spec, values, positive=positive, flagged="flagged range"
        )

    @property
    def is_time_varying(self) -> bool:
        """True when any parameter is a non-constant schedule."""
        return not all(schedule.is_constant for schedule in self.parameters.values())

    def parameter_traces(self, t: ArrayLike) -> dict[str, FloatArray]:
        """Every parameter at the times ``t`` (s), checked against its ranges."""
        t = np.asarray(t, dtype=np.float64)
        traces = {}
        for name, schedule in self.parameters.items():
            values = np.broadcast_to(np.asarray(schedule(t), dtype=np.float64), t.shape).copy()
            self._check(name, values)
            traces[name] = values
        return traces

    def reset(self, seed: int | np.random.Generator | None = None, *, env: Any) -> None:
        """Start driving ``env``'s current episode (call after ``env.reset()``).

        ``seed`` drives the remnant exactly as in
        :func:`~manualcontrol.pilots.driving.simulate_driving`.
        """
        object.__setattr__(self, "_controller", DriverController(self, env, seed))

    def act(self, observation: ArrayLike) -> FloatArray:
        """The driver's action (torque or wheel angle) for an observation, shape ``(1,)``."""
        if self._controller is None:
            raise RuntimeError("call driver.reset(seed, env=env) after env.reset() before act()")
        return self._controller.act(observation)

    def with_parameters(self, **values: float | Schedule) -> Driver:
        """Copy with some parameters replaced."""
        return Driver({**self.parameters, **values}, self.remnant, self.delay_order)

    def with_remnant(self, remnant: Remnant | None) -> Driver:
        """Copy with another remnant."""
        return Driver(dict(self.parameters), remnant, self.delay_order)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description."""
        return {
            "model": self.model.name,
            "parameters": {name: schedule.to_dict() for name, schedule in self.parameters.items()},
            "remnant": None if self.remnant is None else self.remnant.to_dict(),
            "delay_order": self.delay_order,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Driver:
        """Inverse of :meth:`to_dict` (``model`` may be omitted)."""
        data = dict(data)
        model = data.pop("model", cls.model.name)
        if model != cls.model.name:
            raise ValueError(f"driver model must be {cls.model.name!r}, got {model!r}")
        unknown = sorted(set(data) - {"parameters", "remnant", "delay_order"})
        if unknown:
            raise TypeError(
                f"driver got unknown key(s) {unknown}; allowed: delay_order, model, "
                "parameters, remnant"
            )
        parameters = {
            name: Schedule.from_dict(value)
            for name, value in dict(data.get("parameters") or {}).items()
        }
        return cls(parameters, make_remnant(data.get("remnant")), data.get("delay_order"))


# -------------------------------------------------------------------- compiled steps

#: Remnant injection codes of the compiled steps.
INJECT_NONE, INJECT_OUTPUT, INJECT_INPUT = 0, 1, 2

#: Where the compiled steps and eq. 2 live: imported where numba runs them, never by an
#: identification through the Zhao filters' C port.
_KERNEL_MODULE = "manualcontrol.pilots._driver_kernels"
#: The numba kernels exported here, imported from their module on first use.
_KERNELS = (
    "driver_matrices",
    "exact_delay_step",
    "pade_step",
    "driver_sample",
    "driver_action",
    "drive",
)
__getattr__ = kernels_on_first_use(globals(), _KERNEL_MODULE, _KERNELS)


# ---------------------------------------------------------- the driver in an episode

#: The car of one episode: ``packed``/``far_gain`` of the environment's model, the
#: curvature samples, the action bound, 1.0 for angle steering, and the car state (2n,).
CarRecord = namedtuple(
    "CarRecord", ["packed", "far_gain", "kappa", "kappa_far", "bound", "angle", "state"]
)
#: The driver of one episode: parameters per sample ``p`` (n + 1, 8), speed, dt, remnant
#: ``noise`` (n,) and its injection code, state (3,), delay-line histories and their
#: padding, the Padé matrices per distinct parameter set and the set of each sample
#: (empty with the exact delay), scratch and the last output (Gamma_d, delta_sw).
DriverRecord = namedtuple(
    "DriverRecord",
    [
        "p",
        "v_x",
        "dt",
        "noise",
        "inject",
        "state",
        "smooth",
        "held",
        "pad",
        "pade",
        "phi",
        "gamma",
        "C",
        "D",
        "index",
        "work",
        "out",
    ],
)
LoopOutput = namedtuple("LoopOutput", ["perceived", "action", "Gamma_d", "delta_sw"])

#: The compiled steps' code of each remnant injection point (None: no remnant).
INJECT_CODES = {None: INJECT_NONE, "output": INJECT_OUTPUT, "input": INJECT_INPUT}


def remnant_noise(remnant: Remnant, white: FloatArray, dt: float) -> FloatArray:
    """The remnant filter's shape driven by held white noise (exact zero-order hold)."""
    import scipy.signal  # here: importing it costs 1.3 s, which every suite listing paid

    num, den = remnant.shape()
    numd, dend, _ = scipy.signal.cont2discrete((num, den), dt, method="zoh")
    return scipy.signal.lfilter(np.ravel(numd), dend, white)


def driver_record(
    driver: Driver,
    traces: Mapping[str, FloatArray],
    v_x: float,
    dt: float,
    noise: FloatArray,
    inject: int,
) -> Any:
    """The :data:`DriverRecord` the compiled steps read: the driver's traces at speed ``v_x``.

    ``traces`` hold every parameter at every sample and one more (the delay's next
    value), ``noise`` the remnant as injected, ``inject`` its :data:`INJECT_CODES` code;
    with ``delay_order=1`` eq. 2 is discretised once per distinct parameter set.
    """
    names = driver.model.parameter_names
    p = np.ascontiguousarray(np.column_stack([traces[name] for name in names]))
    n = noise.shape[0]
    pade = driver.delay_order == 1
    if pade:
        from manualcontrol.pilots._driver_kernels import driver_matrices

        unique, index = np.unique(p[:n], axis=0, return_inverse=True)
        A = np.zeros((len(unique), 3, 3))
        B = np.zeros((len(unique), 3, 5))
        C = np.zeros((len(unique), 2, 3))
        D = np.zeros((len(unique), 2, 5))
        for i, row in enumerate(unique):
            driver_matrices(row, v_x, A[i], B[i], C[i], D[i])
        exact = discretize(A, B, dt)
        phi, gamma = exact.phi, exact.gamma
        index = np.asarray(index, dtype=np.int64).ravel()
        pad = 0
    else:
        phi = gamma = np.zeros((0, 3, 3))
        C = D = np.zeros((0, 2, 3))
        index = np.zeros(0, dtype=np.int64)
        pad = int(np.ceil(p[:, 4].max() / dt)) + 4
    return DriverRecord(
        p=p,
        v_x=float(v_x),
        dt=float(dt),
        noise=np.ascontiguousarray(noise, dtype=np.float64),
        inject=inject,
        state=np.zeros(3),
        smooth=np.zeros(pad + n + 1),
        held=np.zeros(pad + n + 1),
        pad=pad,
        pade=pade,
        phi=np.ascontiguousarray(phi),
        gamma=np.ascontiguousarray(gamma),
        C=np.ascontiguousarray(C),
        D=np.ascontiguousarray(D),
        index=index,
        work=np.zeros(8),
        out=np.zeros(2),
    )


def _car_record(env: LaneKeeping, kappa: FloatArray, kappa_far: FloatArray) -> Any:
    model = env.model
    return CarRecord(
        packed=model.packed,
        far_gain=model.far_gain,
        kappa=np.ascontiguousarray(kappa),
        kappa_far=np.ascontiguousarray(kappa_far),
        bound=float(env.action_bound),
        angle=1.0 if env.steering == "angle" else 0.0,
        state=np.zeros(2 * model.phi.shape[0]),
    )


def drive_episode(env, driver, traces, kappa, kappa_far, noise, inject) -> Any:
    """The closed loop over ``env``'s episode (curvatures ``kappa``, ``kappa_far``).

    The driver's ``traces`` and remnant ``noise`` (:func:`driver_record`) steer the
    environment's car; returns the :data:`LoopOutput` of every sample.
    """
    from manualcontrol.pilots._driver_kernels import drive

    n = env.episode_steps
    d = driver_record(driver, traces, env.speed, env.dt, noise, inject)
    car = _car_record(env, kappa, kappa_far)
    out = LoopOutput(np.zeros((n + 1, 7)), np.zeros(n), np.zeros(n), np.zeros(n))
    drive(car, d, out)
    return out


def calibrated_gain(
    env: LaneKeeping,
    driver: Driver,
    traces: Mapping[str, FloatArray],
    kappa: FloatArray,
    kappa_far: FloatArray,
    unit: FloatArray,
    inject: int,
    ratio: float,
) -> float:
    """The remnant gain for the power ratio ``ratio`` on ``env``'s episode.

    The loop is run with the road and no remnant, then with the unit remnant ``unit``
    on a straight road, and the gain solved from the two actions
    (:func:`~manualcontrol.pilots.simulation.gain_for_ratio`). The driver acting in the
    environment and :func:`~manualcontrol.pilots.driving.simulate_driving` both
    calibrate here, so both give the same gain.
    """
    n = env.episode_steps
    measured = slice(env.n_run_in, n)
    forced = drive_episode(env, driver, traces, kappa, kappa_far, np.zeros(n), inject).action
    zero = np.zeros_like(kappa)
    alone = drive_episode(env, driver, traces, zero, zero, unit, inject).action
    return gain_for_ratio(forced[measured], alone[measured], ratio)


class DriverController:
    """A driver's runtime state in one episode of :class:`~manualcontrol.envs.driving.LaneKeeping`.

    Create it after ``env.reset(...)`` (it reads the episode's road); a remnant with a
    requested power ratio is calibrated on the simulated loop of the same episode, so
    both give the same gain.
    """

    _sample = LazyKernel(_KERNEL_MODULE, "driver_sample")
    _action = LazyKernel(_KERNEL_MODULE, "driver_action")

    def __init__(
        self, driver: Driver, env: Any, seed: int | np.random.Generator | None = None
    ) -> None:
        base = getattr(env, "unwrapped", env)
        if not isinstance(base, LaneKeeping):
            raise TypeError(f"env must be a LaneKeeping environment, got {type(base).__name__}")
        if base._k < 0:
            raise RuntimeError("reset the environment before the driver")
        n = base.episode_steps
        traces = driver.parameter_traces(base.times)
        rng, _ = as_generator(seed)
        remnant = driver.remnant
        inject = INJECT_CODES[None if remnant is None else remnant.injection]
        noise = np.zeros(n)
        if remnant is not None:
            unit = remnant_noise(remnant, rng.standard_normal(n), base.dt)
            gain = remnant.K_r
            if remnant.P_r is not None:
                kappa, kappa_far = base.episode_curvature()
                gain = calibrated_gain(
                    base, driver, traces, kappa, kappa_far, unit, inject, remnant.P_r
                )
            noise = gain * unit
        self._record = driver_record(driver, traces, base.speed, base.dt, noise, inject)
        # each step calls the kernels from the instance: reading the class's LazyKernel
        # at every step would cost a few per cent of it
        self._step_sample, self._step_action = self._sample, self._action
        self._angle = 1.0 if base.steering == "angle" else 0.0
        self._bound = float(base.action_bound)
        self._n = n
        self.k = 0

    def act(self, observation: Any) -> FloatArray:
        """The action for this observation (shape ``(1,)``); advances the driver one sample."""
        k = self.k
        if k >= self._n:
            raise RuntimeError("the driver's episode is over; reset it with the environment")
        inputs = np.ascontiguousarray(np.asarray(observation, dtype=np.float64)[:4])
        self._step_sample(self._record, k, inputs)
        self.k = k + 1
        self.last_output = (float(self._record.out[0]), float(self._record.out[1]))
        return np.array([self._step_action(self._record, k, self._angle, self._bound)])
