"""The parameters' process noise chosen by cross-validation, for offline (smoothed) runs.

A filter of the family treats each parameter as a random walk whose variance per
second (``Q``) comes from a preset: the thesis's values, tuned for 20-s sigmoids of
``tau_f`` (Sec. V-B-2). How fast a pilot's parameters really vary is what the analysis
wants to learn, and the smoothed estimate depends on it: too small a ``Q`` smears a
change over tens of seconds, too large a one lets the parameters follow the remnant.
Offline the whole run is available, so the variance can be chosen by how well the
estimates predict data they were not fitted to (the classic choice of a smoothing
parameter by cross-validation; Wahba 1990, ch. 4):

1. the run's stick signal ``u`` is split into ``folds`` interleaved sets of
   ``gap``-second stretches (stretch ``j`` belongs to fold ``j mod folds``; the samples
   of the first ``window`` seconds, from which the filter takes its initial variances
   with ``initial_variance="first-window"``, are never held out);
2. for each scale ``c`` of ``scales`` and each fold, the filter runs with every pilot
   parameter's resolved ``Q`` multiplied by ``c`` (the remnant's intensity in the RML
   keeps its own) and the fold's stretches marked dropped (NaN: the filter predicts
   through them), and is smoothed over the run;
3. the isolated pilot model is resimulated with those smoothed traces
   (:func:`~manualcontrol.estimators.analysis.metrics.resimulate`, driven by the recorded
   perceptions), and its error against ``u``, band-passed to the forcing band (a
   second-order Butterworth filter run forwards and backwards over the whole run, from
   half the lowest to twice the highest forcing frequency), is summed over the
   held-out samples and the folds (the zero-phase filter spreads each error over about
   a period of the band's low edge, so a small part of a fold's sum comes from the
   errors in the fitted stretches beside it); the error is divided by the band-passed
   power of ``u`` outside the first window, so it reads as a fraction (a held-out
   1 - VAF);
4. the scale with the smallest error is chosen, and the result is the filter's run at
   that scale, smoothed over the whole run.

Why the forcing band: the resimulation integrates the low-frequency remnant that the
closed loop suppresses (on the double integrator, remnant break 0.01 rad/s, the
held-out errors are most of ``u``'s power whatever the scale), so without the
band-pass the choice follows the remnant; within the band the forcing carries most of
``u`` (less so on the double integrator, below). Why held-out data: the same comparison
on the data the smoother saw (the whole run's spectrum at the forcing frequencies)
picked the largest scale in most runs and raised the errors where the gains are
constant.

Where it helps: with the DEKF, whose faithful preset is far from what runs with
remnant need, it lowers most errors. With the RML it helps where the remnant is
broadband (the single integrator's 10-rad/s break, Levison's 3 rad/s) and where the
parameters vary faster than the preset allows; on the double integrator with its
0.01-rad/s remnant keep the preset, because within the forcing band the low-frequency
remnant still dominates the held-out errors, and the choice there is fragile (one
sample moved at a window's edge can flip it). Tried and not kept: the filter's own
prediction through the held-out stretches (no smoothing, no resimulation), which chose
the largest scale on constant double-integrator batches.

Each run costs ``len(scales) * folds + 2`` filter passes (smoothed) and ``len(scales) *
folds`` resimulations: 22 and 20 with the defaults (each filter pass ``restarts + 1``
passes for a filter with restarts, :mod:`~manualcontrol.estimators.members.pilot_filter`).

Measured figures, each with the command that reproduces it, are in
``docs/estimators.md`` (the ``-cv`` twins): ``manualcontrol bench SUITE --estimators
rml-smoothed,rml-cv`` (or ``dekf-smoothed,dekf-cv``) sets the twins side by side.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import butter, sosfiltfilt

from manualcontrol.envs._validation import check_int, check_positive
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair, Multisine
from manualcontrol.estimators.analysis.metrics import resimulate
from manualcontrol.estimators.members.pilot_filter import PilotFilter
from manualcontrol.estimators.members.pilot_rules import GenericValuesWarning
from manualcontrol.estimators.offline.smoothed_estimator import SmoothedEstimator
from manualcontrol.estimators.protocol import EstimationResult, report_progress

__all__ = [
    "DEFAULT_SCALES",
    "OPTION_KEYS",
    "CrossValidatedEstimator",
    "NoiseScaleChoice",
    "build_cross_validated",
    "choose_noise_scale",
]

#: Multipliers of the filter's resolved ``Q`` tried by default.
DEFAULT_SCALES: tuple[float, ...] = (0.3, 1.0, 3.0, 10.0)
#: Band edges relative to the forcing's lowest and highest frequencies.
BAND_MARGIN = 2.0
#: Settings keys of the cross-validated members (suite files, ``make_estimator``).
OPTION_KEYS = ("cv_scales", "cv_folds", "cv_gap", "cv_band")


@dataclass(frozen=True)
class NoiseScaleChoice:
    """What :func:`choose_noise_scale` tried and chose.

    ``errors[i]`` is the held-out, band-passed error of ``scales[i]`` (a fraction of
    the band-passed power of ``u``), the sum of ``fold_errors[i]`` over the folds;
    ``result`` the run at ``scale``, smoothed.
    """

    scales: tuple[float, ...]
    errors: tuple[float, ...]
    fold_errors: tuple[tuple[float, ...], ...]
    scale: float
    folds: int
    gap: float
    band: tuple[float, float]
    result: EstimationResult

    def as_dict(self) -> dict[str, Any]:
        """Plain values (without the result), as the result's settings record them."""
        return {
            "scales": list(self.scales),
            "errors": list(self.errors),
            "fold_errors": [list(errors) for errors in self.fold_errors],
            "scale": self.scale,
            "folds": self.folds,
            "gap": self.gap,
            "band": list(self.band),
        }


