"""The numba kernels of :mod:`~manualcontrol.estimators.members._rdi_core`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference, ``bench/compile_kernels.py``'s numba jobs): the records and
constants stay in the numba-free module, which exports these kernels by name on first
use. :func:`simulate_output` (``resimulate``'s) has its C port too
(:func:`~manualcontrol.estimators.members._rdi_native.simulate_output`).
"""

from __future__ import annotations

import numba
import numpy as np

from manualcontrol.envs._interpolation import bicubic_derivative_weights, bicubic_weights
from manualcontrol.estimators.filters._kalman_kernels import clamp, joseph_correct
from manualcontrol.estimators.filters._monitor_kernels import belief_health
from manualcontrol.estimators.filters._smoother_kernels import store_belief
from manualcontrol.estimators.filters.monitor import (
    REASON_COVARIANCE,
    REASON_NONFINITE,
)
from manualcontrol.estimators.members._rdi_core import (
    CFG_DT,
    CFG_JITTER,
    CFG_LAMBDA,
    CFG_MAX_COV,
    CFG_NA,
    CFG_NB,
    CFG_R,
    CFG_SIGN,
    CFG_SIZE,
    SC_DIV_INDEX,
    SC_DIV_REASON,
    SC_FROZEN,
    SC_HELD,
    SC_K,
    SC_STEPS,
)


@numba.njit(cache=True, _nrt=False)
def _read(ring, k, position):
    """Value and slope (per sample) at fractional sample ``position`` from the ring.

    The ring holds samples ``oldest .. k`` (``oldest = max(0, k - size + 1)``). Inside,
    the bicubic kernel of Boer & Kenyon's Appendix on ``n - 1 .. n + 2``. Where that
    stencil would need samples after the newest (a delay under two samples), the cubic
    through the newest four samples is used instead (one-sided, still third order, and
    its slope stays informative at a zero delay, where a repeated end sample would give
    none). Positions after ``k`` read the newest sample's cubic at ``k``; positions
    before ``oldest`` its value with zero slope.
    """
    size = ring.shape[0]
    oldest = k - size + 1
    if oldest < 0:
        oldest = 0
    if position <= oldest:
        return ring[oldest % size], 0.0
    n = int(np.floor(position))
    if n + 2 <= k:
        d = position - n
        i_m1 = n - 1 if n - 1 >= oldest else oldest
        x_m1 = ring[i_m1 % size]
        x_0 = ring[n % size]
        x_1 = ring[(n + 1) % size]
        x_2 = ring[(n + 2) % size]
        a, b, c, w = bicubic_weights(d)
        value = a * x_m1 + b * x_0 + c * x_1 + w * x_2
        a, b, c, w = bicubic_derivative_weights(d)
        slope = a * x_m1 + b * x_0 + c * x_1 + w * x_2
        return value, slope
    # one-sided cubic through k, k-1, k-2, k-3 at s = position - k in [-1, 0]
    s = position - k
    if s > 0.0:
        s = 0.0
    x0 = ring[k % size]
    x1 = ring[(k - 1 if k - 1 >= oldest else oldest) % size]
    x2 = ring[(k - 2 if k - 2 >= oldest else oldest) % size]
    x3 = ring[(k - 3 if k - 3 >= oldest else oldest) % size]
    p1, p2, p3 = s + 1.0, s + 2.0, s + 3.0
    value = (
        x0 * p1 * p2 * p3 / 6.0
        - x1 * s * p2 * p3 / 2.0
        + x2 * s * p1 * p3 / 2.0
        - x3 * s * p1 * p2 / 6.0
    )
    slope = (
        x0 * (p2 * p3 + p1 * p3 + p1 * p2) / 6.0
        - x1 * (p2 * p3 + s * p3 + s * p2) / 2.0
        + x2 * (p1 * p3 + s * p3 + s * p1) / 2.0
        - x3 * (p1 * p2 + s * p2 + s * p1) / 6.0
    )
    return value, slope


