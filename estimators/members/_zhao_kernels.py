"""The numba kernels of :mod:`~manualcontrol.estimators.members._zhao_core`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference, ``bench/compile_kernels.py``'s numba jobs): the records and
constants stay in the numba-free module, which exports these kernels by name on first
use, and the Zhao UKF and the multi-UKF name them by
:class:`~manualcontrol.envs._lazy.LazyKernel`.
"""

from __future__ import annotations

import numba
import numpy as np

from manualcontrol.estimators._pilot_core import (
    SC_DIV_INDEX,
    SC_DIV_PARAM,
    SC_DIV_REASON,
    SC_FROZEN,
    SC_K,
)
from manualcontrol.estimators._pilot_kernels import report_frozen, report_row
from manualcontrol.estimators.filters._kalman_kernels import clamp
from manualcontrol.estimators.filters._monitor_kernels import belief_health
from manualcontrol.estimators.filters._unscented_kernels import (
    cross_covariance,
    sigma_points,
    unscented_correct,
    weighted_covariance,
    weighted_mean,
)
from manualcontrol.estimators.filters.monitor import REASON_COVARIANCE, REASON_NONE
from manualcontrol.estimators.members._zhao_core import (
    CFG_COUNT,
    CFG_H,
    CFG_JITTER,
    CFG_MAX_COV,
    CFG_SPREAD,
    CFG_SUBSTEPS,
    CFG_VX,
    N_INPUTS,
    N_OUTPUTS,
    N_STATES,
)
from manualcontrol.pilots._driver_kernels import driver_matrices


@numba.njit(cache=True, _nrt=False)
def _parameters(config, X, row, p):
    """The model parameter vector of sigma point ``row`` into ``p``."""
    for j in range(p.shape[0]):
        p[j] = config.base[j]
    for t in range(config.theta_index.shape[0]):
        p[config.theta_index[t]] = X[row, N_STATES + t]


@numba.njit(cache=True, _nrt=False)
def _measure(config, scratch, X, count, inputs, Z):
    """``Z[i] = C(theta_i) x_i + D(theta_i) u`` for the first ``count`` points."""
    p, A, B, C, D = scratch.point, scratch.A, scratch.B, scratch.C, scratch.D
    v_x = config.cfg[CFG_VX]
    for i in range(count):
        _parameters(config, X, i, p)
        driver_matrices(p, v_x, A, B, C, D)
        for r in range(N_OUTPUTS):
            acc = 0.0
            for j in range(N_STATES):
                acc += C[r, j] * X[i, j]
            for j in range(N_INPUTS):
                acc += D[r, j] * inputs[j]
            Z[i, r] = acc


@numba.njit(cache=True, _nrt=False)
def _propagate(config, scratch, X, count, inputs, Y):
    """``Y[i] = f_d(X[i], u)``: Euler sub-steps of eq. 6, parameters unchanged."""
    p, A, B, C, D, Bu, y = (
        scratch.point,
        scratch.A,
        scratch.B,
        scratch.C,
        scratch.D,
        scratch.Bu,
        scratch.y,
    )
    cfg = config.cfg
    v_x = cfg[CFG_VX]
    h = cfg[CFG_H]
    substeps = int(cfg[CFG_SUBSTEPS])
    n = X.shape[1]
    for i in range(count):
        _parameters(config, X, i, p)
        driver_matrices(p, v_x, A, B, C, D)
        for r in range(N_STATES):
            acc = 0.0
            for j in range(N_INPUTS):
                acc += B[r, j] * inputs[j]
            Bu[r] = acc
            y[r] = X[i, r]
        # eq. 2's A is lower triangular (the lag feeds the Padé state, both feed Gamma_d)
        a00, a10, a11 = A[0, 0], A[1, 0], A[1, 1]
        a20, a21, a22 = A[2, 0], A[2, 1], A[2, 2]
        y0, y1, y2 = y[0], y[1], y[2]
        for _ in range(substeps):
            d0 = a00 * y0 + Bu[0]
            d1 = a10 * y0 + a11 * y1 + Bu[1]
            d2 = a20 * y0 + a21 * y1 + a22 * y2 + Bu[2]
            y0 += h * d0
            y1 += h * d1
            y2 += h * d2
        y[0], y[1], y[2] = y0, y1, y2
        for r in range(N_STATES):
            Y[i, r] = y[r]
        for r in range(N_STATES, n):
            Y[i, r] = X[i, r]


@numba.njit(cache=True, _nrt=False)
def _store(row, x, P, target_x, target_P):
    if target_x.shape[0] == 0:
        return
    for i in range(x.shape[0]):
        target_x[row, i] = x[i]
        for j in range(x.shape[0]):
            target_P[row, i, j] = P[i, j]


