"""The optimal control model (OCM) of the human operator, as a pilot that acts in an env.

Kleinman, Baron & Levison (KBL), "An optimal control model of human response, Part I",
Automatica 6 (1970), and "A control theoretic approach to manned-vehicle systems
analysis", IEEE TAC 16 (1971). The human is modelled as an optimal (LQG) controller
working within his limitations: a perceptual delay, observation and motor noise scaled
to the signals' variances, a neuromuscular lag that follows from a control-rate cost.

Model (continuous time)
-----------------------
*Plant.* The controlled element ``H_c`` (a constant linear element of
:mod:`manualcontrol.envs.elements`, in controllable canonical form) and the forcing.
The estimator cannot know a sum of sines, so, as is standard OCM practice, each forcing
channel is modelled as white noise through a shaping filter. Here that filter is the
critically damped second-order ``omega_b^2/(s + omega_b)^2`` whose output variance and
*rate* variance equal those of the forcing in use; this fixes ``omega_b`` as the
forcing's RMS frequency ``sqrt(sum(omega_i^2 A_i^2) / sum(A_i^2))`` and the driving noise
intensity as ``4 sigma^2 / omega_b``. (A first-order filter would do for the error but
gives the displayed error rate an infinite variance, and the rate's observation noise
is scaled by that variance.) In a compensatory display the target and a disturbance at
the element's output enter the error alike, ``e = (ft - fd) - H_c u``, so they share one
filter (variances added); a disturbance at the element's input gets a filter of its own
that drives the element.

*Cost and neuromuscular lag.* ``J = E{q_e e^2 + g u_dot^2}``. With the control ``u``
appended to the state ``x`` and ``u_dot`` as the control, the LQR of the augmented
system gives ``u_dot = -L_x x - L_u u``, i.e. ``tau_nms u_dot + u = u_c = -l x`` with the
neuromuscular time constant ``tau_nms = 1/L_u`` and ``l = L_x/L_u``. Either ``tau_nms`` is
given (default 0.1 s) and ``g`` is solved for (``tau_nms`` grows monotonically with
``g``; a bracketed root search on ``log g``), or ``g`` is given and ``tau_nms`` follows.

*Noise.* Motor noise ``v_u`` is added to the commanded control, ``tau_nms u_dot + u =
u_c + v_u``, with intensity ``V_u = pi rho_u E{u_c^2}``; observation noise ``v_y`` on
each displayed output ``y_i`` (the error ``e`` and its rate ``e_dot``) has intensity
``V_i = pi rho_y E{y_i^2}`` (``rho_y = 0.01`` is -20 dB, ``rho_u = 0.003`` about
-25 dB).

*Estimator and predictor.* The pilot perceives ``y(t - tau_v) + v_y(t - tau_v)``. A Kalman
filter on the augmented model ``chi = [x; u]`` (``chi_dot = A chi + B u_c + process
noise``, ``B = [0; 1/tau_nms]``) estimates the delayed state, ``p(t) = chi_hat(t - tau_v)``;
the least-mean-squares predictor then compensates the delay with the known (efference)
commands, ``chi_hat(t) = e^{A tau_v} p(t) + int_{t-tau_v}^t e^{A (t - s)} B u_c(s) ds``; and
``u_c = -l chi_hat``. The estimate obeys ``d chi_hat = (A - B l) chi_hat dt + e^{A tau_v}
K d nu`` with the white innovation ``nu`` (intensity ``V_y``), and its error is
orthogonal to it, so the closed-loop covariance is ``E{chi chi'} = X + Sigma`` with ``X``
from a Lyapunov equation and ``Sigma = e^{A tau_v} P e^{A' tau_v} + int_0^tau_v e^{A s} W e^{A'
s} ds`` (filter covariance ``P``, process noise ``W``).

*Self-consistent noise.* Because the noise intensities scale with variances that
depend on the filter, :func:`solve_ocm` iterates covariance -> noise intensities ->
Kalman filter -> covariance from unit intensities until the intensities change by less
than :data:`FIXED_POINT_TOLERANCE` (relative). The map is a contraction in practice
(the noise ratios are small, so the filter changes little with them): it converges in
about 10-30 iterations; more than :data:`FIXED_POINT_MAX_ITERATIONS` raises. The
covariance is that of the model world (shaping-filter forcing), as in KBL.

An element with direct feedthrough (a pure gain) puts ``u_dot`` into ``e_dot``: the
filter subtracts the known command part and ignores the motor-noise part there (whose
variance the white noise would make infinite); the rate's variance is that of the rest.

Describing function
-------------------
:meth:`OCMSolution.frequency_response` is the exact linear map from the displayed error
to the stick, ``Y_p(j omega) = U/E``, the delay as the exact phase ``e^{-j omega tau_v}``
and the neuromuscular lag included. Writing ``F = A - K C`` (the filter's dynamics),
``G = B - K D`` and ``Phi = e^{A tau_v}``::

    U_c = -l Phi (sI - F)^{-1} [K [1; s] E + G U_c] e^{-s tau_v} - l Pi(s) U_c
    Pi(s) = (sI - A)^{-1} (I - e^{-s tau_v} Phi) B
    Y_p = U_c / E / (tau_nms s + 1)

:meth:`OCMSolution.remnant_spectrum` is the closed-loop power spectral density of the
stick's noise part, the observation and motor noise through the pilot and the loop
``1/(1 + Y_p H_c)`` (two-sided, per rad/s: the variance is ``(1/2 pi) int S d omega``).

Acting in discrete time
-----------------------
:meth:`OptimalControlPilot.reset` and :meth:`~OptimalControlPilot.act` follow the
:class:`~manualcontrol.pilots.Pilot` protocol at the env's sample time ``dt``: the
pilot keeps the observed errors; it reads the error and its rate at ``tau_r = tau_v -
dt/2`` back from a cubic (four-sample Lagrange) interpolant, exact at whole samples;
adds observation noise of variance ``V_i/dt`` per sample (the discrete equivalent of
intensity ``V_i``); runs the continuous Kalman filter above discretised exactly over
each sample (the perception taken linear between samples, the delayed commands as the
held signal they are); predicts ``tau_v`` ahead to the middle of the coming sample,
solving for the command that is part of that prediction; holds that command over the
sample (plus motor noise of variance ``V_u/dt``) into the exact neuromuscular lag; and
outputs the lag's value at the sample. The hold centred on the middle of the sample
and the read at ``tau_v - dt/2`` make the sampled pilot the continuous one to second
order in ``omega dt``, at 60 and 100 Hz alike. A delay under half a sample acts as half
a sample. The noise comes from one :class:`numpy.random.Generator` seeded by
``reset(seed=...)``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._validation import (
    check_bool,
    check_choice,
    check_positive,
    reject_unknown,
)
from manualcontrol.envs.dynamics import tf_to_ccf
from manualcontrol.envs.elements import ControlledElement, make_element
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair
from manualcontrol.envs.tasks import DISTURBANCE_POINTS, resolve_forcing, task_named
from manualcontrol.envs.tracking import CompensatoryTracking

__all__ = [
    "DEFAULT_TAU_NMS",
    "FIXED_POINT_MAX_ITERATIONS",
    "FIXED_POINT_TOLERANCE",
    "ForcingModel",
    "OCMSolution",
    "OptimalControlPilot",
    "forcing_model",
    "simulate_ocm",
    "solve_ocm",
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

#: Neuromuscular time constant (s) used when neither ``tau_nms`` nor ``g`` is given.
DEFAULT_TAU_NMS = 0.1
#: Relative change of the noise intensities at which the fixed point is accepted.
FIXED_POINT_TOLERANCE = 1e-12
#: Iterations of the noise fixed point before :func:`solve_ocm` gives up.
FIXED_POINT_MAX_ITERATIONS = 500


# ------------------------------------------------------------------ the forcing model


@dataclass(frozen=True)
class ForcingModel:
    """A forcing channel as the OCM's estimator models it: shaped white noise.

    ``variance`` and ``omega_b`` (rad/s) of the filter ``omega_b^2/(s + omega_b)^2``
    driven by white noise of intensity ``4 variance / omega_b``; ``entry`` is
    ``"error"`` (enters the error like the target) or ``"input"`` (drives the element).
    """

    variance: float
    omega_b: float
    entry: str

    @property
    def intensity(self) -> float:
        """Intensity of the white noise that drives the filter."""
        return 4.0 * self.variance / self.omega_b


def _moments(signal: Any) -> tuple[float, float]:
    """Mean squares of a forcing signal and of its rate."""
    if signal is None:
        return 0.0, 0.0
    if hasattr(signal, "frequencies"):  # a multisine: exact
        power = 0.5 * np.asarray(signal.amplitudes) ** 2
        return float(power.sum()), float((power * np.asarray(signal.frequencies) ** 2).sum())
    # any other forcing function: sampled over its period (or 100 s)
    duration = getattr(signal, "measurement_time", None) or 100.0
    t = np.arange(0.0, duration, 0.005)
    values = np.asarray(signal(t), dtype=np.float64)
    rates = np.asarray(signal.derivative(t), dtype=np.float64)
    return float(np.mean(values**2)), float(np.mean(rates**2))


def forcing_model(forcing: ForcingPair, disturbance_at: str = "output") -> tuple[ForcingModel, ...]:
    """The shaping filters that stand for ``forcing`` in the estimator (module docstring).

    The target and a disturbance at the output share one ``"error"`` channel; a
    disturbance at the input is an ``"input"`` channel. Channels without power are left
    out; a forcing without any raises ``ValueError``.
    """
    check_choice("disturbance_at", disturbance_at, DISTURBANCE_POINTS)
    target = _moments(forcing.target)
    disturbance = _moments(forcing.disturbance)
    groups = []
    if disturbance_at == "output":
        groups.append(("error", target[0] + disturbance[0], target[1] + disturbance[1]))
    else:
        groups.append(("error", *target))
        groups.append(("input", *disturbance))
    channels = tuple(
        ForcingModel(variance, math.sqrt(rate / variance), entry)
        for entry, variance, rate in groups
        if variance > 0.0 and rate > 0.0
    )
    if not channels:
        raise ValueError("forcing must have a target or a disturbance with power, got none")
    return channels


# ------------------------------------------------------------------------ the solution


@dataclass(frozen=True)
class OCMSolution:
    """The solved OCM for one element and forcing: gains, noise, covariances.

    Augmented state ``chi = [element states; forcing-filter states; u]`` (``n`` states).

    Attributes
    ----------
    A, B : (n, n), (n, 1)
        Closed-lag model ``chi_dot = A chi + B u_c`` (``u`` row ``-1/tau_nms``).
    C, D : (2, n), (2, 1)
        Displayed outputs ``[e, e_dot] = C chi + D u_c`` (``D`` non-zero only for an
        element with feedthrough).
    c_e : (n,)
        ``e = c_e chi``.
    Gamma, W : (n, q), (q, q)
        Process noise input and intensities (forcing filters, then motor noise).
    L : (n,)
        LQR gain of the augmented problem, ``u_dot = -L chi``.
    l_c : (n,)
        Command gain ``u_c = -l_c chi_hat`` (``L/L_u`` with the ``u`` entry zero).
    K, P : (n, 2), (n, n)
        Kalman gain and error covariance of the delayed-state filter.
    X, Sigma : (n, n)
        Covariance of the state estimate and of the prediction error.
    V_y : (2,)
        Observation-noise intensities of ``e`` and ``e_dot``.
    V_u : float
        Motor-noise intensity.
    g, tau_nms, tau_v, q_e : float
        Control-rate weight, neuromuscular time constant, delay, error weight.
    variances : dict
        ``E{e^2}``, ``E{e_dot^2}``, ``E{u_c^2}``, ``E{u^2}`` at the fixed point.
    iterations : int
        Iterations the noise fixed point took.
    element_num, element_den : arrays
        The element's transfer function.
    forcing : tuple of ForcingModel
        The shaping filters.
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    D: FloatArray
    c_e: FloatArray
    Gamma: FloatArray
    W: FloatArray
    L: FloatArray
    l_c: FloatArray
    K: FloatArray
    P: FloatArray
    X: FloatArray
    Sigma: FloatArray
    V_y: FloatArray
    V_u: float
    g: float
    tau_nms: float
    tau_v: float
    q_e: float
    variances: Mapping[str, float]
    iterations: int
    element_num: FloatArray
    element_den: FloatArray
    forcing: tuple[ForcingModel, ...]

    def element_response(self, omega: ArrayLike) -> ComplexArray:
        """``H_c(j omega)``."""
        s = 1j * np.asarray(omega, dtype=np.float64)
        return np.polyval(self.element_num, s) / np.polyval(self.element_den, s)

    def _pilot_parts(self, omega: ArrayLike) -> tuple[ComplexArray, ComplexArray]:
        """``U_c/E`` (noise free) and ``U_c/v_y`` per channel, shapes ``(m,)``, ``(m, 2)``."""
        omega = np.atleast_1d(np.asarray(omega, dtype=np.float64))
        n = self.A.shape[0]
        identity = np.eye(n)
        F = self.A - self.K @ self.C
        G = self.B - self.K @ self.D
        Phi = scipy.linalg.expm(self.A * self.tau_v)
        l_phi = self.l_c @ Phi
        to_e = np.empty(omega.shape, dtype=np.complex128)
        to_noise = np.empty((*omega.shape, 2), dtype=np.complex128)
        for i, w in enumerate(omega):
            s = 1j * w
            delay = np.exp(-s * self.tau_v)
            # (sI - F)^{-1} [K, G]: the filter's response to perception and command
            r = np.linalg.solve(s * identity - F, np.hstack([self.K, G]))
            r_y, r_u = r[:, :2], r[:, 2]
            # Pi(s): the predictor's integral of the commands over the last tau_v
            pi = np.linalg.solve(s * identity - self.A, (identity - delay * Phi) @ self.B[:, 0])
            denominator = 1.0 + delay * (l_phi @ r_u) + self.l_c @ pi
            per_channel = -(l_phi @ r_y) / denominator  # U_c per perceived y_i
            to_noise[i] = per_channel
            to_e[i] = delay * (per_channel[0] + per_channel[1] * s)
        return to_e, to_noise

    def frequency_response(self, omega: ArrayLike) -> ComplexArray:
        """The pilot's describing function ``Y_p(j omega) = U/E`` (module docstring)."""
        omega = np.atleast_1d(np.asarray(omega, dtype=np.float64))
        if np.any(omega <= 0.0) or not np.all(np.isfinite(omega)):
            raise ValueError("omega must be finite and > 0 rad/s")
        to_e, _ = self._pilot_parts(omega)
        return to_e / (1.0 + 1j * omega * self.tau_nms)

    def open_loop(self, omega: ArrayLike) -> ComplexArray:
        """``Y_p H_c`` at ``omega`` (rad/s)."""
        return self.frequency_response(omega) * self.element_response(omega)

    def remnant_spectrum(self, omega: ArrayLike) -> FloatArray:
        """Closed-loop PSD of the stick's noise part (two-sided, per rad/s)."""
        omega = np.atleast_1d(np.asarray(omega, dtype=np.float64))
        _, to_noise = self._pilot_parts(omega)
        lag = np.abs(1.0 + 1j * omega * self.tau_nms) ** 2
        open_loop = np.abs(to_noise) ** 2 @ self.V_y + self.V_u
        loop = np.abs(1.0 + self.open_loop(omega)) ** 2
        return open_loop / lag / loop

    def crossover(self, low: float = 0.05, high: float = 50.0) -> tuple[float, float, float]:
        """Crossover frequency (rad/s), phase margin (deg) and effective delay (s).

        The first frequency in ``[low, high]`` where ``|Y_p H_c|`` falls through 1 (a
        log grid, refined by a root search); the phase margin ``180 + arg(Y_p H_c)``
        (phase unwrapped from ``low``); the effective delay of the crossover model
        ``omega_c e^{-j omega tau_e}/(j omega)`` with that margin, ``tau_e = (pi/2 -
        PM)/omega_c``. Raises ``ValueError`` when the gain does not cross 1 there.
        """
        grid = np.geomspace(low, high, 2000)
        magnitude = np.log(np.abs(self.open_loop(grid)))
        crossing = np.flatnonzero((magnitude[:-1] > 0.0) & (magnitude[1:] <= 0.0))
        if crossing.size == 0:
            raise ValueError(f"|Y_p H_c| does not cross 1 between {low:g} and {high:g} rad/s")
        i = int(crossing[0])
        omega_c = scipy.optimize.brentq(
            lambda w: math.log(abs(self.open_loop(w)[0])), grid[i], grid[i + 1], xtol=1e-12
        )
        phase = np.unwrap(np.angle(self.open_loop(np.append(grid[: i + 1], omega_c))))
        margin = 180.0 + math.degrees(phase[-1])
        return omega_c, margin, (math.pi / 2 - math.radians(margin)) / omega_c


