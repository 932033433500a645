"""The numba kernels of :mod:`~manualcontrol.estimators.members._ukf_core`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference, ``bench/compile_kernels.py``'s numba jobs): the records and
constants stay in the numba-free module, which exports these kernels by name on first
use, and the UKFs name them by :class:`~manualcontrol.envs._lazy.LazyKernel`.
"""

from __future__ import annotations

import numba
import numpy as np

from manualcontrol.estimators._pilot_core import (
    CFG_COUNT,
    CFG_DT,
    CFG_ERROR_STATE,
    CFG_GAMMA2,
    CFG_JITTER,
    CFG_MAX_COV,
    CFG_SPREAD,
    CFG_SUBSTEPS,
    SC_FROZEN,
    SC_K,
)
from manualcontrol.estimators._pilot_kernels import (
    inputs_in_use,
    noise_levels,
    report_frozen,
    report_row,
)
from manualcontrol.estimators.filters._kalman_kernels import clamp
from manualcontrol.estimators.filters._monitor_kernels import belief_health
from manualcontrol.estimators.filters._smoother_kernels import store_belief
from manualcontrol.estimators.filters._unscented_kernels import (
    constrain_prior,
    cross_covariance,
    project_points,
    sigma_points,
    triangular_sigma_points,
    unscented_correct,
    weighted_covariance,
    weighted_mean,
)
from manualcontrol.estimators.filters.batch import take
from manualcontrol.estimators.members._internal_model_kernels import (
    evaluate_coefficients,
    model_f,
    model_g,
)
from manualcontrol.estimators.members._ukf_core import SENSITIVITY_STEP


@numba.njit(cache=True, _nrt=False)
def _point_parameters(config, X, i, first, last, point_p):
    """``point_p = p`` with filter states ``first..last-1`` of point ``i`` in their slots.

    Returns True when those entries differ from what ``point_p`` held (the point's
    coefficients must be evaluated again).
    """
    changed = False
    for j in range(first, last):
        value = X[i, j]
        slot = config.slot[j]
        if point_p[slot] != value:
            point_p[slot] = value
            changed = True
    return changed


@numba.njit(cache=True, _nrt=False)
def _propagate(model, config, s, X, Y, count, prev_in, dt, first, offset):
    """``Y_i = X_i`` with canonical states (from ``offset``) advanced by one Euler step.

    The parameters of point ``i`` are the filter states ``first .. config.n_moving - 1``
    (``first = config.n_moving`` when the parameters are held at ``s.point_p``).
    """
    n_c = s.f.shape[0]
    point_p = s.point_p
    m = max(1, int(config.cfg[CFG_SUBSTEPS]))
    h = dt / m
    for i in range(count):
        if _point_parameters(config, X, i, first, config.n_moving, point_p) or i == 0:
            evaluate_coefficients(point_p, model)
        # the canonical states of this point, in place in Y
        for j in range(X.shape[1]):
            Y[i, j] = X[i, j]
        for c in range(n_c):
            s.dgdx[c] = X[i, offset + c]
        for _ in range(m):
            model_f(s.dgdx, prev_in, model, s.f, s.F, s.dfdp, False)
            for c in range(n_c):
                s.dgdx[c] += s.f[c] * h
        for c in range(n_c):
            Y[i, offset + c] = s.dgdx[c]


@numba.njit(cache=True, _nrt=False)
def _measure(model, config, s, X, Z, count, in_use, first, last, offset):
    """``Z_i = g(x_i, in_k, p_i)``; the parameters of point ``i`` are states ``first..last-1``."""
    n_c = s.f.shape[0]
    point_p = s.point_p
    for i in range(count):
        if _point_parameters(config, X, i, first, last, point_p) or i == 0:
            evaluate_coefficients(point_p, model)
        for c in range(n_c):
            s.f[c] = X[i, offset + c]
        Z[i, 0] = model_g(s.f, in_use, model, s.dgdx, s.dgdp, False)


