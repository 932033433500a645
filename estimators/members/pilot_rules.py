"""The settings rules of the members on pilot internal models: limits, starts, noise.

The DEKF, the RML and the joint and dual UKF (:mod:`~manualcontrol.estimators.members.pilot_filter`)
take the same settings (:class:`PilotFilterSettings`, each member adds its own) and
resolve them by the same rules into every number a run uses
(:func:`resolve_settings` -> :class:`ResolvedSettings`): the noise rules (Popovici eqs.
24-25, thesis eqs. 29-30), the initial values, covariances and limits (Popovici eqs.
25-34, thesis Sec. V-B and Table I, or the experiment's element and human ranges), the
parameters held by design, and the generic values held unmeasured
(:class:`GenericValuesWarning`). :class:`ParameterMap` converts between reported and
internal parameter values (the preview time as the apparent delay ``tau_f* = tau_a -
tau_f``, thesis eq. 26): the one place that converts.

Settings rules, with the papers' defaults
-----------------------------------------
* ``q2``, ``r2``: ``Q_s`` at the chain input state is ``q^2 var(e)`` and
  ``R = r^2 var(u)``, variances over the last ``window`` = 5 s (Popovici eqs. 24-25,
  thesis eqs. 29-30), over the first 5 s before that (eq. 34); q^2 = 0.4, r^2 = 0.7
  (Popovici Sec. III-B; the thesis used r^2 = 4 for DI preview data with remnant).
* ``preset``: ``"popovici2017"`` (eqs. 25-26, 32-33: ``P_s0`` 0.1 for canonical
  states, 10 for gains and frequencies, 1 otherwise; ``Q`` 100 % of the initial value
  for gains, 10 % otherwise), ``"vertregt2020"`` (thesis Sec. V-B: ``P_0 = (p
  theta_0)^2`` with p = 0.1 for omega_nms and 0.5 otherwise; ``Q = q_theta theta_0``
  with 5 % for gains and delays and 2.5 % for frequencies and damping) and
  ``"vertregt2020-remnant"`` (the same with r^2 = 4 for DI).
* initial values: Popovici's generic rules eqs. 27-31 for whatever ``initial`` leaves
  out: ``K_p0 = sigma_u/sigma_e``, ``K_v0 = 0.5 K_p0`` (0 for SI), ``omega_nms0 = 10``,
  ``zeta_nms0 = 0.3``, ``tau_v0 = 0.3``; for the preview model (no rule in the thesis,
  which started at the true values) ``K_f0 = 1``, ``omega_f0`` its nominal value
  (3.3 rad/s; 1 rad/s for ``ce="DI"``, where the thesis's DI benchmark started,
  :data:`DI_FAR_BREAK`) and ``tau_f0 = tau_a/2``, the middle of its limits. A
  parameter left out of ``estimated`` as well stays at that value all run, a value no
  one measured for this pilot: the filter says so when it is built
  (:class:`GenericValuesWarning`, :func:`held_without_values`).
* ``limits``: estimate projection (thesis eqs. 20, 25, 27-28) with Table I for the
  ``ce`` type (``"SI"``/``"DI"``); without a CE type the union of both columns (the
  structure's human ranges); ``tau_f*`` always within ``[0.1, tau_a - 0.1]``.
* single-integrator tasks (``ce="SI"``) hold ``K_v`` (at 0) and ``omega_f`` constant,
  as the thesis did; parameters held constant are removed from the filters (thesis
  Sec. III-A) and reported with standard deviation 0.
* variances are population variances (``ddof=0``) of the ``N + 1`` samples
  ``k - N .. k`` (``N = window/dt``), NaN samples left out.
* ``Gamma = I dt`` (``noise_input="euler"``): the "discrete input identity matrices"
  (Popovici eq. 19) read as the Euler discretisation of the identity noise input of
  eqs. 2 and 4, so ``Gamma Q Gamma^T = Q dt^2``; ``noise_input="identity"`` takes
  ``Gamma = I``.
* ``Q`` for ``K_v`` is ``K_v0`` (Popovici eq. 25 and its rule of thumb; its text once
  says ``0.1 K_v0``).
"""

from __future__ import annotations

import functools
import math
import sys
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import (
    check_choice,
    check_int,
    check_positive,
    check_real,
)
from manualcontrol.envs.elements import (
    ControlledElement,
    DoubleIntegrator,
    Integrator,
    make_element,
)
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair, Multisine
from manualcontrol.estimators.analysis.frequency import describing_function
from manualcontrol.estimators.members.internal_model import (
    ANTICIPATED_PARAMETER,
    InternalModel,
    build_internal_model,
)
from manualcontrol.estimators.settings import (
    GuardSettings,
    SettingsRecord,
    limit_pair,
    to_json_value,
)
from manualcontrol.pilots.models import (
    CROSSOVER_RANGE,
    MODEL_NAMES,
    element_gain_ranges,
    make_model,
)

