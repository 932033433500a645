"""Recursive maximum likelihood over a Kalman filter bank: identification that survives remnant.

Why the family's filters lose their way with remnant
-------------------------------------------------------------
The DEKF and the joint and dual UKF treat the remnant as white noise on ``u`` and on
the chain input. Remnant injected in the loop reaches the measured output ``y``, so
the inputs of the filter are correlated with its noise (the closed-loop bias): on the
double integrator with 0.01-rad/s remnant the perceived output drifts far beyond its
remnant-free size and ``K_p``, which multiplies that drift, collapses. Modelling the
remnant as a coloured state of a joint filter (states, remnant and parameters in one
belief) does not cure it: the output gains and the remnant trade ``K -> a K``, remnant
``-> n/a``, and a joint (or dual) filter, which approximates the joint posterior of
states and parameters rather than the likelihood of the parameters, prefers the
smaller remnant (Ljung 1979: its parameter update leaves out how the Kalman gain
depends on the parameters). A remnant state tried in the joint UKF biased the gains
one way or the other, depending on the remnant's assumed variance.

The estimator
-------------
This filter estimates the parameters by the likelihood of the innovations, with the
remnant in the model (:mod:`~manualcontrol.estimators.members._rml_core`):

* for given parameters the pilot's isolated model with a first-order remnant filter
  at its perception (Levison et al. 1969; thesis eq. 5) is linear in its states, and a
  linear Kalman filter gives the one-step prediction of the stick and its variance;
* a bank of ``2 n + 1`` such filters runs at the parameter mean and at ``+- step``
  standard deviations along each direction of the parameter covariance; their
  predictions give the score and the Fisher information of each sample, with the
  dependence of each filter's gain on the parameters included;
* the parameters are random walks (the family's ``P0``/``Q`` rules) updated each
  sample by one Gauss-Newton step of their posterior (recursive prediction-error /
  maximum-likelihood estimation, Ljung & Söderström 1983, in its Bayesian form);
* the remnant's intensity is one of the estimated parameters (in logarithms; the
  likelihood identifies it through the innovation variance), optionally its break
  frequency too;
* the delays (the pilot's and the anticipation delay ``tau_f*`` of the preview
  model) act on the inputs through fractional delay lines with the bicubic kernel of
  Boer & Kenyon (1998) instead of Padé approximants: with the true parameters the
  model then reproduces the simulated pilot almost exactly, where the Padé-3 internal
  model of the DEKF leaves an error that the parameters otherwise absorb;
* the preview model's pursuit form (``anticipation_time = 0``: the display shows the
  current target, nothing ahead, ``tau_f = 0`` held) reads the recorded ``ft`` through
  the pilot's delay alone, as the family's other filters do, so a pursuit recording
  needs no forcing or target period.

Settings (beyond the shared ones of
:class:`~manualcontrol.estimators.members.pilot_filter.PilotFilterSettings`) and their defaults:
``remnant`` (``"levison"`` or ``"none"``), ``remnant_break`` (rad/s; by default the
break frequency van der El et al. measured for the element type, thesis Sec. IV-D: 10
rad/s for ``ce="SI"``, 0.01 rad/s for ``"DI"``, otherwise Levison's 3 rad/s of Popovici
et al.), ``remnant_injection`` (``"input"``: at the perception, ``"output"``: at the
stick, ``"choose"``: offline, both, the pass the describing function agrees with kept,
``"choose-causal"``: both side by side, each sample's estimate from the pass the
describing function of the samples up to it agrees with; :meth:`RML.estimate`),
``remnant_variance`` (the remnant's initial variance as a fraction
of the error variance over the first window), ``learn_intensity`` (True), ``learn_break`` (False),
``intensity_P0``/``intensity_Q`` (the log intensity's initial variance and random-walk
variance, a ``Q`` like the parameters', see "Sample rates" below), ``step`` (the bank's spread in
standard deviations), ``spread_limit`` (0.1: no member lies further from the mean, in
any parameter, than this fraction of the parameter's limit span; where the spread would,
it is reduced along that direction, so the differences stay local derivatives and the
members inside the limits; 0: no limit), ``substeps`` (Euler substeps per 0.01 s, below),
``noise_first`` (seconds at the start during which only the noise parameters learn),
``r2_remnant`` (the part of ``R`` that follows the remnant: 5 where the remnant drifts,
on the double integrator, else 0; below), and the drift rule's ``drift_gain`` (15; 0 =
off), ``drift_window`` (2.5 s) and ``drift_threshold`` (0.3), below. ``r2`` defaults to
1 (``R = var(u)`` over the window; 0.5 where the remnant drifts, below):
``R`` stands for what the model leaves unexplained besides the remnant (the isolated
pilot is a model; the Euler step), and it sets the frequency weighting of the
likelihood: with a small ``R`` the one-sample prediction errors, dominated by the
fastest dynamics, outweigh the forcing band, and the parameters the forcing band
identifies (the far view's ``K_f``) err the more. ``q2`` defaults to 1e-6: the
remnant state, not white noise at the chain input, carries the process noise.

``variance_score`` says which pilot parameters learn from the innovation variance as
well as from the prediction (the ``dS`` part of the score,
:mod:`~manualcontrol.estimators.members._rml_core`). ``"remnant-path"`` (default): those the
remnant passes through on its way to the stick, the main chain's (gains, delay,
neuromuscular system) when the remnant is injected at the perception, none when it is
injected at the stick; the branches' parameters (the preview model's ``K_f``,
``omega_f``, ``tau_f``) follow the prediction error alone. ``"all"``: every
parameter, the exact likelihood of the model with ``R`` taken as a noise variance.
Because ``R`` is a weighting larger than what the innovations leave, ``"all"`` pulls
the branch parameters towards a smaller predicted variance, and their errors grow where
the remnant is strong (the thesis's double integrator); on the single integrator the
two agree. Learning ``R`` as a noise parameter instead lets it collapse: the one-step
prediction then explains all of ``u`` and ``K_p`` runs away.

What ``R``'s level does with remnant: ``R`` also decides how the gains and the remnant
share the stick's slow power. On the double integrator ``K_p``'s bias falls as ``r2``
rises, and the ``r2`` without bias grows with the remnant; on the single integrator
``r2`` moves ``K_p`` little and the neuromuscular parameters both ways. No one fixed
``r2`` serves every remnant level: the level without bias is about seven times the
remnant's share of the stick's power, i.e. ``R`` about seven times the remnant's part
of ``var(u)``.

So where the remnant drifts (``ce="DI"`` with a remnant at the perception:
:attr:`RMLSettings.remnant_drifts`) ``R`` follows the filter's own estimate of that
part: ``R = r2 var(u) + r2_remnant g^2 var(r)``, ``var(r)`` the remnant state's
stationary variance and ``g`` the gain it passes (``K_p``), both at the current
estimate, with ``r2 = 0.5`` and ``r2_remnant = 5`` by default
(:data:`DRIFTING_REMNANT_R2`, :data:`DRIFTING_REMNANT_WEIGHT`; chosen among three
pairs on the thesis's double-integrator pilot with 55 % remnant); elsewhere ``r2 = 1``
and no remnant weight. Against ``R = var(u)`` it lowers most of the double integrator's
parameter errors, most of all where the remnant is strong. On the
single integrator, whose remnant is broadband, the same weight raised the
neuromuscular errors: it is not used there. The weight is evaluated at the bank's
centre, as a weighting, not per member: per member the bank's differences pull ``K_p``
and the intensity towards a smaller ``R`` (tried: ``K_p`` ran to its lower limit).

The double integrator's steady negative biases in ``K_v``, ``omega_nms`` and
``zeta_nms`` are the ``dS`` term's pull towards a smaller ``S`` (above): centring that
term on the innovations' observed level (a moving mean of ``nu^2/S``) turns some of
them positive and frees ``K_p``, because that level is what tells the gains from the
remnant's intensity; leaving ``omega_nms``, ``zeta_nms`` and ``tau_v`` out of it lets
``zeta_nms`` fall. They are not the remnant's delay (a remnant injected after the
pilot's delay, where the filter puts it: the same biases), nor the random walk's memory
(``Q`` a hundred times smaller for the constant parameters: larger errors), nor the
break frequency (learned: the same). A noise model in which ``R`` is a noise, not a
weighting, is what would remove them; none of these variants is an option. The remnant
weight (above) reduces the ``K_v`` and ``zeta_nms`` biases; that of ``omega_nms`` stays.

Process noise that follows a change (the drift rule): the parameters' random-walk
variances are the family's presets (thesis Sec. V-B-2), tuned for 20-s sigmoids of
``tau_f``. When a parameter changes faster, the estimate lags and every sample corrects
it the same way; that persistence raises the parameter's ``Q`` until the corrections
cancel again (:func:`~manualcontrol.estimators.members._rml_kernels._adapt_process_noise`: the
moving mean of the corrections in prior standard deviations over that of their size,
above ``drift_threshold``, scales ``Q`` by up to ``1 + drift_gain``; moving means over
``drift_window``). It is the delta-bar-delta idea (Jacobs 1988; Sutton's IDBD, 1992)
with the random walk's variance as the rate. It lowers the errors of parameters that
change faster than the preset allows (Popovici's time-varying pilot, the thesis's
``tau_f`` sigmoids); the cost is that parameters that are constant wander a little
more. Its gain, window and threshold mattered little over the ranges tried.

Restarts (offline; ``restarts=1``, :mod:`~manualcontrol.estimators.members.pilot_filter`):
with ``R = var(u)`` on the double integrator the 0.01-rad/s remnant can knock the filter
off in its run-in (``K_p`` at its lower limit for over a minute), and a second pass
from the first pass's smoothed estimate rescues such runs; with the remnant weight
(above) the run examined stayed on course in one pass. With the weight the passes'
likelihoods are not comparable (each pass weights ``R`` by its own estimate), and a
restart made things worse: the RML refuses restarts with ``r2_remnant > 0``
(``r2_remnant=0`` allows them again; with ``r2=1`` too, ``R = var(u)``). The
likelihood test matters: choosing the pass with the smaller cost without it changed
most errors, more for the worse than for the better. Cost: a second filter pass and a
smoothing, about twice the time.

Sample rates: the settings were chosen at 100 Hz (the papers' rate,
:data:`~manualcontrol.estimators._pilot_core.PAPERS_DT`) and keep their meaning per
second at any other. The remnant state's transition and process noise are exact (a
continuous intensity), so ``R`` and the random walks' ``Q`` are continuous-time too,
anchored at 100 Hz: ``R`` (``r2 var(u)`` plus the remnant's part, or ``fixed_R``) is a
sample's variance at 100 Hz and ``R (0.01 s) / dt`` at ``dt`` (a white noise of the same
density), and a random walk's variance a sample, ``Q dt^2`` at 100 Hz (the family's
``Gamma = I dt``, :mod:`~manualcontrol.estimators.members.pilot_filter`), is ``Q (0.01 s) dt``
at ``dt`` (``noise_input="identity"``: ``Q`` a sample at any rate). Were ``R`` a
sample's variance at every rate, a 1-kHz run would weigh the remnant state ten times as
much against ``R`` as a 100-Hz run, and its estimates would follow the remnant. The
parameters' information, and so their standard deviations, are then the same per
second at every rate. ``substeps`` are Euler substeps per 0.01 s: a sample of ``dt``
takes ``ceil(substeps dt / 0.01 s)`` of them
(:func:`~manualcontrol.estimators._pilot_core.euler_substeps`; 2 at 100 and 120 Hz, 4 at
50 and 60 Hz, 1 at 1 kHz), so no substep is longer than at 100 Hz: the model's
discretisation error grows with its step. The variance window, ``noise_first``, the
delay lines and the drift rule's window are in seconds already.
``tests/estimators/test_sample_rates.py`` holds the estimates at 50, 60, 120 and 1000 Hz
to those at 100 Hz.

Online and offline: :meth:`estimate` and :meth:`update` give the filtered estimates
(each from the samples up to it); ``estimate(..., smooth=True)`` (or the registered
``"rml-smoothed"``) smooths the parameter track over the whole run as random walks
(Rauch-Tung-Striebel, as the unscented filters).

Measured figures for every choice above, each with the command that reproduces it, are
in ``docs/estimators.md`` (the RML); ``benchmarks/rml_variants.py`` sets RML settings
side by side on a suite's RML batches.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from manualcontrol.envs._lazy import LazyKernel
from manualcontrol.envs._validation import check_choice, check_int, check_positive
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair
from manualcontrol.estimators._pilot_core import PAPERS_DT, euler_substeps
from manualcontrol.estimators.analysis.fit_check import (
    FAR_GAIN_DB,
    FAR_PHASE_DEG,
    column_medians,
    second_half_values,
)
from manualcontrol.estimators.analysis.frequency import response_error
from manualcontrol.estimators.filters.kalman import kalman_work
from manualcontrol.estimators.members import _rml_core as core
from manualcontrol.estimators.members import _rml_native
from manualcontrol.estimators.members.internal_model import (
    ANTICIPATED_PARAMETER,
    InternalModel,
    build_internal_model,
)
from manualcontrol.estimators.members.pilot_filter import CommonArrays, PilotFilter
from manualcontrol.estimators.members.pilot_rules import (
    NoiseSettings,
    PilotFilterSettings,
    ResolvedSettings,
    forcing_period,
    run_describing_function,
)
from manualcontrol.estimators.offline.smoothing import SmootherBlock, SmootherInputs
from manualcontrol.estimators.protocol import summarise_health
from manualcontrol.estimators.settings import SettingsRecord
from manualcontrol.estimators.shell import output_arrays
from manualcontrol.pilots.models import make_model

__all__ = [
    "BREAK_FREQUENCY",
    "RML",
    "BankSettings",
    "DriftSettings",
    "RMLSettings",
    "RemnantSettings",
]

#: Remnant break frequency (rad/s) per controlled-element type (van der El et al.
#: 2019, thesis Part I Sec. IV-D); other dynamics take Levison's 3 rad/s (Popovici).
BREAK_FREQUENCY = {"SI": 10.0, "DI": 0.01}
DEFAULT_BREAK = 3.0
REMNANT_MODELS: tuple[str, ...] = ("levison", "none")
INJECTIONS: tuple[str, ...] = ("input", "output")
#: ``remnant_injection`` that runs both points and keeps the one the describing function
#: agrees with (offline, :meth:`RML.estimate`).
CHOOSE_INJECTION = "choose"
#: ``remnant_injection`` that runs both points side by side and follows, sample by
#: sample, the one the describing function of the samples so far agrees with (causal,
#: :meth:`RML.estimate`).
CHOOSE_CAUSAL_INJECTION = "choose-causal"
#: Seconds between the causal choice's decisions: often against the filters' settling
#: (tens of seconds), rarely against the cost of a least-squares describing function of
#: the run so far (tens of milliseconds on a few minutes at 100 Hz).
CAUSAL_CHOICE_INTERVAL = 5.0
#: Which pilot parameters the variance part of the score moves (module docstring).
VARIANCE_SCORES: tuple[str, ...] = ("remnant-path", "all")
#: Range of the log intensity around its initial value (e^12: beyond any remnant).
INTENSITY_RANGE = 12.0
#: Range of the break frequency when it is learned (rad/s).
BREAK_RANGE = (1e-3, 100.0)
#: ``r2`` and ``r2_remnant`` by default where the remnant drifts (``ce="DI"``, module
#: docstring): ``R = 0.5 var(u) + 5 K_p^2 var(r)``.
DRIFTING_REMNANT_R2 = 0.5
DRIFTING_REMNANT_WEIGHT = 5.0
#: The gain a remnant at the perception passes on its way to the stick.
_REMNANT_GAIN = "K_p"
#: Longest pilot delay the delay lines keep (s), beyond the Table I limit of 0.8 s.
LONGEST_DELAY = 1.5


@dataclass(frozen=True)
class RemnantSettings(SettingsRecord):
    """The remnant model the RML learns beside the pilot (``remnant=``; module docstring).

    Each field is also accepted flat by the name in brackets, the one error messages use.

    Parameters
    ----------
    model : {"levison", "none"}
        (``remnant``) Levison's first-order remnant filter, or no remnant state.
    break_frequency : float or None
        (``remnant_break``, rad/s) The filter's (initial) break; None: the one measured
        for the element type (:data:`BREAK_FREQUENCY`).
    injection : {"input", "output", "choose", "choose-causal"}
        (``remnant_injection``) At the perception, at the stick, offline both with the
        pass the describing function agrees with kept, or both with the estimates
        following, causally, the pass the describing function of the samples so far
        agrees with (:meth:`RML.estimate`).
    variance : float
        (``remnant_variance``) Initial variance as a fraction of the first window's
        error variance.
    learn_intensity, learn_break : bool
        Whether the log intensity (True) and the break (False) are learned.
    intensity_P0, intensity_Q : float
        The log intensity's initial variance and random-walk variance.
    r2 : float or None
        (``r2_remnant``) The part of ``R`` that follows the remnant; None: 5 where the
        remnant drifts (:attr:`RMLSettings.remnant_drifts`), else 0.
    """

    flat_names: ClassVar[Mapping[str, str]] = {
        "model": "remnant",
        "break_frequency": "remnant_break",
        "injection": "remnant_injection",
        "variance": "remnant_variance",
        "r2": "r2_remnant",
    }

    model: str = "levison"
    break_frequency: float | None = None
    injection: str = "input"
    variance: float = 0.5
    learn_intensity: bool = True
    learn_break: bool = False
    intensity_P0: float = 4.0
    intensity_Q: float = 1e-3
    r2: float | None = None

    def __post_init__(self) -> None:
        check_choice("remnant", self.model, REMNANT_MODELS)
        if self.break_frequency is not None:
            object.__setattr__(
                self, "break_frequency", check_positive("remnant_break", self.break_frequency)
            )
        check_choice(
            "remnant_injection",
            self.injection,
            (*INJECTIONS, CHOOSE_INJECTION, CHOOSE_CAUSAL_INJECTION),
        )
        for name in ("learn_intensity", "learn_break"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if self.r2 is not None:
            object.__setattr__(self, "r2", check_positive("r2_remnant", self.r2, allow_zero=True))
        object.__setattr__(self, "variance", check_positive("remnant_variance", self.variance))
        object.__setattr__(self, "intensity_P0", check_positive("intensity_P0", self.intensity_P0))
        object.__setattr__(
            self, "intensity_Q", check_positive("intensity_Q", self.intensity_Q, allow_zero=True)
        )


@dataclass(frozen=True)
class DriftSettings(SettingsRecord):
    """The drift rule on the parameters' process noise (``drift=``; module docstring).

    Flat keys: ``drift_gain``, ``drift_window``, ``drift_threshold``.

    Parameters
    ----------
    gain : float
        Largest factor on a parameter's ``Q`` is ``1 + gain`` (>= 0; 0: off).
    window : float
        The moving means' window (s, > 0).
    threshold : float
        Persistence of the corrections above which ``Q`` grows, in [0, 1).
    """

    flat_names: ClassVar[Mapping[str, str]] = {
        "gain": "drift_gain",
        "window": "drift_window",
        "threshold": "drift_threshold",
    }

    gain: float = 15.0
    window: float = 2.5
    threshold: float = 0.3

    def __post_init__(self) -> None:
        object.__setattr__(self, "gain", check_positive("drift_gain", self.gain, allow_zero=True))
        object.__setattr__(self, "window", check_positive("drift_window", self.window))
        threshold = check_positive("drift_threshold", self.threshold, allow_zero=True)
        if threshold >= 1.0:
            raise ValueError(
                f"drift_threshold must be in [0, 1) (a persistence of the corrections), "
                f"got {threshold!r}"
            )
        object.__setattr__(self, "threshold", threshold)


@dataclass(frozen=True)
class BankSettings(SettingsRecord):
    """How the filter bank spreads, steps and learns (``bank=``; module docstring).

    Each field is also accepted flat by its own name.

    Parameters
    ----------
    step : float
        The bank's spread in standard deviations (> 0).
    substeps : int
        Euler substeps per 0.01 s (>= 1).
    noise_first : float
        Seconds at the start during which only the noise parameters learn (>= 0).
    variance_score : {"remnant-path", "all"}
        Which pilot parameters the variance part of the score moves.
    spread_limit : float
        Largest offset of a member from the mean, as a fraction of each parameter's
        limit span, in [0, 1] (0: no limit).
    """

    step: float = 1.0
    substeps: int = 2
    noise_first: float = 0.0
    variance_score: str = "remnant-path"
    spread_limit: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "step", check_positive("step", self.step))
        object.__setattr__(self, "substeps", check_int("substeps", self.substeps, minimum=1))
        object.__setattr__(
            self, "noise_first", check_positive("noise_first", self.noise_first, allow_zero=True)
        )
        check_choice("variance_score", self.variance_score, VARIANCE_SCORES)
        spread = check_positive("spread_limit", self.spread_limit, allow_zero=True)
        if spread > 1.0:
            raise ValueError(
                f"spread_limit must be in [0, 1] (a fraction of the limit span), got {spread!r}"
            )
        object.__setattr__(self, "spread_limit", spread)


@dataclass(frozen=True)
class RMLSettings(PilotFilterSettings):
    """Settings of the :class:`RML` (module docstring): the shared ones and three groups.

    ``remnant`` (:class:`RemnantSettings`), ``drift`` (:class:`DriftSettings`) and
    ``bank`` (:class:`BankSettings`), besides the shared ``noise`` (here with the
    ``vertregt2020`` preset and ``q2 = 1e-6``) and ``guard``.
    """

    groups: ClassVar[tuple[str, ...]] = ("noise", "guard", "remnant", "drift", "bank")

    noise: NoiseSettings = field(
        default_factory=lambda: NoiseSettings(preset="vertregt2020", q2=1e-6)
    )
    remnant: RemnantSettings = field(default_factory=RemnantSettings)
    drift: DriftSettings = field(default_factory=DriftSettings)
    bank: BankSettings = field(default_factory=BankSettings)

    def __post_init__(self) -> None:
        super().__post_init__()
        self._require_groups(("remnant", "drift", "bank"))
        r2_remnant = self.remnant.r2
        if r2_remnant is not None and r2_remnant > 0.0 and self.remnant.model == "none":
            raise ValueError(
                f"r2_remnant = {r2_remnant!r} weights R by the remnant's variance; "
                'remnant="none" has none (set r2_remnant=0 or a remnant model)'
            )
        if (
            self.r2_remnant_value > 0.0
            and self.remnant.injection == "input"
            and _REMNANT_GAIN not in make_model(self.model).parameter_names
        ):
            raise ValueError(
                f"r2_remnant = {self.r2_remnant_value:g} weights R by the remnant's pass "
                f"through {_REMNANT_GAIN}, which the {self.model} model does not have "
                '(set r2_remnant=0, or remnant_injection="output")'
            )
        if self.restarts > 0 and self.r2_remnant_value > 0.0:
            raise ValueError(
                f"restarts = {self.restarts!r}: a restart is kept by its innovations' "
                f"likelihood, which R weighted by the remnant (r2_remnant = "
                f"{self.r2_remnant_value:g}, the double integrator's default) makes "
                "incomparable between passes (each weights by its own estimate); set "
                "r2_remnant=0 (R = r2 var(u)) to restart"
            )
        previewing = "ft_far" in make_model(self.model).perceptions and not self.pursuit
        if self.remnant.injection == CHOOSE_CAUSAL_INJECTION and previewing:
            # the choice's describing function is of the filter's own samples, and the
            # preview model's carry the target ahead (ft_ahead), not the target ft that
            # its two-channel fit needs: refused here rather than at the first decision
            raise ValueError(
                "remnant_injection='choose-causal' measures the describing function from "
                "the filter's own samples, which on the preview model hold the target "
                "ahead, not the target ft its two-channel fit needs: give "
                "remnant_injection='choose' (offline, the whole run's choice), "
                "remnant_injection='input' or remnant_injection='output', or fit the "
                "model's pursuit form (an anticipation time of 0)"
            )
        if self.delay_order != 3:
            raise ValueError(
                "delay_order does not apply to the RML, whose delays act on the inputs through "
                f"delay lines (no Padé approximant); got {self.delay_order!r}"
            )

    @property
    def remnant_drifts(self) -> bool:
        """Whether the element-type defaults weight ``R`` by the remnant (module docstring).

        The double integrator (``ce="DI"``) with a remnant at the perception: van der El's
        remnant there drifts below the forcing band and shares the stick's slow power
        with the gains.
        """
        return (
            self.ce_type == "DI"
            and self.remnant.model != "none"
            and self.remnant.injection == "input"
            and _REMNANT_GAIN in make_model(self.model).parameter_names
        )

    @property
    def r2_value(self) -> float:
        """``r^2`` in use: the given one, else 0.5 where :attr:`remnant_drifts`, else 1."""
        if self.noise.r2 is not None:
            return self.noise.r2
        return DRIFTING_REMNANT_R2 if self.remnant_drifts else 1.0

    @property
    def r2_remnant_value(self) -> float:
        """``r2_remnant`` in use: the given one, else 5 where :attr:`remnant_drifts`, else 0."""
        if self.remnant.r2 is not None:
            return self.remnant.r2
        return DRIFTING_REMNANT_WEIGHT if self.remnant_drifts else 0.0

    @property
    def remnant_break_value(self) -> float:
        """The remnant filter's (initial) break frequency in use (rad/s)."""
        if self.remnant.break_frequency is not None:
            return self.remnant.break_frequency
        return BREAK_FREQUENCY.get(self.ce_type, DEFAULT_BREAK)


