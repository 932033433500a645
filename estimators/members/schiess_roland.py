"""Schiess & Roland (1975): joint EKF on the delayed pilot model, two measurements.

NASA TN D-8024. The pilot ``K_1 (tau_3 s + 1) e^{-theta s} / ((tau_1 s + 1)(tau_2 s + 1))``
(eq. 1) with the second-order remnant ``1/(s^2 + alpha_1 s + alpha_2)`` (eq. 2) at the
stick, flying the plant ``K/s^2`` (eq. 3) against the disturbing function ``D``
(the target ``ft``, ``e = D - c``), written as the retarded differential-difference
equations 7-12 in the states of eq. 6,

    c, c', u, y_4 = tau_2 u' + u - (K_1 tau_3 / tau_1) e(t - theta), eta, eta',

and augmented with the seven parameters ``K_1, tau_1, tau_2, tau_3, theta, alpha_1,
alpha_2`` as constant states (eq. 14): 13 states. Two measurements (eq. 16): the stick
``delta = u + eta`` (the recorded ``u``) and the plant output ``c`` (the recorded
``y``), each with white noise of variance 0.00092 V^2. Process noise only on ``eta'``
(the remnant's white input ``w_p``).

The filter (:mod:`~manualcontrol.estimators.members._schiess_roland_core`, compiled) is the
discrete EKF of eqs. 18-22 with the Joseph form (eq. 22) and the m = 2 Cholesky solve
of the family's :func:`~manualcontrol.estimators.filters.kalman.joseph_correct`; the
adaptive fictitious noise of the Appendix (eqs. A1-A6) is an option.

Choices where the paper leaves room, or errs
--------------------------------------------
* Eq. 20 prints ``[H P H^T - R]^-1``; read ``+R`` (the Kalman gain).
* Eq. 18 is integrated exactly over the step (the exact flow of eqs. 7-12 with the
  parameters frozen, a Taylor series of the matrix exponential to rounding), and
  ``Phi`` (eq. 19) is the exact derivative of that step. The delayed input is held
  over the step as eq. 18 writes it (``delayed_input="hold"``) or taken linear between
  its values at the step's ends (``"ramp"``, the default: second order, the true
  delayed error varies within the step; for ``q >= 1`` both ends are known).
* The series sums at most ``||A h|| = 4``, so a step of faster dynamics is split into
  substeps, composed by the chain rule, up to 1,024 of them. The paper has no bound:
  parameters are free states. A belief that would need more (a mode thousands of
  times faster than the samples: ``tau_1`` under about 1/4000 of a sample or ``tau_2``
  under 1/2000, a pole gone through zero, parameters a spike threw out) has diverged,
  and the filter stops there, reported as ``"dynamics beyond the sample rate"``,
  rather than split on for up to a second of arithmetic a sample until its values
  overflow.
* The delay is exact and hereditary (eq. 17): the delayed terms read the filtered
  ``c(t - theta | t - theta)`` and ``D(t - theta)`` from a history buffer, at
  ``q = round(theta/dt)`` samples (``delay_read="integer"``, the paper) or at the
  fractional position by the bicubic interpolation of the project's delay lines
  (``"bicubic"``, Boer & Kenyon 1998, Appendix). The delayed states are known forcing
  (the paper: no covariance with the current state). The paper gives no ``df/dtheta``:
  here ``d e(t - theta)/d theta = -de/dt(t - theta)`` (the chain rule on the delayed
  error), with ``de/dt = dD/dt - c'``: the central difference of the forcing and the
  filtered ``c'``. Before the first sample the history holds the first sample.
* Process noise: the remnant's white input is held over each sample (as the
  simulation's, :mod:`manualcontrol.pilots.remnant`) with variance ``q`` per sample (the
  paper's "variance of the process noise"); its exact discrete covariance is
  ``q G_w G_w^T``, ``G_w = int_0^dt e^(A s) e_6 ds`` (``noise_form="held"``).
  ``noise_form="paper"`` adds ``q`` to the variance of ``eta'`` per sample instead:
  that is what Table III implies the paper did (its standard deviation of ``eta'`` is
  about ``sqrt(q)`` in every case), about ``1/dt^2`` times the held noise's effect.
* Initialisation as the paper's simulated cases: ``c`` its first measurement, ``c'``
  the divided difference of the first two, ``u = 0``, ``y_4 = 0``, ``eta = delta``,
  ``eta'`` the divided difference of ``delta``; parameter standard deviations
  ``initial_std_fraction`` (10 %; case 2: 100 %) of the initial values (Table I).
  The paper's state variances (``initial_covariance="paper"``: ``R_c`` for ``c``,
  ``R_delta/2`` for ``u`` and ``eta``, eqs. 23-24, 0.1 for the others) are far
  smaller than the errors of its own rule (at 100 Hz the divided difference of ``c``
  has a standard deviation of 4.3, and the split of ``delta`` into ``u = 0`` and
  ``eta = delta`` is off by ``u``, 30 of its standard deviations at Table I's start).
  With the exact process noise the filter then pushes those errors into the
  parameters within the first second (in the suite, 9 of 20 case-4 runs diverge).
  The default ``"consistent"`` keeps the rule's values and gives them the variances
  of what it knows (:func:`initial_state_covariance`). The first sample then corrects
  that prior as every filter of the family does.
* Passes (the paper's "iterations"): a pass's final parameter estimates and their
  covariance start the next pass over the same data; the states start again by the
  rule above. ``carry="diagonal"`` (default) carries the variances only (the paper:
  "estimates and the corresponding variances"), ``"block"`` the whole parameter block,
  ``"mean"`` the means only. Passes that carry variances use the same data again as
  if it were new: the final standard deviations shrink with every pass.
* Adaptive noise (Appendix): ``"full"`` (``Gamma = [.707, 0, .5, 0, .5, 0, ...]``, both
  residuals) or ``"modified"`` (plant-output residual only, ``Gamma = [.707, 0, ...]``).
  Misprints corrected: A4's normalised residual is ``(m_j - [H y]_j)/sqrt(R_jj)``, A5
  uses ``H_j P H_i^T``, A6 ``Gamma Gamma^T``. ``qbar`` (A3, never negative) is
  estimated from each sample's predicted residual with the prior covariance before
  ``qbar`` is added, averaged over the latest ``adaptive_window`` = 20 samples, and
  added to that sample's prior (A2) before its correction.
* ``theta`` is kept in ``[0, max_delay]`` by estimate projection (the history covers
  ``max_delay``); the paper sets no limits, others may be given.
* Sample rates: the step is integrated exactly and the delay, ``max_delay`` and
  ``pinned_time`` are seconds, but two of the paper's numbers are per sample and are
  not rescaled (the suite runs at 100 Hz). ``process_noise`` ``q`` is the variance of
  each held sample of the remnant's white input, as the simulation's ``noise_variance``
  (:mod:`manualcontrol.pilots.remnant`): a continuous intensity ``q dt``, so the same
  ``q`` at 60 Hz is a remnant 100/60 times as strong as at 100 Hz (carry a value from
  ``dt_1`` to ``dt_2`` as ``q dt_1 / dt_2``); ``noise_form="paper"`` adds ``q`` a
  sample. ``adaptive_window`` counts samples: 20 is 0.2 s at 100 Hz, 0.33 s at 60 Hz.
"""

