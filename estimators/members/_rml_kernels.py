"""The numba kernels of :mod:`~manualcontrol.estimators.members._rml_core`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference, ``bench/compile_kernels.py``'s numba jobs): the records and
constants stay in the numba-free module, which exports these kernels by name on first
use, and the RML names them by :class:`~manualcontrol.envs._lazy.LazyKernel`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from manualcontrol.envs._interpolation import bicubic_weights
from manualcontrol.estimators._pilot_core import (
    CFG_DT,
    CFG_ERROR_STATE,
    CFG_FLOOR,
    CFG_GAMMA2,
    CFG_MAX_COV,
    PAPERS_DT,
    SC_E,
    SC_FROZEN,
    SC_K,
)
from manualcontrol.estimators._pilot_kernels import (
    inputs_in_use,
    noise_levels,
    report_frozen,
    report_row,
)
from manualcontrol.estimators.filters._kalman_kernels import joseph_correct, predict_covariance
from manualcontrol.estimators.filters._linalg_kernels import (
    cholesky,
    cholesky_solve_rows,
    symmetrise,
)
from manualcontrol.estimators.filters._monitor_kernels import belief_health, window_variance
from manualcontrol.estimators.filters._smoother_kernels import store_belief
from manualcontrol.estimators.filters.batch import take
from manualcontrol.estimators.members._internal_model_kernels import (
    evaluate_coefficients,
    model_f,
    model_g,
)
from manualcontrol.estimators.members._rml_core import (
    _FILLED,
    INJECT_INPUT,
    INJECT_OUTPUT,
    SLOT_LOG_BREAK,
    SLOT_LOG_INTENSITY,
)


@numba.njit(cache=True, _nrt=False)
def _read(hist, row, newest, position):
    """Bicubic read of input ``row`` at fractional sample ``position`` (ring buffer).

    Samples older than the ring or before the first are replaced by the oldest kept,
    positions after ``newest`` by the newest sample.
    """
    size = hist.shape[1]
    oldest = newest - size + 1
    if oldest < 0:
        oldest = 0
    if position >= newest:
        return hist[row, newest % size]
    if position <= oldest:
        return hist[row, oldest % size]
    n = int(position)  # position > oldest >= 0: truncation is the floor
    d = position - n
    w_m1, w_0, w_1, w_2 = bicubic_weights(d)
    i_m1 = max(n - 1, oldest)
    i_1 = min(n + 1, newest)
    i_2 = min(n + 2, newest)
    return (
        w_m1 * hist[row, i_m1 % size]
        + w_0 * hist[row, n % size]
        + w_1 * hist[row, i_1 % size]
        + w_2 * hist[row, i_2 % size]
    )


@numba.njit(cache=True, _nrt=False)
def _delayed_inputs(lines, point_p, newest, position, dt):
    """The inputs of a point with parameters ``point_p`` at sample ``position``."""
    tau = point_p[lines.delay_slot]
    for i in range(lines.point_in.shape[0]):
        delay = tau
        if lines.extra_slot[i] >= 0:
            delay += point_p[lines.extra_slot[i]]
        lines.point_in[i] = _read(lines.hist, i, newest, position - delay / dt)


@numba.njit(cache=True, _nrt=False)
def _member_parameters(config, th, point_p):
    """Model parameters of a bank point into ``point_p``; returns (intensity, break).

    The intensity parameter is relative: the remnant's stationary variance over the
    error variance of the first window, ``intensity = exp(log_rel) var_e 2 omega_r``.
    """
    log_rel = config.remnant[0]
    log_w = config.remnant[1]
    for j in range(th.shape[0]):
        slot = config.slot[j]
        if slot >= 0:
            point_p[slot] = th[j]
        elif slot == SLOT_LOG_INTENSITY:
            log_rel = th[j]
        elif slot == SLOT_LOG_BREAK:
            log_w = th[j]
    omega = math.exp(log_w)
    return math.exp(log_rel + config.base[0]) * 2.0 * omega, omega


@numba.njit(cache=True, _nrt=False)
def _member_step(model, config, lines, belief, s, i, k, u_k, R, q_error, dropped, predict):
    """Predict (unless the first sample) and correct member ``i``; its z and S to ``s``."""
    cfg = config.cfg
    dt = cfg[CFG_DT]
    gamma2 = cfg[CFG_GAMMA2]
    x = belief.X[i]
    P = belief.PX[i]
    ns = x.shape[0]
    n_c = s.f.shape[0]
    err = int(cfg[CFG_ERROR_STATE])
    has_r = config.has_remnant
    intensity, omega = _member_parameters(config, s.points[i], s.point_p)
    evaluate_coefficients(s.point_p, model)
    if predict:
        substeps = config.substeps
        h = dt / substeps
        Phi, sub, T = s.Phi, s.sub, s.T
        for a in range(ns):
            for b in range(ns):
                Phi[a, b] = 1.0 if a == b else 0.0
        n = x[n_c] if has_r and config.inject == INJECT_INPUT else 0.0
        for c in range(n_c):
            s.xs[c] = x[c]
        for m in range(substeps):
            _delayed_inputs(lines, s.point_p, k, k - 1.0 + (m + 0.5) / substeps, dt)
            model_f(s.xs, lines.point_in, model, s.f, s.F, s.dfdp, False)
            for c in range(n_c):
                s.xs[c] += s.f[c] * h
            s.xs[err] += n * h
            # sub = I + h [F, e_err (remnant)]; Phi <- sub Phi
            for a in range(ns):
                for b in range(ns):
                    sub[a, b] = 1.0 if a == b else 0.0
            for a in range(n_c):
                for b in range(n_c):
                    sub[a, b] += h * s.F[a, b]
            if has_r and config.inject == INJECT_INPUT:
                sub[err, n_c] += h
            for a in range(ns):
                for b in range(ns):
                    acc = 0.0
                    for c in range(ns):
                        acc += sub[a, c] * Phi[c, b]
                    T[a, b] = acc
            for a in range(ns):
                for b in range(ns):
                    Phi[a, b] = T[a, b]
        for c in range(n_c):
            x[c] = s.xs[c]
        Q = s.Q
        for a in range(ns):
            for b in range(ns):
                Q[a, b] = 0.0
        Q[err, err] = q_error * gamma2
        if has_r:
            decay = math.exp(-omega * dt)
            Phi[n_c, n_c] = decay
            for b in range(n_c):
                Phi[n_c, b] = 0.0
            x[n_c] = decay * x[n_c]
            Q[n_c, n_c] = intensity * (1.0 - decay * decay) / (2.0 * omega)
        predict_covariance(P, Phi, Q, T)
    # measurement
    _delayed_inputs(lines, s.point_p, k, float(k), dt)
    for c in range(n_c):
        s.xs[c] = x[c]
    z = model_g(s.xs, lines.point_in, model, s.dgdx, s.dgdp, False)
    for c in range(n_c):
        s.H[0, c] = s.dgdx[c]  # model_g writes dg/dx whatever its last argument
    if has_r:
        s.H[0, n_c] = 1.0 if config.inject == INJECT_OUTPUT else 0.0
        if config.inject == INJECT_OUTPUT:
            z += x[n_c]
    s.z[i] = z
    if dropped:
        S = R
        for a in range(ns):
            acc = 0.0
            for b in range(ns):
                acc += P[a, b] * s.H[0, b]
            S += s.H[0, a] * acc
        s.S[i] = S
        return
    s.r[0] = u_k - z
    s.R[0, 0] = R
    joseph_correct(x, P, s.r, s.H, s.R, s.work, 0.0)  # leaves x, P as they were if S <= 0
    s.S[i] = s.work.S[0, 0]


@numba.njit(cache=True, _nrt=False)
def _bank_points(config, belief, s):
    """``L = chol(P)`` and the points ``theta``, ``theta +- h_j L e_j`` (projected).

    ``h_j`` is the bank's spread, reduced along a direction where it would move a
    parameter further than its ``spread_cap``.
    """
    th, P = belief.th, belief.P
    n_t = th.shape[0]
    if not cholesky(P, s.L):
        return False
    for a in range(n_t):
        s.points[0, a] = th[a]
    for j in range(n_t):
        h = config.step
        for a in range(n_t):
            if abs(s.L[a, j]) * h > config.spread_cap[a]:
                h = config.spread_cap[a] / abs(s.L[a, j])
        s.h_dir[j] = h
        for a in range(n_t):
            d = h * s.L[a, j]
            s.points[1 + 2 * j, a] = th[a] + d
            s.points[2 + 2 * j, a] = th[a] - d
    for r in range(s.points.shape[0]):
        for a in range(n_t):
            if s.points[r, a] < config.lo[a]:
                s.points[r, a] = config.lo[a]
            elif s.points[r, a] > config.hi[a]:
                s.points[r, a] = config.hi[a]
    return True


@numba.njit(cache=True, _nrt=False)
def _update_parameters(config, belief, s, u_k, k):
    """The Gauss-Newton (Bayesian) step of the module docstring.

    Before sample ``config.noise_first`` only the noise parameters learn: the pilot
    parameters' directions get no score and no information.
    """
    th, P = belief.th, belief.P
    n_t = th.shape[0]
    noise_only = k < config.noise_first
    z0 = s.z[0]
    S0 = s.S[0]
    if not (S0 > 0.0) or not np.isfinite(z0):
        return False
    nu = u_k - z0
    for j in range(n_t):
        s.dz[j] = (s.z[1 + 2 * j] - s.z[2 + 2 * j]) / (2.0 * s.h_dir[j])
        s.dS[j] = (s.S[1 + 2 * j] - s.S[2 + 2 * j]) / (2.0 * s.h_dir[j])
    for j in range(n_t):
        # parameters the remnant does not pass through learn from the prediction only
        if config.slot[j] >= 0 and not config.variance_score[config.slot[j]]:
            s.dS[j] = 0.0
    if noise_only:
        # xi_j moves theta along L e_j: keep only the directions of the noise parameters
        # (L is lower triangular with the noise parameters last, so those columns leave
        # the pilot parameters alone)
        for j in range(n_t):
            if config.slot[j] >= 0:
                s.dz[j] = 0.0
                s.dS[j] = 0.0
    w = 1.0 / S0 - nu * nu / (S0 * S0)
    for j in range(n_t):
        s.g[j] = nu / S0 * s.dz[j] - 0.5 * w * s.dS[j]
    for a in range(n_t):
        for b in range(n_t):
            s.Lam[a, b] = s.dz[a] * s.dz[b] / S0 + 0.5 * s.dS[a] * s.dS[b] / (S0 * S0)
        s.Lam[a, a] += 1.0
    if not cholesky(s.Lam, s.LamL):
        return False
    # xi = Lambda^-1 g (g as a row), then theta += L xi
    for j in range(n_t):
        s.xi[0, j] = s.g[j]
    cholesky_solve_rows(s.LamL, s.xi, s.xi)
    for a in range(n_t):
        acc = 0.0
        for j in range(n_t):
            acc += s.L[a, j] * s.xi[0, j]
        th[a] += acc
    # P = L Lambda^-1 L^T: the rows of B solve B Lambda = L
    cholesky_solve_rows(s.LamL, s.L, s.B)
    for a in range(n_t):
        for b in range(n_t):
            acc = 0.0
            for j in range(n_t):
                acc += s.B[a, j] * s.L[b, j]
            P[a, b] = acc
    symmetrise(P)
    for a in range(n_t):
        if th[a] < config.lo[a]:
            th[a] = config.lo[a]
        elif th[a] > config.hi[a]:
            th[a] = config.hi[a]
    return True


@numba.njit(cache=True, _nrt=False)
def _adapt_process_noise(config, th, drift, prior):
    """Raise a pilot parameter's process noise while its corrections keep one sign.

    The correction of parameter ``a`` at this sample, in prior standard deviations,
    ``c = (theta_a^+ - theta_a^-) / sigma_a^-``, enters two exponential moving means
    (weight ``w = drift_rule[1]``, ``min(1, dt / window)``): ``m`` of ``c`` and ``M`` of
    ``|c|``. Their ratio ``rho = |m| / M`` is near 0 for corrections that cancel and 1 for
    corrections that all push one way, which is what a random walk too slow for a
    changing parameter makes: the estimate lags, and every sample corrects it in the
    same direction. The factor on the parameter's ``Q`` for the next sample is ``1 +
    gain (rho - rho_0) / (1 - rho_0)`` above the threshold ``rho_0`` and 1 below
    (``drift_rule = (gain, w, rho_0)``). Per-parameter rates raised while successive
    updates agree are the delta-bar-delta rule of Jacobs (1988) and Sutton's IDBD
    (1992) for tracking; here the rate is the random walk's variance. The noise
    parameters keep their ``Q``.

    A few corrections always look one-sided (one alone gives ``rho = 1``), so the rule
    waits until the means hold a window's worth of updates: their accumulated weight
    ``1 - (1 - w)^n`` (row 3 of ``drift``) must reach ``1 - 1/e``. The means advance on
    the samples that update the parameters (not on dropped ones).
    """
    gain, weight, threshold = config.drift_rule[0], config.drift_rule[1], config.drift_rule[2]
    for a in range(th.shape[0]):
        if config.slot[a] < 0 or not (prior[1, a] > 0.0):
            continue
        c = (th[a] - prior[0, a]) / prior[1, a]
        drift[0, a] += weight * (c - drift[0, a])
        drift[1, a] += weight * (abs(c) - drift[1, a])
        drift[3, a] += weight * (1.0 - drift[3, a])
        if drift[3, a] < _FILLED or not (drift[1, a] > 0.0):
            continue
        rho = abs(drift[0, a]) / drift[1, a]
        excess = (rho - threshold) / (1.0 - threshold)
        drift[2, a] = 1.0 + gain * excess if excess > 0.0 else 1.0


@numba.njit(cache=True, _nrt=False)
def _remnant_weight(config, point, p):
    """The part of ``R`` that follows the remnant: ``r2_remnant g^2 var(r)``.

    ``var(r)`` is the remnant state's stationary variance and ``g`` the gain it passes
    on its way to the stick (``K_p`` at the perception, 1 at the stick), both at the
    bank's centre ``point`` (model parameters not estimated from ``p``): a weighting
    evaluated at the current estimate, as ``var(u)`` is evaluated on the data, not a
    function of each member's parameters (the bank's differences would then pull
    ``K_p`` and the intensity towards a smaller ``R``; tried: ``K_p`` at its lower
    limit).
    """
    index = int(config.remnant_weight[1])
    gain = 1.0 if index < 0 else p[index]
    log_rel = config.remnant[0]
    for j in range(point.shape[0]):
        if index >= 0 and config.slot[j] == index:
            gain = point[j]
        elif config.slot[j] == SLOT_LOG_INTENSITY:
            log_rel = point[j]
    return config.remnant_weight[0] * gain * gain * math.exp(log_rel + config.base[0])


@numba.njit(cache=True, _nrt=False)
def bank_step(model, config, lines, belief, monitor, report, s, inputs_k, u_k, e_k, row, out):
    """One sample of the filter bank; writes row ``row`` of ``out``."""
    cfg = config.cfg
    th, P, X, _, prev_in, p, sc, drift = belief
    n_t = th.shape[0]
    k = int(sc[SC_K])
    in_use = s.in_use
    R, _, q_error = noise_levels(cfg, sc, monitor, u_k, e_k)
    dropped = inputs_in_use(inputs_k, u_k, prev_in, in_use)
    size = lines.hist.shape[1]
    for i in range(in_use.shape[0]):
        lines.hist[i, k % size] = in_use[i]
    if sc[SC_FROZEN] > 0.0:
        store_belief(row, th, P, out.th_prior, out.P_prior)
        store_belief(row, th, P, out.th_post, out.P_post)
        report_frozen(sc, monitor, prev_in, in_use, dropped, row, out)
        return
    gamma2 = cfg[CFG_GAMMA2]
    anchored = k >= config.base[1]
    if not anchored:
        # a causal start: the error variance of the samples so far, floored
        config.base[0] = math.log(max(window_variance(sc, SC_E), cfg[CFG_FLOOR]))
    if k > 0 and anchored:
        for a in range(n_t):
            if k >= config.noise_first or config.slot[a] < 0:
                P[a, a] += config.q[a] * drift[2, a] * gamma2
    store_belief(row, th, P, out.th_prior, out.P_prior)
    for a in range(n_t):
        s.prior[0, a] = th[a]
        s.prior[1, a] = math.sqrt(P[a, a])
    for j in range(p.shape[0]):
        s.point_p[j] = p[j]
    ok = _bank_points(config, belief, s)
    if ok:
        if config.remnant_weight[0] > 0.0 and config.has_remnant:
            R += _remnant_weight(config, s.points[0], p)
        # R is a sample's variance at 100 Hz, a white noise's density at any rate
        # (rml.py, "Sample rates"): the remnant state's noise is exact
        R *= PAPERS_DT / cfg[CFG_DT]
        for i in range(s.points.shape[0]):
            _member_step(model, config, lines, belief, s, i, k, u_k, R, q_error, dropped, k > 0)
        if not dropped and anchored:
            ok = _update_parameters(config, belief, s, u_k, k)
            if ok and config.drift_rule[0] > 0.0 and k >= config.noise_first:
                _adapt_process_noise(config, th, drift, s.prior)
    store_belief(row, th, P, out.th_post, out.P_post)
    for i in range(prev_in.shape[0]):
        prev_in[i] = in_use[i]

    finite, cov_ok = belief_health(th, P, cfg[CFG_MAX_COV], False)
    finite = finite and np.isfinite(s.z[0]) and np.isfinite(s.S[0])
    for i in range(X.shape[0]):
        for a in range(X.shape[1]):
            if not np.isfinite(X[i, a]):
                finite = False
    cov_ok = ok and cov_ok
    variance = s.variance
    for a in range(n_t):
        slot = config.slot[a]
        if slot >= 0:
            p[slot] = th[a]
            variance[slot] = P[a, a]
    prediction = s.z[0]
    innovation = np.nan if dropped else u_k - prediction
    s.scalars[0] = prediction
    s.scalars[1] = innovation
    s.scalars[2] = s.S[0]
    report_row(
        sc,
        monitor,
        report,
        p,
        variance,
        config.estimated,
        finite,
        cov_ok,
        dropped,
        s.scalars,
        row,
        out,
    )
    intensity, omega = _member_parameters(config, th, s.point_p)
    out.extra[row, 0] = X[0, X.shape[1] - 1] if config.has_remnant else 0.0
    out.extra[row, 1] = intensity if config.has_remnant else 0.0
    out.extra[row, 2] = omega if config.has_remnant else 0.0


@numba.njit(cache=True, _nrt=False)
def bank_step_many(
    model, config, lines, belief, monitor, report, s, inputs, u, e, active, rows, out_rows, out
):
    """:func:`bank_step` on every filter bank of a stack whose ``active[i]`` is set.

    See :func:`~manualcontrol.estimators.members._dekf_core.dekf_step_many`.
    """
    records = (model, config, lines, belief, monitor, report, s, out)
    last = 0
    views = take(records, 0)
    for i in range(u.shape[0]):
        if active[i]:
            r = rows[i]
            if r != last:  # a block of one filter's samples takes its views once
                views = take(records, r)
                last = r
            bank_step(*views[:7], inputs[i], u[i], e[i], out_rows[i], views[7])