@numba.njit(cache=True, _nrt=False)
def zhao_step(config, belief, monitor, report, scratch, inputs_k, y_k, row, out):
    """Advance the belief by one sample (module docstring); write row ``row`` of ``out``.

    ``out.scalar[row]`` = (prediction, innovation, innovation variance) of ``Gamma_d``;
    ``out.predictions/innovations/S`` hold both outputs.
    """
    cfg = config.cfg
    x, P, prev_in, p, sc, link = belief
    w = scratch.work
    n = x.shape[0]
    n_t = config.theta_index.shape[0]
    k = int(sc[SC_K])
    in_use = scratch.in_use
    dropped = False
    for i in range(N_INPUTS):
        if np.isnan(inputs_k[i]):
            dropped = True
            in_use[i] = prev_in[i]
        else:
            in_use[i] = inputs_k[i]
    for r in range(N_OUTPUTS):
        if np.isnan(y_k[r]):
            dropped = True
    if sc[SC_FROZEN] > 0.0:
        _store(row, x, P, out.x_prior, out.P_prior)
        _store(row, x, P, out.x_post, out.P_post)
        if out.link.shape[0] > 0:
            for i in range(n):
                for j in range(n):
                    out.link[row, i, j] = 0.0
        for r in range(N_OUTPUTS):
            out.predictions[row, r] = np.nan
            out.innovations[row, r] = np.nan
            for c in range(N_OUTPUTS):
                out.S[row, r, c] = np.nan
        for i in range(N_STATES):
            out.states[row, i] = x[i]
        report_frozen(sc, monitor, prev_in, in_use, dropped, row, out)
        return
    _store(row, x, P, out.x_prior, out.P_prior)
    if out.link.shape[0] > 0:
        for i in range(n):
            for j in range(n):
                out.link[row, i, j] = link[i, j]

    # ---- output prediction (Algorithm 2 step 2)
    spread = cfg[CFG_SPREAD]
    count = int(cfg[CFG_COUNT])
    correct_ok = sigma_points(x, P, spread, w.L, w.X)
    if not correct_ok:
        for r in range(N_OUTPUTS):
            out.predictions[row, r] = np.nan
            out.innovations[row, r] = np.nan
            for c in range(N_OUTPUTS):
                out.S[row, r, c] = np.nan
    else:
        _measure(config, scratch, w.X, count, in_use, w.Z)
        weighted_mean(w.Z, config.w_mean, count, w.z)
        weighted_covariance(w.Z, w.z, config.w_cov, count, config.R, w.S)
        for r in range(N_OUTPUTS):
            out.predictions[row, r] = w.z[r]
            scratch.r[r] = y_k[r] - w.z[r]
            out.innovations[row, r] = np.nan if dropped else scratch.r[r]
            for c in range(N_OUTPUTS):
                out.S[row, r, c] = w.S[r, c]
        # ---- correction (step 3)
        if not dropped:
            cross_covariance(w.X, x, w.Z, w.z, config.w_cov, count, w.Cxz)
            correct_ok = unscented_correct(
                x, P, scratch.r, w.Cxz, w.S, w.LS, w.K, w.log_det, cfg[CFG_JITTER]
            )
            clamp(x, config.limit, report.lo, report.hi)
    _store(row, x, P, out.x_post, out.P_post)
    for i in range(N_STATES):
        out.states[row, i] = x[i]
    for i in range(N_INPUTS):
        prev_in[i] = in_use[i]

    # ---- health and report (before the prediction: the estimate after this sample)
    finite, cov_ok = belief_health(x, P, cfg[CFG_MAX_COV], True)
    if not correct_ok:
        cov_ok = False
    variance = scratch.variance
    for j in range(p.shape[0]):
        p[j] = config.base[j]
        variance[j] = 0.0
    for t in range(n_t):
        p[config.theta_index[t]] = x[N_STATES + t]
        variance[config.theta_index[t]] = P[N_STATES + t, N_STATES + t]
    scalars = scratch.scalars
    scalars[0] = out.predictions[row, 0]
    scalars[1] = out.innovations[row, 0]
    scalars[2] = out.S[row, 0, 0]
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
        scalars,
        row,
        out,
    )
    if sc[SC_FROZEN] > 0.0:
        return

    # ---- prediction of the next prior (step 4)
    if sigma_points(x, P, spread, w.L, w.X):
        _propagate(config, scratch, w.X, count, in_use, w.Y)
        weighted_mean(w.Y, config.w_mean, count, w.xbar)
        cross_covariance(w.X, x, w.Y, w.xbar, config.w_cov, count, link)
        weighted_covariance(w.Y, w.xbar, config.w_cov, count, config.Q, P)
        for i in range(n):
            x[i] = w.xbar[i]
    else:  # the posterior covariance is not positive definite: stop here
        sc[SC_FROZEN] = 1.0
        if sc[SC_DIV_REASON] == REASON_NONE:
            sc[SC_DIV_REASON] = REASON_COVARIANCE
            sc[SC_DIV_INDEX] = k
            sc[SC_DIV_PARAM] = -1


@numba.njit(cache=True, _nrt=False)
def zhao_run(config, belief, monitor, report, scratch, inputs, outputs, out):
    """:func:`zhao_step` over every sample: ``inputs`` (n, 4), ``outputs`` (n, 2)."""
    for k in range(inputs.shape[0]):
        zhao_step(config, belief, monitor, report, scratch, inputs[k], outputs[k], k, out)