def _is_vector(value: Any) -> bool:
    """A sequence or a 1-D array (not a string)."""
    if isinstance(value, (str, bytes)):
        return False
    return isinstance(value, (Sequence, np.ndarray)) and np.ndim(value) == 1


def _check_scales(scales: Any) -> tuple[float, ...]:
    if not _is_vector(scales) or len(scales) == 0:
        raise ValueError(f"scales must be a non-empty sequence of numbers > 0, got {scales!r}")
    checked = tuple(check_positive("scales", value) for value in scales)
    if len(set(checked)) != len(checked):
        raise ValueError(f"scales must be distinct, got {scales!r}")
    return checked


def _check_band(band: Any) -> tuple[float, float] | None:
    """``(low, high)`` with ``0 < low < high`` (the Nyquist bound needs the sample time)."""
    if band is None:
        return None
    if not _is_vector(band) or len(band) != 2:
        raise ValueError(f"band must be (low, high) in rad/s, got {band!r}")
    low, high = (check_positive("band", value) for value in band)
    if not low < high:
        raise ValueError(f"band must satisfy 0 < low < high (rad/s), got {band!r}")
    return low, high


def _band(band: Any, recording: Recording, forcing: Any) -> tuple[float, float]:
    nyquist = math.pi / recording.dt
    checked = _check_band(band)
    if checked is not None:
        if not checked[1] < nyquist:
            raise ValueError(
                f"band must satisfy 0 < low < high < {nyquist:g} rad/s (the Nyquist "
                f"frequency of dt = {recording.dt:g} s), got {band!r}"
            )
        return checked
    if not isinstance(forcing, ForcingPair):
        if "forcing" not in recording.metadata:
            given = "" if forcing is None else f" (forcing is a {type(forcing).__name__})"
            raise ValueError(
                "band: the forcing's multisine frequencies set the band by default, and there "
                f"is no ForcingPair{given} nor a 'forcing' in the recording's metadata; pass "
                "forcing= (`--forcing PRESET`) or band=(low, high) in rad/s (`cv_band` in "
                "suite files and `--set`)"
            )
        forcing = ForcingPair.from_dict(recording.metadata["forcing"])
    parts = [f for f in (forcing.target, forcing.disturbance) if isinstance(f, Multisine)]
    if not parts:
        raise ValueError(
            "band: the forcing has no multisine whose frequencies set the band; pass "
            "band=(low, high) in rad/s (`cv_band` in suite files and `--set`)"
        )
    frequencies = np.concatenate([part.frequencies for part in parts])
    low = float(frequencies.min()) / BAND_MARGIN
    high = min(float(frequencies.max()) * BAND_MARGIN, 0.9 * nyquist)
    return low, high