__all__ = [
    "CE_TYPES",
    "CROSSOVER_RANGE",
    "DESCRIBED_START",
    "DI_FAR_BREAK",
    "GENERIC_INITIAL",
    "HUMAN_RANGES",
    "INITIAL_VARIANCE_MODES",
    "LIMIT_CHOICES",
    "MAX_DELAY_ORDER",
    "NOISE_INPUTS",
    "PRESETS",
    "STARTS",
    "TABLE_I",
    "TAU_F_MARGIN",
    "GenericValuesWarning",
    "ParameterMap",
    "PilotFilterSettings",
    "ResolvedSettings",
    "default_limits",
    "element_type",
    "held_by_design",
    "held_without_values",
    "human_limits",
    "internal_model",
    "resolve_settings",
    "run_describing_function",
    "warn_held_without_values",
]

FloatArray = NDArray[np.float64]


#: Controlled-element types with Table I limits.
CE_TYPES: tuple[str, ...] = ("SI", "DI")
#: Initialisation presets.
PRESETS: tuple[str, ...] = ("popovici2017", "vertregt2020", "vertregt2020-remnant")
INITIAL_VARIANCE_MODES: tuple[str, ...] = ("first-window", "causal")
#: Highest Padé order of the internal model's delays. The canonical-form coefficients
#: grow like (2m)!/(m! tau^m): at order 5 with tau 0.2 s they are near 1e7, the
#: canonical-state variances start near 1e18 from the 0.1 of Popovici eq. 32, and the
#: covariance loses positive definiteness within a fraction of a second (measured on
#: the Popovici compensatory run). Order 4 runs but identifies worse than order 3.
MAX_DELAY_ORDER = 4

#: Discrete noise-input matrices Gamma_s, Gamma_p (Popovici eq. 19): ``"euler"``
#: ``Gamma = I dt``, the Euler discretisation of the identity noise input of eqs. 2 and 4
#: (``Gamma Q Gamma^T = Q dt^2``); ``"identity"``: ``Gamma = I`` (``Q`` per sample).
NOISE_INPUTS: tuple[str, ...] = ("euler", "identity")

#: Thesis Part I Table I, HO parameter limits per CE type (model units). ``tau_f`` is
#: limited through ``tau_f* = tau_a - tau_f`` in ``[0.1, tau_a - 0.1]``, which is the same
#: interval for ``tau_f``; "n/a" entries (SI ``omega_f``, ``K_v``) are absent.
TABLE_I: Mapping[str, Mapping[str, tuple[float, float]]] = MappingProxyType(
    {
        "SI": MappingProxyType(
            {
                "K_f": (0.2, 2.5),
                "K_p": (0.2, 2.5),
                "omega_nms": (6.0, 15.0),
                "zeta_nms": (0.1, 0.8),
                "tau_v": (0.1, 0.8),
            }
        ),
        "DI": MappingProxyType(
            {
                "K_f": (0.2, 2.5),
                "omega_f": (0.1, 10.0),
                "K_p": (0.05, 1.0),
                "K_v": (0.05, 1.5),
                "omega_nms": (6.0, 15.0),
                "zeta_nms": (0.1, 0.8),
                "tau_v": (0.1, 0.8),
            }
        ),
    }
)
#: Distance of the ``tau_f*`` limits from 0 and from ``tau_a`` (Table I: 0.1 s).
TAU_F_MARGIN = 0.1
#: Where the delay and neuromuscular parameters start (``start``): the generic rules, or
#: the model fitted to the run's describing function (offline).
STARTS: tuple[str, ...] = ("generic", "describing-function")
#: The parameters a describing-function start sets: the ones the generic rules guess
#: blind (the gains' rule reads the data already, Popovici eq. 27).
DESCRIBED_START: tuple[str, ...] = ("tau_v", "omega_nms", "zeta_nms")
#: Limits choices: the thesis's Table I for ``ce``, limits from the experiment's element
#: and human ranges (:func:`human_limits`), or none.
LIMIT_CHOICES: tuple[str, ...] = ("table-I", "human", "none")
#: Ranges human tracking experiments report for the visual delay, the neuromuscular
#: frequency and damping, whatever the element (the ``"human"`` limits): wider than
#: thesis Table I, which was set for its two simulated pilots.
HUMAN_RANGES: Mapping[str, tuple[float, float]] = MappingProxyType(
    {"tau_v": (0.05, 0.6), "omega_nms": (4.0, 30.0), "zeta_nms": (0.05, 1.2)}
)
#: Initial far-view break frequency (rad/s) on the double integrator: the thesis's DI
#: benchmark started there (Part II Table 6.3, estimation 8.1); the preview model's
#: nominal 3.3 rad/s is the single integrator's, where the target is hardly filtered
#: (thesis Part I Sec. II). Started at 3.3 on DI data (55 % remnant, 30 runs, the RML
#: smoothed) the estimate stayed near it: NRMSE 1.54 against 0.21 from 1 rad/s.
DI_FAR_BREAK = 1.0
#: Popovici eqs. 29-31 and the preview extension: generic initial values.
GENERIC_INITIAL = MappingProxyType({"omega_nms": 10.0, "zeta_nms": 0.3, "tau_v": 0.3, "K_f": 1.0})
#: Order of the parameter filter's vector (Popovici eq. 39, thesis eq. 41).
_THETA_ORDER = ("omega_nms", "zeta_nms", "tau_v", "K_f", "omega_f", "tau_f")