# ---------------------------------------------------------------------- multi-UKF


@numba.njit(cache=True, _nrt=False)
def fuse_step(fusion, state, slow, out_slow, out_fast, row, out):
    """Fuse row ``row`` of the members' outputs into ``out``; re-centre the slow member.

    ``theta = theta_s + lambda dbar`` per estimated parameter (never beyond ``theta_f``),
    ``dbar`` the EWMA of the disagreement ``theta_f - theta_s``, ``lambda = clip(1 -
    (level + dead_zone^2) / dbar^2, 0, 1)`` with ``level`` the long EWMA of ``dbar^2``;
    the variance is that of the two-component mixture. Predictions, innovations and
    states are the slow member's; the row is marked diverged when either member
    diverged. With feedback the slow member's parameter means move to the fused values
    (projected onto its limits) and the disagreement they remove is taken out of ``dbar``.
    """
    config, belief, _, report, _ = slow
    n_p = out.mean.shape[1]
    for j in range(n_p):
        out.mean[row, j] = out_slow.mean[row, j]
        out.std[row, j] = out_slow.std[row, j]
        out.pinned[row, j] = out_slow.pinned[row, j] or out_fast.pinned[row, j]
    for i in range(3):
        out.scalar[row, i] = out_slow.scalar[row, i]
    for r in range(N_OUTPUTS):
        out.predictions[row, r] = out_slow.predictions[row, r]
        out.innovations[row, r] = out_slow.innovations[row, r]
        for c in range(N_OUTPUTS):
            out.S[row, r, c] = out_slow.S[row, r, c]
    for i in range(N_STATES):
        out.states[row, i] = out_slow.states[row, i]
    out.flag[row, 0] = out_slow.flag[row, 0] and out_fast.flag[row, 0]
    out.flag[row, 1] = out_slow.flag[row, 1] and out_fast.flag[row, 1]
    out.flag[row, 2] = out_slow.flag[row, 2]
    diverged = out_slow.flag[row, 3] or out_fast.flag[row, 3]
    out.flag[row, 3] = diverged
    n_t = fusion.theta_index.shape[0]
    first = state.started[0] == 0.0
    state.started[0] = 1.0
    moved = False
    for t in range(n_t):
        j = fusion.theta_index[t]
        s = out_slow.mean[row, j]
        f = out_fast.mean[row, j]
        out.members[row, t] = s
        out.members[row, n_t + t] = f
        d = f - s
        out.gate[row, t] = 0.0
        if diverged or not np.isfinite(d):
            continue
        if first:
            state.smooth[t] = d
            state.level[t] = d * d
        else:
            state.smooth[t] += fusion.a_short * (d - state.smooth[t])
        dbar = state.smooth[t]
        floor = state.level[t] + fusion.dead_zone[t] * fusion.dead_zone[t]
        lam = 0.0
        if dbar * dbar > floor:
            lam = 1.0 - floor / (dbar * dbar)
        else:
            # the usual level is learnt while the members agree, not from a change
            state.level[t] += fusion.a_long * (dbar * dbar - state.level[t])
        step = lam * dbar
        # never beyond the fast member's current value (dbar may still hold a past
        # disagreement the fast member has already taken back)
        if step > 0.0 and step > d:
            step = max(d, 0.0)
        elif step < 0.0 and step < d:
            step = min(d, 0.0)
        fused = s + step
        out.gate[row, t] = lam
        out.mean[row, j] = fused
        vs = out_slow.std[row, j] * out_slow.std[row, j]
        vf = out_fast.std[row, j] * out_fast.std[row, j]
        out.std[row, j] = np.sqrt((1.0 - lam) * vs + lam * vf + lam * (1.0 - lam) * d * d)
        if fusion.feedback and lam > 0.0:
            belief.x[N_STATES + t] += fused - s
            state.smooth[t] -= fused - s
            moved = True
    if moved:
        clamp(belief.x, config.limit, report.lo, report.hi)


@numba.njit(cache=True, _nrt=False)
def multi_step(slow, fast, fusion, state, inputs_k, y_k, row, out_slow, out_fast, out):
    """Both members' :func:`zhao_step` on one sample, then :func:`fuse_step`."""
    zhao_step(slow[0], slow[1], slow[2], slow[3], slow[4], inputs_k, y_k, row, out_slow)
    zhao_step(fast[0], fast[1], fast[2], fast[3], fast[4], inputs_k, y_k, row, out_fast)
    fuse_step(fusion, state, slow, out_slow, out_fast, row, out)


@numba.njit(cache=True, _nrt=False)
def multi_run(slow, fast, fusion, state, inputs, outputs, out_slow, out_fast, out):
    """:func:`multi_step` over every sample."""
    for k in range(inputs.shape[0]):
        multi_step(slow, fast, fusion, state, inputs[k], outputs[k], k, out_slow, out_fast, out)
