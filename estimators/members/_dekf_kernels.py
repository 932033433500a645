"""The numba kernels of :mod:`~manualcontrol.estimators.members._dekf_core`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference, ``bench/compile_kernels.py``'s numba jobs): the records stay in
the numba-free module, which exports these kernels by name on first use, and the DEKF
names them by :class:`~manualcontrol.envs._lazy.LazyKernel`.
"""

from __future__ import annotations

import numba
import numpy as np

from manualcontrol.estimators._pilot_core import (
    CFG_DIMENSIONAL,
    CFG_DT,
    CFG_ERROR_STATE,
    CFG_GAMMA2,
    CFG_JITTER,
    CFG_MAX_COV,
    CFG_SUBSTEPS,
    PAPERS_DT,
    SC_FROZEN,
    SC_K,
)
from manualcontrol.estimators._pilot_kernels import (
    inputs_in_use,
    noise_levels,
    report_frozen,
    report_row,
)
from manualcontrol.estimators.filters._kalman_kernels import clamp, joseph_correct
from manualcontrol.estimators.filters._linalg_kernels import symmetrise
from manualcontrol.estimators.filters._monitor_kernels import belief_health
from manualcontrol.estimators.filters._smoother_kernels import store_belief
from manualcontrol.estimators.filters.batch import take
from manualcontrol.estimators.members._internal_model_kernels import (
    evaluate_coefficients,
    model_f,
    model_g,
)


@numba.njit(cache=True, _nrt=False)
def _apply_phi(F, is_dense, n_c, dt, src, dst):
    """``dst = (I + dt F) src`` for a square or tall ``src``, F acting on canonical rows."""
    n_cols = src.shape[1]
    for i in range(src.shape[0]):
        if i < n_c and is_dense[i]:
            for c in range(n_cols):
                acc = 0.0
                for j in range(n_c):
                    acc += F[i, j] * src[j, c]
                dst[i, c] = src[i, c] + dt * acc
        elif i < n_c:
            for c in range(n_cols):
                dst[i, c] = src[i, c] + dt * src[i + 1, c]
        else:
            for c in range(n_cols):
                dst[i, c] = src[i, c]


@numba.njit(cache=True, _nrt=False)
def _apply_phi_transpose(F, is_dense, n_c, dt, src, dst):
    """``dst = src (I + dt F)^T``."""
    n = src.shape[0]
    for i in range(src.shape[1]):
        if i < n_c and is_dense[i]:
            for r in range(n):
                acc = 0.0
                for j in range(n_c):
                    acc += src[r, j] * F[i, j]
                dst[r, i] = src[r, i] + dt * acc
        elif i < n_c:
            for r in range(n):
                dst[r, i] = src[r, i] + dt * src[r, i + 1]
        else:
            for r in range(n):
                dst[r, i] = src[r, i]


@numba.njit(cache=True, _nrt=False)
def _store_phi(out, row, F, is_dense, n_c, dt, k):
    """``Phi_s`` of this sample's prediction (identity on the gains; identity at k = 0)."""
    Phi = out.Phi
    if Phi.shape[0] == 0:
        return
    n_s = Phi.shape[1]
    for i in range(n_s):
        for j in range(n_s):
            Phi[row, i, j] = 1.0 if i == j else 0.0
    if k == 0:
        return
    for i in range(n_c):
        if is_dense[i]:
            for j in range(n_c):
                Phi[row, i, j] += dt * F[i, j]
        else:
            Phi[row, i, i + 1] += dt