from __future__ import annotations

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
    reject_unknown,
)
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators import _pilot_core as pilot_core
from manualcontrol.estimators.members import _schiess_roland_core as core
from manualcontrol.estimators.members import _schiess_roland_native
from manualcontrol.estimators.offline.smoothing import SmootherBlock, SmootherInputs
from manualcontrol.estimators.protocol import EstimationResult
from manualcontrol.estimators.settings import GuardSettings, SettingsRecord, limit_pair
from manualcontrol.estimators.shell import (
    FilterShell,
    output_arrays,
    read_sample,
    trace_arrays,
    two_output_arrays,
)

__all__ = [
    "ADAPTIVE_MODES",
    "CARRY_MODES",
    "DELAYED_INPUTS",
    "DELAY_READS",
    "INITIAL_COVARIANCES",
    "NOISE_FORMS",
    "PAPER_INITIAL",
    "PARAMETER_NAMES",
    "STATE_NAMES",
    "InitialUncertaintySettings",
    "SchiessRoland",
    "SchiessRolandNoiseSettings",
    "SchiessRolandSettings",
    "closed_loop_eigenvalues",
    "initial_state_covariance",
    "paper_initial_states",
]

FloatArray = NDArray[np.float64]

#: The estimated parameters, in the order of eq. 14 (``y_7 .. y_13``).
PARAMETER_NAMES: tuple[str, ...] = (
    "K_1",
    "tau_1",
    "tau_2",
    "tau_3",
    "theta",
    "alpha_1",
    "alpha_2",
)
#: The dynamic states of eq. 6 (``y_1 .. y_6``): ``c, c', u, y_4, eta, eta'``;
#: ``u_pilot`` is the paper's deterministic pilot output ``u`` (the recorded ``u`` is
#: the stick ``delta = u + eta``).
DYNAMIC_STATES: tuple[str, ...] = ("c", "c_rate", "u_pilot", "y4", "eta", "eta_rate")
#: Recorded state traces: the dynamic states and ``q_adaptive``, the adaptive fictitious
#: noise variance added to the prior (A2; 0 when adaptive noise is off).
STATE_NAMES: tuple[str, ...] = (*DYNAMIC_STATES, "q_adaptive")
#: Table I, the initial estimates of the simulated cases.
PAPER_INITIAL: Mapping[str, float] = MappingProxyType(
    {
        "K_1": 1.1,
        "tau_1": 0.09,
        "tau_2": 0.12,
        "tau_3": 0.6,
        "theta": 0.04,
        "alpha_1": 4.0,
        "alpha_2": 10.5,
    }
)
DELAY_READS: tuple[str, ...] = ("integer", "bicubic")
DELAYED_INPUTS: tuple[str, ...] = ("hold", "ramp")
ADAPTIVE_MODES: tuple[str, ...] = ("off", "full", "modified")
#: What a pass hands the next: the final means and variances (``"diagonal"``, the
#: paper's "estimates and the corresponding variances"), means and the whole parameter
#: block (``"block"``), or the means only, the covariance starting again from its
#: initial value (``"mean"``: each pass re-linearises about the last estimates
#: without counting the same data twice, so the final standard deviations stay those
#: of one pass).
CARRY_MODES: tuple[str, ...] = ("diagonal", "block", "mean")
NOISE_FORMS: tuple[str, ...] = ("held", "paper")
INITIAL_COVARIANCES: tuple[str, ...] = ("consistent", "paper")
#: The adaptive technique's noise-input vectors (Appendix).
GAMMA_FULL = (0.707, 0.0, 0.5, 0.0, 0.5, 0.0)
GAMMA_MODIFIED = (0.707, 0.0, 0.0, 0.0, 0.0, 0.0)
_ADAPTIVE_CODES = {"off": core.ADAPTIVE_OFF, "full": core.ADAPTIVE_FULL}
_ADAPTIVE_CODES["modified"] = core.ADAPTIVE_MODIFIED