def _kind(name: str) -> str:
    """Parameter kind for the presets: gain, delay, frequency or damping."""
    if name.startswith("K"):
        return "gain"
    if name.startswith(("tau", "theta")):
        return "delay"
    if name.startswith("omega"):
        return "frequency"
    return "damping"


def _frozen_mapping(name: str, value: Any, convert: Any) -> Mapping[str, Any]:
    if value is None:
        return MappingProxyType({})
    if not isinstance(value, Mapping):
        raise TypeError(f"{name} must be a mapping of parameter names, got {value!r}")
    out = {}
    for key, item in value.items():
        if not isinstance(key, str):
            raise TypeError(f"{name} keys must be parameter names, got {key!r}")
        out[key] = convert(f"{name}[{key!r}]", item)
    return MappingProxyType(out)


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class NoiseSettings(SettingsRecord):
    """The noise of a filter on a pilot internal model: its covariances and their sources.

    A group of :class:`PilotFilterSettings` (``noise=``); each field is also accepted by
    its own name in suite files, ``--set`` and keyword arguments (``q2=0.1``).

    Parameters
    ----------
    preset : str
        Initial covariances and process noise: one of :data:`PRESETS`.
    q2, r2 : float
        Process-noise factor of the error variance and measurement-noise factor of the
        control variance (> 0); ``r2=None`` takes the preset's value.
    window : float
        Retrospective window of the variances (s), 5 s.
    initial_variance : {"first-window", "causal"}
        Before a full window: the variances of the first window (the papers; needs
        the first ``window`` of data at reset, which ``estimate`` computes),
        or of the samples so far (a causal online start; then ``initial`` must give
        ``K_p`` for the precision and preview models).
    P0, Q : Mapping[str, float]
        Initial variance and process-noise variance per parameter (> 0; Q enters as
        ``Gamma Q Gamma^T``), replacing the preset's.
    P0_fraction, Q_fraction : Mapping[str, float]
        Per parameter, the thesis's forms with another fraction: ``P_0 = (p theta_0)^2``
        and ``Q = q theta_0`` (> 0), replacing the preset's (``P0``/``Q`` win).
    P0_canonical : float
        Initial variance of the canonical states (> 0), 0.1 (Popovici eq. 32).
    noise_input : {"euler", "identity"}
        The noise-input matrices ``Gamma``, see :data:`NOISE_INPUTS`.
    variance_floor : float
        Lower bound of the windowed variances (> 0) so ``R > 0`` on silent starts.
    fixed_R, fixed_Q_error : float or None
        Constant ``R`` and constant chain-input process noise instead of the
        windowed ones (> 0); for checks against a linear Kalman filter.

    The parameter names of ``P0``, ``Q``, ``P0_fraction`` and ``Q_fraction`` are
    checked against the model by :class:`PilotFilterSettings`, which knows it.
    """

    preset: str = "popovici2017"
    q2: float = 0.4
    r2: float | None = None
    window: float = 5.0
    initial_variance: str = "first-window"
    P0: Mapping[str, float] = field(default_factory=dict)
    Q: Mapping[str, float] = field(default_factory=dict)
    P0_fraction: Mapping[str, float] = field(default_factory=dict)
    Q_fraction: Mapping[str, float] = field(default_factory=dict)
    P0_canonical: float = 0.1
    noise_input: str = "euler"
    variance_floor: float = 1e-12
    fixed_R: float | None = None
    fixed_Q_error: float | None = None

    def __post_init__(self) -> None:
        check_choice("preset", self.preset, PRESETS)
        object.__setattr__(self, "q2", check_positive("q2", self.q2))
        if self.r2 is not None:
            object.__setattr__(self, "r2", check_positive("r2", self.r2))
        object.__setattr__(self, "window", check_positive("window", self.window))
        check_choice("initial_variance", self.initial_variance, INITIAL_VARIANCE_MODES)
        for which in ("P0", "Q", "P0_fraction", "Q_fraction"):
            values = _frozen_mapping(which, getattr(self, which), check_positive)
            for key, value in values.items():
                if value <= 0.0:
                    raise ValueError(f"{which}[{key!r}] must be > 0 (a variance), got {value!r}")
            object.__setattr__(self, which, values)
        object.__setattr__(self, "P0_canonical", check_positive("P0_canonical", self.P0_canonical))
        check_choice("noise_input", self.noise_input, NOISE_INPUTS)
        object.__setattr__(
            self, "variance_floor", check_positive("variance_floor", self.variance_floor)
        )
        for which in ("fixed_R", "fixed_Q_error"):
            value = getattr(self, which)
            if value is not None:
                object.__setattr__(self, which, check_positive(which, value))