@numba.njit(cache=True, _nrt=False)
def dekf_step(model, config, belief, monitor, report, scratch, inputs_k, u_k, e_k, row, out):
    """Advance the belief by one sample; write its estimate into output row ``row``.

    ``out.scalar[row]`` = (prediction, innovation, innovation variance);
    ``out.flag[row]`` = (finite, covariance ok, dropped, diverged).
    """
    cfg = config.cfg
    x, P, th, Pp, dx, prev_in, p, sc = belief
    F, f, dfdp, dgdx, dgdp = scratch.F, scratch.f, scratch.dfdp, scratch.dgdx, scratch.dgdp
    H, Ht, dxm, in_use = scratch.H_state, scratch.H_theta, scratch.dxm, scratch.in_use
    gain_index, theta_index = config.gain_index, config.theta_index

    n_c = f.shape[0]
    n_s = x.shape[0]
    n_g = gain_index.shape[0]
    n_t = th.shape[0]
    dt = cfg[CFG_DT]
    gamma2 = cfg[CFG_GAMMA2]
    k = int(sc[SC_K])

    # retrospective variances (Popovici eqs. 24-25, thesis eqs. 29-30)
    R, R_p, q_error = noise_levels(cfg, sc, monitor, u_k, e_k)
    dropped = inputs_in_use(inputs_k, u_k, prev_in, in_use)

    if sc[SC_FROZEN] > 0.0:
        store_belief(row, x, P, out.x_prior, out.P_prior)
        store_belief(row, x, P, out.x_post, out.P_post)
        store_belief(row, th, Pp, out.th_prior, out.Pp_prior)
        store_belief(row, th, Pp, out.th_post, out.Pp_post)
        _store_phi(out, row, F, config.is_dense, n_c, dt, 0)
        report_frozen(sc, monitor, prev_in, in_use, dropped, row, out)
        return

    # current parameter vector: gains from the state filter, theta^- = theta^+ (eq. 11)
    for g in range(n_g):
        p[gain_index[g]] = x[n_c + g]
    for t in range(n_t):
        p[theta_index[t]] = th[t]
    evaluate_coefficients(p, model)

    if k > 0:
        # ---- 1. parameter prediction (eq. 12)
        for t in range(n_t):
            Pp[t, t] += config.q_theta[t] * gamma2
        # ---- 2. state prediction (eqs. 13-14) at x^+_{k-1}, in_{k-1}, theta^-_k: Euler
        # substeps of h = dt / m (one at 100 Hz), Phi_s their product
        m = max(1, int(cfg[CFG_SUBSTEPS]))
        h = dt / m
        # eq. 49's weight of df/dtheta per substep: h (dimensional), h / 0.01 s (printed:
        # 1 a sample at the papers' 100 Hz, the same weight per second at every rate)
        scale = h if cfg[CFG_DIMENSIONAL] > 0.0 else h / PAPERS_DT
        store_phi = out.Phi.shape[0] > 0
        if store_phi:
            _store_phi(out, row, F, config.is_dense, n_c, h, 0)
        for j in range(m):
            model_f(x, prev_in, model, f, F, dfdp, True)
            # total-derivative recursion, eq. 49: dx^-_k = df/dtheta (dt) + Phi dx^+_{k-1}
            if j > 0:
                for i in range(n_s):
                    for t in range(n_t):
                        dx[i, t] = dxm[i, t]
            _apply_phi(F, config.is_dense, n_c, h, dx, dxm)
            for i in range(n_c):
                for t in range(n_t):
                    dxm[i, t] += dfdp[i, theta_index[t]] * scale
            for i in range(n_c):
                x[i] += f[i] * h
            _apply_phi(F, config.is_dense, n_c, h, P, scratch.M)
            _apply_phi_transpose(F, config.is_dense, n_c, h, scratch.M, P)
            if store_phi:
                _apply_phi(F, config.is_dense, n_c, h, out.Phi[row], scratch.M)
                for a in range(n_s):
                    for b in range(n_s):
                        out.Phi[row, a, b] = scratch.M[a, b]
        for i in range(n_s):
            P[i, i] += config.q_state[i] * gamma2
        P[int(cfg[CFG_ERROR_STATE]), int(cfg[CFG_ERROR_STATE])] += q_error * gamma2
        symmetrise(P)
    else:
        for i in range(n_s):
            for t in range(n_t):
                dxm[i, t] = dx[i, t]
        _store_phi(out, row, F, config.is_dense, n_c, dt, k)
    store_belief(row, x, P, out.x_prior, out.P_prior)
    store_belief(row, th, Pp, out.th_prior, out.Pp_prior)

    # ---- output equation at x^-_k, theta^-_k
    prediction = model_g(x, in_use, model, dgdx, dgdp, True)
    for i in range(n_c):
        H[0, i] = dgdx[i]
    for g in range(n_g):
        H[0, n_c + g] = dgdp[gain_index[g]]
    # G_p^tot = dg/dtheta + dg/dx dx^-/dtheta (eq. 48)
    for t in range(n_t):
        acc = dgdp[theta_index[t]]
        for i in range(n_s):
            acc += H[0, i] * dxm[i, t]
        Ht[0, t] = acc

    correct_ok = True
    if dropped:
        innovation = np.nan
        S = R
        for i in range(n_s):
            acc = 0.0
            for j in range(n_s):
                acc += P[i, j] * H[0, j]
            S += H[0, i] * acc
        # no correction: K_s = 0, so dx^+ = dx^- (eq. 50)
        for i in range(n_s):
            for t in range(n_t):
                dx[i, t] = dxm[i, t]
    else:
        innovation = u_k - prediction  # eq. 16
        scratch.r[0] = innovation
        # ---- 3. state correction (eqs. 15-19)
        scratch.R_state[0, 0] = R
        correct_ok = joseph_correct(
            x, P, scratch.r, H, scratch.R_state, scratch.state_work, cfg[CFG_JITTER]
        )
        S = scratch.state_work.S[0, 0]
        K = scratch.state_work.K
        # ---- 4. state limitation (eq. 20): with unit-row D, the projection clamps
        clamp(x, config.state_limit, report.lo, report.hi)
        # ---- 5. parameter correction (eqs. 21-24)
        if n_t > 0 and correct_ok:
            scratch.R_theta[0, 0] = R_p
            correct_ok = joseph_correct(
                th, Pp, scratch.r, Ht, scratch.R_theta, scratch.theta_work, cfg[CFG_JITTER]
            )
            # ---- 6. parameter limitation (eq. 25)
            clamp(th, config.theta_limit, report.lo, report.hi)
        # eq. 50 for the next step: dx^+_k = dx^-_k - K_s,k G_p,k^tot
        for i in range(n_s):
            for t in range(n_t):
                dx[i, t] = dxm[i, t] - K[i, 0] * Ht[0, t]
    store_belief(row, x, P, out.x_post, out.P_post)
    store_belief(row, th, Pp, out.th_post, out.Pp_post)

    for i in range(prev_in.shape[0]):
        prev_in[i] = in_use[i]

    # ---- health and report
    max_cov = cfg[CFG_MAX_COV]
    finite_s, cov_ok_s = belief_health(x, P, max_cov, True)
    finite_t, cov_ok_t = belief_health(th, Pp, max_cov, False)
    finite = np.isfinite(prediction) and finite_s and finite_t
    cov_ok = cov_ok_s and cov_ok_t
    if not dropped and not np.isfinite(innovation):
        finite = False
    if not correct_ok:
        # an innovation variance that is not positive: non-finite, or the covariance broke
        if np.isfinite(S):
            cov_ok = False
        else:
            finite = False
    variance = scratch.variance
    for g in range(n_g):
        p[gain_index[g]] = x[n_c + g]
        variance[gain_index[g]] = P[n_c + g, n_c + g]
    for t in range(n_t):
        p[theta_index[t]] = th[t]
        variance[theta_index[t]] = Pp[t, t]
    scalars = scratch.scalars
    scalars[0] = prediction
    scalars[1] = innovation
    scalars[2] = S
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