def _mapping(name: str, value: Any, allowed: tuple[str, ...], convert: Any) -> Mapping[str, Any]:
    if value is None:
        return MappingProxyType({})
    if not isinstance(value, Mapping):
        raise TypeError(f"{name} must be a mapping of names to values, got {value!r}")
    reject_unknown(name, value, allowed)
    return MappingProxyType({key: convert(f"{name}[{key!r}]", item) for key, item in value.items()})


@dataclass(frozen=True)
class SchiessRolandNoiseSettings(SettingsRecord):
    """The filter's noise: the remnant's process noise, the measurements', the adaptive noise.

    A group of :class:`SchiessRolandSettings` (``noise=``); each field is also accepted
    flat by the name in brackets (its own where none is given), the one error messages
    use: ``process_noise=576`` is ``noise={"process": 576}``.

    Parameters
    ----------
    process : float
        (``process_noise``) ``q`` (>= 0): variance of each held sample of the remnant's
        white input (V^2/s^4; the paper's cases 59,600, 576 and 25). A per-sample figure
        (module docstring, "Sample rates").
    form : {"held", "paper"}
        (``noise_form``) How ``q`` enters the prior (module docstring,
        :data:`NOISE_FORMS`).
    measurement_variance : (float, float)
        Variances (> 0) of the stick and the plant-output measurements, 0.00092 V^2 each.
    adaptive : {"off", "full", "modified"}
        The Appendix's adaptive fictitious noise.
    adaptive_window : int
        Samples over which ``qbar`` is averaged (>= 1), 20.
    """

    tuple_fields: ClassVar[tuple[str, ...]] = ("measurement_variance",)
    flat_names: ClassVar[Mapping[str, str]] = {"process": "process_noise", "form": "noise_form"}

    process: float = 59600.0
    form: str = "held"
    measurement_variance: tuple[float, float] = (0.00092, 0.00092)
    adaptive: str = "off"
    adaptive_window: int = 20

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "process", check_positive("process_noise", self.process, allow_zero=True)
        )
        check_choice("noise_form", self.form, NOISE_FORMS)
        try:
            pair = tuple(self.measurement_variance)
        except TypeError:
            pair = ()
        if len(pair) != 2:
            raise ValueError(
                f"measurement_variance must be a pair (stick, plant output) of variances, "
                f"got {self.measurement_variance!r}"
            )
        object.__setattr__(
            self,
            "measurement_variance",
            (
                check_positive("measurement_variance[0]", pair[0]),
                check_positive("measurement_variance[1]", pair[1]),
            ),
        )
        check_choice("adaptive", self.adaptive, ADAPTIVE_MODES)
        object.__setattr__(
            self, "adaptive_window", check_int("adaptive_window", self.adaptive_window, minimum=1)
        )


@dataclass(frozen=True)
class InitialUncertaintySettings(SettingsRecord):
    """The filter's initial covariance: of the parameters and of the dynamic states.

    A group of :class:`SchiessRolandSettings` (``uncertainty=``); each field is also
    accepted flat by the name in brackets (its own where none is given), the one error
    messages use: ``initial_covariance="paper"`` is ``uncertainty={"states": "paper"}``.

    Parameters
    ----------
    initial_std_fraction : float
        Initial standard deviation of each parameter as a fraction of its initial
        value (> 0): 0.1 (the paper's 10 %), 1.0 (case 2).
    P0 : Mapping[str, float]
        Initial variances (> 0) of some parameters, replacing the fraction's.
    states : {"consistent", "paper"}
        (``initial_covariance``) Initial covariance of the dynamic states
        (:func:`initial_state_covariance`, :data:`INITIAL_COVARIANCES`).
    initial_state_variance : float
        ``"paper"``: initial variance (> 0) of ``c'``, ``y_4`` and ``eta'``, 0.1.
    split_variance : float
        ``"consistent"``: the variance (> 0) of the unknown split of the first stick
        sample into ``u`` and ``eta`` (V^2), 1.
    """

    tuple_fields: ClassVar[tuple[str, ...]] = ()
    flat_names: ClassVar[Mapping[str, str]] = {"states": "initial_covariance"}

    initial_std_fraction: float = 0.1
    P0: Mapping[str, float] = field(default_factory=dict)
    states: str = "consistent"
    initial_state_variance: float = 0.1
    split_variance: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(
            self,
            "initial_std_fraction",
            check_positive("initial_std_fraction", self.initial_std_fraction),
        )
        object.__setattr__(self, "P0", _mapping("P0", self.P0, PARAMETER_NAMES, check_positive))
        check_choice("initial_covariance", self.states, INITIAL_COVARIANCES)
        object.__setattr__(
            self,
            "initial_state_variance",
            check_positive("initial_state_variance", self.initial_state_variance),
        )
        object.__setattr__(
            self, "split_variance", check_positive("split_variance", self.split_variance)
        )