@dataclass(frozen=True)
class PilotFilterSettings(SettingsRecord):
    """Settings shared by the filters on pilot internal models (frozen).

    The DEKF's settings (:class:`~manualcontrol.estimators.members.dekf.DEKFSettings`) and the
    unscented filters' (:mod:`~manualcontrol.estimators.members.ukf`) add their own fields to
    these; vary any of them with ``replace`` (flat keys or group tables).

    Parameters
    ----------
    model : str
        Pilot structure: ``"precision"`` (compensatory) or ``"preview"`` (far view);
        other single-channel structures (``"gain-delay"``, ``"schiess-roland"``) work
        with nominal initial values and their human ranges as limits.
    ce : {"SI", "DI"} or None
        Thesis controlled-element type: Table I limits and the SI rule (``K_v``,
        ``omega_f`` held constant). None for other dynamics (e.g. Popovici's
        ``4/(s(s+3))``): limits are the union of both columns.
    element : str, Mapping or None
        The experiment's controlled element (a preset, a transfer function in ``s`` as
        :func:`~manualcontrol.envs.elements.parse_element` reads it, or an element's
        dict): the limits then come from it and from human ranges (``"human"``,
        :func:`human_limits`), and its type (``K/s``: ``"SI"``, ``K/s^2``: ``"DI"``)
        sets ``ce``'s rules. Give ``ce`` or ``element``, not two that disagree.
    anticipation_time : float or None
        ``tau_a`` (s), required for the preview model: the target is anticipated by
        ``tau_a`` and ``tau_f`` must stay below it (thesis Sec. III-B). ``0`` fits the
        *pursuit* form: the display shows the current target and nothing ahead, the
        far-view branch reads ``ft`` itself and ``tau_f`` is held at 0 (no target
        ahead of the samples is needed).
    estimated : tuple of str or None
        Parameters to estimate; the others are held at their ``initial`` values.
        None: all (minus the SI rule).
    initial : Mapping[str, float]
        Initial values (model units; ``tau_f`` as preview time); missing ones follow
        the generic rules (module docstring).
    limits : "table-I", "human", "none", Mapping[str, (low, high)] or None
        Estimate-projection limits: Table I for ``ce``, limits from ``element`` and human
        ranges (:func:`human_limits`), none at all, or the defaults with these entries
        replaced (``(-inf, inf)`` removes one). None (default): ``"human"`` where an
        ``element`` is given, else ``"table-I"``.
    delay_order : int
        Padé order of the delays in the internal model, 1 to
        :data:`MAX_DELAY_ORDER`, 3 (the papers' choice).
    noise : NoiseSettings
        The filter's noise: preset, ``q2``/``r2``, the variances' window, initial and
        process-noise variances (:class:`NoiseSettings`; each field also by its own
        name, ``q2=0.1``).
    guard : GuardSettings
        ``jitter``, ``max_covariance``, ``pinned_time``
        (:class:`~manualcontrol.estimators.settings.GuardSettings`).
    restarts : int
        Offline only (:meth:`PilotFilter.estimate`; ``update`` ignores it): after a
        pass over the run, the filter runs again from the median of that pass's
        smoothed estimates over the last half of the run, this many times, and a
        restarted pass replaces the one kept where its innovations are clearly more
        likely (the "Restarts" section of the module docstring). 0 (default): one
        pass, the papers' filter.
    start : {"generic", "describing-function"}
        Where the delay and the neuromuscular parameters start when ``initial`` does not
        give them: the generic rules (Popovici eqs. 29-31), or (offline only,
        :meth:`PilotFilter.estimate`) the precision or preview model fitted to the run's
        describing function at the forcing frequencies
        (:func:`~manualcontrol.estimators.analysis.frequency.fit_describing_function`), the
        laboratory's own measurement of this pilot, clipped into the limits. A filter
        started far from a human's delay can settle in another optimum for the whole run.

    """

    pair_mapping_fields: ClassVar[tuple[str, ...]] = ("limits",)
    groups: ClassVar[tuple[str, ...]] = ("noise", "guard")

    model: str = "precision"
    ce: str | None = None
    element: Any = None
    anticipation_time: float | None = None
    estimated: tuple[str, ...] | None = None
    initial: Mapping[str, float] = field(default_factory=dict)
    limits: str | Mapping[str, tuple[float, float]] | None = None
    delay_order: int = 3
    restarts: int = 0
    start: str = "generic"
    noise: NoiseSettings = field(default_factory=lambda: NoiseSettings())
    guard: GuardSettings = field(default_factory=GuardSettings)

    def __post_init__(self) -> None:
        check_choice("model", self.model, MODEL_NAMES)
        model = make_model(self.model)
        names = model.parameter_names
        known = ", ".join(names)

        def check_names(what: str, keys: Any) -> None:
            unknown = [key for key in keys if key not in names]
            if unknown:
                raise ValueError(
                    f"{what}: unknown parameter(s) {', '.join(map(repr, unknown))} for the "
                    f"{self.model!r} model; its parameters are {known}"
                )

        if self.ce is not None:
            check_choice("ce", self.ce, CE_TYPES)
        if self.element is not None:
            object.__setattr__(self, "element", _element_setting(self.element))
            if self.ce is not None:
                raise ValueError(
                    f"ce={self.ce!r} (a thesis element type, Table I limits) and "
                    f"element={self.element!r} (the experiment's element, limits from it) "
                    "both given: give the experiment's element alone"
                )
        preview = "ft_far" in model.perceptions
        if preview:
            if self.anticipation_time is None:
                raise ValueError(
                    "anticipation_time (tau_a, s) is required for the preview model "
                    "(thesis Sec. III-B); the thesis used 0.9 s (SI) and 1.5 s (DI)"
                )
            tau_a = check_positive("anticipation_time", self.anticipation_time, allow_zero=True)
            if 0.0 < tau_a <= 2.0 * TAU_F_MARGIN:
                raise ValueError(
                    f"anticipation_time must be > {2.0 * TAU_F_MARGIN:g} s so that tau_f* "
                    f"can lie in [{TAU_F_MARGIN:g}, tau_a - {TAU_F_MARGIN:g}] (thesis "
                    f"Table I), or 0 for a pursuit fit; got {tau_a!r}"
                )
            object.__setattr__(self, "anticipation_time", tau_a)
        elif self.anticipation_time is not None:
            raise ValueError(
                f"anticipation_time applies to the preview model only, not {self.model!r}; "
                f"got {self.anticipation_time!r}"
            )
        if self.estimated is not None:
            if isinstance(self.estimated, str):
                raise TypeError(
                    f"estimated must be a tuple of parameter names, got {self.estimated!r}"
                )
            estimated = tuple(self.estimated)
            check_names("estimated", estimated)
            if len(set(estimated)) != len(estimated):
                raise ValueError(f"estimated names a parameter twice: {estimated}")
            object.__setattr__(self, "estimated", estimated)
        initial = _frozen_mapping("initial", self.initial, check_real)
        check_names("initial", initial)
        object.__setattr__(self, "initial", initial)
        pursuit = preview and self.anticipation_time == 0.0
        if pursuit and initial.get("tau_f", 0.0) != 0.0:
            raise ValueError(
                "a pursuit fit (anticipation_time = 0) holds tau_f at 0 (nothing is shown "
                f"ahead), got initial tau_f = {initial['tau_f']!r}"
            )
        if (
            preview
            and not pursuit
            and "tau_f" in initial
            and initial["tau_f"] >= self.anticipation_time
        ):
            raise ValueError(
                f"initial tau_f must be < anticipation_time = {self.anticipation_time:g} s "
                f"(tau_f* = tau_a - tau_f > 0, thesis eq. 26), got {initial['tau_f']!r}"
            )
        if isinstance(self.limits, str):
            check_choice("limits", self.limits, LIMIT_CHOICES)
            if self.limits == "human" and self.element is None:
                raise ValueError(
                    "limits='human' derives the gain limits from the controlled element: "
                    "give element= (e.g. '1/s')"
                )
        elif self.limits is not None:
            limits = _frozen_mapping("limits", self.limits, limit_pair)
            check_names("limits", limits)
            if preview and "tau_f" in limits and limits["tau_f"][1] >= self.anticipation_time:
                if pursuit:
                    raise ValueError(
                        "a pursuit fit (anticipation_time = 0) has no tau_f to limit, got "
                        f"limits['tau_f'] = {limits['tau_f']!r}"
                    )
                raise ValueError(
                    f"limits['tau_f'] must stay below anticipation_time = "
                    f"{self.anticipation_time:g} s, got {limits['tau_f']!r}"
                )
            object.__setattr__(self, "limits", limits)
        self._require_groups(("noise", "guard"))
        for which in ("P0", "Q", "P0_fraction", "Q_fraction"):
            check_names(which, getattr(self.noise, which))
        order = check_int("delay_order", self.delay_order, minimum=1)
        if order > MAX_DELAY_ORDER:
            raise ValueError(
                f"delay_order must be <= {MAX_DELAY_ORDER}, got {order!r}: higher orders make "
                "the controllable canonical form of the internal model too ill-conditioned "
                "for the filter (order 5 loses a positive-definite covariance in the first "
                "samples)"
            )
        object.__setattr__(self, "delay_order", order)
        object.__setattr__(self, "restarts", check_int("restarts", self.restarts, minimum=0))
        check_choice("start", self.start, STARTS)

    @property
    def ce_type(self) -> str | None:
        """The element type the family's rules read: ``ce``, else the element's type."""
        if self.ce is not None:
            return self.ce
        return element_type(self.element) if self.element is not None else None

    @property
    def limits_choice(self) -> str:
        """The named limits in use.

        The given name, else ``"human"`` with an element, else ``"table-I"`` (a mapping
        of limits replaces entries of that default).
        """
        if isinstance(self.limits, str):
            return self.limits
        return "human" if self.element is not None else "table-I"

    @property
    def pursuit(self) -> bool:
        """The preview model fitted in its pursuit form (``anticipation_time = 0``)."""
        return self.anticipation_time == 0.0 and "ft_far" in make_model(self.model).perceptions

    @property
    def r2_value(self) -> float:
        """``r^2`` in use: the given one, else the preset's."""
        if self.noise.r2 is not None:
            return self.noise.r2
        return 4.0 if self.noise.preset == "vertregt2020-remnant" and self.ce_type == "DI" else 0.7