_MODELS: dict[tuple[str, bool], InternalModel] = {}


class _CausalChoice:
    """When and how ``remnant_injection="choose-causal"`` decides (:meth:`RML.estimate`).

    Shared by the whole-recording and the step-by-step forms, so both decide alike:
    :meth:`decision_counts` says after how many samples, :meth:`decide` scores each
    pass's model (its second-half medians of the samples so far) against the
    least-squares describing function of the signals so far and returns the index
    (into :data:`INJECTIONS`) of the nearer; each change is kept in :attr:`decisions`.
    """

    def __init__(
        self, settings: RMLSettings, forcing: ForcingPair, dt: float, sample_keys: tuple[str, ...]
    ) -> None:
        self.settings, self.forcing, self.dt = settings, forcing, dt
        #: The signals the describing function reads: those of the samples.
        self.recorded = tuple(n for n in ("e", "u", "y", "fd", "ft") if n in sample_keys)
        self.first = math.ceil(0.5 * forcing_period(forcing) / dt)
        self.every = max(1, round(CAUSAL_CHOICE_INTERVAL / dt))
        self.decisions: list[dict[str, Any]] = []

    def decision_counts(self, size: int) -> range:
        """The numbers of samples so far after which a decision is made."""
        return range(self.first, size + 1, self.every)

    def decide(self, t: Any, signals: Mapping[str, Any], values: list[Mapping[str, float]]) -> int:
        """The pass followed from the last of these samples on (index into INJECTIONS)."""
        settings = self.settings
        describing = run_describing_function(
            settings,
            Recording({"t": t, **signals}, dt=self.dt),
            self.forcing,
            None,
            f"remnant_injection={CHOOSE_CAUSAL_INJECTION!r}",
            method="least-squares",
        )
        scores = []
        for pass_values in values:
            if all(math.isfinite(v) for v in pass_values.values()):
                gain, phase = response_error(describing, settings.model, pass_values)
                scores.append(gain / FAR_GAIN_DB + phase / FAR_PHASE_DEG)
            else:
                scores.append(math.inf)
        choice = int(np.argmin(scores))
        point = INJECTIONS[choice]
        if not self.decisions or self.decisions[-1]["point"] != point:
            self.decisions.append({"t": float(t[-1]), "point": point})
        return choice