def _element_matrices(
    element: ControlledElement,
) -> tuple[FloatArray, FloatArray, FloatArray, float, FloatArray, FloatArray]:
    if element.is_time_varying:
        raise ValueError(
            f"element must be constant for the OCM (a time-invariant LQG problem), "
            f"got the time-varying {element.describe()}"
        )
    num, den = (np.asarray(c, dtype=np.float64).reshape(-1) for c in element.transfer_function())
    model = tf_to_ccf(num, den)
    A = np.asarray(model.A, dtype=np.float64).reshape(model.A.shape[-2:])
    B = np.asarray(model.B, dtype=np.float64).reshape(-1)
    C = np.asarray(model.C, dtype=np.float64).reshape(-1)
    D = float(np.asarray(model.D).reshape(-1)[0])
    return A, B, C, D, num, den


def _augmented(
    element: ControlledElement, channels: tuple[ForcingModel, ...]
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Open-lag model ``chi_dot = A0 chi + b0 u_dot``, error row, noise inputs, etc.

    Returns ``A0`` (n, n), ``b0`` (n,), ``c_e`` (n,), ``Gamma_w`` (n, channels),
    ``element_num``, ``element_den``.
    """
    A_c, B_c, C_c, D_c, num, den = _element_matrices(element)
    n_c = A_c.shape[0]
    n = n_c + 2 * len(channels) + 1
    u = n - 1
    A0 = np.zeros((n, n))
    c_e = np.zeros(n)
    gamma = np.zeros((n, len(channels)))
    A0[:n_c, :n_c] = A_c
    A0[:n_c, u] = B_c
    c_e[:n_c] = -C_c
    c_e[u] = -D_c
    for j, channel in enumerate(channels):
        w = n_c + 2 * j  # [w, w_dot]
        omega = channel.omega_b
        A0[w, w + 1] = 1.0
        A0[w + 1, w] = -(omega**2)
        A0[w + 1, w + 1] = -2.0 * omega
        gamma[w + 1, j] = omega**2 * math.sqrt(channel.intensity)
        if channel.entry == "error":
            c_e[w] = 1.0
        else:  # drives the element alongside the stick
            A0[:n_c, w] = B_c
            c_e[w] = -D_c
    b0 = np.zeros(n)
    b0[u] = 1.0
    return A0, b0, c_e, gamma, num, den


def _lqr(A0: FloatArray, b0: FloatArray, c_e: FloatArray, q_e: float, g: float) -> FloatArray:
    """Gain ``L`` of ``u_dot = -L chi`` minimising ``E{q_e e^2 + g u_dot^2}``."""
    Q = q_e * np.outer(c_e, c_e)
    S = scipy.linalg.solve_continuous_are(A0, b0[:, None], Q, np.array([[g]]))
    return (b0 @ S) / g


def _g_for(A0: FloatArray, b0: FloatArray, c_e: FloatArray, q_e: float, tau_nms: float) -> float:
    """The control-rate weight ``g`` whose LQR has neuromuscular lag ``tau_nms``."""

    def mismatch(log_g: float) -> float:
        L = _lqr(A0, b0, c_e, q_e, 10.0**log_g)
        return math.log(1.0 / L[-1]) - math.log(tau_nms)

    low, high = -6.0, 2.0
    for _ in range(40):
        if mismatch(low) < 0.0:
            break
        low -= 2.0
    for _ in range(40):
        if mismatch(high) > 0.0:
            break
        high += 2.0
    if not mismatch(low) < 0.0 < mismatch(high):
        raise ValueError(f"no control-rate weight g gives tau_nms = {tau_nms!r} s for this element")
    return 10.0 ** scipy.optimize.brentq(mismatch, low, high, xtol=1e-14, rtol=1e-14)


def _integrated_covariance(A: FloatArray, Q: FloatArray, t: float) -> FloatArray:
    """``int_0^t e^{A s} Q e^{A' s} ds`` (Van Loan)."""
    n = A.shape[0]
    block = np.zeros((2 * n, 2 * n))
    block[:n, :n] = -A
    block[:n, n:] = Q
    block[n:, n:] = A.T
    E = scipy.linalg.expm(block * t)
    phi = E[n:, n:].T
    return _symmetric(phi @ E[:n, n:])


def _symmetric(M: FloatArray) -> FloatArray:
    return 0.5 * (M + M.T)


def _kalman_gain(A: FloatArray, C: FloatArray, Q: FloatArray, V: FloatArray) -> tuple:
    """Steady-state continuous Kalman filter ``(K, P)``: ``K = P C' V^{-1}``.

    ``P`` solves the filter Riccati equation ``A P + P A' + Q - P C' V^{-1} C P = 0``
    with the process-noise covariance intensity ``Q`` and observation-noise intensity
    ``V`` (the dual of the LQR equation).
    """
    P = _symmetric(scipy.linalg.solve_continuous_are(A.T, C.T, Q, V))
    K = np.linalg.solve(V, C @ P).T
    return K, P


def solve_ocm(
    element: str | ControlledElement | Mapping[str, Any],
    forcing: str | ForcingPair,
    *,
    tau_v: float = 0.2,
    tau_nms: float | None = None,
    g: float | None = None,
    rho_y: float = 0.01,
    rho_u: float = 0.003,
    q_e: float = 1.0,
    disturbance_at: str = "output",
) -> OCMSolution:
    """Solve the OCM for an element and a forcing (see the module docstring).

    Give ``tau_nms`` (s) or ``g``, not both (neither: ``tau_nms`` 0.1 s). ``forcing`` is a
    preset name (realisation 0) or a :class:`~manualcontrol.envs.signals.ForcingPair`.
    """
    settings = _Settings.create(tau_v, tau_nms, g, rho_y, rho_u, q_e, disturbance_at)
    return _solve(_element_argument(element), resolve_forcing(forcing), settings)


def _element_argument(element: Any) -> ControlledElement:
    try:
        return make_element(element)
    except (TypeError, ValueError) as error:
        raise type(error)(f"element: {error}") from None


@dataclass(frozen=True)
class _Settings:
    tau_v: float
    tau_nms: float | None
    g: float | None
    rho_y: float
    rho_u: float
    q_e: float
    disturbance_at: str

    @classmethod
    def create(
        cls,
        tau_v: Any,
        tau_nms: Any,
        g: Any,
        rho_y: Any,
        rho_u: Any,
        q_e: Any,
        disturbance_at: Any,
    ) -> _Settings:
        """Checked settings; messages name the argument, its value and the range."""
        tau_v = check_positive("tau_v", tau_v, allow_zero=True)
        if g is not None and tau_nms is not None:
            raise ValueError(
                f"give tau_nms (neuromuscular lag, s) or g (control-rate weight), not both; "
                f"got tau_nms={tau_nms!r} and g={g!r}"
            )
        if g is None:
            tau_nms = check_positive("tau_nms", DEFAULT_TAU_NMS if tau_nms is None else tau_nms)
        else:
            g = check_positive("g", g)
        return cls(
            tau_v,
            tau_nms,
            g,
            check_positive("rho_y", rho_y),
            check_positive("rho_u", rho_u),
            check_positive("q_e", q_e),
            check_choice("disturbance_at", disturbance_at, DISTURBANCE_POINTS),
        )


def _solve(element: ControlledElement, forcing: ForcingPair, settings: _Settings) -> OCMSolution:
    channels = forcing_model(forcing, settings.disturbance_at)
    A0, b0, c_e, gamma_w, num, den = _augmented(element, channels)
    q_e = settings.q_e
    g = settings.g if settings.g is not None else _g_for(A0, b0, c_e, q_e, settings.tau_nms)
    L = _lqr(A0, b0, c_e, q_e, g)
    tau_nms = 1.0 / L[-1]
    n = A0.shape[0]
    A = A0.copy()
    A[-1, -1] = -1.0 / tau_nms
    B = np.zeros((n, 1))
    B[-1, 0] = 1.0 / tau_nms
    l_c = L * tau_nms
    l_c[-1] = 0.0
    # displayed outputs: e = c_e chi, e_dot = c_e (A chi + B u_c) (motor noise left out)
    C = np.vstack([c_e, c_e @ A])
    D = np.array([[0.0], [float(c_e @ B[:, 0])]])
    gamma = np.hstack([gamma_w, B])  # forcing filters, then motor noise (through 1/tau_nms)
    closed = A - B @ l_c[None, :]
    Phi = scipy.linalg.expm(A * settings.tau_v)
    output = C - D @ l_c[None, :]
    V_y = np.ones(2)
    V_u = 1.0
    iteration = 0
    while iteration < FIXED_POINT_MAX_ITERATIONS:
        iteration += 1
        W = np.diag(np.append(np.ones(len(channels)), V_u))
        Q = gamma @ W @ gamma.T
        K, P = _kalman_gain(A, C, Q, np.diag(V_y))
        Sigma = _symmetric(Phi @ P @ Phi.T) + _integrated_covariance(A, Q, settings.tau_v)
        drive = Phi @ K
        X = _symmetric(
            scipy.linalg.solve_continuous_lyapunov(closed, -drive @ np.diag(V_y) @ drive.T)
        )
        outputs = output @ X @ output.T + C @ Sigma @ C.T
        command = float(l_c @ X @ l_c)
        new_V_y = math.pi * settings.rho_y * np.diag(outputs)
        new_V_u = math.pi * settings.rho_u * command
        change = max(float(np.max(np.abs(new_V_y - V_y) / new_V_y)), abs(new_V_u - V_u) / new_V_u)
        V_y, V_u = new_V_y, new_V_u
        if change < FIXED_POINT_TOLERANCE:
            break
    else:
        raise RuntimeError(
            f"the OCM noise fixed point did not converge in {FIXED_POINT_MAX_ITERATIONS} "
            f"iterations (last relative change {change:.3g})"
        )
    # the final gains, with the converged intensities
    W = np.diag(np.append(np.ones(len(channels)), V_u))
    Q = gamma @ W @ gamma.T
    K, P = _kalman_gain(A, C, Q, np.diag(V_y))
    state = X + Sigma
    variances = {
        "e": float(outputs[0, 0]),
        "e_dot": float(outputs[1, 1]),
        "u_c": command,
        "u": float(state[-1, -1]),
    }
    return OCMSolution(
        A=A,
        B=B,
        C=C,
        D=D,
        c_e=c_e,
        Gamma=gamma,
        W=W,
        L=L,
        l_c=l_c,
        K=K,
        P=P,
        X=X,
        Sigma=Sigma,
        V_y=V_y,
        V_u=V_u,
        g=g,
        tau_nms=tau_nms,
        tau_v=settings.tau_v,
        q_e=q_e,
        variances=variances,
        iterations=iteration,
        element_num=num,
        element_den=den,
        forcing=channels,
    )


# ------------------------------------------------------------------ acting in discrete time


def _held_input(A: FloatArray, B: FloatArray, h: float) -> tuple[FloatArray, FloatArray]:
    """``e^{A h}`` and ``int_0^h e^{A s} ds B`` (exact zero-order hold)."""
    n, m = B.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = A
    block[:n, n:] = B
    E = scipy.linalg.expm(block * h)
    return E[:n, :n], E[:n, n:]


def _ramp_inputs(A: FloatArray, h: float) -> tuple[FloatArray, FloatArray]:
    """``M0 = int_0^h e^{A r} dr`` and ``M1 = (1/h) int_0^h e^{A r} (h - r) dr``.

    Over a sample with an input linear from ``y0`` to ``y1``, ``x1 = e^{A h} x0 + M0 y0
    + M1 (y1 - y0)`` before the input matrix.
    """
    n = A.shape[0]
    block = np.zeros((3 * n, 3 * n))
    identity = np.eye(n)
    block[:n, :n] = A
    block[:n, n : 2 * n] = identity
    block[n : 2 * n, 2 * n :] = identity
    E = scipy.linalg.expm(block * h)
    return E[:n, n : 2 * n], E[:n, 2 * n :] / h


def _lagrange_weights(nodes: FloatArray, x: float) -> tuple[FloatArray, FloatArray]:
    """Weights of the cubic through ``nodes`` for the value and slope at ``x``."""
    value = np.empty(4)
    slope = np.empty(4)
    for i in range(4):
        others = np.delete(nodes, i)
        scale = np.prod(nodes[i] - others)
        value[i] = np.prod(x - others) / scale
        slope[i] = sum(np.prod(x - np.delete(others, j)) for j in range(3)) / scale
    return value, slope


class _OCMController:
    """Runtime state of the OCM in one episode (module docstring, Acting in discrete time)."""

    def __init__(
        self, solution: OCMSolution, dt: float, rng: np.random.Generator, noise: bool
    ) -> None:
        self.solution = solution
        self.dt = dt
        self.rng = rng
        self.noise = noise
        tau_r = max(solution.tau_v - 0.5 * dt, 0.0)
        position = tau_r / dt
        m = math.floor(position + 1e-9)
        f = position - m
        if f < 1e-9:
            f = 0.0
        self.m, self.f = m, f
        # perception: the cubic through the four samples nearest t - tau_r that exist
        # (index 0 = newest), read at distance `position` back
        first = max(m - 1, 0)
        nodes = np.arange(first, first + 4, dtype=np.float64)
        value, slope = _lagrange_weights(-nodes, -position)
        self.stencil = nodes.astype(int)
        self.read_weights = np.vstack([value, slope / dt])
        # the filter over one sample: perception linear between samples, commands held
        A, B, C, D, K = solution.A, solution.B, solution.C, solution.D, solution.K
        F = A - K @ C
        G = B - K @ D
        self.phi_f = scipy.linalg.expm(F * dt)
        M0, M1 = _ramp_inputs(F, dt)
        self.filter_y0 = (M0 - M1) @ K
        self.filter_y1 = M1 @ K
        # command pieces over the sample: u_c[k-m-2] for f dt, then u_c[k-m-1]
        phi_late, gamma_late = _held_input(F, G, (1.0 - f) * dt)
        _, gamma_early = _held_input(F, G, f * dt)
        self.filter_early = (phi_late @ gamma_early)[:, 0]
        self.filter_late = gamma_late[:, 0]
        # predictor to the middle of the coming sample: p -> chi_hat(t_k + dt/2)
        horizon = tau_r + 0.5 * dt
        self.phi_predict = scipy.linalg.expm(A * horizon)
        columns = []  # commands u_c[k-m-1] (for f dt), u_c[k-m], ..., u_c[k-1]
        start = 0.0
        for length in [f * dt] + [dt] * m:
            phi_rest = scipy.linalg.expm(A * (horizon - start - length))
            columns.append(phi_rest @ _held_input(A, B, length)[1][:, 0])
            start += length
        self.predict_commands = np.array(columns).T  # (n, m + 1)
        gamma_half = _held_input(A, B, 0.5 * dt)[1][:, 0]
        self.l_phi = solution.l_c @ self.phi_predict
        self.l_commands = solution.l_c @ self.predict_commands
        self.own_share = 1.0 + float(solution.l_c @ gamma_half)
        # neuromuscular lag over one sample, exact for the held command
        self.lag = math.exp(-dt / solution.tau_nms)
        self.noise_std = np.append(np.sqrt(solution.V_y / dt), math.sqrt(solution.V_u / dt))
        n = A.shape[0]
        self.p = np.zeros(n)
        self.errors = [0.0] * (int(self.stencil.max()) + 1)
        self.commands = [0.0] * (m + 3)
        self.previous_y = np.zeros(2)
        self.u = 0.0
        self.k = 0
        self.last_noise = np.zeros(3)

    def act(self, error: float) -> float:
        errors = self.errors
        errors.append(error)
        size = len(errors)
        samples = np.array([errors[size - 1 - i] for i in self.stencil])
        y = self.read_weights @ samples
        draws = self.rng.standard_normal(3) * self.noise_std if self.noise else np.zeros(3)
        self.last_noise = draws
        y = y + draws[:2]
        commands = self.commands  # ..., u_c[k-2], u_c[k-1]
        count = len(commands)
        m = self.m
        early = commands[count - m - 2]  # u_c[k-m-2]
        late = commands[count - m - 1]  # u_c[k-m-1]
        if self.k == 0:
            self.previous_y = y
        self.p = (
            self.phi_f @ self.p
            + self.filter_y0 @ self.previous_y
            + self.filter_y1 @ y
            + self.filter_early * early
            + self.filter_late * late
        )
        self.previous_y = y
        history = np.array(commands[count - m - 1 :])  # u_c[k-m-1] ... u_c[k-1]
        command = -(self.l_phi @ self.p + self.l_commands @ history) / self.own_share
        commands.append(command)
        if len(commands) > 4 * (m + 3):
            del commands[: len(commands) - (m + 3)]
        if len(errors) > 4 * len(self.stencil) + 64:
            del errors[: len(errors) - (int(self.stencil.max()) + 1)]
        u = self.u
        self.u = self.lag * u + (1.0 - self.lag) * (command + draws[2])
        self.k += 1
        return u


# -------------------------------------------------------------------------------- the pilot


@dataclass(frozen=True)
class OptimalControlPilot:
    """The KBL optimal control model as a pilot for compensatory tracking envs.

    Parameters
    ----------
    element
        The controlled element the pilot's internal model holds (preset, transfer
        function text, element or dict), or None (default): the env's, at :meth:`reset`.
    forcing
        The forcing its shaping filters stand for (preset name, realisation 0, or a
        :class:`~manualcontrol.envs.signals.ForcingPair`), or None: the env's episode's.
    tau_v
        Perceptual delay (s), >= 0; default 0.2.
    tau_nms, g
        Neuromuscular time constant (s, > 0) or control-rate weight (> 0); give one. With
        neither, ``tau_nms = 0.1``.
    rho_y, rho_u
        Observation and motor noise ratios, > 0 (defaults 0.01 and 0.003: -20 and -25 dB).
    q_e
        Error weight of the cost, > 0 (default 1; only ``g/q_e`` matters).
    disturbance_at
        Where the disturbance enters when ``element``/``forcing`` are given here
        (``"output"`` or ``"input"``); in an env, the env's.
    noise
        Inject the observation and motor noise when acting (default True). The filter
        is designed with them either way; False gives the noise-free describing function.

    ``frequency_response``, ``remnant_spectrum`` and ``crossover`` use the solution for
    the given element and forcing, or, after :meth:`reset`, the env's.
    """

    element: Any = None
    forcing: Any = None
    tau_v: float = 0.2
    tau_nms: float | None = None
    g: float | None = None
    rho_y: float = 0.01
    rho_u: float = 0.003
    q_e: float = 1.0
    disturbance_at: str = "output"
    noise: bool = True
    _state: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        settings = _Settings.create(
            self.tau_v, self.tau_nms, self.g, self.rho_y, self.rho_u, self.q_e, self.disturbance_at
        )
        for name in ("tau_v", "tau_nms", "g", "rho_y", "rho_u", "q_e"):
            object.__setattr__(self, name, getattr(settings, name))
        object.__setattr__(self, "noise", check_bool("noise", self.noise))
        if self.element is not None:
            object.__setattr__(self, "element", _element_argument(self.element))
        if self.forcing is not None:
            try:
                object.__setattr__(self, "forcing", resolve_forcing(self.forcing))
            except (TypeError, ValueError) as error:
                raise type(error)(f"forcing: {error}") from None

    def _settings(self, disturbance_at: str) -> _Settings:
        return _Settings.create(
            self.tau_v, self.tau_nms, self.g, self.rho_y, self.rho_u, self.q_e, disturbance_at
        )

    def solve(
        self,
        element: Any = None,
        forcing: Any = None,
        disturbance_at: str | None = None,
    ) -> OCMSolution:
        """The solution for an element and forcing (defaults: the pilot's own)."""
        element = self.element if element is None else _element_argument(element)
        forcing = self.forcing if forcing is None else resolve_forcing(forcing)
        if element is None or forcing is None:
            raise ValueError(
                "the OCM needs an element and a forcing: give them to OptimalControlPilot "
                "or to solve(), or reset the pilot with an env"
            )
        where = self.disturbance_at if disturbance_at is None else disturbance_at
        key = (element, forcing, where)
        cache = self._state.setdefault("solutions", {})
        if key not in cache:
            cache[key] = _solve(element, forcing, self._settings(where))
        return cache[key]

    @property
    def solution(self) -> OCMSolution:
        """The solution in use: the env's after :meth:`reset`, else the pilot's own."""
        controller = self._state.get("controller")
        return controller.solution if controller is not None else self.solve()

    def frequency_response(self, omega: ArrayLike) -> ComplexArray:
        """Describing function ``Y_p(j omega)`` (see :meth:`OCMSolution.frequency_response`)."""
        return self.solution.frequency_response(omega)

    def remnant_spectrum(self, omega: ArrayLike) -> FloatArray:
        """Closed-loop remnant PSD of ``u`` (see :meth:`OCMSolution.remnant_spectrum`)."""
        return self.solution.remnant_spectrum(omega)

    def crossover(self) -> tuple[float, float, float]:
        """Crossover frequency, phase margin, effective delay (:meth:`OCMSolution.crossover`)."""
        return self.solution.crossover()

    def reset(self, seed: int | np.random.Generator | None = None, *, env: Any) -> None:
        """Start acting in ``env``'s current episode (call after ``env.reset()``).

        Reads the env's element, forcing realisation, sample time and disturbance point
        (the pilot's own element and forcing, when given, take precedence: a pilot with
        a wrong internal model); the noise is drawn from ``seed``'s generator.
        """
        base = getattr(env, "unwrapped", env)
        for attribute in ("task", "element", "forcing", "dt"):
            if not hasattr(base, attribute):
                raise TypeError(
                    f"env must be a manualcontrol tracking environment after reset(), "
                    f"it has no {attribute!r}"
                )
        if not task_named(base.task).shows_error_only:
            raise ValueError(f"the OCM pilot flies compensatory tasks, got task {base.task!r}")
        where = getattr(base, "disturbance_at", "output")
        solution = self.solve(
            self.element if self.element is not None else base.element,
            self.forcing if self.forcing is not None else base.forcing,
            where,
        )
        if isinstance(seed, np.random.Generator):
            rng = seed
        else:
            rng = np.random.default_rng(seed)
        self._state["controller"] = _OCMController(
            solution, check_positive("dt", base.dt), rng, self.noise
        )

    def act(self, observation: ArrayLike) -> FloatArray:
        """The stick for a compensatory observation (the error first), shape ``(1,)``."""
        controller = self._state.get("controller")
        if controller is None:
            raise RuntimeError("call pilot.reset(seed, env=env) after env.reset() before act()")
        observation = np.asarray(observation, dtype=np.float64).reshape(-1)
        if observation.size == 0 or not math.isfinite(observation[0]):
            raise ValueError(f"observation must start with a finite error, got {observation!r}")
        return np.array([controller.act(float(observation[0]))])

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description (settings; element and forcing when given)."""
        return {
            "model": "ocm",
            "element": None if self.element is None else self.element.to_dict(),
            "forcing": None if self.forcing is None else self.forcing.to_dict(),
            "tau_v": self.tau_v,
            "tau_nms": self.tau_nms,
            "g": self.g,
            "rho_y": self.rho_y,
            "rho_u": self.rho_u,
            "q_e": self.q_e,
            "disturbance_at": self.disturbance_at,
            "noise": self.noise,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> OptimalControlPilot:
        """Inverse of :meth:`to_dict`."""
        if not isinstance(data, Mapping):
            raise TypeError(f"OCM pilot data must be a dict, got {data!r}")
        data = dict(data)
        model = data.pop("model", "ocm")
        if model != "ocm":
            raise ValueError(f"model must be 'ocm', got {model!r}")
        known = [f.name for f in dataclasses.fields(cls) if f.init]
        reject_unknown("OptimalControlPilot.from_dict", data, known)
        if data.get("forcing") is not None:
            data["forcing"] = ForcingPair.from_dict(data["forcing"])
        return cls(**data)


def simulate_ocm(
    pilot: OptimalControlPilot,
    element: str | ControlledElement | Mapping[str, Any] = "SI",
    forcing: str | ForcingPair = "vanderel-bw4",
    *,
    realisation: int = 0,
    dt: float = 0.01,
    run_in: float = 10.0,
    measurement_time: float | None = None,
    seed: int | np.random.Generator | None = None,
    disturbance_at: str = "output",
    action_bound: float = 1e6,
) -> Recording:
    """The OCM pilot flying a compensatory env over one run: its :class:`Recording`.

    The loop of :func:`manualcontrol.pilots.simulate` with ``loop="sampled"``, through
    :class:`~manualcontrol.envs.tracking.CompensatoryTracking` (same arguments; the
    stick bound is wide so the loop stays linear). The run-in is cut; the pilot's
    settings are in ``metadata["pilot"]``.
    """
    if not isinstance(pilot, OptimalControlPilot):
        raise TypeError(f"pilot must be an OptimalControlPilot, got {pilot!r}")
    env = CompensatoryTracking(
        element,
        forcing,
        realisation,
        dt=dt,
        run_in=run_in,
        measurement_time=measurement_time,
        disturbance_at=disturbance_at,
        action_bound=action_bound,
    )
    observation, _ = env.reset(seed=seed if isinstance(seed, int) else None)
    pilot.reset(seed, env=env)
    done = False
    while not done:
        observation, _, terminated, truncated, _ = env.step(pilot.act(observation))
        done = terminated or truncated
    recording = env.recording()
    return Recording(
        signals=dict(recording.signals),
        dt=recording.dt,
        parameters=dict(recording.parameters),
        metadata={**dict(recording.metadata), "pilot": pilot.to_dict()},
    )