def held_by_design(ce: str | None, pursuit: bool) -> frozenset[str]:
    """Parameters the family holds whatever the pilot, unless ``estimated`` names them.

    The single integrator's ``K_v`` (at 0) and ``omega_f`` (thesis Sec. III-A), and the
    pursuit form's preview time (no preview: ``tau_f = 0`` enters nowhere).
    """
    held = {"K_v", "omega_f"} if ce == "SI" else set()
    if pursuit:
        held.add(ANTICIPATED_PARAMETER)
    return frozenset(held)


class GenericValuesWarning(UserWarning):
    """A filter holds parameters at generic starting values (:func:`held_without_values`)."""


def _in_library(module: str) -> bool:
    """Whether ``module`` is the package's own code (its tests are callers, like users)."""
    return module.startswith("manualcontrol.") and not module.startswith("manualcontrol.tests")


def _caller_level() -> int:
    """``stacklevel`` of the first caller outside the library, seen from the caller of this."""
    frame, level = sys._getframe(1), 1
    while frame.f_back is not None and _in_library(frame.f_globals.get("__name__", "")):
        frame, level = frame.f_back, level + 1
    return level


def warn_held_without_values(owner: str, assumed: Iterable[str]) -> None:
    """Warn (:class:`GenericValuesWarning`) that ``owner`` holds ``assumed`` unmeasured.

    The warning points at the first caller outside the library: the user's line that
    built the filter.
    """
    assumed = tuple(assumed)
    if assumed:
        warnings.warn(
            f"{owner} holds {', '.join(assumed)} at generic starting "
            "values all run (not estimated, no value in initial): give the pilot's "
            f"values in initial={{{', '.join(repr(n) + ': ...' for n in assumed)}}} or "
            "name them in estimated",
            GenericValuesWarning,
            stacklevel=_caller_level(),
        )