@numba.njit(cache=True, _nrt=False)
def _past_output(ring_y, k, back):
    """``y[k - back]``, 0 before the first sample (the system starts at rest)."""
    j = k - back
    if j < 0 or back >= ring_y.shape[0]:
        return 0.0
    return ring_y[j % ring_y.shape[0]]


@numba.njit(cache=True, _nrt=False)
def predict(cfg, p, ring_r, ring_y, k, gradient):
    """``y_hat`` at sample ``k`` for parameters ``p``; ``gradient`` (n_p,) gets dy_hat/dp."""
    dt = cfg[CFG_DT]
    lam = int(cfg[CFG_LAMBDA])
    n_a = int(cfg[CFG_NA])
    n_b = int(cfg[CFG_NB])
    shift = p[0] / dt
    value = 0.0
    slope_sum = 0.0
    for i in range(1, n_a + 1):
        y_past = _past_output(ring_y, k, i * lam)
        gradient[i] = y_past
        value += p[i] * y_past
    for m in range(n_b + 1):
        j = 1 + n_a + m
        r_value, r_slope = _read(ring_r, k, k - m * lam - shift)
        gradient[j] = r_value
        value += p[j] * r_value
        slope_sum += p[j] * r_slope
    gradient[0] = -slope_sum / dt
    return value


@numba.njit(cache=True, _nrt=False)
def _report(config, belief, scratch, row, out, prediction, innovation, S, flags):
    x, P, p = belief.x, belief.P, belief.p
    variance = scratch.variance
    for j in range(p.shape[0]):
        variance[j] = 0.0
    for i in range(x.shape[0]):
        variance[config.state_param[i]] = P[i, i]
    for j in range(p.shape[0]):
        out.mean[row, j] = p[j]
        out.std[row, j] = np.sqrt(variance[j]) if variance[j] > 0.0 else 0.0
        out.pinned[row, j] = False
    for i in range(x.shape[0]):
        j = config.state_param[i]
        if config.limit[i] >= 0 and (p[j] <= config.lo[j] or p[j] >= config.hi[j]):
            out.pinned[row, j] = True
    out.scalar[row, 0] = prediction
    out.scalar[row, 1] = innovation
    out.scalar[row, 2] = S
    for f in range(flags.shape[0]):
        out.flag[row, f] = flags[f]