@numba.njit(cache=True, _nrt=False)
def dekf_step_many(
    model, config, belief, monitor, report, scratch, inputs, u, e, active, rows, out_rows, out
):
    """:func:`dekf_step` on sample ``i`` wherever ``active[i]`` is set, in order.

    The records are stacked (:func:`~manualcontrol.estimators.filters.batch.stack_records`):
    sample ``i`` (``inputs[i], u[i], e[i]``) steps the filter in row ``rows[i]`` of
    each, whose estimate goes to row ``out_rows[i]`` of that filter's output. Many
    filters on one sample each: ``rows = arange(n)``, ``out_rows`` zero (one-row
    outputs). One filter on a block of samples, in time order: ``rows`` all zero on a
    stack of one (:func:`~manualcontrol.estimators.filters.batch.stack_of_one`), and
    ``out_rows`` zero for the online block (the latest estimate in the row) or
    ``arange(n)`` for a whole run (sample ``k`` into row ``k``): the one compiled loop
    serves the batch, the online block and the offline run, so a member compiles no
    separate run loop (each loop is compiled, the step's code optimised into it, anew).
    """
    records = (model, config, belief, monitor, report, scratch, out)
    last = 0
    views = take(records, 0)
    for i in range(u.shape[0]):
        if active[i]:
            r = rows[i]
            if r != last:  # a block of one filter's samples takes its views once
                views = take(records, r)
                last = r
            dekf_step(*views[:6], inputs[i], u[i], e[i], out_rows[i], views[6])