def held_without_values(
    names: Iterable[str],
    estimated: Iterable[str] | None,
    initial: Mapping[str, float],
    ce: str | None,
    pursuit: bool,
) -> tuple[str, ...]:
    """Of ``names``, those held all run at a generic rule's starting value.

    Not estimated, no value given in ``initial``, and not held by design
    (:func:`held_by_design`): such a parameter stays all run at a value no one measured
    for this pilot (Popovici's eqs. 27-31, the preview model's nominal values: the
    module docstring). ``estimated=None`` (all but the design's holds) holds none.
    """
    if estimated is None:
        return ()
    estimated = set(estimated)
    rule = held_by_design(ce, pursuit)
    return tuple(
        name for name in names if name not in estimated and name not in initial and name not in rule
    )


@dataclass(frozen=True)
class ResolvedSettings:
    """Every number a filter run uses, resolved from its settings at reset.

    Values are in model units (``tau_f`` as preview time, its variances those of
    ``tau_f*``, which has the same spread).
    """

    parameter_names: tuple[str, ...]
    estimated: tuple[str, ...]
    gains: tuple[str, ...]
    theta: tuple[str, ...]
    initial: Mapping[str, float]
    P0: Mapping[str, float]
    Q: Mapping[str, float]
    limits: Mapping[str, tuple[float, float]]
    q2: float
    r2: float
    r2_parameter: float
    var_u0: float | None
    var_e0: float | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {
            "parameter_names": list(self.parameter_names),
            "estimated": list(self.estimated),
            "state_filter_gains": list(self.gains),
            "parameter_filter": list(self.theta),
            "initial": dict(self.initial),
            "P0": dict(self.P0),
            "Q": dict(self.Q),
            "limits": {
                k: [to_json_value(v[0]), to_json_value(v[1])] for k, v in self.limits.items()
            },
            "q2": self.q2,
            "r2": self.r2,
            "r2_parameter": self.r2_parameter,
            "var_u0": self.var_u0,
            "var_e0": self.var_e0,
        }


def _plant(element: Any) -> Any:
    """The element a setting names (a preset, a transfer function in ``s``, a dict)."""
    return make_element(element)


def _element_setting(element: Any) -> Any:
    """``element`` checked and in a JSON-able form (text as given, else a dict)."""
    plant = _plant(element)
    if plant.is_time_varying:
        raise ValueError(f"element must be constant for the limits it sets, got {plant.describe()}")
    if isinstance(element, str):
        return element
    return plant.to_dict() if isinstance(element, ControlledElement) else dict(element)


def human_limits(element: Any, model: str) -> dict[str, tuple[float, float]]:
    """Limits from the experiment's controlled element and from human ranges.

    Gains: the ones that put the crossover anywhere humans do
    (:func:`~manualcontrol.pilots.models.element_gain_ranges`: ``K_p`` between the
    smallest and the largest ``1/|H_c(j w)|`` over 0.5-8 rad/s, ``K_v`` from 0 to the
    largest ``1/(w |H_c(j w)|)``), so a plant of gain 1 allows the gains humans use on
    it, which thesis Table I (set for ``1.5/s`` and ``5/s^2``) does not. Delay and
    neuromuscular limits: :data:`HUMAN_RANGES`. The structure's other parameters (far
    view, near view), and the gains on an element that does not integrate, keep the
    structure's human ranges.
    """
    limits = {spec.name: spec.human for spec in make_model(model).parameters}
    limits.update(HUMAN_RANGES)
    # an element that does not integrate gives no crossover range: the structure's own
    limits.update(element_gain_ranges(_plant(element)))
    return limits