@dataclass(frozen=True)
class SchiessRolandSettings(SettingsRecord):
    """Settings of the :class:`SchiessRoland` filter (frozen; vary with ``replace``).

    The filter's noise and its initial covariance are groups (``noise``,
    ``uncertainty``), as are its guards (``guard``); suite files, ``--set`` and keyword
    arguments give each of their fields by its flat name (``process_noise=576``,
    ``initial_std_fraction=1.0``, ``jitter=1e-9``) or a group as a table, and
    ``to_dict`` writes the nested form.

    Parameters
    ----------
    initial : Mapping[str, float]
        Initial parameter estimates; missing ones from :data:`PAPER_INITIAL` (Table I).
        ``tau_1``, ``tau_2`` must be non-zero (they divide in eqs. 9-10).
    estimated : tuple of str or None
        Parameters to estimate (None: all seven); the others are held at their initial
        values (variance 0).
    plant_gain : float
        ``K`` of the plant ``K/s^2`` (> 0), 10 s^-2.
    initial_states : Mapping[str, float]
        Initial values of some of :data:`DYNAMIC_STATES`, replacing the paper's rule.
    delay_read : {"integer", "bicubic"}
        How the delayed terms are read from the history (module docstring).
    delayed_input : {"hold", "ramp"}
        The delayed input over a step: held (eq. 18) or linear between its ends.
    passes : int
        Passes over the data in :meth:`SchiessRoland.estimate` (>= 1).
    carry : {"diagonal", "block", "mean"}
        What of the parameter belief starts the next pass (:data:`CARRY_MODES`).
    max_delay : float
        Longest delay the history holds (s, > 0); ``theta`` is kept in ``[0, max_delay]``.
    limits : Mapping[str, (low, high)]
        Estimate-projection limits of parameters (theta's replaces ``[0, max_delay]``
        and must lie inside it).
    noise : SchiessRolandNoiseSettings
        ``process_noise`` (``q``), ``noise_form``, ``measurement_variance``, ``adaptive``
        and ``adaptive_window`` (:class:`SchiessRolandNoiseSettings`).
    uncertainty : InitialUncertaintySettings
        The initial covariance: ``initial_std_fraction``, ``P0``, ``initial_covariance``,
        ``initial_state_variance`` and ``split_variance``
        (:class:`InitialUncertaintySettings`).
    guard : GuardSettings
        ``jitter``, ``max_covariance`` (1e10 here) and ``pinned_time``, each also by its
        own name (:class:`~manualcontrol.estimators.settings.GuardSettings`).

    """

    tuple_fields: ClassVar[tuple[str, ...]] = ("estimated",)
    pair_mapping_fields: ClassVar[tuple[str, ...]] = ("limits",)
    groups: ClassVar[tuple[str, ...]] = ("noise", "uncertainty", "guard")

    initial: Mapping[str, float] = field(default_factory=dict)
    estimated: tuple[str, ...] | None = None
    plant_gain: float = 10.0
    initial_states: Mapping[str, float] = field(default_factory=dict)
    delay_read: str = "integer"
    delayed_input: str = "ramp"
    passes: int = 1
    carry: str = "diagonal"
    max_delay: float = 0.5
    limits: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    noise: SchiessRolandNoiseSettings = field(default_factory=SchiessRolandNoiseSettings)
    uncertainty: InitialUncertaintySettings = field(default_factory=InitialUncertaintySettings)
    guard: GuardSettings = field(default_factory=lambda: GuardSettings(max_covariance=1e10))

    def __post_init__(self) -> None:
        initial = dict(PAPER_INITIAL)
        initial.update(_mapping("initial", self.initial, PARAMETER_NAMES, check_real))
        for name in ("tau_1", "tau_2"):
            if initial[name] == 0.0:
                raise ValueError(f"initial {name} must be non-zero (it divides in eqs. 9-10)")
        object.__setattr__(self, "initial", MappingProxyType(initial))
        if self.estimated is not None:
            if isinstance(self.estimated, str):
                raise TypeError(
                    f"estimated must be a tuple of parameter names, got {self.estimated!r}"
                )
            estimated = tuple(self.estimated)
            reject_unknown("estimated", estimated, PARAMETER_NAMES)
            if len(set(estimated)) != len(estimated):
                raise ValueError(f"estimated names a parameter twice: {estimated}")
            object.__setattr__(self, "estimated", estimated)
        object.__setattr__(self, "plant_gain", check_positive("plant_gain", self.plant_gain))
        object.__setattr__(
            self,
            "initial_states",
            _mapping("initial_states", self.initial_states, DYNAMIC_STATES, check_real),
        )
        check_choice("delay_read", self.delay_read, DELAY_READS)
        check_choice("delayed_input", self.delayed_input, DELAYED_INPUTS)
        object.__setattr__(self, "passes", check_int("passes", self.passes, minimum=1))
        check_choice("carry", self.carry, CARRY_MODES)
        object.__setattr__(self, "max_delay", check_positive("max_delay", self.max_delay))
        limits = _mapping("limits", self.limits, PARAMETER_NAMES, limit_pair)
        if "theta" in limits:
            low, high = limits["theta"]
            if low < 0.0 or high > self.max_delay:
                raise ValueError(
                    f"limits['theta'] must lie inside [0, max_delay = {self.max_delay:g}] s "
                    f"(the history covers max_delay), got {limits['theta']!r}"
                )
        object.__setattr__(self, "limits", limits)
        resolved = self.resolved_limits()
        for name in self.estimated_names():
            if name in resolved:
                low, high = resolved[name]
                if not low <= initial[name] <= high:
                    raise ValueError(
                        f"initial {name} = {initial[name]!r} lies outside its limits "
                        f"[{low:g}, {high:g}]"
                    )
        self._require_groups(("noise", "uncertainty", "guard"))

    def estimated_names(self) -> tuple[str, ...]:
        """The estimated parameters, in :data:`PARAMETER_NAMES` order."""
        chosen = PARAMETER_NAMES if self.estimated is None else self.estimated
        return tuple(name for name in PARAMETER_NAMES if name in chosen)

    def resolved_limits(self) -> dict[str, tuple[float, float]]:
        """Limits in use: ``theta`` in ``[0, max_delay]`` unless given, plus ``limits``."""
        return {"theta": (0.0, self.max_delay), **dict(self.limits)}

    def initial_variances(self) -> dict[str, float]:
        """Initial variance of every estimated parameter."""
        uncertainty = self.uncertainty
        out = {}
        for name in self.estimated_names():
            default = (uncertainty.initial_std_fraction * self.initial[name]) ** 2
            out[name] = uncertainty.P0.get(name, default)
            if not out[name] > 0.0:
                raise ValueError(
                    f"the initial variance of {name} is 0 (its initial value is 0): give "
                    f"P0={{{name!r}: ...}}"
                )
        return out