class _SteppedChoice:
    """The step-by-step form of the causal choice: both passes stepped, one followed."""

    def __init__(self, choice: _CausalChoice, passes: list[RML], t0: float) -> None:
        self.choice, self.passes, self.t0 = choice, passes, t0
        self.names = passes[0].parameter_names
        self.times: list[float] = []
        self.signals: dict[str, list[float]] = {name: [] for name in choice.recorded}
        self.rows: list[list[list[float]]] = [[] for _ in passes]
        self.followed = 0
        self.next_decision = choice.first

    def update(self, sample: Mapping[str, float], form: str) -> Any:
        """Step both passes; return the followed one's answer in ``form``.

        ``"estimate"``: an Estimate; ``"plain"``: its plain dicts; ``"quiet"``: the
        sample's time, the estimate left in the passes' rows.
        """
        if form == "quiet":
            answers = [p.update_quiet(sample) for p in self.passes]
            means = [p.latest()[0].tolist() for p in self.passes]
        else:
            plain = form == "plain"
            answers = [p.update_plain(sample) if plain else p.update(sample) for p in self.passes]
            means = [
                [(a["mean"] if plain else a.mean)[name] for name in self.names] for a in answers
            ]
        count = len(self.times) + 1
        t = sample.get("t")
        self.times.append(self.t0 + (count - 1) * self.choice.dt if t is None else float(t))
        for name, values in self.signals.items():
            values.append(float(sample[name]))
        for rows, mean in zip(self.rows, means, strict=True):
            rows.append(mean)
        if count == self.next_decision:
            values = [
                column_medians(np.array(rows[count // 2 : count]), self.names) for rows in self.rows
            ]
            signals = {name: np.array(v) for name, v in self.signals.items()}
            self.followed = self.choice.decide(np.array(self.times), signals, values)
            self.next_decision += self.choice.every
        return answers[self.followed]


def _joined(
    passes: list[Any], followed: Any, settings: RMLSettings, decisions: list[dict[str, Any]]
) -> Any:
    """One result whose every per-sample row is that of the pass ``followed`` names.

    ``followed[i]`` indexes :data:`INJECTIONS` (and ``passes``). The health summary is
    recounted from the joined flags; a divergence counts where the pass followed then
    diverged.
    """
    last = passes[int(followed[-1])]
    rows = {}
    for name in (
        "mean",
        "std",
        "predictions",
        "innovations",
        "innovation_covariance",
        "finite",
        "covariance_ok",
        "dropped",
        "diverged",
        "pinned",
        "states",
    ):
        arrays = [getattr(result, name) for result in passes]
        if any(array is None for array in arrays):
            rows[name] = None
            continue
        joined = arrays[0].copy()
        for index, array in enumerate(arrays[1:], start=1):
            joined[followed == index] = array[followed == index]
        rows[name] = joined
    diverged = np.flatnonzero(rows["diverged"])
    reason, index, stopped = "", -1, False
    if diverged.size:
        index = int(diverged[0])
        source = passes[int(followed[index])]
        reason, stopped = source.health.divergence_reason or "diverged", source.health.stopped
    health = summarise_health(
        last.t,
        float(last.t[1] - last.t[0]) if len(last.t) > 1 else 0.0,
        rows["dropped"],
        rows["pinned"],
        last.parameter_names,
        reason=reason,
        divergence_index=index,
        stopped=stopped,
    )
    shares = {point: float(np.mean(followed == i)) for i, point in enumerate(INJECTIONS)}
    record = {"chosen": INJECTIONS[int(followed[-1])], "decisions": decisions, "share": shares}
    return dataclasses.replace(
        last,
        **{name: array for name, array in rows.items() if array is not None},
        health=health,
        smoother_inputs=None,
        settings={**last.settings, "settings": settings.to_dict(), "remnant_injection": record},
    )


def _delay_free_model(model: str, pursuit: bool = False) -> InternalModel:
    """The internal model without its delays (cached): they act on the inputs.

    ``pursuit``: the preview model's pursuit form (``anticipation_time = 0``), whose far
    view reads the recorded target ``ft`` itself (``tau_f = 0``: nothing shown ahead,
    :func:`~manualcontrol.estimators.members.internal_model.build_internal_model`); otherwise
    it reads the anticipated target ``ft(t + tau_a)``, which a recording of a pursuit
    display does not hold.
    """
    key = (model, pursuit)
    if key not in _MODELS:
        _MODELS[key] = build_internal_model(model, 0, pursuit=pursuit)
    return _MODELS[key]


class RML(PilotFilter):
    """Recursive maximum likelihood over a Kalman filter bank (module docstring).

    Parameters
    ----------
    settings
        A :class:`RMLSettings`; keyword arguments replace its fields (or build one).

    Examples
    --------
    >>> from manualcontrol.pilots import Pilot, simulate
    >>> recording = simulate(Pilot("precision"), "popovici2017", "popovici2017", seed=0)
    >>> result = RML(model="precision").estimate(recording)
    >>> round(result.final()["K_p"], 1)
    1.5

    """

    name: ClassVar[str] = "rml"
    settings_type = RMLSettings
    # the numba kernels, imported (with numba) on first read: the C port runs without them
    _step_kernel = LazyKernel("manualcontrol.estimators.members._rml_kernels", "bank_step")
    _step_many_kernel = LazyKernel(
        "manualcontrol.estimators.members._rml_kernels", "bank_step_many"
    )
    _native_binding = _rml_native

    def __init__(self, settings: RMLSettings | None = None, **changes: Any) -> None:
        super().__init__(settings, **changes)
        # the pursuit form reads ft, as the family's filters (PilotFilter.__init__) do
        self._internal = _delay_free_model(self._settings.model, self._settings.pursuit)
        self._stepped: _SteppedChoice | None = None  # remnant_injection="choose-causal"

    def estimate(self, recording: Any, **options: Any) -> Any:
        """Run the filter over a recording; see :meth:`PilotFilter.estimate`.

        With ``remnant_injection="choose"`` the recording is identified twice, the
        remnant model at the perception and at the stick, and the pass kept is the one
        whose model (second-half medians) lies nearer the describing function measured
        at the forcing frequencies (:func:`~manualcontrol.estimators.analysis.frequency.
        response_error`, gain and phase gaps each in units of the cross-check's pass
        mark, 2 dB and 10 deg). Why not the likelihood: where the remnant comes from is
        what the time domain cannot tell apart from the pilot's own dynamics. A
        perception remnant passes through the modelled delay and neuromuscular system,
        which then bend to shape its spectrum (the human-like suite's pilot with a
        resonant remnant at the stick: the likelihood prefers the perception model while
        it biases ``tau_v``; ``benchmarks/remnant_choice.py``). At the forcing frequencies the
        remnant averages out, so the describing function judges the pilot alone. The
        forcing comes from ``forcing=`` or the recording's metadata; the choice and both
        gaps are in ``result.settings["remnant_injection"]`` (``target_period=``, where no
        forcing is known, is the forcing's period).
        """
        injection = self._settings.remnant.injection
        if injection == CHOOSE_CAUSAL_INJECTION:
            return self._estimate_choosing_causally(recording, **options)
        if injection != CHOOSE_INJECTION:
            return super().estimate(recording, **options)
        settings = self._settings
        describing = run_describing_function(
            settings,
            recording,
            options.get("forcing"),
            options.get("target_period"),
            f"remnant_injection={settings.remnant.injection!r}",
        )
        passes, gaps = {}, {}
        for point in INJECTIONS:
            passes[point] = self.configure(remnant_injection=point).estimate(recording, **options)
            values = second_half_values(passes[point])
            if all(math.isfinite(v) for v in values.values()):
                gaps[point] = response_error(describing, settings.model, values)
            else:
                gaps[point] = (math.inf, math.inf)
        chosen = min(
            INJECTIONS, key=lambda p: gaps[p][0] / FAR_GAIN_DB + gaps[p][1] / FAR_PHASE_DEG
        )
        kept = passes[chosen]
        record = {  # None for a pass without finite estimates (JSON has no infinity)
            "chosen": chosen,
            "gain_error_db": {
                p: gaps[p][0] if math.isfinite(gaps[p][0]) else None for p in INJECTIONS
            },
            "phase_error_deg": {
                p: gaps[p][1] if math.isfinite(gaps[p][1]) else None for p in INJECTIONS
            },
        }
        return dataclasses.replace(
            kept,
            settings={
                **kept.settings,
                "settings": settings.to_dict(),
                "remnant_injection": record,
            },
        )

    def _estimate_choosing_causally(self, recording: Any, **options: Any) -> Any:
        """Both remnant points side by side; each sample's estimate from the one chosen so far.

        ``remnant_injection="choose-causal"``: the choice of ``"choose"`` made online. Both
        passes run over the recording (each a causal filter). From half a forcing period
        on, every :data:`CAUSAL_CHOICE_INTERVAL` seconds, the describing function of the
        samples so far is measured by least squares at the forcing lines
        (:func:`~manualcontrol.estimators.analysis.frequency.describing_function`,
        ``method="least-squares"``: any length, where the Fourier method needs whole
        periods), and each pass's model (its medians over the second half of the samples
        so far, as ``"choose"`` takes the run's second half) is scored against it as
        ``"choose"`` scores. The estimates from that sample on are the nearer pass's,
        until the next decision; before the first, the perception pass's (the default).
        So every sample's estimate uses the samples up to it alone. Half a period: the
        least-squares fit then tells lines one harmonic apart with its coefficients'
        variance inflated by a factor under two (their sinusoids drift half a cycle
        apart over the stretch). The decisions are in
        ``result.settings["remnant_injection"]``; the result cannot be smoothed (its
        trace joins two filters), a smoothed estimate takes ``"choose"``.
        """
        if options.get("smooth") or options.get("smoother_inputs"):
            raise ValueError(
                "remnant_injection='choose-causal' joins two filters' traces at the samples "
                "the choice changes, which no smoother can run back over: for a smoothed "
                "estimate give remnant_injection='choose' (the whole run's choice)"
            )
        settings = self._settings
        forcing = options.get("forcing")
        if forcing is None and recording.metadata.get("forcing") is not None:
            forcing = ForcingPair.from_dict(recording.metadata["forcing"])
        if not isinstance(forcing, ForcingPair):
            raise ValueError(
                "remnant_injection='choose-causal' measures the describing function of the "
                "samples so far at the forcing's lines: give forcing= (the run's ForcingPair) "
                "or a recording whose metadata holds it"
            )
        passes = [
            self.configure(remnant_injection=point).estimate(recording, **options)
            for point in INJECTIONS
        ]
        choice = _CausalChoice(settings, forcing, recording.dt, self.sample_keys)
        if "e" in choice.recorded and "e" not in recording:
            recording = recording.with_error_signal()
        size = len(recording)
        followed = np.zeros(size, dtype=np.int64)  # index into INJECTIONS, the input first
        for samples in choice.decision_counts(size):
            signals = {name: recording[name][:samples] for name in choice.recorded}
            values = [second_half_values(result, samples) for result in passes]
            followed[samples - 1 :] = choice.decide(recording.t[:samples], signals, values)
        return _joined(passes, followed, settings, choice.decisions)

    def reset(
        self,
        dt: float = 0.01,
        *,
        var_u0: float | None = None,
        var_e0: float | None = None,
        t0: float = 0.0,
        forcing: ForcingPair | None = None,
    ) -> None:
        """Start from the initial belief; see :meth:`PilotFilter.reset`.

        ``forcing`` (the run's ForcingPair) is read by ``remnant_injection="choose-causal"``
        alone, which needs it: both passes are then reset, and :meth:`update` steps both
        and answers with the one followed, deciding as :meth:`estimate` does at the same
        samples, so the two give the same numbers.
        """
        self._stepped = None
        if self._settings.remnant.injection != CHOOSE_CAUSAL_INJECTION:
            super().reset(dt, var_u0=var_u0, var_e0=var_e0, t0=t0)
            return
        if not isinstance(forcing, ForcingPair):
            raise ValueError(
                "remnant_injection='choose-causal' measures the describing function of the "
                "samples so far at the forcing's lines: reset needs forcing= (the run's "
                f"ForcingPair), got {forcing!r}"
            )
        passes = [self.configure(remnant_injection=point) for point in INJECTIONS]
        for estimator in passes:
            estimator.reset(dt, var_u0=var_u0, var_e0=var_e0, t0=t0)
        choice = _CausalChoice(self._settings, forcing, dt, self.sample_keys)
        self._stepped = _SteppedChoice(choice, passes, t0)

    def batchable(self) -> str:
        """Why a batch (``FilterBatch``) cannot step this filter; '' where it can."""
        if self._settings.remnant.injection == CHOOSE_CAUSAL_INJECTION:
            return (
                "remnant_injection='choose-causal' decides between two passes in Python "
                "every few seconds and is not batched; give remnant_injection='input' or "
                "'output', or step it one stream at a time (an EstimatorObserver per env)"
            )
        return ""

    #: :meth:`reset` takes the run's forcing (the online observer hands it over).
    reads_forcing: ClassVar[bool] = True

    def estimated_names(self, dt: float) -> tuple[str, ...]:
        """See :meth:`PilotFilter.estimated_names`; both passes of a choice estimate alike."""
        if self._settings.remnant.injection == CHOOSE_CAUSAL_INJECTION:
            return self.configure(remnant_injection=INJECTIONS[0]).estimated_names(dt)
        return super().estimated_names(dt)

    @property
    def resolved(self) -> ResolvedSettings:
        """Numbers resolved at the last :meth:`reset` (the perception pass's when choosing)."""
        if self._stepped is not None:
            return self._stepped.passes[0].resolved
        return super().resolved

    def update(self, sample: Mapping[str, float]) -> Any:
        """Consume one sample; see :meth:`PilotFilter.update` (and :meth:`reset`)."""
        if self._stepped is not None:
            return self._stepped.update(sample, "estimate")
        return super().update(sample)

    def update_plain(self, sample: Mapping[str, float]) -> dict[str, Any]:
        """:meth:`update` as plain data; see :meth:`PilotFilter.update_plain`."""
        if self._stepped is not None:
            return self._stepped.update(sample, "plain")
        return super().update_plain(sample)

    def update_quiet(self, sample: Mapping[str, float]) -> float:
        """:meth:`update` without its answer; see :meth:`PilotFilter.update_quiet`."""
        if self._stepped is not None:
            return self._stepped.update(sample, "quiet")
        return super().update_quiet(sample)

    def latest(self) -> tuple[Any, Any]:
        """Views of the last estimate (the followed pass's when choosing); see the shell's."""
        if self._stepped is not None:
            return self._stepped.passes[self._stepped.followed].latest()
        return super().latest()

    def latest_plain(self, t: float) -> dict[str, Any]:
        """The last estimate's plain dicts (the followed pass's when choosing)."""
        if self._stepped is not None:
            return self._stepped.passes[self._stepped.followed].latest_plain(t)
        return super().latest_plain(t)

    @property
    def settings(self) -> RMLSettings:
        """The frozen settings."""
        return self._settings

    def _start(self, resolved: ResolvedSettings, common: CommonArrays) -> None:
        settings = self._settings
        if settings.remnant.injection == CHOOSE_INJECTION:
            raise ValueError(
                "remnant_injection='choose' runs the whole recording with the remnant at the "
                "perception and at the stick and keeps the pass the describing function "
                "agrees with: offline only (estimate); online give 'input' or 'output'"
            )
        internal = self._internal
        names = internal.parameter_names
        dt = float(common.cfg[0])
        if settings.noise.noise_input == "euler":
            # a random walk's variance a sample: Q dt^2 at 100 Hz, Q (0.01 s) dt at dt
            # (module docstring, "Sample rates"); R is scaled to match in the core
            common.cfg[core.CFG_GAMMA2] = PAPERS_DT * dt
        has_remnant = settings.remnant.model != "none"
        omega = settings.remnant_break_value
        causal = resolved.var_e0 is None
        var_e0 = max(resolved.var_e0 or 0.0, settings.noise.variance_floor)
        # the intensity is learned relative to the error variance of the first window:
        # the remnant's stationary variance is remnant_variance * var(e) to begin with
        log_intensity = math.log(settings.remnant.variance)
        window = round(settings.noise.window / dt)
        slots, mean, p0, q, lo, hi, labels = [], [], [], [], [], [], []
        for name in resolved.estimated:
            j = names.index(name)
            slots.append(j)
            mean.append(common.p[j])
            p0.append(resolved.P0[name])
            q.append(resolved.Q[name])
            lo.append(common.report.lo[j])
            hi.append(common.report.hi[j])
            labels.append(name)
        if has_remnant and settings.remnant.learn_intensity:
            slots.append(core.SLOT_LOG_INTENSITY)
            mean.append(log_intensity)
            p0.append(settings.remnant.intensity_P0)
            q.append(settings.remnant.intensity_Q)
            lo.append(log_intensity - INTENSITY_RANGE)
            hi.append(log_intensity + INTENSITY_RANGE)
            labels.append("log_intensity")
        if has_remnant and settings.remnant.learn_break:
            slots.append(core.SLOT_LOG_BREAK)
            mean.append(math.log(omega))
            p0.append(settings.remnant.intensity_P0)
            q.append(settings.remnant.intensity_Q)
            lo.append(math.log(BREAK_RANGE[0]))
            hi.append(math.log(BREAK_RANGE[1]))
            labels.append("log_break")
        n_t = len(mean)
        n_c = internal.n_states
        n_s = n_c + (1 if has_remnant else 0)
        members = 2 * n_t + 1
        inject = core.INJECT_INPUT if settings.remnant.injection == "input" else core.INJECT_OUTPUT
        config = core.BankConfig(
            cfg=common.cfg,
            slot=np.array(slots, dtype=np.int64),
            lo=np.array(lo, dtype=np.float64),
            hi=np.array(hi, dtype=np.float64),
            q=np.array(q, dtype=np.float64),
            step=settings.bank.step,
            substeps=euler_substeps(dt, settings.bank.substeps),
            inject=inject,
            has_remnant=has_remnant,
            remnant=np.array([log_intensity, math.log(omega)]),
            estimated=common.estimated,
            noise_first=round(settings.bank.noise_first / dt) + (window if causal else 0),
            base=np.array([math.log(var_e0), float(window if causal else 0)]),
            variance_score=self._variance_score(),
            spread_cap=self._spread_cap(np.array(lo), np.array(hi)),
            drift_rule=np.array(
                [
                    settings.drift.gain,
                    min(1.0, dt / settings.drift.window),  # a window under a sample: one
                    settings.drift.threshold,
                ]
            ),
            remnant_weight=np.array([settings.r2_remnant_value, float(self._remnant_gain_index())]),
        )
        state_covariance = np.zeros((members, n_s, n_s))
        for i in range(members):
            for c in range(n_c):
                state_covariance[i, c, c] = settings.noise.P0_canonical
            if has_remnant:
                state_covariance[i, n_c, n_c] = settings.remnant.variance * var_e0
        n_in = len(internal.input_names)
        belief = core.BankBelief(
            th=np.array(mean, dtype=np.float64),
            P=np.diag(np.array(p0, dtype=np.float64)),
            X=np.zeros((members, n_s)),
            PX=state_covariance,
            prev_in=np.zeros(n_in),
            p=common.p,
            sc=common.sc,
            drift=np.vstack([np.zeros((2, n_t)), np.ones((1, n_t)), np.zeros((1, n_t))]),
        )
        n_p = len(names)
        scratch = core.BankScratch(
            L=np.zeros((n_t, n_t)),
            points=np.zeros((members, n_t)),
            z=np.zeros(members),
            S=np.zeros(members),
            dz=np.zeros(n_t),
            dS=np.zeros(n_t),
            g=np.zeros(n_t),
            Lam=np.zeros((n_t, n_t)),
            LamL=np.zeros((n_t, n_t)),
            B=np.zeros((n_t, n_t)),
            xi=np.zeros((1, n_t)),
            Phi=np.zeros((n_s, n_s)),
            sub=np.zeros((n_s, n_s)),
            Q=np.zeros((n_s, n_s)),
            T=np.zeros((n_s, n_s)),
            H=np.zeros((1, n_s)),
            r=np.zeros(1),
            R=np.zeros((1, 1)),
            work=kalman_work(n_s, 1, log_det=False),
            xs=np.zeros(n_c),
            f=np.zeros(n_c),
            F=np.zeros((n_c, n_c)),
            dfdp=np.zeros((n_c, n_p)),
            dgdx=np.zeros(n_c),
            dgdp=np.zeros(n_p),
            point_p=np.zeros(n_p),
            in_use=np.zeros(n_in),
            variance=np.zeros(n_p),
            scalars=np.zeros(3),
            h_dir=np.zeros(n_t),
            prior=np.zeros((2, n_t)),
        )
        longest = LONGEST_DELAY + (settings.anticipation_time or 0.0)
        lines = core.DelayLines(
            hist=np.zeros((n_in, round(longest / dt) + 8)),
            delay_slot=names.index(internal.model.delay_parameter),
            extra_slot=np.array(
                [
                    names.index(ANTICIPATED_PARAMETER) if name == "ft_ahead" else -1
                    for name in internal.input_names
                ],
                dtype=np.int64,
            ),
            point_in=np.zeros(n_in),
        )
        self._records = (
            internal.kernel(()),
            config,
            lines,
            belief,
            common.monitor,
            common.report,
            scratch,
        )
        self._labels = tuple(labels)

    def _spread_cap(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Largest offset of a bank member in each parameter (inf where unlimited)."""
        span = hi - lo
        limit = self._settings.bank.spread_limit
        if limit == 0.0:
            return np.full(span.shape, np.inf)
        return np.where(np.isfinite(span), limit * span, np.inf)

    def _remnant_gain_index(self) -> int:
        """Model index of the gain the remnant passes to the stick (-1: at it, or no weight)."""
        settings = self._settings
        if settings.remnant.injection == "output" or settings.r2_remnant_value == 0.0:
            return -1
        return self._internal.parameter_names.index(_REMNANT_GAIN)

    def _variance_score(self) -> np.ndarray:
        """Per model parameter: whether the variance part of the score moves it."""
        settings = self._settings
        names = self._internal.parameter_names
        if settings.bank.variance_score == "all":
            return np.ones(len(names), dtype=np.bool_)
        on_path = settings.remnant.model != "none" and settings.remnant.injection == "input"
        branches = self._internal.branch_parameters
        return np.array([on_path and name not in branches for name in names], dtype=np.bool_)

    def _new_output(self, n: int, store: bool) -> core.BankOutput:
        n_p = len(self._internal.parameter_names)
        n_t = len(self._labels)
        rows = n if store else 0
        return core.BankOutput(
            **output_arrays(n, n_p),
            th_prior=np.zeros((rows, n_t)),
            P_prior=np.zeros((rows, n_t, n_t)),
            th_post=np.zeros((rows, n_t)),
            P_post=np.zeros((rows, n_t, n_t)),
            extra=np.zeros((n, 3)),
        )

    def _state_traces(self, out: core.BankOutput) -> tuple[tuple[str, ...], Any]:
        """The centre filter's remnant estimate, the remnant intensity and break frequency."""
        if self._settings.remnant.model == "none":
            return (), None
        return ("remnant", "remnant_intensity", "remnant_break"), out.extra

    def _smoother_inputs(self, out: core.BankOutput) -> Any:
        """One random-walk block over the parameters (the noise parameters left out)."""
        model_names = self._internal.parameter_names
        block = SmootherBlock(
            kind="random-walk",
            x_filtered=out.th_post,
            P_filtered=out.P_post,
            x_predicted=out.th_prior,
            P_predicted=out.P_prior,
            link=None,
            parameters={name: i for i, name in enumerate(self._labels) if name in model_names},
        )
        report = self._common.report
        return SmootherInputs.of_report((block,), model_names, report)
