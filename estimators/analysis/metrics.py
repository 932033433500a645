"""How good an estimate is: VAF, moving VAF, NRMSE, relative bias, innovation consistency.

Parameter errors (thesis Part I Sec. IV-E; Part II Sec. 5.3)
--------------------------------------------------------------
* NRMSE, eq. 37 (Part II eq. 5.6): the RMS of ``estimate - truth`` divided by
  ``|mean(truth)|``; for parameters whose mean true value is near zero
  (``|mean| < 0.05``) the plain RMSE instead (Part II eq. 5.7).
* Relative bias: the mean of ``estimate - truth`` divided by ``|mean(truth)|`` (the plain
  mean error for near-zero parameters), the "mean relative parameter bias" of Sec.
  IV-E-1: positive when the parameter is overestimated.

Variance accounted for
----------------------
Every VAF is eq. 38, ``(1 - sum (a - b)^2 / sum a^2) * 100 %`` of a reference signal
``a`` and a model signal ``b``, over the scored samples where both are finite (eq. 38
divides by ``sum a^2``, not the variance; for the zero-mean control signals of
tracking tasks the two agree). They differ in what ``a`` and ``b`` are:

* **one-step VAF**: ``b`` is the filter's one-step prediction ``g(x^-_k, theta^-_k)``
  (:attr:`EstimationResult.prediction`, Popovici et al.'s "filter output"), made from
  the states corrected with every earlier sample of ``u``; ``a`` is ``u`` as measured,
  remnant included. It tells how well the filter follows the stick one sample ahead,
  not how good the identified parameters are: a filter whose states absorb the
  remnant scores high with wrong parameters. It has no ceiling of its own.
* **resimulated VAF against u** (``resimulated_vaf``): ``b`` is the output of the
  isolated pilot model with the identified parameter traces, started at rest and
  driven by the perceptions as recorded (the error ``e``; or the previewed target
  ``ft(t + tau_f)`` at the identified ``tau_f`` and the output ``y``; the pursuit form,
  ``tau_f = 0``, reads the recorded ``ft``), see :func:`resimulate`; ``a`` is ``u`` as
  measured, remnant included. The recorded perceptions carry the remnant's effect on
  the loop but not the remnant itself, so even the true parameters leave the open-loop
  response to the remnant unexplained:
  its **ceiling** (``resimulated_vaf_ceiling``, the same resimulation with the true
  parameter traces, what a perfect estimator scores on that run) is below 100 %:
  about 79 % for the thesis's single-integrator preview pilot with 35 % remnant, and
  far below zero for its double integrator with 55 % remnant at 0.01 rad/s, whose
  slowly drifting remnant the closed loop suppresses but the open-loop resimulation
  integrates.
* **remnant-free resimulated VAF** (``remnant_free_vaf``, the results column
  ``vaf_resimulated_ideal``): ``b`` is the isolated model with the identified
  parameter traces driven by the perceptions of the remnant-free run (``y - y_n``,
  ``e + y_n``; the target is unchanged), ``a`` the remnant-free control signal ``u -
  u_n``. Simulations record ``u_n`` and ``y_n``, the parts of ``u`` and ``y`` the
  remnant caused (thesis eq. 6); the loop is linear in its signals, so ``u - u_n``,
  ``y - y_n`` is exactly the run without remnant. With the true parameters the model
  reproduces ``u - u_n`` up to its delay approximation: the **ceiling** is near 100 %
  (99.99 % on the thesis's pilots with the exact delay), whatever the remnant's level
  or colour. This is the score that means something with coloured remnant; NaN
  without ``u_n`` and ``y_n``.

The thesis's Tables III and IV VAF (17.8/40.3 % and 90.3/76.4 %) is the remnant-free
one. Its eq. 38 compares the resimulated ``u`` with "the true simulated HO input
signal", and its simulation framework computes the VAF both against ``u`` and
against "the idealised u-signal, without added remnant noise" (Part III App. H.2.3).
Against ``u`` the ceilings above (79 % and below zero) make 90.3 % and 76.4 %
unreachable; the thesis also notes that on the double integrator "even with a gain
K_p at only a fraction of its true value, the VAF is still very high", which holds for
the remnant-free score (``K_p`` acts mostly below the forcing band) and not against
``u`` (where ``K_p`` multiplies the open-loop remnant drift).

Other metrics
-------------
* Moving VAF: eq. 38 over a retrospective window (10 s in the thesis, Fig. 7).
* Innovation consistency: the fractions of innovations within one and two predicted
  standard deviations (about 68 % and 95 % for a consistent filter); innovation
  whiteness: the lag-1 autocorrelation of the normalised innovations and the fraction
  of lags outside the white-noise band.
* Observability Gramian of a discrete linear model ``(A, C)`` (Zhao et al. 2019 eq. 14):
  how strongly each state direction shows in the outputs; any model, infinite or finite
  horizon (:func:`observability_gramian`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._validation import check_int, check_positive, check_real
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.members._targets import previewed_target
from manualcontrol.estimators.protocol import EstimationResult
from manualcontrol.estimators.registry import ESTIMATORS
from manualcontrol.pilots.models import PilotModel, make_model
from manualcontrol.pilots.simulation import isolated_pilot_outputs

__all__ = [
    "NEAR_ZERO",
    "REMNANT_PARTS",
    "EstimationMetrics",
    "evaluate",
    "has_remnant_parts",
    "hold_last_finite",
    "innovation_cost",
    "innovation_cost_terms",
    "innovation_fractions",
    "innovation_whiteness",
    "moving_vaf",
    "nrmse",
    "observability_gramian",
    "paired_cost_evidence",
    "relative_bias",
    "resimulate",
    "resimulate_parameters",
    "vaf",
    "vaf_ceilings",
]

FloatArray = NDArray[np.float64]

#: Mean true value below which NRMSE and bias are absolute (thesis Part II eq. 5.7).
NEAR_ZERO = 0.05


def _pair(name_a: str, a: ArrayLike, name_b: str, b: ArrayLike) -> tuple[FloatArray, FloatArray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim != 1 or a.shape != b.shape:
        raise ValueError(
            f"{name_a} and {name_b} must be 1-D of the same length, got shapes {a.shape} "
            f"and {b.shape}"
        )
    return a, b


def vaf(measured: ArrayLike, modelled: ArrayLike) -> float:
    """Variance accounted for (%), thesis eq. 38, over samples where both are finite.

    Returns NaN when no sample is usable or ``sum u^2`` is zero, and ``-inf`` when the
    model's error is too large to square (a resimulation that diverged).
    """
    u, u_hat = _pair("measured", measured, "modelled", modelled)
    ok = np.isfinite(u) & np.isfinite(u_hat)
    power = float(np.sum(u[ok] ** 2))
    if not ok.any() or power == 0.0:
        return float("nan")
    with np.errstate(over="ignore"):
        return float((1.0 - np.sum((u[ok] - u_hat[ok]) ** 2) / power) * 100.0)


def moving_vaf(
    measured: ArrayLike, modelled: ArrayLike, dt: float, window: float = 10.0
) -> FloatArray:
    """Retrospective moving VAF (%): eq. 38 over the last ``window`` seconds at each sample.

    Sample ``k`` uses samples ``k - N + 1 .. k`` with ``N = round(window/dt)``; the first
    ``N - 1`` samples are NaN, as are windows without a usable sample.
    """
    u, u_hat = _pair("measured", measured, "modelled", modelled)
    dt = check_positive("dt", dt)
    n = check_int("window samples", round(check_positive("window", window) / dt), minimum=1)
    ok = np.isfinite(u) & np.isfinite(u_hat)
    error = np.where(ok, (u - u_hat) ** 2, 0.0)
    power = np.where(ok, u * u, 0.0)
    cumulative_error = np.concatenate(([0.0], np.cumsum(error)))
    cumulative_power = np.concatenate(([0.0], np.cumsum(power)))
    out = np.full(u.shape, np.nan)
    if u.shape[0] >= n:
        window_error = cumulative_error[n:] - cumulative_error[:-n]
        window_power = cumulative_power[n:] - cumulative_power[:-n]
        with np.errstate(divide="ignore", invalid="ignore"):
            values = (1.0 - window_error / window_power) * 100.0
        values[window_power <= 0.0] = np.nan
        out[n - 1 :] = values
    return out


def _errors(estimate: ArrayLike, truth: ArrayLike) -> tuple[FloatArray, float]:
    est, true = _pair("estimate", estimate, "truth", truth)
    ok = np.isfinite(est) & np.isfinite(true)
    if not ok.any():
        raise ValueError("estimate and truth have no finite sample in common")
    return est[ok] - true[ok], float(np.mean(true[ok]))


def nrmse(estimate: ArrayLike, truth: ArrayLike, near_zero: float = NEAR_ZERO) -> float:
    """NRMSE, thesis eq. 37; the RMSE (Part II eq. 5.7) when ``|mean(truth)| < near_zero``."""
    error, mean = _errors(estimate, truth)
    rmse = float(np.sqrt(np.mean(error**2)))
    return rmse if abs(mean) < near_zero else rmse / abs(mean)


def relative_bias(estimate: ArrayLike, truth: ArrayLike, near_zero: float = NEAR_ZERO) -> float:
    """Mean error over ``|mean(truth)|`` (the mean error when ``|mean(truth)| < near_zero``)."""
    error, mean = _errors(estimate, truth)
    bias = float(np.mean(error))
    return bias if abs(mean) < near_zero else bias / abs(mean)


def innovation_fractions(innovation: ArrayLike, variance: ArrayLike) -> tuple[float, float]:
    """Fractions of innovations within one and two predicted standard deviations."""
    r, s = _pair("innovation", innovation, "variance", variance)
    ok = np.isfinite(r) & np.isfinite(s) & (s >= 0.0)
    if not ok.any():
        return float("nan"), float("nan")
    sigma = np.sqrt(s[ok])
    magnitude = np.abs(r[ok])
    return float(np.mean(magnitude <= sigma)), float(np.mean(magnitude <= 2.0 * sigma))


def innovation_cost_terms(innovation: ArrayLike, variance: ArrayLike) -> FloatArray:
    """Per sample ``ln S_k + nu_k^2 / S_k`` (see :func:`innovation_cost`).

    NaN where ``nu_k`` or ``S_k`` is not finite or ``S_k <= 0``.
    """
    r, s = _pair("innovation", innovation, "variance", variance)
    ok = np.isfinite(r) & np.isfinite(s) & (s > 0.0)
    terms = np.full(r.shape, np.nan)
    terms[ok] = np.log(s[ok]) + r[ok] ** 2 / s[ok]
    return terms


def innovation_cost(innovation: ArrayLike, variance: ArrayLike) -> float:
    """Mean negative log-likelihood of Gaussian innovations, per sample, up to a constant.

    ``mean(ln S_k + nu_k^2 / S_k)`` over the samples where both are finite and ``S_k >
    0`` (twice the negative log-likelihood of the prediction-error decomposition,
    without ``ln 2 pi``; Harvey 1989, ch. 3): lower is more likely. NaN when no
    sample counts.
    """
    terms = innovation_cost_terms(innovation, variance)
    ok = np.isfinite(terms)
    return float(np.mean(terms[ok])) if ok.any() else float("nan")


def paired_cost_evidence(candidate: ArrayLike, incumbent: ArrayLike, block: int) -> float:
    """How much lower ``candidate``'s per-sample costs are, in standard errors (< 0: lower).

    ``candidate`` and ``incumbent`` are :func:`innovation_cost_terms` of two runs over the
    same samples, so their differences ``d_k`` are paired; consecutive ``d_k`` are
    strongly correlated (two slowly parting parameter tracks), so the standard error of
    their mean is taken from the means of ``block``-sample stretches (batch means). NaN
    with fewer than two stretches holding a finite difference.
    """
    a, b = _pair("candidate", candidate, "incumbent", incumbent)
    block = check_int("block", block, minimum=1)
    difference = a - b
    stretches = [
        chunk[np.isfinite(chunk)].mean()
        for chunk in np.array_split(difference, max(len(difference) // block, 1))
        if np.isfinite(chunk).any()
    ]
    if len(stretches) < 2:
        return math.nan
    spread = float(np.std(stretches, ddof=1)) / math.sqrt(len(stretches))
    mean = float(np.mean(stretches))
    if spread == 0.0:
        return 0.0 if mean == 0.0 else math.copysign(math.inf, mean)
    return mean / spread


def observability_gramian(A: ArrayLike, C: ArrayLike, horizon: int | None = None) -> FloatArray:
    """Observability Gramian ``G_o = sum_{k<N} (A^T)^k C^T C A^k`` of ``x+ = A x, y = C x``.

    Zhao et al. 2019 eq. 14 (their Algorithm 3 normalises the state process noise by
    it, ``Q_x,d = (T_x G_o)^-1``). ``horizon=None`` is the infinite sum, the solution of
    the discrete Lyapunov equation ``G = A^T G A + C^T C``, which exists when every
    eigenvalue of ``A`` lies inside the unit circle; a finite ``horizon`` (samples)
    sums that many terms and serves any ``A``. ``A`` (n, n), ``C`` (m, n); returns (n, n).
    """
    A = np.asarray(A, dtype=np.float64)
    C = np.asarray(C, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1]:
        raise ValueError(f"A must be a square matrix, got shape {A.shape}")
    if C.ndim != 2 or C.shape[1] != A.shape[0]:
        raise ValueError(f"C must have shape (m, {A.shape[0]}), got {C.shape}")
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(C))):
        raise ValueError("A and C must be finite")
    if horizon is None:
        radius = float(np.max(np.abs(np.linalg.eigvals(A))))
        if radius >= 1.0:
            raise ValueError(
                f"the infinite-horizon Gramian needs A stable (spectral radius < 1), got "
                f"{radius:.6g}; pass a finite horizon"
            )
        import scipy.linalg

        gramian = scipy.linalg.solve_discrete_lyapunov(A.T, C.T @ C)
    else:
        steps = check_int("horizon", horizon, minimum=1)
        gramian = np.zeros_like(A)
        power = np.eye(A.shape[0])
        for _ in range(steps):
            row = C @ power
            gramian += row.T @ row
            power = A @ power
    return 0.5 * (gramian + gramian.T)


# -------------------------------------------------------------------- resimulation


def innovation_whiteness(
    innovation: ArrayLike, variance: ArrayLike, max_lag: int = 50
) -> tuple[float, float]:
    """Whiteness of the normalised innovation ``nu/sqrt(S)``: ``(r_1, fraction outside)``.

    ``r_1`` is the lag-1 autocorrelation; the fraction is that of the lags 1..``max_lag``
    whose autocorrelation lies outside the 95 % band ``+-1.96/sqrt(N)`` of white noise
    (about 0.05 for a filter whose model explains the data; a model that misses
    dynamics leaves correlated innovations, r_1 near 1). Non-finite samples are
    dropped. NaN for fewer than ``max_lag + 2`` usable samples.
    """
    nu = np.asarray(innovation, dtype=np.float64)
    s = np.asarray(variance, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = nu / np.sqrt(s)
    z = z[np.isfinite(z)]
    if z.shape[0] < max_lag + 2:
        return math.nan, math.nan
    z = z - z.mean()
    denominator = float(z @ z)
    if denominator == 0.0:
        return math.nan, math.nan
    r = np.array([float(z[:-k] @ z[k:]) / denominator for k in range(1, max_lag + 1)])
    return float(r[0]), float(np.mean(np.abs(r) > 1.96 / math.sqrt(z.shape[0])))


def _model_of(result: EstimationResult) -> PilotModel:
    # pilot-filter results name the model among their settings; an estimator with a
    # fixed model (Schiess-Roland) names it beside them
    settings = result.settings
    name = settings.get("model") or settings.get("settings", {}).get("model")
    if not name:
        raise ValueError("the result's settings do not name its pilot model")
    return make_model(name)


def pilot_model_of(result: EstimationResult) -> PilotModel | None:
    """The pilot model structure ``result`` was identified with, or None.

    None for a member whose model is its own (the RDI's ARMAX model) or a result that
    names none.
    """
    if not _has_pilot_model(result):
        return None
    try:
        return _model_of(result)
    except ValueError:
        return None


def _has_pilot_model(result: EstimationResult) -> bool:
    """Whether ``result`` is resimulated with a pilot model (not its estimator's own)."""
    entry = ESTIMATORS.get(result.estimator)
    return entry is None or entry.resimulate is None


def hold_last_finite(values: FloatArray) -> FloatArray:
    """NaN (dropped) samples replaced by the last finite value (0 before the first).

    What a resimulation feeds a model where the recording dropped samples: the signal
    held, as a display holds its last frame.
    """
    out = np.array(values, dtype=np.float64, copy=True)
    bad = ~np.isfinite(out)
    if bad.any():
        index = np.where(~bad, np.arange(out.shape[0]), 0)
        np.maximum.accumulate(index, out=index)
        out = out[index]
        out[~np.isfinite(out)] = 0.0
    return out


#: Signals a simulation records for the remnant-free run (``u - u_n``, ``y - y_n``).
REMNANT_PARTS = ("u_n", "y_n")


def has_remnant_parts(recording: Recording) -> bool:
    """True when ``recording`` holds ``u_n`` and ``y_n`` (the remnant-free run is known)."""
    return all(name in recording for name in REMNANT_PARTS)


def _perception_sets(
    model: PilotModel,
    tau_f: FloatArray | None,
    recording: Recording,
    remnant_free: Sequence[bool],
    forcing: Any,
    target_period: float | None,
) -> list[dict[str, FloatArray]]:
    """The model's perceptions as recorded or of the remnant-free run, one set per flag."""
    if any(remnant_free) and not has_remnant_parts(recording):
        raise ValueError(
            "the remnant-free resimulation needs the recording's u_n and y_n (the parts of "
            "u and y the remnant caused, recorded by simulate)"
        )
    shared: dict[str, FloatArray] = {}
    if "ft_far" in model.perceptions:  # the target is the same with or without remnant
        # ft(t + tau_f): the recorded ft where tau_f = 0 throughout (the pursuit form)
        shared["ft_far"] = previewed_target(recording, tau_f, forcing, target_period)
    if "e" in model.perceptions and "e" not in recording:
        recording = recording.with_error_signal()
    sets = []
    for free in remnant_free:
        y_n = np.asarray(recording["y_n"]) if free else 0.0
        perceptions: dict[str, FloatArray] = {}
        for signal in model.perceptions:
            if signal == "ft_far":
                perceptions[signal] = shared[signal]
            elif signal == "y":
                perceptions[signal] = hold_last_finite(np.asarray(recording.y) - y_n)
            elif signal == "e":
                # e = ft - y, so the remnant-free error is e + y_n
                perceptions[signal] = hold_last_finite(np.asarray(recording.e) + y_n)
            else:
                raise ValueError(f"cannot resimulate a model that reads {signal!r}")
        sets.append(perceptions)
    return sets


def _resimulations(
    model: PilotModel | str,
    parameters: Mapping[str, ArrayLike],
    recording: Recording,
    remnant_free: Sequence[bool],
    delay_order: int | None,
    forcing: Any,
    target_period: float | None,
) -> list[FloatArray]:
    """:func:`resimulate_parameters` once per flag of ``remnant_free``, one discretisation."""
    if not isinstance(recording, Recording):
        raise TypeError(f"recording must be a Recording, got {recording!r}")
    model = make_model(model)
    n = len(recording)
    values = {}
    for name in model.parameter_names:
        if name not in parameters:
            raise ValueError(f"parameters must include {name!r} for the {model.name} model")
        values[name] = np.broadcast_to(np.asarray(parameters[name], dtype=np.float64), (n,))
    sets = _perception_sets(
        model, values.get("tau_f"), recording, remnant_free, forcing, target_period
    )
    order = None if delay_order is None else check_int("delay_order", delay_order, minimum=1)
    return isolated_pilot_outputs(model, values, sets, recording.dt, order)


def resimulate_parameters(
    model: PilotModel | str,
    parameters: Mapping[str, ArrayLike],
    recording: Recording,
    *,
    remnant_free: bool = False,
    delay_order: int | None = None,
    forcing: Any = None,
    target_period: float | None = None,
) -> FloatArray:
    """Output of the isolated pilot ``model`` with these parameter traces (eq. 38).

    ``parameters`` gives every parameter of the model, a constant or one value per
    sample. The model runs in
    :func:`~manualcontrol.pilots.simulation.isolated_pilot_output` (the simulation's own
    isolated pilot, started at rest), driven by the recorded perceptions (the error
    ``e``, or the previewed target ``ft(t + tau_f(t))`` at the given preview time and
    the output ``y``; target from ``forcing``, the recording's metadata, or its periodic
    extension, as for the DEKF; with ``tau_f = 0`` at every sample, the preview model's
    pursuit form, the recorded ``ft`` itself, which needs none of them:
    :func:`~manualcontrol.estimators.members._targets.previewed_target`), or with
    ``remnant_free`` by those of the remnant-free run (``y - y_n``, ``e + y_n``; see
    the module docstring). Perceptions are held over each sample; dropped samples hold
    the last value. The model delay is exact (a fractional delay line, as in the
    simulation; ``delay_order=None``, default) or a Padé approximant.
    """
    (output,) = _resimulations(
        model, parameters, recording, (remnant_free,), delay_order, forcing, target_period
    )
    return output


def _check_pair(result: Any, recording: Any) -> None:
    if not isinstance(result, EstimationResult):
        raise TypeError(f"result must be an EstimationResult, got {result!r}")
    if not isinstance(recording, Recording):
        raise TypeError(f"recording must be a Recording, got {recording!r}")
    if len(result) != len(recording):
        raise ValueError(
            f"result and recording must have the same samples: {len(result)} != {len(recording)}"
        )


def resimulate(
    result: EstimationResult,
    recording: Recording,
    *,
    remnant_free: bool = False,
    delay_order: int | None = None,
    forcing: Any = None,
    target_period: float | None = None,
) -> FloatArray:
    """Output of the isolated pilot model with the identified parameter traces (eq. 38).

    The model structure of ``result`` (from its settings) with the parameters of every
    sample, in :func:`resimulate_parameters` (see there for ``remnant_free``,
    ``delay_order``, ``forcing`` and ``target_period``; a pursuit fit of the preview
    model, ``anticipation_time = 0``, holds ``tau_f`` at 0 and is resimulated from the
    recorded ``ft``, without them). Estimators whose model is their own (the RDI's
    ARMAX model) register a ``resimulate`` in :mod:`~manualcontrol.estimators.registry`,
    used instead (against the recording as it is; ``remnant_free`` is then refused).
    """
    (output,) = _resimulate_result(
        result, recording, (remnant_free,), delay_order, forcing, target_period
    )
    return output


def _resimulate_result(
    result: EstimationResult,
    recording: Recording,
    remnant_free: Sequence[bool],
    delay_order: int | None,
    forcing: Any,
    target_period: float | None,
) -> list[FloatArray]:
    """:func:`resimulate` once per flag of ``remnant_free``, one discretisation."""
    _check_pair(result, recording)
    if not _has_pilot_model(result):
        if any(remnant_free):
            raise ValueError(
                f"remnant_free = True needs a pilot model; {result.estimator!r} resimulates "
                "its own model against the recording as it is"
            )
        entry = ESTIMATORS[result.estimator]
        return [np.asarray(entry.resimulate(result, recording), dtype=np.float64)]
    model = _model_of(result)
    values = {name: np.array(result.mean_of(name)) for name in model.parameter_names}
    return _resimulations(
        model, values, recording, remnant_free, delay_order, forcing, target_period
    )


# ------------------------------------------------------------------------ summary


@dataclass(frozen=True)
class EstimationMetrics:
    """All metrics of one estimation run against its recording (see the module docstring).

    Attributes
    ----------
    start : float
        Time (s) from which the metrics are computed.
    one_step_vaf : float
        VAF (%) of the one-step prediction against ``u`` as measured.
    resimulated_vaf, resimulated_vaf_ceiling : float
        VAF (%) against ``u`` as measured of the isolated model driven by the recorded
        perceptions, with the identified parameter traces and (ceiling) with the true
        ones; the ceiling is NaN without the true traces of every parameter.
    remnant_free_vaf, remnant_free_vaf_ceiling : float
        VAF (%) against the remnant-free ``u - u_n`` of the isolated model driven by the
        remnant-free perceptions, identified and true traces; NaN without ``u_n`` and
        ``y_n`` (or, for the ceiling, the true traces).
    nrmse, relative_bias : Mapping[str, float]
        Per estimated parameter with a known true trace.
    error_kind : Mapping[str, str]
        ``"nrmse"`` or ``"rmse"`` (near-zero parameters) per parameter.
    within_1_sigma, within_2_sigma : float
        Innovation consistency.

    """

    start: float
    one_step_vaf: float
    resimulated_vaf: float
    resimulated_vaf_ceiling: float
    remnant_free_vaf: float
    remnant_free_vaf_ceiling: float
    nrmse: Mapping[str, float]
    relative_bias: Mapping[str, float]
    error_kind: Mapping[str, str]
    within_1_sigma: float
    within_2_sigma: float

    def __post_init__(self) -> None:
        for name in ("nrmse", "relative_bias", "error_kind"):
            object.__setattr__(self, name, MappingProxyType(dict(getattr(self, name))))

    @property
    def ideal_resimulated_vaf(self) -> float:
        """Former name of :attr:`remnant_free_vaf` (the thesis's "VAFideal")."""
        return self.remnant_free_vaf


def vaf_ceilings(
    model: PilotModel | str,
    recording: Recording,
    *,
    start: float = 0.0,
    delay_order: int | None = None,
    forcing: Any = None,
    target_period: float | None = None,
) -> tuple[float, float]:
    """What a perfect estimator scores: ``(resimulated, remnant-free)`` VAF ceilings (%).

    The resimulations of :func:`evaluate` with the recording's true parameter traces,
    scored from ``start``; NaN without the true trace of every parameter (both), or
    without ``u_n`` and ``y_n`` (the remnant-free one).
    """
    model = make_model(model)
    truth = recording.parameters
    mask = np.asarray(recording.t) >= check_real("start", start)
    if not all(name in truth for name in model.parameter_names) or not mask.any():
        return math.nan, math.nan
    u = np.asarray(recording.u)
    flags = (False, True) if has_remnant_parts(recording) else (False,)
    outputs = _resimulations(model, truth, recording, flags, delay_order, forcing, target_period)
    measured = vaf(u[mask], outputs[0][mask])
    free = math.nan
    if len(outputs) == 2:
        reference = u - np.asarray(recording["u_n"])
        free = vaf(reference[mask], outputs[1][mask])
    return measured, free


def evaluate(
    result: EstimationResult,
    recording: Recording,
    *,
    start: float = 0.0,
    delay_order: int | None = None,
    forcing: Any = None,
    target_period: float | None = None,
    ceilings: bool = True,
) -> EstimationMetrics:
    """Every metric of ``result`` against ``recording`` from time ``start`` on.

    Parameter errors and the ceilings need the recording's true parameter traces
    (simulations), the remnant-free VAF its ``u_n`` and ``y_n``; what cannot be computed
    is NaN. Resimulations run over the whole recording and are scored from ``start``.
    ``ceilings=False`` skips the two resimulations with the true traces (NaN).
    """
    start = check_real("start", start)
    mask = np.asarray(recording.t) >= start
    if not mask.any():
        raise ValueError(f"start = {start!r} s is after the last sample")
    target = {"delay_order": delay_order, "forcing": forcing, "target_period": target_period}
    truth = recording.parameters
    u = np.asarray(recording.u)
    best = (math.nan, math.nan)
    _check_pair(result, recording)
    # both resimulations, where there are two, on one discretisation of the model
    free_too = _has_pilot_model(result) and has_remnant_parts(recording)
    flags = (False, True) if free_too else (False,)
    outputs = _resimulate_result(result, recording, flags, delay_order, forcing, target_period)
    vafs = {"resimulated": vaf(u[mask], outputs[0][mask]), "remnant_free": math.nan}
    if free_too:
        free = u - np.asarray(recording["u_n"])
        vafs["remnant_free"] = vaf(free[mask], outputs[1][mask])
    if _has_pilot_model(result):
        if ceilings:
            best = vaf_ceilings(_model_of(result), recording, start=start, **target)
    errors, biases, kinds = {}, {}, {}
    for name in result.estimated:
        if name not in truth:
            continue
        true_trace = truth[name][mask]
        estimate = result.mean_of(name)[mask]
        errors[name] = nrmse(estimate, true_trace)
        biases[name] = relative_bias(estimate, true_trace)
        kinds[name] = "rmse" if abs(float(np.mean(true_trace))) < NEAR_ZERO else "nrmse"
    within_1, within_2 = innovation_fractions(
        result.innovation[mask], result.innovation_variance[mask]
    )
    return EstimationMetrics(
        start=start,
        one_step_vaf=vaf(u[mask], result.prediction[mask]),
        resimulated_vaf=vafs["resimulated"],
        resimulated_vaf_ceiling=best[0],
        remnant_free_vaf=vafs["remnant_free"],
        remnant_free_vaf_ceiling=best[1],
        nrmse=errors,
        relative_bias=biases,
        error_kind=kinds,
        within_1_sigma=within_1,
        within_2_sigma=within_2,
    )