def initial_state_covariance(
    settings: SchiessRolandSettings, dt: float, tau_2: float
) -> FloatArray:
    """Initial covariance (6, 6) of the dynamic states (``initial_covariance``).

    ``"paper"``: ``R_c`` for ``c``, ``R_delta/2`` for ``u`` and ``eta`` (eqs. 23-24), the
    ``initial_state_variance`` for ``c'``, ``y_4``, ``eta'``, no correlations.
    ``"consistent"``: the uncertainty of what the paper's rule actually knows. ``c' =
    (c_1 - c_0)/dt`` has variance ``2 R_c/dt^2`` and covariance ``-R_c/dt`` with ``c``;
    the split of the measured stick ``delta = u + eta`` is unknown: ``u = 0`` with
    variance ``V`` (``split_variance``), ``eta = delta_0 - u`` with ``V + R_delta`` and
    covariance ``-V``; ``y_4`` has ``V``; ``eta' = delta' - u'`` has ``2 R_delta/dt^2``
    (from ``delta_0``, ``delta_1``: covariance ``-R_delta/dt`` with ``eta``) plus the
    unknown ``u'``, taken on the scale of ``u`` over the pilot's lag, ``V/tau_2^2``.
    The paper's variances are far smaller than the errors of its own rule (its ``c'``
    is 4 standard deviations of the divided difference off at 100 Hz, its split of
    ``delta`` 30): with the exact process noise the filter then pushes those errors
    into the parameters in the first second, see the module docstring.
    """
    r_stick, r_plant = settings.noise.measurement_variance
    uncertainty = settings.uncertainty
    P = np.zeros((core.N_DYNAMIC, core.N_DYNAMIC))
    if uncertainty.states == "paper":
        P[core.I_C, core.I_C] = r_plant  # the plant output is measured
        P[core.I_U, core.I_U] = P[core.I_ETA, core.I_ETA] = 0.5 * r_stick  # eqs. 23-24
        for i in (core.I_C_RATE, core.I_Y4, core.I_ETA_RATE):
            P[i, i] = uncertainty.initial_state_variance
        return P
    split = uncertainty.split_variance
    P[core.I_C, core.I_C] = r_plant
    P[core.I_C_RATE, core.I_C_RATE] = 2.0 * r_plant / dt**2
    P[core.I_C, core.I_C_RATE] = P[core.I_C_RATE, core.I_C] = -r_plant / dt
    P[core.I_U, core.I_U] = split
    P[core.I_ETA, core.I_ETA] = split + r_stick
    P[core.I_U, core.I_ETA] = P[core.I_ETA, core.I_U] = -split
    P[core.I_Y4, core.I_Y4] = split
    P[core.I_ETA_RATE, core.I_ETA_RATE] = 2.0 * r_stick / dt**2 + split / tau_2**2
    P[core.I_ETA, core.I_ETA_RATE] = P[core.I_ETA_RATE, core.I_ETA] = -r_stick / dt
    return P


def closed_loop_eigenvalues(
    parameters: Mapping[str, float], plant_gain: float = 10.0
) -> NDArray[np.complex128]:
    """Eigenvalues of the closed loop with the first-order Padé delay (the paper's ``A'``).

    The stability check of Schiess & Roland (their Table VI): the pilot of eq. 1 with
    ``e^{-theta s} ~ (1 - theta s/2)/(1 + theta s/2)`` closing the loop around
    ``K/s^2``, which gives the roots of
    ``s^2 (tau_1 s + 1)(tau_2 s + 1)(theta s/2 + 1) + K K_1 (tau_3 s + 1)(1 - theta s/2)``,
    and the remnant filter's poles, roots of ``s^2 + alpha_1 s + alpha_2`` (the remnant
    is outside the loop). Seven eigenvalues, sorted by real then imaginary part; the
    system is stable when every real part is negative.
    """
    reject_unknown("parameters", parameters, PARAMETER_NAMES)
    missing = [name for name in PARAMETER_NAMES if name not in parameters]
    if missing:
        raise ValueError(f"parameters lacks {', '.join(missing)}")
    p = {name: check_real(f"parameters[{name!r}]", parameters[name]) for name in PARAMETER_NAMES}
    gain = check_positive("plant_gain", plant_gain)
    half = 0.5 * p["theta"]
    lags = np.polymul(np.polymul([p["tau_1"], 1.0], [p["tau_2"], 1.0]), [half, 1.0])
    lead = gain * p["K_1"] * np.polymul([p["tau_3"], 1.0], [-half, 1.0])
    loop = np.polyadd(np.polymul([1.0, 0.0, 0.0], lags), lead)
    roots = np.concatenate((np.roots(loop), np.roots([1.0, p["alpha_1"], p["alpha_2"]])))
    return np.array(sorted(roots, key=lambda z: (z.real, z.imag)))