def run_describing_function(
    settings: PilotFilterSettings,
    recording: Recording,
    forcing: Any,
    target_period: float | None,
    what: str,
    method: str = "fourier",
) -> Any:
    """The run's describing function for a filter's offline choices, on its model's display.

    The choices: its start, the RML's remnant model. The forcing from ``forcing`` (a
    ForcingPair), else ``recording.metadata``, else ``target_period`` (the forcing's
    period, its lines read off the recorded signals).
    ``what``, the setting that needs it as ``name=value``, is named in the error when it
    cannot be measured; ``method`` is :func:`describing_function`'s.
    """
    task = "compensatory"
    if "ft_far" in make_model(settings.model).perceptions:
        task = "pursuit" if settings.pursuit else "preview"
    pair = forcing if isinstance(forcing, ForcingPair) else None
    try:
        return describing_function(
            recording,
            pair,
            period=target_period if pair is None else None,
            element=settings.element,
            task=recording.metadata.get("task", task),
            method=method,
        )
    except ValueError as error:
        raise ValueError(
            f"{what} needs the describing function of the run "
            f"({error}); pass forcing= (the run's ForcingPair) or target_period= (the "
            "forcing's period, s)"
        ) from None


def forcing_period(forcing: ForcingPair) -> float:
    """The period (s) a forcing's multisines repeat at; ValueError where none does."""
    periods = [
        signal.measurement_time
        for signal in (forcing.target, forcing.disturbance)
        if isinstance(signal, Multisine) and signal.measurement_time is not None
    ]
    if not periods:
        raise ValueError("the forcing has no periodic multisine (one with a measurement time)")
    return float(max(periods))


def element_type(element: Any) -> str | None:
    """The family's element type: ``"SI"`` for ``K/s``, ``"DI"`` for ``K/s^2``, else None.

    The type sets the rules by element (the module docstring).
    """
    plant = _plant(element)
    if isinstance(plant, Integrator):
        return "SI"
    if isinstance(plant, DoubleIntegrator):
        return "DI"
    return None


def default_limits(
    settings: PilotFilterSettings, names: tuple[str, ...]
) -> dict[str, tuple[float, float]]:
    """The limits of ``names`` the settings' ``limits`` choice gives, before any given ones."""
    model = make_model(settings.model)
    if settings.limits_choice == "human":
        table = human_limits(settings.element, settings.model)
    elif settings.ce is not None:
        table = dict(TABLE_I[settings.ce])
    else:
        table = {spec.name: spec.human for spec in model.parameters}
    limits = {name: table[name] for name in names if name in table}
    if "ft_far" in model.perceptions and not settings.pursuit:
        tau_a = settings.anticipation_time
        limits["tau_f"] = (TAU_F_MARGIN, tau_a - TAU_F_MARGIN)
    return limits


