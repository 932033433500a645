"""Zhao et al. (2019): the UKF on the cybernetic driver model, its tuning, the multi-UKF.

The driver model of :mod:`manualcontrol.pilots.driver` (eq. 2, Padé-1 delay, the two
corrected entries) is augmented with the estimated parameters as Wiener processes (eq. 3,
Hypothesis 1), discretised by Euler (eq. 6) and run through the unscented Kalman filter
with cubature sigma points (Algorithms 1-2: ``W_0 = 0``, ``W_i = 1/(2N)``). Inputs
``u = (theta_far, theta_near, delta_d, Gamma_s)``, measured outputs ``y = (Gamma_d,
delta_sw)``. Which parameters are estimated is a setting (the paper: ``K_p`` and
``K_c``); the others are held at their ``initial`` values (Table 2 by default).

Tuning (Algorithm 3, :func:`zhao_tuning`)
-----------------------------------------
* ``R_d``: given, or eq. 13 ``diag(sigma_i^2 y_i,max^2)`` from the run's outputs and
  error ratios ``sigma_i``;
* ``Q_x,d = Q_x_scale G_o^-1`` (eqs. 14, 18 with ``Q_x_scale = 1/T_x``), ``G_o`` the
  observability Gramian of the nominal LTI model discretised by eq. 6, over an infinite
  horizon (``gramian_horizon=None``, the discrete Lyapunov solution of eq. 14) or a
  finite one in seconds;
* ``Q_theta,d = Q_theta_scale diag(theta_nom^2)`` (eq. 15 with one ``alpha^2/T_theta``
  for all; ``Q_theta`` overrides per parameter).

The paper gives these per sample of its own sample time ``T_s`` (``reference_dt``, 1 ms:
the observer poles of eq. 18 come out at -1.10, -10.2 and -51.4 rad/s there, the paper's
"-1, -10, -50"). Eq. 6 defines them from continuous intensities, ``Q_d = T_s Q`` and
``R_d = R / T_s``; the filter converts them to its own sample time ``dt`` that way
(``Q_d(dt) = Q_d(T_s) dt/T_s``, ``R_d(dt) = R_d(T_s) T_s/dt``), so a tuning means the
same observer at any data rate. Presets (eqs. 16-20): ``"ukf1"`` ``R_d = diag(9e-4,
25e-4)``, ``Q_x,d = 1e-7 G_o^-1``, ``Q_theta,d = 1e-8 diag(3.4^2, 15^2)``; ``"ukf2"`` the
same with ``1e-6``.

Choices where the paper is silent
---------------------------------
* Euler sub-steps: the prediction integrates eq. 6 in ``substeps`` Euler steps over each
  sample (default: as many as make the step at most ``reference_dt``, 10 at 100 Hz), the
  inputs held; at 100 Hz a single Euler step of the Padé pole at ``-2/tau_p = -50`` rad/s
  would put it at ``-69`` rad/s (the model would not be the paper's).
* ``P_a[0]`` ("chosen arbitrarily"): ``P0_states`` (1e-2) on the states and ``(P0_fraction
  theta_0)^2`` (10 %) on the parameters; ``x_a[0]`` as eq. 16 (states 0, parameters at
  their initial values).
* Limits: each estimated parameter is projected onto ``[0.1, 10]`` times its initial
  value (a sign change makes no sense for these gains); ``limits="none"`` removes them.
* The speed ``v_x`` in the model is the car's (the recording's metadata ``speed``), not
  Table 2's 18 m/s, unless ``speed`` is set.

The multi-UKF (Sec. 4.2) is :class:`MultiUKF`, with the fusion rule documented there.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._lazy import LazyKernel
from manualcontrol.envs._validation import (
    check_choice,
    check_int,
    check_positive,
    check_real,
)
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators import _pilot_core as pilot_core
from manualcontrol.estimators.analysis.metrics import observability_gramian
from manualcontrol.estimators.filters.unscented import sigma_weights, unscented_work
from manualcontrol.estimators.members import _zhao_core as core
from manualcontrol.estimators.members import _zhao_native
from manualcontrol.estimators.offline.smoothing import SmootherBlock, SmootherInputs
from manualcontrol.estimators.protocol import EstimationResult, sample_floats
from manualcontrol.estimators.settings import GuardSettings, SettingsRecord, limit_pair
from manualcontrol.estimators.shell import (
    FilterShell,
    health_summary,
    output_arrays,
    trace_arrays,
    two_output_arrays,
)
from manualcontrol.pilots.driver import DRIVER_INPUTS, DRIVER_OUTPUTS, CyberneticDriverModel

__all__ = [
    "PRESETS",
    "REFERENCE_DT",
    "FastMemberSettings",
    "FusionSettings",
    "ZhaoNoiseSettings",
    "ZhaoTuning",
    "ZhaoUKF",
    "ZhaoUKFSettings",
    "observer_poles",
    "zhao_tuning",
]

FloatArray = NDArray[np.float64]

#: The paper's sample time (s) at which its ``R_d`` and ``Q_d`` are given.
REFERENCE_DT = 0.001
#: Zhao eqs. 17-20: R_d, the Q_x,d factor on G_o^-1, the Q_theta,d factor on theta_nom^2.
PRESETS: Mapping[str, Mapping[str, Any]] = MappingProxyType(
    {
        "ukf1": MappingProxyType({"R_d": (9e-4, 25e-4), "Q_x_scale": 1e-7, "Q_theta_scale": 1e-8}),
        "ukf2": MappingProxyType({"R_d": (9e-4, 25e-4), "Q_x_scale": 1e-7, "Q_theta_scale": 1e-6}),
    }
)
SCHEMES: tuple[str, ...] = ("cubature", "merwe")
STATE_NAMES: tuple[str, ...] = ("x_1", "x_2", "x_3")
_MODEL = CyberneticDriverModel()
_NAMES = _MODEL.parameter_names
#: Where the numba kernels live: imported where numba runs them, never by the C path.
_KERNEL_MODULE = "manualcontrol.estimators.members._zhao_kernels"


def _pair(name: str, value: Any, *, allow_none: bool = True) -> tuple[float, float] | None:
    if value is None and allow_none:
        return None
    try:
        first, second = value
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a pair of numbers, got {value!r}") from None
    return (check_positive(f"{name}[0]", first), check_positive(f"{name}[1]", second))


def _names_mapping(name: str, value: Any, check: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise TypeError(f"{name} must be a mapping of parameter names, got {value!r}")
    out = {}
    for key, item in value.items():
        if key not in _NAMES:
            raise ValueError(
                f"{name}: unknown parameter {key!r}; the driver model's parameters are "
                f"{', '.join(_NAMES)}"
            )
        out[key] = check(f"{name}[{key!r}]", item)
    return MappingProxyType(out)


@dataclass(frozen=True)
class ZhaoNoiseSettings(SettingsRecord):
    """The filter's covariances: Algorithm 3's tuning and the initial covariance.

    A group of :class:`ZhaoUKFSettings` (``noise=``); each field is also accepted by its
    own name in suite files, ``--set`` and keyword arguments (``Q_x_scale=0.1``). A
    tuning field left None takes the ``preset``'s value (:func:`zhao_tuning`).

    Parameters
    ----------
    R_d : (float, float) or None
        Measurement noise per reference sample (``Gamma_d``, ``delta_sw``); None: the
        preset's, or eq. 13 when ``output_error_ratios`` is given.
    output_error_ratios : (float, float) or None
        ``sigma_i`` of eq. 13, ``R_d = diag(sigma_i^2 max|y_i|^2)`` over the run.
    Q_x_scale, Q_theta_scale : float or None
        ``1/T_x`` of eq. 14 and ``alpha^2/T_theta`` of eq. 15; None: the preset's.
    Q_theta : Mapping[str, float]
        Per-parameter ``Q_theta,d`` per reference sample, overriding eq. 15 (estimated
        parameters only, which :class:`ZhaoUKFSettings` checks).
    reference_dt : float
        The sample time (s) at which ``R_d`` and the ``Q`` are given (1 ms, the paper's).
    gramian_horizon : float or None
        Horizon (s) of eq. 14's sum; None: infinite.
    P0_states, P0_fraction : float
        Initial covariance: ``P0_states`` on the states, ``(P0_fraction theta_0)^2`` on
        the parameters.
    """

    tuple_fields: ClassVar[tuple[str, ...]] = ("R_d", "output_error_ratios")

    R_d: tuple[float, float] | None = None
    output_error_ratios: tuple[float, float] | None = None
    Q_x_scale: float | None = None
    Q_theta_scale: float | None = None
    Q_theta: Mapping[str, float] = field(default_factory=dict)
    reference_dt: float = REFERENCE_DT
    gramian_horizon: float | None = None
    P0_states: float = 1e-2
    P0_fraction: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "R_d", _pair("R_d", self.R_d))
        object.__setattr__(
            self, "output_error_ratios", _pair("output_error_ratios", self.output_error_ratios)
        )
        if self.R_d is not None and self.output_error_ratios is not None:
            raise ValueError("give R_d or output_error_ratios (eq. 13), not both")
        for name in ("Q_x_scale", "Q_theta_scale"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, check_positive(name, value))
        object.__setattr__(self, "Q_theta", _names_mapping("Q_theta", self.Q_theta, check_positive))
        object.__setattr__(self, "reference_dt", check_positive("reference_dt", self.reference_dt))
        if self.gramian_horizon is not None:
            object.__setattr__(
                self, "gramian_horizon", check_positive("gramian_horizon", self.gramian_horizon)
            )
        object.__setattr__(self, "P0_states", check_positive("P0_states", self.P0_states))
        object.__setattr__(self, "P0_fraction", check_positive("P0_fraction", self.P0_fraction))


@dataclass(frozen=True)
class ZhaoUKFSettings(SettingsRecord):
    """Settings of :class:`ZhaoUKF` (frozen; module docstring for the rules).

    The covariances (``noise``) and the guards (``guard``) are groups; suite files,
    ``--set`` and keyword arguments give each of their fields by its own name
    (``R_d=...``, ``Q_x_scale=0.1``, ``jitter=1e-9``) or a group as a table, and
    ``to_dict`` writes the nested form.

    Parameters
    ----------
    preset : {"ukf1", "ukf2"}
        Zhao eqs. 17-20: the slow (1e-8) or the fast (1e-6) parameter noise.
    estimated : tuple of str
        Parameters in the augmented state (``K_p``, ``K_c``).
    initial : Mapping[str, float]
        Initial (and, for the others, held) parameter values; Table 2 where missing.
    initial_states : (float, float, float)
        ``x[0]`` of the driver model's states (eq. 16: zeros).
    substeps : int or None
        Euler steps per sample in the prediction; None: ``ceil(dt / reference_dt)``.
    scheme : {"cubature", "merwe"}
        Sigma points (Zhao's choice: cubature).
    limits : "default", "none" or Mapping[str, (low, high)]
        Estimate projection: ``[0.1, 10]`` times the initial value by default.
    speed : float or None
        ``v_x`` (m/s); None: the recording's ``speed``.
    noise : ZhaoNoiseSettings
        ``R_d`` or ``output_error_ratios``, ``Q_x_scale``, ``Q_theta_scale``,
        ``Q_theta``, ``reference_dt``, ``gramian_horizon``, ``P0_states`` and
        ``P0_fraction`` (:class:`ZhaoNoiseSettings`).
    guard : GuardSettings
        As the pilot filters' (``jitter``, ``max_covariance``, ``pinned_time``, each also
        by its own name), with ``pinned_time = inf`` (never reported) by default.

    """

    tuple_fields: ClassVar[tuple[str, ...]] = ("estimated", "initial_states")
    pair_mapping_fields: ClassVar[tuple[str, ...]] = ("limits",)
    groups: ClassVar[tuple[str, ...]] = ("noise", "guard")

    preset: str = "ukf1"
    estimated: tuple[str, ...] = ("K_p", "K_c")
    initial: Mapping[str, float] = field(default_factory=dict)
    initial_states: tuple[float, float, float] = (0.0, 0.0, 0.0)
    substeps: int | None = None
    scheme: str = "cubature"
    limits: str | Mapping[str, tuple[float, float]] = "default"
    speed: float | None = None
    noise: ZhaoNoiseSettings = field(default_factory=ZhaoNoiseSettings)
    guard: GuardSettings = field(default_factory=lambda: GuardSettings(pinned_time=math.inf))

    def __post_init__(self) -> None:
        check_choice("preset", self.preset, tuple(PRESETS))
        if isinstance(self.estimated, str) or not isinstance(self.estimated, (tuple, list)):
            raise TypeError(f"estimated must be a tuple of parameter names, got {self.estimated!r}")
        estimated = tuple(self.estimated)
        if not estimated:
            raise ValueError("estimated must name at least one parameter")
        for name in estimated:
            check_choice("estimated parameter", name, _NAMES)
        if len(set(estimated)) != len(estimated):
            raise ValueError(f"estimated names a parameter twice: {estimated}")
        object.__setattr__(self, "estimated", estimated)
        object.__setattr__(self, "initial", _names_mapping("initial", self.initial, check_real))
        states = tuple(self.initial_states)
        if len(states) != 3:
            raise ValueError(f"initial_states must have 3 entries, got {self.initial_states!r}")
        object.__setattr__(
            self,
            "initial_states",
            tuple(check_real(f"initial_states[{i}]", v) for i, v in enumerate(states)),
        )
        if self.substeps is not None:
            object.__setattr__(self, "substeps", check_int("substeps", self.substeps, minimum=1))
        check_choice("scheme", self.scheme, SCHEMES)
        if isinstance(self.limits, str):
            check_choice("limits", self.limits, ("default", "none"))
        else:
            object.__setattr__(self, "limits", _names_mapping("limits", self.limits, limit_pair))
        if self.speed is not None:
            object.__setattr__(self, "speed", check_positive("speed", self.speed))
        self._require_groups(("noise", "guard"))
        for name in self.noise.Q_theta:
            if name not in estimated:
                raise ValueError(f"Q_theta names {name!r}, which is not estimated")

    def initial_vector(self) -> FloatArray:
        """Every parameter's initial value, model order."""
        return _MODEL.vector(self.initial)


# ------------------------------------------------------------------------- tuning


def observer_poles(A_d: Any, C_d: Any, Q: Any, R: Any, dt: float) -> FloatArray:
    """Poles of the steady-state Kalman observer of ``(A_d, C_d)``, as rates ``ln(z)/dt``.

    The discrete algebraic Riccati equation (scipy ``solve_discrete_are``) gives the
    prior covariance ``P``; the observer ``x+ = (A_d - A_d K C_d) x + ...`` with ``K = P
    C^T (C P C^T + R)^-1`` has eigenvalues ``z``; Algorithm 3's "verification by the
    adequate algebraic Riccati equation". Sorted by real part, fastest first.
    """
    import scipy.linalg

    A_d = np.asarray(A_d, dtype=np.float64)
    C_d = np.asarray(C_d, dtype=np.float64)
    P = scipy.linalg.solve_discrete_are(A_d.T, C_d.T, np.asarray(Q), np.asarray(R))
    S = C_d @ P @ C_d.T + np.asarray(R)
    K = np.linalg.solve(S, C_d @ P).T
    z = np.linalg.eigvals(A_d - A_d @ K @ C_d).astype(complex)
    rates = np.log(z) / dt
    return rates[np.argsort(rates.real)]


@dataclass(frozen=True)
class ZhaoTuning:
    """Every number a :class:`ZhaoUKF` run uses (Algorithm 3 resolved at reset).

    ``R_d`` (2, 2) and ``Q`` (n, n) are per sample of the run's ``dt``; the ``*_reference``
    entries per ``reference_dt``; ``gramian`` is eq. 14 of ``(A_reference, C)``, the
    nominal (initial) model discretised by eq. 6 at ``reference_dt``.
    """

    dt: float
    reference_dt: float
    substeps: int
    speed: float
    R_d: FloatArray
    Q: FloatArray
    R_d_reference: FloatArray
    Q_x_reference: FloatArray
    Q_theta_reference: FloatArray
    gramian: FloatArray
    A_reference: FloatArray
    C: FloatArray
    limits: Mapping[str, tuple[float, float]]

    def observer_poles(self) -> FloatArray:
        """Poles (rad/s) of the steady-state observer of the states with ``Q_x``, ``R_d``.

        At ``reference_dt`` (Algorithm 3 step 3's check; :func:`observer_poles`).
        """
        return observer_poles(
            self.A_reference, self.C, self.Q_x_reference, self.R_d_reference, self.reference_dt
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {
            "dt": self.dt,
            "reference_dt": self.reference_dt,
            "substeps": self.substeps,
            "speed": self.speed,
            "R_d": self.R_d.tolist(),
            "Q": self.Q.tolist(),
            "R_d_reference": self.R_d_reference.tolist(),
            "Q_x_reference": self.Q_x_reference.tolist(),
            "Q_theta_reference": self.Q_theta_reference.tolist(),
            "gramian": self.gramian.tolist(),
            "limits": {k: [v[0], v[1]] for k, v in self.limits.items()},
        }


def zhao_tuning(
    settings: ZhaoUKFSettings,
    dt: float,
    speed: float,
    output_max: tuple[float, float] | None = None,
) -> ZhaoTuning:
    """Resolve Algorithm 3 for a run at sample time ``dt`` and speed ``speed``.

    ``output_max`` (max ``|Gamma_d|``, max ``|delta_sw|`` over the run) is needed by eq.
    13 when the settings give ``output_error_ratios``.
    """
    dt = check_positive("dt", dt)
    speed = check_positive("speed", speed)
    preset = PRESETS[settings.preset]
    noise = settings.noise
    reference = noise.reference_dt
    if noise.output_error_ratios is not None:
        if output_max is None:
            raise ValueError(
                "output_error_ratios (eq. 13) need the outputs' largest magnitudes: pass "
                "output_max=(max|Gamma_d|, max|delta_sw|) to reset(); estimate() computes them"
            )
        ratios = np.asarray(noise.output_error_ratios)
        R_ref = np.diag((ratios * np.asarray(output_max, dtype=np.float64)) ** 2)
        if not np.all(np.diag(R_ref) > 0.0):
            raise ValueError(
                f"eq. 13 gives a zero R_d: outputs all zero? output_max={output_max!r}"
            )
    else:
        R_ref = np.diag(noise.R_d if noise.R_d is not None else preset["R_d"])
    initial = settings.initial_vector()
    system = _MODEL.state_space(dict(zip(_NAMES, initial, strict=True)), speed)
    A_d = np.eye(3) + reference * system.A  # eq. 6
    horizon = None
    if noise.gramian_horizon is not None:
        horizon = max(1, round(noise.gramian_horizon / reference))
    gramian = observability_gramian(A_d, system.C, horizon)
    Q_x_scale = noise.Q_x_scale if noise.Q_x_scale is not None else preset["Q_x_scale"]
    Q_x_ref = Q_x_scale * np.linalg.inv(gramian)
    Q_x_ref = 0.5 * (Q_x_ref + Q_x_ref.T)
    Q_theta_scale = (
        noise.Q_theta_scale if noise.Q_theta_scale is not None else preset["Q_theta_scale"]
    )
    Q_theta_ref = np.array(
        [
            noise.Q_theta.get(name, Q_theta_scale * initial[_NAMES.index(name)] ** 2)
            for name in settings.estimated
        ]
    )
    n = 3 + len(settings.estimated)
    Q = np.zeros((n, n))
    Q[:3, :3] = Q_x_ref * (dt / reference)
    Q[3:, 3:] = np.diag(Q_theta_ref * (dt / reference))
    R_d = R_ref * (reference / dt)
    substeps = settings.substeps or max(1, math.ceil(dt / reference - 1e-9))
    limits: dict[str, tuple[float, float]] = {}
    if settings.limits == "default":
        for name in settings.estimated:
            value = initial[_NAMES.index(name)]
            low, high = sorted((0.1 * value, 10.0 * value))
            if value != 0.0:
                limits[name] = (low, high)
    elif isinstance(settings.limits, Mapping):
        limits = {k: v for k, v in settings.limits.items() if k in settings.estimated}
    return ZhaoTuning(
        dt=dt,
        reference_dt=reference,
        substeps=substeps,
        speed=speed,
        R_d=R_d,
        Q=Q,
        R_d_reference=R_ref,
        Q_x_reference=Q_x_ref,
        Q_theta_reference=Q_theta_ref,
        gramian=gramian,
        A_reference=A_d,
        C=np.asarray(system.C),
        limits=MappingProxyType(limits),
    )


# ---------------------------------------------------------------------- estimator

_SAMPLE_KEYS = (*DRIVER_INPUTS, *DRIVER_OUTPUTS)
_ALLOWED_SAMPLE_KEYS = frozenset((*_SAMPLE_KEYS, "t"))


def _driving_signals(recording: Recording) -> tuple[FloatArray, FloatArray]:
    if not isinstance(recording, Recording):
        raise TypeError(f"recording must be a Recording, got {recording!r}")
    missing = [name for name in _SAMPLE_KEYS if name not in recording]
    if missing:
        raise ValueError(
            f"the recording lacks {', '.join(map(repr, missing))}: the driver-model filters "
            f"read {', '.join(_SAMPLE_KEYS)} (simulate_driving records them)"
        )
    inputs = np.ascontiguousarray(np.column_stack([recording[n] for n in DRIVER_INPUTS]))
    outputs = np.ascontiguousarray(np.column_stack([recording[n] for n in DRIVER_OUTPUTS]))
    return inputs, outputs


def _recording_speed(settings_speed: float | None, recording: Recording) -> float:
    if settings_speed is not None:
        return settings_speed
    speed = recording.metadata.get("speed")
    if speed is None:
        raise ValueError(
            "the recording's metadata has no 'speed': give the car's speed in the settings "
            "(speed=... m/s)"
        )
    return check_positive("recording speed", speed)


def _sample_arrays(sample: Mapping[str, float], where: str) -> tuple[FloatArray, FloatArray]:
    """The driver model's inputs and outputs in one sample, checked (``sample_floats``)."""
    values = sample_floats(where, sample, _SAMPLE_KEYS, _ALLOWED_SAMPLE_KEYS)
    return np.array(values[:4]), np.array(values[4:])


class ZhaoUKF(FilterShell):
    """Zhao et al.'s UKF on the cybernetic driver model (module docstring).

    Parameters
    ----------
    settings
        A :class:`ZhaoUKFSettings`; keyword arguments replace its fields (or build one).

    Examples
    --------
    >>> from manualcontrol.pilots.driver import Driver
    >>> from manualcontrol.pilots.driving import simulate_driving
    >>> recording = simulate_driving(Driver(), measurement_time=30.0)
    >>> result = ZhaoUKF(preset="ukf2").estimate(recording)
    >>> round(result.final()["K_p"], 1)
    3.4

    """

    name = "zhao-ukf"
    settings_type = ZhaoUKFSettings
    outputs = DRIVER_OUTPUTS
    # the driver model's inputs and outputs
    _sample_keys = _SAMPLE_KEYS

    #: The binding of this member's C port (envs/_native.py builds it).
    _native_binding = _zhao_native
    #: numba's step and run, read only where the C port does not run.
    _step_kernel = LazyKernel(_KERNEL_MODULE, "zhao_step")
    _run_kernel = LazyKernel(_KERNEL_MODULE, "zhao_run")

    def __init__(self, settings: ZhaoUKFSettings | None = None, **changes: Any) -> None:
        super().__init__(settings, **changes)
        self._tuning: ZhaoTuning | None = None

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """The driver model's parameters."""
        return _NAMES

    def signals(self, recording: Recording) -> dict[str, FloatArray]:
        """The sample signals :meth:`estimate` feeds the filter, by key."""
        inputs, outputs = _driving_signals(recording)
        return dict(zip(self._sample_keys, (*inputs.T, *outputs.T), strict=True))

    @property
    def tuning(self) -> ZhaoTuning:
        """Everything resolved at the last :meth:`reset`."""
        if self._tuning is None:
            raise RuntimeError(f"the {type(self).__name__} has not been reset; call reset() first")
        return self._tuning

    def _repr_fields(self) -> Mapping[str, Any]:
        return {"preset": self._settings.preset, "estimated": self._settings.estimated}

    # ----------------------------------------------------------------- reset

    def reset(
        self,
        dt: float = 0.01,
        *,
        speed: float | None = None,
        output_max: tuple[float, float] | None = None,
        t0: float = 0.0,
    ) -> None:
        """Start from the initial belief (eq. 16) for samples ``dt`` apart.

        ``speed`` (m/s) is required unless the settings give it; ``output_max`` only for
        eq. 13 (``output_error_ratios``).
        """
        settings = self._settings
        speed = settings.speed if settings.speed is not None else speed
        if speed is None:
            raise ValueError("reset needs the car's speed (m/s): reset(dt, speed=...)")
        tuning = zhao_tuning(settings, dt, speed, output_max)
        self._tuning = tuning
        self._begin(self._build(tuning), tuning.dt, check_real("t0", t0), settings.estimated)

    def _build(self, tuning: ZhaoTuning) -> tuple[Any, ...]:
        settings = self._settings
        names = _NAMES
        n_t = len(settings.estimated)
        n = 3 + n_t
        initial = settings.initial_vector()
        theta_index = np.array([names.index(name) for name in settings.estimated], dtype=np.int64)
        weights = sigma_weights(n, settings.scheme)
        cfg = np.zeros(core.CFG_SIZE)
        cfg[core.CFG_VX] = tuning.speed
        cfg[core.CFG_H] = tuning.dt / tuning.substeps
        cfg[core.CFG_SUBSTEPS] = tuning.substeps
        cfg[core.CFG_SPREAD] = weights.spread
        cfg[core.CFG_COUNT] = weights.count
        cfg[core.CFG_JITTER] = settings.guard.jitter
        cfg[core.CFG_MAX_COV] = settings.guard.max_covariance
        lo = np.full(len(names), -np.inf)
        hi = np.full(len(names), np.inf)
        for name, (low, high) in tuning.limits.items():
            lo[names.index(name)], hi[names.index(name)] = low, high
        limit = np.full(n, -1, dtype=np.int64)
        limit[3:] = theta_index
        estimated = np.array([name in settings.estimated for name in names], dtype=np.bool_)
        config = core.ZhaoConfig(
            cfg=cfg,
            base=initial.copy(),
            theta_index=theta_index,
            Q=np.ascontiguousarray(tuning.Q),
            R=np.ascontiguousarray(tuning.R_d),
            w_mean=weights.mean,
            w_cov=weights.cov,
            limit=limit,
            estimated=estimated,
        )
        x = np.zeros(n)
        x[:3] = settings.initial_states
        x[3:] = initial[theta_index]
        P = np.zeros((n, n))
        P[:3, :3] = np.eye(3) * settings.noise.P0_states
        P[3:, 3:] = np.diag((settings.noise.P0_fraction * initial[theta_index]) ** 2)
        sc = np.zeros(pilot_core.SC_SIZE)
        sc[pilot_core.SC_DIV_INDEX] = -1.0
        sc[pilot_core.SC_DIV_PARAM] = -1.0
        belief = core.ZhaoBelief(
            x=x, P=P, prev_in=np.zeros(4), p=initial.copy(), sc=sc, link=np.zeros((n, n))
        )
        pinned = settings.guard.pinned_time
        n_pin = 0 if math.isinf(pinned) else max(1, round(pinned / tuning.dt))
        watch = pilot_core.PilotMonitor(
            np.zeros(1),
            np.zeros(1),
            np.zeros(len(names), dtype=np.int64),
            np.zeros((len(names), n_pin), dtype=np.int64),
            initial.copy(),
            np.zeros(len(names)),
            np.zeros(len(names), dtype=np.bool_),
        )
        report = pilot_core.PilotReport(lo, hi, np.zeros(len(names)), np.ones(len(names)))
        scratch = core.ZhaoScratch(
            work=unscented_work(n, 2),
            A=np.zeros((3, 3)),
            B=np.zeros((3, 4)),
            C=np.zeros((2, 3)),
            D=np.zeros((2, 4)),
            Bu=np.zeros(3),
            y=np.zeros(3),
            r=np.zeros(2),
            in_use=np.zeros(4),
            variance=np.zeros(len(names)),
            scalars=np.zeros(3),
            point=np.zeros(len(names)),
        )
        return (config, belief, watch, report, scratch)

    def _new_output(self, n: int, store: bool) -> core.ZhaoOutput:
        n_a = 3 + len(self._settings.estimated)
        p = len(_NAMES)
        rows = n if store else 0
        return core.ZhaoOutput(
            **output_arrays(n, p),
            **two_output_arrays(n),
            states=np.zeros((n, 3)),
            **trace_arrays(rows, n_a),
            link=np.zeros((rows, n_a, n_a)),
        )

    # ---------------------------------------------------------------- update

    def _step_sample(self, sample: Mapping[str, float]) -> None:
        """Step on one sample.

        ``sample`` maps ``theta_far, theta_near, delta_d, Gamma_s, Gamma_d, delta_sw`` to
        floats (optionally ``t``); NaN in any marks a dropped sample.
        """
        inputs, outputs = _sample_arrays(sample, self._where)
        self._call_step("_step_kernel", (*self._records, inputs, outputs, 0, self._row))

    # The C port of the compiled path (_zhao_native.c) runs wherever it builds: the same
    # numbers bit for bit as the numba kernels, which run elsewhere (envs/_native.py).

    def _run(self, inputs: Any, outputs: Any, out: core.ZhaoOutput) -> None:
        native = self._native_records(out)
        if native is None:
            self._run_kernel(*self._records, inputs, outputs, out)
        else:
            native.run(inputs, outputs)
            self._native = None  # the binding would keep a whole run's output alive

    def _call_step(self, kernel: Any, arguments: tuple) -> None:
        """One sample through the C port where it runs (else numba's, as the shell does).

        The online path (``update``: the one-row output) then calls the C step directly
        for the rest of the reset (``_entry``, as numba's entry point).
        """
        entry = self._entry
        if entry is not None:
            entry(*arguments)
            return
        *_, inputs, outputs, _, out = arguments
        native = self._native_records(out)
        if native is None:
            super()._call_step(kernel, arguments)
            return
        native.step(inputs, outputs)
        if out is self._row:
            self._entry = native.entry()

    # -------------------------------------------------------------- estimate

    def estimate(
        self,
        recording: Recording,
        *,
        smoother_inputs: bool = False,
        smooth: bool = False,
    ) -> EstimationResult:
        """Run the filter over a recording from a fresh reset.

        The recording needs the driver model's inputs and outputs, as
        :func:`~manualcontrol.pilots.driving.simulate_driving` records them, and the
        car's ``speed`` in its metadata (or in the settings).

        ``smoother_inputs`` keeps what :func:`~manualcontrol.estimators.offline.smoothing.smooth`
        needs; ``smooth`` returns the smoothed result.
        """
        inputs, outputs = _driving_signals(recording)
        speed = _recording_speed(self._settings.speed, recording)
        output_max = None
        if self._settings.noise.output_error_ratios is not None:
            with np.errstate(invalid="ignore"):
                output_max = tuple(float(np.nanmax(np.abs(outputs[:, i]))) for i in range(2))
        self.reset(recording.dt, speed=speed, output_max=output_max, t0=float(recording.t[0]))
        n = len(recording)
        store = bool(smoother_inputs or smooth)
        out = self._new_output(n, store)
        self._run(inputs, outputs, out)
        self._k = n
        return self._finish(self._result(np.asarray(recording.t), out, store), smooth)

    def _result(self, t: FloatArray, out: core.ZhaoOutput, store: bool) -> EstimationResult:
        return self._assemble(
            t,
            out,
            store,
            settings={"settings": self._settings.to_dict(), "resolved": self.tuning.to_dict()},
            state_names=STATE_NAMES,
            states=out.states,
        )

    def _smoother_inputs(self, out: core.ZhaoOutput) -> Any:

        report = self._records[3]
        block = SmootherBlock.of_trace(
            "ukf",
            out,
            out.link,
            parameters={name: 3 + t for t, name in enumerate(self._settings.estimated)},
            states={name: i for i, name in enumerate(STATE_NAMES)},
        )
        return SmootherInputs.of_report((block,), _NAMES, report)


# ---------------------------------------------------------------------- multi-UKF


@dataclass(frozen=True)
class FusionSettings(SettingsRecord):
    """How the multi-UKF fuses its members (``fusion=``; :class:`MultiUKF` for the rule).

    A group of :class:`MultiUKFSettings`; each field is also accepted by its own name
    (``dead_zone=0``).

    Parameters
    ----------
    smoothing_time : float
        Time constant (s) of the EWMA of the disagreement (2 s).
    level_time : float
        Time constant (s) of the EWMA of its square, the disagreement's usual level (200 s).
    dead_zone : float
        Disagreements below this fraction of each parameter's initial value are never
        followed (0.5 %).
    feedback : bool
        Re-centre the slow member on the fused estimate (True).
    """

    tuple_fields: ClassVar[tuple[str, ...]] = ()

    smoothing_time: float = 2.0
    level_time: float = 200.0
    dead_zone: float = 0.005
    feedback: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "smoothing_time", check_positive("smoothing_time", self.smoothing_time)
        )
        object.__setattr__(self, "level_time", check_positive("level_time", self.level_time))
        object.__setattr__(
            self, "dead_zone", check_positive("dead_zone", self.dead_zone, allow_zero=True)
        )
        if not isinstance(self.feedback, bool):
            raise TypeError(f"feedback must be True or False, got {self.feedback!r}")


@dataclass(frozen=True)
class FastMemberSettings(SettingsRecord):
    """What sets the multi-UKF's fast member apart from its slow one (``fast=``).

    A group of :class:`MultiUKFSettings`; each field is also accepted flat by the name in
    brackets, the one error messages use: ``fast_preset="ukf1"`` is
    ``fast={"preset": "ukf1"}``.

    Parameters
    ----------
    preset : {"ukf1", "ukf2"}
        (``fast_preset``) The fast member: the slow member's settings with this preset
        (``"ukf2"``).
    Q_theta_scale : float or None
        (``fast_Q_theta_scale``) The fast member's ``Q_theta_scale`` (None: its preset's).
    """

    tuple_fields: ClassVar[tuple[str, ...]] = ()
    flat_names: ClassVar[Mapping[str, str]] = {
        "preset": "fast_preset",
        "Q_theta_scale": "fast_Q_theta_scale",
    }

    preset: str = "ukf2"
    Q_theta_scale: float | None = None

    def __post_init__(self) -> None:
        check_choice("fast_preset", self.preset, tuple(PRESETS))
        if self.Q_theta_scale is not None:
            object.__setattr__(
                self, "Q_theta_scale", check_positive("fast_Q_theta_scale", self.Q_theta_scale)
            )


@dataclass(frozen=True)
class MultiUKFSettings(ZhaoUKFSettings):
    """Settings of :class:`MultiUKF`: both members' and the fusion's.

    Every :class:`ZhaoUKFSettings` field (``noise`` and ``guard`` included) describes the
    slow member (``preset`` "ukf1"); the fast member is the same with the ``fast``
    group's preset and ``Q_theta_scale``.

    Parameters
    ----------
    fusion : FusionSettings
        ``smoothing_time`` (2 s), ``level_time`` (200 s), ``dead_zone`` (0.5 %) and
        ``feedback`` (True), each also by its own name (:class:`FusionSettings`).
    fast : FastMemberSettings
        ``fast_preset`` (``"ukf2"``) and ``fast_Q_theta_scale`` (None: its preset's)
        (:class:`FastMemberSettings`).

    """

    groups: ClassVar[tuple[str, ...]] = ("noise", "guard", "fusion", "fast")

    fusion: FusionSettings = field(default_factory=FusionSettings)
    fast: FastMemberSettings = field(default_factory=FastMemberSettings)

    def __post_init__(self) -> None:
        super().__post_init__()
        self._require_groups(("fusion", "fast"))

    def members(self) -> tuple[ZhaoUKFSettings, ZhaoUKFSettings]:
        """The slow and the fast member's settings."""
        base = {f.name: getattr(self, f.name) for f in dataclasses.fields(ZhaoUKFSettings)}
        noise = dataclasses.replace(self.noise, Q_theta_scale=self.fast.Q_theta_scale)
        fast = {**base, "preset": self.fast.preset, "noise": noise}
        return ZhaoUKFSettings(**base), ZhaoUKFSettings(**fast)


class MultiUKF(FilterShell):
    """Zhao Sec. 4.2's multi-UKF: a slow and a fast :class:`ZhaoUKF` side by side, fused.

    The paper gives no fusion rule. This one follows the paper's roles ("one configured
    to get a precise steady-state value, the other to detect possible fast
    variations"): the output is the slow member's estimate, moved toward the fast
    member's only as far as their disagreement is systematic. Per estimated parameter,
    ``dbar`` is the disagreement ``theta_fast - theta_slow`` smoothed over
    ``smoothing_time`` (the fast member's sample-to-sample noise averages out, a lag of
    the slow member does not), ``level`` the mean of ``dbar^2`` over ``level_time`` (what
    the disagreement usually is), and::

        lambda = clip(1 - (level + (dead_zone theta_0)^2) / dbar^2, 0, 1)
        theta  = theta_slow + lambda dbar      (not beyond theta_fast)

    (a positive-part shrinkage: a disagreement at its usual level or within the dead
    zone is ignored, one well above it is followed). With ``feedback`` the slow member is
    then re-centred on ``theta`` (its parameter means move; its covariance is kept), so
    after a change it continues from the new value instead of catching up over its
    long time constant: the precise member never lags by more than the fusion allows.

    Why not the innovation likelihood (IMM-style weighting): on the lane-keeping
    drives the parameters change the outputs so little from one sample to the next
    that the slow member's innovations are as likely as the fast one's even during
    ramps (log-likelihood over a second in favour of the slow member throughout), so
    likelihood weights pick the slow member always and lose its lag (measured while
    designing this rule).

    The result's ``states`` hold, besides the slow member's model states, each
    member's estimates (``slow.K_p``, ``fast.K_p``, ...) and the gates (``gate.K_p``);
    predictions and innovations are the slow member's.
    """

    name = "zhao-multi-ukf"
    settings_type = MultiUKFSettings
    outputs = DRIVER_OUTPUTS
    _sample_keys = _SAMPLE_KEYS

    #: The binding of this member's C port (envs/_native.py builds it).
    _native_binding = _zhao_native
    #: numba's step and run of both members and the fusion, read as ZhaoUKF's.
    _step_kernel = LazyKernel(_KERNEL_MODULE, "multi_step")
    _run_kernel = LazyKernel(_KERNEL_MODULE, "multi_run")

    def __init__(self, settings: MultiUKFSettings | None = None, **changes: Any) -> None:
        super().__init__(settings, **changes)
        slow, fast = self._settings.members()
        self._slow = ZhaoUKF(slow)
        self._fast = ZhaoUKF(fast)

    parameter_names = ZhaoUKF.parameter_names
    signals = ZhaoUKF.signals

    def _repr_fields(self) -> Mapping[str, Any]:
        return {"slow": self._settings.preset, "fast": self._settings.fast.preset}

    def reset(
        self,
        dt: float = 0.01,
        *,
        speed: float | None = None,
        output_max: tuple[float, float] | None = None,
        t0: float = 0.0,
    ) -> None:
        """Reset both members (see :meth:`ZhaoUKF.reset`) and the fusion."""
        self._slow.reset(dt, speed=speed, output_max=output_max, t0=t0)
        self._fast.reset(dt, speed=speed, output_max=output_max, t0=t0)
        settings = self._settings
        dt = self._slow.tuning.dt
        initial = settings.initial_vector()
        theta_index = np.array([_NAMES.index(n) for n in settings.estimated], dtype=np.int64)
        n_t = len(theta_index)
        rule = settings.fusion
        fusion = core.FusionConfig(
            a_short=1.0 - math.exp(-dt / rule.smoothing_time),
            a_long=1.0 - math.exp(-dt / rule.level_time),
            dead_zone=np.abs(rule.dead_zone * initial[theta_index]),
            feedback=rule.feedback,
            theta_index=theta_index,
        )
        state = core.FusionState(np.zeros(n_t), np.zeros(n_t), np.zeros(1))
        records = (self._slow._records, self._fast._records, fusion, state)
        self._begin(records, dt, float(t0), settings.estimated)
        self._member_rows = self._member_outputs(1)

    def _new_output(self, n: int, store: bool) -> core.MultiOutput:
        """The fused output (the members' are :meth:`_member_outputs`)."""
        n_t = len(self._settings.estimated)
        p = len(_NAMES)
        return core.MultiOutput(
            **output_arrays(n, p),
            **two_output_arrays(n),
            states=np.zeros((n, 3)),
            gate=np.zeros((n, n_t)),
            members=np.zeros((n, 2 * n_t)),
        )

    def _member_outputs(self, n: int) -> tuple[Any, Any]:
        return self._slow._new_output(n, False), self._fast._new_output(n, False)

    def _step_sample(self, sample: Mapping[str, float]) -> None:
        """Step both members and the fusion on one sample (as :meth:`ZhaoUKF.update`)."""
        inputs, outputs = _sample_arrays(sample, self._where)
        arguments = (*self._records, inputs, outputs, 0, *self._member_rows, self._row)
        self._call_step("_step_kernel", arguments)

    # The C port (_zhao_native.c) runs wherever it builds, as ZhaoUKF's does.

    def _native_multi(self, out_slow: Any, out_fast: Any, out: core.MultiOutput) -> Any:
        """The C port bound to this reset's records and outputs, or None (numba runs).

        Decided once per reset and output records: a step pays no lookup.
        """
        bound = self._native
        key = (self._records, out_slow, out_fast, out)
        if bound is None or any(a is not b for a, b in zip(bound[:4], key, strict=True)):
            lib = _zhao_native.library()
            native = (
                None
                if lib is None
                else _zhao_native.NativeMulti(lib, self._records, out_slow, out_fast, out)
            )
            bound = (*key, native)
            self._native = bound
        return bound[4]

    def _run(
        self, inputs: Any, outputs: Any, out_slow: Any, out_fast: Any, out: core.MultiOutput
    ) -> None:
        native = self._native_multi(out_slow, out_fast, out)
        if native is None:
            self._run_kernel(*self._records, inputs, outputs, out_slow, out_fast, out)
        else:
            native.run(inputs, outputs)
            self._native = None  # the binding would keep a whole run's output alive

    def _call_step(self, kernel: Any, arguments: tuple) -> None:
        """One sample through the C port where it runs (else numba's, as the shell does).

        The online path (``update``: the one-row outputs) then calls the C step directly
        for the rest of the reset (``_entry``, as numba's entry point).
        """
        entry = self._entry
        if entry is not None:
            entry(*arguments)
            return
        *_, inputs, outputs, _, out_slow, out_fast, out = arguments
        native = self._native_multi(out_slow, out_fast, out)
        if native is None:
            super()._call_step(kernel, arguments)
            return
        native.step(inputs, outputs)
        if out is self._row:
            self._entry = native.entry()

    def _health(self, t: FloatArray, flag: NDArray[np.bool_], pinned: NDArray[np.bool_]) -> Any:
        """The slow member's health; the fast member's divergence when only it diverged."""
        pinned_time = self._settings.guard.pinned_time
        health = health_summary(
            self._slow._records[1].sc, t, self._dt, flag, pinned, _NAMES, pinned_time
        )
        if not health.diverged:
            fast = health_summary(
                self._fast._records[1].sc, t, self._dt, flag, pinned, _NAMES, pinned_time
            )
            if fast.diverged:
                health = dataclasses.replace(
                    fast, divergence_reason=f"fast member: {fast.divergence_reason}", stopped=False
                )
        return health

    def estimate(self, recording: Recording, *, smoother_inputs: bool = False) -> EstimationResult:
        """Run both members and the fusion over a recording from a fresh reset.

        The fused estimate is causal, sample by sample; a fixed-interval smoother does
        not apply to it (smooth the members instead), so ``smoother_inputs`` must be False.
        """
        if smoother_inputs:
            raise ValueError(
                "the multi-UKF's fused estimate has no smoother; smooth a member "
                "(ZhaoUKF(...).estimate(recording, smooth=True)) instead"
            )
        inputs, outputs = _driving_signals(recording)
        speed = _recording_speed(self._settings.speed, recording)
        output_max = None
        if self._settings.noise.output_error_ratios is not None:
            with np.errstate(invalid="ignore"):
                output_max = tuple(float(np.nanmax(np.abs(outputs[:, i]))) for i in range(2))
        self.reset(recording.dt, speed=speed, output_max=output_max, t0=float(recording.t[0]))
        n = len(recording)
        out = self._new_output(n, False)
        self._run(inputs, outputs, *self._member_outputs(n), out)
        self._k = n
        settings = self._settings
        names = settings.estimated
        return self._assemble(
            np.asarray(recording.t),
            out,
            False,
            settings={
                "settings": settings.to_dict(),
                "resolved": {
                    "slow": self._slow.tuning.to_dict(),
                    "fast": self._fast.tuning.to_dict(),
                },
            },
            state_names=(
                *STATE_NAMES,
                *(f"slow.{name}" for name in names),
                *(f"fast.{name}" for name in names),
                *(f"gate.{name}" for name in names),
            ),
            states=np.column_stack([out.states, out.members, out.gate]),
        )