def _copy(estimator: PilotFilter, **changes: Any) -> PilotFilter:
    """The filter built again (with ``changes``), its construction's warning not repeated.

    The user's own construction said which parameters it holds at generic values
    (:class:`~manualcontrol.estimators.members.pilot_filter.GenericValuesWarning`).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GenericValuesWarning)
        return type(estimator)(estimator.settings, **changes)


def _held_out(
    t: NDArray[np.float64], first: int, folds: int, gap: float
) -> list[NDArray[np.bool_]]:
    """One boolean mask per fold: its ``gap``-second stretches from sample ``first`` on."""
    eligible = np.arange(t.shape[0]) >= first
    stretch = np.floor((t - t[0]) / gap).astype(np.int64)
    return [eligible & (stretch % folds == fold) for fold in range(folds)]


def choose_noise_scale(
    estimator: PilotFilter,
    recording: Recording,
    *,
    scales: Sequence[float] = DEFAULT_SCALES,
    folds: int = 5,
    gap: float = 4.0,
    band: tuple[float, float] | None = None,
    forcing: Any = None,
    target_period: float | None = None,
) -> NoiseScaleChoice:
    """Choose the multiplier of the parameters' ``Q`` by cross-validation (module docstring).

    Parameters
    ----------
    estimator
        A filter of the family on a pilot model (DEKF, RML, joint or dual UKF); it is
        not run itself (copies with its settings are).
    recording
        The run; ``u`` and the filter's perceptions.
    scales
        Multipliers of the filter's resolved ``Q`` to try (each > 0, distinct).
    folds, gap
        Number of folds (>= 2) and length of each held-out stretch (s, > 0); the run
        after the first ``window`` seconds must hold at least two cycles of ``folds``
        stretches.
    band
        ``(low, high)`` (rad/s) of the error's band-pass; by default from the
        forcing's multisine frequencies (``forcing`` if it is a
        :class:`~manualcontrol.envs.signals.ForcingPair`, else the recording's metadata).
    forcing, target_period
        As for the filter's ``estimate`` (the preview model's target ahead), and the
        forcing whose frequencies set the band.

    Returns
    -------
    NoiseScaleChoice
        The scales, their held-out errors (total and per fold), the chosen scale and its
        smoothed run, whose ``settings["cross_validation"]`` records the choice.

    Raises
    ------
    TypeError
        ``estimator`` is not a pilot filter of the family, ``recording`` not a Recording.
    ValueError
        A bad ``scales``, ``folds``, ``gap`` or ``band``; a run too short for the folds;
        no band (no multisine forcing and no ``band``); no scale with a finite error.

    """
    if not isinstance(estimator, PilotFilter):
        raise TypeError(
            "estimator must be a filter of the family on a pilot model (DEKF, RML, "
            f"JointUKF, DualUKF), got {estimator!r}"
        )
    if not isinstance(recording, Recording):
        raise TypeError(f"recording must be a Recording, got {recording!r}")
    scales = _check_scales(scales)
    folds = check_int("folds", folds, minimum=2)
    gap = check_positive("gap", gap)
    t = np.asarray(recording.t)
    window = estimator.settings.noise.window
    # the samples the filter's first-window variances read (estimate: 0 .. n_window)
    first = min(round(window / recording.dt) + 1, t.shape[0] - 1)
    if t[-1] - t[first] < 2 * folds * gap:
        raise ValueError(
            f"gap: {folds} folds of {gap:g} s (folds, gap; `cv_folds`, `cv_gap` in suite "
            f"files and `--set`) need at least {2 * folds * gap:g} s of the run after its "
            f"first {window:g} s (window); the run has {max(t[-1] - t[first], 0.0):g} s"
        )
    low, high = _band(band, recording, forcing)
    sos = butter(2, [low, high], btype="band", fs=2.0 * math.pi / recording.dt, output="sos")
    options = {"forcing": forcing, "target_period": target_period}

    u = np.asarray(recording.u)
    measured = np.isfinite(u)
    power = float(np.sum(sosfiltfilt(sos, np.where(measured, u, 0.0))[first:] ** 2))
    if not power > 0.0:
        raise ValueError(
            f"band: the run's u has no power in the band {low:g}-{high:g} rad/s after its "
            f"first {window:g} s"
        )
    probe = _copy(estimator)
    probe.estimate(recording, **options)
    Q = dict(probe.resolved.Q)

    def scaled(scale: float) -> PilotFilter:
        """A copy of the filter with every resolved ``Q`` multiplied by ``scale``."""
        return _copy(estimator, Q={n: q * scale for n, q in Q.items()})

    masks = _held_out(t, first, folds, gap)
    fold_errors = []
    for index, scale in enumerate(scales):
        report_progress(
            f"cross-validation: Q scale {scale:g} ({index + 1} of {len(scales)}), "
            f"{folds} held-out folds"
        )
        variant = scaled(scale)
        per_fold = []
        for held in masks:
            blanked = recording.with_signals(u=np.where(held, np.nan, u))
            fitted = variant.estimate(blanked, smooth=True, **options)
            with np.errstate(all="ignore"):  # a diverged pass may overflow: an inf error
                output = resimulate(fitted, recording, **options)
                error = sosfiltfilt(sos, np.where(measured, u - output, 0.0))
                held_error = float(np.sum(error[held & measured] ** 2)) / power
            per_fold.append(held_error if math.isfinite(held_error) else math.inf)
        fold_errors.append(tuple(per_fold))
    errors = [math.fsum(per_fold) for per_fold in fold_errors]
    if not any(math.isfinite(error) for error in errors):
        raise ValueError(
            f"no scale of {list(scales)} gave a finite held-out error: every pass diverged"
        )
    best = int(np.argmin(errors))
    result = scaled(scales[best]).estimate(recording, smooth=True, **options)
    choice = NoiseScaleChoice(
        scales, tuple(errors), tuple(fold_errors), scales[best], folds, gap, (low, high), result
    )
    settings = {**result.settings, "cross_validation": choice.as_dict()}
    return dataclasses.replace(choice, result=dataclasses.replace(result, settings=settings))


class CrossValidatedEstimator(SmoothedEstimator):
    """A filter whose whole-run results are smoothed at a cross-validated ``Q`` scale.

    Parameters
    ----------
    filter
        The online filter (a family member on a pilot model).
    scales, folds, gap, band
        As for :func:`choose_noise_scale`.
    """

    def __init__(
        self,
        filter: Any,
        *,
        scales: Sequence[float] = DEFAULT_SCALES,
        folds: int = 5,
        gap: float = 4.0,
        band: tuple[float, float] | None = None,
    ) -> None:

        if not isinstance(filter, PilotFilter):
            raise TypeError(
                f"filter must be a filter of the family on a pilot model, got {filter!r}"
            )
        super().__init__(filter)
        self._options = {
            "scales": _check_scales(scales),
            "folds": check_int("folds", folds, minimum=2),
            "gap": check_positive("gap", gap),
            "band": _check_band(band),
        }

    def choose(self, recording: Recording, **options: Any) -> NoiseScaleChoice:
        """:func:`choose_noise_scale` with this estimator's options."""
        return choose_noise_scale(self.filter, recording, **self._options, **options)

    def estimate(self, recording: Recording, **options: Any) -> EstimationResult:
        """The smoothed run at the chosen scale (``options``: ``forcing``, ``target_period``)."""
        unknown = set(options) - {"forcing", "target_period"}
        if unknown:
            raise TypeError(
                f"a cross-validated estimator takes forcing= and target_period=, got "
                f"{', '.join(sorted(unknown))}"
            )
        return self.choose(recording, **options).result

    def __repr__(self) -> str:
        options = ", ".join(f"{key}={value!r}" for key, value in self._options.items())
        return f"CrossValidatedEstimator({self.filter!r}, {options})"


def build_cross_validated(
    build: Callable[[Mapping[str, Any]], Any], settings: Mapping[str, Any]
) -> CrossValidatedEstimator:
    """A ``-cv`` twin built from a settings table.

    The ``cv_*`` keys (:data:`OPTION_KEYS`) are the cross-validation's options, the
    rest the filter's (built by ``build``).
    """
    unknown = [k for k in settings if k.startswith("cv_") and k not in OPTION_KEYS]
    if unknown:
        raise TypeError(
            f"unknown cross-validation setting(s) {', '.join(map(repr, unknown))}; "
            f"known: {', '.join(OPTION_KEYS)}"
        )
    rest = {k: v for k, v in settings.items() if k not in OPTION_KEYS}
    options = {k[3:]: settings[k] for k in OPTION_KEYS if k in settings}
    return CrossValidatedEstimator(build(rest), **options)