def resolve_settings(
    settings: PilotFilterSettings,
    internal: InternalModel,
    var_u0: float | None,
    var_e0: float | None,
) -> ResolvedSettings:
    """Fill in initial values, covariances and limits (see the module docstring)."""
    r2_parameter = getattr(settings, "r2_parameter", None)
    model = internal.model
    names = internal.parameter_names
    pursuit = settings.pursuit
    preview = ANTICIPATED_PARAMETER in names and "ft_far" in model.perceptions and not pursuit
    si = settings.ce_type == "SI"
    if settings.estimated is None:
        held = held_by_design(settings.ce_type, pursuit)
        estimated = tuple(name for name in names if name not in held)
    else:
        estimated = settings.estimated
        if pursuit and ANTICIPATED_PARAMETER in estimated:
            raise ValueError(
                "a pursuit fit (anticipation_time = 0) has no preview time to estimate: "
                f"leave {ANTICIPATED_PARAMETER} out of estimated"
            )
    # limits
    if settings.limits == "none":
        limits: dict[str, tuple[float, float]] = {}
    else:
        limits = default_limits(settings, names)
        if isinstance(settings.limits, Mapping):
            limits.update(settings.limits)
    # initial values
    initial: dict[str, float] = {}
    generic_gain = None
    if var_u0 is not None and var_e0 is not None and var_u0 > 0.0 and var_e0 > 0.0:
        generic_gain = math.sqrt(var_u0 / var_e0)  # Popovici eq. 27
    for name in names:
        if name in settings.initial:
            initial[name] = float(settings.initial[name])
            continue
        if name == "K_p" and model.name in ("precision", "preview"):
            if generic_gain is None:
                raise ValueError(
                    "initial K_p is needed: Popovici's generic rule K_p0 = sigma_u/sigma_e "
                    "(eq. 27) needs the variances of u and e over the first window (reset with "
                    "var_u0 and var_e0, or use initial_variance='first-window' through "
                    "estimate), or give initial={'K_p': ...}"
                )
            value = generic_gain
        elif name == "K_v" and model.name in ("precision", "preview"):
            value = 0.0 if si else 0.5 * initial["K_p"]  # eq. 28
        elif name == "tau_f" and preview:
            value = 0.5 * settings.anticipation_time
        elif name == "tau_f" and pursuit:
            value = 0.0
        elif name == "omega_f" and settings.ce_type == "DI":
            value = DI_FAR_BREAK
        elif name in GENERIC_INITIAL and model.name in ("precision", "preview"):
            value = GENERIC_INITIAL[name]  # eqs. 29-31
        else:
            value = model.spec(name).nominal
        if name in limits and name not in settings.initial:
            low, high = limits[name]
            value = min(max(value, low), high)
        initial[name] = value
    for name in estimated:
        if name in limits:
            low, high = limits[name]
            if not low <= initial[name] <= high:
                raise ValueError(
                    f"initial {name} = {initial[name]!r} lies outside its limits "
                    f"[{low:g}, {high:g}]"
                )

    def internal_value(name: str) -> float:
        if preview and name == ANTICIPATED_PARAMETER:
            return settings.anticipation_time - initial[name]
        return initial[name]

    # covariances
    P0: dict[str, float] = {}
    Q: dict[str, float] = {}
    for name in estimated:
        value = abs(internal_value(name))
        kind = _kind(name)
        if settings.noise.preset == "popovici2017":
            p0 = 10.0 if kind in ("gain", "frequency") else 1.0  # eqs. 32-33
            q = (1.0 if kind == "gain" else 0.1) * value  # eqs. 25-26
        else:
            p_factor = 0.1 if name == "omega_nms" else 0.5
            p0 = (p_factor * value) ** 2  # thesis Sec. V-B-1
            q = (0.05 if kind in ("gain", "delay") else 0.025) * value  # Sec. V-B-2
        if name in settings.noise.P0_fraction:
            p0 = (settings.noise.P0_fraction[name] * value) ** 2  # thesis Sec. V-B-1 form
        if name in settings.noise.Q_fraction:
            q = settings.noise.Q_fraction[name] * value  # thesis Sec. IV-F-2 form
        P0[name] = settings.noise.P0.get(name, p0)
        Q[name] = settings.noise.Q.get(name, q)
        for which, table in (("P0", P0), ("Q", Q)):
            if not table[name] > 0.0:
                raise ValueError(
                    f"{which}[{name!r}] resolves to {table[name]!r} (from the initial value "
                    f"{initial[name]!r} with preset {settings.noise.preset!r}); covariances must "
                    f"be > 0: give {which}={{{name!r}: ...}} or another initial value"
                )
    gains = tuple(name for name in internal.gain_parameters if name in estimated)
    theta_names = [name for name in _THETA_ORDER if name in estimated and name not in gains]
    theta_names += [
        name
        for name in names
        if name in estimated and name not in gains and name not in theta_names
    ]
    return ResolvedSettings(
        parameter_names=names,
        estimated=tuple(name for name in names if name in estimated),
        gains=gains,
        theta=tuple(theta_names),
        initial=MappingProxyType(initial),
        P0=MappingProxyType(P0),
        Q=MappingProxyType(Q),
        limits=MappingProxyType({k: v for k, v in limits.items() if k in estimated}),
        q2=settings.noise.q2,
        r2=settings.r2_value,
        r2_parameter=settings.r2_value if r2_parameter is None else r2_parameter,
        var_u0=var_u0,
        var_e0=var_e0,
    )


@functools.lru_cache(maxsize=16)
def internal_model(model: str, delay_order: int, pursuit: bool = False) -> InternalModel:
    """The internal model of ``model`` with Padé order ``delay_order`` (cached)."""
    return build_internal_model(model, delay_order, pursuit=pursuit)


# ------------------------------------------------------------------ parameter map


@dataclass(frozen=True)
class ParameterMap:
    """Internal values of the model's parameters (what the filters estimate), and back.

    The preview model's preview time is estimated as the apparent delay
    ``tau_f* = tau_a - tau_f`` behind the target anticipated by ``tau_a`` (thesis eq.
    26): its slot holds ``tau_f*`` inside the filters, and results report ``tau_f``.
    Every other parameter is its own internal value.
    """

    names: tuple[str, ...]
    anticipation_time: float
    anticipated: str | None

    @classmethod
    def of(cls, settings: PilotFilterSettings, internal: InternalModel) -> ParameterMap:
        """The map of a filter with these settings on this internal model."""
        names = internal.parameter_names
        preview = ANTICIPATED_PARAMETER in names and "ft_far" in internal.model.perceptions
        if not preview or settings.pursuit:
            return cls(names, 0.0, None)
        return cls(names, float(settings.anticipation_time), ANTICIPATED_PARAMETER)

    def internal(self, name: str, value: float) -> float:
        """Internal value of parameter ``name`` reported as ``value``."""
        return self.anticipation_time - value if name == self.anticipated else value

    def reported(self, name: str, value: float) -> float:
        """Reported value of parameter ``name`` whose internal value is ``value``."""
        return self.anticipation_time - value if name == self.anticipated else value

    def internal_limits(self, name: str, low: float, high: float) -> tuple[float, float]:
        """Limits on the internal value from limits on the reported one."""
        if name == self.anticipated:
            return self.anticipation_time - high, self.anticipation_time - low
        return low, high

    def report_transform(self) -> tuple[FloatArray, FloatArray]:
        """``(offset, sign)`` per parameter: reported = offset + sign internal."""
        offset = np.zeros(len(self.names))
        sign = np.ones(len(self.names))
        if self.anticipated is not None:
            j = self.names.index(self.anticipated)
            offset[j] = self.anticipation_time
            sign[j] = -1.0
        return offset, sign


# ---------------------------------------------------------------------- the shell