@numba.njit(cache=True, _nrt=False)
def joint_step(model, config, belief, monitor, report, scratch, inputs_k, u_k, e_k, row, out):
    """One sample of the joint UKF (module docstring); writes row ``row`` of ``out``."""
    cfg = config.cfg
    z, P, prev_in, p, sc = belief
    work = scratch.work
    X, Y, Z = work.X, work.Y, work.Z
    n = z.shape[0]
    n_param = config.n_param
    offset = n_param
    dt = cfg[CFG_DT]
    gamma2 = cfg[CFG_GAMMA2]
    spread = cfg[CFG_SPREAD]
    count = int(cfg[CFG_COUNT])
    k = int(sc[SC_K])
    in_use = scratch.in_use

    R, _, q_error = noise_levels(cfg, sc, monitor, u_k, e_k)
    dropped = inputs_in_use(inputs_k, u_k, prev_in, in_use)
    if sc[SC_FROZEN] > 0.0:
        store_belief(row, z, P, out.x_prior, out.P_prior)
        store_belief(row, z, P, out.x_post, out.P_post)
        report_frozen(sc, monitor, prev_in, in_use, dropped, row, out)
        return

    for j in range(p.shape[0]):
        scratch.point_p[j] = p[j]
    ok = True
    if k > 0:
        # ---- prediction: sigma points of z^+_{k-1} through the Euler step
        for i in range(n):
            scratch.z_prev[i] = z[i]
        ok = sigma_points(z, P, spread, work.L, X)
        if ok:
            project_points(X, count, config.limit, report.lo, report.hi)
            _propagate(model, config, scratch, X, Y, count, prev_in, dt, 0, offset)
            weighted_mean(Y, config.wm, count, z)
            Q = scratch.Q
            for i in range(n):
                for j in range(n):
                    Q[i, j] = 0.0
                Q[i, i] = config.q[i] * gamma2
            Q[offset + int(cfg[CFG_ERROR_STATE]), offset + int(cfg[CFG_ERROR_STATE])] += (
                q_error * gamma2
            )
            weighted_covariance(Y, z, config.wc, count, Q, P)
            if out.cross.shape[0] > 0:
                cross_covariance(X, scratch.z_prev, Y, z, config.wc, count, scratch.cross)
                for i in range(n):
                    for j in range(n):
                        out.cross[row, i, j] = scratch.cross[i, j]
    store_belief(row, z, P, out.x_prior, out.P_prior)

    # ---- output: sigma points of z^-_k through g
    prediction = np.nan
    innovation = np.nan
    S = np.nan
    if ok:
        for j in range(p.shape[0]):
            scratch.point_p[j] = p[j]
        ok = sigma_points(z, P, spread, work.L, X)
    if ok:
        lo, hi = report.lo, report.hi
        constrain_prior(X, config.wm, config.wc, count, config.limit, lo, hi, z, P, scratch.zero)
        _measure(model, config, scratch, X, Z, count, in_use, 0, n_param, offset)
        weighted_mean(Z, config.wm, count, work.z)
        scratch.R[0, 0] = R
        weighted_covariance(Z, work.z, config.wc, count, scratch.R, work.S)
        prediction = work.z[0]
        S = work.S[0, 0]
        if not dropped:
            cross_covariance(X, z, Z, work.z, config.wc, count, work.Cxz)
            innovation = u_k - prediction
            scratch.r[0] = innovation
            ok = unscented_correct(
                z, P, scratch.r, work.Cxz, work.S, work.LS, work.K, work.log_det, cfg[CFG_JITTER]
            )
            clamp(z, config.limit, report.lo, report.hi)
    store_belief(row, z, P, out.x_post, out.P_post)
    for i in range(prev_in.shape[0]):
        prev_in[i] = in_use[i]

    finite, cov_ok = belief_health(z, P, cfg[CFG_MAX_COV], True)
    finite = finite and np.isfinite(prediction)
    if not dropped and not np.isfinite(innovation):
        finite = False
    if not ok:
        cov_ok = False
    variance = scratch.variance
    for j in range(n_param):
        p[config.slot[j]] = z[j]
        variance[config.slot[j]] = P[j, j]
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
def joint_step_many(
    model, config, belief, monitor, report, scratch, inputs, u, e, active, rows, out_rows, out
):
    """:func:`joint_step` on every filter of a stack whose ``active[i]`` is set.

    See :func:`~manualcontrol.estimators.members._dekf_core.dekf_step_many`.
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
            joint_step(*views[:6], inputs[i], u[i], e[i], out_rows[i], views[6])


@numba.njit(cache=True, _nrt=False)
def _set_point(theta, config, th_scale, j, sign, state, in_state_scale, base_state):
    """``point_p`` at ``theta + sign th_scale E_j`` and ``point_s`` at ``base + sign s M_j``."""
    tc = theta.config
    n_t = theta.th.shape[0]
    for t in range(n_t):
        theta.point_p[tc.slot[t]] = theta.th[t] + sign * th_scale * theta.E[t, j]
    for i in range(base_state.shape[0]):
        theta.point_s[i] = base_state[i] + sign * in_state_scale * state[i, j]
    for g in range(config.n_param):
        theta.point_p[config.slot[g]] = theta.point_s[g]


@numba.njit(cache=True, _nrt=False)
def _predict_sensitivity(model, config, theta, s, s_post, prev_in, dt, offset):
    """``M^- = D^- E``: the Euler step differenced along each sigma direction of ``theta``.

    ``(x(+) - x(-))/(2 h)`` with ``x(+-) = step(s^+ +- h D^+ E_j, theta +- h E_j)``.
    """
    n_t = theta.th.shape[0]
    n_c = s.f.shape[0]
    step = SENSITIVITY_STEP
    m = max(1, int(config.cfg[CFG_SUBSTEPS]))
    h = dt / m
    D, M, E = theta.D, theta.M, theta.E
    for j in range(n_t):
        # D^+ E_j into M (as scratch), then difference the step
        for i in range(D.shape[0]):
            acc = 0.0
            for t in range(n_t):
                acc += D[i, t] * E[t, j]
            M[i, j] = acc
    for j in range(n_t):
        for i in range(D.shape[0]):
            s.z_prev[i] = M[i, j]
        for sign in (1.0, -1.0):
            for i in range(D.shape[0]):
                theta.point_s[i] = s_post[i] + sign * step * s.z_prev[i]
            for t in range(n_t):
                theta.point_p[theta.config.slot[t]] = theta.th[t] + sign * step * E[t, j]
            evaluate_coefficients(theta.point_p, model)
            for c in range(n_c):
                theta.point_x[c] = theta.point_s[offset + c]
            for _ in range(m):
                model_f(theta.point_x, prev_in, model, s.f, s.F, s.dfdp, False)
                for c in range(n_c):
                    theta.point_x[c] += s.f[c] * h
            for i in range(D.shape[0]):
                value = theta.point_s[i] if i < offset else theta.point_x[i - offset]
                if sign > 0.0:
                    M[i, j] = value
                else:
                    M[i, j] = (M[i, j] - value) / (2.0 * step)


@numba.njit(cache=True, _nrt=False)
def _output_at(model, config, theta, s, in_use, offset):
    """``g`` at ``point_s`` (gains and canonical states) and ``point_p``."""
    n_c = s.f.shape[0]
    evaluate_coefficients(theta.point_p, model)
    for c in range(n_c):
        theta.point_x[c] = theta.point_s[offset + c]
    return model_g(theta.point_x, in_use, model, s.dgdx, s.dgdp, False)


@numba.njit(cache=True, _nrt=False)
def _theta_images(model, config, theta, s, s_prior, in_use, count, offset):
    """Parameter images ``Z = g(s^- + M^- e, theta + E e)`` at the sigma points.

    Point ``i < n_t`` lies at ``+E_i``, ``n_t + i`` at ``-E_i``, the centre (row 2 n_t,
    used by schemes that weigh it) at the prior.
    """
    n_t = theta.th.shape[0]
    Z = theta.work.Z
    for i in range(count):
        if i < 2 * n_t:
            j = i % n_t
            sign = 1.0 if i < n_t else -1.0
            _set_point(theta, config, 1.0, j, sign, theta.M, 1.0, s_prior)
        else:
            _set_point(theta, config, 0.0, 0, 1.0, theta.M, 0.0, s_prior)
        Z[i, 0] = _output_at(model, config, theta, s, in_use, offset)


@numba.njit(cache=True, _nrt=False)
def _correct_sensitivity(model, config, theta, s, s_prior, K, in_use, offset, corrected):
    """``M^+ = M^- - K_s G_tot E`` (eq. 50), ``G_tot E_j`` differenced; then ``D^+ = M^+ E^-1``.

    Without a correction (a dropped sample) ``M^+ = M^-``.
    """
    n_t = theta.th.shape[0]
    h = SENSITIVITY_STEP
    M = theta.M
    for j in range(n_t if corrected else 0):
        _set_point(theta, config, h, j, 1.0, M, h, s_prior)
        up = _output_at(model, config, theta, s, in_use, offset)
        _set_point(theta, config, h, j, -1.0, M, h, s_prior)
        down = _output_at(model, config, theta, s, in_use, offset)
        slope = (up - down) / (2.0 * h)
        for i in range(M.shape[0]):
            M[i, j] -= K[i, 0] * slope
    # D E = M  ->  rows of D solve D E = M, with E = c L lower triangular; a direction of
    # zero parameter variance (a semidefinite factor) carries no sensitivity
    E = theta.E
    for i in range(M.shape[0]):
        for j in range(n_t - 1, -1, -1):
            if E[j, j] <= 0.0:
                theta.D[i, j] = 0.0
                continue
            acc = M[i, j]
            for t in range(j + 1, n_t):
                acc -= theta.D[i, t] * E[t, j]
            theta.D[i, j] = acc / E[j, j]


@numba.njit(cache=True, _nrt=False)
def dual_step(model, config, belief, monitor, report, scratch, theta, inputs_k, u_k, e_k, row, out):
    """One sample of the dual UKF (module docstring); writes row ``row`` of ``out``."""
    cfg = config.cfg
    s_mean, P, prev_in, p, sc = belief
    work = scratch.work
    X, Y, Z = work.X, work.Y, work.Z
    n = s_mean.shape[0]
    n_g = config.n_param
    offset = n_g
    tc = theta.config
    th, Pp, tw = theta.th, theta.Pp, theta.work
    n_t = th.shape[0]
    dt = cfg[CFG_DT]
    gamma2 = cfg[CFG_GAMMA2]
    spread = cfg[CFG_SPREAD]
    count = int(cfg[CFG_COUNT])
    t_spread = tc.cfg[CFG_SPREAD]
    t_count = int(tc.cfg[CFG_COUNT])
    k = int(sc[SC_K])
    in_use = scratch.in_use

    R, R_p, q_error = noise_levels(cfg, sc, monitor, u_k, e_k)
    dropped = inputs_in_use(inputs_k, u_k, prev_in, in_use)
    if sc[SC_FROZEN] > 0.0:
        store_belief(row, s_mean, P, out.x_prior, out.P_prior)
        store_belief(row, s_mean, P, out.x_post, out.P_post)
        store_belief(row, th, Pp, out.x_prior_2, out.P_prior_2)
        store_belief(row, th, Pp, out.x_post_2, out.P_post_2)
        report_frozen(sc, monitor, prev_in, in_use, dropped, row, out)
        return

    # theta^- = theta^+ in p (the state filter's parameters)
    for t in range(n_t):
        p[tc.slot[t]] = th[t]
    ok = True
    if k > 0:
        # ---- parameter prediction: random walk
        for t in range(n_t):
            Pp[t, t] += tc.q[t] * gamma2
    store_belief(row, th, Pp, out.x_prior_2, out.P_prior_2)
    # ---- parameter sigma directions and the state sensitivity along them
    with_theta = n_t > 0 and k > 0
    if with_theta:
        for j in range(p.shape[0]):
            theta.point_p[j] = p[j]
        # E below is read as lower triangular (_correct_sensitivity)
        ok = triangular_sigma_points(th, Pp, t_spread, tw.L, tw.X)
        if ok:
            if constrain_prior(
                tw.X, tc.wm, tc.wc, t_count, tc.limit, report.lo, report.hi, th, Pp, theta.zero
            ):
                ok = triangular_sigma_points(th, Pp, t_spread, tw.L, tw.X)
                project_points(tw.X, t_count, tc.limit, report.lo, report.hi)
        if ok:
            for t in range(n_t):
                for j in range(n_t):
                    theta.E[t, j] = t_spread * tw.L[t, j]
            _predict_sensitivity(model, config, theta, scratch, s_mean, prev_in, dt, offset)

    # ---- state filter with theta^-: prediction
    for j in range(p.shape[0]):
        scratch.point_p[j] = p[j]
    if k > 0 and ok:
        for i in range(n):
            scratch.z_prev[i] = s_mean[i]
        ok = sigma_points(s_mean, P, spread, work.L, X)
        if ok:
            project_points(X, count, config.limit, report.lo, report.hi)
            # theta is held: no state of this filter enters f (first = n_moving = 0)
            _propagate(model, config, scratch, X, Y, count, prev_in, dt, 0, offset)
            weighted_mean(Y, config.wm, count, s_mean)
            Q = scratch.Q
            for i in range(n):
                for j in range(n):
                    Q[i, j] = 0.0
                Q[i, i] = config.q[i] * gamma2
            Q[offset + int(cfg[CFG_ERROR_STATE]), offset + int(cfg[CFG_ERROR_STATE])] += (
                q_error * gamma2
            )
            weighted_covariance(Y, s_mean, config.wc, count, Q, P)
            if out.cross.shape[0] > 0:
                cross_covariance(X, scratch.z_prev, Y, s_mean, config.wc, count, scratch.cross)
                for i in range(n):
                    for j in range(n):
                        out.cross[row, i, j] = scratch.cross[i, j]
    store_belief(row, s_mean, P, out.x_prior, out.P_prior)

    # ---- parameter images: the output along the sigma directions, states moving with theta
    if with_theta and ok:
        for j in range(p.shape[0]):
            theta.point_p[j] = p[j]
        for i in range(n):
            theta.point_s[i] = s_mean[i]
        _theta_images(model, config, theta, scratch, s_mean, in_use, t_count, offset)
        weighted_mean(tw.Z, tc.wm, t_count, tw.z)
        theta.R[0, 0] = R_p
        weighted_covariance(tw.Z, tw.z, tc.wc, t_count, theta.R, tw.S)
        cross_covariance(tw.X, th, tw.Z, tw.z, tc.wc, t_count, tw.Cxz)
        for i in range(n):
            scratch.z_prev[i] = s_mean[i]  # the state prior, for the sensitivity correction

    # ---- state filter: output and correction
    prediction = np.nan
    innovation = np.nan
    S = np.nan
    corrected = False
    if ok:
        for j in range(p.shape[0]):
            scratch.point_p[j] = p[j]
        ok = sigma_points(s_mean, P, spread, work.L, X)
    if ok:
        lo, hi = report.lo, report.hi
        constrain_prior(
            X, config.wm, config.wc, count, config.limit, lo, hi, s_mean, P, scratch.zero
        )
        _measure(model, config, scratch, X, Z, count, in_use, 0, n_g, offset)
        weighted_mean(Z, config.wm, count, work.z)
        scratch.R[0, 0] = R
        weighted_covariance(Z, work.z, config.wc, count, scratch.R, work.S)
        prediction = work.z[0]
        S = work.S[0, 0]
        if not dropped:
            cross_covariance(X, s_mean, Z, work.z, config.wc, count, work.Cxz)
            innovation = u_k - prediction
            scratch.r[0] = innovation
            ok = unscented_correct(
                s_mean,
                P,
                scratch.r,
                work.Cxz,
                work.S,
                work.LS,
                work.K,
                work.log_det,
                cfg[CFG_JITTER],
            )
            corrected = ok
            clamp(s_mean, config.limit, report.lo, report.hi)
    if with_theta and ok:
        # eq. 50: the state filter's correction moves the sensitivity too
        _correct_sensitivity(
            model, config, theta, scratch, scratch.z_prev, work.K, in_use, offset, corrected
        )
        # ---- parameter correction with the state filter's innovation (as the DEKF)
        if corrected:
            scratch.r[0] = innovation
            ok = unscented_correct(
                th, Pp, scratch.r, tw.Cxz, tw.S, tw.LS, tw.K, tw.log_det, cfg[CFG_JITTER]
            )
            clamp(th, tc.limit, report.lo, report.hi)
    store_belief(row, s_mean, P, out.x_post, out.P_post)
    store_belief(row, th, Pp, out.x_post_2, out.P_post_2)
    for i in range(prev_in.shape[0]):
        prev_in[i] = in_use[i]

    finite_s, cov_ok_s = belief_health(s_mean, P, cfg[CFG_MAX_COV], True)
    finite_t, cov_ok_t = belief_health(th, Pp, cfg[CFG_MAX_COV], False)
    finite = finite_s and finite_t and np.isfinite(prediction)
    cov_ok = cov_ok_s and cov_ok_t and ok
    if not dropped and not np.isfinite(innovation):
        finite = False
    variance = scratch.variance
    for g in range(n_g):
        p[config.slot[g]] = s_mean[g]
        variance[config.slot[g]] = P[g, g]
    for t in range(n_t):
        p[tc.slot[t]] = th[t]
        variance[tc.slot[t]] = Pp[t, t]
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
def dual_step_many(
    model,
    config,
    belief,
    monitor,
    report,
    scratch,
    theta,
    inputs,
    u,
    e,
    active,
    rows,
    out_rows,
    out,
):
    """:func:`dual_step` on every filter of a stack whose ``active[i]`` is set.

    See :func:`~manualcontrol.estimators.members._dekf_core.dekf_step_many`.
    """
    records = (model, config, belief, monitor, report, scratch, theta, out)
    last = 0
    views = take(records, 0)
    for i in range(u.shape[0]):
        if active[i]:
            r = rows[i]
            if r != last:  # a block of one filter's samples takes its views once
                views = take(records, r)
                last = r
            dual_step(*views[:7], inputs[i], u[i], e[i], out_rows[i], views[7])