def paper_initial_states(
    stick: tuple[float, float], plant: tuple[float, float], dt: float
) -> dict[str, float]:
    """The paper's initial states from the first two samples of each measurement.

    ``c`` the first plant output, ``c'`` its divided difference, ``u = y_4 = 0``,
    ``eta`` the first stick sample and ``eta'`` its divided difference.
    """
    dt = check_positive("dt", dt)
    values = {"stick[0]": stick[0], "stick[1]": stick[1], "plant[0]": plant[0]}
    values["plant[1]"] = plant[1]
    for name, value in values.items():
        if isinstance(value, (float, np.floating)) and math.isnan(value):
            raise ValueError(
                f"{name} is missing (NaN): the paper's initial states need the first two "
                "samples of the stick u and the plant output y; give initial_states instead"
            )
        check_real(name, value)
    return {
        "c": float(plant[0]),
        "c_rate": (float(plant[1]) - float(plant[0])) / dt,
        "u_pilot": 0.0,
        "y4": 0.0,
        "eta": float(stick[0]),
        "eta_rate": (float(stick[1]) - float(stick[0])) / dt,
    }


class SchiessRoland(FilterShell):
    """Joint EKF of Schiess & Roland (1975) with exact delay and adaptive noise.

    Parameters
    ----------
    settings
        A :class:`SchiessRolandSettings`; keyword arguments replace its fields (or
        build one).

    Examples
    --------
    >>> from manualcontrol.pilots import Pilot, SchiessRolandRemnant, simulate
    >>> pilot = Pilot("schiess-roland", remnant=SchiessRolandRemnant(noise_variance=25.0))
    >>> recording = simulate(pilot, "schiess-roland1975", "schiess-roland1975", run_in=0.0,
    ...                      measurement_time=15.0, seed=0,
    ...                      measurement_noise={"u": 0.00092, "y": 0.00092})
    >>> result = SchiessRoland(process_noise=25.0, passes=3).estimate(recording)
    >>> result.outputs, result.passes
    (('u', 'y'), 3)
    >>> abs(result.final()["tau_3"] - 0.5) < 0.1
    True

    """

    name = "schiess-roland"
    settings_type = SchiessRolandSettings
    outputs = ("u", "y")
    # the forcing D, the stick and the plant output
    _sample_keys = ("ft", "u", "y")

    #: The binding of this member's C port (envs/_native.py builds it).
    _native_binding = _schiess_roland_native
    #: numba's one-sample step, read only where the C port does not take it.
    _step_kernel = LazyKernel("manualcontrol.estimators.members._schiess_roland_kernels", "sr_step")

    def __init__(self, settings: SchiessRolandSettings | None = None, **changes: Any) -> None:
        super().__init__(settings, **changes)
        self._start: dict[str, Any] = {}

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """The pilot's seven parameters (:data:`PARAMETER_NAMES`)."""
        return PARAMETER_NAMES

    def _repr_fields(self) -> Mapping[str, Any]:
        s = self._settings
        return {
            "process_noise": s.noise.process,
            "adaptive": s.noise.adaptive,
            "passes": s.passes,
        }

    # ------------------------------------------------------------------ reset

    def reset(
        self,
        dt: float = 0.01,
        *,
        initial_states: Mapping[str, float] | None = None,
        t0: float = 0.0,
        parameter_mean: Mapping[str, float] | None = None,
        parameter_covariance: Any = None,
    ) -> None:
        """Start from the initial belief.

        Parameters
        ----------
        dt
            Sample time (s).
        initial_states
            Values of the six dynamic states (:data:`DYNAMIC_STATES`); the settings'
            ``initial_states`` override them. :meth:`estimate` derives them from the
            first two samples (:func:`paper_initial_states`); online, give them.
        t0
            Time of the first sample (s).
        parameter_mean, parameter_covariance
            Start the parameters from this belief instead of the settings' (a later
            pass): means of the estimated parameters and their covariance
            (``(p, p)`` in :meth:`SchiessRolandSettings.estimated_names` order).

        """
        settings = self._settings
        dt = check_positive("dt", dt)
        t0 = check_real("t0", t0)
        states = dict(initial_states or {})
        reject_unknown("initial_states", states, DYNAMIC_STATES)
        states.update(settings.initial_states)
        missing = [name for name in DYNAMIC_STATES if name not in states]
        if missing:
            raise ValueError(
                f"reset needs initial_states for {', '.join(missing)} (the six states of "
                "eq. 6); estimate() derives them from the first two samples by the paper's "
                "rule (paper_initial_states)"
            )
        estimated = settings.estimated_names()
        x = np.zeros(core.N_STATES)
        P = np.zeros((core.N_STATES, core.N_STATES))
        for i, name in enumerate(DYNAMIC_STATES):
            x[i] = check_real(f"initial_states[{name!r}]", states[name])
        noise = settings.noise
        r_stick, r_plant = noise.measurement_variance
        P[: core.N_DYNAMIC, : core.N_DYNAMIC] = initial_state_covariance(
            settings, dt, settings.initial["tau_2"]
        )
        mean = dict(settings.initial)
        index = [core.N_DYNAMIC + PARAMETER_NAMES.index(name) for name in estimated]
        if parameter_mean is not None:
            reject_unknown("parameter_mean", parameter_mean, estimated)
            for name, value in parameter_mean.items():
                mean[name] = check_real(f"parameter_mean[{name!r}]", value)
        for j, name in enumerate(PARAMETER_NAMES):
            x[core.N_DYNAMIC + j] = mean[name]
        if parameter_covariance is None:
            variances = settings.initial_variances()
            for name, i in zip(estimated, index, strict=True):
                P[i, i] = variances[name]
        else:
            cov = np.asarray(parameter_covariance, dtype=np.float64)
            if cov.shape != (len(index), len(index)) or not np.all(np.isfinite(cov)):
                raise ValueError(
                    f"parameter_covariance must be a finite {len(index)} x {len(index)} matrix "
                    f"(estimated parameters {estimated}), got shape {cov.shape}"
                )
            P[np.ix_(index, index)] = 0.5 * (cov + cov.T)
        limits = settings.resolved_limits()
        lo = np.full(core.N_PARAMETERS, -np.inf)
        hi = np.full(core.N_PARAMETERS, np.inf)
        state_limit = np.full(core.N_STATES, -1, dtype=np.int64)
        for name, (low, high) in limits.items():
            j = PARAMETER_NAMES.index(name)
            lo[j], hi[j] = low, high
            if name in estimated:
                state_limit[core.N_DYNAMIC + j] = j
        for name in ("tau_1", "tau_2"):
            if x[core.N_DYNAMIC + PARAMETER_NAMES.index(name)] == 0.0:
                raise ValueError(f"parameter_mean[{name!r}] must be non-zero")
        cfg = np.zeros(core.CFG_SIZE)
        cfg[core.CFG_DT] = dt
        cfg[core.CFG_PLANT_GAIN] = settings.plant_gain
        cfg[core.CFG_PROCESS_NOISE] = noise.process
        cfg[core.CFG_JITTER] = settings.guard.jitter
        cfg[core.CFG_MAX_COV] = settings.guard.max_covariance
        cfg[core.CFG_BICUBIC] = 1.0 if settings.delay_read == "bicubic" else 0.0
        cfg[core.CFG_RAMP] = 1.0 if settings.delayed_input == "ramp" else 0.0
        cfg[core.CFG_ADAPTIVE] = _ADAPTIVE_CODES[noise.adaptive]
        cfg[core.CFG_MAX_DELAY] = settings.max_delay
        cfg[core.CFG_NOISE_FORM] = 1.0 if noise.form == "paper" else 0.0
        gamma = np.zeros(core.N_STATES)
        gamma[: core.N_DYNAMIC] = GAMMA_MODIFIED if noise.adaptive == "modified" else GAMMA_FULL
        config = core.SRConfig(
            cfg=cfg,
            gamma=gamma,
            state_limit=state_limit,
            estimated=np.array([name in estimated for name in PARAMETER_NAMES]),
            R=np.diag([r_stick, r_plant]),
        )
        size = math.ceil(settings.max_delay / dt) + 8
        sc = np.zeros(pilot_core.SC_SIZE)
        sc[pilot_core.SC_DIV_INDEX] = -1.0
        sc[pilot_core.SC_DIV_PARAM] = -1.0
        belief = core.SRBelief(
            x=x,
            P=P,
            sc=sc,
            hist_d=np.zeros(size),
            hist_c=np.full(size, x[core.I_C]),
            hist_rate=np.full(size, x[core.I_C_RATE]),
            q_window=np.zeros(noise.adaptive_window),
            q_sum=np.zeros(3),
            prev_d=np.zeros(1),
            in_d=np.zeros(1),
        )
        n_pin = (
            0
            if math.isinf(settings.guard.pinned_time)
            else max(1, round(settings.guard.pinned_time / dt))
        )
        watch = pilot_core.PilotMonitor(
            np.zeros(0),
            np.zeros(0),
            np.zeros(core.N_PARAMETERS, dtype=np.int64),
            np.zeros((core.N_PARAMETERS, n_pin), dtype=np.int64),
            x[core.N_DYNAMIC :].copy(),
            np.zeros(core.N_PARAMETERS),
            np.zeros(core.N_PARAMETERS, dtype=np.bool_),
        )
        report = pilot_core.PilotReport(lo, hi, np.zeros(core.N_PARAMETERS), np.ones(7))
        self._begin((config, belief, watch, report, core.new_scratch()), dt, t0, estimated)
        self._start = {
            "initial_states": {name: float(x[i]) for i, name in enumerate(DYNAMIC_STATES)},
            "parameters": {n: float(x[core.N_DYNAMIC + j]) for j, n in enumerate(PARAMETER_NAMES)},
            "parameter_variances": {
                n: float(P[i, i]) for n, i in zip(estimated, index, strict=True)
            },
        }

    def _new_output(self, n: int, store: bool) -> Any:
        rows = n if store else 0
        p, s = core.N_PARAMETERS, core.N_STATES
        return core.SROutput(
            **output_arrays(n, p),
            **two_output_arrays(n),
            states=np.zeros((n, len(STATE_NAMES))),
            **trace_arrays(rows, s),
            Phi=np.zeros((rows, s, s)),
        )

    # ----------------------------------------------------------------- update

    def _step_sample(self, sample: Mapping[str, float]) -> None:
        """Step on one sample: ``ft`` (the forcing ``D``), ``u`` (stick), ``y`` (plant output).

        NaN in ``u`` or ``y`` corrects with the other measurement only; NaN in both, or
        in ``ft`` (held at its last value), drops the sample.
        """
        values = read_sample(sample, self._sample_keys, self._where)
        arguments = (*self._records, values["ft"], values["u"], values["y"], 0, self._row)
        self._call_step("_step_kernel", arguments)

    # The C port of the compiled path (_schiess_roland_native.c) runs wherever it builds:
    # the same numbers bit for bit as the numba kernels, which run elsewhere
    # (envs/_native.py).

    def _run(self, d: FloatArray, u: FloatArray, y: FloatArray, out: Any) -> None:
        native = self._native_records(out)
        if native is None:
            core.sr_run(*self._records, d, u, y, out)
        else:
            native.run(d, u, y)
            self._native = None  # the binding would keep a whole run's output alive

    def _call_step(self, kernel: Any, arguments: tuple) -> None:
        """One sample through the C port where it runs (else numba's, as the shell does).

        The online path (``update``: the one-row output) then calls the C step directly
        for the rest of the reset (``_entry``, as numba's entry point).
        """
        if self._entry is not None:
            self._entry(*arguments)
            return
        *_, d, u, y, row, out = arguments
        native = self._native_records(out)
        if native is None:
            super()._call_step(kernel, arguments)
            return
        native.step(d, u, y, row)
        if out is self._row and row == 0:
            self._entry = native.entry()

    # --------------------------------------------------------------- estimate

    def signals(self, recording: Recording) -> dict[str, FloatArray]:
        """The sample signals :meth:`estimate` feeds the filter: ``ft``, ``u``, ``y``."""
        if not isinstance(recording, Recording):
            raise TypeError(f"recording must be a Recording, got {recording!r}")
        missing = [name for name in self.sample_keys if name not in recording]
        if missing:
            raise ValueError(
                f"the recording lacks {', '.join(missing)}: the filter reads the forcing ft, "
                "the stick u and the plant output y"
            )
        return {name: np.ascontiguousarray(recording[name]) for name in self.sample_keys}

    def initial_states_of(self, recording: Recording) -> dict[str, float]:
        """The paper's initial states from the recording's first two samples."""
        if len(recording) < 2:
            raise ValueError(
                f"the recording has {len(recording)} sample(s); the paper's initial states "
                "need two (divided differences)"
            )
        signals = self.signals(recording)
        u, y = signals["u"], signals["y"]
        return paper_initial_states((u[0], u[1]), (y[0], y[1]), recording.dt)

    def estimate(
        self,
        recording: Recording,
        *,
        smoother_inputs: bool = False,
        smooth: bool = False,
    ) -> EstimationResult:
        """Run ``passes`` passes over a recording (each from a fresh reset of the states).

        The traces are the last pass's; ``pass_mean``/``pass_std`` hold each pass's
        final estimates. ``smoother_inputs`` keeps what
        :func:`~manualcontrol.estimators.offline.smoothing.smooth` needs (of the last pass);
        ``smooth`` returns the smoothed result.
        """
        signals = self.signals(recording)
        settings = self._settings
        dt = recording.dt
        t0 = float(recording.t[0])
        states = self.initial_states_of(recording) if len(settings.initial_states) < 6 else None
        estimated = settings.estimated_names()
        index = [PARAMETER_NAMES.index(name) for name in estimated]
        carried: dict[str, Any] = {}
        pass_mean, pass_std, starts = [], [], []
        n = len(recording)
        store = bool(smoother_inputs or smooth)
        out = None
        for number in range(settings.passes):
            self.reset(dt, initial_states=states, t0=t0, **carried)
            starts.append(self._start)
            last = number == settings.passes - 1
            out = self._new_output(n, store=store and last)
            self._run(signals["ft"], signals["u"], signals["y"], out)
            pass_mean.append(out.mean[-1].copy())
            pass_std.append(out.std[-1].copy())
            if self._records[1].sc[pilot_core.SC_FROZEN] > 0.0:
                break  # a diverged pass ends the iterations
            P = self._records[1].P
            block = P[core.N_DYNAMIC :, core.N_DYNAMIC :][np.ix_(index, index)]
            covariance = block if settings.carry == "block" else np.diag(np.diag(block))
            carried = {
                "parameter_mean": {
                    name: float(self._records[1].x[core.N_DYNAMIC + j])
                    for name, j in zip(estimated, index, strict=True)
                },
                "parameter_covariance": None if settings.carry == "mean" else covariance.copy(),
            }
        self._k = n
        result = self._assemble(
            np.asarray(recording.t),
            out,
            store,
            settings={
                "settings": settings.to_dict(),
                "model": "schiess-roland",
                "passes": starts,
            },
            state_names=STATE_NAMES,
            states=out.states,
            passes=len(pass_mean),
            pass_mean=np.array(pass_mean),
            pass_std=np.array(pass_std),
        )
        return self._finish(result, smooth)

    def _smoother_inputs(self, out: Any) -> Any:

        block = SmootherBlock.of_trace(
            "ekf",
            out,
            out.Phi,
            parameters={name: core.N_DYNAMIC + j for j, name in enumerate(PARAMETER_NAMES)},
            states={name: i for i, name in enumerate(DYNAMIC_STATES)},
        )
        report = self._records[3]
        return SmootherInputs.of_report((block,), PARAMETER_NAMES, report)