@numba.njit(cache=True, _nrt=False)
def rdi_step(config, belief, scratch, r_k, y_k, row, out):
    """Consume one sample; write its estimate into output row ``row`` (module docstring)."""
    cfg = config.cfg
    x, P, p, ring_r, ring_y, sc = belief
    H = scratch.H
    k = int(sc[SC_K])
    size = ring_r.shape[0]
    ring_r[k % size] = r_k
    ring_y[k % size] = y_k
    sc[SC_K] = k + 1
    lam = int(cfg[CFG_LAMBDA])
    n_a = int(cfg[CFG_NA])
    n_s = x.shape[0]
    flags = scratch.flags  # finite, cov ok, dropped, diverged, identified, held
    gradient = scratch.gradient
    for f in range(flags.shape[0]):
        flags[f] = False

    if sc[SC_FROZEN] > 0.0:
        # a diverged filter repeats its last estimate and predicts nothing
        store_belief(row, x, P, out.x_prior, out.P_prior)
        store_belief(row, x, P, out.x_post, out.P_post)
        flags[0] = sc[SC_DIV_REASON] != REASON_NONFINITE
        flags[1] = sc[SC_DIV_REASON] != REASON_COVARIANCE
        flags[3] = True
        _report(config, belief, scratch, row, out, np.nan, np.nan, np.nan, flags)
        return

    # identify on the decimated grid once every regressor lies in the recorded history
    # (the bicubic stencil of the oldest delayed read included): reading before the
    # first sample would hold it, and a wrong regressor with a small R is a large jump
    oldest_read = k - int(cfg[CFG_NB]) * lam - p[0] / cfg[CFG_DT]
    available = k - size + 1 if k - size + 1 > 0 else 0
    identify = k % lam == 0 and k >= n_a * lam and np.floor(oldest_read) - 1.0 >= available
    if identify:
        # time update, eqs. 1a/2a with f = I: P^- = P^+ + Q
        for i in range(n_s):
            P[i, i] += config.q[i]
    store_belief(row, x, P, out.x_prior, out.P_prior)

    prediction = predict(cfg, p, ring_r, ring_y, k, gradient)
    for i in range(n_s):
        H[0, i] = gradient[config.state_param[i]]
    S = cfg[CFG_R]
    for i in range(n_s):
        acc = 0.0
        for j in range(n_s):
            acc += P[i, j] * H[0, j]
        S += H[0, i] * acc
    dropped = not (np.isfinite(y_k) and np.isfinite(prediction) and np.isfinite(S))
    innovation = np.nan if dropped else y_k - prediction
    correct_ok = True
    if identify and not dropped:
        sc[SC_STEPS] += 1.0
        held = False
        if cfg[CFG_SIGN] > 0.0 and k >= 1:
            # Sec. III-F: sign of the magnitude and of the rate, measured vs predicted
            previous = predict(cfg, p, ring_r, ring_y, k - 1, gradient)
            y_previous = ring_y[(k - 1) % size]
            if y_k * prediction < 0.0 or (y_k - y_previous) * (prediction - previous) < 0.0:
                held = True
        if held:
            sc[SC_HELD] += 1.0
            flags[5] = True
        else:
            flags[4] = True
            scratch.r[0] = innovation
            scratch.R[0, 0] = cfg[CFG_R]
            correct_ok = joseph_correct(
                x, P, scratch.r, H, scratch.R, scratch.work, cfg[CFG_JITTER]
            )
            S = scratch.work.S[0, 0]
            clamp(x, config.limit, config.lo, config.hi)
            for i in range(n_s):
                p[config.state_param[i]] = x[i]
    store_belief(row, x, P, out.x_post, out.P_post)

    finite, cov_ok = belief_health(x, P, cfg[CFG_MAX_COV], False)
    if not correct_ok:
        if np.isfinite(S):
            cov_ok = False
        else:
            finite = False
    if not dropped and not np.isfinite(innovation):
        finite = False
    flags[0] = finite
    flags[1] = cov_ok
    flags[2] = dropped
    if not (finite and cov_ok):
        sc[SC_FROZEN] = 1.0
        sc[SC_DIV_INDEX] = row
        sc[SC_DIV_REASON] = REASON_NONFINITE if not finite else REASON_COVARIANCE
        flags[3] = True
    _report(config, belief, scratch, row, out, prediction, innovation, S, flags)


@numba.njit(cache=True, _nrt=False)
def rdi_run(config, belief, scratch, r, y, out):
    """:func:`rdi_step` over every sample of ``r`` and ``y``."""
    for k in range(y.shape[0]):
        rdi_step(config, belief, scratch, r[k], y[k], k, out)


@numba.njit(cache=True)
def simulate_output(p, r, dt, lam, n_a, n_b):
    """The model's output from the input alone (its own past outputs fed back).

    ``p`` (n, n_p): the parameter vector at every sample (the identified traces); the
    output error counterpart of :func:`predict`, started at rest, reading ``r``
    causally as the filter does.
    """
    n = r.shape[0]
    out = np.zeros(n)
    ring_r = np.zeros(n)
    ring_y = np.zeros(n)
    cfg = np.zeros(CFG_SIZE)
    cfg[CFG_DT] = dt
    cfg[CFG_LAMBDA] = lam
    cfg[CFG_NA] = n_a
    cfg[CFG_NB] = n_b
    gradient = np.empty(p.shape[1])
    for k in range(n):
        ring_r[k] = r[k]
        value = predict(cfg, p[k], ring_r, ring_y, k, gradient)
        ring_y[k] = value
        out[k] = value
    return out
